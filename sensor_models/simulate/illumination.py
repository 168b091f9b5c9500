"""Sun, hill shading and cast shadows of a simulated scene and its reference (``realistic`` profile).

The scene and the reference DOM are lit by different suns (another time of day, another season).
The source radiance is taken as the ground's albedo under a flat, unshadowed sun; each image sees

``L = rho * (k + (1 - k) max(cos i, 0) (1 - s)) / (k + (1 - k) cos z)``

with ``k`` the skylight (diffuse) share of the irradiance on flat ground, ``i`` the local
incidence angle (``cos i = cos z cos beta + sin z sin beta cos(A - aspect)``, slope ``beta``,
aspect measured like the sun azimuth ``A`` from north through east), ``z`` the solar zenith and
``s`` the cast shadow (1 where the terrain hides the sun, :func:`cast_shadow`). The denominator
keeps flat, sunlit ground at its albedo, so only relief and shadows change the texture.

Sun position (:func:`sun_angles_deg`): Cooper's declination ``23.45 sin(360 (284 + n) / 365)``
and the hour angle ``15 (t - 12)`` degrees of local solar time ``t`` (Iqbal 1983, ch. 1);
elevation ``sin e = sin phi sin d + cos phi cos d cos h``, azimuth from north through east.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from affine import Affine

__all__ = ["Sun", "cast_shadow", "illumination", "resample_to_grid", "sun_angles_deg", "terrain_light_on_grid"]

#: target pixels :func:`resample_to_grid` resamples at a time (whole rows, at least one)
_STRIP_PIXELS = 1 << 18


@dataclass(frozen=True)
class Sun:
    """Where the sun stands, degrees.

    Attributes
    ----------
    elevation_deg : float
        Above the horizon.
    azimuth_deg : float
        From north through east.
    """

    elevation_deg: float
    azimuth_deg: float

    def to_dict(self) -> dict:
        """JSON-safe ``{"elevation_deg", "azimuth_deg"}`` (rounded to 0.01 degree)."""
        return {"elevation_deg": round(self.elevation_deg, 2), "azimuth_deg": round(self.azimuth_deg, 2)}


def sun_angles_deg(lat_deg: float, day_of_year: float, local_solar_hour: float) -> Sun:
    """Solar elevation and azimuth at a latitude, day and local solar time.

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude, degrees (north positive).
    day_of_year : float
        1 = January 1st.
    local_solar_hour : float
        Local solar time, hours (12: the sun in the meridian).

    Returns
    -------
    Sun
        Elevation and azimuth (from north through east), degrees.
    """
    phi = np.radians(lat_deg)
    dec = np.radians(23.45 * np.sin(np.radians(360.0 * (284.0 + day_of_year) / 365.0)))
    h = np.radians(15.0 * (local_solar_hour - 12.0))
    sin_e = np.sin(phi) * np.sin(dec) + np.cos(phi) * np.cos(dec) * np.cos(h)
    e = np.arcsin(np.clip(sin_e, -1.0, 1.0))
    cos_a = (np.sin(dec) - np.sin(e) * np.sin(phi)) / max(np.cos(e) * np.cos(phi), 1e-12)
    a = np.degrees(np.arccos(np.clip(cos_a, -1.0, 1.0)))
    return Sun(float(np.degrees(e)), float(a if h <= 0 else 360.0 - a))


def cast_shadow(dem_m: np.ndarray, resolution_m: float, sun: Sun, *, max_steps: int = 400) -> np.ndarray:
    """1 where the terrain hides the sun from the ground, by marching towards the sun.

    A node ``p`` is in shadow when some node ``q = p + k d`` (``d`` one grid step towards the
    sun's azimuth, ``k = 1 .. K``) rises above the sun ray: ``h(q) > h(p) + |q - p| tan e``.
    Each step is one bilinear resampling of the whole grid (:func:`cv2.remap`); ``K`` covers the
    grid's height range at the sun's elevation.

    Parameters
    ----------
    dem_m : ndarray of float32, shape (H, W)
        Heights, metres, on a north-up grid (NaN: no data, never casts a shadow).
    resolution_m : float
        Grid spacing, metres.
    sun : Sun
        The sun.
    max_steps : int
        Cap on ``K``.

    Returns
    -------
    ndarray of float32, shape (H, W)
        1 in shadow, 0 lit.
    """
    h = np.asarray(dem_m, np.float32)
    finite = np.isfinite(h)
    if not finite.any() or sun.elevation_deg >= 89.9:
        return np.zeros(h.shape, np.float32)
    tan_e = np.tan(np.radians(sun.elevation_deg))
    span = float(np.nanmax(h) - np.nanmin(h))
    steps = int(min(max_steps, np.ceil(span / (resolution_m * tan_e)) + 1))
    az = np.radians(sun.azimuth_deg)
    # north is up: rows grow southwards; rounded so that a due east/west/north/south sun stays on its row/column
    d_col, d_row = np.float32(round(np.sin(az), 9)), np.float32(round(-np.cos(az), 9))
    filled = np.where(finite, h, np.float32(-1e9))
    rows, cols = np.mgrid[0 : h.shape[0], 0 : h.shape[1]].astype(np.float32)
    horizon = np.full(h.shape, -np.inf, np.float32)  # highest h(q) - |q - p| tan e so far
    for k in range(1, steps + 1):
        q = cv2.remap(filled, cols + k * d_col, rows + k * d_row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=-1e9)
        np.maximum(horizon, q - np.float32(k * resolution_m * tan_e), out=horizon)
    return ((horizon > h) & finite).astype(np.float32)


def illumination(dem_m: np.ndarray, resolution_m: float, sun: Sun, *, skylight: float,
                 shadow=None) -> np.ndarray:
    """Relative radiance factor of every node (1 on flat, sunlit ground), see the module docstring.

    Parameters
    ----------
    dem_m : ndarray of float32, shape (H, W)
        Heights, metres, north-up grid.
    resolution_m : float
        Grid spacing, metres.
    sun : Sun
        The sun.
    skylight : float
        Diffuse share ``k`` of the irradiance on flat ground, ``[0, 1)``.
    shadow : ndarray, shape (H, W), optional
        Cast shadow (:func:`cast_shadow`); None: computed here.

    Returns
    -------
    ndarray of float32, shape (H, W)
        ``(k + (1 - k) max(cos i, 0) (1 - s)) / (k + (1 - k) cos z)``; 1 where the DEM has no data.
    """
    h = np.asarray(dem_m, np.float32)
    finite = np.isfinite(h)
    hf = np.where(finite, h, np.nanmean(h) if finite.any() else 0.0)
    dh_drow, dh_dcol = np.gradient(hf.astype(np.float64), resolution_m)
    dz_de, dz_dn = dh_dcol, -dh_drow  # east and north slopes
    z = np.radians(90.0 - sun.elevation_deg)
    az = np.radians(sun.azimuth_deg)
    sun_vec = np.array([np.sin(z) * np.sin(az), np.sin(z) * np.cos(az), np.cos(z)])  # east, north, up
    norm = np.sqrt(1.0 + dz_de**2 + dz_dn**2)
    cos_i = (-dz_de * sun_vec[0] - dz_dn * sun_vec[1] + sun_vec[2]) / norm
    s = cast_shadow(h, resolution_m, sun) if shadow is None else shadow
    direct = np.clip(cos_i, 0.0, None) * (1.0 - s)
    out = (skylight + (1.0 - skylight) * direct) / (skylight + (1.0 - skylight) * np.cos(z))
    return np.where(finite, out, 1.0).astype(np.float32)


def terrain_light_on_grid(dem_m, dem_transform: Affine, shape, transform: Affine, sun: Sun, *,
                          skylight: float):
    """Illumination (:func:`illumination`) and cast shadow of a DEM, resampled onto another north-up grid.

    Parameters
    ----------
    dem_m : ndarray of float32, shape (H, W)
        Heights, metres.
    dem_transform : affine.Affine
        Its pixel-corner affine (same CRS as ``transform``).
    shape : (int, int)
        Target grid rows and columns.
    transform : affine.Affine
        Target pixel-corner affine.
    sun : Sun
        The sun.
    skylight : float
        Diffuse share of the irradiance.

    Returns
    -------
    light, shadow : ndarray of float32, shape ``shape``
        Radiance factor (1 outside the DEM) and cast shadow (0 outside), bilinear.
    """
    res = abs(dem_transform.a)
    shadow = cast_shadow(dem_m, res, sun)
    light = illumination(dem_m, res, sun, skylight=skylight, shadow=shadow)
    return (resample_to_grid(light, dem_transform, shape, transform, fill=1.0),
            resample_to_grid(shadow, dem_transform, shape, transform, fill=0.0))


def resample_to_grid(values, from_transform: Affine, shape, transform: Affine, *, fill: float,
                     rows: slice | None = None) -> np.ndarray:
    """Bilinear resampling of a north-up raster onto another north-up grid of the same CRS.

    Parameters
    ----------
    values : ndarray of float32, shape (H, W)
        Source raster.
    from_transform : affine.Affine
        Its pixel-corner affine.
    shape : (int, int)
        Target rows and columns.
    transform : affine.Affine
        Target pixel-corner affine.
    fill : float
        Value outside the source.
    rows : slice, optional
        Only these target rows (``start:stop``, step 1): the same values as those rows of the
        whole result, without a whole-grid array.

    Returns
    -------
    ndarray of float32, shape ``shape`` (``(len(rows), shape[1])`` with ``rows``)
    """
    r_all = np.arange(shape[0], dtype=np.float64)
    cols = np.arange(shape[1], dtype=np.float64)
    dc = ((transform.c + (cols + 0.5) * transform.a - from_transform.c) / from_transform.a - 0.5).astype(np.float32)
    dr = ((transform.f + (r_all + 0.5) * transform.e - from_transform.f) / from_transform.e - 0.5).astype(np.float32)
    src = np.asarray(values, np.float32)
    first, stop = (0, shape[0]) if rows is None else rows.indices(shape[0])[:2]
    out = np.empty((max(0, stop - first), shape[1]), dtype=np.float32)
    step = max(1, _STRIP_PIXELS // max(1, shape[1]))
    for r0 in range(first, stop, step):  # pixel by pixel: no whole-grid maps
        r1 = min(r0 + step, stop)
        map_c = np.broadcast_to(dc[None, :], (r1 - r0, shape[1])).copy()
        map_r = np.broadcast_to(dr[r0:r1, None], (r1 - r0, shape[1])).copy()
        out[r0 - first:r1 - first] = cv2.remap(src, map_c, map_r, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                               borderValue=float(fill))
    return out
