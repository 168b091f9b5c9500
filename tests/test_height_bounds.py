"""The DEM's ray-marching bounds built on float32 node bounds equal the float64 construction, bit for bit.

:func:`sensor_models.terrain.height_bounds.node_bounds` rounds the heights outwards to float32
once; the pyramid's levels and the DEM's cell maxima are maxima (minima) of those bounds. Since
rounding outwards is monotone, that is the bound of the float64 maximum (minimum). The reference
here is the construction on float64 heights rounded at the end.
"""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from scipy import ndimage

from sensor_models.terrain.dem import Dem
from sensor_models.terrain.height_bounds import RangePyramid, float32_bound


def _reference_pyramid(z):
    """Levels of the min/max pyramid reduced in float64, rounded outwards to float32 at the end."""
    valid = np.isfinite(z)
    flats, offsets, widths = [], [], []
    for reduce, fill in ((np.maximum, np.inf), (np.minimum, -np.inf)):
        zz = np.where(valid, z, fill)
        level = reduce(reduce(zz[:-1, :-1], zz[:-1, 1:]), reduce(zz[1:, :-1], zz[1:, 1:]))
        blocks, offsets, widths, offset = [], [], [], 0
        while True:
            blocks.append(level.reshape(-1))
            offsets.append(offset)
            widths.append(level.shape[1])
            offset += level.size
            if max(level.shape) == 1:
                break
            rows, cols = level.shape
            padded = np.full((rows + rows % 2, cols + cols % 2), -fill)
            padded[:rows, :cols] = level
            level = reduce(reduce(padded[0::2, 0::2], padded[0::2, 1::2]), reduce(padded[1::2, 0::2], padded[1::2, 1::2]))
        flats.append(float32_bound(np.concatenate(blocks), upper=reduce is np.maximum))
    return flats, offsets, widths


def _heights(seed):
    """A random DEM (heights with float32-unrepresentable values, some nodata) of random shape."""
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(2, 90)), int(rng.integers(2, 90)))
    z = rng.normal(800.0, 600.0, shape) + rng.random(shape) * 1e-5
    z[rng.random(shape) < rng.choice([0.0, 0.05, 0.4])] = np.nan
    if not np.isfinite(z).any():
        z[0, 0] = 12.345678901
    return z


@pytest.mark.parametrize("seed", range(40))
def test_pyramid_and_cell_maxima_equal_the_float64_construction(seed):
    z = _heights(seed)
    (ref_max, ref_min), offsets, widths = _reference_pyramid(z)
    pyramid = RangePyramid(z)
    np.testing.assert_array_equal(pyramid._max_flat, ref_max)
    np.testing.assert_array_equal(pyramid._min_flat, ref_min)
    assert pyramid._max_flat.dtype == np.float32 and pyramid._offsets.tolist() == offsets
    assert pyramid._widths.tolist() == widths

    dem = Dem(z, Affine(30.0, 0.0, 500_000.0, 0.0, -30.0, 4_000_000.0), "EPSG:32631")
    z_inf = np.where(np.isfinite(z), z, np.inf)
    dmax = ndimage.maximum_filter(z_inf, size=4, mode="constant", cval=np.inf, origin=-1)
    np.testing.assert_array_equal(dem._cell_max_flat, float32_bound(dmax[:-1, :-1], upper=True).reshape(-1))
    finite = z[np.isfinite(z)]
    assert dem.height_range_m == (finite.min(), finite.max())
    # the bounds bound: every float64 node height lies within its float32 bounds
    assert (dem._cell_max_flat.reshape(z.shape[0] - 1, -1) >= np.nan_to_num(z[:-1, :-1], nan=-np.inf)).all()


@pytest.mark.parametrize("seed", range(20))
def test_height_planes_by_strips_equal_the_whole_grid(seed):
    """The renderer's sampling planes by strips of rows (a few rows each here) equal the whole-grid
    gradient, bit for bit, with nodata and infinite heights, down to 2-row grids."""
    from sensor_models.terrain.intersect import height_planes

    rng = np.random.default_rng([seed, 3])
    z = _heights(seed)
    z[rng.random(z.shape) < 0.02] = np.inf
    gv, gu = np.gradient(np.where(np.isfinite(z), z, np.nan))
    whole = np.ascontiguousarray(np.stack([z, gu, gv], axis=-1).astype(np.float32))
    for strip_nodes in (1, z.shape[1] * int(rng.integers(1, 5)), z.size):
        got = height_planes(z, strip_nodes=strip_nodes)
        assert got.flags["C_CONTIGUOUS"] and got.dtype == np.float32
        np.testing.assert_array_equal(got, whole)
