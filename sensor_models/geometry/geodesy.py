"""WGS84 geodetic <-> Earth-centred Earth-fixed (ITRF) conversions, vectorized.

The ellipsoid is WGS84 (a = 6 378 137 m, f = 1/298.257223563). ITRF and WGS84 (G1762 and
later) agree at the centimetre level, which is below anything this toolkit resolves.

References
----------
.. [1] H. Vermeille, "Direct transformation from geocentric coordinates to geodetic
   coordinates", Journal of Geodesy 76, 451-454 (2002). Closed form, exact outside the
   evolute (a few hundred km around the Earth's centre).
"""

from __future__ import annotations

import numpy as np

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

__all__ = [
    "WGS84_A_M",
    "WGS84_B_M",
    "WGS84_E2",
    "WGS84_F",
    "degrees_per_metre",
    "ecef_to_geodetic",
    "enu_basis",
    "geodetic_to_ecef",
]


def geodetic_to_ecef(lon_deg, lat_deg, h_m):
    """Geodetic coordinates to ECEF (ITRF) Cartesian coordinates.

    Parameters
    ----------
    lon_deg, lat_deg : array_like
        Longitude and geodetic latitude in degrees.
    h_m : array_like
        Height above the WGS84 ellipsoid in metres.

    Returns
    -------
    xyz_m : ndarray, shape (..., 3)
        ``X = (N + h) cos(lat) cos(lon)``, ``Y = (N + h) cos(lat) sin(lon)``,
        ``Z = (N (1 - e^2) + h) sin(lat)`` with ``N = a / sqrt(1 - e^2 sin^2(lat))``.
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    h = np.asarray(h_m, dtype=np.float64)
    sin_lat = np.sin(lat)
    cos_lat = np.cos(lat)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
    x = (n + h) * cos_lat * np.cos(lon)
    y = (n + h) * cos_lat * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(xyz_m):
    """ECEF (ITRF) Cartesian coordinates to geodetic coordinates (Vermeille 2002, exact).

    Parameters
    ----------
    xyz_m : array_like, shape (..., 3)
        Cartesian coordinates in metres.

    Returns
    -------
    lon_deg, lat_deg, h_m : ndarray, shape (...)
        Longitude and geodetic latitude in degrees, ellipsoidal height in metres.
    """
    xyz = np.asarray(xyz_m, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    a2 = WGS84_A_M * WGS84_A_M
    e4 = WGS84_E2 * WGS84_E2
    rho2 = x * x + y * y
    p = rho2 / a2
    q = (1.0 - WGS84_E2) / a2 * z * z
    r = (p + q - e4) / 6.0
    s = e4 * p * q / (4.0 * r * r * r)
    t = np.cbrt(1.0 + s + np.sqrt(s * (2.0 + s)))
    u = r * (1.0 + t + 1.0 / t)
    v = np.sqrt(u * u + e4 * q)
    w = WGS84_E2 * (u + v - q) / (2.0 * v)
    k = np.sqrt(u + v + w * w) - w
    d = k * np.sqrt(rho2) / (k + WGS84_E2)
    dz = np.sqrt(d * d + z * z)
    lat = 2.0 * np.arctan2(z, d + dz)
    h = (k + WGS84_E2 - 1.0) / k * dz
    lon = np.arctan2(y, x)
    return np.degrees(lon), np.degrees(lat), h


def enu_basis(lon_deg, lat_deg):
    """East, north and up unit vectors in ECEF at geodetic positions.

    Parameters
    ----------
    lon_deg, lat_deg : array_like, shape (...)
        WGS84 geodetic longitude and latitude, degrees (broadcast together).

    Returns
    -------
    east, north, up : ndarray, shape (..., 3)
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    sl, cl = np.sin(lon), np.cos(lon)
    sp, cp = np.sin(lat), np.cos(lat)
    zero = np.zeros_like(sl * sp)
    east = np.stack([-sl + zero, cl + zero, zero], axis=-1)
    north = np.stack([-sp * cl, -sp * sl, cp + zero], axis=-1)
    up = np.stack([cp * cl, cp * sl, sp + zero], axis=-1)
    return east, north, up


def degrees_per_metre(lat_deg):
    """Degrees of longitude and latitude per metre east and north at ``lat_deg`` (WGS84).

    From the ellipsoid's radii of curvature: the prime vertical ``N = a / w`` (east, times
    ``cos lat``) and the meridian ``M = a (1 - e^2) / w^3`` (north), ``w = sqrt(1 - e^2 sin^2 lat)``.

    Parameters
    ----------
    lat_deg : array_like
        Geodetic latitude, degrees.

    Returns
    -------
    dlon_per_m, dlat_per_m : ndarray, shape of ``lat_deg``
        Degrees per metre.
    """
    phi = np.radians(np.asarray(lat_deg, dtype=np.float64))
    w = np.sqrt(1.0 - WGS84_E2 * np.sin(phi) ** 2)
    meridian = WGS84_A_M * (1.0 - WGS84_E2) / w**3
    normal = WGS84_A_M / w
    return np.degrees(1.0 / (normal * np.cos(phi))), np.degrees(1.0 / meridian)

