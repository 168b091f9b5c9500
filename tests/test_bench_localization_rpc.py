"""The RPC-over-DEM comparison of ``bench/bench_localization.py`` at a tiny size, on the real
Pleiades RPC and SRTM of ``../shared/data`` (skipped when absent).

Checks that the shareloc column is skipped with a reason when no shareloc environment is given
or it cannot import shareloc, that the accuracy measures catch a half-pixel convention error
(the error the comparison with GDAL and shareloc must rule out), and, when
``GCPCAL_SHARELOC_PYTHON`` names a Python with shareloc installed, that shareloc's C++ points
agree with ours far below a pixel. gcpcal does not depend on shareloc.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_localization", ROOT / "bench" / "bench_localization.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_shareloc_column_is_skipped_with_a_reason(bench, shared_data, capsys):
    r = bench.bench_rpc_dem(shared_data, 500, repeat=1)
    assert r["shareloc"] == {"skipped": "--shareloc-python not given"}
    assert "shareloc column skipped: --shareloc-python not given" in capsys.readouterr().out
    # this environment has no shareloc: the child fails to import it and the run goes on
    r = bench.bench_rpc_dem(shared_data, 500, repeat=1, shareloc_python=sys.executable)
    assert "could not run shareloc" in r["shareloc"]["skipped"]
    assert "ratio_vs_shareloc_cpp" not in r and r["ratio_vs_gdal"] > 0
    # ours, its bracketed search and GDAL compared: all within 1e-4 px, a few 1e-4 px apart
    assert r["after"]["reprojection_px_max"] <= 1.0001e-4 and r["after"]["found"] == 1.0
    assert r["bracketed"]["reprojection_px_max"] <= 1.0001e-4
    assert r["after"]["distance_to_bracketed_px_max"] < 2e-3
    assert r["gdal"]["distance_to_after_px_max"] < 2e-3
    assert r["gdal"]["reprojection_px_max"] < 2e-4
    bench.print_rpc_result(r)
    assert "GDAL RPCTransformer" in capsys.readouterr().out


def test_accuracy_measures_catch_a_half_pixel_convention_error(bench, shared_data):
    rpc, dem, rows, cols = bench.real_rpc_scene(shared_data, 400)
    ours = rpc.image_to_ground(rows, cols, dem=dem)
    ref = {"before": ours, "after": ours}
    shifted = rpc.image_to_ground(rows + 0.5, cols + 0.5, dem=dem)  # a corner/centre mix-up
    bad = bench._accuracy(rpc, dem, rows, cols, shifted, ref)
    assert 0.6 < bad["distance_to_after_px_max"] < 0.8  # hypot(0.5, 0.5) = 0.71 px
    assert 0.45 < bad["reprojection_px_max"] < 0.55
    good = bench._accuracy(rpc, dem, rows, cols, tuple(np.copy(a) for a in ours), ref)
    assert good["distance_to_after_px_max"] < 1e-9 and good["reprojection_px_max"] <= 1.0001e-4


def test_shareloc_cpp_agrees_with_ours(bench, shared_data):
    python = os.environ.get("GCPCAL_SHARELOC_PYTHON")
    if not python:
        pytest.skip("GCPCAL_SHARELOC_PYTHON (a Python with shareloc installed) not set")
    r = bench.bench_rpc_dem(shared_data, 2000, repeat=1, shareloc_python=python)
    s = r["shareloc"]
    assert "skipped" not in s, s
    # the same convention: offsets far below a pixel, yet not identical (shareloc follows a
    # straight line of sight between the DTM's lowest and highest heights, 2.7 km apart: on the
    # Pleiades RPC that chord lies up to 0.03 px off the RPC's line of sight)
    assert 1e-7 < s["distance_to_after_px_max"] < 0.05
    assert s["reprojection_px_max"] < 0.05 and s["dem_misfit_m_max"] < 0.01
    assert abs(s["found"] - r["after"]["found"]) < 0.01 and r["ratio_vs_shareloc_cpp"] > 0
