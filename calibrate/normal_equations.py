"""The reweighted normal equations of the least-squares solver, accumulated chunk by chunk.

One pass over the caller's chunks (:func:`evaluate`) validates each :class:`Chunk`, normalizes
its residuals by ``sqrt(w0)``, weighs each point by its robust weight ``w(u)`` and adds it to
``N = sum w J~^T J~``, ``b = sum w J~^T r~`` and the prior-weighted ``N0 = sum J~^T J~``
(the :class:`Evaluation`); without a scale, the first :data:`PROBE_POINTS` points give a
provisional one. :func:`robust_cost`, :func:`prior_cost` and :func:`with_prior` give the
robust objective ``F(x)`` and add the pseudo-observations of a :class:`Prior`. The equations
and the scale rules are in the docstring of :mod:`calibrate.lsq`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibrate.lsq_inputs import Chunk
from calibrate.robust_loss import robust_rho, robust_scale, robust_weights
from sensor_models.errors import InputError

__all__ = ["PROBE_POINTS", "Evaluation", "evaluate", "prior_cost", "robust_cost", "with_prior"]

#: points from which a provisional robust scale is taken when none is known
PROBE_POINTS = 5000


@dataclass
class Evaluation:
    """One pass of :func:`evaluate` at ``x``: the normal equations and the residuals.

    Attributes
    ----------
    x : ndarray, shape (P,)
        Parameters of the pass.
    normal, rhs : ndarray, shape (P, P) and (P,)
        IRLS-weighted ``N`` and ``b`` (robust weights with ``weight_scale`` and ``rule``).
    normal0 : ndarray, shape (P, P)
        ``N0`` with the prior weights only (robust covariance).
    residuals : ndarray, shape (n, k)
        Observed minus modelled (NaN where not finite).
    norms : ndarray, shape (n,)
        ``||r~||`` of each point, NaN where invalid.
    k : int
        Residual components per point.
    weight_scale : float
        The scale ``s`` the robust weights used.
    rule : str
        Their robust function.
    c : float
        Its tuning constant.
    """

    x: np.ndarray
    normal: np.ndarray  # IRLS-weighted N
    rhs: np.ndarray  # IRLS-weighted b
    normal0: np.ndarray  # prior-weighted N0
    residuals: np.ndarray  # (n, k) raw
    norms: np.ndarray  # (n,) ||r~||, NaN where invalid
    k: int
    weight_scale: float  # the scale s the IRLS weights of ``normal``/``rhs`` used
    rule: str  # and their robust function
    c: float


def _as_chunk(chunk, n_par):
    if not isinstance(chunk, Chunk):
        chunk = Chunk(*chunk)
    r = np.asarray(chunk.residual, dtype=np.float64)
    if r.ndim == 1:
        r = r[:, None]
    n, k = r.shape
    jac = np.asarray(chunk.jacobian, dtype=np.float64)
    if jac.ndim == 2:
        jac = jac[:, None, :]
    cols = np.arange(n_par) if chunk.columns is None else np.asarray(chunk.columns, dtype=np.intp).reshape(-1)
    if jac.shape != (n, k, cols.size):
        raise InputError(f"chunk jacobian has shape {jac.shape}, expected {(n, k, cols.size)}")
    if cols.size and (cols.min() < 0 or cols.max() >= n_par):
        raise InputError(f"chunk columns outside 0..{n_par - 1}")
    w0 = np.ones(n) if chunk.weight is None else np.asarray(chunk.weight, dtype=np.float64).reshape(-1)
    if w0.shape != (n,):
        raise InputError(f"chunk weight has shape {w0.shape}, expected ({n},)")
    return r, jac, w0, cols


def evaluate(chunks, x, rule, c, scale):
    """One pass over the chunks at ``x``: normal equations and residuals.

    ``scale`` is the robust scale of the weights; without one, chunks are held back until
    :data:`PROBE_POINTS` points give a provisional scale.

    Parameters
    ----------
    chunks : callable
        ``f(x) -> iterable of Chunk`` (or tuples), as given to :func:`calibrate.lsq.solve`.
    x : ndarray, shape (P,)
        Parameters.
    rule : str
        Robust function of the weights.
    c : float
        Its tuning constant.
    scale : float or None
        Robust scale of the weights; None: from the first points.

    Returns
    -------
    Evaluation
        The accumulated normal equations, residuals and norms.

    Raises
    ------
    InputError
        Malformed chunks, or none.
    """
    n_par = x.size
    normal = np.zeros((n_par, n_par))
    normal0 = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    res_parts, norm_parts = [], []
    k_seen = None
    pending, n_pending = [], 0
    with np.errstate(over="ignore", invalid="ignore"):
        for chunk in chunks(x.copy()):
            chunk = _as_chunk(chunk, n_par)
            k = chunk[0].shape[1]
            if k_seen is None:
                k_seen = k
            elif k != k_seen:
                raise InputError(f"chunks mix {k_seen} and {k} residual components per point")
            if scale is None:
                pending.append(chunk)
                n_pending += chunk[0].shape[0]
                if n_pending < PROBE_POINTS:
                    continue
                scale = _probe_scale(pending)
                ready, pending = pending, []
            else:
                ready = [chunk]
            for item in ready:
                _accumulate(item, rule, c, scale, normal, normal0, rhs, res_parts, norm_parts)
        if pending:
            scale = _probe_scale(pending)
            for item in pending:
                _accumulate(item, rule, c, scale, normal, normal0, rhs, res_parts, norm_parts)
    if k_seen is None:
        raise InputError("the residual function yielded no chunks")
    return Evaluation(
        x=x.copy(),
        normal=normal,
        rhs=rhs,
        normal0=normal0,
        residuals=np.concatenate(res_parts, axis=0),
        norms=np.concatenate(norm_parts),
        k=k_seen,
        weight_scale=float(scale),
        rule=rule,
        c=float(c),
    )


def _normalized(r, jac, w0):
    """Validity mask, ``sqrt(w0)``, normalized residuals and their norms (NaN if invalid)."""
    valid = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(jac), axis=(1, 2)) & (w0 > 0.0)
    valid &= np.isfinite(w0)
    sw = np.sqrt(np.where(valid, w0, 0.0))
    rt = np.where(valid[:, None], r, 0.0) * sw[:, None]
    norms = np.sqrt(np.sum(rt * rt, axis=1))
    valid &= np.isfinite(norms)  # overflow
    rt[~valid] = 0.0
    norms[~valid] = np.nan
    return valid, sw, rt, norms


def _probe_scale(chunks):
    """Robust scale of the points of the held-back chunks."""
    norms = [_normalized(r, jac, w0)[3] for r, jac, w0, _cols in chunks]
    return robust_scale(np.concatenate(norms), chunks[0][0].shape[1])


def _accumulate(chunk, rule, c, scale, normal, normal0, rhs, res_parts, norm_parts):
    """Add one validated chunk to the normal equations and the residual lists (in place)."""
    r, jac, w0, cols = chunk
    k = r.shape[1]
    valid, sw, rt, norms = _normalized(r, jac, w0)
    res_parts.append(np.where(np.all(np.isfinite(r), axis=1)[:, None], r, np.nan))
    norm_parts.append(norms)
    if cols.size == 0 or not np.any(valid):
        return
    jt = np.where(valid[:, None, None], jac, 0.0) * sw[:, None, None]
    u = np.where(valid, norms, 0.0) / (np.sqrt(k) * scale)
    w = np.where(valid, robust_weights(u, rule, c), 0.0)
    a0 = jt.reshape(-1, cols.size)
    a = (jt * np.sqrt(w)[:, None, None]).reshape(-1, cols.size)
    block = np.ix_(cols, cols)
    normal[block] += a.T @ a
    rhs[cols] += a.T @ (rt * np.sqrt(w)[:, None]).reshape(-1)
    normal0[block] += a0.T @ a0


def robust_cost(norms, k, scale, rule, c, mask=None):
    """Robust objective ``F = sum_i k s^2 rho(u_i)`` over the finite norms (or ``mask``).

    Parameters
    ----------
    norms : ndarray, shape (n,)
        ``||r~_i||``, NaN where invalid.
    k : int
        Residual components per point.
    scale : float
        Scale ``s``.
    rule : str
        Robust function.
    c : float
        Its tuning constant.
    mask : ndarray of bool, shape (n,), optional
        Points counted (default: the finite norms).

    Returns
    -------
    float
        ``F`` in squared normalized residual units.
    """
    good = np.isfinite(norms) if mask is None else mask
    u = norms[good] / (np.sqrt(k) * scale)
    return float(k * scale * scale * np.sum(robust_rho(u, rule, c)))


def prior_cost(x, prior):
    """Cost ``0.5 sum ((G x - v) / sigma)^2`` of the pseudo-observations (0 without a prior).

    Parameters
    ----------
    x : ndarray, shape (P,)
        Parameters.
    prior : Prior or None
        Pseudo-observations.

    Returns
    -------
    float
        The cost.
    """
    if prior is None:
        return 0.0
    return float(0.5 * np.sum(((prior.matrix @ x - prior.value) / prior.sigma) ** 2))


def with_prior(normal, rhs, x, prior):
    """Add ``G^T S^-2 G`` and ``G^T S^-2 (v - G x)`` of the pseudo-observations.

    Parameters
    ----------
    normal : ndarray, shape (P, P)
        Normal matrix.
    rhs : ndarray, shape (P,)
        Right-hand side.
    x : ndarray, shape (P,)
        Parameters.
    prior : Prior or None
        Pseudo-observations.

    Returns
    -------
    normal, rhs : ndarray
        With the prior's terms (unchanged without a prior).
    """
    if prior is None:
        return normal, rhs
    g = prior.matrix / prior.sigma[:, None]
    return normal + g.T @ g, rhs + g.T @ ((prior.value - prior.matrix @ x) / prior.sigma)
