"""Smoke test of ``bench/bench_fullsize.py`` at a tiny scale (the whole chain, as a user runs it).

The benchmark itself runs the seed-003 scene at full size (not in CI); here ``--scale 0.0625``
(4 CCDs of 341 detectors, 512 lines, realistic profile, two bands) checks that every stage runs
as a child process, that the measured figures are there and plausible, and that calibration
brings the LAB model's hundreds of pixels down to a fraction of a pixel against the TRUE model.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_fullsize", ROOT / "bench" / "bench_fullsize.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_scaled_config_shrinks_detectors_and_lines():
    bench = _bench()
    full = bench.scaled_config(1.0)
    assert full["camera"]["detectors_per_ccd"] == 5450 and full["scene"]["n_rows"] == 8192
    quarter = bench.scaled_config(0.25, ["B2", "B4"])
    assert quarter["camera"]["detectors_per_ccd"] == 1362 and quarter["scene"]["n_rows"] == 2048
    assert quarter["camera"]["bands"] == ["B2", "B4"] and quarter["camera"]["band_offsets_px"] == [-2.0, 6.0]
    assert len(quarter["radiometry"]["band_gain"]) == 2
    for bad in (0.0, 1.5):
        with pytest.raises(SystemExit):
            bench.scaled_config(bad)
    with pytest.raises(SystemExit, match="reference band"):
        bench.scaled_config(0.5, ["B1", "B3"])


@pytest.mark.slow
def test_tiny_scale_runs_every_stage_and_measures(tmp_path):
    if not (Path(sys.executable).parent / "gcpcal").exists():
        pytest.skip("the gcpcal console script is not installed beside this interpreter")
    bench = _bench()
    out = tmp_path / "fullsize_tiny.json"
    assert bench.main(["--scale", "0.0625", "--cache", str(tmp_path / "cache"), "--bands", "B2,B4",
                       "--truth-step", "32", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["scene"]["image"]["n_cols"] == 4 * 341 and res["scene"]["image"]["n_rows"] == 512
    for name in ("simulate", "match", "calibrate_auto", "calibrate_static", "relative_auto", "relative_static"):
        rec = res["stages"][name]
        assert rec["rc"] in (0, 4), (name, rec["stderr_tail"])  # 4: the other band awaits `relative`
        assert 0.0 < rec["cpu_s"] and 0.0 < rec["wall_s"] < 600.0
        assert 50.0 < rec["peak_rss_mib"] < 8000.0
    assert res["accuracy"]["match"]["gcps"] > 100
    truth = res["truth_error"]
    assert truth["lab"]["reference_band"]["rms_px"] > 50.0  # the LAB model is hundreds of px off
    for name in ("cal_static", "cal_auto"):
        assert 0.005 < truth[name]["reference_band"]["rms_px"] < 1.0
    for name in ("rel_static", "rel_auto"):
        assert 0.005 < truth[name]["all_bands"]["rms_px"] < 1.0
    # before `relative` the other band keeps its LAB offset; after, it is calibrated
    assert truth["cal_auto"]["per_band"]["B4"]["rms_px"] > 5 * truth["rel_auto"]["per_band"]["B4"]["rms_px"]
    mc = res["match_plus_calibrate"]
    assert mc["cpu_s_half"] == pytest.approx(mc["cpu_s"] / 2.0, abs=0.02)


def test_lines_option_sets_rows_and_names_cache_and_outputs(tmp_path):
    bench = _bench()
    strip = bench.scaled_config(1.0, ["B2", "B4"], 1024)
    assert strip["camera"]["detectors_per_ccd"] == 5450 and strip["scene"]["n_rows"] == 1024
    assert bench.scaled_config(0.25, None, 300)["scene"]["n_rows"] == 300
    assert bench.scaled_config(0.25)["scene"]["n_rows"] == 2048  # default unchanged
    with pytest.raises(SystemExit, match="--lines"):
        bench.scaled_config(1.0, None, 63)
    assert bench.default_out_name(1.0, None) == "fullsize.json"
    assert bench.default_out_name(0.25, None) == "fullsize_scale0.25.json"
    assert bench.default_out_name(1.0, 1024) == "fullsize_scale1_lines1024.json"
    assert bench.default_out_name(1.0, 512, "true") == "fullsize_scale1_lines512_userdem_true.json"
    assert bench.inputs_dir(tmp_path / "scale1_ideal-dom_B2B4").name == "inputs_scale1"
    assert bench.inputs_dir(tmp_path / "scale1_lines256_ideal-dom_B2B4").name == "inputs_scale1_lines256"
    cache = tmp_path / "scale1_lines256_realistic_B2B4"
    given, true = bench.reference_paths(cache, "realistic"), bench.reference_paths(cache, "realistic", "true")
    assert given["dem"].name == "dem.tif" and true["dem"] == true["true_dem"] == given["true_dem"]
    assert bench.work_dir(cache) == cache and bench.work_dir(cache, "true") == cache / "userdem_true"
    cmds = bench.stage_commands(cache, "realistic", 2, "true")
    assert str(cache / "userdem_true" / "gcps.csv") in cmds["match"] and str(true["dem"]) in cmds["match"]
    assert str(cache / "scene") in cmds["simulate"]  # the render is the same scene
    with pytest.raises(SystemExit):
        bench.main(["--profile", "ideal-dom", "--user-dem", "true", "--cache", str(tmp_path)])


@pytest.mark.slow
def test_lines_strip_then_true_dem_reuses_the_render(tmp_path):
    if not (Path(sys.executable).parent / "gcpcal").exists():
        pytest.skip("the gcpcal console script is not installed beside this interpreter")
    bench = _bench()
    common = ["--scale", "0.0625", "--lines", "640", "--cache", str(tmp_path / "cache"), "--bands", "B2,B4",
              "--truth-step", "32", "--stages", "simulate,match,calibrate_auto,truth"]
    given_out, true_out = tmp_path / "given.json", tmp_path / "true.json"
    assert bench.main(common + ["--out", str(given_out)]) == 0
    given = json.loads(given_out.read_text())
    assert given["lines"] == 640 and given["scene"]["image"]["n_rows"] == 640
    assert given["scene"]["image"]["n_cols"] == 4 * 341 and "lines640" in given["cache"]
    scene_summary = Path(given["cache"]) / "scene" / "summary.json"
    stamp = scene_summary.stat().st_mtime_ns
    assert given["scene"]["injected"]  # what the realistic profile injected, DEM error included
    gcp = given["gcp_truth_error"]
    assert gcp["all"]["n"] > 100 and 0.005 < gcp["all"]["rms_px"] < 1.0
    assert gcp["all"]["median_px"] <= gcp["all"]["rms_px"] <= gcp["all"]["max_px"]
    # 4 x 341 detectors at 45 m: about +-2.3 deg (the quarter scale reaches 9.2 deg)
    assert 1.5 < gcp["off_nadir_max_deg"] < 3.5
    assert sum(c["n"] for c in gcp["by_off_nadir_deg"].values()) == gcp["all"]["n"]
    assert 0.005 < given["truth_error"]["cal_auto"]["reference_band"]["rms_px"] < 1.0
    assert len(given["truth_error"]["cal_auto"]["reference_band_per_ccd"]) == 4

    assert bench.main(common + ["--user-dem", "true", "--out", str(true_out)]) == 0
    true = json.loads(true_out.read_text())
    assert "simulate" not in true["stages"] and scene_summary.stat().st_mtime_ns == stamp  # not re-rendered
    assert true["user_dem_path"].endswith("dem_true.tif") and true["work"].endswith("userdem_true")
    assert (Path(true["work"]) / "gcps.csv").exists() and (Path(true["work"]) / "cal_auto").is_dir()
    assert true["gcp_truth_error"]["all"]["n"] > 100
    assert 0.005 < true["truth_error"]["cal_auto"]["reference_band"]["rms_px"] < 1.0
    dem_term_of_the_render(Path(given["cache"]) / "scene", tmp_path)
    widened_match_of_the_render(Path(given["cache"]), tmp_path)
    match_memory_of_the_render(Path(given["cache"]), tmp_path)


def match_memory_of_the_render(cache: Path, tmp_path: Path) -> None:
    """``bench/bench_match_memory.py``: both coarse-stage settings measured, calibrated and graded."""
    spec = importlib.util.spec_from_file_location("bench_match_memory", ROOT / "bench" / "bench_match_memory.py")
    memory = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(memory)
    out = tmp_path / "match_memory.json"
    assert memory.main(["--cache", str(cache), "--truth-step", "32", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    for name in ("tiled", "whole"):
        r = res[name]
        assert r["match"]["rc"] in (0, 4) and r["match"]["peak_rss_mib"] > 100
        assert r["coarse_alone"]["tiles"] == 1  # 1364 columns: within the default budget, matched whole
        assert r["coarse_alone"]["coarse_adds_mib"] > 0 and r["gcps"] > 100
        assert r["gcp_truth_error"]["all"]["n"] == r["gcps"] + r["check_points"]
        assert r["truth_error"]["reference_band"]["rms_px"] < 1.0


def widened_match_of_the_render(cache: Path, tmp_path: Path) -> None:
    """``bench/bench_fullwidth_match.py``: the coarse stage's target reaches ``coarse_match``, then is restored."""
    import gcpmatch.extract as extract

    spec = importlib.util.spec_from_file_location("bench_fullwidth_match", ROOT / "bench" / "bench_fullwidth_match.py")
    widened = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(widened)
    original = extract.coarse_match
    out = tmp_path / "widened.json"
    # 1364 columns: the default target (1600) reduces by 1, a target of 700 by 2
    assert widened.main(["--cache", str(cache), "--target-px", "700", "--n-features", "12000",
                         "--truth-step", "32", "--out", str(out)]) == 0
    assert extract.coarse_match is original
    res = json.loads(out.read_text())
    assert res["match"]["coarse"]["factor"] == 2
    assert res["match"]["gcps"] > 100
    assert res["gcp_truth_error"]["all"]["n"] == res["match"]["gcps"] + res["match"]["check_points"]
    assert res["truth_error"]["lab"]["reference_band"]["rms_px"] > 50.0
    assert res["truth_error"]["cal_static"]["reference_band"]["rms_px"] < 1.0


