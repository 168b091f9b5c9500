"""Band-to-band relative calibration (seed 003 section 2.2.2) on the embedded HY-1C-like scene.

The reference band B2 is first calibrated absolutely from GCPs the TRUE model gives (ground seen
by the true B2 pixels on the DEM, observed with 0.05 px of seeded noise): as an analyst's DOM
matching would, it leaves B2 about 0.1 px from the truth, and it takes a second instead of the
matcher's several. B1, B3 and B4 keep their laboratory interiors, several pixels off their true
band-to-band registration (focal-plane offsets and per-CCD errors); the relative calibration must
bring them within a few hundredths of a pixel of the truth, from tie points with B2 alone.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calibrate.absolute import calibrate_model
from gcpmatch.gcps import GcpTable
from calibrate.cli import main
from calibrate.band_registration import registration_error
from calibrate.relative import relative_calibration
from calibrate.tie_points import match_band
from gcpmatch.extract import read_band
from sensor_models.errors import InputError
from sensor_models.readers import open_model, open_scene
from sensor_models.readers.manifest import write_manifest
from sensor_models.simulate.truth import truth_error
from sensor_models.terrain.dem import Dem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
OTHERS = ("B1", "B3", "B4")


@pytest.fixture(scope="module")
def scene():
    opened = open_scene(FIXTURE / "manifest.json")
    lab = opened.model
    truth = open_model(FIXTURE / "truth_manifest.json")
    dem = Dem.open(FIXTURE / "reference" / "dem.tif")
    images = {b: read_band(opened, b) for b in lab.bands}
    # GCPs of B2 from the truth: a grid of pixels localized by the TRUE model, observed with noise
    rng = np.random.default_rng(3)
    rows, cols, ccds = [], [], []
    for i, look in enumerate(lab.band_ccds("B2")):
        r, c = np.meshgrid(np.linspace(8, lab.n_rows - 8, 16), look.first_col + np.linspace(2, look.n_detectors - 2, 12),
                           indexing="ij")
        rows.append(r.ravel())
        cols.append(c.ravel())
        ccds.append(np.full(r.size, i))
    row, col, ccd = (np.concatenate(a) for a in (rows, cols, ccds))
    lon, lat, h = truth.image_to_ground(row, col, dem=dem, band="B2", array=ccd)
    noisy_row, noisy_col = row + rng.normal(0, 0.05, row.size), col + rng.normal(0, 0.05, col.size)
    gcps = GcpTable.from_arrays(noisy_row, noisy_col, lon, lat, h, band="B2", ccd=ccd, sigma_px=0.05)
    ref = calibrate_model(lab, gcps)
    assert ref.success, ref.message
    return {"lab": lab, "rasters": opened.rasters, "truth": truth, "dem": dem, "images": images,
            "calibrated": ref.model, "gcps": gcps}


@pytest.fixture(scope="module")
def relative(scene):
    return relative_calibration(scene["calibrated"], scene["images"], scene["dem"])


def test_band_to_band_registration_goes_from_pixels_to_hundredths(scene, relative):
    truth, dem = scene["truth"], scene["dem"]
    before = registration_error(truth, scene["calibrated"], dem=dem)
    after = registration_error(truth, relative.model, dem=dem)
    assert relative.success, relative.message
    for band in OTHERS:
        b, a = before[band], after[band]
        r = relative.bands[band]
        print(f"{band}: registration vs truth {b['rms_px']:.3f} -> {a['rms_px']:.4f} px (max {a['max_px']:.3f}); "
              f"tie RMS {r.before['rms_px']:.3f} -> {r.after['rms_px']:.4f} px over {len(r.ties)} ties")
        assert 3.0 < b["rms_px"] < 10.0
        assert 0.002 < a["rms_px"] < 0.05
        assert a["max_px"] < 0.2
        assert all(c["rms_px"] < 0.06 for c in a["per_ccd"])
        # the tie residuals say the same, without the truth
        assert 3.0 < r.before["rms_px"] < 10.0
        assert 0.002 < r.after["rms_px"] < 0.05
        assert all(c["after"]["rms_px"] < 0.05 and c["ties"] > 50 for c in r.per_ccd)
        assert len(r.ties) > 0.6 * r.windows


def test_every_band_ends_as_accurate_as_the_reference_band(scene, relative):
    truth, dem = scene["truth"], scene["dem"]
    ref_err = truth_error(truth, relative.model, dem=dem, bands=["B2"], step_px=24)["rms_px"]
    assert 0.01 < ref_err < 0.2
    for band in OTHERS:
        lab_err = truth_error(truth, scene["calibrated"], dem=dem, bands=[band], step_px=24)["rms_px"]
        err = truth_error(truth, relative.model, dem=dem, bands=[band], step_px=24)["rms_px"]
        assert lab_err > 3.0
        assert abs(err - ref_err) < 0.02


def test_only_the_band_interiors_change(scene, relative):
    before, after = scene["calibrated"].parameters(), relative.model.parameters()
    changed = {n for n, a, b in zip(before.names, before.values, after.values) if a != b}
    assert changed and all(n.split(".")[0] in OTHERS for n in changed)
    assert {n.split(".")[0] for n in changed} == set(OTHERS)


def test_tie_points_measure_the_true_band_positions(scene):
    """Independent of the solve: the matched positions are where the TRUE model puts them."""
    truth, dem = scene["truth"], scene["dem"]
    ties, windows, rejected, _ = match_band(scene["calibrated"], scene["images"]["B2"], scene["images"]["B4"], dem,
                                            band="B4")
    lon, lat, h = truth.image_to_ground(ties.row_ref, ties.col_ref, dem=dem, band="B2", array=ties.ccd_ref)
    r, c = truth.ground_to_image(lon, lat, h, band="B4", array=ties.ccd)
    d = np.hypot(ties.row - r, ties.col - c)
    assert len(ties) > 300 and windows == sum(rejected.values()) + len(ties)
    assert 0.002 < float(np.sqrt(np.mean(d**2))) < 0.05
    # and the model used for matching was several pixels off
    assert float(np.median(np.hypot(ties.row - ties.predicted_row, ties.col - ties.predicted_col))) > 2.0


def test_a_band_offset_beyond_the_fine_windows_is_found_by_the_coarse_step(scene):
    model = scene["calibrated"]
    values = model.parameters().values.copy()
    names = model.parameters().names
    ifov = float(model.band_ccds("B1")[0].tan_psi_y[1])
    for k, n in enumerate(names):
        if n.startswith("B1.") and n.endswith("tan_psi_x.c0"):
            values[k] += 40 * ifov  # 40 lines: beyond a quarter of the 64 px windows
    shifted = model.with_parameters(values)
    with_coarse = relative_calibration(shifted, scene["images"], scene["dem"], bands=["B1"], passes=1)
    assert with_coarse.success, with_coarse.message
    rows = [o["row_px"] for o in with_coarse.bands["B1"].coarse_offsets]
    assert all(35.0 < abs(r) < 50.0 for r in rows)
    reg = registration_error(scene["truth"], with_coarse.model, dem=scene["dem"], bands=["B1"])["B1"]["rms_px"]
    assert reg < 0.05
    # without it the band fails, reported, and keeps its interior
    without = relative_calibration(shifted, scene["images"], scene["dem"], bands=["B1"], passes=1, coarse=False)
    r = without.bands["B1"]
    assert not without.success and not r.success
    assert "B1" in r.message and "band-to-band error may exceed" in r.message
    assert np.array_equal(without.model.parameters().values, shifted.parameters().values)


def test_a_short_along_track_stretch_is_enough(scene):
    rel = relative_calibration(scene["calibrated"], scene["images"], scene["dem"], rows=(200, 330), bands=["B3"])
    ties = rel.bands["B3"].ties
    assert rel.success and ties.row_ref.min() >= 200 and ties.row_ref.max() <= 330
    reg = registration_error(scene["truth"], rel.model, dem=scene["dem"], bands=["B3"])["B3"]["rms_px"]
    assert 0.002 < reg < 0.1


def test_narrow_windows_reach_the_ccd_ends(scene):
    rel = relative_calibration(scene["calibrated"], scene["images"], scene["dem"], window_px=(64, 32), spacing_px=16,
                               bands=["B4"])
    ties = rel.bands["B4"].ties
    s = ties.col_ref - np.array([c.first_col for c in scene["lab"].band_ccds("B2")])[ties.ccd_ref]
    # window centres 16 px from the CCD ends (a pixel or two further in where the band's window
    # had to be moved inside its CCD)
    assert rel.success and 16 <= s.min() <= 20 and 192 - 20 <= s.max() <= 192 - 16
    reg = registration_error(scene["truth"], rel.model, dem=scene["dem"], bands=["B4"])["B4"]
    assert 0.002 < reg["rms_px"] < 0.03 and reg["max_px"] < 0.1


@pytest.mark.parametrize("kwargs, field", [
    ({"reference_band": "B9"}, "reference_band"),
    ({"bands": ["B2"]}, "bands"),
    ({"bands": ["B7"]}, "bands"),
    ({"rows": (300, 200)}, "rows"),
    ({"rows": (0, 40)}, "rows"),
    ({"window_px": 33}, "window_px"),
    ({"window_px": (64, 8)}, "window_px"),
])
def test_bad_arguments_are_input_errors(scene, kwargs, field):
    with pytest.raises(InputError) as err:
        relative_calibration(scene["calibrated"], scene["images"], scene["dem"], **kwargs)
    assert err.value.field == field


def test_missing_or_missized_rasters_are_input_errors(scene):
    images = dict(scene["images"])
    del images["B3"]
    with pytest.raises(InputError, match="B3"):
        relative_calibration(scene["calibrated"], images, scene["dem"])
    images["B3"] = scene["images"]["B3"][:100]
    with pytest.raises(InputError, match="B3"):
        relative_calibration(scene["calibrated"], images, scene["dem"])


# ----------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def calibration_dir(scene, tmp_path_factory):
    """A calibrated manifest as ``gcpcal calibrate`` writes it (B2 calibrated, relative rasters)."""
    out = tmp_path_factory.mktemp("cal")
    write_manifest(scene["calibrated"], out / "manifest.json", rasters={b: r["path"] for b, r in scene["rasters"].items()})
    return out


def test_relative_command_writes_a_calibrated_manifest(scene, calibration_dir, tmp_path, capsys):
    out = tmp_path / "rel"
    rc = main(["-q", "relative", str(FIXTURE / "manifest.json"), "--calibration", str(calibration_dir),
               "--dem", str(FIXTURE / "reference" / "dem.tif"), "--out", str(out), "--window", "64x32", "--spacing", "16",
               "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["success"] and summary["reference_band"] == "B2"
    assert sorted(p.name for p in out.iterdir() if p.name != ".gcpcal-outputs.json") == ["manifest.json", "relative.json", "relative.summary.json"]
    opened = open_scene(out / "manifest.json")
    model = opened.model
    assert opened.rasters and all(Path(r["path"]).exists() for r in opened.rasters.values())
    reg = registration_error(scene["truth"], model, dem=scene["dem"])
    assert all(0.002 < reg[b]["rms_px"] < 0.05 for b in OTHERS)
    doc = json.loads((out / "relative.json").read_text())
    for band in OTHERS:
        per_ccd = doc["bands"][band]["per_ccd"]
        assert len(per_ccd) == 4 and all(c["before"]["rms_px"] > 2.0 and c["after"]["rms_px"] < 0.05 for c in per_ccd)
        assert summary["bands"][band]["tie_rms_px"]["after"] < 0.05


def test_relative_command_with_the_band_parallax(scene, calibration_dir, tmp_path, capsys):
    """--gcps turns the parallax path on: the summary names the ties and the knots; --no-parallax keeps it off."""
    from gcpmatch.gcp_csv import write_gcps_csv

    csv = tmp_path / "b2.csv"
    write_gcps_csv(scene["gcps"], csv)
    common = ["relative", str(FIXTURE / "manifest.json"), "--calibration", str(calibration_dir),
              "--dem", str(FIXTURE / "reference" / "dem.tif"), "--spacing", "16"]
    rc = main(["-q", *common, "--out", str(tmp_path / "joint"), "--gcps", str(csv), "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    p = summary["parallax"]
    assert p["used"] and 0.95 * len(scene["gcps"]) <= p["gcps"] <= len(scene["gcps"]) and p["ties"] > 1000
    assert p["selected"]["kind"] in ("static", "drift", "spline") and p["rounds"] >= 1
    model = open_model(tmp_path / "joint" / "manifest.json")
    doc = json.loads((tmp_path / "joint" / "relative.json").read_text())
    assert doc["parallax"]["ties"] == p["ties"] and len(doc["parallax"]["candidates"]) >= 2
    spline = [c for c in doc["parallax"]["candidates"] if c["kind"] == "spline"]
    assert spline and spline[0]["smoothing"]["criterion"] == "blocked-cv" and spline[0]["smoothing"]["edf"] > 3
    if p["selected"]["kind"] != "static":
        assert model.attitude_correction is not None and model.attitude_correction.n_terms == p["selected"]["n_terms"]
    reg = registration_error(scene["truth"], model, dem=scene["dem"])
    assert all(0.002 < reg[b]["rms_px"] < 0.05 for b in OTHERS)
    # without GCPs (no calibration.json beside this manifest) and with --no-parallax it is off, and says why
    rc = main(["-q", *common, "--out", str(tmp_path / "plain"), "--json"])
    assert rc == 0 and "no GCP table" in json.loads(capsys.readouterr().out)["parallax"]["reason"]
    rc = main(["-q", *common, "--out", str(tmp_path / "off"), "--gcps", str(csv), "--no-parallax", "--json"])
    off = json.loads(capsys.readouterr().out)["parallax"]
    assert rc == 0 and not off["used"] and off["reason"] == "--no-parallax"


def _edited(calibration_dir, tmp_path, edit):
    doc = json.loads((calibration_dir / "manifest.json").read_text())
    edit(doc)
    path = tmp_path / "other.json"
    # raster paths stay valid: they are relative to the calibration folder
    for r in doc["image"]["rasters"].values():
        r["path"] = str((calibration_dir / r["path"]).resolve())
    path.write_text(json.dumps(doc))
    return path


def _set_rows(doc):
    doc["image"]["n_rows"] = 500


def _drop_detector(doc):
    for ccds in doc["interior"]["bands"].values():
        ccds[-1]["n_detectors"] -= 1


def _set_epoch(doc):
    doc["epoch_utc"] = "2023-06-16T03:00:00.000000000Z"


@pytest.mark.parametrize("edit, expect", [(_set_rows, "500 lines"), (_drop_detector, "CCD layout"), (_set_epoch, "epoch")])
def test_a_calibration_of_another_scene_is_a_one_line_error(calibration_dir, tmp_path, capsys, edit, expect):
    cal = _edited(calibration_dir, tmp_path, edit)
    out = tmp_path / "out"
    rc = main(["relative", str(FIXTURE / "manifest.json"), "--calibration", str(cal),
               "--dem", str(FIXTURE / "reference" / "dem.tif"), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1
    assert expect in err and "other.json" in err and err.count("\n") == 1
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("case", ["corrupt", "missing", "csv", "band", "rows", "window"])
def test_bad_command_input_is_a_one_line_error(calibration_dir, tmp_path, capsys, case):
    cal, extra = str(calibration_dir), []
    if case == "corrupt":
        bad = tmp_path / "manifest.json"
        bad.write_text('{"format_version": 1, "sensor": "pushbroom", ')
        cal = str(bad)
    elif case == "missing":
        cal = str(tmp_path / "nowhere")
    elif case == "csv":
        bad = tmp_path / "b2.csv"
        bad.write_text("id,row,col,lon,lat,h\n")
        cal = str(bad)
    elif case == "band":
        extra = ["--reference-band", "B9"]
    elif case == "rows":
        extra = ["--rows", "10-20"]
    else:
        extra = ["--window", "64x31"]
    rc = main(["relative", str(FIXTURE / "manifest.json"), "--calibration", cal,
               "--dem", str(FIXTURE / "reference" / "dem.tif"), "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err
    assert rc == (2 if case == "window" else 1), err  # a malformed option is a usage error
    assert err.startswith("gcpcal: error:") and err.count("\n") == 1
    assert {"corrupt": "manifest.json", "missing": "nowhere", "csv": "b2.csv", "band": "B9", "rows": "--rows",
            "window": "--window"}[case] in err


def test_a_partial_reference_calibration_ends_relative_partial_and_names_the_array(scene, tmp_path, capsys):
    """The bands are registered (ties) but the model the stage writes is not whole: one CCD of the
    reference band had no GCP (``gcpcal calibrate`` ended partial). ``gcpcal relative`` says so
    and ends with exit 4 (docs/cli.md), not 0; with a whole calibration it ends 0 (tests above)."""
    from gcpmatch.gcp_csv import write_gcps_csv

    gcps = scene["gcps"]
    names = np.array([look.name for look in scene["lab"].band_ccds("B2")])
    index = np.asarray(gcps.ccd).astype(int)
    keep = index != 3
    csv = tmp_path / "b2_three_ccds.csv"
    write_gcps_csv(GcpTable.from_arrays(gcps.row[keep], gcps.col[keep], gcps.lon[keep], gcps.lat[keep], gcps.h[keep],
                                        band="B2", ccd=names[index[keep]], sigma_px=0.05), csv)
    cal = tmp_path / "cal"
    rc = main(["-q", "calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(csv), "--out", str(cal), "--no-report"])
    assert rc == 4  # the reference calibration itself is partial
    capsys.readouterr()
    out = tmp_path / "rel"
    rc = main(["relative", str(FIXTURE / "manifest.json"), "--calibration", str(cal), "--dem",
               str(FIXTURE / "reference" / "dem.tif"), "--out", str(out), "--window", "64x32", "--spacing", "16"])
    err = capsys.readouterr().err
    assert rc == 4, err
    assert "partial" in err and "cam2_ccd2" in err and "Traceback" not in err
    summary = json.loads((out / "relative.summary.json").read_text())
    assert summary["success"] and summary["calibration_status"] == "partial"
    assert open_model(out / "manifest.json").calibration.status == "partial"
