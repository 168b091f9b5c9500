"""The result of a GCP calibration (:func:`calibrate.absolute.calibrate_model`) and its units.

:class:`CalibrationResult` holds the calibrated model, the estimated parameters with their
covariance, the per-step log, the per-point residuals before and after, the robust weights and
inlier flags; :meth:`CalibrationResult.to_dict` is the CLI's ``calibration.json``.
:func:`residual_statistics` gives the RMS of (row, col) residuals and :func:`parameter_unit`
the unit of a parameter from its name. The result is assembled from the solver's runs by
:mod:`calibrate.result_assembly`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibrate._json import json_safe
from calibrate.normal_decomposition import covariance_sigma
from sensor_models.base import SensorModel

__all__ = ["CalibrationResult", "parameter_unit", "residual_statistics"]

_ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate.absolute.calibrate_model`.

    Attributes
    ----------
    success : bool
        Every step converged with a well-conditioned system.
    message : str
        Summary, naming skipped CCDs, failures and near-dependent parameters.
    scheme : str
    model : SensorModel
        The calibrated model (``initial_model.with_parameters``); on failure, the last
        accepted values.
    names : tuple of str
        Estimated parameters (model order).
    values, initial_values : ndarray, shape (P,)
        Their calibrated and initial values.
    covariance, correlation : ndarray, shape (P, P) or None
        See ``covariance_kind``.
    covariance_kind : str
        ``"joint"`` or ``"conditional-blocks"`` (stepwise schemes, :mod:`calibrate.absolute`).
    condition_numbers : dict of str to float
        Of the equilibrated normal matrix of the last run of each step.
    steps : list of dict
        Per scheme step: ``step, outer, success, message, iterations, cost, scale, sigma0,
        condition_number, rms_row_px, rms_col_px, rms_px`` (inliers), ``n_points``,
        ``n_inliers`` and the solver's ``log``.
    residuals_before, residuals_after : ndarray, shape (N, 2)
        Observed minus modelled (row, col) in pixels, input order; NaN where the model
        gives no projection.
    weights : ndarray, shape (N,)
        Robust weights at the solution, in [0, 1].
    inlier : ndarray of bool, shape (N,)
        Normalized residual at most ``outlier_threshold`` robust standard deviations.
    band, ccd : ndarray, shape (N,)
        Band name and CCD index of each point (``None`` / -1 for models without them).
    skipped : list of dict
        CCDs whose interior was not estimated: ``band, ccd, n_points, needed, span, reason``.
    attitude : dict or None
        Time-varying attitude (``CalibrationOptions.attitude`` other than ``"static"`` on a
        push-broom model): ``mode``, ``selected`` (``kind``, ``n_terms``) and the BIC of each
        candidate (:func:`calibrate.attitude.select_correction`); None otherwise.
    sigma0, scale : float
        Of the last step (:class:`calibrate.lsq.LsqResult`): ``sigma0`` is the a-posteriori
        standard deviation of unit weight (robust form of ``sqrt(sum w r~^2 / (n - p))`` over
        the normalized residuals ``r~ = r / sigma_px``); the covariance is already scaled by its
        square where it exceeds 1, ``C = max(1, sigma0^2) (J^T W J)^-1`` per step (a factor below
        1 leaves the a-priori ``(J^T W J)^-1``: :mod:`calibrate.reference_covariance`).
    uncertainty : dict or None
        What the covariance holds besides ``(J^T W J)^-1``: the factor applied per step and the
        reference DOM's common-shift term
        (:func:`calibrate.reference_covariance.with_honest_covariance`).
    """

    success: bool
    message: str
    scheme: str
    model: SensorModel
    names: tuple
    values: np.ndarray
    initial_values: np.ndarray
    covariance: np.ndarray | None
    correlation: np.ndarray | None
    covariance_kind: str
    condition_numbers: dict
    steps: list
    residuals_before: np.ndarray
    residuals_after: np.ndarray
    weights: np.ndarray
    inlier: np.ndarray
    band: np.ndarray
    ccd: np.ndarray
    skipped: list = field(default_factory=list)
    sigma0: float = float("nan")
    scale: float = float("nan")
    robust: str = "huber"
    attitude: dict | None = None
    uncertainty: dict | None = None

    @property
    def variance_factor(self) -> float:
        """A-posteriori variance factor ``sigma0**2`` of the last step (1 when ``sigma_px`` is right).

        Returns
        -------
        float
            ``sigma0**2`` (dimensionless): about 4 when the GCP errors are twice their stated
            ``sigma_px``; NaN when nothing was estimated.
        """
        return float(self.sigma0) ** 2

    @property
    def sigma(self) -> np.ndarray | None:
        """Standard deviations of ``values``, shape (P,), or None.

        Returns
        -------
        ndarray, shape (P,), or None
            Square roots of the covariance diagonal (parameter units); None without a covariance.
        """
        return covariance_sigma(self.covariance)

    def statistics(self, which: str = "after") -> dict:
        """RMS residuals (px) of all valid points and of the inliers, ``which`` in before/after.

        Parameters
        ----------
        which : {"after", "before"}
            Residuals at the solution or under the initial model.

        Returns
        -------
        dict
            :func:`residual_statistics` of those residuals with the result's inlier flags (pixels).
        """
        res = self.residuals_after if which == "after" else self.residuals_before
        return residual_statistics(res, self.inlier)

    def to_dict(self, *, points: bool = True) -> dict:
        """JSON-safe summary (NaN and infinity become ``None``); the CLI's ``calibration.json``.

        Parameters carry names, units, initial and calibrated values, changes and standard
        deviations (angles also in arcseconds); then the covariance and correlation with their
        names, condition numbers, the per-step convergence log, residual statistics and, with
        ``points=True``, the per-point residuals before and after, weights and inlier flags.

        Parameters
        ----------
        points : bool
            Include the per-point arrays (residuals in pixels, weights, inlier flags, band, CCD).

        Returns
        -------
        dict
            Strict-JSON-ready mapping (format ``gcpcal.calibration``, version 1).
        """
        sigma = self.sigma
        params = []
        for j, name in enumerate(self.names):
            entry = {
                "name": name,
                "unit": parameter_unit(name),
                "initial": float(self.initial_values[j]),
                "value": float(self.values[j]),
                "change": float(self.values[j] - self.initial_values[j]),
                "sigma": None if sigma is None else float(sigma[j]),
            }
            if entry["unit"] == "rad":
                for key in ("initial", "value", "change", "sigma"):
                    if entry[key] is not None:
                        entry[key + "_arcsec"] = entry[key] * _ARCSEC_PER_RAD
            params.append(entry)
        out = {
            "format": "gcpcal.calibration",
            "format_version": 1,
            "success": self.success,
            "message": self.message,
            "scheme": self.scheme,
            "robust": self.robust,
            "model_kind": getattr(self.model, "kind", type(self.model).__name__),
            "model_name": getattr(self.model, "name", ""),
            "parameters": params,
            "covariance": {
                "kind": self.covariance_kind,
                "names": list(self.names),
                "matrix": None if self.covariance is None else self.covariance.tolist(),
            },
            "correlation": None if self.correlation is None else self.correlation.tolist(),
            "condition_numbers": dict(self.condition_numbers),
            "sigma0": self.sigma0,
            "variance_factor": self.variance_factor,
            "covariance_scaling": ("covariance = max(1, sigma0^2) (J^T W J)^-1 per step (a variance factor below 1 "
                                   "does not shrink it) + G Sigma_ref G^T (the reference DOM's common shift)"),
            **(self.uncertainty or {}),
            "scale": self.scale,
            "skipped": list(self.skipped),
            "steps": list(self.steps),
            "statistics": {"before": self.statistics("before"), "after": self.statistics("after")},
        }
        if self.attitude is not None:
            out["attitude"] = self.attitude
        if points:
            out["points"] = {
                "band": [None if b is None else str(b) for b in self.band],
                "ccd": [int(c) for c in self.ccd],
                "row_residual_before_px": self.residuals_before[:, 0],
                "col_residual_before_px": self.residuals_before[:, 1],
                "row_residual_after_px": self.residuals_after[:, 0],
                "col_residual_after_px": self.residuals_after[:, 1],
                "weight": self.weights,
                "inlier": self.inlier,
            }
        return json_safe(out)


