"""Batch validation on Dask: a simulated validation series of one sensor, with known truth.

A small sensor (4 CCDs x 128 detectors, one band, 256 lines) is calibrated on its calibration
scene; four further acquisitions (other sites, dates, attitude biases; one cloudy, one with a
truncated raster) plus a scene whose DOM is missing and a scene of another sensor are validated
on a two-process LocalCluster. The truth: each scene's attitude-bias difference to the
calibration scene predicts the mean check-point residual (``series.json``), which the
calibrated model must show, while the LAB model stays about 260 px off.
"""

from __future__ import annotations

import csv
import json
import re
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.actions.validate import run_validation
from calibrate.batch import COLUMNS, Site, read_sites, validate_sites
from calibrate.cli import main
from sensor_models.errors import InputError
from sensor_models.simulate.config import SimConfig
from sensor_models.simulate.series import plan_series, simulate_series

ROOT = Path(__file__).resolve().parents[1]
FOREIGN = ROOT / "fixtures" / "hy1c_czi"  # the embedded scene: another sensor (4 bands, 192 detectors)


def small_sensor() -> SimConfig:
    cfg = SimConfig()
    cam = replace(cfg.camera, detectors_per_ccd=128, overlap_detectors=8, bands=("B2",), reference_band="B2",
                  band_offsets_px=(0.0,))
    rad = replace(cfg.radiometry, band_gain=(1.0,), band_offset_dn=(40.0,), band_gamma=(1.0,))
    return replace(cfg, scene=replace(cfg.scene, n_rows=256), camera=cam, radiometry=rad).validate()


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    """The series, the calibration of its sensor, and a sites file with three bad entries."""
    from calibrate.actions.calibrate import calibrate_scene
    from calibrate.actions.match import match_scene
    from gcpmatch.options import MatchOptions

    root = tmp_path_factory.mktemp("series")
    manifests = simulate_series(root, 4, base_config=small_sensor(), seed=5, calibration_scene=True,
                                cloud_fractions=(0.0, 0.0, 0.4, 0.0))
    cal = root / "calibration"
    match_scene(cal / "manifest.json", dom_path=cal / "reference" / "dom.tif", dem_path=cal / "reference" / "dem.tif",
                out_path=root / "cal_gcps.csv", options=MatchOptions(spacing_px=16))
    summary = calibrate_scene(cal / "manifest.json", root / "cal_gcps.csv", root / "calibrated", report=False)
    assert summary["success"] and summary["check_rmse_px"]["after"] < 0.2
    # scene 4: a truncated raster
    raster = manifests[3].parent / "B2.tif"
    raster.write_bytes(raster.read_bytes()[: raster.stat().st_size // 2])
    text = (root / "sites.yaml").read_text()
    text += ("- name: no_dom\n  scene: scenes/" + manifests[0].parent.name + "/manifest.json\n"
             "  dom: references/nowhere/dom.tif\n  dem: references/zhengzhou/dem.tif\n"
             f"- name: other_sensor\n  scene: {FOREIGN / 'manifest.json'}\n  dom: {FOREIGN / 'reference/dom.tif'}\n"
             f"  dem: {FOREIGN / 'reference/dem.tif'}\n")
    (root / "all_sites.yaml").write_text(text)
    truth = json.loads((root / "series.json").read_text())["scenes"]
    return {"root": root, "manifests": manifests, "calibration": root / "calibrated", "truth": truth}


def test_series_is_one_sensor_with_varied_acquisitions():
    from sensor_models.simulate.scene import build_models

    plan = plan_series(5, base_config=small_sensor(), seed=3)
    assert [p.site for p in plan] == ["zhengzhou", "huairou", "dalian", "hohhot", "provence"]
    assert plan == plan_series(5, base_config=small_sensor(), seed=3)  # deterministic
    a, b = build_models(plan[0].config), build_models(plan[1].config)
    assert a.true_camera == b.true_camera  # same camera, installation and camera-2 rotation
    assert a.truth["installation_rad"] == b.truth["installation_rad"]
    assert a.truth["camera2_rotation_arcsec"] == b.truth["camera2_rotation_arcsec"]
    assert plan[0].config.scene.epoch_utc < plan[1].config.scene.epoch_utc
    bias = np.array([p.config.errors.attitude_bias_arcsec for p in plan])
    assert np.all(np.ptp(bias, axis=0) > 1.0)  # per-scene attitude bias
    offsets = np.array([p.expected_offset_px(small_sensor())["planar"] for p in plan])
    assert 0.3 < offsets.mean() < 12.0  # a few pixels, as in seed 003 table 5
    with pytest.raises(InputError, match="cloud_fractions"):
        plan_series(2, cloud_fractions=(1.5,))


def test_validation_table_against_the_truth(series, tmp_path):
    sites = read_sites(series["root"] / "all_sites.yaml")
    assert [s.name for s in sites][-2:] == ["no_dom", "other_sensor"]
    calls = []
    t0 = time.perf_counter()
    rows, summary = run_validation(sites, series["calibration"], tmp_path / "val", workers=2,
                                   progress=lambda done, total, row: calls.append((done, total, row["name"])))
    print(f"validated {len(rows)} scenes in {time.perf_counter() - t0:.1f} s")
    assert [c[0] for c in calls] == list(range(1, 7)) and {c[1] for c in calls} == {6}
    assert sorted(c[2] for c in calls) == sorted(s.name for s in sites)
    assert [r["name"] for r in rows] == [s.name for s in sites]  # the sites' order, not completion order
    by = {r["name"]: r for r in rows}
    names = [m.parent.name for m in series["manifests"]]

    # failures: each a row with its reason, none stops the others
    corrupt = by[names[3]]
    assert corrupt["status"] == "failed" and "cannot read the scene raster" in corrupt["reason"]
    assert corrupt["date"] == series["truth"][3]["epoch_utc"][:10]  # what was learnt before the failure stays
    assert by["no_dom"]["status"] == "failed" and "no such DOM file" in by["no_dom"]["reason"]
    assert by["other_sensor"]["status"] == "failed"
    assert "calibration does not fit this sensor" in by["other_sensor"]["reason"]
    for r in (corrupt, by["no_dom"], by["other_sensor"]):
        assert r["rmse_planar_px"] is None and "\n" not in r["reason"]

    # the good scenes: calibrated residual = the attitude-bias difference, LAB ~260 px off
    for name, truth in zip(names[:3], series["truth"][:3]):
        r, exp = by[name], truth["expected_offset_px"]
        assert r["status"] == "ok", r["reason"]
        assert r["points"] >= 8
        assert abs(r["mean_along_px"] - exp["row"]) < 0.35, (name, r["mean_along_px"], exp)
        assert abs(r["mean_across_px"] - exp["col"]) < 0.35, (name, r["mean_across_px"], exp)
        assert exp["planar"] - 0.35 < r["rmse_planar_px"] < exp["planar"] + 0.5
        assert r["rmse_planar_px"] == pytest.approx(math.hypot(r["rmse_along_px"], r["rmse_across_px"]))
        assert 20.0 < r["rmse_planar_m"] / r["rmse_planar_px"] < 40.0  # 30 m pixels
        assert 200.0 < r["lab_rmse_planar_px"] < 330.0
        assert r["date"] == truth["epoch_utc"][:10]
        assert abs(r["center_lon_deg"] - truth["center_lon_deg"]) < 0.15  # the true look is ~0.1 deg off nadir
        # a calibrated model is a few pixels off: the coarse SIFT stage is skipped, and says so
        assert r["coarse"].startswith("coarse stage skipped: model within "), r["coarse"]
        assert abs(float(r["coarse"].split("within ")[1].split(" px")[0]) - exp["planar"]) < 1.0
    cloudy, clear = by[names[2]], by[names[0]]
    assert cloudy["cloud_fraction"] > 0.1 > clear["cloud_fraction"]
    assert cloudy["points"] < clear["points"]

    # summary: mean over the scenes that succeeded (seed 003 table 5's mean row)
    assert summary["ok"] == 3 and summary["failed"] == 3 and summary["workers"] == 2
    assert summary["coarse_skipped"] == 3 and set(summary["coarse"]) == set(names[:3])
    mean = summary["mean"]["rmse_planar_px"]
    assert math.isfinite(mean)
    assert mean == pytest.approx(np.mean([by[n]["rmse_planar_px"] for n in names[:3]]))
    assert 0.3 < mean < 8.0

    # outputs
    out = tmp_path / "val"
    with open(out / "validation.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0]) == list(COLUMNS) and len(table) == 6
    assert table[3]["status"] == "failed" and table[3]["rmse_planar_px"] == ""
    doc = json.loads((out / "validation.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON {c}"))
    assert doc["kind"] == "gcpcal.validate" and len(doc["rows"]) == 6 and doc["mean"]["rmse_planar_px"] == mean
    page = (out / "validation.html").read_text()
    assert "mean of 3 scene(s)" in page and page.count("failed:") == 3 and "validation_planar.png" in page
    assert (out / "validation_planar.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.stem for p in (out / "points").glob("*.csv")) == sorted(names[:3])
    assert not list(out.glob(".*gcpcal-stage*"))


def test_validation_with_and_without_the_coarse_skip_agrees(series):
    """One clear scene validated with SIFT forced and with the skip: the rows say which ran,
    and the calibrated model's check-point figures agree within 0.05 px (the fine stage sees
    the same offsets either way)."""
    from calibrate.batch import calibration_manifest, validate_scene

    site = read_sites(series["root"] / "all_sites.yaml")[0]
    calibrated = calibration_manifest(series["calibration"])
    sift = validate_scene(site, calibrated, threads=1, coarse_skip=False)
    skip = validate_scene(site, calibrated, threads=1, coarse_skip=True)
    assert sift["status"] == skip["status"] == "ok", (sift["reason"], skip["reason"])
    assert sift["coarse"].startswith("coarse stage: SIFT, ") and int(sift["coarse"].split(", ")[1].split()[0]) > 6
    assert skip["coarse"].startswith("coarse stage skipped: model within ")
    for key in ("mean_along_px", "mean_across_px", "rmse_planar_px"):
        assert abs(sift[key] - skip[key]) < 0.05, key
    assert abs(sift["points"] - skip["points"]) <= 0.1 * sift["points"]


def test_cli_validate_reports_failures(series, tmp_path, capsys, monkeypatch):
    """Every scene failed: exit 3, the rows say why; off a terminal the scenes are counted in tenths."""
    import calibrate.cli._progress as progress_module

    monkeypatch.setattr(progress_module, "PLAIN_AFTER_S", 0.0)
    sites = tmp_path / "sites.csv"
    row = f"{FOREIGN / 'manifest.json'},{FOREIGN / 'reference/dom.tif'},{FOREIGN / 'reference/dem.tif'}"
    sites.write_text(f"name,scene,dom,dem,site\nforeign,{row},nowhere\nforeign2,{row},elsewhere\n")
    code = main(["validate", str(sites), "--calibration", str(series["calibration"]), "--out", str(tmp_path / "o"),
                 "--workers", "1"])
    out, err = capsys.readouterr()
    assert code == 3, err
    counted = re.findall(r"^gcpcal validate (\d+) % \((\d+)/2\)", err, flags=re.M)
    assert counted == [("50", "1"), ("100", "2")], err
    doc = json.loads((tmp_path / "o" / "validation.json").read_text())
    assert doc["failed"] == 2 and [r["site"] for r in doc["rows"]] == ["nowhere", "elsewhere"]
    assert all("does not fit this sensor" in r["reason"] for r in doc["rows"])
    assert (tmp_path / "o" / "validation.html").is_file()


def test_cli_validate_one_good_one_failed_scene_is_partial(series, tmp_path, capsys):
    """A good scene and one of another sensor: exit 4, the reason on stderr even under -q, both rows."""
    good = read_sites(series["root"] / "sites.yaml")[0]
    sites = tmp_path / "sites.csv"
    sites.write_text("name,scene,dom,dem,site\n"
                     f"good,{good.scene},{good.dom},{good.dem},{good.site}\n"
                     f"foreign,{FOREIGN / 'manifest.json'},{FOREIGN / 'reference/dom.tif'},"
                     f"{FOREIGN / 'reference/dem.tif'},nowhere\n")
    code = main(["-q", "validate", str(sites), "--calibration", str(series["calibration"]), "--out",
                 str(tmp_path / "o"), "--workers", "1", "--json"])
    out, err = capsys.readouterr()
    assert code == 4, err
    doc = json.loads(out)
    assert doc["failed"] == 1 and len(doc["rows"]) == 2
    assert err.strip().splitlines()[-1].startswith("gcpcal: partial:")
    assert (tmp_path / "o" / "validation.html").is_file()


def test_unreachable_scheduler_is_a_one_line_error(series, tmp_path, capsys):
    sites = read_sites(series["root"] / "sites.yaml")
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="cannot reach the Dask scheduler") as info:
        validate_sites(sites, series["calibration"], scheduler="tcp://127.0.0.1:1", timeout_s=1.0)
    assert time.perf_counter() - t0 < 8.0
    assert "\n" not in str(info.value) and "tcp://127.0.0.1:1" in str(info.value)
    code = main(["validate", str(series["root"] / "sites.csv"), "--calibration", str(series["calibration"]),
                 "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:1", "--timeout", "1"])
    _, err = capsys.readouterr()
    assert code == 1 and err.strip().splitlines()[-1].startswith("gcpcal: error: tcp://127.0.0.1:1")


def test_scheduler_without_workers_is_an_error(series, tmp_path):
    import logging

    from distributed import LocalCluster

    sites = read_sites(series["root"] / "sites.yaml")
    with LocalCluster(n_workers=0, processes=False, dashboard_address=":0", silence_logs=logging.ERROR) as cluster:
        with pytest.raises(InputError, match="has no worker"):
            validate_sites(sites, series["calibration"], scheduler=cluster.scheduler_address, timeout_s=0.5)


def test_calibration_path_errors(series, tmp_path):
    sites = read_sites(series["root"] / "sites.yaml")
    with pytest.raises(InputError, match="holds no manifest.json"):
        validate_sites(sites, tmp_path)
    with pytest.raises(InputError, match="no such calibration file"):
        validate_sites(sites, tmp_path / "nothing.json")


# --------------------------------------------------------------------------- sites files
def test_sites_yaml_and_csv_agree_and_resolve_relative_paths(series):
    root = series["root"]
    from_yaml, from_csv = read_sites(root / "sites.yaml"), read_sites(root / "sites.csv")
    assert from_yaml == from_csv and len(from_yaml) == 4
    s = from_yaml[0]
    assert isinstance(s, Site) and s.scene == root.resolve() / "scenes" / s.name / "manifest.json"
    assert s.scene.is_file() and s.dom.is_file() and s.dem.is_file() and s.site == "zhengzhou"
    assert s.dem_datum is None and s.geoid is None and s.band is None


@pytest.mark.parametrize("text, message", [
    ("- {name: a, scene: s.json, dom: d.tif}\n", r"sites\.yaml: field 'dem': entry 1 \('a'\): required field missing"),
    ("- {name: a, scene: s.json, dom: d.tif, dem: ''}\n", r"field 'dem': entry 1 \('a'\)"),
    ("- {name: a, scene: s.json, dom: d.tif, dem: e.tif, colour: red}\n", r"field 'colour': entry 1 \('a'\): unknown field"),
    ("- {name: a, scene: s.json, dom: d.tif, dem: e.tif}\n- {name: a, scene: t.json, dom: d.tif, dem: e.tif}\n",
     r"field 'name': entry 2 \('a'\): name 'a' already used by entry 1"),
    ("- {name: a, scene: s.json, dom: d.tif, dem: e.tif, dem_datum: navd88}\n", r"field 'dem_datum'.*ellipsoid or egm96"),
    ("- {name: a, scene: [1, 2], dom: d.tif, dem: e.tif}\n", r"field 'scene': entry 1 \('a'\): must be a string"),
    ("name: a\n", r"must be a YAML list"),
    ("- just a string\n", r"entry 1: must be a mapping"),
    ("- {name: a, scene: s.json\n", r"is not valid YAML \(line"),
    ("", r"lists no scene"),
])
def test_sites_yaml_errors(tmp_path, text, message):
    path = tmp_path / "sites.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        read_sites(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("text, message", [
    ("name,scene,dom\na,s.json,d.tif\n", r"field 'dem': the header lacks column\(s\) dem"),
    ("name,scene,dom,dem,colour\na,s.json,d.tif,e.tif,red\n", r"field 'colour': unknown column"),
    ("name,scene,dom,dem\na,s.json,,e.tif\n", r"field 'dom': entry 1 \(line 2, 'a'\): required field missing"),
    ("name,scene,dom,dem\na,s.json,d.tif,e.tif,extra\n", r"entry 1 \(line 2\): more cells"),
])
def test_sites_csv_errors(tmp_path, text, message):
    path = tmp_path / "sites.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        read_sites(path)


def test_sites_file_kind_and_presence(tmp_path):
    with pytest.raises(InputError, match=r"missing\.yaml: cannot read: No such file"):
        read_sites(tmp_path / "missing.yaml")
    (tmp_path / "sites.txt").write_text("x")
    with pytest.raises(InputError, match=r"must be \.yaml, \.yml or \.csv"):
        read_sites(tmp_path / "sites.txt")
    path = tmp_path / "sites.csv"
    path.write_text("name,scene,dom,dem,dem_datum,geoid\na,sub/s.json,d.tif,e.tif,,\n\n"
                    "b,/abs/s.json,d.tif,e.tif,egm96,g.gtx\n")
    a, b = read_sites(path)
    assert a.scene == tmp_path.resolve() / "sub" / "s.json" and a.dem_datum is None and a.geoid is None
    assert b.scene == Path("/abs/s.json") and b.dem_datum == "egm96" and b.geoid == tmp_path.resolve() / "g.gtx"
