"""Issue 12, items 2 and 5: a failed calibration is unusable, inputs are checked against each other.

Bad-input cases assert the exit code, exactly one stderr line without "Traceback", and the
files left (none new). Commands run in-process through ``calibrate.cli.main``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rasterio
from affine import Affine

from calibrate.cli import main
from sensor_models.base import CalibrationStatus
from sensor_models.errors import DemError, InputError
from sensor_models.readers import open_model
from sensor_models.readers.manifest import write_manifest
from sensor_models.terrain.dem import Dem
from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"
TRUTH = FIXTURE / "truth_manifest.json"
DEM = FIXTURE / "reference" / "dem.tif"
DOM = FIXTURE / "reference" / "dom.tif"

PARTIAL = CalibrationStatus("partial", "camera 2 not estimable",
                            uncalibrated=({"band": "B2", "ccd": "cam2_ccd1", "reason": "0 GCPs"},),
                            unverified=({"band": "B2", "ccd": "cam2_ccd2", "reason": "no check points"},))


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def files_under(folder: Path) -> set:
    return {p.relative_to(folder) for p in folder.rglob("*")} if folder.exists() else set()


def assert_one_line_refusal(code, err, *words):
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 1, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for word in words:
        assert word in lines[0], lines[0]


def manifest_with(status: CalibrationStatus | None, folder: Path) -> Path:
    """The fixture's LAB model written with a calibration status into ``folder/manifest.json``."""
    model = open_model(SCENE)
    model.calibration = status
    folder.mkdir(parents=True, exist_ok=True)
    rasters = {b: str(FIXTURE / f"{b}.tif") for b in model.bands}
    write_manifest(model, folder / "manifest.json", rasters=rasters)
    return folder / "manifest.json"


@pytest.fixture(scope="module")
def failed(tmp_path_factory) -> Path:
    return manifest_with(CalibrationStatus("failed", "one GCP"), tmp_path_factory.mktemp("failed") / "cal")


@pytest.fixture(scope="module")
def partial(tmp_path_factory) -> Path:
    return manifest_with(PARTIAL, tmp_path_factory.mktemp("partial") / "cal")


def far_dem(path: Path, *, shift_m: float = 300_000.0) -> Path:
    """The fixture DEM moved ``shift_m`` east (same heights, same datum tag)."""
    with rasterio.open(DEM) as ds:
        profile, z, tags = ds.profile, ds.read(1), ds.tags()
    t = profile["transform"]
    profile["transform"] = Affine(t.a, t.b, t.c + shift_m, t.d, t.e, t.f)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z, 1)
        ds.update_tags(**tags)
    return path


# --------------------------------------------------------------------------- failed means unusable
def _failed_cases(failed: Path, out: Path):
    sites = out.parent / "sites.yaml"
    sites.write_text("- name: a\n  scene: x\n  dom: x\n  dem: x\n")
    return {
        "ortho --calibration": ["ortho", SCENE, "--calibration", failed.parent, "--dem", DEM, "--out", out / "o.tif"],
        "ortho SCENE": ["ortho", failed, "--dem", DEM, "--out", out / "o.tif"],
        "relative": ["relative", SCENE, "--calibration", failed, "--dem", DEM, "--out", out],
        "rpc": ["rpc", failed, "--out", out / "x_RPC.TXT"],
        "validate": ["validate", sites, "--calibration", failed, "--out", out],
        "localize": ["localize", failed, "--rows", "10", "--cols", "10", "--height", "0", "--out", out / "p.csv"],
        "truth error": ["truth", "error", failed, "--truth", TRUTH, "--height", "0", "--out", out / "t.json"],
    }


@pytest.mark.parametrize("case", ["ortho --calibration", "ortho SCENE", "relative", "rpc", "validate", "localize",
                                  "truth error"])
def test_a_failed_calibration_is_refused(case, failed, tmp_path, capsys):
    out = tmp_path / "out"
    argv = _failed_cases(failed, out)[case]
    before = files_under(tmp_path)
    code, _, err = run(capsys, *argv)
    assert_one_line_refusal(code, err, str(failed), "the calibration failed (one GCP)",
                            f"gcpcal {case.split(' --')[0].replace(' SCENE', '')} does not use a failed calibration")
    assert files_under(tmp_path) == before  # nothing new


