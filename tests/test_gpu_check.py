"""bench/gpu_check.py's dry run (torch on the CPU, reduced sizes): it runs end to end and its
figures say that the torch path agrees with the CPU path."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_gpu_check_dry_run(tmp_path):
    pytest.importorskip("torch", reason="torch (optional 'gpu' extra) is not installed")
    spec = importlib.util.spec_from_file_location("gpu_check", ROOT / "bench" / "gpu_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path / "gpu_check.json"
    saved = list(sys.path)
    try:
        assert module.main(["--device", "cpu", "--small", "--work", str(tmp_path / "work"), "--out", str(out)]) == 0
    finally:
        sys.path[:] = saved
    result = json.loads(out.read_text())
    env, phase = result["environment"], result["phase"]
    assert env["card"].startswith("none") and env["cpu_count"] >= 1 and len(env["loadavg_start"]) == 3
    assert phase["cpu"]["windows_per_s"] > 0 and all(r["windows_per_s"] > 0 for r in phase["device"].values())
    agree = phase["agreement"]
    assert agree["valid_both"] > 0.9 * agree["pairs"] and agree["max_abs_shift_diff_px"] < 0.01
    assert set(result["match"]) == {"small", "scale0.0625"}
    for rec in result["match"].values():
        c = rec["compare"]
        assert c["precorrection_max_px"] < 0.1 * c["capture_radius_px"]
        assert c["same_windows"] > 0.95 * min(c["gcps_cpu"], c["gcps_device"]) > 0
        assert c["max_gcp_diff_px"] < 0.05
        assert rec["cpu"]["read_and_match_s"] > 0 and rec["device"]["batch"] >= 1