def dem_term_of_the_render(scene: Path, tmp_path: Path) -> None:
    """``bench/bench_dem_term.py`` on a rendered realistic scene: GCPs on the TRUE DEM, both heights."""
    spec = importlib.util.spec_from_file_location("bench_dem_term", ROOT / "bench" / "bench_dem_term.py")
    dem_term = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(dem_term)
    out = tmp_path / "dem_term.json"
    assert dem_term.main(["--scene", str(scene), "--work", str(tmp_path / "dem_term"), "--out", str(out),
                          "--spacing", "32", "--truth-step", "32"]) == 0
    res = json.loads(out.read_text())
    term = res["dem_term_per_gcp"]
    # the injected user DEM error is ~8 m rms; at +-2.3 deg, 8 m * tan(2 deg) / 45 m ~ 0.006 px
    assert 4.0 < term["dh_rms_m"] < 16.0
    assert 0.0005 < term["all"]["rms_px"] < 0.03
    exact, with_dem = res["runs"]["h_true"], res["runs"]["h_user"]
    assert exact["gcp_truth_error"]["all"]["max_px"] < 1e-3  # TRUE heights: the GCPs are exact
    assert with_dem["gcp_truth_error"]["all"]["rms_px"] == pytest.approx(term["all"]["rms_px"], rel=1e-3)
    for run in (exact, with_dem):
        assert 0.0 < run["cal_static"]["truth_error"]["reference_band"]["rms_px"] < 1.0
