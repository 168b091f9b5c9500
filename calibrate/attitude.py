"""Time-varying attitude in the calibration: candidate bases, selection by BIC, ridge, spectrum.

The push-broom model carries an optional body-frame attitude correction ``delta(t)``
(:mod:`sensor_models.models.attitude_correction`): a drift (rate, optionally quadratic) or a cubic
B-spline in time. :func:`calibrate.absolute.calibrate_model` first calibrates the static model,
then (``CalibrationOptions.attitude`` other than ``"static"``) chooses the basis here and solves
it with the exterior and interior (docs/attitude.md).

Selection. Around the static solution the image residuals ``r_i`` (2,) of GCP ``i`` observed at
time ``t_i`` respond linearly to the angles: ``r_i ~ J_i delta(t_i)``, ``J_i = d(row, col)/d
delta`` (2, 3) (:meth:`PushbroomModel.attitude_angle_jacobian`). For a candidate basis
``phi_k(t)`` (plus a constant, which is the installation's freedom) the weighted least-squares
fit of ``sum_k c_k phi_k(t_i) J_i`` to ``r_i`` gives a residual sum ``RSS`` and effective number
of parameters ``p`` (trace of the hat matrix). The spline candidate is a P-spline: knots as
dense as the observations' times, a difference penalty whose weight is chosen by generalized
cross-validation (:mod:`calibrate.pspline`), so its ``p`` is the effective degrees of freedom
the data support. Among static, drift and P-spline the candidate of least

.. math::  BIC = m \\ln(RSS / m) + p \\ln m

over ``m = 2 n`` residuals (Schwarz 1978) is chosen. The static model is a candidate, so a scene
without time-varying attitude error keeps the static solution.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from calibrate.pspline import MAX_PSPLINE_SEGMENTS, N_FOLDS, difference_penalty, pspline_segments, smooth, time_folds
from sensor_models.models.attitude_correction import AXES, AttitudeCorrection

__all__ = [
    "MAX_SEGMENTS",
    "REGULARIZATION_SIGMA_RAD",
    "basis_columns",
    "candidate_corrections",
    "choose_candidate",
    "correction_band",
    "held_out_masks",
    "jitter_spectrum",
    "ridge_solution",
    "ridge_weights",
    "select_correction",
    "selection_info",
    "spline_penalty",
]

#: standard deviation of the ridge pseudo-observation ``c = 0`` of every correction coefficient,
#: radians: far above the micro-radian corrections, it only pins the spline's constant mode
#: (the installation's)
REGULARIZATION_SIGMA_RAD = (1e-4, 1e-4, 1e-4)
#: most P-spline segments for GCPs alone (:data:`calibrate.pspline.MAX_PSPLINE_SEGMENTS`)
MAX_SEGMENTS = MAX_PSPLINE_SEGMENTS
#: level of the test that keeps a time-varying correction over the static model
#: (:func:`choose_candidate`): the rate of scenes without time-varying error that get one
SIGNIFICANCE = 1e-3


def candidate_corrections(mode: str, t0_s: float, t1_s: float, *, n_points: int, n_lines: float,
                          seconds=None, image_span_s=None, min_span_fraction: float = 0.5,
                          max_segments: int = MAX_SEGMENTS, support_s=None):
    """The bases tried by ``--attitude MODE``.

    Parameters
    ----------
    mode : {"static", "drift", "spline", "auto"}
        ``drift``: static, rate, rate + quadratic; ``spline``: static and the P-spline (dense
        cubic B-splines whose smoothing :func:`select_correction` chooses,
        :mod:`calibrate.pspline`); ``auto``: all of them.
    t0_s, t1_s : float
        Time span of the basis, seconds since the model's epoch.
    n_points : int
        Observations used (no time-varying candidate with fewer than 2).
    n_lines : float
        Image lines in the span (bounds the segment length).
    seconds : ndarray, shape (N,), optional
        Times of the observations used: their distinct times set the P-spline's knot spacing
        (:func:`calibrate.pspline.pspline_segments`), and time-varying candidates need them over
        at least ``min_span_fraction`` of ``image_span_s`` (seconds). Without them the knots
        are ``n_points`` distinct times' worth, spread evenly.
    image_span_s : float, optional
        Duration of the image lines, seconds.
    min_span_fraction : float
        See ``seconds``.
    max_segments : int
        Most P-spline segments (:data:`MAX_SEGMENTS`; the band parallax passes its own).
    support_s : (float, float), optional
        First and last observation time, seconds. When given, the spline spans it and holds
        its end values beyond it (``outside="hold"``, :mod:`sensor_models.models.attitude_correction`):
        lines before the first or after the last observation are not extrapolated.

    Returns
    -------
    list of AttitudeCorrection or None
        None is the static model.
    """
    out = [None]
    if n_points < 2:
        return out
    if seconds is not None and image_span_s:
        if np.ptp(seconds) < min_span_fraction * image_span_s:
            return out  # GCPs on a few lines do not observe a function of time
    if mode in ("drift", "auto"):
        out += [AttitudeCorrection("drift", t0_s, t1_s, d) for d in (1, 2)]
    if mode in ("spline", "auto"):
        s0, s1, outside = (t0_s, t1_s, "continue") if support_s is None else (*support_s, "hold")
        if s1 > s0:
            lines = n_lines * (s1 - s0) / (t1_s - t0_s)
            times = np.linspace(s0, s1, int(n_points)) if seconds is None else seconds
            n_seg = pspline_segments(times, s0, s1, n_lines=lines, max_segments=max_segments)
            out.append(AttitudeCorrection("spline", s0, s1, n_seg, outside=outside))
    return out


def _sparse_basis(correction, seconds):
    """Non-zero basis functions ``(index (N, M), value (N, M))`` of a candidate, with a constant.

    Column 0 of a drift (and of the static candidate) is the constant (the installation's
    freedom); a spline's basis sums to one and holds the constant itself.
    """
    n = seconds.size
    if correction is None:
        return np.zeros((n, 1), dtype=np.intp), np.ones((n, 1))
    index, value, _ = correction.basis_sparse(seconds)
    if correction.kind == "drift":
        index = np.concatenate([np.zeros((n, 1), dtype=np.intp), index + 1], axis=1)
        value = np.concatenate([np.ones((n, 1)), value], axis=1)
    return index, value


def basis_columns(correction, seconds):
    """Non-zero basis columns of a candidate at ``seconds``, with its constant (see ``_sparse_basis``).

    Parameters
    ----------
    correction : AttitudeCorrection or None
        A candidate of :func:`candidate_corrections` (None: the static model, a constant).
    seconds : ndarray, shape (N,)
        Seconds since the model's epoch.

    Returns
    -------
    index : ndarray of intp, shape (N, M)
        Column per axis (``0 .. K - 1``, ``K`` from :func:`ridge_weights`).
    value : ndarray, shape (N, M)
    k : int
        Columns per axis.
    """
    index, value = _sparse_basis(correction, seconds)
    return index, value, _n_columns(correction)


def ridge_weights(correction, k, *, yaw_sigma_rad=None):
    """Diagonal ridge weights (3 K,), 1/rad^2, of a candidate's columns, axis-major.

    Parameters
    ----------
    correction : AttitudeCorrection or None
    k : int
        Columns per axis (:func:`basis_columns`).
    yaw_sigma_rad : float, optional
        Prior standard deviation of the yaw coefficients (``CalibrationOptions.attitude_yaw_sigma_urad``).

    Returns
    -------
    ndarray, shape (3 K,)
    """
    return _ridge(correction, k, yaw_sigma_rad)


def ridge_solution(normal, rhs, ridge):
    """Ridge least squares: coefficients, ``(N + R)^-1`` and the hat matrix's trace.

    Parameters
    ----------
    normal : ndarray, shape (P, P)
        Weighted normal matrix ``X^T W X``.
    rhs : ndarray, shape (P,)
        ``X^T W r``.
    ridge : ndarray, shape (P,)
        Diagonal ridge weights (0: free).

    Returns
    -------
    coef : ndarray, shape (P,)
    inverse : ndarray, shape (P, P)
    dof : float
        Effective number of parameters.
    """
    return _ridge_solution(normal, rhs, ridge)


def spline_penalty(correction, k, n_columns):
    """The P-spline's difference penalty ``S`` (n_columns, n_columns), per axis; None if not a spline.

    Block ``a`` (columns ``a K .. a K + K - 1``, ``K = k``) is ``D^T D`` of
    :func:`calibrate.pspline.difference_penalty`; further columns (nuisance) are unpenalized.

    Parameters
    ----------
    correction : AttitudeCorrection or None
    k : int
        Columns per axis.
    n_columns : int
        Columns of the whole design (``>= 3 k``).

    Returns
    -------
    ndarray, shape (n_columns, n_columns) or None
    """
    if correction is None or correction.kind != "spline":
        return None
    block = difference_penalty(k)
    out = np.zeros((n_columns, n_columns))
    for a in range(3):
        out[a * k:(a + 1) * k, a * k:(a + 1) * k] = block
    return out


def held_out_masks(correction, seconds):
    """Held-out observations of each fold of the P-spline's blocked cross-validation.

    Blocks of twice the knot spacing (:func:`calibrate.pspline.time_folds`): about the mean
    spacing of the observations' distinct lines, so that points of one image line (a row of
    matched GCPs) leave together and are predicted from the lines around them.

    Parameters
    ----------
    correction : AttitudeCorrection
        The P-spline candidate.
    seconds : ndarray, shape (N,)
        Time of each observation.

    Returns
    -------
    list of ndarray of bool, shape (N,)
        One mask per fold with held-out observations.
    """
    return _held_out(correction, seconds)


def _held_out(correction, seconds):
    fold = time_folds(seconds, correction.t0_s, 2.0 * correction.knot_spacing_s, N_FOLDS)
    return [fold == k for k in range(N_FOLDS) if np.any(fold == k)]


def _n_columns(correction):
    """Coefficients per axis of a candidate in the selection (a drift adds its constant)."""
    return 1 if correction is None else correction.n_coefficients + (correction.kind == "drift")


def _normal_equations(jac_delta, seconds, residuals, weights, correction):
    """``X^T W X`` (3K, 3K) and ``X^T W r`` (3K,), axis-major, from per-point 3x3 blocks.

    Column ``(a, j)`` of point ``i`` is ``phi_j(t_i) J_i[:, a]``, so the normal matrix is
    ``sum_i phi_j phi_l (J_i^T W_i J_i)[a, b]``: it is accumulated with ``bincount`` over the
    few basis functions that do not vanish at each point (4 for a spline).
    """
    k = _n_columns(correction)
    index, value = _sparse_basis(correction, seconds)
    block = np.einsum("n,nia,nib->nab", weights, jac_delta, jac_delta)  # (N, 3, 3)
    grad = np.einsum("n,nia,ni->na", weights, jac_delta, residuals)  # (N, 3)
    normal = np.zeros((3, k, 3, k))
    rhs = np.zeros((3, k))
    m = index.shape[1]
    pairs = [(a, b) for a in range(3) for b in range(a, 3)]  # the 3x3 blocks are symmetric
    for p in range(m):
        for a in range(3):
            rhs[a] += np.bincount(index[:, p], value[:, p] * grad[:, a], minlength=k)
        for q in range(p, m):  # the (q, p) term is the (p, q) term transposed in (j, l)
            flat = index[:, p] * k + index[:, q]
            vv = value[:, p] * value[:, q]
            for a, b in pairs:
                t = np.bincount(flat, vv * block[:, a, b], minlength=k * k).reshape(k, k)
                normal[a, :, b, :] += t if q == p else t + t.T
    for a, b in pairs:
        if a != b:
            normal[b, :, a, :] = normal[a, :, b, :]  # sum_i phi_j phi_l B_ab is symmetric in (j, l)
    return normal.reshape(3 * k, 3 * k), rhs.reshape(-1), k


def _ridge(correction, k, yaw_sigma_rad=None):
    """Diagonal ridge weights of a candidate's columns (none on the constants of a drift)."""
    sigma = np.asarray(REGULARIZATION_SIGMA_RAD, dtype=float).copy()
    if yaw_sigma_rad is not None:
        sigma[2] = float(yaw_sigma_rad)
    ridge = np.repeat(1.0 / sigma[:, None] ** 2, k, axis=1)
    if correction is None or correction.kind == "drift":
        ridge[:, 0] = 0.0
    return ridge.reshape(-1)


