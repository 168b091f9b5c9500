"""Smoothing weight of a cubic smoothing spline by generalized cross-validation, in closed form.

The cubic smoothing spline ``f`` of points ``(x_i, y_i)``, ``i = 1..n``, minimizes

    sum_i (y_i - f(x_i))^2 + lam * integral f''(x)^2 dx,

and its values at the knots are ``f = A(lam) y`` with the hat matrix
``A(lam) = (I + lam K)^-1`` and the penalty matrix ``K = Q R^-1 Q^T`` (Reinsch form; Q the
``n x (n-2)`` second-difference matrix with ``1/h_{j-1}, -1/h_{j-1} - 1/h_j, 1/h_j`` in column
``j``, R the ``(n-2) x (n-2)`` tridiagonal matrix with ``(h_{j-1} + h_j)/3`` on the diagonal and
``h_j/6`` beside it, ``h_j = x_{j+1} - x_j``; Green and Silverman, *Nonparametric Regression and
Generalized Linear Models*, Chapman & Hall 1994, section 2.1). With ``R = L L^T`` and the
singular value decomposition ``Q L^-T = U S V^T``, ``K = U S^2 U^T`` (two more eigenvalues are
zero: the straight lines), so with ``d = s^2`` and ``c = U^T y``

    ||y - f||^2 = sum_k (lam d_k / (1 + lam d_k))^2 c_k^2,
    tr A(lam)   = 2 + sum_k 1 / (1 + lam d_k),

and the generalized cross-validation score (Craven and Wahba, Numer. Math. 31, 377-403, 1979;
Wahba, *Spline Models for Observational Data*, SIAM 1990, section 4.3)

    GCV(lam) = (||y - f||^2 / n) / (1 - tr A(lam) / n)^2

costs O(n) per weight once the decomposition (O(n^3), n of a star track: up to ~120) is made.
The weight minimizing it over ``0 <= lam <= n`` (bounded Brent search,
:func:`scipy.optimize.minimize_scalar`) is the one :func:`scipy.interpolate.make_smoothing_spline`
chooses itself when given no weight (the same criterion, the same penalty scale, the same
search), which forms the hat matrix's trace band by band in Python at every trial weight; here
the decomposition serves every trial and both coordinates of a track. The score is often
multimodal and the search is local: where SciPy's score carries rounding (about 1e-4 relative
at large weights, where the score is flat) the two searches can settle in different local
minima, on about 1 % of random tracks (``tests/test_spline_gcv.py``); otherwise the splines
agree to ~1e-6 px or better.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cholesky, solve_triangular, svd
from scipy.optimize import minimize_scalar

from sensor_models.files.threads import blas_threads

__all__ = ["gcv_weights"]


def gcv_weights(x, y) -> np.ndarray:
    """Smoothing weight of each column of ``y`` minimizing the GCV score (module docstring).

    Parameters
    ----------
    x : array_like, shape (n,)
        Abscissae, strictly increasing, ``n >= 5``.
    y : array_like, shape (n,) or (n, m)
        Ordinates, one column per curve sharing ``x``.

    Returns
    -------
    ndarray of float64, shape (m,)
        ``lam`` of each column in ``[0, n]``, for
        ``make_smoothing_spline(x, y[:, j], lam=lam[j])``; in the units of ``x`` and ``y``
        (``lam`` weighs ``integral f''^2 dx`` against squared residuals).

    Raises
    ------
    ValueError
        Fewer than 5 points, or ``x`` not strictly increasing.
    """
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    y = np.asarray(y, dtype=np.float64).reshape(x.size, -1)
    n = x.size
    h = np.diff(x)
    if n < 5 or not np.all(h > 0):
        raise ValueError("need at least 5 strictly increasing abscissae")
    d, c2 = _penalty_spectrum(h, y)
    out = np.empty(y.shape[1])
    for j in range(y.shape[1]):
        out[j] = minimize_scalar(_gcv, bounds=(0, n), method="bounded", args=(d, c2[:, j], n)).x
    return out


def _penalty_spectrum(h: np.ndarray, y: np.ndarray):
    """Non-zero eigenvalues ``d`` (n-2,) of ``K = Q R^-1 Q^T`` and the squared coordinates
    ``(U^T y)^2`` (n-2, m) of ``y`` on their eigenvectors."""
    n = h.size + 1
    m = n - 2
    j = np.arange(m)
    q = np.zeros((n, m))
    q[j, j] = 1.0 / h[:-1]
    q[j + 1, j] = -1.0 / h[:-1] - 1.0 / h[1:]
    q[j + 2, j] = 1.0 / h[1:]
    r = np.diag((h[:-1] + h[1:]) / 3.0) + np.diag(h[1:-1] / 6.0, 1) + np.diag(h[1:-1] / 6.0, -1)
    with blas_threads(1):  # a ~100 x 100 problem: BLAS threads only contend
        g = solve_triangular(cholesky(r, lower=True), q.T, lower=True).T  # Q L^-T, (n, n-2)
        u, s, _ = svd(g, full_matrices=False)
        c = u.T @ y
    return s * s, c * c


def _gcv(lam: float, d: np.ndarray, c2: np.ndarray, n: int) -> float:
    """GCV score at weight ``lam`` from the penalty spectrum (module docstring)."""
    damp = 1.0 / (1.0 + lam * d)
    shrink = lam * d * damp
    tr = 2.0 + np.sum(damp)
    return float(np.sum(shrink * shrink * c2) / n / (1.0 - tr / n) ** 2)
