"""read_band gives, without a masked array's copies, what the masked read gives: the native
pixels as float32, NaN where GDAL's mask (nodata value or mask band) says no data."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from gcpmatch.extract import read_band


def _masked_read(path, index):
    with rasterio.open(path) as ds:
        return np.ma.filled(ds.read(index, masked=True).astype(np.float32), np.nan)


class _Scene:
    def __init__(self, path, index):
        self.rasters = {"B": {"path": str(path), "index": index}}


def _write(path, pixels, nodata=None, mask=None):
    count, height, width = pixels.shape
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=count, dtype=pixels.dtype,
                           nodata=nodata, crs="EPSG:32650", transform=from_origin(500000, 4000000, 10, 10)) as ds:
            ds.write(pixels)
            if mask is not None:
                ds.write_mask(mask)


@pytest.mark.parametrize("dtype, nodata", [("uint16", 0), ("uint16", None), ("int16", -1), ("uint8", 255), ("int32", -5),
                                           ("float32", -9999.0), ("float32", np.nan), ("float64", None)])
def test_read_band_equals_the_masked_read(tmp_path, dtype, nodata):
    rng = np.random.default_rng(3)
    pixels = rng.uniform(1, 250, (2, 40, 60)).astype(dtype)  # no pixel at a nodata value by chance
    if nodata is not None:
        pixels[:, 4:9, 10:30] = nodata
    path = tmp_path / "band.tif"
    _write(path, pixels, nodata)
    for index in (1, 2):
        got, want = read_band(_Scene(path, index), "B"), _masked_read(path, index)
        assert got.dtype == np.float32 and np.array_equal(got, want, equal_nan=True)
        assert np.isnan(got).sum() == (100 if nodata is not None else 0)


def test_read_band_honours_a_mask_band(tmp_path):
    pixels = np.random.default_rng(4).integers(1, 900, (1, 40, 60)).astype("uint16")
    mask = np.full((40, 60), 255, np.uint8)
    mask[20:30, 5:15] = 0
    path = tmp_path / "band.tif"
    _write(path, pixels, mask=mask)
    got = read_band(None, "B", image=path)
    assert np.array_equal(got, _masked_read(path, 1), equal_nan=True) and np.isnan(got).sum() == 100
