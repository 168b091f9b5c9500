"""Grid-interpolated inverse localization for dense use (resampling, orthorectification).

The exact model projects the nodes of a regular ``(h, lat, lon)`` grid into the image once,
separately for every CCD (each CCD's polynomial is smooth across the whole grid); dense points
are then interpolated trilinearly (:func:`scipy.ndimage.map_coordinates`, order 1). A point is
given to the first CCD whose interpolated column falls inside its columns, else to the nearest.

Interpolation error of a trilinear grid with node spacing ``d`` is about ``d^2 |f''| / 8``; the
ground-to-image mapping of a push-broom scene is close to affine, so spacings of 16 to 32
pixels keep it far below 0.01 px (measured by ``bench/bench_localization.py``).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

from sensor_models.base import as_float_arrays
from sensor_models.errors import InputError

__all__ = ["InverseLocalizationGrid"]


class InverseLocalizationGrid:
    """Ground -> image by trilinear interpolation of exactly projected grid nodes.

    Parameters
    ----------
    model : PushbroomModel
        Any model with ``ground_to_image(lon, lat, h, band=, array=)`` and ``band_ccds(band)``.
    lon_range, lat_range : (float, float)
        Extent of the grid in degrees.
    height_range_m : (float, float)
        Ellipsoidal heights covered.
    spacing_px : float
        Approximate node spacing in image pixels (the ground spacing is derived from the
        model's ground sampling distance at the grid centre).
    height_step_m : float
        Node spacing in height.
    band : str, optional
    """

    def __init__(self, model, lon_range, lat_range, height_range_m, *, spacing_px=16.0, height_step_m=500.0, band=None):
        self.band = band
        self.ccds = model.band_ccds(band)
        lon0, lon1 = map(float, lon_range)
        lat0, lat1 = map(float, lat_range)
        h0, h1 = map(float, height_range_m)
        if not (lon1 > lon0 and lat1 > lat0 and h1 >= h0):
            raise InputError("grid ranges must be increasing")
        gsd_deg = self._gsd_deg(model, band, (lon0 + lon1) / 2, (lat0 + lat1) / 2, (h0 + h1) / 2)
        step_lat = spacing_px * gsd_deg
        step_lon = step_lat / max(np.cos(np.radians((lat0 + lat1) / 2)), 1e-3)
        self.lon = np.linspace(lon0, lon1, max(2, int(np.ceil((lon1 - lon0) / step_lon)) + 1))
        self.lat = np.linspace(lat0, lat1, max(2, int(np.ceil((lat1 - lat0) / step_lat)) + 1))
        self.h = np.linspace(h0, h1, max(2, int(np.ceil((h1 - h0) / height_step_m)) + 1))
        hh, la, lo = np.meshgrid(self.h, self.lat, self.lon, indexing="ij")
        shape = hh.shape
        self.nodes = []  # per CCD: (row grid, col grid), shape (n_h, n_lat, n_lon)
        for i in range(len(self.ccds)):
            r, c = model.ground_to_image(lo.ravel(), la.ravel(), hh.ravel(), band=band, array=i)
            self.nodes.append((r.reshape(shape), c.reshape(shape)))

    @staticmethod
    def _gsd_deg(model, band, lon, lat, h):
        r, c = model.ground_to_image([lon], [lat], [h], band=band)
        if not np.isfinite(r[0]):
            r, c = np.array([model.n_rows / 2]), np.array([model.n_cols / 2])
        lo, la, _ = model.image_to_ground(np.array([r[0], r[0] + 1.0]), np.array([c[0], c[0]]), height=h, band=band)
        return float(np.hypot(np.diff(la)[0], np.diff(lo)[0] * np.cos(np.radians(lat))))

    @property
    def shape(self) -> tuple[int, int, int]:
        """Node counts ``(n_heights, n_lat, n_lon)``."""
        return (self.h.size, self.lat.size, self.lon.size)

    def _index(self, values, axis):
        return (values - axis[0]) / (axis[1] - axis[0])

    def ground_to_image(self, lon, lat, h, *, array=None):
        """Interpolated ``(row, col)``; NaN outside the grid or where nodes were not imaged.

        Parameters
        ----------
        lon, lat : array_like
            WGS84 longitude and latitude, degrees (broadcast together with ``h``).
        h : array_like
            Ellipsoidal heights, metres.
        array : int or array_like of int, optional
            Forces the CCD (index into the band's CCDs), as in
            :meth:`PushbroomModel.ground_to_image`; default: the CCD whose columns contain the
            point, else the nearest.

        Returns
        -------
        row, col : ndarray
            Continuous image coordinates (first pixel's centre at 0.5), the broadcast shape.
        """
        lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
        shape = lon.shape
        coords = np.stack([self._index(h.ravel(), self.h), self._index(lat.ravel(), self.lat), self._index(lon.ravel(), self.lon)])
        outside = np.zeros(coords.shape[1], dtype=bool)
        for axis, n in enumerate(self.shape):
            outside |= (coords[axis] < -1e-9) | (coords[axis] > n - 1 + 1e-9)
        row = np.full(coords.shape[1], np.nan)
        col = np.full(coords.shape[1], np.nan)
        best = np.full(coords.shape[1], np.inf)
        forced = None if array is None else np.broadcast_to(np.asarray(array), shape).reshape(-1)
        for i, (look, (rg, cg)) in enumerate(zip(self.ccds, self.nodes)):
            sel = slice(None) if forced is None else forced == i
            c = np.full(coords.shape[1], np.nan)
            r = np.full(coords.shape[1], np.nan)
            c[sel] = map_coordinates(cg, coords[:, sel], order=1, mode="nearest", prefilter=False)
            r[sel] = map_coordinates(rg, coords[:, sel], order=1, mode="nearest", prefilter=False)
            dist = np.maximum(np.maximum(look.first_col - c, c - look.last_col), 0.0)
            better = dist < best
            row[better] = r[better]
            col[better] = c[better]
            best[better] = dist[better]
        row[outside] = np.nan
        col[outside] = np.nan
        return row.reshape(shape), col.reshape(shape)
