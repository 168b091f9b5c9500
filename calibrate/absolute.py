"""Absolute geometric calibration of a sensor model from ground control points.

For a push-broom directional-angle model (seed 003 eq. 1-3) the parameters split into

* the *exterior*: installation angles ``installation.roll|pitch|yaw`` (camera -> body);
* the *interior*: per band and CCD, the directional-angle coefficients
  ``{band}.{ccd}.tan_psi_x.c0..`` and ``tan_psi_y.c0..`` (cubic in the detector index).

Each GCP ``i`` gives two observation equations (seed 000 eq. 11-12): the residual
``(row_i, col_i) - model.ground_to_image(lon_i, lat_i, h_i)`` in pixels, linearized with the
model's analytic Jacobian. Points are weighted by ``score_i / sigma_i^2`` and robustly
reweighted (:mod:`calibrate.lsq`).

Schemes (seed 002 section 3, seed 003 section 2.2, seed 000 eq. 12-17):

======================  ==========================================================
``"exterior"``          ECO: installation angles only, interior held at its values
``"interior"``          ICO: interior of every estimable CCD only
``"exterior-interior"`` ECBIC (default, seed 003 2.2.1): exterior with the interior
                        fixed, then the interior in the frame the exterior fixes,
                        iterated until the exterior no longer moves (after the first
                        round, exterior steps use only the GCPs of CCDs whose interior
                        is estimated)
``"interior-exterior"`` ICBEC: the same, interior first
``"joint"``             all together; the installation angles and the c0/c1 terms of
                        the CCDs are nearly dependent (a rotation of the camera is a
                        shift of every detector's look), so pseudo-observations hold
                        the reference CCD's mean look and along-track tilt at their
                        initial values (they fix roll, pitch, yaw; see
                        :mod:`calibrate.gauge_priors`) and the largest correlation
                        is reported
======================  ==========================================================

A CCD whose GCPs are too few (fewer than ``min_points_factor`` times its unknowns) or cover
too small a fraction of its detectors keeps its interior; the message names it. In stepwise
schemes each group's covariance is conditional on the other group (the scheme fixes the
frame by its order); the cross-covariance between groups is not estimated (zero blocks,
``covariance_kind = "conditional-blocks"``). Each block is scaled by ``max(1, sigma0^2)`` (a
variance factor below 1 does not shrink it), and with ``CalibrationOptions.reference_sigma_m``
the reference DOM's common ground shift is propagated into the installation angles
(:mod:`calibrate.reference_covariance`, docs/calibration_outputs.md).

Other sensor models (RPC, a single CCD view...) are calibrated with ``scheme="joint"``
over ``parameters`` (default: all of the model's parameters).

This module holds the entry point, :func:`calibrate_model`. Its pieces, in the order it uses
them: :mod:`calibrate.gcp_groups` (points grouped by band and CCD, estimable interiors),
:mod:`calibrate.calibration_problem` (the residual function of a step),
:mod:`calibrate.calibration_steps` (the steps of each scheme, with :mod:`calibrate.gauge_priors`),
:mod:`calibrate.result_assembly` (the :class:`~calibrate.calibration_result.CalibrationResult`
of the runs) and :mod:`calibrate.attitude_rounds` (the time-varying attitude).
"""

from __future__ import annotations

import numpy as np

from calibrate.attitude_rounds import time_varying_attitude
from calibrate.calibration_problem import CalibrationProblem
from calibrate.calibration_result import CalibrationResult
from calibrate.calibration_steps import Stepper, run_scheme
from calibrate.config import CalibrationOptions
from calibrate.gcp_groups import as_points, group_points, mark_estimable
from calibrate.reference_covariance import with_honest_covariance
from calibrate.result_assembly import assemble_result
from gcpmatch.gcps import GcpTable
from sensor_models.base import SensorModel
from sensor_models.errors import InputError

__all__ = ["calibrate_model"]


