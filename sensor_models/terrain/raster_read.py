"""Raster reading for terrain grids: the only terrain code that reads rasters with rasterio.

:func:`read_raster` reads band 1 of a DEM or geoid grid (whole, or a window of it) as float64
with nodata as NaN and the file's scale and offset applied; rasterio's errors become ours here
(:class:`~sensor_models.errors.DemError`, or the error the caller names).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyproj

from sensor_models.errors import DemError
from sensor_models.files.gdal_paths import is_gdal_virtual, virtual_exists

__all__ = ["read_raster"]


def read_raster(path, *, what, window_from=None, missing_error=DemError):
    """Read band 1 of a raster as float64 with nodata as NaN.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file is ("DEM", "geoid grid"), for messages.
    window_from : callable, optional
        ``window_from(transform, crs, width, height) -> (row0, row1, col0, col1)``: the node
        rows and columns to read (half-open). Whole raster when None.
    missing_error : type
        Exception raised when the file is missing or unreadable.

    Returns
    -------
    values : ndarray, shape (rows, cols), float64
    transform : affine.Affine
        Of the part read (pixel-corner convention).
    crs : pyproj.CRS or None
    """
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.windows import Window

    path = os.fspath(path)
    if not (Path(path).is_file() or (is_gdal_virtual(path) and virtual_exists(path))):
        raise missing_error(f"{path}: {what} file not found")
    try:
        with rasterio.open(path) as ds:
            crs = None if ds.crs is None else pyproj.CRS.from_wkt(ds.crs.to_wkt())
            if window_from is None:
                window = Window(0, 0, ds.width, ds.height)
            else:
                row0, row1, col0, col1 = window_from(ds.transform, crs, ds.width, ds.height)
                window = Window(col0, row0, col1 - col0, row1 - row0)
            band = ds.read(1, window=window, masked=True)
            scale = ds.scales[0] if ds.scales else 1.0
            offset = ds.offsets[0] if ds.offsets else 0.0
            transform = ds.window_transform(window)
    except RasterioError as err:
        raise missing_error(f"{path}: cannot be read as a {what} raster ({err})") from err
    values = np.ma.filled(band.astype(np.float64), np.nan)
    if scale != 1.0 or offset != 0.0:
        values = values * scale + offset
    return np.ascontiguousarray(values), transform, crs