def test_a_partial_calibration_is_used_with_a_warning(partial, tmp_path, capsys):
    out = tmp_path / "p.csv"
    code, _, err = run(capsys, "localize", partial, "--rows", "10.5", "--cols", "20.5", "--height", "100",
                       "--out", out)
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gcpcal: warning:") and "partial" in lines[0]
    assert "B2/cam2_ccd1 (0 GCPs)" in lines[0] and "B2/cam2_ccd2 (no check points)" in lines[0]
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["calibration_status"] == "partial" and summary["warnings"] == [lines[0][len("gcpcal: warning: "):]]


def test_rpc_of_a_partial_calibration_records_the_warning(partial, tmp_path, capsys):
    # --max-error-px 1: one RPC within it, so the only warning is the status's
    code, _, err = run(capsys, "rpc", partial, "--ccd", "cam1_ccd1", "--out", tmp_path / "x_RPC.TXT",
                       "--max-error-px", "1")
    assert code == 0, err
    summary = json.loads((tmp_path / "x_RPC.TXT.summary.json").read_text())
    assert summary["calibration_status"] == "partial" and len(summary["warnings"]) == 1
    assert "warning" in err


def test_a_lab_model_has_no_status_and_no_warning(tmp_path, capsys):
    code, out, err = run(capsys, "localize", SCENE, "--rows", "10.5", "--cols", "20.5", "--height", "100", "--json")
    assert code == 0 and err == ""
    doc = json.loads(out)
    assert doc["calibration_status"] is None and doc["warnings"] == []


def test_run_marks_its_failed_result_unusable(tmp_path):
    from calibrate.pipelines.run import _own_status

    cal = tmp_path / "calibration"
    manifest_with(None, cal)
    fields = _own_status(tmp_path, {"success": False, "message": "2 GCPs", "model": "calibration/manifest.json"})
    assert fields["success"] is False and fields["model"] is None
    status = open_model(cal / "manifest.json").calibration
    assert status.status == "failed" and status.message == "2 GCPs"


def test_run_refuses_its_own_result_when_it_says_failed(tmp_path):
    from calibrate.pipelines.run import _own_status

    manifest_with(CalibrationStatus("failed", "collinear GCPs"), tmp_path / "calibration")
    fields = _own_status(tmp_path, {"success": True, "model": "calibration/manifest.json"})
    assert fields["success"] is False and fields["model"] is None and "collinear GCPs" in fields["message"]
    manifest_with(PARTIAL, tmp_path / "calibration")
    fields = _own_status(tmp_path, {"success": True, "model": "calibration/manifest.json"})
    assert fields["calibration_status"] == "partial" and "gcpcal run uses it" in fields["warnings"][0]


def _band(success: bool, message: str = ""):
    return SimpleNamespace(success=success, message=message)


def test_relative_status_is_calibrated_only_when_every_band_is():
    from calibrate.actions.relative import _output_status

    ok = SimpleNamespace(bands={"B1": _band(True), "B3": _band(True)})
    assert _output_status(ok, None).status == "calibrated"
    assert _output_status(ok, CalibrationStatus("calibrated")).status == "calibrated"
    one_failed = SimpleNamespace(bands={"B1": _band(True), "B3": _band(False, "12 tie points")})
    status = _output_status(one_failed, None)
    assert status.status == "partial" and "B3" in status.message
    assert status.uncalibrated == ({"band": "B3", "ccd": "", "reason": "12 tie points"},)
    carried = _output_status(ok, PARTIAL)
    assert carried.status == "partial" and carried.uncalibrated == PARTIAL.uncalibrated
    assert carried.unverified == PARTIAL.unverified


