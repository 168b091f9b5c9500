"""Orthorectification: a raw-geometry image resampled onto a map grid through a model and a DEM.

For every node of the map grid, the ground point ``(x, y)`` with the DEM height ``h(x, y)`` is
projected into the image by the model's inverse localization, ``(row, col) =
model.ground_to_image(lon, lat, h)``, and the image is sampled there (bilinear, OpenCV
``remap``; pixel centres at ``(row, col) = (i + 0.5, j + 0.5)``). Nodes that the image does
not see, or that lie off the DEM, are NaN.
"""

from __future__ import annotations

import cv2
import numpy as np
import pyproj

__all__ = ["orthorectify"]


def orthorectify(model, image: np.ndarray, dem, transform, crs, shape, *, band=None, block_rows: int = 512) -> np.ndarray:
    """Orthoimage (float32, ``shape``) of ``image`` on the grid ``transform``/``crs``.

    Parameters
    ----------
    model : SensorModel
        Describes ``image`` (same pixel grid).
    image : ndarray (n_rows, n_cols)
    dem : sensor_models.terrain.Dem
        Heights (ellipsoidal) of the ground.
    transform : affine.Affine
        Pixel-corner transform of the output grid.
    crs : pyproj.CRS or anything pyproj accepts
    shape : (rows, cols)
    """
    from affine import Affine

    transform = Affine(*tuple(transform)[:6])
    to_lonlat = pyproj.Transformer.from_crs(pyproj.CRS.from_user_input(crs), "EPSG:4326", always_xy=True)
    src = np.ascontiguousarray(image, dtype=np.float32)
    n_rows, n_cols = shape
    out = np.full(shape, np.nan, dtype=np.float32)
    cols = np.arange(n_cols) + 0.5
    for a in range(0, n_rows, block_rows):
        b = min(n_rows, a + block_rows)
        rr, cc = np.meshgrid(np.arange(a, b) + 0.5, cols, indexing="ij")
        x = transform.a * cc + transform.b * rr + transform.c
        y = transform.d * cc + transform.e * rr + transform.f
        lon, lat = to_lonlat.transform(x.ravel(), y.ravel())
        lon, lat = np.asarray(lon), np.asarray(lat)
        h = dem.height_m(lon, lat)
        ok = np.isfinite(h)
        row = np.full(lon.size, np.nan)
        col = np.full(lon.size, np.nan)
        if ok.any():
            kw = {} if band is None else {"band": band}
            row[ok], col[ok] = model.ground_to_image(lon[ok], lat[ok], h[ok], **kw)
        u = np.where(np.isfinite(col), col - 0.5, -10.0).astype(np.float32).reshape(rr.shape)
        v = np.where(np.isfinite(row), row - 0.5, -10.0).astype(np.float32).reshape(rr.shape)
        out[a:b] = cv2.remap(src, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return out
