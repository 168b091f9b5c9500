"""Penalized B-spline (P-spline) attitude correction: dense knots, smoothing chosen on the data.

The time-varying attitude correction ``delta_a(t) = sum_j c_{a,j} B_j(t)`` (roll, pitch, yaw;
uniform cubic B-splines, :mod:`sensor_models.models.attitude_correction`) is given knots as dense as
the observations' time sampling allows (:func:`pspline_segments`) and the roughness penalty of
Eilers and Marx (1996):

.. math::

    \\hat c(\\lambda) = \\arg\\min_c\\; (r - X c)^T W (r - X c)
        + \\lambda \\sum_a \\lVert D_k c_a \\rVert^2 + c^T R c

with ``D_k`` the ``k``-th order difference matrix (``k = PENALTY_ORDER = 2``: the penalty's
null space is a constant and a rate per axis, so ``lambda -> infinity`` is a drift and
``lambda -> 0`` the unpenalized dense spline) and ``R`` the weak ridge of
:data:`calibrate.attitude.REGULARIZATION_SIGMA_RAD` that pins the installation's constant mode.
Nuisance columns (the per-CCD polynomials of the band-parallax fit) enter ``X`` unpenalized.

The smoothing ``lambda`` minimizes the generalized cross-validation score (Craven and Wahba
1979)

.. math::  GCV(\\lambda) = m\\, RSS(\\lambda) / (m - \\nu(\\lambda))^2,
           \\qquad \\nu(\\lambda) = \\mathrm{tr}\\,[(N + R + \\lambda S)^{-1} N]

over ``m`` weighted residuals, ``nu`` the effective degrees of freedom (trace of the hat
matrix), ``N = X^T W X`` and ``S`` the block-diagonal ``D_k^T D_k``. One generalized symmetric
eigendecomposition ``S v = s (N + R) v`` (``V^T (N + R) V = I``) diagonalizes every
``lambda`` at once (Demmler-Reinsch form): ``(N + R + lambda S)^-1 = V diag(1 / (1 + lambda
s)) V^T``, so the whole criterion curve costs ``O(P^2)`` per ``lambda`` after one ``O(P^3)``
decomposition. The grid spans the penalty's eigenvalues and is refined around its minimum by a
bounded scalar search in ``log lambda``.

References
----------
P. H. C. Eilers, B. D. Marx, "Flexible smoothing with B-splines and penalties", Statistical
Science 11(2):89-121, 1996. P. Craven, G. Wahba, "Smoothing noisy data with spline functions",
Numerische Mathematik 31:377-403, 1979. G. Wahba, *Spline Models for Observational Data*, SIAM
1990, ch. 4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.optimize import minimize_scalar

from sensor_models.files.threads import blas_threads

__all__ = [
    "MAX_PSPLINE_SEGMENTS",
    "MIN_LINES_PER_SEGMENT",
    "PENALTY_ORDER",
    "Smoothing",
    "difference_penalty",
    "pspline_segments",
    "recovered_spectrum",
    "smooth",
    "time_folds",
]

#: order ``k`` of the difference penalty (Eilers and Marx 1996: 2 or 3)
PENALTY_ORDER = 2
#: most segments of the P-spline: a computing bound (one dense eigendecomposition of ``3 (n + 3)``
#: columns); 256 segments over 20 s are 0.078 s apart, four per period of 3 Hz jitter
MAX_PSPLINE_SEGMENTS = 256
#: fewest image lines per segment (the attitude is sampled once per line)
MIN_LINES_PER_SEGMENT = 4
#: points of the coarse ``log lambda`` grid before the refinement
GRID_POINTS = 48
#: folds of the blocked cross-validation
N_FOLDS = 5


def pspline_segments(seconds, t0_s: float, t1_s: float, *, n_lines: float,
                     max_segments: int = MAX_PSPLINE_SEGMENTS) -> int:
    """Segments of the P-spline on ``[t0_s, t1_s]``: twice the distinct observation times in it.

    With ``n_t`` distinct observation times (image lines) over the span, their mean spacing is
    ``dt = span / n_t`` and their Nyquist period ``2 dt``. Knots ``dt / 2`` apart put four
    segments in that period, where a cubic spline follows a sinusoid to about 2 % (interpolation
    error ``(2 pi h / T)^4 / 384``), so the basis can follow whatever the observations sample;
    the penalty, not the knot count, sets the smoothness. Bounded by ``n_lines /
    MIN_LINES_PER_SEGMENT`` and ``max_segments``.

    Parameters
    ----------
    seconds : ndarray, shape (N,)
        Observation times (GCP lines; tie points' lines), seconds since the model's epoch.
    t0_s, t1_s : float
        Span of the spline, seconds.
    n_lines : float
        Image lines in the span.
    max_segments : int
        Upper bound.

    Returns
    -------
    int
        At least 1.
    """
    t = np.asarray(seconds, dtype=np.float64).reshape(-1)
    t = t[np.isfinite(t) & (t >= t0_s) & (t <= t1_s)]
    span = float(t1_s - t0_s)
    if t.size == 0 or span <= 0.0:
        return 1
    line_s = span / max(float(n_lines), 1.0)
    n_t = np.unique(np.floor((t - t0_s) / line_s)).size  # distinct image lines
    return int(max(1, min(2 * n_t, int(n_lines // MIN_LINES_PER_SEGMENT), int(max_segments))))


def difference_penalty(k: int, order: int = PENALTY_ORDER) -> np.ndarray:
    """``D^T D`` (k, k) of the ``order``-th difference matrix ``D`` ((k - order), k).

    Parameters
    ----------
    k : int
        Coefficients per axis.
    order : int
        Difference order (no penalty when ``k <= order``).

    Returns
    -------
    ndarray, shape (k, k)
    """
    if k <= order:
        return np.zeros((k, k))
    d = np.diff(np.eye(k), n=order, axis=0)
    return d.T @ d


@dataclass(frozen=True)
class Smoothing:
    """The chosen smoothing of a P-spline fit and its criterion curve.

    Attributes
    ----------
    lam : float
        Chosen ``lambda`` (same units as the normal matrix: 1 / rad^2 of weighted px^2).
    edf : float
        Effective degrees of freedom at ``lam`` (trace of the hat matrix, every column).
    score : float
        The criterion at ``lam``: blocked cross-validation's held-out weighted squared error
        summed over the folds, or ``GCV(lam)``, px^2 (weighted).
    curve_lambda, curve_score, curve_edf : ndarray, shape (G,)
        The criterion over the coarse grid.
    at_bound : str or None
        ``"rough"`` or ``"smooth"`` when the minimum sits at an end of the grid.
    """

    lam: float
    edf: float
    score: float
    curve_lambda: np.ndarray
    curve_score: np.ndarray
    curve_edf: np.ndarray
    at_bound: str | None = None
    criterion: str = "gcv"
    n_folds: int = 0

    @property
    def gcv(self) -> float:  # noqa: D102 - the criterion's value (either kind)
        return self.score

    def to_dict(self) -> dict:
        """JSON form: ``lambda``, ``edf``, ``criterion`` ("blocked-cv" or "gcv"), ``n_folds``,
        ``score``, ``at_bound`` and ``curve`` (lists).

        Returns
        -------
        dict
        """
        return {"criterion": self.criterion, "n_folds": self.n_folds, "lambda": float(self.lam),
                "edf": float(self.edf), "score": float(self.score), "at_bound": self.at_bound,
                "curve": {"lambda": [float(v) for v in self.curve_lambda],
                          "score": [float(v) for v in self.curve_score],
                          "edf": [float(v) for v in self.curve_edf]}}


def time_folds(seconds, t0_s: float, block_s: float, n_folds: int = N_FOLDS) -> np.ndarray:
    """Fold of each observation for cross-validation blocked in time.

    The time axis is cut into blocks of ``block_s`` seconds from ``t0_s``; block ``b`` goes to
    fold ``b mod n_folds``, so a fold holds every ``n_folds``-th block and its observations are
    predicted from the blocks on either side.

    Parameters
    ----------
    seconds : ndarray, shape (N,)
    t0_s, block_s : float
    n_folds : int

    Returns
    -------
    ndarray of int, shape (N,)
    """
    t = np.asarray(seconds, dtype=np.float64)
    block = np.floor((np.where(np.isfinite(t), t, t0_s) - t0_s) / max(block_s, 1e-12)).astype(np.int64)
    return np.mod(block, n_folds)


def smooth(normal, rhs, rss0: float, m: int, penalty, ridge, *, folds=()):
    """P-spline least squares with ``lambda`` chosen by blocked cross-validation (module docstring).

    Parameters
    ----------
    normal : ndarray, shape (P, P)
        ``N = X^T W X`` of every observation.
    rhs : ndarray, shape (P,)
        ``X^T W r``.
    rss0 : float
        ``r^T W r``.
    m : int
        Number of weighted residuals.
    penalty : ndarray, shape (P, P)
        ``S`` (zero rows and columns for unpenalized nuisance columns).
    ridge : ndarray, shape (P,)
        Diagonal ridge weights ``R`` (0: free).
    folds : sequence of (normal, rhs, rss0)
        The held-out observations of each fold (:func:`time_folds`): their ``X^T W X``,
        ``X^T W r`` and ``r^T W r``. Empty: ``lambda`` by GCV on every observation.

    Returns
    -------
    coef : ndarray, shape (P,)
    inverse : ndarray, shape (P, P)
        ``(N + R + lambda S)^-1``.
    edf : float
    rss : float
        Weighted residual sum of squares at the chosen ``lambda``.
    smoothing : Smoothing
    """
    normal = np.asarray(normal, dtype=np.float64)
    diag = np.diag(normal)
    ridge = np.asarray(ridge, dtype=np.float64) + np.where(diag > 0, diag * 1e-12, 1.0)  # columns without data
    full = _Pencil(normal, rhs, rss0, penalty, ridge)
    lo, hi = full.log_lambda_range()
    grid = np.linspace(lo, hi, GRID_POINTS)
    if folds:
        pencils = [(_Pencil(normal - n_h, rhs - b_h, rss0 - r_h, penalty, ridge), n_h, b_h, r_h)
                   for n_h, b_h, r_h in folds]

        def score(log_lam):
            lam = np.exp(log_lam)
            return sum(p.held_out_error(lam, n_h, b_h, r_h) for p, n_h, b_h, r_h in pencils)
    else:
        def score(log_lam):
            rss, edf = full.rss_edf(np.exp(log_lam))
            return m * rss / max(m - edf, 1e-3) ** 2

    scores = np.array([score(g) for g in grid])
    edfs = np.array([full.rss_edf(np.exp(g))[1] for g in grid])
    i = int(np.argmin(scores))
    bound = "rough" if i == 0 else "smooth" if i == grid.size - 1 else None
    best = grid[i]
    if bound is None:
        opt = minimize_scalar(score, bounds=(grid[i - 1], grid[i + 1]), method="bounded", options={"xatol": 1e-2})
        if opt.fun < scores[i]:
            best = float(opt.x)
    lam = float(np.exp(best))
    coef, inverse = full.solve(lam)
    rss, edf = full.rss_edf(lam)
    smoothing = Smoothing(lam, edf, float(score(best)), np.exp(grid), scores, edfs, bound,
                          "blocked-cv" if folds else "gcv", len(folds))
    return coef, inverse, edf, rss, smoothing


class _Pencil:
    """``(N + R + lambda S)^-1`` for every ``lambda`` from one generalized eigendecomposition."""

    def __init__(self, normal, rhs, rss0, penalty, ridge):
        a = normal + np.diag(ridge)
        self.d = d = 1.0 / np.sqrt(np.diag(a))  # Jacobi scaling: the same problem, tamer numbers
        with blas_threads(1):  # a few hundred columns: threads only contend
            s, v = scipy.linalg.eigh(d[:, None] * penalty * d[None, :], d[:, None] * a * d[None, :])
        self.s, self.v = np.clip(s, 0.0, None), v  # S v = s A v, V^T A V = I
        self.beta = v.T @ (d * rhs)
        self.n_diag = np.sum(v * ((d[:, None] * normal * d[None, :]) @ v), axis=0)  # diag(V^T N V)
        self.r_diag = ridge * d * d
        self.rss0 = float(rss0)

    def log_lambda_range(self):
        pos = self.s[self.s > self.s.max() * 1e-12] if self.s.max() > 0 else np.array([1.0])
        return np.log(1e-3 / pos.max()), np.log(1e3 / pos.min())

    def _coef_scaled(self, lam):
        f = 1.0 / (1.0 + lam * self.s)
        return self.v @ (self.beta * f), f

    def rss_edf(self, lam):
        coef_s, f = self._coef_scaled(lam)
        b2 = self.beta**2
        rss = self.rss0 - 2.0 * np.sum(b2 * f) + np.sum(b2 * f**2) - np.sum(self.r_diag * coef_s**2)
        return max(float(rss), 1e-300), float(np.sum(self.n_diag * f))

    def solve(self, lam):
        coef_s, f = self._coef_scaled(lam)
        return self.d * coef_s, self.d[:, None] * ((self.v * f) @ self.v.T) * self.d[None, :]

    def held_out_error(self, lam, n_h, b_h, r_h):
        c = self.d * self._coef_scaled(lam)[0]
        return float(r_h - 2.0 * c @ b_h + c @ n_h @ c)


def recovered_spectrum(correction, t_lo_s: float, t_hi_s: float) -> dict:
    """Amplitude periodogram of a correction's angles over the image lines.

    The angles are sampled at four points per knot interval over ``[t_lo_s, t_hi_s]``, a
    linear trend (bias and drift) is removed and the amplitude periodogram
    ``2 |sum_n y_n w_n e^{-2 pi i f t_n}| / sum_n w_n`` (Hann window ``w``, so that a sinusoid of
    amplitude A away from the ends reads about A) is taken at frequencies ``j / (2 T)``
    (twice zero-padded), ``T`` the span, up to the knots' Nyquist frequency ``1 / (2 h)``.

    Parameters
    ----------
    correction : AttitudeCorrection
    t_lo_s, t_hi_s : float
        Span of the image lines, seconds since the epoch.

    Returns
    -------
    dict
        ``frequency_hz`` (F,) and ``amplitude_urad`` with ``roll``, ``pitch``, ``yaw`` (F,)
        each, lists.
    """
    span = float(t_hi_s - t_lo_s)
    h = correction.knot_spacing_s
    n = int(min(max(64, 4 * span / h), 8192))
    t = np.linspace(t_lo_s, t_hi_s, n)
    y = correction.angles(t) * 1e6
    tc = t - t.mean()
    trend = np.polynomial.polynomial.polyfit(tc, y, 1)
    y = y - (trend[0][None, :] + tc[:, None] * trend[1][None, :])
    w = np.hanning(n)
    f_max = min(0.5 / h, 0.5 * (n - 1) / span)
    freq = np.arange(1, int(np.floor(2.0 * span * f_max)) + 1) / (2.0 * span)
    phase = np.exp(-2j * np.pi * freq[:, None] * tc[None, :])  # (F, n)
    amp = 2.0 * np.abs(phase @ (y * w[:, None])) / w.sum()  # (F, 3)
    return {"frequency_hz": [float(v) for v in freq],
            "amplitude_urad": {a: [float(v) for v in amp[:, i]] for i, a in enumerate(("roll", "pitch", "yaw"))}}
