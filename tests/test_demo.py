"""The main job end to end on the embedded ``ideal`` fixture (``gcpcal demo --fixture ideal``), and the calibrate command's bad input.

The default demo, on the ``realistic`` fixture, is tested in ``tests/test_demo_realistic.py``.
"""

from __future__ import annotations

import json

import pytest

from calibrate.cli import main


@pytest.fixture(scope="module")
def demo_run(demo_folder):
    out = demo_folder
    return out, json.loads((out / "summary.json").read_text())


def test_demo_calibrates_the_fixture_from_hundreds_of_pixels_to_a_tenth(demo_run):
    out, s = demo_run
    for key in ("gcps", "check_points", "check_rmse_px", "truth_error_px", "seconds"):
        assert key in s
    # the ideal scene: its user DEM is the TRUE DEM, graded as such
    assert (s["fixture"], s["profile"], s["truth_dem"]) == ("hy1c_czi", "ideal", "reference/dem.tif")
    print(f"demo: check RMSE {s['check_rmse_px']['before']:.1f} -> {s['check_rmse_px']['after']:.3f} px, "
          f"truth rms {s['truth_error_px']['rms']:.3f} max {s['truth_error_px']['max']:.3f} px, {s['seconds']:.0f} s")
    assert s["check_rmse_px"]["before"] > 100.0
    assert 0.01 < s["check_rmse_px"]["after"] <= 0.3
    assert 0.005 < s["truth_error_px"]["rms"] <= 0.1
    assert s["truth_error_px"]["max"] < 1.0
    assert s["gcps"] > 500 and s["check_points"] > 100
    assert all(v["success"] for v in s["calibration"].values())
    # the calibrated manifest opens and names the fixture's rasters
    from sensor_models.readers import open_scene

    rasters = open_scene(out / "relative" / "manifest.json").rasters
    assert set(rasters) == {"B1", "B2", "B3", "B4"}
    assert all(__import__("os").path.exists(r["path"]) for r in rasters.values())


def test_calibrate_command_on_demo_gcps(demo_run, tmp_path):
    out, _ = demo_run
    from pathlib import Path

    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi" / "manifest.json"
    # only the reference band's points: the others need their own interior
    from gcpmatch.gcp_csv import write_gcps_csv
    from gcpmatch.gcp_files import read_gcps

    table = read_gcps(out / "gcps.csv")
    write_gcps_csv(table.select(table.band == "B2"), tmp_path / "b2.csv")
    rc = main(["-q", "calibrate", str(fixture), "--gcps", str(tmp_path / "b2.csv"), "--out", str(tmp_path / "cal"),
               "--no-report"])
    assert rc == 4  # partial: B1, B3 and B4 are left to `gcpcal relative`
    doc = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert doc["success"] and doc["check_accuracy"]["after"]["absolute"]["rmse_px"] < 0.3
    assert (tmp_path / "cal" / "manifest.json").exists()


@pytest.mark.parametrize(
    "text, expect",
    [
        ("id,row,col,lon,lat\ng1,1,2,5.5,44.5\n", "h"),
        ("id,row,col,lon,lat,h\ng1,1,2,5.5,nan,100\n", "lat"),
        ("id,row,col,lon,lat,h\ng1,1,2,5.5,44.5,100\ng1,3,4,5.5,44.5,100\n", "id"),
        ("id,row,col,lon,lat,h\ng1,100000,2,5.5,44.5,100\n", "row"),
    ],
)
def test_calibrate_bad_gcp_files_fail_in_one_line_without_output(tmp_path, capsys, text, expect):
    from pathlib import Path

    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi" / "manifest.json"
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    rc = main(["calibrate", str(fixture), "--gcps", str(bad), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 1
    assert "bad.csv" in err and expect in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_too_few_points_is_a_reported_failure_not_nonsense(tmp_path, capsys):
    from pathlib import Path

    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi" / "manifest.json"
    few = tmp_path / "few.csv"
    few.write_text("id,row,col,lon,lat,h\ng1,100.5,100.5,5.5,44.5,300\ng2,200.5,300.5,5.51,44.52,320\n")
    rc = main(["calibrate", str(fixture), "--gcps", str(few), "--out", str(tmp_path / "out"), "--no-report"])
    captured = capsys.readouterr()
    assert rc != 0
    assert "Traceback" not in captured.err


def test_forty_percent_gross_outliers_barely_move_the_calibration(demo_run):
    """Seed-like robustness: 40 % of the GCPs moved by 5-200 px; truth error within 1.2x of clean."""
    import numpy as np
    from pathlib import Path

    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions
    from calibrate.from_gcps import points_of
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.gcps import GcpTable
    from sensor_models.readers import open_model
    from sensor_models.simulate.truth import truth_error
    from sensor_models.terrain.dem import Dem

    out, _ = demo_run
    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
    lab, truth = open_model(fixture / "manifest.json"), open_model(fixture / "truth_manifest.json")
    dem = Dem.open(fixture / "reference" / "dem.tif")
    table = read_gcps(out / "gcps.csv")
    g = points_of(table.select((table.band == "B2") & (table.kind == "gcp")))
    rng = np.random.default_rng(40)
    bad = rng.random(g["row"].size) < 0.4
    size = rng.uniform(5.0, 200.0, bad.sum())
    angle = rng.uniform(0.0, 2.0 * np.pi, bad.sum())
    row, col = g["row"].copy(), g["col"].copy()
    row[bad] += size * np.sin(angle)
    col[bad] += size * np.cos(angle)
    errors = {}
    for name, (r, c) in {"clean": (g["row"], g["col"]), "outliers": (row, col)}.items():
        gcps = GcpTable.from_arrays(r, c, g["lon"], g["lat"], g["h"], band="B2", ccd=g["ccd"])
        res = calibrate_model(lab, gcps, options=CalibrationOptions(scheme="exterior-interior"))
        assert res.success
        errors[name] = truth_error(truth, res.model, dem=dem, step_px=16, bands=["B2"])["rms_px"]
    print(f"40 % outliers: truth rms {errors['outliers']:.4f} px vs clean {errors['clean']:.4f} px")
    assert errors["clean"] < 0.1
    assert errors["outliers"] <= 1.2 * errors["clean"]
