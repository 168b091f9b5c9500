"""Robust Gauss-Newton / Levenberg-Marquardt least squares on chunked residuals.

The problem
-----------
Observations come in *points*, each with ``k`` residual components (``k = 2`` for image
points: row and column) that share one prior weight and one robust weight. For parameters
``x`` (shape (P,)) the caller supplies, chunk by chunk,

* ``r_i = observed_i - f_i(x)``, shape (n, k): observed minus modelled;
* ``J_i = d f_i / d x``, shape (n, k, p): derivatives of the *model* (not of the residual),
  possibly for a subset of ``p`` of the ``P`` parameters (``columns``);
* ``w0_i``, shape (n,): prior weights, ``1 / sigma_i^2`` in the units of the residuals
  (a zero weight removes the point from the fit but still reports its residual).

With normalized residuals ``r~ = sqrt(w0) r`` and ``J~ = sqrt(w0) J``, the robust size of a
point is the RMS of its normalized components in units of the scale ``s``::

    u_i = ||r~_i|| / (sqrt(k) s)

and the estimate minimizes ``F(x) = sum_i k s^2 rho(u_i)`` plus optional linear
pseudo-observations ``G x = v +- sigma`` (:class:`Prior`, e.g. gauge constraints). Each
iteration solves the reweighted (IRLS) normal equations of seed 000 eq. 12-13
(``dX = (A^T P A)^-1 A^T P L``), accumulated chunk by chunk so that memory does not grow with
the number of points::

    N = sum_i w(u_i) J~_i^T J~_i,     b = sum_i w(u_i) J~_i^T r~_i,     (N + mu D^2) dx = b

with ``w(u) = psi(u) / u`` and ``D^2 = diag(N)`` (Marquardt's scaled damping ``mu``, zero for a
plain Gauss-Newton step; it grows when a step fails to lower ``F``).

Robust functions (``c`` the tuning constant; both give 95 % efficiency at the normal
distribution, Holland & Welsch 1977):

=========  =========================================  ==========================  =========
name       rho(u)                                     w(u)                        c
=========  =========================================  ==========================  =========
none       u^2 / 2                                    1                           -
huber      u^2/2 (u <= c), c u - c^2/2 (u > c)        min(1, c / u)               1.345
cauchy     c^2/2 log(1 + (u/c)^2)                     1 / (1 + (u/c)^2)           2.385
=========  =========================================  ==========================  =========

The Cauchy function redescends, so its minimum need not be unique; iterations therefore start
with Huber weights and switch to Cauchy near the solution (below), unless ``warm_start``.

Scale. Unless given, ``s`` is estimated from the median of the point norms (MAD-type
estimator of the normalized residual scale): for Gaussian errors ``sqrt(k) u s / sigma``
follows a chi distribution with ``k`` degrees of freedom, so
``s = median(||r~||) / sqrt(chi2_k.ppf(0.5))``, i.e. ``1.4826 median |r~|`` for ``k = 1``.
While the iterations are far from the solution the scale follows the residuals: the weights
of an evaluation use the scale of the previous one, or, after a step predicted to change the
residuals by more than half the scale, the scale of the first ``PROBE_POINTS`` points of the
evaluation itself (held back until then: put a representative sample first). This keeps one
pass over the data per iteration. Once the scale changes by less than 2 % between
evaluations and a step is below one standard deviation, or would change the residuals by
less than a tenth of the scale, the scale is frozen at the current residuals' and the loss
becomes the final one (Cauchy after the Huber start), so that the last iterations minimize
a fixed function, as in MM-estimation (a scale from an initial robust fit, then a
redescending M-step): re-estimating the scale at every step can drift for many iterations
when the residuals are a mixture of systematic groups.

Numerics. The normal matrix is Jacobi-equilibrated, ``N_s = D^-1 N D^-1``, and decomposed
with a symmetric eigen-decomposition. Its condition number is reported; parameters no
observation constrains (zero diagonal) and near-null directions (eigenvalues below
``lambda_max / max_condition``) are reported by name and end the solve with
``success=False``. Numerical trouble never raises.

Covariance. For the M-estimator, the asymptotic covariance (Huber 1981, section 7.6, here
written for points of ``k`` isotropic components, with ``w' = dw/du``) is::

    C = sigma0^2 (N0 + N_prior)^-1,   N0 = sum_i J~_i^T J~_i   (prior weights only)
    sigma0^2 = s^2 [sum_i w_i^2 u_i^2 / (m - (P - n_prior) / k)] / [mean_i(w_i + u_i w'_i / k)]^2

over the ``m`` valid points at the solution. Without robust weights it is the classical
``sigma0^2 = sum r~^2 / (m k + n_prior - P)`` and ``C = sigma0^2 N^-1``; with robust weights
it accounts for the down-weighted points, unlike ``sigma0^2 N_w^-1`` computed with the IRLS
weights, which is optimistic by about 10 % in standard deviation for Huber at the normal.

References
----------
P. J. Huber, *Robust Statistics*, Wiley (1981), ch. 7 (regression), section 7.6.
P. W. Holland and R. E. Welsch, "Robust regression using iteratively reweighted
least-squares", Commun. Statist. Theory Methods 6(9), 813-827 (1977).
D. W. Marquardt, "An algorithm for least-squares estimation of nonlinear parameters",
J. SIAM 11(2), 431-441 (1963).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.stats import chi2

from sensor_models.errors import InputError

__all__ = [
    "CAUCHY_C",
    "HUBER_C",
    "Chunk",
    "LsqResult",
    "Prior",
    "robust_scale",
    "robust_weights",
    "solve",
    "summarize_names",
]

#: Huber's tuning constant: 95 % asymptotic efficiency at the normal distribution.
HUBER_C = 1.345
#: Cauchy tuning constant: 95 % asymptotic efficiency at the normal distribution.
CAUCHY_C = 2.3849
_TUNING = {"huber": HUBER_C, "cauchy": CAUCHY_C, "none": np.inf}
#: eigenvector components at least this fraction of the largest name a near-null direction
_PARTICIPATION = 0.3
#: directions whose eigenvalue is this many times below the largest are listed as warnings
WARN_CONDITION = 1e7
#: points from which a provisional robust scale is taken when none is known
PROBE_POINTS = 5000


class Chunk(NamedTuple):
    """One block of points handed to :func:`solve`.

    Attributes
    ----------
    residual : ndarray, shape (n, k) or (n,)
        Observed minus modelled values.
    jacobian : ndarray, shape (n, k, p) or (n, p)
        Derivatives of the modelled values with respect to the parameters ``columns``.
    weight : ndarray, shape (n,), optional
        Prior weights (``1 / sigma^2``); default 1. Zero removes a point from the fit.
    columns : array_like of int, shape (p,), optional
        Positions in ``x`` of the Jacobian's columns; default: all ``P`` parameters.
    """

    residual: np.ndarray
    jacobian: np.ndarray
    weight: np.ndarray | None = None
    columns: Sequence[int] | None = None


@dataclass(frozen=True)
class Prior:
    """Linear pseudo-observations ``matrix @ x = value +- sigma`` (e.g. gauge constraints).

    Attributes
    ----------
    matrix : ndarray, shape (m, P)
    value, sigma : ndarray, shape (m,)

    Their weights ``1 / sigma^2`` are in the units of the prior point weights; they are not
    robustly reweighted. :meth:`fixed` builds ``x[index] = value +- sigma``.
    """

    matrix: np.ndarray
    value: np.ndarray
    sigma: np.ndarray

    def __post_init__(self):
        matrix = np.atleast_2d(np.asarray(self.matrix, dtype=np.float64))
        value = np.asarray(self.value, dtype=np.float64).reshape(-1)
        sigma = np.asarray(self.sigma, dtype=np.float64).reshape(-1)
        if not (matrix.shape[0] == value.size == sigma.size):
            raise InputError("prior matrix rows, values and sigmas must have one length")
        if not np.all(np.isfinite(matrix)) or not np.all(np.isfinite(value)):
            raise InputError("prior matrix and values must be finite")
        if np.any(~(sigma > 0.0)) or np.any(~np.isfinite(sigma)):
            raise InputError("prior sigmas must be positive and finite")
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "sigma", sigma)

    @classmethod
    def fixed(cls, index, value, sigma, n_par: int) -> "Prior":
        """Pseudo-observations of single parameters: ``x[index] = value +- sigma``.

        Parameters
        ----------
        index : int or array_like of int, shape (M,)
            Positions of the held parameters in the parameter vector.
        value, sigma : float or array_like, shape (M,)
            Held values and their standard deviations (parameter units).
        n_par : int
            Number of parameters P.

        Returns
        -------
        Prior
            ``M`` pseudo-observations with a (M, P) selection matrix.
        """
        index = np.asarray(index, dtype=np.intp).reshape(-1)
        if np.any((index < 0) | (index >= n_par)):
            raise InputError("prior index outside the parameter vector")
        matrix = np.zeros((index.size, n_par))
        matrix[np.arange(index.size), index] = 1.0
        return cls(matrix, value, sigma)

    def __len__(self) -> int:
        return self.value.size


@dataclass
class LsqResult:
    """Outcome of :func:`solve`; a failure is a result with ``success=False``.

    Attributes
    ----------
    success : bool
    message : str
        What happened, naming unconstrained or nearly dependent parameters.
    x : ndarray, shape (P,)
        Estimate (the last accepted iterate; ``x0`` when the first step failed).
    covariance, correlation : ndarray, shape (P, P) or None
        ``sigma0^2 (N0 + N_prior)^-1`` (module docstring) and its normalized form.
    condition_number : float
        Of the equilibrated normal matrix at the last step (``inf`` when singular).
    sigma0 : float
        A posteriori standard deviation of unit weight (robust form, module docstring).
    iterations : int
        Steps computed (accepted or not).
    log : list of dict
        Per evaluation: ``iteration``, ``cost`` (``F`` with the scale ``scale`` and robust
        function ``rule`` of the weights the step was computed with), ``step_sigma`` (largest
        step of the undamped step in standard deviations) and ``step_norm`` (equilibrated) of
        the step that led here, its ``damping``, ``accepted``, ``n_valid`` points.
    weights : ndarray, shape (n,)
        Robust weights ``w(u)`` in ``[0, 1]`` at the solution, final scale (0 for invalid
        points).
    residuals : ndarray, shape (n, k)
        Observed minus modelled at ``x`` (NaN where the model gave no value).
    names : tuple of str
    scale : float
        Robust scale ``s`` of the normalized residuals at the solution.
    u : ndarray, shape (n,)
        Normalized residual sizes ``u_i`` at the solution (NaN for invalid points).
    initial_residuals : ndarray, shape (n, k)
        Residuals at ``x0``.
    n_points, n_valid : int
        Points seen and points with finite residuals and positive weight at the solution.
    redundancy : float
        ``m k + n_prior - P``.
    cost : float
        ``F(x)`` at the solution (with the final scale).
    unconstrained : tuple of str
        Parameters no observation constrains.
    near_dependent : list of tuple of str
        Groups of parameters spanning near-null directions (eigenvalues below
        ``lambda_max / 1e7`` at the last step), reported even when solvable.
    """

    success: bool
    message: str
    x: np.ndarray
    covariance: np.ndarray | None
    correlation: np.ndarray | None
    condition_number: float
    sigma0: float
    iterations: int
    log: list = field(default_factory=list)
    weights: np.ndarray | None = None
    residuals: np.ndarray | None = None
    names: tuple = ()
    scale: float = float("nan")
    u: np.ndarray | None = None
    initial_residuals: np.ndarray | None = None
    n_points: int = 0
    n_valid: int = 0
    redundancy: float = float("nan")
    cost: float = float("nan")
    unconstrained: tuple = ()
    near_dependent: list = field(default_factory=list)

    @property
    def sigma(self) -> np.ndarray | None:
        """Standard deviations of the parameters, shape (P,), or None.

        Returns
        -------
        ndarray, shape (P,), or None
            Square roots of the covariance diagonal (parameter units); None without a covariance.
        """
        if self.covariance is None:
            return None
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


# --------------------------------------------------------------------------- robust functions
def _check_rule(robust):
    if robust not in _TUNING:
        raise InputError(f"robust must be one of {', '.join(_TUNING)}, got {robust!r}", field="robust")


def robust_weights(u, robust: str, c: float | None = None) -> np.ndarray:
    """IRLS weights ``w(u) = psi(u) / u`` (table in the module docstring), shape of ``u``.

    Parameters
    ----------
    u : ndarray
        Normalized residual norms (residual / scale), >= 0.
    robust : {"huber", "cauchy", "none"}
        Loss.
    c : float, optional
        Tuning constant (default: the loss's, module docstring).

    Returns
    -------
    ndarray
        Weights in [0, 1], shape of ``u``.
    """
    _check_rule(robust)
    u = np.asarray(u, dtype=np.float64)
    c = _TUNING[robust] if c is None else float(c)
    if robust == "none":
        return np.ones_like(u)
    if robust == "huber":
        return np.where(u > c, c / np.maximum(u, 1e-300), 1.0)
    return 1.0 / (1.0 + (u / c) ** 2)


def _rho(u, robust, c):
    if robust == "none":
        return 0.5 * u * u
    if robust == "huber":
        return np.where(u <= c, 0.5 * u * u, c * u - 0.5 * c * c)
    return 0.5 * c * c * np.log1p((u / c) ** 2)


def _u_dw(u, robust, c):
    """``u * w'(u)``."""
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


# --------------------------------------------------------------------------- names
def summarize_names(names: Sequence[str], universe: Sequence[str] | None = None, *, limit: int = 12) -> str:
    """Compact, readable list of parameter names.

    Names sharing a dotted prefix are written ``prefix.*`` when every name of ``universe``
    (default: ``names``) with that prefix is in ``names``, e.g. ``B3.ccd2.*``.

    Parameters
    ----------
    names : sequence of str
        Names to list.
    universe : sequence of str, optional
        Every name that could appear (decides when ``prefix.*`` is exact); default ``names``.
    limit : int
        Most items written; the rest are counted (``and 3 more``).

    Returns
    -------
    str
        Comma-separated list.
    """
    names = list(dict.fromkeys(names))
    universe = list(universe) if universe is not None else names
    chosen = set(names)
    out, covered = [], set()
    for name in names:
        if name in covered:
            continue
        parts = name.split(".")
        label = name
        # the shortest complete prefix, keeping two components of long names (B3.ccd2.*)
        for cut in range(1 if len(parts) < 3 else 2, len(parts)):
            prefix = ".".join(parts[:cut]) + "."
            members = [n for n in universe if n.startswith(prefix)]
            if len(members) > 1 and all(n in chosen for n in members):
                label = prefix + "*"
                covered.update(members)
                break
        covered.add(name)
        out.append(label)
    if len(out) > limit:
        return ", ".join(out[:limit]) + f" and {len(out) - limit} more"
    return ", ".join(out)


# --------------------------------------------------------------------------- evaluation
@dataclass
class _Evaluation:
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


def _evaluate(chunks, x, rule, c, scale):
    """One pass over the chunks at ``x``: normal equations and residuals.

    ``scale`` is the robust scale of the weights; without one, chunks are held back until
    :data:`PROBE_POINTS` points give a provisional scale.
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
    return _Evaluation(
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


def _robust_cost(norms, k, scale, rule, c, mask=None):
    good = np.isfinite(norms) if mask is None else mask
    u = norms[good] / (np.sqrt(k) * scale)
    return float(k * scale * scale * np.sum(_rho(u, rule, c)))


def _prior_cost(x, prior):
    if prior is None:
        return 0.0
    return float(0.5 * np.sum(((prior.matrix @ x - prior.value) / prior.sigma) ** 2))


def _with_prior(normal, rhs, x, prior):
    """Add ``G^T S^-2 G`` and ``G^T S^-2 (v - G x)`` of the pseudo-observations."""
    if prior is None:
        return normal, rhs
    g = prior.matrix / prior.sigma[:, None]
    return normal + g.T @ g, rhs + g.T @ ((prior.value - prior.matrix @ x) / prior.sigma)


# --------------------------------------------------------------------------- linear algebra
@dataclass
class _Decomposition:
    ok: bool
    message: str
    d: np.ndarray  # sqrt(diag N)
    eigval: np.ndarray
    eigvec: np.ndarray
    condition: float
    unconstrained: tuple
    near_dependent: list


def _decompose(normal, names, max_condition):
    """Equilibrated eigen-decomposition with rank diagnostics."""
    diag = np.diag(normal).copy()
    if not np.all(np.isfinite(normal)):
        msg = "the normal equations hold NaN or infinite values"
        return _Decomposition(False, msg, diag, None, None, np.inf, (), [])
    zero = ~(diag > 0.0)
    if np.any(zero):
        bad = tuple(n for n, z in zip(names, zero) if z)
        msg = f"no observations constrain {summarize_names(bad, names)}"
        return _Decomposition(False, msg, np.sqrt(np.abs(diag)), None, None, np.inf, bad, [])
    d = np.sqrt(diag)
    ns = normal / np.outer(d, d)
    ns = 0.5 * (ns + ns.T)
    try:
        lam, vec = np.linalg.eigh(ns)
    except np.linalg.LinAlgError as exc:  # pragma: no cover - LAPACK failure
        return _Decomposition(False, f"eigen-decomposition failed: {exc}", d, None, None, np.inf, (), [])
    lam_max = float(lam[-1])
    condition = lam_max / float(lam[0]) if lam[0] > 0.0 else np.inf

    def groups(threshold):
        out = []
        for i in np.nonzero(~(lam * threshold > lam_max))[0]:
            v = np.abs(vec[:, i])
            order = np.argsort(-v)
            keep = order[v[order] >= _PARTICIPATION * v[order[0]]]
            out.append(tuple(names[j] for j in keep))
        return out

    near = groups(WARN_CONDITION)
    if not condition <= max_condition:
        bad = "; ".join(summarize_names(g, names) for g in groups(max_condition))
        msg = (
            f"ill-conditioned normal equations (condition number {condition:.3g} > {max_condition:.3g}): "
            f"parameters {bad} are nearly dependent"
        )
        return _Decomposition(False, msg, d, lam, vec, condition, (), near)
    return _Decomposition(True, "", d, lam, vec, condition, (), near)


def _step(dec, rhs, damping):
    """``dx = D^-1 V (V^T D^-1 b) / (lambda + mu)``."""
    bs = rhs / dec.d
    coef = (dec.eigvec.T @ bs) / (dec.eigval + damping)
    return (dec.eigvec @ coef) / dec.d


def _inverse_diag(dec):
    """``diag(N^-1)`` from the decomposition."""
    return np.sum(dec.eigvec**2 / dec.eigval[None, :], axis=1) / dec.d**2


# --------------------------------------------------------------------------- solver
def solve(
    residual_and_jacobian_chunks: Callable[[np.ndarray], Iterable],
    x0,
    *,
    names: Sequence[str] | None = None,
    robust: str = "huber",
    scale: float | None = None,
    tuning: float | None = None,
    max_iter: int = 30,
    tol: float = 1e-2,
    damping: float = 0.0,
    prior: Prior | None = None,
    max_condition: float = 1e10,
    warm_start: bool = False,
) -> LsqResult:
    """Minimize a robust sum of squares by Gauss-Newton / Levenberg-Marquardt with IRLS.

    Parameters
    ----------
    residual_and_jacobian_chunks : callable
        ``f(x) -> iterable of Chunk`` (or tuples ``(residual, jacobian[, weight[, columns]])``,
        see :class:`Chunk`). Every call must yield the same points in the same order;
        points whose residual or Jacobian is not finite are left out of that iteration.
    x0 : array_like, shape (P,)
        Starting values.
    names : sequence of str, optional
        Parameter names used in messages (default ``x0, x1, ...``).
    robust : {"huber", "cauchy", "none"}
        Robust loss (module docstring).
    scale : float, optional
        Fixed scale ``s`` of the normalized residuals (e.g. 1 when the prior weights are
        honest ``1 / sigma^2``); default: estimated robustly at each iteration.
    tuning : float, optional
        Tuning constant (default 1.345 for Huber, 2.385 for Cauchy).
    max_iter : int
        Maximum number of steps.
    tol : float
        Convergence when every parameter's step is below ``tol`` of its standard deviation
        (``|dx_j| < tol * s * sqrt((N^-1)_jj)``).
    damping : float
        Initial Marquardt damping ``mu`` (0: Gauss-Newton first). It becomes at least 1e-3
        after a step that raises the cost and shrinks tenfold after each accepted one.
    prior : Prior, optional
        Pseudo-observations on some parameters.
    max_condition : float
        Largest acceptable condition number of the equilibrated normal matrix.
    warm_start : bool
        ``x0`` is already near the solution: a redescending loss (Cauchy) is used from the
        first iteration instead of after a Huber start (the scale still follows the
        residuals until it is frozen).

    Returns
    -------
    LsqResult
        ``success=False`` with a message for rank deficiency, ill-conditioning, no
        convergence or no usable observations; never raises for numerical trouble.

    Raises
    ------
    InputError
        For malformed arguments or chunks (a programming or user error, not numerics).
    """
    x, names = _checked_start(x0, names, robust, scale, max_iter, prior)
    n_par = x.size
    state, initial_residuals = _start_state(residual_and_jacobian_chunks, x, names, robust=robust, scale=scale,
                                            tuning=tuning, warm_start=warm_start, prior=prior, damping=damping)
    n_prior = 0 if prior is None else len(prior)
    success, message = _iterate(state, n_par, n_prior, max_iter, tol, max_condition)
    return _finish(state.ev, state.dec, success, message, names, state.s, prior, state.iterations, state.log,
                   initial_residuals)  # fmt: skip


def _start_state(residual_and_jacobian_chunks, x, names, *, robust, scale, tuning, warm_start, prior, damping):
    """The IRLS state at ``x`` (first evaluation, loss, scale, log entry 0) and the initial residuals."""
    c_huber = HUBER_C if (tuning is None or robust != "huber") else float(tuning)
    c_final = _TUNING[robust] if tuning is None else float(tuning)
    rule = "huber" if (robust == "cauchy" and not warm_start) else robust
    c = c_huber if rule == "huber" else c_final

    ev = _evaluate(residual_and_jacobian_chunks, x, rule, c, scale)
    initial_residuals = ev.residuals.copy()
    # the scale follows the residuals until the iterations are near the solution, then it is
    # frozen (and the loss becomes the final one): the last iterations minimize a fixed function
    # (without a robust loss the weights do not depend on the scale, but the convergence test
    # does: a scale frozen at a far start's residuals would declare convergence too early)
    s = scale if scale is not None else robust_scale(ev.norms, ev.k)
    state = _Irls(chunks=residual_and_jacobian_chunks, names=names, robust=robust, fixed_scale=scale, prior=prior,
                  c_final=c_final, k=ev.k, ev=ev, rule=rule, c=c, s=s, frozen=scale is not None,
                  mu=float(damping))  # fmt: skip
    cost = _robust_cost(ev.norms, ev.k, ev.weight_scale, rule, c) + _prior_cost(x, prior)
    state.log.append(_log_entry(0, cost, ev.weight_scale, np.nan, np.nan, damping, True, ev, rule))
    return state, initial_residuals


def _checked_start(x0, names, robust, scale, max_iter, prior):
    """Validated starting values and parameter names of :func:`solve`."""
    _check_rule(robust)
    x = np.asarray(x0, dtype=np.float64).reshape(-1).copy()
    n_par = x.size
    if n_par == 0:
        raise InputError("x0 is empty: nothing to estimate")
    if not np.all(np.isfinite(x)):
        raise InputError("x0 holds NaN or infinite values")
    names = tuple(f"x{i}" for i in range(n_par)) if names is None else tuple(names)
    if len(names) != n_par:
        raise InputError(f"{len(names)} names for {n_par} parameters")
    if scale is not None and not (np.isfinite(scale) and scale > 0.0):
        raise InputError("scale must be positive and finite", field="scale")
    if int(max_iter) < 1:
        raise InputError("must be >= 1", field="max_iter")
    if prior is not None and prior.matrix.shape[1] != n_par:
        raise InputError(f"prior matrix has {prior.matrix.shape[1]} columns for {n_par} parameters")
    return x, names


@dataclass
class _Irls:
    """State of the iterations of :func:`solve` (current evaluation, scale, loss, damping, log)."""

    chunks: Callable
    names: tuple
    robust: str
    fixed_scale: float | None
    prior: Prior | None
    c_final: float
    k: int
    ev: _Evaluation
    rule: str
    c: float
    s: float
    frozen: bool
    mu: float
    s_previous: float = np.inf
    dec: _Decomposition | None = None
    iterations: int = 0
    rejections: int = 0
    last_step: float = np.inf
    log: list = field(default_factory=list)


def _iterate(st: _Irls, n_par, n_prior, max_iter, tol, max_condition):
    """Gauss-Newton / Levenberg-Marquardt iterations until a stop; ``(success, message)``."""
    while True:
        ev = st.ev
        n_valid = int(np.sum(np.isfinite(ev.norms)))
        if n_valid * st.k + n_prior <= n_par:
            return False, f"too few observations: {n_valid} valid points x {st.k} components for {n_par} parameters"
        normal, rhs = _with_prior(ev.normal, ev.rhs, ev.x, st.prior)
        st.dec = _decompose(normal, st.names, max_condition)
        if not st.dec.ok:
            return False, st.dec.message
        if st.iterations >= max_iter:
            return False, f"no convergence after {max_iter} iterations (last step {st.last_step:.3g} sigma)"
        dx, step_sigma = _gauss_newton_step(st, rhs)
        if not np.all(np.isfinite(dx)):
            return False, "the step is not finite"
        st.last_step = step_sigma
        if _converged(st, step_sigma, tol):
            return True, f"converged after {st.iterations} iterations"
        # RMS change of the residuals the step will make (from the normal equations)
        predicted = float(np.sqrt(max(dx @ normal @ dx, 0.0) / max(n_valid * st.k, 1)))
        _maybe_freeze(st, step_sigma, predicted)
        st.iterations += 1
        _try_step(st, dx, step_sigma, predicted)
        if st.rejections >= 12:
            return False, "the cost could not be reduced (12 rejected steps)"


def _gauss_newton_step(st: _Irls, rhs):
    """The damped step and the undamped one's largest size in standard deviations."""
    dx = _step(st.dec, rhs, st.mu)
    # convergence is judged on the undamped Gauss-Newton step
    sd = np.sqrt(_inverse_diag(st.dec)) * st.s
    step_sigma = float(np.max(np.abs(_step(st.dec, rhs, 0.0) if st.mu > 0.0 else dx) / sd))
    return dx, step_sigma


def _converged(st: _Irls, step_sigma, tol) -> bool:
    """A negligible step from weights of the final loss and scale.

    The final scale is the frozen one, or one within 1 % of the current residuals' scale.
    """
    ev = st.ev
    if st.frozen:
        final_scale = st.fixed_scale is not None or ev.weight_scale == st.s
    else:
        final_scale = abs(ev.weight_scale / st.s - 1.0) < 0.01
    return step_sigma < tol and ev.rule == st.robust and final_scale


def _maybe_freeze(st: _Irls, step_sigma, predicted):
    """Near the solution the scale has settled: freeze it and switch to the final loss."""
    stable = abs(st.s_previous / st.s - 1.0) < 0.02  # between the last two accepted evaluations
    if not st.frozen and stable and (step_sigma < 1.0 or predicted < 0.1 * st.s):
        # the residuals no longer move on the scale of their spread
        st.frozen = True
        st.rule, st.c = st.robust, st.c_final


def _try_step(st: _Irls, dx, step_sigma, predicted):
    """Evaluate ``x + dx``; accept it if the robust cost does not rise, else raise the damping."""
    ev = st.ev
    mu_used = st.mu
    x_new = ev.x + dx
    # far from the solution, when the step changes the residuals by more than half their
    # scale, the previous scale is stale: take it from the first points instead
    s_next = None if (not st.frozen and predicted > 0.5 * st.s) else st.s
    ev_new = _evaluate(st.chunks, x_new, st.rule, st.c, s_next)
    # the IRLS step minimizes a majorizer of F(.; s_w) at ev.x: compare with that scale
    s_w, rule_w, c_w = ev.weight_scale, ev.rule, ev.c
    both = np.isfinite(ev_new.norms) & np.isfinite(ev.norms)
    old = _robust_cost(ev.norms, st.k, s_w, rule_w, c_w, both) + _prior_cost(ev.x, st.prior)
    new = _robust_cost(ev_new.norms, st.k, s_w, rule_w, c_w, both) + _prior_cost(x_new, st.prior)
    accepted = bool(np.any(both) and np.isfinite(new) and new <= old * (1.0 + 1e-12) + 1e-300)
    if accepted:
        st.ev = ev_new
        if not st.frozen:
            st.s_previous, st.s = st.s, robust_scale(ev_new.norms, st.k)
        st.mu = 0.0 if st.mu < 1e-7 else st.mu / 10.0
        st.rejections = 0
    else:
        st.mu = max(1e-3, 10.0 * st.mu)
        st.rejections += 1
    step_norm = float(np.linalg.norm(dx * st.dec.d))
    st.log.append(_log_entry(st.iterations, new, s_w, step_sigma, step_norm, mu_used, accepted, ev_new, rule_w))


def _log_entry(iteration, cost, scale, step_sigma, step_norm, damping, accepted, ev, rule):
    return {
        "iteration": int(iteration),
        "cost": float(cost),
        "scale": float(scale),
        "step_sigma": float(step_sigma),
        "step_norm": float(step_norm),
        "damping": float(damping),
        "accepted": bool(accepted),
        "n_valid": int(np.sum(np.isfinite(ev.norms))),
        "rule": rule,
    }


def _finish(ev, dec, success, message, names, scale, prior, iterations, log, initial_residuals):
    """Weights, robust covariance and diagnostics at the last accepted evaluation."""
    rule, c = ev.rule, ev.c
    k = ev.k
    n_par = ev.x.size
    n_prior = 0 if prior is None else len(prior)
    valid = np.isfinite(ev.norms)
    m = int(np.sum(valid))
    s_final = scale
    u = ev.norms / (np.sqrt(k) * s_final)
    weights = np.where(valid, robust_weights(np.where(valid, u, 0.0), rule, c), 0.0)
    redundancy = m * k + n_prior - n_par
    covariance = correlation = None
    sigma0 = float("nan")
    condition = float(dec.condition) if dec is not None else float("nan")
    result_msg = message
    if success and redundancy > 0:
        uv, wv = u[valid], weights[valid]
        denom = np.mean(wv + _u_dw(uv, rule, c) / k)
        numer = np.sum(wv * wv * uv * uv) / (redundancy / k)
        if denom > 0.0:
            sigma0 = float(s_final * np.sqrt(numer) / denom)
            normal0, _ = _with_prior(ev.normal0, np.zeros(n_par), ev.x, prior)
            dec0 = _decompose(normal0, names, np.inf)
            if dec0.ok and np.all(dec0.eigval > 0.0):
                inv = (dec0.eigvec / dec0.eigval[None, :]) @ dec0.eigvec.T
                covariance = sigma0**2 * inv / np.outer(dec0.d, dec0.d)
                sd = np.sqrt(np.diag(covariance))
                correlation = covariance / np.outer(sd, sd)
                np.fill_diagonal(correlation, 1.0)
            else:
                success, result_msg = False, "converged, but the covariance is singular: " + dec0.message
        else:
            success, result_msg = False, "converged, but no point keeps a usable weight: covariance undefined"
    elif success:
        success, result_msg = False, "no redundancy: as many observations as parameters"
    if success and dec is not None and dec.near_dependent:
        groups = "; ".join(summarize_names(g, names) for g in dec.near_dependent)
        result_msg += f"; warning: condition number {condition:.3g}, nearly dependent: {groups}"
    cost = _robust_cost(ev.norms, k, s_final, rule, c) + _prior_cost(ev.x, prior)
    return LsqResult(
        success=bool(success),
        message=result_msg,
        x=ev.x.copy(),
        covariance=covariance,
        correlation=correlation,
        condition_number=condition,
        sigma0=sigma0,
        iterations=int(iterations),
        log=log,
        weights=weights,
        residuals=ev.residuals,
        names=tuple(names),
        scale=float(s_final),
        u=np.where(valid, u, np.nan),
        initial_residuals=initial_residuals,
        n_points=int(ev.norms.size),
        n_valid=m,
        redundancy=float(redundancy),
        cost=cost,
        unconstrained=dec.unconstrained if dec is not None else (),
        near_dependent=list(dec.near_dependent) if dec is not None else [],
    )
