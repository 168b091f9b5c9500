"""Outlier rejection of dense matches: local consistency and robust smooth-correction residuals.

Never a fixed fraction: every test compares a match with what its neighbours or a fitted model
say, with thresholds scaled by robust (MAD) spreads and floored at a fraction of a pixel.

* :func:`local_consistency`: on the regular window grid of one CCD, a match whose shift differs
  from the median of its valid neighbours (5 x 5 grid cells) by more than
  ``max(floor_px, k * 1.4826 MAD)`` is rejected.
* :func:`smooth_residuals`: per CCD, the shifts ``(d_row, d_col)`` are fitted by a low-degree
  polynomial in ``(row, col)`` (cubic across track like the directional-angle model, quadratic
  along track for attitude drift), by IRLS with Huber weights, then with Tukey's biweight
  (redescending: a match far from the fit gets no weight at all, so a compact cluster of
  consistently wrong matches, e.g. a cast shadow that moved with the season, cannot pull the fit
  toward itself and hide below the threshold); matches whose residual exceeds
  ``max(floor_px, k sigma)`` are rejected and ``sigma`` (robust) is returned as the matches'
  measurement uncertainty.

Weights: Huber with ``1.345 s``, biweight ``(1 - (d / c s)^2)^2`` for ``d < c s`` with
``c = 4.685`` (95 % efficiency at Gaussian noise for both: Holland & Welsch, "Robust regression
using iteratively reweighted least-squares", Commun. Statist. A6(9), 1977), ``s = 1.4826``
times the median residual distance. The Huber steps give the biweight its start (a redescending
estimator needs one near the solution: Huber, "Robust Statistics", Wiley 1981, ch. 7).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["local_consistency", "smooth_residuals"]


def local_consistency(shift_grid: np.ndarray, *, radius: int = 2, k: float = 4.0, floor_px: float = 0.5) -> np.ndarray:
    """Flags (n_r, n_c) of grid matches consistent with their neighbours.

    Parameters
    ----------
    shift_grid : ndarray (n_r, n_c, 2)
        Shifts on the window grid; NaN where there is no valid match.
    radius : int
        Neighbourhood half-size in grid cells.
    k : float
        Threshold in robust (1.4826 MAD) standard deviations of the deviations from the
        neighbours' median.
    floor_px : float
        Smallest threshold, pixels.

    Returns
    -------
    ndarray of bool, shape (n_r, n_c)
        True where the match is valid and within the threshold of its neighbours' median (or
        has fewer than 2 valid neighbours: left to the model-residual test).
    """
    n_r, n_c, _ = shift_grid.shape
    pad = np.pad(shift_grid, ((radius, radius), (radius, radius), (0, 0)), constant_values=np.nan)
    win = sliding_window_view(pad, (2 * radius + 1, 2 * radius + 1), axis=(0, 1))  # (n_r, n_c, 2, w, w)
    win = win.reshape(n_r, n_c, 2, -1).copy()
    win[:, :, :, win.shape[-1] // 2] = np.nan  # exclude the match itself
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(win, axis=-1)  # (n_r, n_c, 2)
            count = np.sum(np.isfinite(win[:, :, 0, :]), axis=-1)
    dev = np.hypot(*(shift_grid - med).transpose(2, 0, 1))
    ok = np.isfinite(dev)
    if not ok.any():
        return np.zeros((n_r, n_c), bool)
    spread = 1.4826 * np.median(dev[ok])
    thr = max(floor_px, k * spread)
    # isolated matches (fewer than 2 valid neighbours) cannot be checked here: keep them for the
    # model-residual test
    return np.isfinite(shift_grid[..., 0]) & ((count < 2) | (dev <= thr))


def _design(row, col, row_span, col_span):
    u = (col - col_span[0]) / max(col_span[1] - col_span[0], 1.0) * 2.0 - 1.0
    v = (row - row_span[0]) / max(row_span[1] - row_span[0], 1.0) * 2.0 - 1.0
    return np.stack([np.ones_like(u), u, u * u, u**3, v, v * v, u * v], axis=-1)


#: Tuning constants of the IRLS weights (module docstring), in units of ``s``.
HUBER_C = 1.345
BIWEIGHT_C = 4.685


def smooth_residuals(row, col, d_row, d_col, *, k: float = 4.0, floor_px: float = 0.25, iterations: int = 8,
                     redescending_iterations: int = 6):
    """Robust smooth fit of the shifts of one CCD; returns (inlier flags, sigma_px, residuals).

    Parameters
    ----------
    row, col : ndarray (N,)
        Match positions: continuous scene pixels (first pixel's centre at (0.5, 0.5)).
    d_row, d_col : ndarray (N,)
        Measured shifts (pixels).
    k : float
        Rejection threshold in robust standard deviations of the residual distance.
    floor_px : float
        Smallest rejection threshold, pixels.
    iterations : int
        IRLS iterations with Huber weights.
    redescending_iterations : int
        Further IRLS iterations with biweight weights (0: Huber only).

    Returns
    -------
    inlier : ndarray (N,) bool
        True for matches within the threshold (all True with fewer than 10 matches).
    sigma_px : float
        Robust standard deviation of the residuals (per axis, MAD-based) of the inliers;
        NaN with fewer than 10 matches.
    residual : ndarray (N, 2)
        Measured minus fitted (d_row, d_col), pixels.
    """
    n = row.size
    if n < 10:
        return np.ones(n, bool), float("nan"), np.zeros((n, 2))
    a = _design(row, col, (row.min(), row.max()), (col.min(), col.max()))
    y = np.stack([d_row, d_col], axis=-1)
    w = np.ones(n)
    for step in range(iterations + redescending_iterations):
        sw = np.sqrt(w)[:, None]
        coef = np.linalg.lstsq(a * sw, y * sw, rcond=None)[0]
        res = y - a @ coef
        dist = np.hypot(res[:, 0], res[:, 1])
        scale = 1.4826 * np.median(dist) + 1e-9
        if step + 1 < iterations:
            u = dist / (HUBER_C * scale)
            w = np.where(u <= 1.0, 1.0, 1.0 / u)
        else:  # the biweight, from the Huber solution on
            u = dist / (BIWEIGHT_C * scale)
            w = np.where(u < 1.0, (1.0 - u * u) ** 2, 0.0)
    res = y - a @ coef
    dist = np.hypot(res[:, 0], res[:, 1])
    per_axis = 1.4826 * np.median(np.abs(res), axis=0)
    sigma = float(np.sqrt(np.mean(per_axis**2)))
    inlier = dist <= max(floor_px, k * sigma * np.sqrt(2.0))
    return inlier, sigma, res
