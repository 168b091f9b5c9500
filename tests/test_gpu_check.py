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
        # the device's fine stage from the CPU run's pre-corrected model: the same chips, the same GCPs
        fine = rec["fine"]["compare"]
        assert fine["precorrection_max_px"] == 0.0 and fine["same_windows"] == fine["gcps_cpu"] == fine["gcps_device"]
        assert fine["max_gcp_diff_px"] < 1e-4
        assert "coarse stage skipped" in rec["fine"]["device"]["coarse_note"]


def _gpu_check_module():
    spec = importlib.util.spec_from_file_location("gpu_check_module", ROOT / "bench" / "gpu_check.py")
    module = importlib.util.module_from_spec(spec)
    saved = list(sys.path)
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path[:] = saved
    return module


def test_gcps_compared_at_the_same_ground_point():
    """Two runs whose pre-corrections differ see each window centre at a slightly different ground
    point; with the image points given by one smooth ground-to-image map (the same GCPs), the
    comparison at the same ground point reads ~0 while the raw image-point difference reads the
    ground offset (0.1-0.2 px); a real 0.03 px difference on one GCP is found."""
    import numpy as np

    module = _gpu_check_module()
    gsd, lat0 = 30.0, 40.0
    metres = 6371008.8 * np.deg2rad(1.0)
    kx, ky = 1.0 / (metres * np.cos(np.deg2rad(lat0))), 1.0 / metres

    def image_point(x, y):  # a smooth, slightly rotated and curved ground -> image map (px)
        return (-y / gsd + 2e-7 * x * x / gsd, x / gsd + 0.03 * y / gsd)

    gx, gy = np.meshgrid(np.arange(40) * 32.0 * gsd, np.arange(30) * 32.0 * gsd)
    x, y = gx.ravel(), gy.ravel()
    ccd = np.where(x < x.mean(), "0", "1")
    offset = np.stack([0.1 + 0.05 * x / x.max(), -0.15 * y / y.max()], axis=1) * gsd  # the other pre-correction

    def run(xx, yy):
        r, c = image_point(xx, yy)
        corners = (np.array([0.0, 1.0]) * kx, lat0 + np.array([0.0, 1.0]) * ky)
        return ({"gsd_m": gsd, "gcps": xx.size, "read_and_match_s": 1.0},
                {"lon": xx * kx, "lat": lat0 + yy * ky, "row": r, "col": c, "ccd": ccd,
                 "corner_lon": corners[0], "corner_lat": corners[1]})

    cpu = run(x, y)
    dev = run(x + offset[:, 0], y + offset[:, 1])
    out = module.compare_matches(cpu, dev)
    assert out["same_windows"] == x.size
    assert out["max_gcp_diff_px"] < 1e-3 < 0.1 < out["max_gcp_diff_px_uncorrected"]
    dev[1]["row"][77] += 0.03
    out = module.compare_matches(cpu, dev)
    assert abs(out["max_gcp_diff_px"] - 0.03) < 2e-3
