"""Intersection of ITRF rays with surfaces of constant geodetic height above the WGS84 ellipsoid.

:func:`intersect_ellipsoid` starts from the near root of the ray with the ellipsoid of semi-axes
``(a + h, b + h)`` (:func:`ellipsoid_quadratic`, :func:`first_ray_root`) and makes it exact by
Newton steps on the true geodetic height (:func:`newton_on_height`). The DEM intersection
(:mod:`sensor_models.terrain.los_intersect`) brackets its rays with the same helpers.
"""

from __future__ import annotations

import numpy as np

from sensor_models.errors import InputError
from sensor_models.geometry.geodesy import WGS84_A_M, WGS84_B_M, ecef_to_geodetic

__all__ = ["as_rays", "ellipsoid_quadratic", "first_ray_root", "intersect_ellipsoid", "newton_on_height"]


#: Tolerance on the geodetic height of :func:`intersect_ellipsoid`, metres.
_ELLIPSOID_TOL_M = 1e-6


def as_rays(origin_m, direction, name_o="origin_m", name_d="direction"):
    """Validate rays: (N, 3) float64 origins and unit directions, plus the batch shape."""
    o = np.asarray(origin_m, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if o.shape[-1:] != (3,) or d.shape[-1:] != (3,):
        raise InputError(
            f"{name_o} and {name_d} need a last axis of length 3, got {o.shape} and {d.shape}"
        )
    shape = np.broadcast_shapes(o.shape, d.shape)[:-1]
    o = np.broadcast_to(o, shape + (3,)).reshape(-1, 3)
    d = np.broadcast_to(d, shape + (3,)).reshape(-1, 3)
    for label, a in ((name_o, o), (name_d, d)):
        if not np.all(np.isfinite(a)):
            raise InputError(f"{label} holds NaN or infinite values")
    norm = np.sqrt(np.einsum("ij,ij->i", d, d))
    if np.any(norm == 0.0):
        raise InputError(f"{name_d} holds zero-length vectors")
    return np.ascontiguousarray(o), d / norm[:, None], shape


def ellipsoid_quadratic(o, d, height_m):
    """Quadratic ``A t^2 + 2 B t + C = 0`` of the ray with the (a + h, b + h) ellipsoid."""
    ax = WGS84_A_M + height_m
    bz = WGS84_B_M + height_m
    ox, oy, oz = o[:, 0] / ax, o[:, 1] / ax, o[:, 2] / bz
    dx, dy, dz = d[:, 0] / ax, d[:, 1] / ax, d[:, 2] / bz
    a_ = dx * dx + dy * dy + dz * dz
    b_ = ox * dx + oy * dy + oz * dz
    c_ = ox * ox + oy * oy + oz * oz - 1.0
    return a_, b_, c_, b_ * b_ - a_ * c_


def first_ray_root(a_, b_, c_, disc):
    """Smallest root ``t >= 0`` (near root from outside, exit from inside); NaN if none."""
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -(b_ + np.copysign(sq, b_))
        t1 = q / a_
        t2 = c_ / q
        near = np.fmin(t1, t2)
        far = np.fmax(t1, t2)
        t = np.where(c_ > 0.0, np.where(near >= 0.0, near, np.nan), far)
    return np.where(disc >= 0.0, t, np.nan)


def _up(lon_deg, lat_deg):
    lon = np.radians(lon_deg)
    lat = np.radians(lat_deg)
    cl = np.cos(lat)
    return np.stack([cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)], axis=-1)


def intersect_ellipsoid(origin_m, direction, height_m, *, max_iter: int = 10) -> np.ndarray:
    """Intersect rays with the surface of constant geodetic height ``height_m`` (WGS84).

    The start is the near root of the ray with the ellipsoid of semi-axes ``(a + h, b + h)``;
    Newton steps along the ray on the true geodetic height then run until
    ``|h(p) - height_m| < 1e-6 m``. The gradient of the geodetic height in ECEF is the unit
    ellipsoid normal ``n`` at the foot point, so each step is ``t -= (h(p) - height_m) / (n . d)``.

    Parameters
    ----------
    origin_m : array_like, shape (..., 3)
        Ray origins in ITRF metres (e.g. satellite positions).
    direction : array_like, shape (..., 3)
        Ray directions in ITRF (normalised here).
    height_m : float or array_like, shape (...)
        Geodetic height above the WGS84 ellipsoid of the surface to hit, per ray or scalar.
    max_iter : int
        Newton steps at most (one or two are needed except for grazing rays).

    Returns
    -------
    xyz_m : ndarray, shape (..., 3)
        ``origin + t * direction / |direction|`` with the smallest ``t >= 0`` on the surface:
        the near intersection for an origin above the surface (the exit for one below it).
        NaN for rays that miss the surface, point away from it, or graze it so closely that
        the Newton steps do not converge.

    Raises
    ------
    InputError
        On malformed shapes, non-finite inputs or zero directions.
    """
    o, d, shape = as_rays(origin_m, direction)
    h_target = np.asarray(height_m, dtype=np.float64)
    try:
        h_target = np.broadcast_to(h_target, shape).reshape(-1)
    except ValueError as err:
        raise InputError(
            f"height_m of shape {np.shape(height_m)} does not match {shape} rays"
        ) from err
    if not np.all(np.isfinite(h_target)):
        raise InputError("height_m holds NaN or infinite values")
    t = newton_on_height(o, d, h_target, first_ray_root(*ellipsoid_quadratic(o, d, h_target)),
                          max_iter=max_iter)
    xyz = o + t[:, None] * d
    return xyz.reshape(shape + (3,))


def newton_on_height(o, d, h_target, t, *, max_iter):
    """Newton steps along rays ``o + t d`` until their geodetic height is ``h_target`` to 1e-6 m.

    Parameters
    ----------
    o, d : ndarray, shape (n, 3)
        Ray origins (ITRF metres) and unit directions (:func:`as_rays`).
    h_target : ndarray, shape (n,)
        Geodetic heights to reach, metres above the WGS84 ellipsoid.
    t : ndarray, shape (n,)
        Start parameters (e.g. :func:`first_ray_root`); NaN rays stay NaN.
    max_iter : int
        Newton steps at most.

    Returns
    -------
    t : ndarray, shape (n,)
        A new array; NaN where the steps did not converge within ``max_iter``.
    """
    t = t.copy()
    todo = np.nonzero(np.isfinite(t))[0]
    for _ in range(max_iter):
        if todo.size == 0:
            break
        p = o[todo] + t[todo, None] * d[todo]
        lon, lat, h = ecef_to_geodetic(p)
        dh = h - h_target[todo]
        done = np.abs(dh) < _ELLIPSOID_TOL_M
        todo, dh, lon, lat = todo[~done], dh[~done], lon[~done], lat[~done]
        slope = np.einsum("ij,ij->i", _up(lon, lat), d[todo])
        with np.errstate(divide="ignore", invalid="ignore"):
            t[todo] -= dh / slope
        bad = ~np.isfinite(t[todo])
        t[todo[bad]] = np.nan
        todo = todo[~bad]
    if todo.size:
        p = o[todo] + t[todo, None] * d[todo]
        still = np.abs(ecef_to_geodetic(p)[2] - h_target[todo]) >= _ELLIPSOID_TOL_M
        t[todo[still]] = np.nan
    return t
