"""Virtual control points of a staring camera, and the errors of a model on them (seed 002).

Seed 002 section 2.2 (figure 1): an image-space-uniform grid of pixels projected through a
model onto the Earth; each pixel and its ground point form a *virtual control point* (VCP).
:func:`virtual_control_points` builds them (ground or deep-space views, optional image noise),
:func:`check_grid` the independent check points offset by half a grid step,
:func:`positioning_errors` scores a model on them as seed 002 table 3 (X = column, Y = row,
pixels) and :func:`pointing_difference_px` maps the body-frame pointing-angle difference of two
models (seed 002 figures 4-10). The schemes that use them are in
:mod:`calibrate.schemes.compensate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError

__all__ = ["VirtualControlPoints", "check_grid", "pointing_difference_px", "positioning_errors",
           "virtual_control_points"]


# --------------------------------------------------------------------------- VCPs
@dataclass
class VirtualControlPoints:
    """Image-space-uniform virtual control points (seed 002 section 2.2, figure 1).

    Attributes
    ----------
    row, col : ndarray, shape (N,)
        Pixel coordinates (first pixel centre 0.5), possibly with added noise.
    lon, lat, h : ndarray, shape (N,) or None
        Ground points (WGS84 degrees, metres) of the noise-free pixels; None for sky targets.
    vectors_gcrf : ndarray, shape (N, 3)
        Unit object vectors (apparent directions) of the noise-free pixels in GCRF
        (:meth:`GeoStaringModel.object_vector_gcrf`): the deep-space form.
    grid_shape : (int, int)
        Grid rows and columns before points missing the Earth were dropped.
    noise_px : float
        Standard deviation of the Gaussian noise added to ``row`` and ``col``.
    """

    row: np.ndarray
    col: np.ndarray
    lon: np.ndarray | None
    lat: np.ndarray | None
    h: np.ndarray | None
    vectors_gcrf: np.ndarray
    grid_shape: tuple
    noise_px: float = 0.0

    @property
    def n_points(self) -> int:
        """Number of points.

        Returns
        -------
        int
            ``row.size``.
        """
        return int(self.row.size)


def _grid_axis(start_px, stop_px, step_px, n, field_name):
    """Pixel indices ``start, start + step, ... <= stop`` (default stop: the last pixel)."""
    step = float(step_px)
    if not (math.isfinite(step) and step > 0.0):
        raise InputError(f"must be positive, got {step_px}", field="step_px")
    start = float(start_px)
    stop = float(n - 1) if stop_px is None else float(stop_px)
    if not (math.isfinite(start) and math.isfinite(stop)) or start < 0.0 or stop > n - 1 or stop < start:
        raise InputError(f"needs 0 <= start ({start_px}) <= stop ({stop_px}) <= {n - 1}", field=field_name)
    k = int(math.floor((stop - start) / step + 1e-9)) + 1
    if k < 2:
        raise InputError(f"a step of {step_px} px leaves fewer than 2 grid points per axis", field="step_px")
    return start + step * np.arange(k)


def virtual_control_points(model, *, step_px: float = 100.0, start_px: float = 0.0, stop_px: float | None = None,
                           height_m: float | None = 0.0, dem=None, target: str = "ground", noise_px: float = 0.0,
                           seed: int = 0) -> VirtualControlPoints:
    """Image-space-uniform grid of pixels projected through ``model`` (seed 002 section 2.2).

    The pixels with indices ``start_px, start_px + step_px, ... <= stop_px`` along both axes
    (seed 002: 0 .. 10 000 every 100) are taken at their centres (index + 0.5) and localized
    with ``model`` (the TRUE model in a simulation, a calibrated reference model in practice).

    Parameters
    ----------
    model : GeoStaringModel
    step_px, start_px, stop_px : float
        Grid in pixel indices; ``stop_px`` defaults to the last pixel of the shorter axis.
    height_m : float, optional
        Ellipsoidal height of the ground points (default 0 m) unless ``dem`` is given.
    dem : sensor_models.terrain.dem.Dem, optional
        Intersect the lines of sight with a DEM instead.
    target : {"ground", "sky"}
        ``"sky"``: deep-space views; no ground intersection, only ``vectors_gcrf``.
    noise_px : float
        Standard deviation (pixels) of Gaussian noise added to the returned ``row`` and
        ``col`` (the ground points and vectors stay those of the noise-free pixels).
    seed : int
        Seed of the noise generator.

    Returns
    -------
    VirtualControlPoints
        Grid points whose line of sight misses the Earth are dropped (``target="ground"``).
    """
    if target not in ("ground", "sky"):
        raise InputError(f"must be 'ground' or 'sky', got {target!r}", field="target")
    noise = float(noise_px)
    if not (math.isfinite(noise) and noise >= 0.0):
        raise InputError(f"must be >= 0, got {noise_px}", field="noise_px")
    n_rows, n_cols = model.image_shape
    axis = _grid_axis(start_px, stop_px, step_px, min(n_rows, n_cols), "grid")
    rr, cc = np.meshgrid(axis + 0.5, axis + 0.5, indexing="ij")
    row, col = rr.ravel(), cc.ravel()
    lon = lat = h = None
    if target == "ground":
        if dem is not None:
            lon, lat, h = model.image_to_ground(row, col, dem=dem)
        else:
            if height_m is None:
                raise InputError("give height_m or dem", field="height_m")
            lon, lat, h = model.image_to_ground(row, col, height=float(height_m))
        ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
        row, col, lon, lat, h = row[ok], col[ok], lon[ok], lat[ok], h[ok]
        if row.size < 2:
            raise InputError("fewer than 2 grid points see the Earth", field="grid")
    vectors = model.object_vector_gcrf(row, col)
    if noise > 0.0:
        rng = np.random.default_rng(seed)
        row = row + rng.normal(0.0, noise, row.size)
        col = col + rng.normal(0.0, noise, col.size)
    return VirtualControlPoints(row, col, lon, lat, h, vectors, (axis.size, axis.size), noise)


def check_grid(model, *, step_px: float = 100.0, start_px: float = 0.0, stop_px: float | None = None,
               height_m: float = 0.0) -> VirtualControlPoints:
    """Independent check points: the VCP grid offset by half a step (never used in a fit).

    Parameters
    ----------
    model : GeoStaringModel
        The TRUE model (localizes the grid).
    step_px, start_px, stop_px : float
        Grid of :func:`virtual_control_points`, pixels (shifted by ``step_px / 2``).
    height_m : float
        Ground height above the ellipsoid, metres.

    Returns
    -------
    VirtualControlPoints
        Ground check points.
    """
    n = min(model.image_shape)
    stop = float(n - 1) if stop_px is None else float(stop_px)
    return virtual_control_points(model, step_px=step_px, start_px=float(start_px) + 0.5 * float(step_px),
                                  stop_px=stop, height_m=height_m)


# --------------------------------------------------------------------------- accuracy
def positioning_errors(model, check: VirtualControlPoints) -> dict:
    """Positioning errors (seed 002 table 3) of ``model`` on true check points, pixels.

    The ground point of each check pixel (from the TRUE model) is projected by ``model``;
    ``error = projected - true pixel``; X is the column, Y the row.

    Parameters
    ----------
    model : GeoStaringModel
        Model to score.
    check : VirtualControlPoints
        Ground check points of the TRUE model.

    Returns
    -------
    dict
        ``mean_x_px, mean_y_px`` (signed), ``rms_x_px, rms_y_px``, ``total_px`` =
        ``sqrt(rms_x^2 + rms_y^2)``, ``max_px`` (largest vector length), ``n_points``, and
        the per-point arrays ``dx_px, dy_px`` (N,).
    """
    r, c = model.ground_to_image(check.lon, check.lat, check.h)
    dy, dx = r - check.row, c - check.col
    ok = np.isfinite(dx) & np.isfinite(dy)
    if not ok.any():
        return {"n_points": 0, "mean_x_px": math.nan, "mean_y_px": math.nan, "rms_x_px": math.nan,
                "rms_y_px": math.nan, "total_px": math.nan, "max_px": math.nan, "dx_px": dx, "dy_px": dy}
    rx, ry = float(np.sqrt(np.mean(dx[ok] ** 2))), float(np.sqrt(np.mean(dy[ok] ** 2)))
    return {
        "n_points": int(ok.sum()),
        "mean_x_px": float(np.mean(dx[ok])),
        "mean_y_px": float(np.mean(dy[ok])),
        "rms_x_px": rx,
        "rms_y_px": ry,
        "total_px": float(math.hypot(rx, ry)),
        "max_px": float(np.max(np.hypot(dx[ok], dy[ok]))),
        "dx_px": dx,
        "dy_px": dy,
    }


def pointing_difference_px(model, truth, row, col):
    """Body-frame pointing-angle difference ``model - truth`` (seed 002 figures 4-10), pixels.

    For each pixel the line of sight in the body frame ``R_inst R_ref (tan psi_x, tan psi_y,
    1)`` gives the two pointing angles ``atan(b_x / b_z)``, ``atan(b_y / b_z)``; the
    differences are divided by the truth's IFOV (one pixel = ``truth.ifov_rad`` radians).

    Parameters
    ----------
    model, truth : GeoStaringModel
        Compared models.
    row, col : array_like, shape (N,)
        Pixels, first pixel's centre at 0.5.

    Returns
    -------
    dx_px, dy_px : ndarray, shape (N,)
    """
    row = np.asarray(row, dtype=np.float64).reshape(-1)
    col = np.asarray(col, dtype=np.float64).reshape(-1)

    def angles(m):
        b = m.look_cam(row, col) @ m.generalized_installation.T
        return np.arctan2(b[:, 0], b[:, 2]), np.arctan2(b[:, 1], b[:, 2])

    mx, my = angles(model)
    tx, ty = angles(truth)
    return (mx - tx) / truth.ifov_rad, (my - ty) / truth.ifov_rad