def residual_statistics(residuals, inlier=None) -> dict:
    """RMS of (row, col) residuals in pixels over valid points and over inliers.

    Parameters
    ----------
    residuals : array_like, shape (N, 2)
        Row and column residuals, pixels; rows with a non-finite value are not valid.
    inlier : array_like of bool, shape (N,), optional
        Inlier flags; default: every valid point.

    Returns
    -------
    dict
        ``n_points, n_valid, n_inliers, rms_row_px, rms_col_px, rms_px`` (planar, over the
        inliers), ``rms_px_all`` (every valid point), ``max_px`` (inliers).
    """
    res = np.asarray(residuals, dtype=np.float64).reshape(-1, 2)
    valid = np.all(np.isfinite(res), axis=1)
    ins = valid if inlier is None else (valid & np.asarray(inlier, dtype=bool))

    def rms(a):
        return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")

    planar = np.hypot(res[:, 0], res[:, 1])
    return {
        "n_points": int(res.shape[0]),
        "n_valid": int(valid.sum()),
        "n_inliers": int(ins.sum()),
        "rms_row_px": rms(res[ins, 0]),
        "rms_col_px": rms(res[ins, 1]),
        "rms_px": rms(planar[ins]),
        "rms_px_all": rms(planar[valid]),
        "max_px": float(planar[ins].max()) if ins.any() else float("nan"),
    }


def parameter_unit(name: str) -> str:
    """Unit of a model parameter from its name (``rad``, ``px``, ``1``, ``detector^-k``).

    Parameters
    ----------
    name : str
        Model parameter name (e.g. ``installation.roll``, ``B2.ccd1.tan_psi_y.c3``).

    Returns
    -------
    str
        ``"rad"``, ``"px"``, ``"px/px"``, ``"1"``, ``"detector^-k"``, or ``""`` when unknown.
    """
    if name.startswith(("installation.", "attitude.")):
        return "rad"
    if name.startswith("interior.tan_psi_"):  # staring camera: coefficients of normalized u^i v^j
        return "1"
    if ".tan_psi_" in name:
        k = int(name.rsplit(".c", 1)[1])
        return "1" if k == 0 else ("detector^-1" if k == 1 else f"detector^-{k}")
    if name in ("bias.row.a0", "bias.col.b0"):
        return "px"
    if name.startswith("bias."):
        return "px/px"
    return ""