# --------------------------------------------------------------------------- ground coordinates
@pytest.mark.parametrize("argv, field", [
    (["--lon", "5.4", "--lat", "100", "--h", "0"], "lat"),
    (["--lon", "400", "--lat", "44", "--h", "0"], "lon"),
    (["--lon", "-181", "--lat", "44", "--h", "0"], "lon"),
    (["--lon", "5.4", "--lat", "44", "--h", "12000"], "h"),
    (["--lon", "5.4", "--lat", "44", "--h", "-900"], "h"),
    (["--rows", "10", "--cols", "5000", "--height", "0"], "col"),
    (["--rows", "-3", "--cols", "10", "--height", "0"], "row"),
    (["--rows", "10", "--cols", "10", "--height", "10000"], "h"),
])
def test_coordinates_out_of_range_are_refused(argv, field, tmp_path, capsys):
    code, _, err = run(capsys, "localize", SCENE, *argv, "--out", tmp_path / "p.csv")
    assert_one_line_refusal(code, err, f"field '{field}'", "outside")
    assert files_under(tmp_path) == set()


def test_csv_coordinates_out_of_range_name_the_file(tmp_path, capsys):
    pts = tmp_path / "pts.csv"
    pts.write_text("lon,lat,h\n5.4,44.4,0\n5.4,95,0\n")
    code, _, err = run(capsys, "localize", SCENE, "--csv", pts, "--inverse")
    assert_one_line_refusal(code, err, str(pts), "field 'lat'", "point 2")


def test_longitudes_east_up_to_360_are_accepted(capsys):
    code, out, err = run(capsys, "localize", SCENE, "--lon", "365.43", "--lat", "44.45", "--h", "0")
    assert code == 1 and "field 'lon'" in err
    code, out, err = run(capsys, "localize", SCENE, "--lon", "5.43", "--lat", "44.45", "--h", "0", "--json")
    assert code == 0, err


# --------------------------------------------------------------------------- DEM footprint
def test_coverage_and_void_fractions_are_vectorized():
    z = np.full((11, 11), 100.0)
    z[:, :3] = np.nan  # the western 3 columns of nodes are voids
    dem = Dem.from_array(z, Affine(0.1, 0, 0.0, 0, -0.1, 1.1), "EPSG:4326")
    lon, lat = np.meshgrid(np.linspace(0.05, 2.05, 41), np.linspace(0.1, 1.0, 5))
    assert dem.coverage_fraction(lon, lat) == pytest.approx(21 / 41)
    inside_lon = np.linspace(0.05, 1.05, 101)
    assert dem.void_fraction(inside_lon, np.full(101, 0.5)) == pytest.approx(0.3, abs=0.02)
    assert dem.coverage_fraction([np.nan], [0.5]) == 0.0


def test_check_dem_footprint_refuses_and_describes():
    dem = Dem.open(DEM)
    lon, lat = footprint_sample_lonlat(open_model(TRUTH), 500.0)
    figures = check_dem_footprint(dem, lon, lat)
    assert figures["dem_coverage"] == 1.0 and figures["dem_void_fraction"] == 0.0 and figures["warnings"] == []
    with pytest.raises(DemError, match=r"covers 0\.0 % of the scene footprint"):
        check_dem_footprint(dem, lon + 3.0, lat)
    half = lon < np.median(lon)
    lon_half = np.where(half, lon + 3.0, lon)
    with pytest.raises(DemError, match=r"covers \d+\.\d % of the scene footprint"):
        check_dem_footprint(dem, lon_half, lat, min_coverage=0.6)
    assert "covers" in check_dem_footprint(dem, lon_half, lat, min_coverage=0.3)["warnings"][0]


def test_rpc_refuses_a_dem_300_km_away(tmp_path, capsys):
    dem = far_dem(tmp_path / "far.tif")
    out = tmp_path / "out"
    code, _, err = run(capsys, "rpc", SCENE, "--dem", dem, "--out", out / "x_RPC.TXT")
    assert_one_line_refusal(code, err, str(dem), "covers 0.0 % of the scene footprint")
    assert not out.exists()


def test_rpc_with_a_covering_dem_records_the_coverage(tmp_path, capsys):
    code, _, err = run(capsys, "rpc", TRUTH, "--dem", DEM, "--ccd", "cam1_ccd1", "--out", tmp_path / "x_RPC.TXT",
                       "--max-error-px", "1")  # one RPC within it: nothing to warn about
    assert code == 0 and err == ""
    summary = json.loads((tmp_path / "x_RPC.TXT.summary.json").read_text())
    assert summary["dem_coverage"] == 1.0 and summary["dem_void_fraction"] == 0.0 and summary["warnings"] == []


