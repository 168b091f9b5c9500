"""Issue 12 items 1 and 7: the coverage gate of a calibration and its a-posteriori variance factor.

Bad-input and fault cases of the gate (half-DEM scene, CCD without check points, CCD with too
little spread, failed solve); the lead assembles them into tests/test_bad_inputs.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calibrate.cli import main
from calibrate.config import CalibrationOptions
from calibrate.coverage import calibration_coverage, calibration_status

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"


def _crop_dem_west(dst: Path) -> Path:
    """The fixture DEM cropped to its western half (tags kept: the vertical datum)."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(FIXTURE / "reference" / "dem.tif") as src:
        window = Window(0, 0, src.width // 2, src.height)
        profile = src.profile.copy()
        profile.update(width=src.width // 2, transform=src.window_transform(window))
        with rasterio.open(dst, "w", **profile) as out:
            out.write(src.read(window=window))
            out.update_tags(**src.tags())
    return dst


def _run(capsys, args):
    code = main(args)
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out, err


@pytest.fixture(scope="module")
def half_dem_gcps(tmp_path_factory):
    """GCPs of the fixture matched against the DOM and a DEM of the western half only."""
    folder = tmp_path_factory.mktemp("half_dem")
    dem = _crop_dem_west(folder / "dem_west.tif")
    code = main(["match", str(FIXTURE / "manifest.json"), "--dom", str(FIXTURE / "reference" / "dom.tif"),
                 "--dem", str(dem), "--out", str(folder / "gcps.csv")])
    return code, folder


@pytest.fixture(scope="module")
def full_gcps(tmp_path_factory):
    folder = tmp_path_factory.mktemp("full_dem")
    code = main(["match", str(FIXTURE / "manifest.json"), "--dom", str(FIXTURE / "reference" / "dom.tif"),
                 "--dem", str(FIXTURE / "reference" / "dem.tif"), "--out", str(folder / "gcps.csv")])
    assert code == 0
    return folder / "gcps.csv"


def test_half_dem_match_names_the_dem(half_dem_gcps):
    code, folder = half_dem_gcps
    assert code == 0
    summary = json.loads((folder / "gcps.summary.json").read_text())
    per_ccd = {c["ccd"]: c for c in summary["per_ccd"]}
    for name in ("cam2_ccd1", "cam2_ccd2"):
        assert per_ccd[name]["gcps"] == 0
        assert per_ccd[name]["dem_coverage"] < 0.5 and per_ccd[name]["dom_coverage"] > 0.9
        assert per_ccd[name]["cause"].startswith("DEM covers") and "dem_west.tif" in per_ccd[name]["cause"]
    for name in ("cam1_ccd1", "cam1_ccd2"):
        assert per_ccd[name]["dem_coverage"] > 0.5
        assert per_ccd[name]["cause"] is None
    assert "restricted" in summary["coarse"]["note"]


def _other_dom(dst: Path) -> Path:
    """The fixture DOM at half the resolution with another tone curve (another sensor, date)."""
    import rasterio
    from rasterio.enums import Resampling

    with rasterio.open(FIXTURE / "reference" / "dom.tif") as src:
        data = src.read(1, out_shape=(src.height // 2, src.width // 2), resampling=Resampling.average).astype(float)
        top = float(data.max())
        toned = (np.clip(data / top, 0, 1) ** 0.6 * top * 0.9 + 20).astype(src.dtypes[0])
        profile = src.profile.copy()
        profile.update(width=src.width // 2, height=src.height // 2, transform=src.transform * src.transform.scale(2, 2))
    with rasterio.open(dst, "w", **profile) as out:
        out.write(toned, 1)
    return dst


def test_half_dem_cause_is_the_same_whatever_the_dom(half_dem_gcps, tmp_path, capsys):
    _code, folder = half_dem_gcps
    dom = _other_dom(tmp_path / "dom_other.tif")
    code, stdout, _err = _run(capsys, ["match", str(FIXTURE / "manifest.json"), "--dom", str(dom), "--dem",
                                       str(folder / "dem_west.tif"), "--out", str(tmp_path / "gcps.csv")])
    assert code == 0
    other = json.loads((tmp_path / "gcps.summary.json").read_text())
    first = json.loads((folder / "gcps.summary.json").read_text())
    assert [c["cause"] for c in other["per_ccd"]] == [c["cause"] for c in first["per_ccd"]]
    assert [c["gcps"] > 0 for c in other["per_ccd"]] == [c["gcps"] > 0 for c in first["per_ccd"]]
    for name in ("cam2_ccd1", "cam2_ccd2"):
        assert f"CCD {name}: 0 GCPs; DEM" in stdout
    assert stdout.count("cause: DEM covers") == 2 and "coarse search was restricted" in stdout


def test_dem_outside_the_scene_names_the_dem(tmp_path, capsys):
    """A DEM that covers none of the reference around the scene: one line naming the DEM, exit 3."""
    import rasterio
    from rasterio.transform import Affine

    with rasterio.open(FIXTURE / "reference" / "dem.tif") as src:
        profile, data, tags = src.profile.copy(), src.read(), src.tags()
    profile.update(transform=Affine.translation(200_000.0, 0.0) * profile["transform"])
    far = tmp_path / "dem_far.tif"
    with rasterio.open(far, "w", **profile) as out:
        out.write(data)
        out.update_tags(**tags)
    out_csv = tmp_path / "gcps.csv"
    code, _out, err = _run(capsys, ["match", str(FIXTURE / "manifest.json"), "--dom",
                                    str(FIXTURE / "reference" / "dom.tif"), "--dem", str(far), "--out", str(out_csv)])
    assert code == 1 and err.count("\n") == 1 and "dem_far.tif" in err and "covers 0 %" in err
    assert not out_csv.exists()


def test_half_dem_calibration_is_partial(half_dem_gcps, tmp_path, capsys):
    _code, folder = half_dem_gcps
    out = tmp_path / "cal"
    code, stdout, _err = _run(capsys, ["calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(folder / "gcps.csv"),
                                       "--out", str(out), "--no-report"])
    assert code == 4  # EXIT_PARTIAL
    for name in ("cam2_ccd1", "cam2_ccd2"):
        assert f"B2.{name}: no GCP on this detector array" in stdout
    summary = json.loads((out / "calibrate.summary.json").read_text())
    assert summary["status"] == "partial"
    bad = {c["ccd"] for c in summary["coverage"] if not c["calibrated"]}
    assert bad == {"cam2_ccd1", "cam2_ccd2"}
    assert all(c["check_rmse_px"]["after"] is not None for c in summary["coverage"] if c["verified"])
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["status"]["status"] == "partial" and len(doc["coverage"]) == 4
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["calibration"]["status"] == "partial"
    assert {e["ccd"] for e in manifest["calibration"]["uncalibrated"] if e["ccd"]} == {"cam2_ccd1", "cam2_ccd2"}
    # the bands without GCPs are named too: band-to-band calibration is still to run on them
    assert {e["band"] for e in manifest["calibration"]["uncalibrated"] if not e["ccd"]} == {"B1", "B3", "B4"}


def test_half_dem_report_names_uncalibrated(half_dem_gcps, tmp_path, capsys):
    _code, folder = half_dem_gcps
    out = tmp_path / "cal"
    code, _out, _err = _run(capsys, ["calibrate", str(FIXTURE / "manifest.json"), "--gcps",
                                     str(folder / "gcps.csv"), "--out", str(out), "--json"])
    assert code == 4
    html = (out / "report.html").read_text()
    assert "Coverage per CCD" in html and "B2.cam2_ccd1: no GCP" in html and "partial" in html


def test_full_dem_is_partial_until_relative_then_calibrated(full_gcps, tmp_path, capsys):
    """Absolute calibration of the reference band leaves the other bands to band-to-band
    calibration: partial (exit 4) naming them, then `gcpcal relative` makes it calibrated."""
    code, stdout, _err = _run(capsys, ["calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(full_gcps),
                                       "--out", str(tmp_path / "cal"), "--no-report"])
    assert code == 4, stdout
    summary = json.loads((tmp_path / "cal" / "calibrate.summary.json").read_text())
    assert summary["status"] == "partial"
    assert all(c["calibrated"] and c["verified"] for c in summary["coverage"])  # every B2 CCD
    assert summary["variance_factor"] > 0
    status = json.loads((tmp_path / "cal" / "manifest.json").read_text())["calibration"]
    assert {(e["band"], e["ccd"]) for e in status["uncalibrated"]} == {("B1", ""), ("B3", ""), ("B4", "")}
    code, stdout, err = _run(capsys, ["relative", str(FIXTURE / "manifest.json"), "--calibration",
                                      str(tmp_path / "cal"), "--dem", str(FIXTURE / "reference" / "dem.tif"),
                                      "--out", str(tmp_path / "rel")])
    assert code == 0, stdout + err
    status = json.loads((tmp_path / "rel" / "manifest.json").read_text())["calibration"]
    assert status["status"] == "calibrated" and not status["uncalibrated"] and not status["unverified"]


def _without(table_path, out_path, drop):
    from gcpmatch.gcp_csv import write_gcps_csv
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.gcps import GcpTable

    table = read_gcps(table_path)
    keep = ~drop(table)
    write_gcps_csv(GcpTable.from_arrays(**{k: np.asarray(v)[keep] for k, v in table.as_dict().items()}), out_path)
    return out_path


def test_ccd_without_check_points_is_unverified(full_gcps, tmp_path, capsys):
    gcps = _without(full_gcps, tmp_path / "g.csv", lambda t: (t.kind == "check") & (t.ccd == "cam1_ccd2"))
    code, stdout, _err = _run(capsys, ["calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(gcps),
                                       "--out", str(tmp_path / "cal"), "--no-report"])
    assert code == 4
    assert "B2.cam1_ccd2: no check point" in stdout
    summary = json.loads((tmp_path / "cal" / "calibrate.summary.json").read_text())
    row = {c["ccd"]: c for c in summary["coverage"]}["cam1_ccd2"]
    assert row["calibrated"] and not row["verified"] and row["check_rmse_px"]["after"] is None


def test_ccd_with_too_little_spread_is_uncalibrated(full_gcps, tmp_path, capsys):
    from gcpmatch.gcp_files import read_gcps
    from sensor_models.readers import open_model

    model = open_model(FIXTURE / "manifest.json")
    first = {a.name: a.first_col for a in model.detector_arrays("B2")}
    table = read_gcps(full_gcps)
    offset = table.col - np.array([first.get(str(c), 0) for c in table.ccd])
    gcps = _without(full_gcps, tmp_path / "g.csv",
                    lambda t: (t.kind == "gcp") & (t.ccd == "cam1_ccd1") & (offset > 60))
    code, stdout, _err = _run(capsys, ["calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(gcps),
                                       "--out", str(tmp_path / "cal"), "--no-report"])
    assert code == 4
    summary = json.loads((tmp_path / "cal" / "calibrate.summary.json").read_text())
    row = {c["ccd"]: c for c in summary["coverage"]}["cam1_ccd1"]
    assert not row["calibrated"] and "needed" in row["reason"] and row["spread_across"] < 0.3
    assert "B2.cam1_ccd1: 6 GCPs < 24 needed" in stdout


def test_ccd_with_narrow_spread_is_uncalibrated(full_gcps):
    """Enough GCPs, all on a narrow strip of the CCD's detectors: the span rule skips it."""
    from calibrate.absolute import calibrate_model
    from calibrate.from_gcps import points_of
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.gcps import GcpTable
    from sensor_models.readers import open_model

    model = open_model(FIXTURE / "manifest.json")
    array = {a.name: a for a in model.detector_arrays("B2")}["cam1_ccd1"]
    table = read_gcps(full_gcps)
    narrow = (table.ccd == "cam1_ccd1") & (table.col - array.first_col > 0.4 * array.n_detectors)
    keep = ~narrow
    table = GcpTable.from_arrays(**{k: np.asarray(v)[keep] for k, v in table.as_dict().items()})
    result = calibrate_model(model, table, options=CalibrationOptions(min_points_factor=1.0))
    fitted = points_of(table.gcps(), model)
    rows = calibration_coverage(model, fitted, points_of(table.checks(), model), success=result.success,
                                skipped=result.skipped, weight=fitted["score"])
    row = {r.ccd: r for r in rows}["cam1_ccd1"]
    assert not row.calibrated and "span" in row.reason and row.spread_across < 0.4
    assert calibration_status(result.success, result.message, rows).status == "partial"


def test_failed_solve_is_failed_status():
    from sensor_models.readers import open_model

    model = open_model(FIXTURE / "manifest.json")
    pts = {"row": np.array([10.0, 500.0]), "col": np.array([10.0, 60.0]), "band": None, "ccd": None}
    rows = calibration_coverage(model, pts, pts, success=False)
    status = calibration_status(False, "rank deficient", rows)
    assert status.status == "failed" and not status.usable
    assert all(not r.calibrated for r in rows) and rows[0].reason.startswith("the calibration failed")


# --------------------------------------------------------------------------- variance factor
def _synthetic_gcps(lab, truth, rng, *, noise_px, sigma_px, n_per_ccd=60):
    """GCPs rendered by ``truth`` on every CCD of the reference band, image noise ``noise_px``."""
    from gcpmatch.gcps import GcpTable

    band = lab.reference_band
    rows, cols, lon, lat, h, ccd = [], [], [], [], [], []
    n_rows = lab.image_shape[0]
    for array in lab.detector_arrays(band):
        r = rng.uniform(0.05, 0.95, n_per_ccd) * n_rows
        c = array.first_col + rng.uniform(0.02, 0.98, n_per_ccd) * array.n_detectors
        height = rng.uniform(0.0, 1500.0, n_per_ccd)
        lo, la, hh = truth.image_to_ground(r, c, height=height, band=band, array=array.name)
        rows.append(r + rng.normal(0.0, noise_px, n_per_ccd))
        cols.append(c + rng.normal(0.0, noise_px, n_per_ccd))
        lon.append(lo)
        lat.append(la)
        h.append(hh)
        ccd += [array.name] * n_per_ccd
    return GcpTable.from_arrays(np.concatenate(rows), np.concatenate(cols), np.concatenate(lon),
                                np.concatenate(lat), np.concatenate(h), sigma_px=sigma_px, band=band,
                                ccd=np.array(ccd), kind="gcp")


def test_variance_factor_and_sigma_coverage_with_noise_twice_sigma():
    """GCP noise 2x the stated sigma_px: variance factor ~4 and the sigmas cover the truth at ~95 %."""
    from calibrate.absolute import calibrate_model
    from sensor_models.readers import open_model

    lab = open_model(FIXTURE / "manifest.json")
    names = list(lab.parameters().names)
    theta = lab.parameters().values.copy()
    ext = [names.index(f"installation.{a}") for a in ("roll", "pitch", "yaw")]
    theta[ext] += np.deg2rad(np.array([60.0, -40.0, 90.0]) / 3600.0)
    truth = lab.with_parameters(theta)
    rng = np.random.default_rng(5)
    factors, inside, total = [], 0, 0
    for _trial in range(30):
        gcps = _synthetic_gcps(lab, truth, rng, noise_px=1.0, sigma_px=0.5)
        result = calibrate_model(lab, gcps, options=CalibrationOptions(scheme="exterior"))
        assert result.success, result.message
        factors.append(result.variance_factor)
        true_values = theta[[names.index(n) for n in result.names]]
        z = np.abs(result.values - true_values) / result.sigma
        inside += int(np.sum(z <= 1.96))
        total += z.size
    assert 3.2 < np.median(factors) < 4.8
    assert 0.88 <= inside / total <= 1.0  # 95 % nominal, 90 trials
    assert result.to_dict(points=False)["variance_factor"] == pytest.approx(result.sigma0**2)


def test_failed_rpc_bias_writes_no_rpc_file(shared_data, tmp_path, capsys, monkeypatch):
    """A failed bias compensation ends 'failed' (exit 3) and leaves no RPC file to be used."""
    import dataclasses

    import calibrate.actions.calibrate as action

    real = action.apply_calibration

    def failing(model, table, **kw):
        result, g = real(model, table, **kw)
        return dataclasses.replace(result, success=False, message="forced failure"), g

    monkeypatch.setattr(action, "apply_calibration", failing)
    gcps = tmp_path / "g.csv"
    gcps.write_text("id,row,col,lon,lat,h,kind\ng1,100.5,100.5,5.1616,44.2296,500,gcp\n"
                    "g2,500.5,900.5,5.1668,44.2279,500,gcp\nc1,300.5,500.5,5.164,44.229,500,check\n")
    out = tmp_path / "cal"
    code, stdout, _err = _run(capsys, ["calibrate", str(shared_data / "pleiades_ventoux" / "right_image_bias.geom"),
                                       "--gcps", str(gcps), "--out", str(out), "--no-report"])
    assert code == 3 and "FAILED" in stdout
    assert not list(out.glob("*_RPC.TXT"))
    summary = json.loads((out / "calibrate.summary.json").read_text())
    assert summary["status"] == "failed" and summary["model"] is None
