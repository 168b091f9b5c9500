"""Honest parameter covariance: the variance-factor floor and the reference DOM's common error.

Two corrections to the least-squares covariance ``C = sigma0^2 (J^T W J)^-1``
(:mod:`calibrate.lsq`) of a GCP calibration (:func:`calibrate.absolute.calibrate_model`):

1. **Floor of the variance factor.** Each step's block is scaled by ``max(1, sigma0^2)``
   instead of ``sigma0^2`` (:func:`floor_factor`). A variance factor below 1 means that the
   GCPs scatter less than their stated ``sigma_px`` about the fit, which on real imagery
   happens when part of their error is common to all of them (the reference DOM's geolocation
   bias, its smooth error field): the exterior absorbs it, so the residuals never show it, but
   it still moves the parameters. The a-priori sigmas then stand; a factor above 1 still
   inflates the covariance. A GCP table that states no ``sigma_px`` (all at the default 1:
   unit weights, the scale left to the variance factor, :mod:`gcpmatch.gcps`) keeps
   ``sigma0^2`` (``CalibrationOptions.covariance_floor``).

2. **The reference's common ground shift.** Every GCP takes its ground coordinates from the
   same reference DOM, whose geolocation error is, to first order, one shift
   ``d = (east, north)`` metres shared by all points, with covariance
   ``Sigma_d = diag(sigma_e^2, sigma_n^2)`` (the DOM's stated accuracy,
   :func:`sensor_models.maps.dom_inputs.reference_accuracy`). Observation equations
   ``l_i = f_i(x, X_i + d)`` linearize to ``dl = J dx + A d`` with ``A_i = d(row, col) /
   d(east, north)`` at GCP ``i`` (pixels per metre); the weighted least-squares estimate
   ``dx = (J^T W J)^-1 J^T W (dl - A d)`` then moves by ``-G d`` with::

       G = (J^T W J)^-1 J^T W A,        Cov_ref = G Sigma_d G^T

   (the propagation of a systematic error through a least-squares adjustment, Mikhail and
   Ackermann 1976, ch. 5; Foerstner and Wrobel 2016, section 4.2.6). ``J`` is the image
   Jacobian of the parameters that absorb a common shift: the installation angles when they
   are estimated (a shift of every ground point is a rotation of the camera to first order; the
   interior, fitted in the frame the exterior fixes, and the attitude correction, whose mean is
   held by the installation, do not take it), otherwise every estimated parameter. ``W`` are
   the final weights (prior weight times robust weight). ``A`` comes from projecting each GCP's
   ground point shifted east and north (:func:`sensor_models.imaging.ground_shift.ground_shift_jacobian`).
   ``Cov_ref`` is added to the covariance; sigmas and correlations follow.

References
----------
E. M. Mikhail and F. Ackermann, *Observations and Least Squares*, IEP (1976), ch. 5.
W. Foerstner and B. P. Wrobel, *Photogrammetric Computer Vision*, Springer (2016), ch. 4.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sensor_models.geometry.geodesy import degrees_per_metre
from sensor_models.imaging.ground_shift import ground_shift_jacobian

__all__ = ["FIELD_CUTOFF", "covariance_floor", "field_covariance", "floor_factor", "with_honest_covariance"]

#: cell pairs of the field term further apart than this many correlation lengths are left out
FIELD_CUTOFF = 5.0
_INSTALLATION = ("installation.roll", "installation.pitch", "installation.yaw")


def floor_factor(sigma0: float) -> float:
    """Factor applied to ``(J^T W J)^-1``: ``max(1, sigma0^2)`` (1 when ``sigma0`` is not finite).

    Parameters
    ----------
    sigma0 : float
        A-posteriori standard deviation of unit weight (dimensionless).

    Returns
    -------
    float
        The variance factor where it exceeds 1, else 1.
    """
    vf = float(sigma0) ** 2
    return max(1.0, vf) if np.isfinite(vf) else 1.0


def covariance_floor(steps: list, enabled: bool = True) -> dict:
    """Variance factor and factor applied of the last run of each step kind.

    Parameters
    ----------
    steps : list of dict
        :attr:`calibrate.calibration_result.CalibrationResult.steps` (``step``, ``sigma0``).
    enabled : bool
        Whether the floor was applied (else the factor applied is the variance factor).

    Returns
    -------
    dict
        Step kind -> ``{"variance_factor", "factor_applied"}`` (dimensionless).
    """
    last = {}
    for s in steps:
        last[s["step"]] = s.get("sigma0")
    out = {}
    for step, sigma0 in last.items():
        vf = float("nan") if sigma0 is None else float(sigma0) ** 2
        applied = (floor_factor(np.sqrt(vf)) if enabled else vf) if np.isfinite(vf) else 1.0
        out[step] = {"variance_factor": vf, "factor_applied": applied}
    return out


def _absorbing(names) -> list:
    exterior = [n for n in names if n in _INSTALLATION]
    return exterior or list(names)


def _point_gains(result, points, weight, groups) -> tuple[list, np.ndarray, np.ndarray]:
    """Absorbing names, per-point gains ``G_i = (J^T W J)^-1 J_i^T W_i A_i`` (n, p, 2) and point validity."""
    names = _absorbing(result.names)
    model = result.model
    pushbroom = getattr(model, "interior_layout", "") == "per_array"
    n = points["row"].size
    jac = np.full((n, 2, len(names)), np.nan)
    shift = np.full((n, 2, 2), np.nan)
    for g in groups:
        where = {"band": g.band, "array": g.ccd} if pushbroom else {"band": g.band}
        lon, lat, h = points["lon"][g.idx], points["lat"][g.idx], points["h"][g.idx]
        _r, _c, jac[g.idx] = model.image_jacobian(lon, lat, h, names=names, **where)
        shift[g.idx] = ground_shift_jacobian(model, lon, lat, h, **where)
    w = np.asarray(weight, dtype=np.float64) * np.nan_to_num(np.asarray(result.weights, dtype=np.float64))
    ok = (w > 0) & np.all(np.isfinite(jac), axis=(1, 2)) & np.all(np.isfinite(shift), axis=(1, 2))
    w = np.where(ok, w, 0.0)
    jac, shift = np.nan_to_num(jac), np.nan_to_num(shift)
    normal = np.einsum("n,nkp,nkq->pq", w, jac, jac)
    per_point = np.einsum("n,nkp,nkq->npq", w, jac, shift)
    return names, _solve_each(normal, per_point), ok


def _solve_each(normal, per_point):
    """``normal^-1 per_point[i]`` for every point (least squares when ``normal`` is singular)."""
    n, p, k = per_point.shape
    rhs = per_point.transpose(1, 0, 2).reshape(p, n * k)
    return np.linalg.lstsq(normal, rhs, rcond=None)[0].reshape(p, n, k).transpose(1, 0, 2)


def field_covariance(point_gains, lon, lat, rms_m, length_m) -> np.ndarray:
    """Covariance of the parameters from a smooth reference error field (per axis, Gaussian correlation).

    Points closer than ``length_m / 8`` are merged into one cell (their gains summed; the
    correlation between them is above 0.99) and pairs of cells further apart than
    ``FIELD_CUTOFF`` lengths are left out (correlation below 4e-6), so memory and time grow with
    the number of occupied cells and their neighbours, not with the square of the GCP count.

    Parameters
    ----------
    point_gains : ndarray, shape (n, p, 2)
        ``G_i`` of every point (parameter units per metre east and north; 0 for unused points).
    lon, lat : ndarray, shape (n,)
        The points, WGS84 degrees.
    rms_m : float
        Field rms per axis, metres.
    length_m : float
        Correlation length ``l`` of ``rho(r) = exp(-r^2 / (2 l^2))``, metres.

    Returns
    -------
    ndarray, shape (p, p)
        ``sum_ij G_i K_ij G_j^T`` with ``K_ij = rms^2 rho(|X_i - X_j|) I``.
    """
    from scipy.spatial import cKDTree

    dlon, dlat = degrees_per_metre(np.mean(lat))
    xy = np.stack([(lon - np.mean(lon)) / dlon, (lat - np.mean(lat)) / dlat], axis=1)
    cell = np.floor(xy / (length_m / 8.0)).astype(np.int64)
    _keys, inverse = np.unique(cell, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    m = int(inverse.max()) + 1
    gains = np.zeros((m,) + point_gains.shape[1:])
    np.add.at(gains, inverse, point_gains)
    centre = np.zeros((m, 2))
    np.add.at(centre, inverse, xy)
    centre /= np.bincount(inverse, minlength=m)[:, None]
    pairs = cKDTree(centre).sparse_distance_matrix(cKDTree(centre), FIELD_CUTOFF * length_m, output_type="coo_matrix")
    off = pairs.row != pairs.col  # zero distances are not stored: the diagonal is added below
    rho = np.exp(-0.5 * (pairs.data[off] / length_m) ** 2)
    out = np.zeros((gains.shape[1], gains.shape[1]))
    for a in range(2):
        h = gains[:, :, a]
        out += h.T @ h + np.einsum("k,kp,kq->pq", rho, h[pairs.row[off]], h[pairs.col[off]])
    return rms_m**2 * out


def _scaling_text(enabled, sigma_m) -> str:
    text = ("covariance = max(1, sigma0^2) (J^T W J)^-1 per step (a variance factor below 1 does not shrink it)"
            if enabled else "covariance = sigma0^2 (J^T W J)^-1 per step (the table states no sigma_px)")
    return text + (" + G Sigma_ref G^T (the reference's common ground shift)" if sigma_m is not None else "")


def _correlation(covariance):
    sd = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(sd, sd)
    np.fill_diagonal(correlation, 1.0)
    return correlation


def with_honest_covariance(result, points, weight, groups, options):
    """The result with the floor recorded and the reference term added to its covariance.

    Parameters
    ----------
    result : calibrate.calibration_result.CalibrationResult
        A finished calibration (its covariance already floored per step by
        ``calibrate.result_assembly._block_covariance``).
    points : dict of ndarray
        ``lon, lat, h`` (degrees, metres) of the fitted GCPs, shape (N,) each, result order.
    weight : ndarray, shape (N,)
        Prior weights of the GCPs (1 / px^2).
    groups : list
        Point groups (``band``, ``ccd``, ``idx``) of the calibration.
    options : calibrate.config.CalibrationOptions
        ``reference_sigma_m`` (None, or east and north metres) and ``reference_source``.

    Returns
    -------
    CalibrationResult
        ``uncertainty`` holds ``covariance_factor`` (last step), ``covariance_floor`` (per step
        kind), ``reference_accuracy`` (``east_m, north_m, source``; metres) and
        ``reference_sigma`` (name -> the term's standard deviation, parameter units); the
        covariance and correlation include ``Cov_ref`` when a reference accuracy is given and
        the covariance exists.
    """
    enabled = options.covariance_floor is not False
    floor = covariance_floor(result.steps, enabled)
    last_step = result.steps[-1]["step"] if result.steps else None
    info = {"covariance_scaling": _scaling_text(enabled, options.reference_sigma_m),
            "covariance_factor": floor[last_step]["factor_applied"] if last_step else None,
            "covariance_floor": floor,
            "reference_accuracy": {"east_m": None, "north_m": None,
                                   "source": "none: no reference accuracy given, no reference term"},
            "reference_sigma": {}}
    sigma_m = options.reference_sigma_m
    if sigma_m is not None:
        info["reference_accuracy"] = {"east_m": float(sigma_m[0]), "north_m": float(sigma_m[1]),
                                      "source": options.reference_source or "option"}
    covariance = result.covariance
    if sigma_m is None or covariance is None or not result.names or max(sigma_m) <= 0.0:
        return replace(result, uncertainty=info)
    names, point_gains, _ok = _point_gains(result, points, weight, groups)
    gain = point_gains.sum(axis=0)
    common = np.square(np.asarray(sigma_m, dtype=np.float64))
    field = options.reference_field_m
    if field is not None:  # the stated accuracy is the total: the field's share is not common
        common = np.clip(common - field[0] ** 2, 0.0, None)
    term_small = gain @ np.diag(common) @ gain.T
    if field is not None and field[0] > 0.0:
        term_small = term_small + field_covariance(point_gains, points["lon"], points["lat"], *field)
        info["reference_field"] = {"rms_m": float(field[0]), "length_m": float(field[1])}
    pos = [result.names.index(n) for n in names]
    term = np.zeros_like(covariance)
    term[np.ix_(pos, pos)] = term_small
    info["reference_sigma"] = {n: float(np.sqrt(max(term_small[j, j], 0.0))) for j, n in enumerate(names)}
    info["reference_gain_per_m"] = {n: [float(gain[j, 0]), float(gain[j, 1])] for j, n in enumerate(names)}
    covariance = covariance + term
    return replace(result, covariance=covariance, correlation=_correlation(covariance), uncertainty=info)