def test_rpc_says_how_much_of_the_footprint_a_dem_covers(tmp_path, capsys):
    # the LAB model's footprint is 260 px off the true one: the fixture DEM covers three quarters of it
    code, _, err = run(capsys, "rpc", SCENE, "--dem", DEM, "--ccd", "cam1_ccd1", "--out", tmp_path / "x_RPC.TXT")
    assert code == 0, err
    summary = json.loads((tmp_path / "x_RPC.TXT.summary.json").read_text())
    assert 0.5 < summary["dem_coverage"] < 1.0
    assert err.startswith("gcpcal: warning:") and f"covers {100 * summary['dem_coverage']:.1f} %" in err


def test_truth_error_refuses_a_dem_not_under_the_scene(tmp_path, capsys):
    dem = far_dem(tmp_path / "far.tif")
    code, _, err = run(capsys, "truth", "error", SCENE, "--truth", TRUTH, "--dem", dem, "--out", tmp_path / "t.json")
    assert_one_line_refusal(code, err, "covers 0.0 % of the scene footprint")
    assert not (tmp_path / "t.json").exists()


def _with_voids(p_dem: Path, fraction_of_cols: float) -> None:
    with rasterio.open(p_dem, "r+") as ds:
        z = ds.read(1)
        z[:, : int(fraction_of_cols * z.shape[1])] = np.nan
        ds.write(z, 1)


def test_simulate_pushbroom_refuses_a_dem_away_and_mostly_void(tmp_path, capsys):
    from test_simulate import small_config, write_reference

    cfg = small_config()
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    (tmp_path / "cfg.json").write_text(json.dumps(cfg.to_dict()))
    _with_voids(p_dem, 0.5)
    out = tmp_path / "scene"
    code, _, err = run(capsys, "-q", "simulate", "pushbroom", "--out", out, "--config", tmp_path / "cfg.json",
                       "--dom", p_dom, "--dem", p_dem)
    assert_one_line_refusal(code, err, "falls in DEM voids", "at most 5 %")
    assert files_under(out) == set()


def test_simulate_pushbroom_reports_small_voids(tmp_path, capsys):
    from sensor_models.simulate.pushbroom_sim import footprint_lonlat, simulate_pushbroom
    from sensor_models.simulate.scene import build_models
    from test_simulate import small_config, write_reference

    cfg = small_config()
    p_dom, p_dem, _, crs = write_reference(tmp_path, cfg)
    lon, lat = footprint_lonlat(build_models(cfg).true_model, (900.0,))
    with rasterio.open(p_dem, "r+") as ds:  # a small void at the footprint's centre
        z = ds.read(1)
        import pyproj

        x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon.mean(), lat.mean())
        r, c = ds.index(x, y)
        z[r - 4 : r + 4, c - 4 : c + 4] = np.nan
        ds.write(z, 1)
    summary = simulate_pushbroom(tmp_path / "scene", config=cfg, dom=p_dom, dem=p_dem)
    assert 0.0 < summary["dem_void_fraction"] < 0.05 and summary["dem_coverage"] == 1.0
    assert len(summary["warnings"]) == 1 and "DEM voids" in summary["warnings"][0]
    on_disk = json.loads((tmp_path / "scene" / "summary.json").read_text())
    assert on_disk["dem_void_fraction"] == summary["dem_void_fraction"]


# --------------------------------------------------------------------------- star frames of the camera
@pytest.fixture(scope="module")
def star_sequences(tmp_path_factory):
    from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

    root = tmp_path_factory.mktemp("stars")
    cfg = GeoStarsConfig(n_frames=3, mag_limit=6.0)
    simulate_geo_stars(root / "small", config=replace(cfg, image_shape=(64, 64)))
    simulate_geo_stars(root / "large", config=replace(cfg, image_shape=(96, 96)))
    return root


