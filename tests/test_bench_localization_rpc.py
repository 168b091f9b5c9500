"""The RPC-over-DEM comparison of ``bench/bench_localization.py`` at a tiny size.

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


@pytest.fixture(scope="module")
def scene(bench):
    from sensor_models.models.pushbroom_types import Installation
    from sensor_models.models.synthetic import example_pushbroom_model

    dem, _ = bench.load_dem()
    model = example_pushbroom_model(n_rows=2000, installation=Installation(0.0, 0.0, np.radians(3.55)))
    return model, dem


def test_shareloc_column_is_skipped_with_a_reason(bench, scene, capsys):
    model, dem = scene
    r = bench.bench_rpc_dem(model, dem, 500, repeat=1)
    assert r["shareloc"] == {"skipped": "--shareloc-python not given"}
    assert "shareloc column skipped: --shareloc-python not given" in capsys.readouterr().out
    # this environment has no shareloc: the child fails to import it and the run goes on
    r = bench.bench_rpc_dem(model, dem, 500, repeat=1, shareloc_python=sys.executable)
    assert "could not run shareloc" in r["shareloc"]["skipped"]
    assert "ratio_vs_shareloc_cpp" not in r and r["ratio_vs_gdal"] > 0
    # ours and GDAL still compared: both within a few 1e-4 px of the base revision
    assert r["after"]["reprojection_px_max"] <= 1.0001e-4
    assert r["gdal"]["distance_to_after_px_max"] < 1e-3


def test_accuracy_measures_catch_a_half_pixel_convention_error(bench, scene):
    model, dem = scene
    rpc, _, rows, cols, _ = bench._rpc_scene(model, dem, 400)
    ours = rpc.image_to_ground(rows, cols, dem=dem)
    ref = {"before": ours, "after": ours}
    shifted = rpc.image_to_ground(rows + 0.5, cols + 0.5, dem=dem)  # a corner/centre mix-up
    bad = bench._accuracy(rpc, dem, rows, cols, shifted, ref)
    assert 0.6 < bad["distance_to_after_px_max"] < 0.8  # hypot(0.5, 0.5) = 0.71 px
    assert 0.45 < bad["reprojection_px_max"] < 0.55
    good = bench._accuracy(rpc, dem, rows, cols, tuple(np.copy(a) for a in ours), ref)
    assert good["distance_to_after_px_max"] < 1e-9 and good["reprojection_px_max"] <= 1.0001e-4


def test_shareloc_cpp_agrees_with_ours(bench, scene):
    python = os.environ.get("GCPCAL_SHARELOC_PYTHON")
    if not python:
        pytest.skip("GCPCAL_SHARELOC_PYTHON (a Python with shareloc installed) not set")
    model, dem = scene
    r = bench.bench_rpc_dem(model, dem, 2000, repeat=1, shareloc_python=python)
    s = r["shareloc"]
    assert "skipped" not in s, s
    # the same convention: offsets far below a pixel, yet not identical (shareloc follows a
    # straight line of sight between the DTM's lowest and highest heights)
    assert 1e-7 < s["distance_to_after_px_max"] < 1e-3
    assert s["reprojection_px_max"] < 1e-3 and s["dem_misfit_m_max"] < 0.01
    assert abs(s["found"] - r["after"]["found"]) < 0.01 and r["ratio_vs_shareloc_cpp"] > 0
