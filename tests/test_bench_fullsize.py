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
