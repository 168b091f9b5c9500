"""The fast paths of the matcher against the slow ones they replace, with accuracy bounds.

* The adaptive DEM intersection (:mod:`sensor_models.locate_adaptive`: coarse-grid start, one
  chord step everywhere, Newton steps only where the convergence mask says so) against the fixed
  four-step solver, on the embedded fixture (``fixtures/hy1c_czi``, heights 0..1500 m).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sensor_models.locate import HEIGHT_TOLERANCE_M, MapGrid, MapProjector, _intersect_dem, _pixel_layers, dem_planes, locate_block
from sensor_models.locate_adaptive import intersect_dem_adaptive
from sensor_models.raster import MapImage
from sensor_models.readers import open_model
from sensor_models.terrain import Dem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
BAND = "B2"


@pytest.fixture(scope="module")
def scene():
    model = open_model(FIXTURE / "truth_manifest.json")
    dem = Dem.open(FIXTURE / "reference" / "dem.tif")
    dom = MapImage.open(FIXTURE / "reference" / "dom.tif")
    dem_planes(dem)
    return model, dem, dom


@pytest.fixture(scope="module")
def layers(scene):
    """Straight-ray layers of CCD 2's first 400 lines in the DEM grid, and their lower height."""
    model, dem, _ = scene
    look = model.detector_arrays(BAND)[2]
    h_lo, h_hi = dem.height_range_m[0] - 50.0, dem.height_range_m[1] + 50.0
    lay = _pixel_layers(model, {"band": BAND, "array": 2}, [MapProjector(MapGrid.of_dem(dem))], 0, 400,
                        look.first_col, look.first_col + look.n_detectors, 16.0, h_lo, h_hi)[0]
    return lay, np.float32(h_lo)


def test_adaptive_locate_block_agrees_with_the_fixed_solver_everywhere(scene):
    """Every pixel of the fixture's four CCDs (512 x 768): same NaN pixels, heights within
    1 cm RMS and 5 cm at worst (the fixed solver's own error against the exact model is up to
    9 mm: tests/test_locate.py), DOM positions within 2e-3 DOM px."""
    model, dem, dom = scene
    n_rows = model.image_shape[0]
    d_h, d_uv, n = [], [], 0
    for ccd in range(len(model.detector_arrays(BAND))):
        a = locate_block(model, dem, [dom.grid], band=BAND, ccd=ccd, row0=0, row1=n_rows)
        b = locate_block(model, dem, [dom.grid], band=BAND, ccd=ccd, row0=0, row1=n_rows,
                         tolerance_m=HEIGHT_TOLERANCE_M)
        assert np.array_equal(np.isnan(a.h_m), np.isnan(b.h_m))
        d_h.append((a.h_m - b.h_m).ravel())
        d_uv.append(np.hypot(a.uv[0][0] - b.uv[0][0], a.uv[0][1] - b.uv[0][1]).ravel())
        n += a.h_m.size
    d_h, d_uv = np.concatenate(d_h), np.concatenate(d_uv)
    ok = np.isfinite(d_h)
    assert n == n_rows * 768 and ok.mean() > 0.8
    assert np.sqrt(np.mean(d_h[ok] ** 2)) < 0.01 and np.abs(d_h[ok]).max() < 0.05
    assert d_uv[ok].max() < 2e-3


def test_convergence_mask_refines_the_pixels_that_need_it(layers, scene):
    """Against a converged solution (12 fixed steps): without the refinement steps (one chord
    step from the coarse start) heights are off by more than 1 cm somewhere; with the mask's
    Newton steps every pixel is within 1 cm. A start the coarse grid cannot give (coarse step 1:
    mid-height everywhere) converges through the mask too."""
    _, dem, _ = scene
    lay, h_lo = layers
    exact = _intersect_dem(dem, *lay, h_lo, 12)[0]
    ok = np.isfinite(exact)
    assert ok.mean() > 0.9
    rough = intersect_dem_adaptive(dem, *lay, h_lo, chord_steps=1, max_refine_steps=0)[0]
    assert np.nanmax(np.abs(rough - exact)) > 0.01
    for kw in ({}, {"coarse_step": 1, "max_refine_steps": 8}):
        h = intersect_dem_adaptive(dem, *lay, h_lo, tolerance_m=HEIGHT_TOLERANCE_M, **kw)[0]
        assert np.array_equal(np.isnan(h), ~ok)
        assert np.abs(h[ok] - exact[ok]).max() < 0.01


def test_adaptive_intersection_rejects_a_tolerance_of_zero(layers, scene):
    _, dem, _ = scene
    lay, h_lo = layers
    with pytest.raises(ValueError, match="tolerance_m"):
        intersect_dem_adaptive(dem, *lay, h_lo, tolerance_m=0.0)