def test_stars_refuses_frames_of_another_camera(star_sequences, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run(capsys, "stars", star_sequences / "large", "--manifest", star_sequences / "small" / "manifest.json",
                       "--out", out)
    assert_one_line_refusal(code, err, "another camera", "96 x 96", "64 x 64")
    assert not out.exists()


def test_run_refuses_star_frames_of_another_camera(star_sequences, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run(capsys, "run", SCENE, "--dom", DOM, "--dem", DEM, "--star-frames", star_sequences / "large",
                       "--out", out)
    assert_one_line_refusal(code, err, "another camera", "96 x 96", "512 x 768")
    assert not out.exists()


def test_frames_of_the_same_size_but_another_pixel_angle_are_refused(star_sequences):
    from calibrate.actions.stars import read_star_inputs
    from calibrate.star_frames import check_frames_camera

    frames, _, _, lab, _ = read_star_inputs(star_sequences / "small")
    other = SimpleNamespace(image_shape=lab.image_shape, ifov_rad=lab.ifov_rad * 1.5)
    with pytest.raises(InputError, match="pixel angle"):
        check_frames_camera(frames, lab, other, frames_source="frames.json", model_source="scene.json")
    check_frames_camera(frames, lab, SimpleNamespace(image_shape=lab.image_shape, ifov_rad=lab.ifov_rad * 1.001),
                        frames_source="frames.json", model_source="scene.json")


@pytest.mark.parametrize("success", [True, False])
def test_stars_writes_its_status_into_the_manifest(star_sequences, tmp_path, monkeypatch, success):
    import calibrate.report.star_report
    import calibrate.star_calibration
    from calibrate.actions.stars import stars_sequence

    def fake_process_frames(frames, seconds, lab, **_):  # the estimation itself is tested elsewhere
        doc = {"success": success, "message": "ok" if success else "3 tracks", "timings": {}}
        return SimpleNamespace(success=success, message=doc["message"], model=lab, to_dict=lambda points: dict(doc))

    monkeypatch.setattr(calibrate.star_calibration, "process_frames", fake_process_frames)
    monkeypatch.setattr(calibrate.report.star_report, "write_star_report", lambda *a, **k: None)
    doc = stars_sequence(star_sequences / "small", tmp_path / "out")
    want = "calibrated" if success else "failed"
    assert doc["calibration_status"] == want
    status = open_model(tmp_path / "out" / "manifest.json").calibration
    assert status.status == want and (success or status.message == "3 tracks")


def test_truth_error_with_a_dem_under_part_of_the_scene_says_so(tmp_path, capsys):
    with rasterio.open(DEM) as ds:
        profile, z, tags = ds.profile, ds.read(1), ds.tags()
    width = int(0.55 * z.shape[1])  # the western 55 %: camera 2's last CCD falls off it
    profile.update(width=width)
    with rasterio.open(tmp_path / "west.tif", "w", **profile) as ds:
        ds.write(z[:, :width], 1)
        ds.update_tags(**tags)
    code, out, err = run(capsys, "truth", "error", SCENE, "--truth", TRUTH, "--dem", tmp_path / "west.tif")
    assert code == 0 and "Traceback" not in err
    assert err.count("\n") == 1 and "gcpcal: warning:" in err and "of the scene footprint" in err
    assert "cam2_ccd2  no point on the DEM" in out


def test_ortho_uses_a_partial_calibration_and_says_so(partial, tmp_path, capsys):
    out = tmp_path / "o.tif"
    code, _, err = run(capsys, "-q", "ortho", SCENE, "--calibration", partial.parent, "--dem", DEM, "--out", out,
                       "--resolution", "240")
    assert code == 0, err
    assert err.count("gcpcal: warning:") == 1 and "gcpcal ortho uses it" in err
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["calibration_status"] == "partial" and len(summary["warnings"]) == 1


def test_run_without_a_result_leaves_earlier_files_alone(tmp_path):
    from calibrate.pipelines.run import _own_status

    old = manifest_with(None, tmp_path / "calibration")  # an earlier run's output
    before = old.read_text()
    fields = _own_status(tmp_path, {"success": False, "path": None, "message": "no star frames"})
    assert fields["success"] is False and fields["model"] is None
    assert old.read_text() == before
