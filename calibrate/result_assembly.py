"""The :class:`~calibrate.calibration_result.CalibrationResult` assembled from a scheme's solver runs.

:func:`assemble_result` takes the last run of each step kind for the estimated values and their
covariance (zero cross blocks between the steps of a stepwise scheme, each block scaled by
``max(1, sigma0^2)``), the residuals before the first and after the last run, the robust weights
and inlier flags at the solution, the per-step log and the one-line summary message.
"""

from __future__ import annotations

import numpy as np

from calibrate.calibration_problem import EXTERIOR
from calibrate.calibration_result import CalibrationResult, residual_statistics
from calibrate.reference_covariance import floor_factor
from calibrate.robust_loss import robust_weights

__all__ = ["assemble_result"]


def assemble_result(model, problem, stepper, skipped, options, bands, ccd_idx, unsettled=""):
    """The :class:`~calibrate.calibration_result.CalibrationResult` of the steps ``stepper`` ran.

    Parameters
    ----------
    model : SensorModel
        The model the steps started from.
    problem : CalibrationProblem
        The grouped points of the steps.
    stepper : Stepper
        Its runs and parameter vectors.
    skipped : list of dict
        CCDs whose interior was not estimated (:func:`calibrate.gcp_groups.mark_estimable`).
    options : CalibrationOptions
        ``scheme``, ``robust``, ``outlier_threshold`` and ``covariance_floor``.
    bands, ccd_idx : ndarray, shape (N,)
        Band name and CCD index of each point.
    unsettled : str
        Why a stepwise scheme did not settle (a failure), or empty.

    Returns
    -------
    CalibrationResult
        Without the reference DOM's covariance term and the attitude record.
    """
    runs, theta0, theta = stepper.runs, stepper.theta0, stepper.theta
    scheme = options.scheme
    last = {}  # the last run of each step kind defines that group's values and covariance
    for step, _outer, result, free in runs:
        last[step] = (result, free)
    estimated = [nm for nm in problem.all_names if any(nm in free for _r, free in last.values())]
    covariance, correlation = _block_covariance(estimated, last, floor=options.covariance_floor is not False)
    idx = np.array([problem.lookup[nm] for nm in estimated], dtype=np.intp)
    before, after, scale, sigma0 = _residuals_before_after(model, problem, runs)
    weights, inlier = _final_weights(problem, after, scale, options)
    success = bool(runs) and all(r.success for _s, _o, r, _f in runs) and not unsettled
    message = _summary_message(runs, success, unsettled, skipped, scheme, after, inlier, problem.order.size,
                               estimated, correlation)  # fmt: skip
    return CalibrationResult(
        success=success,
        message=message,
        scheme=scheme,
        model=model.with_parameters(theta),
        names=tuple(estimated),
        values=theta[idx].copy(),
        initial_values=theta0[idx].copy(),
        covariance=covariance,
        correlation=correlation,
        covariance_kind="joint" if scheme in ("joint", "exterior", "interior") else "conditional-blocks",
        condition_numbers={f"{s_}": float(r.condition_number) for s_, (r, _f) in last.items()},
        steps=_step_log(problem, runs, inlier),
        residuals_before=before,
        residuals_after=after,
        weights=weights,
        inlier=inlier,
        band=bands,
        ccd=ccd_idx,
        skipped=skipped,
        sigma0=float(sigma0),
        scale=float(scale),
        robust=options.robust,
    )


def _block_covariance(estimated, last, floor=True):
    """Covariance of ``estimated`` from each step kind's last run (zero cross blocks), correlation.

    With ``floor`` each block ``sigma0^2 (J^T W J)^-1`` is rescaled to
    ``max(1, sigma0^2) (J^T W J)^-1`` (:func:`calibrate.reference_covariance.floor_factor`): a
    variance factor below 1 does not shrink the a-priori covariance.
    """
    pos = {nm: j for j, nm in enumerate(estimated)}
    covariance = np.zeros((len(estimated), len(estimated))) if estimated else None
    for result, free in last.values():
        if result.covariance is None:
            covariance = None
            break
        j = np.array([pos[nm] for nm in free], dtype=np.intp)
        vf = float(result.sigma0) ** 2
        scale = floor_factor(result.sigma0) / vf if floor and np.isfinite(vf) and vf > 0.0 else 1.0
        covariance[np.ix_(j, j)] = result.covariance * scale
    correlation = None
    if covariance is not None and covariance.size:
        sd = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation = covariance / np.outer(sd, sd)
        np.fill_diagonal(correlation, 1.0)
    return covariance, correlation


