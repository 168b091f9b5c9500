"""locate_block (node grid + Catmull-Rom + per-pixel Newton on the DEM) against the exact model.

The reference is the model's own per-pixel ``image_to_ground(row, col, dem=dem)`` on the
embedded fixture (``fixtures/hy1c_czi``: 512 lines, 4 CCDs x 192 detectors, 30 m GSD; DOM 15 m
and DEM 30 m in UTM 31N, heights 0..1500 m), projected into the same grids.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj
import pytest
from affine import Affine

from gcpmatch.reference import NODE_STEP_COLS, POSITION_TOLERANCE_DOM_PX
from sensor_models.imaging.locate import HEIGHT_TOLERANCE_M, dem_planes, locate_block
from sensor_models.maps.grid import MapGrid, MapProjector
from sensor_models.maps.raster import MapImage
from sensor_models.readers import open_model
from sensor_models.terrain.dem import Dem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
BAND = "B2"


@pytest.fixture(scope="module")
def scene():
    model = open_model(FIXTURE / "truth_manifest.json")
    dem = Dem.open(FIXTURE / "reference" / "dem.tif")
    dom = MapImage.open(FIXTURE / "reference" / "dom.tif")
    # a geographic grid (another CRS than the DEM's): its indices come from the interpolated
    # layers, not from the DEM indices by an affine map
    lon0, lat0 = pyproj.Transformer.from_crs(dem.crs, 4326, always_xy=True).transform(dem.transform.c, dem.transform.f)
    geographic = MapGrid(Affine(2e-4, 0.0, lon0, 0.0, -2e-4, lat0), pyproj.CRS.from_epsg(4326), (1500, 1500))
    return model, dem, dom.grid, geographic


def _random_blocks(model, rng, n_blocks: int):
    """Blocks of random origin and size on every CCD: pixel centres fall at all node fractions."""
    n_rows = model.image_shape[0]
    for i, ccd in enumerate(model.band_ccds(BAND)):
        for _ in range(n_blocks):
            r0 = int(rng.integers(0, n_rows // 3))
            r1 = int(rng.integers(r0 + 40, n_rows + 1))
            c0 = ccd.first_col + int(rng.integers(0, 40))
            c1 = int(rng.integers(c0 + 30, ccd.first_col + ccd.n_detectors + 1))
            yield i, r0, r1, c0, c1


#: the three ways of locating: the fixed solver (simulators), the adaptive one with a height
#: tolerance, and the reference chips' settings (position-bounded stopping, 32-column nodes)
SOLVERS = {"fixed": {}, "adaptive": {"tolerance_m": HEIGHT_TOLERANCE_M},
           "chips": {"tolerance_m": HEIGHT_TOLERANCE_M, "position_tolerance_m": POSITION_TOLERANCE_DOM_PX * 15.0,
                     "node_step_cols": NODE_STEP_COLS}}


def _errors(model, dem, grids, blocks, *, row_shift_px: float = 0.0, **kw):
    """Differences located - exact over every pixel of the blocks: (du, dv) per grid and dh (m)."""
    projectors = [MapProjector(g) for g in grids]
    d_uv = [[] for _ in grids]
    d_h = []
    for ccd, r0, r1, c0, c1 in blocks:
        pg = locate_block(model, dem, grids, band=BAND, ccd=ccd, row0=r0, row1=r1, col0=c0, col1=c1, **kw)
        rr, cc = np.meshgrid(np.arange(r0, r1) + 0.5 + row_shift_px, np.arange(c0, c1) + 0.5, indexing="ij")
        lon, lat, h = model.image_to_ground(rr.ravel(), cc.ravel(), dem=dem, band=BAND, array=ccd)
        d_h.append(pg.h_m.ravel() - h)
        for k, project in enumerate(projectors):
            u, v = project(lon, lat)
            d_uv[k].append(np.stack([pg.uv[k][0].ravel() - u, pg.uv[k][1].ravel() - v], -1))
    return [np.concatenate(d) for d in d_uv], np.concatenate(d_h)


@pytest.mark.parametrize("solver", list(SOLVERS))
def test_locate_block_matches_the_exact_model_per_pixel(scene, solver):
    """Every pixel of 12 random blocks over the 4 CCDs of B2 (351 368 pixels), with the fixed
    solver, the adaptive one (coarse start, convergence mask) and the chips' settings
    (stopping at 1e-3 DOM px of position, nodes every 32 columns): same bounds.

    Measured: DOM grid 1.9e-4 DOM px RMS (2.8 mm), 5.6e-4 px at worst (chips: 3.0e-4 and
    8.6e-4, the 32-column nodes of the truth model's lens); heights 0.8 mm RMS, 8 mm at worst
    (chips: 1.2 mm and 14 mm, its height tolerance being 1.5 cm / tan z); geographic grid
    1.6e-4 px RMS (chips 2.7e-4). Bounds:
    2e-3 DOM px (3 cm) RMS, 1e-2 px worst, 1 cm height RMS. Not vacuous: the interpolation
    leaves a non-zero residual, and the same comparison sees a 0.01-pixel misplacement of the
    exact positions (0.3 m: 0.020 DOM px RMS, ten times the bound).
    """
    model, dem, dom_grid, geographic = scene
    dem_planes(dem)
    kw = SOLVERS[solver]
    blocks = list(_random_blocks(model, np.random.default_rng(15), 3))
    (d_dom, d_geo), d_h = _errors(model, dem, [dom_grid, geographic], blocks, **kw)
    assert d_dom.shape[0] > 300_000
    finite = np.isfinite(d_dom).all(axis=1) & np.isfinite(d_h)
    assert finite.mean() > 0.999  # the fixture's DEM covers the scene
    e_dom = np.hypot(*d_dom[finite].T)
    e_geo = np.hypot(*d_geo[finite].T)
    rms_dom, rms_h = float(np.sqrt(np.mean(e_dom**2))), float(np.sqrt(np.mean(d_h[finite] ** 2)))
    rms_geo = float(np.sqrt(np.mean(e_geo**2)))
    print(f"locate_block vs exact: DOM {rms_dom:.2e} px rms ({rms_dom * dom_grid.resolution_m * 1e3:.1f} mm), "
          f"max {e_dom.max():.2e} px; geographic {rms_geo:.2e} px rms; h {rms_h * 1e3:.2f} mm rms, "
          f"max {np.abs(d_h[finite]).max() * 1e3:.1f} mm")
    assert 1e-6 < rms_dom < 2e-3 and e_dom.max() < 1e-2
    assert 1e-6 < rms_geo < 2e-3 * dom_grid.resolution_m / geographic.resolution_m and e_geo.max() < 1e-2
    assert rms_h < 0.01 and np.abs(d_h[finite]).max() < 0.05

    (d_shift,), _ = _errors(model, dem, [dom_grid], blocks[:4], row_shift_px=0.01, **kw)
    e_shift = np.hypot(*d_shift[np.isfinite(d_shift).all(axis=1)].T)
    assert np.sqrt(np.mean(e_shift**2)) > 5.0 * 2e-3  # a 0.01 px error would fail the bound


@pytest.mark.parametrize("solver", list(SOLVERS))
def test_locate_block_of_one_line_and_one_column(scene, solver):
    """The smallest block (one pixel) uses the same nodes logic and agrees with the exact model."""
    model, dem, dom_grid, _ = scene
    (d_dom,), d_h = _errors(model, dem, [dom_grid], [(1, 300, 301, 250, 251)], **SOLVERS[solver])
    assert d_dom.shape == (1, 2)
    assert np.hypot(*d_dom[0]) < 1e-2 and abs(d_h[0]) < 0.05
