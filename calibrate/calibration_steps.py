"""The steps of a calibration scheme: which parameters each solve frees, in what order.

:class:`Stepper` runs the robust solver (:func:`calibrate.lsq.solve`) step after step on one
:class:`~calibrate.calibration_problem.CalibrationProblem`, keeping the parameter vector and
the log of runs (the attitude coefficients, when free, are held near zero by a ridge).
:func:`run_scheme` runs the steps of ``CalibrationOptions.scheme`` (the table is in
:mod:`calibrate.absolute`): the joint solve with its gauge (:mod:`calibrate.gauge_priors`), the
exterior or the interior alone, or the two in turn until the exterior no longer moves.
"""

from __future__ import annotations

import numpy as np

from calibrate import attitude as _attitude
from calibrate.gauge_priors import gauge_prior, staring_gauge_prior
from calibrate.lsq import LsqResult, solve
from calibrate.lsq_inputs import Prior
from sensor_models.errors import InputError

__all__ = ["Stepper", "run_scheme"]


def _every(_group):
    return True


def _estimable(group):
    return group.estimable


class Stepper:
    """Runs the solver step after step on one problem, keeping the parameter vector and log.

    Parameters
    ----------
    problem : CalibrationProblem
        The grouped points and their residual function.
    options : CalibrationOptions
        Robust loss, stopping rules and ``max_extrapolation`` of every step.

    Attributes
    ----------
    theta0, theta : ndarray, shape (P,)
        Initial and current values of every model parameter.
    runs : list of tuple
        ``(step, outer, LsqResult, free names)`` per run, in order.
    """

    def __init__(self, problem, options):
        self.problem = problem
        self.options = options
        self.theta0 = problem.model.parameters().values.copy()
        self.theta = self.theta0.copy()
        self.runs: list[tuple[str, int, LsqResult, tuple]] = []

    def run(self, step, outer, free, active, prior=None):
        """Solve for the ``free`` names on the groups ``active`` selects; update ``theta``."""
        opt = self.options
        free = tuple(free)
        idx = np.array([self.problem.lookup[n] for n in free], dtype=np.intp)
        prior = _with_attitude_ridge(prior, free)
        chunks = self.problem.chunks_for(self.theta, free, active, opt.max_extrapolation)
        # after the first step the model is close: a redescending loss can start at once
        result = solve(chunks, self.theta[idx], names=free, prior=prior, warm_start=bool(self.runs),
                       robust=opt.robust, max_iter=opt.max_iter, tol=opt.tol,
                       max_condition=opt.max_condition)  # fmt: skip
        self.theta = self.theta.copy()
        self.theta[idx] = result.x
        self.runs.append((step, outer, result, free))
        return result

    def values_of(self, names):
        """Current values of ``names``."""
        return self.theta[[self.problem.lookup[n] for n in names]].copy()


def _with_attitude_ridge(prior, free):
    """``prior`` plus ``c = 0 +- REGULARIZATION_SIGMA_RAD`` on the free attitude coefficients."""
    ridge = [j for j, n in enumerate(free) if n.startswith("attitude.")]
    if not ridge:
        return prior
    axis = [("roll", "pitch", "yaw").index(free[j].split(".")[1]) for j in ridge]
    sigma = np.asarray(_attitude.REGULARIZATION_SIGMA_RAD, dtype=float)[axis]
    extra = Prior.fixed(ridge, np.zeros(len(ridge)), sigma, len(free))
    if prior is None:
        return extra
    return Prior(np.vstack([prior.matrix, extra.matrix]), np.concatenate([prior.value, extra.value]),
                 np.concatenate([prior.sigma, extra.sigma]))


def run_scheme(stepper, model, groups, options):
    """Run the steps of ``options.scheme``; a message when the stepwise schemes did not settle.

    Parameters
    ----------
    stepper : Stepper
        Runs the solves (its ``runs`` grow).
    model : SensorModel
        The model calibrated (the gauge's initial values).
    groups : list
        Point groups with their ``estimable`` flags (:mod:`calibrate.gcp_groups`).
    options : CalibrationOptions
        ``scheme``, ``parameters``, gauge settings, ``max_outer`` and ``outer_tol``.

    Returns
    -------
    str
        Empty, or why the stepwise scheme had not settled after ``max_outer`` rounds.

    Raises
    ------
    InputError
        Unknown names in ``options.parameters``.
    """
    problem = stepper.problem
    staged = problem.staged
    exterior = list(problem.exterior) if staged else []
    interior = [n for g in groups if g.estimable for n in g.interior]
    scheme = options.scheme
    if scheme == "joint":
        free = _joint_free(problem, exterior, interior, options.parameters)
        prior = None
        if options.gauge and problem.pushbroom:
            prior = gauge_prior(model, groups, free, options.reference_ccd, options.gauge_sigma_px)
        elif options.gauge and staged:
            prior = staring_gauge_prior(model, free, options.gauge_sigma_px)
        stepper.run("joint", 0, free, _every, prior)
    elif scheme == "exterior":
        stepper.run("exterior", 0, exterior, _every)
    elif scheme == "interior":
        if interior:
            stepper.run("interior", 0, interior, _estimable)
    else:
        return _alternate(stepper, exterior, interior, options)
    return ""


def _joint_free(problem, exterior, interior, parameters):
    """Names estimated by the joint scheme (``parameters`` or exterior + estimable interior)."""
    if parameters is None:
        return exterior + interior if problem.staged else list(problem.all_names)
    unknown = [p for p in parameters if p not in problem.lookup]
    if unknown:
        raise InputError(f"unknown parameters {', '.join(unknown)}", field="parameters")
    return [n for n in problem.all_names if n in set(parameters)]


def _alternate(stepper, exterior, interior, options):
    """Stepwise schemes: exterior and interior in turn until the exterior no longer moves."""
    scheme, max_outer = options.scheme, options.max_outer
    order = ("exterior", "interior") if scheme == "exterior-interior" else ("interior", "exterior")
    moved = np.inf
    for outer in range(max(1, int(max_outer))):
        stop = False
        for step in order:
            if step == "interior":
                if not interior:
                    continue
                result = stepper.run("interior", outer, interior, _estimable)
            else:
                # the first exterior step uses every GCP; later ones only those of CCDs
                # whose interior is estimated: a CCD holding its laboratory interior would
                # drag the frame towards it, a little more each round
                before = stepper.values_of(exterior)
                result = stepper.run("exterior", outer, exterior, _every if outer == 0 else _estimable)
                moved = _moved_sigmas(before, result)
                # the exterior no longer moves: the interior, fitted in this frame, holds
                if moved < options.outer_tol and (outer > 0 or order[0] == "interior" or not interior):
                    stop = True
            if not result.success or stop:
                break
        if stop or not stepper.runs[-1][2].success:
            return ""
    if interior and max_outer > 1:  # one round (seed 003's single pass) was asked for
        return (
            f"{scheme}: the exterior still moved {moved:.3g} standard deviations in round "
            f"{max_outer} (max_outer); alternating steps converge slowly when the groups "
            "conflict (e.g. a CCD whose interior is not estimated); try scheme='joint'"
        )
    return ""


def _moved_sigmas(before, result):
    sd = result.sigma
    if sd is None or not result.success:
        return np.inf
    return float(np.max(np.abs(result.x - before) / np.where(sd > 0, sd, np.inf)))