def calibrate_model(
    model: SensorModel,
    gcps: GcpTable,
    *,
    options: CalibrationOptions = CalibrationOptions(),
) -> CalibrationResult:
    """Calibrate a sensor model from ground control points.

    Only the points of kind ``"gcp"`` are fitted: the function takes ``gcps.gcps()`` itself,
    so check points in the table never enter the fit. Every per-point array of the result
    (residuals, weights, inlier flags, band, CCD) follows the order of ``gcps.gcps()``.

    Parameters
    ----------
    model : SensorModel
        Initial (e.g. laboratory) model; :class:`~sensor_models.models.pushbroom.PushbroomModel` or a
        staring camera for the exterior/interior schemes, any model for ``scheme="joint"``.
    gcps : GcpTable
        Observed image coordinates ``row, col`` (pixels, first pixel centre at 0.5) of ground
        points ``lon, lat`` (WGS84 degrees) and ``h`` (metres above the ellipsoid), shape (N,)
        each. ``sigma_px`` (pixels) and ``score`` weight each point by ``score / sigma_px**2``
        (a score of 0 drops it). ``band``: an empty string means the model's reference band
        (push-broom) or no band. ``ccd``: a CCD name or index; an empty string means the CCD
        whose columns hold ``col``. Points of kind ``"check"`` are left out.
    options : CalibrationOptions
        Scheme, robust loss, estimated terms, stopping rules and gauge
        (:class:`calibrate.config.CalibrationOptions` documents each field). The stepwise
        schemes stop when a step of the exterior moves every angle by less than
        ``outer_tol`` of its standard deviation; still moving after ``max_outer`` rounds is a
        failure, except with ``max_outer=1`` (a single pass, as in seed 003). The default
        Cauchy loss starts with Huber iterations and is as efficient on clean data; with 40 %
        gross mismatches it keeps the accuracy of a clean fit where Huber loses a factor of
        about five (tests). ``options.attitude`` other than ``"static"`` adds a time-varying
        attitude correction to a push-broom model, chosen and solved after the static
        calibration (:mod:`calibrate.attitude`, docs/attitude.md); a correction the model
        already carries is then estimated afresh, while ``"static"`` and the interior-only
        scheme hold it.

    Returns
    -------
    CalibrationResult
        ``success=False`` with a message when a step fails (rank deficiency,
        ill-conditioning, no convergence).

    Raises
    ------
    InputError
        Malformed inputs (no point of kind "gcp", unknown band/CCD/parameters, a scheme the
        model does not support).
    """
    if not isinstance(gcps, GcpTable):
        raise InputError(f"gcps must be a GcpTable, got {type(gcps).__name__}", field="gcps")
    if not isinstance(options, CalibrationOptions):
        raise InputError(f"options must be a CalibrationOptions, got {type(options).__name__}", field="options")
    fitted = gcps.gcps()
    if len(fitted) == 0:
        raise InputError("no GCPs given (no point of kind 'gcp')")
    points, weight = as_points(fitted.row, fitted.col, fitted.lon, fitted.lat, fitted.h, fitted.sigma_px,
                               fitted.score, options.score_weight)  # fmt: skip
    if options.covariance_floor is None:  # a table without sigma_px (all 1): its scale is the variance factor's
        options = options.replace(covariance_floor=bool(np.any(fitted.sigma_px != 1.0)))
    groups, bands, ccd_idx = group_points(model, points, fitted, options)
    if not np.any(weight > 0.0):
        raise InputError("every GCP has zero weight", field="score")
    time_varying = options.attitude != "static" and options.scheme != "interior" and hasattr(model, "with_attitude_correction")
    if time_varying and model.attitude_correction is not None:
        model = model.with_attitude_correction(None)  # estimated afresh below
    skipped = mark_estimable(model, groups, weight, points, options)
    problem = CalibrationProblem(model, points, weight, groups, options.chunk_points)
    stepper = Stepper(problem, options)
    unsettled = run_scheme(stepper, model, groups, options)
    result = assemble_result(model, problem, stepper, skipped, options, bands, ccd_idx, unsettled)
    if time_varying and result.success:
        result = time_varying_attitude(model, result, points, weight, groups, skipped, options, bands, ccd_idx)
    return with_honest_covariance(result, points, weight, groups, options)  # the reference DOM's common shift


