"""Robust loss functions and the robust scale of the least-squares solver (:mod:`calibrate.lsq`).

For a normalized residual size ``u`` (residual norm over the scale) this module holds the IRLS
weight ``w(u) = psi(u) / u`` (:func:`robust_weights`), the loss ``rho(u)``
(:func:`robust_rho`) and ``u w'(u)`` (:func:`robust_u_dw`, used by the robust covariance) of
the losses ``none``, ``huber`` and ``cauchy`` with their tuning constants (95 % efficiency at
the normal distribution), and the MAD-type scale of normalized residual vectors
(:func:`robust_scale`). The table of the functions and the choice of the scale are in the
docstring of :mod:`calibrate.lsq`.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from sensor_models.errors import InputError

__all__ = ["CAUCHY_C", "HUBER_C", "TUNING", "check_robust_rule", "robust_rho", "robust_scale", "robust_u_dw",
           "robust_weights"]

#: Huber's tuning constant: 95 % asymptotic efficiency at the normal distribution.
HUBER_C = 1.345
#: Cauchy tuning constant: 95 % asymptotic efficiency at the normal distribution.
CAUCHY_C = 2.3849
#: Default tuning constant of each robust loss (``none``: no down-weighting).
TUNING = {"huber": HUBER_C, "cauchy": CAUCHY_C, "none": np.inf}


def check_robust_rule(robust):
    """Raise :class:`~sensor_models.errors.InputError` unless ``robust`` names a loss of :data:`TUNING`.

    Parameters
    ----------
    robust : str
        Name of the robust loss (``"huber"``, ``"cauchy"`` or ``"none"``).
    """
    if robust not in TUNING:
        raise InputError(f"robust must be one of {', '.join(TUNING)}, got {robust!r}", field="robust")


def robust_weights(u, robust: str, c: float | None = None) -> np.ndarray:
    """IRLS weights ``w(u) = psi(u) / u`` (table in :mod:`calibrate.lsq`), shape of ``u``.

    Parameters
    ----------
    u : ndarray
        Normalized residual norms (residual / scale), >= 0.
    robust : {"huber", "cauchy", "none"}
        Loss.
    c : float, optional
        Tuning constant (default: the loss's, :data:`TUNING`).

    Returns
    -------
    ndarray
        Weights in [0, 1], shape of ``u``.
    """
    check_robust_rule(robust)
    u = np.asarray(u, dtype=np.float64)
    c = TUNING[robust] if c is None else float(c)
    if robust == "none":
        return np.ones_like(u)
    if robust == "huber":
        return np.where(u > c, c / np.maximum(u, 1e-300), 1.0)
    return 1.0 / (1.0 + (u / c) ** 2)


def robust_rho(u, robust, c):
    """The loss ``rho(u)`` (table in :mod:`calibrate.lsq`), shape of ``u``.

    Parameters
    ----------
    u : ndarray
        Normalized residual norms, >= 0.
    robust : {"huber", "cauchy", "none"}
        Loss.
    c : float
        Tuning constant.

    Returns
    -------
    ndarray
        ``rho(u)``, shape of ``u``.
    """
    if robust == "none":
        return 0.5 * u * u
    if robust == "huber":
        return np.where(u <= c, 0.5 * u * u, c * u - 0.5 * c * c)
    return 0.5 * c * c * np.log1p((u / c) ** 2)


def robust_u_dw(u, robust, c):
    """``u * w'(u)``, the derivative of the IRLS weight times ``u`` (robust covariance), shape of ``u``.

    Parameters
    ----------
    u : ndarray
        Normalized residual norms, >= 0.
    robust : {"huber", "cauchy", "none"}
        Loss.
    c : float
        Tuning constant.

    Returns
    -------
    ndarray
        ``u w'(u)`` (<= 0), shape of ``u``.
    """
    if robust == "none":
        return np.zeros_like(u)
    if robust == "huber":
        return np.where(u > c, -c / np.maximum(u, 1e-300), 0.0)
    w = 1.0 / (1.0 + (u / c) ** 2)
    return -2.0 * (u / c) ** 2 * w * w


def robust_scale(norms, k: int) -> float:
    """MAD-type scale of normalized residuals from the norms ``||r~_i||`` of k-vectors.

    ``s = median(||r~||) / sqrt(chi2_k.ppf(0.5))`` (``1.4826 median |r~|`` for ``k = 1``);
    falls back to the RMS when more than half the residuals are exactly zero, and to 1 when
    all are.

    Parameters
    ----------
    norms : array_like, shape (N,)
        Norms of the weighted residual k-vectors (non-finite values are ignored).
    k : int
        Components per residual vector (2 for an image point).

    Returns
    -------
    float
        The scale ``s`` (> 0), in the residuals' unit.
    """
    norms = np.asarray(norms, dtype=np.float64)
    norms = norms[np.isfinite(norms)]
    if norms.size == 0:
        return 1.0
    s = float(np.median(norms)) / np.sqrt(chi2.ppf(0.5, k))
    if s > 0.0:
        return s
    rms = float(np.sqrt(np.mean(norms**2) / k))
    return rms if rms > 0.0 else 1.0
