"""The time-varying attitude correction of a push-broom calibration, chosen and solved in rounds.

After the static calibration, :func:`time_varying_attitude` fits the candidate bases
(:func:`calibrate.attitude.candidate_corrections`) to the static residuals, keeps the one the
BIC chooses (:func:`calibrate.attitude.select_correction`) and solves it with the exterior and
interior in one pass of the scheme; then up to :data:`ATTITUDE_REFINE_ROUNDS` rounds choose and
solve it again around the new solution (docs/attitude.md).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibrate import attitude as _attitude
from calibrate.calibration_problem import CalibrationProblem
from calibrate.calibration_steps import Stepper, run_scheme
from calibrate.pspline import recovered_spectrum
from calibrate.result_assembly import assemble_result

__all__ = ["ATTITUDE_REFINE_ROUNDS", "ATTITUDE_REFINE_TOL_URAD", "time_varying_attitude"]

#: further rounds of the time-varying attitude after the first (choice and one pass of the scheme)
ATTITUDE_REFINE_ROUNDS = 2
#: the rounds stop when the correction moves by less than this, micro-radians rms over the lines
ATTITUDE_REFINE_TOL_URAD = 0.05


def _select_attitude(static, points, weight, groups, options):
    """Candidate bases fitted to the static residuals; the chosen one (calibrate.attitude).

    When ``static.model`` carries a correction (a refinement round), its linear effect is
    added back to the residuals, so that every candidate is fitted to "static" residuals.
    """
    fitted = static.model
    n = points["row"].size
    jac_delta = np.full((n, 2, 3), np.nan)
    for g in groups:
        _, _, jac_delta[g.idx] = fitted.attitude_angle_jacobian(
            points["lon"][g.idx], points["lat"][g.idx], points["h"][g.idx], band=g.band, array=g.ccd)
    seconds = fitted.line_timing.seconds(points["row"])
    t0, t1 = sorted(float(t) for t in fitted.line_timing.seconds(np.array(fitted.row_range)))
    w = weight * np.where(static.inlier, static.weights, 0.0)
    used = (w > 0) & np.isfinite(seconds)
    t_img = sorted(float(t) for t in fitted.line_timing.seconds(np.array([0.0, float(fitted.n_rows)])))
    candidates = _attitude.candidate_corrections(
        options.attitude, t0, t1, n_points=int(np.sum(used)), n_lines=float(np.diff(fitted.row_range)[0]),
        seconds=seconds[used], image_span_s=t_img[1] - t_img[0], min_span_fraction=options.min_span_fraction,
        support_s=(float(np.min(seconds[used])), float(np.max(seconds[used]))) if np.any(used) else None)
    yaw = None if options.attitude_yaw_sigma_urad is None else options.attitude_yaw_sigma_urad * 1e-6
    residuals = static.residuals_after
    base = getattr(fitted, "attitude_correction", None)
    if base is not None:
        residuals = residuals + np.einsum("nia,na->ni", jac_delta, base.angles(seconds))
    chosen, covariance, table = _attitude.select_correction(jac_delta, seconds, residuals, w,
                                                            candidates, yaw_sigma_rad=yaw)
    return chosen, covariance, table, seconds, w, t_img


def time_varying_attitude(model, static, points, weight, groups, skipped, options, bands, ccd_idx):
    """Choose the attitude basis around the static solution; solve it with exterior and interior.

    Then up to :data:`ATTITUDE_REFINE_ROUNDS` rounds choose it again around the new exterior and
    interior (which no longer carry what the attitude error had bent them by) and solve them
    once more, until the correction moves by less than :data:`ATTITUDE_REFINE_TOL_URAD` rms.

    Parameters
    ----------
    model : PushbroomModel
        The initial model (without a correction): the starting values of every round.
    static : CalibrationResult
        The static calibration.
    points, weight, groups, skipped
        The points, their prior weights, groups and skip records of the static calibration.
    options : CalibrationOptions
        ``attitude`` (the candidate bases) and the scheme's settings.
    bands, ccd_idx : ndarray, shape (N,)
        Band name and CCD index of each point.

    Returns
    -------
    CalibrationResult
        With the correction solved, or ``static`` when none is chosen or its solve fails;
        ``attitude`` records the choice (and ``rounds``).
    """
    result = _attitude_round(model, static, static, points, weight, groups, skipped, options, bands, ccd_idx)
    if result.model is static.model or result.attitude.get("failed"):
        return result
    rounds = 1
    for _ in range(ATTITUDE_REFINE_ROUNDS):
        again = _attitude_round(model, static, result, points, weight, groups, skipped, options, bands, ccd_idx)
        if again.attitude.get("failed") or again.model.attitude_correction is None:
            break
        t = result.model.line_timing.seconds(np.linspace(0.0, float(result.model.n_rows), 512))
        moved = float(np.sqrt(np.mean(np.square(again.model.attitude_correction.angles(t)
                                                 - result.model.attitude_correction.angles(t))))) * 1e6
        result, rounds = again, rounds + 1
        if moved < ATTITUDE_REFINE_TOL_URAD:
            break
    result.attitude["rounds"] = rounds
    return result


def _attitude_round(model, static, around, points, weight, groups, skipped, options, bands, ccd_idx):
    """One choice of the correction around ``around`` and one pass of the scheme with it held."""
    chosen, covariance, table, seconds, w, t_img = _select_attitude(around, points, weight, groups, options)
    info = _attitude.selection_info(options.attitude, chosen, table)
    if chosen is None:
        return replace(static, attitude=info)
    # the correction's mean over the GCPs is a constant rotation: the installation takes it
    mean = np.average(chosen.angles(seconds), axis=0, weights=w)
    if chosen.kind == "spline":  # the B-splines sum to one
        chosen = chosen.with_coefficients(chosen.coefficients_rad - mean[:, None])
    info["coefficients_covariance_rad2"] = covariance
    spectrum = _attitude.jitter_spectrum(chosen, *t_img)
    info["jitter"] = {axis: v["peak"] for axis, v in spectrum["axes"].items()}
    info["spectrum"] = recovered_spectrum(chosen, *t_img)
    start = around.model.with_attitude_correction(chosen)
    # one pass of the scheme with the correction held, from the static solution (the exterior
    # takes the correction's mean; the interior sheds what the attitude error had bent it by)
    problem = CalibrationProblem(start, points, weight, groups, options.chunk_points)
    stepper = Stepper(problem, options)
    stepper.theta0 = np.concatenate([model.parameters().values, chosen.coefficients_rad.reshape(-1)])
    once = options.replace(max_outer=1)
    unsettled = run_scheme(stepper, start, groups, once)
    result = assemble_result(start, problem, stepper, skipped, once, bands, ccd_idx, unsettled)
    if not result.success:  # keep the static solution, say why
        info["failed"] = result.message
        return replace(static, attitude=info)
    return replace(result, residuals_before=static.residuals_before, attitude=info)