def _ridge_solution(normal, rhs, ridge):
    """Coefficients, ``(N + R)^-1`` and the hat matrix's trace of a ridge least squares."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(normal) + ridge, 1e-300))
    scaled = d[:, None] * (normal + np.diag(ridge)) * d[None, :]
    try:  # positive definite with the ridge: Cholesky, a fraction of an eigendecomposition's cost
        inv = scipy.linalg.cho_solve(scipy.linalg.cho_factor(scaled), np.eye(scaled.shape[0]))
    except np.linalg.LinAlgError:  # numerically singular: the clipped eigendecomposition
        val, vec = np.linalg.eigh(scaled)
        inv = (vec / np.maximum(val, val.max() * 1e-14)) @ vec.T
    coef = d * (inv @ (d * rhs))
    dof = float(np.sum(inv * (d[:, None] * normal * d[None, :])))
    return coef, d[:, None] * inv * d[None, :], dof


def select_correction(jac_delta, seconds, residuals, weights, candidates, *, yaw_sigma_rad=None):
    """Choose the candidate basis of least BIC and its linearized solution (module docstring).

    Parameters
    ----------
    jac_delta : ndarray, shape (N, 2, 3)
        ``d(row, col)/d(roll, pitch, yaw)`` at each GCP, pixels per radian.
    seconds : ndarray, shape (N,)
        Time of each GCP's line, seconds since the model's epoch.
    residuals : ndarray, shape (N, 2)
        Observed minus computed ``(row, col)`` of the static solution, pixels.
    weights : ndarray, shape (N,)
        Final weights of the static solution (0 for outliers and unused points), 1/px^2.
    candidates : list of AttitudeCorrection or None
        From :func:`candidate_corrections`.
    yaw_sigma_rad : float, optional
        Prior on the yaw coefficients (:func:`ridge_weights`).

    Returns
    -------
    chosen : AttitudeCorrection or None
        With the least-squares coefficients (radians; a drift's constant left out); None:
        static.
    covariance : ndarray, shape (3 K, 3 K) or None
        Of the chosen coefficients, scaled by the a-posteriori variance factor, rad^2.
    table : list of dict
        Per candidate ``kind``, ``n_terms``, ``n_parameters`` (effective), ``rss``
        (weighted, px^2), ``bic``, ``chosen``.
    """
    ok = np.isfinite(residuals).all(axis=1) & np.isfinite(jac_delta).all(axis=(1, 2)) & (weights > 0)
    jac_delta, seconds, residuals, weights = jac_delta[ok], seconds[ok], residuals[ok], weights[ok]
    m = 2 * int(ok.sum())
    rss0 = float(np.sum(weights[:, None] * residuals**2))
    table, solutions = [], []
    for cand in candidates:
        normal, rhs, k = _normal_equations(jac_delta, seconds, residuals, weights, cand)
        ridge = _ridge(cand, k, yaw_sigma_rad)
        penalty = spline_penalty(cand, k, 3 * k)
        smoothing = None
        if penalty is None:
            coef, inv, dof = _ridge_solution(normal, rhs, ridge)
            rss = max(rss0 - 2.0 * coef @ rhs + coef @ normal @ coef, 1e-300)
        else:
            folds = []
            for held in _held_out(cand, seconds):
                w_h = np.where(held, weights, 0.0)
                n_h, b_h, _ = _normal_equations(jac_delta, seconds, residuals, w_h, cand)
                folds.append((n_h, b_h, float(np.sum(w_h[:, None] * residuals**2))))
            coef, inv, dof, rss, smoothing = smooth(normal, rhs, rss0, m, penalty, ridge, folds=folds)
        bic = m * np.log(rss / m) + dof * np.log(m)
        solutions.append((coef, inv * rss / max(m - dof, 1.0), k))
        row = {"kind": "static" if cand is None else cand.kind, "n_terms": 0 if cand is None else cand.n_terms,
               "n_parameters": round(dof, 2), "rss": float(rss), "bic": float(bic), "chosen": False}
        if smoothing is not None:
            row["smoothing"] = smoothing.to_dict()
        table.append(row)
    best = choose_candidate(table, m)
    table[best]["chosen"] = True
    cand = candidates[best]
    if cand is None:
        return None, None, table
    coef, cov, k = solutions[best]
    keep = np.arange(3 * k).reshape(3, k)
    if cand.kind == "drift":
        keep = keep[:, 1:]
    keep = keep.reshape(-1)
    return cand.with_coefficients(coef[keep]), cov[np.ix_(keep, keep)], table


def selection_info(mode: str, chosen, table) -> dict:
    """The ``attitude`` record of ``calibration.json`` for a selection (docs/attitude.md).

    Parameters
    ----------
    mode : str
        ``CalibrationOptions.attitude``.
    chosen : AttitudeCorrection or None
    table : list of dict
        Candidate rows (:func:`select_correction`).

    Returns
    -------
    dict
        ``mode``, ``candidates``, ``selected`` (``kind``, ``n_terms``, and for a correction
        ``knot_spacing_s``, ``edf``; for the P-spline also ``lambda`` and ``criterion``) and,
        when a P-spline was fitted, ``smoothing`` (its criterion curve, chosen or not).
    """
    row = next((r for r in table if r["chosen"]), None)
    if chosen is None:
        selected = {"kind": "static", "n_terms": 0, "edf": None if row is None else row["n_parameters"]}
    else:
        selected = {"kind": chosen.kind, "n_terms": chosen.n_terms, "knot_spacing_s": chosen.knot_spacing_s,
                    "edf": row["n_parameters"]}
        if "smoothing" in row:
            selected.update({"lambda": row["smoothing"]["lambda"], "criterion": row["smoothing"]["criterion"]})
    rows = [{k: v for k, v in r.items() if k != "smoothing"} | (
        {"lambda": r["smoothing"]["lambda"]} if "smoothing" in r else {}) for r in table]
    info = {"mode": mode, "candidates": rows, "selected": selected}
    spline = next((r for r in table if "smoothing" in r), None)
    if spline is not None:
        info["smoothing"] = {"n_segments": spline["n_terms"], "edf": spline["n_parameters"], **spline["smoothing"]}
    return info


def choose_candidate(table, m: int, *, alpha: float = SIGNIFICANCE) -> int:
    """Index of the chosen candidate: least GCV among the time-varying ones, if significant.

    The time-varying candidate of least ``GCV = m RSS / (m - p)^2`` is kept when the
    approximate F-test of "no time variation" (Hastie and Tibshirani 1990, section 3.9: effective
    degrees of freedom ``p`` in place of parameter counts)

    .. math::  F = \\frac{(RSS_0 - RSS) / (p - p_0)}{RSS / (m - p)}
               > F_{1-\\alpha}(p - p_0,\\; m - p)

    rejects the static model (``RSS_0``, ``p_0``) at level ``alpha``; otherwise the static one.

    Parameters
    ----------
    table : list of dict
        Rows with ``kind`` (``"static"`` for the static candidate), ``rss`` and ``n_parameters``.
    m : int
        Weighted residuals.
    alpha : float
        Level of the test (:data:`SIGNIFICANCE`).

    Returns
    -------
    int
        Also writes ``gcv``, ``f_statistic`` and ``p_value`` into the time-varying rows.
    """
    from scipy.stats import f as f_dist

    static = next((i for i, r in enumerate(table) if r["kind"] == "static"), None)
    for r in table:
        r["gcv"] = float(m * r["rss"] / max(m - r["n_parameters"], 1e-3) ** 2)
    varying = [i for i, r in enumerate(table) if r["kind"] != "static"]
    if not varying:
        return 0 if static is None else static
    best = min(varying, key=lambda i: table[i]["gcv"])
    if static is None:
        return best
    r0 = table[static]
    for i in varying:
        r = table[i]
        d1, d2 = r["n_parameters"] - r0["n_parameters"], m - r["n_parameters"]
        if d1 > 1e-6 and d2 > 0:
            stat = ((r0["rss"] - r["rss"]) / d1) / (r["rss"] / d2)
            r["f_statistic"], r["p_value"] = float(stat), float(f_dist.sf(stat, d1, d2))
    return best if table[best].get("p_value", 1.0) < alpha else static


def correction_band(correction: AttitudeCorrection, covariance, seconds):
    """Correction angles and their standard deviations at ``seconds``.

    Parameters
    ----------
    correction : AttitudeCorrection
    covariance : ndarray, shape (3 K, 3 K) or None
        Covariance of the coefficients (axis-major), rad^2.
    seconds : ndarray, shape (T,)

    Returns
    -------
    angles_urad, sigma_urad : ndarray, shape (T, 3)
        ``sigma_urad`` is NaN without a covariance.
    """
    basis, _ = correction.basis(seconds)
    angles = basis @ correction.coefficients_rad.T * 1e6
    sigma = np.full_like(angles, np.nan)
    if covariance is not None:
        k = correction.n_coefficients
        for a in range(3):
            block = covariance[a * k : (a + 1) * k, a * k : (a + 1) * k]
            sigma[:, a] = np.sqrt(np.clip(np.einsum("tk,kl,tl->t", basis, block, basis), 0.0, None)) * 1e6
    return angles, sigma


def _fit_sinusoid(t, y, f0):
    """Least squares ``a + b t + A sin(2 pi f t + phi)`` from a starting frequency; (A, f, phi)."""
    from scipy.optimize import least_squares

    tc = t - t.mean()

    def linear_part(f):
        x = np.stack([np.ones_like(tc), tc, np.sin(2 * np.pi * f * tc), np.cos(2 * np.pi * f * tc)], axis=1)
        return x, np.linalg.lstsq(x, y, rcond=None)[0]

    def resid(p):
        x, c = linear_part(p[0])
        return x @ c - y

    f = float(least_squares(resid, [f0], bounds=([f0 * 0.5], [f0 * 1.5])).x[0])
    _, c = linear_part(f)
    return float(np.hypot(c[2], c[3])), f, float(np.arctan2(c[3], c[2]))


def jitter_spectrum(correction: AttitudeCorrection, t_lo_s: float, t_hi_s: float, *, n_samples: int = 2048):
    """Amplitude spectrum of the recovered correction and its dominant sinusoid per axis.

    The correction is sampled over the image's time span, a linear trend (bias and drift) is
    removed, and its amplitude spectrum is taken (Hann window, amplitude-normalized, zero-padded
    eight times). The highest peak above the lowest resolvable frequency starts a least-squares
    fit of ``a + b t + A sin(2 pi f t + phi)`` to the samples, which gives the amplitude and
    frequency reported.

    Parameters
    ----------
    correction : AttitudeCorrection
    t_lo_s, t_hi_s : float
        Time span of the image lines, seconds since the epoch.
    n_samples : int
        Samples over the span.

    Returns
    -------
    dict
        ``frequency_hz`` (F,), per axis ``spectrum_urad`` (F,) and ``peak``
        (``amplitude_urad``, ``frequency_hz``, ``phase_rad``; None when the span holds less
        than one and a half periods of any resolvable frequency).
    """
    t = np.linspace(t_lo_s, t_hi_s, n_samples)
    angles = correction.angles(t) * 1e6
    span = t_hi_s - t_lo_s
    dt = t[1] - t[0]
    n_fft = 8 * n_samples
    freq = np.fft.rfftfreq(n_fft, dt)
    window = np.hanning(n_samples)
    out = {"frequency_hz": freq, "axes": {}}
    keep = freq <= 0.25 / dt
    out["frequency_hz"] = freq[keep]
    for a, name in enumerate(AXES):
        y = angles[:, a]
        detrended = y - np.polyval(np.polyfit(t - t.mean(), y, 1), t - t.mean())
        spec = 2.0 * np.abs(np.fft.rfft(detrended * window, n_fft)) / window.sum()
        low = freq >= 1.5 / span
        peak = None
        if np.any(low & keep) and np.max(spec[low & keep]) > 0:
            f0 = float(freq[low & keep][np.argmax(spec[low & keep])])
            amp, f, phase = _fit_sinusoid(t, y, f0)
            peak = {"amplitude_urad": amp, "frequency_hz": f, "phase_rad": phase}
        out["axes"][name] = {"spectrum_urad": spec[keep], "peak": peak}
    return out