def _residuals_before_after(model, problem, runs):
    """Residuals (input order) before the first and after the last run, scale and sigma0."""
    if runs:
        first, final = runs[0][2], runs[-1][2]
        before = problem.to_input_order(first.initial_residuals)
        after = problem.to_input_order(final.residuals)
        return before, after, final.scale, final.sigma0
    before = _project_all(model, problem)  # nothing estimable: evaluate the model once
    return before, before, float("nan"), float("nan")


def _final_weights(problem, after, scale, options):
    """Robust weights and inlier flags of every point at the solution."""
    norms = np.sqrt(problem.weight) * np.hypot(after[:, 0], after[:, 1])
    s = scale if np.isfinite(scale) else 1.0
    u = norms / (np.sqrt(2.0) * s)
    valid = np.isfinite(u) & (problem.weight > 0.0)
    weights = np.where(valid, robust_weights(np.where(valid, u, 0.0), options.robust), 0.0)
    inlier = valid & (u <= options.outlier_threshold)
    return weights, inlier


def _step_log(problem, runs, inlier):
    """One record per run: convergence, cost, scale and residual statistics."""
    steps = []
    for step, outer, result, free in runs:
        res = problem.to_input_order(result.residuals)
        stats = residual_statistics(res, inlier)
        steps.append(
            {
                "step": step,
                "outer": outer,
                "parameters": len(free),
                "success": result.success,
                "message": result.message,
                "iterations": result.iterations,
                "cost": result.cost,
                "scale": result.scale,
                "sigma0": result.sigma0,
                "condition_number": result.condition_number,
                "n_valid": result.n_valid,
                **{k: stats[k] for k in ("rms_row_px", "rms_col_px", "rms_px", "n_inliers")},
                "log": result.log,
            }
        )
    return steps


def _summary_message(runs, success, unsettled, skipped, scheme, after, inlier, n, estimated, correlation):
    """The result's one-line message: failures, convergence, warnings, skipped CCDs."""
    messages = [unsettled]
    if not runs:
        messages.append("nothing to estimate")
    messages += [f"{s_} step (round {o_ + 1}): {r.message}" for s_, o_, r, _f in runs if not r.success]
    if success:
        stats = residual_statistics(after, inlier)
        messages.append(
            f"{scheme} calibration converged ({len(runs)} steps); RMS {stats['rms_px']:.3g} px over "
            f"{stats['n_inliers']} inliers of {n} GCPs"
        )
        for _s, _o, r, _f in runs[-2:]:
            if "warning" in r.message:
                messages.append(r.message.split("; ", 1)[1])
    if scheme == "joint" and success and correlation is not None:
        messages.append(_max_correlation_note(estimated, correlation))
    messages += [rec["reason"] for rec in skipped]
    return "; ".join(m for m in messages if m)


def _project_all(model, problem):
    """Residuals of every GCP under ``model``, input order (when nothing is estimated)."""
    p = problem.points
    out = np.full((problem.order.size, 2), np.nan)
    for g in problem.groups:
        kw = {"band": g.band, "array": g.ccd} if problem.pushbroom else {"band": g.band}
        r, c = model.ground_to_image(p["lon"][g.idx], p["lat"][g.idx], p["h"][g.idx], **kw)
        out[g.idx] = np.stack([p["row"][g.idx] - r, p["col"][g.idx] - c], axis=-1)
    return out


def _max_correlation_note(names, correlation):
    ext = [j for j, nm in enumerate(names) if nm in EXTERIOR]
    other = [j for j, nm in enumerate(names) if nm not in EXTERIOR]
    if not ext or not other:
        return ""
    block = np.abs(correlation[np.ix_(ext, other)])
    i, j = np.unravel_index(np.nanargmax(block), block.shape)
    return (
        f"largest installation/interior correlation {block[i, j]:.4f} "
        f"({names[ext[i]]} vs {names[other[j]]})"
    )
