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
pseudo-observations ``G x = v +- sigma`` (:class:`~calibrate.lsq_inputs.Prior`, e.g. gauge constraints). Each
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
residuals by more than half the scale, the scale of the first
:data:`~calibrate.normal_equations.PROBE_POINTS` points of the evaluation itself (held back
until then: put a representative sample first). This keeps one
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

This module holds :func:`solve`, its iterations (loss and scale switching, damping,
convergence) and its :class:`LsqResult` with the robust covariance. The caller's inputs are
:class:`~calibrate.lsq_inputs.Chunk` and :class:`~calibrate.lsq_inputs.Prior`; the robust
functions and scale live in :mod:`calibrate.robust_loss`, the accumulation of the normal
equations in :mod:`calibrate.normal_equations` and their decomposition and rank diagnostics in
:mod:`calibrate.normal_decomposition`.

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

import numpy as np

from calibrate.lsq_inputs import Prior
from calibrate.normal_decomposition import (Decomposition, covariance_sigma, damped_step, decompose, inverse_diagonal,
                                            summarize_names)
from calibrate.normal_equations import Evaluation, evaluate, prior_cost, robust_cost, with_prior
from calibrate.robust_loss import HUBER_C, TUNING, check_robust_rule, robust_scale, robust_u_dw, robust_weights
from sensor_models.errors import InputError

__all__ = ["LsqResult", "solve"]


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
        return covariance_sigma(self.covariance)


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
        see :class:`~calibrate.lsq_inputs.Chunk`). Every call must yield the same points in the same order;
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
    c_final = TUNING[robust] if tuning is None else float(tuning)
    rule = "huber" if (robust == "cauchy" and not warm_start) else robust
    c = c_huber if rule == "huber" else c_final

    ev = evaluate(residual_and_jacobian_chunks, x, rule, c, scale)
    initial_residuals = ev.residuals.copy()
    # the scale follows the residuals until the iterations are near the solution, then it is
    # frozen (and the loss becomes the final one): the last iterations minimize a fixed function
    # (without a robust loss the weights do not depend on the scale, but the convergence test
    # does: a scale frozen at a far start's residuals would declare convergence too early)
    s = scale if scale is not None else robust_scale(ev.norms, ev.k)
    state = _Irls(chunks=residual_and_jacobian_chunks, names=names, robust=robust, fixed_scale=scale, prior=prior,
                  c_final=c_final, k=ev.k, ev=ev, rule=rule, c=c, s=s, frozen=scale is not None,
                  mu=float(damping))  # fmt: skip
    cost = robust_cost(ev.norms, ev.k, ev.weight_scale, rule, c) + prior_cost(x, prior)
    state.log.append(_log_entry(0, cost, ev.weight_scale, np.nan, np.nan, damping, True, ev, rule))
    return state, initial_residuals


def _checked_start(x0, names, robust, scale, max_iter, prior):
    """Validated starting values and parameter names of :func:`solve`."""
    check_robust_rule(robust)
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
    ev: Evaluation
    rule: str
    c: float
    s: float
    frozen: bool
    mu: float
    s_previous: float = np.inf
    dec: Decomposition | None = None
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
        normal, rhs = with_prior(ev.normal, ev.rhs, ev.x, st.prior)
        st.dec = decompose(normal, st.names, max_condition)
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
    dx = damped_step(st.dec, rhs, st.mu)
    # convergence is judged on the undamped Gauss-Newton step
    sd = np.sqrt(inverse_diagonal(st.dec)) * st.s
    step_sigma = float(np.max(np.abs(damped_step(st.dec, rhs, 0.0) if st.mu > 0.0 else dx) / sd))
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
    ev_new = evaluate(st.chunks, x_new, st.rule, st.c, s_next)
    # the IRLS step minimizes a majorizer of F(.; s_w) at ev.x: compare with that scale
    s_w, rule_w, c_w = ev.weight_scale, ev.rule, ev.c
    both = np.isfinite(ev_new.norms) & np.isfinite(ev.norms)
    old = robust_cost(ev.norms, st.k, s_w, rule_w, c_w, both) + prior_cost(ev.x, st.prior)
    new = robust_cost(ev_new.norms, st.k, s_w, rule_w, c_w, both) + prior_cost(x_new, st.prior)
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
        denom = np.mean(wv + robust_u_dw(uv, rule, c) / k)
        numer = np.sum(wv * wv * uv * uv) / (redundancy / k)
        if denom > 0.0:
            sigma0 = float(s_final * np.sqrt(numer) / denom)
            normal0, _ = with_prior(ev.normal0, np.zeros(n_par), ev.x, prior)
            dec0 = decompose(normal0, names, np.inf)
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
    cost = robust_cost(ev.norms, k, s_final, rule, c) + prior_cost(ev.x, prior)
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
