"""Geometry of a terrain grid: affine transforms and WGS84 lon/lat <-> node indices.

Continuous pixel coordinates follow GDAL/rasterio (the first pixel's centre is ``(0.5, 0.5)``);
a *node index* ``(col, row)`` puts the first node centre at ``(0, 0)``, i.e.
``col = x_pixel - 0.5``. :class:`GridGeometry` maps WGS84 points to node indices and back, through
the grid's affine alone for a plain lon/lat grid, through PROJ otherwise.
"""

from __future__ import annotations

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError

__all__ = ["GridGeometry", "apply_affine", "as_affine"]


def as_affine(transform) -> Affine:
    """``transform`` as an :class:`affine.Affine`: itself, or built from its 6 (or 9) coefficients.

    Raises
    ------
    InputError
        When ``transform`` does not hold 6 or 9 coefficients.
    """
    if isinstance(transform, Affine):
        return transform
    coeffs = tuple(float(c) for c in transform)
    if len(coeffs) not in (6, 9):
        raise InputError(
            f"transform needs the 6 affine coefficients (a, b, c, d, e, f), got {len(coeffs)}"
        )
    return Affine(*coeffs[:6])


def apply_affine(transform: Affine, x, y):
    """``transform`` applied to arrays ``x``, ``y`` (pixel <-> CRS coordinates)."""
    return (transform.a * x + transform.b * y + transform.c,
            transform.d * x + transform.e * y + transform.f)


def _node_index_affine(transform: Affine):
    """Coefficients of ``(x, y) -> (col, row)`` node indices (first node centre at 0, 0)."""
    inv = ~transform
    return (inv.a, inv.b, inv.c - 0.5, inv.d, inv.e, inv.f - 0.5)


class GridGeometry:
    """WGS84 lon/lat <-> node indices ``(col, row)`` of a grid (first node centre at 0, 0).

    A grid in a geographic CRS that PROJ maps identically from WGS84 uses its affine alone
    (fast path, with longitudes wrapped onto the grid's 360-degree branch when the grid runs
    past +-180); any other CRS goes through a PROJ transformation first.
    """

    def __init__(self, transform: Affine, crs: pyproj.CRS, shape):
        self.transform = transform
        self.index_coeffs = _node_index_affine(transform)
        self.to_grid = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        self.from_grid = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        self.plain_lonlat = False
        self.wrap_west_deg = None
        if crs.is_geographic:
            n_rows, n_cols = shape
            xs, ys = apply_affine(transform, np.array([0.5, n_cols - 0.5, 0.5, n_cols - 0.5]),
                                   np.array([0.5, 0.5, n_rows - 0.5, n_rows - 0.5]))
            lon, lat = self.from_grid.transform(xs, ys)
            if (np.allclose(lon, xs, rtol=0.0, atol=1e-10)
                    and np.allclose(lat, ys, rtol=0.0, atol=1e-10)):
                self.plain_lonlat = True
                west = float(np.min(xs)) - 0.5 * abs(transform.a)
                if west < -180.0 or float(np.max(xs)) > 180.0:
                    self.wrap_west_deg = west

    def lonlat_to_index(self, lon_deg, lat_deg):
        """Node indices ``(col, row)`` of WGS84 points; inf where PROJ cannot map them."""
        if self.plain_lonlat:
            x, y = lon_deg, lat_deg
            if self.wrap_west_deg is not None:
                x = self.wrap_west_deg + np.mod(x - self.wrap_west_deg, 360.0)
        else:
            x, y = self.to_grid.transform(lon_deg, lat_deg)
            x = np.asarray(x, dtype=np.float64)
            y = np.asarray(y, dtype=np.float64)
        a, b, c, d, e, f = self.index_coeffs
        return a * x + b * y + c, d * x + e * y + f

    def index_to_lonlat(self, col, row):
        """WGS84 ``(lon, lat)`` in degrees of node indices."""
        x, y = apply_affine(self.transform, np.asarray(col, dtype=np.float64) + 0.5,
                             np.asarray(row, dtype=np.float64) + 0.5)
        if self.plain_lonlat:
            return x, y
        lon, lat = self.from_grid.transform(x, y)
        return np.asarray(lon), np.asarray(lat)
