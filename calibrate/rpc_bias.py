"""Bias compensation of an RPC model from GCPs (Grodecki & Dial 2003).

A vendor RPC carries the systematic errors of the ephemeris and attitude it was fitted to. For
a narrow-field push-broom scene they act, to first order, as an offset or an affine map in
image space, so Grodecki & Dial [1]_ correct them there::

    row = row_rpc + a0 + a1 row_rpc + a2 col_rpc
    col = col_rpc + b0 + b1 row_rpc + b2 col_rpc

:class:`~sensor_models.models.rpc.RpcModel` carries exactly this correction as its parameters
(``bias.row.a0 .. bias.col.b2``), with analytic derivatives, so the estimate is a (linear)
robust least-squares fit of the chosen terms from GCPs, starting from the model's current
bias:

* ``terms="offset"``: ``a0, b0`` (2 parameters; at least 1 GCP, 3 or more advised);
* ``terms="shift-drift"``: ``a0, a1, b0, b1`` (offsets plus a drift along the lines);
* ``terms="affine"``: all six (at least 3 GCPs not on a line).

``a1, a2, b1, b2`` multiply full-scene pixel coordinates (tens of thousands); the solver
equilibrates the normal equations. The corrected model folds ``a0, a1, b0, b2`` into its
offsets and scales when written (:func:`~sensor_models.readers.rpc_files.write_rpc`); the cross
terms ``a2, b1`` cannot be written to an RPC file (``writable=False`` in the result; refit with
:func:`sensor_models.models.rpc_fit.fit_rpc` instead).

References
----------
.. [1] J. Grodecki and G. Dial, "Block adjustment of high-resolution satellite images
   described by rational polynomials", Photogrammetric Engineering & Remote Sensing 69(1),
   59-68 (2003).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibrate.absolute import calibrate_model
from calibrate.calibration_result import CalibrationResult
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.rpc import BIAS_NAMES, RpcModel

__all__ = ["BIAS_TERMS", "RpcBiasResult", "compensate_rpc_bias"]

#: The bias parameters estimated for each choice of ``terms``.
BIAS_TERMS = {
    "offset": ("bias.row.a0", "bias.col.b0"),
    "shift-drift": ("bias.row.a0", "bias.row.a1", "bias.col.b0", "bias.col.b1"),
    "affine": BIAS_NAMES,
}


@dataclass
class RpcBiasResult:
    """Outcome of :func:`compensate_rpc_bias`.

    Attributes
    ----------
    success : bool
    message : str
    model : RpcModel
        The corrected RPC (its bias parameters set).
    terms : str
    bias : dict of str to float
        All six bias parameters of the corrected model.
    sigma : dict of str to float
        Standard deviations of the estimated ones.
    writable : bool
        Whether :func:`~sensor_models.readers.rpc_files.write_rpc` can store the correction (no ``a2``/``b1`` terms).
    rms_before_px, rms_after_px : float
        Planar RMS of the inlier residuals before and after.
    calibration : CalibrationResult
        The underlying fit (residuals, weights, covariance, log).
    """

    success: bool
    message: str
    model: RpcModel
    terms: str
    bias: dict
    sigma: dict
    writable: bool
    rms_before_px: float
    rms_after_px: float
    calibration: CalibrationResult

    def to_dict(self, *, points: bool = False) -> dict:
        """JSON-safe summary (the calibration's own ``to_dict`` under ``"calibration"``).

        Parameters
        ----------
        points : bool
            Include the calibration's per-point arrays.

        Returns
        -------
        dict
            JSON-ready mapping (bias terms in pixels, RMS before and after in pixels).
        """
        return {
            "success": self.success,
            "message": self.message,
            "terms": self.terms,
            "bias": dict(self.bias),
            "sigma": dict(self.sigma),
            "writable": self.writable,
            "rms_before_px": _finite_or_none(self.rms_before_px),
            "rms_after_px": _finite_or_none(self.rms_after_px),
            "calibration": self.calibration.to_dict(points=points),
        }


def _finite_or_none(x):
    x = float(x)
    return x if np.isfinite(x) else None


def compensate_rpc_bias(
    rpc: RpcModel,
    row,
    col,
    lon,
    lat,
    h,
    *,
    terms: str = "offset",
    sigma_px=None,
    score=None,
    robust: str = CalibrationOptions.robust,
    max_iter: int = CalibrationOptions.max_iter,
) -> RpcBiasResult:
    """Estimate the image-space bias correction of an RPC from GCPs.

    Parameters
    ----------
    rpc : RpcModel
        The model to correct (its current bias is the starting point).
    row, col : array_like, shape (N,)
        Observed image coordinates, pixels (first pixel centre at 0.5; full-scene pixels of
        the RPC).
    lon, lat, h : array_like, shape (N,)
        Ground coordinates (WGS84 degrees, metres above the ellipsoid).
    terms : {"offset", "shift-drift", "affine"}
        Which bias parameters to estimate (:data:`BIAS_TERMS`); the others keep their values.
    sigma_px, score : array_like, optional
        Point weights, as in :func:`calibrate.absolute.calibrate_model`.
    robust : {"cauchy", "huber", "none"}
        Robust loss.
    max_iter : int
        Solver iterations.

    Returns
    -------
    RpcBiasResult
        ``success=False`` with a message when the GCPs cannot determine the terms.
    """
    if "bias" not in rpc.parameter_groups():
        raise InputError(f"needs an RPC model (bias parameters), got a {rpc.kind} model", field="rpc")
    if terms not in BIAS_TERMS:
        raise InputError(f"terms must be one of {', '.join(BIAS_TERMS)}, got {terms!r}", field="terms")
    names = BIAS_TERMS[terms]
    table = GcpTable.from_arrays(row, col, lon, lat, h, sigma_px=sigma_px, score=score)
    options = CalibrationOptions(scheme="joint", parameters=names, robust=robust, max_iter=max_iter)
    result = calibrate_model(rpc, table, options=options)
    model = result.model
    bias = dict(zip(BIAS_NAMES, (float(v) for v in model.bias)))
    sd = result.sigma
    sigma = {} if sd is None else {n: float(s) for n, s in zip(result.names, sd)}
    writable = bias["bias.row.a2"] == 0.0 and bias["bias.col.b1"] == 0.0
    before = result.statistics("before")["rms_px"]
    after = result.statistics("after")["rms_px"]
    message = result.message
    if result.success:
        shift = ", ".join(f"{n.split('.')[-1]}={bias[n]:.4g}" for n in names)
        message = f"RPC bias ({terms}) {shift}; RMS {before:.3g} -> {after:.3g} px; " + message
    if not writable:
        message += "; the cross terms a2, b1 cannot be written to an RPC file (refit with fit_rpc)"
    return RpcBiasResult(
        success=result.success,
        message=message,
        model=model,
        terms=terms,
        bias=bias,
        sigma=sigma,
        writable=writable,
        rms_before_px=before,
        rms_after_px=after,
        calibration=result,
    )
