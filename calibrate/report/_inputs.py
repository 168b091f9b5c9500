"""Inputs of the calibration report, checked and gathered (:func:`calibrate.report.write_report`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from calibrate.calibration_result import CalibrationResult
from sensor_models.errors import InputError

__all__ = ["ReportContext", "check_result", "point_columns", "unwrap_result"]


def unwrap_result(result) -> CalibrationResult:
    """The CalibrationResult itself, or the one a wrapper holds (with the wrapper's message).

    Parameters
    ----------
    result : CalibrationResult or object
        A result, or one with a ``calibration`` attribute (e.g. ``RpcBiasResult``).

    Returns
    -------
    CalibrationResult
        The result.
    """
    if isinstance(result, CalibrationResult):
        return result
    inner = getattr(result, "calibration", None)
    if isinstance(inner, CalibrationResult):
        message = getattr(result, "message", None)
        return dataclasses.replace(inner, message=message) if isinstance(message, str) and message else inner
    raise InputError(f"must be a CalibrationResult, got {type(result).__name__}", field="result")


def point_columns(points, name) -> dict:
    """``row, col`` (float arrays), ``h`` (or None) and per-point ``band``/``ccd`` (or None).

    Parameters
    ----------
    points : mapping of str to array_like
        ``row``, ``col`` (pixels, shape (N,)) and optionally ``h`` (metres), ``band``, ``ccd``.
    name : str
        Field named in errors (``"gcps"`` or ``"checks"``).

    Returns
    -------
    dict
        The columns as arrays of shape (N,) (absent ones None).
    """
    if not isinstance(points, Mapping):
        raise InputError(f"must be a mapping of arrays, got {type(points).__name__}", field=name)
    out = {}
    for key in ("row", "col"):
        if points.get(key) is None:
            raise InputError(f"needs '{key}'", field=name)
        out[key] = np.asarray(points[key], dtype=np.float64).reshape(-1)
    n = out["row"].size
    if out["col"].size != n:
        raise InputError(f"has {out['col'].size} values for {n} points", field=f"{name}.col")
    for key in ("h", "band", "ccd"):
        value = points.get(key)
        if value is None:
            out[key] = None
            continue
        if isinstance(value, (str, bytes)) or np.ndim(value) == 0:
            value = np.full(n, value, dtype=object)
        arr = np.asarray(value, dtype=np.float64 if key == "h" else object).reshape(-1)
        if arr.size != n:
            raise InputError(f"has {arr.size} values for {n} points", field=f"{name}.{key}")
        out[key] = arr
    return out


def check_result(result: CalibrationResult, n_gcps: int) -> None:
    """Check that the per-point arrays of ``result`` hold one entry per GCP.

    Parameters
    ----------
    result : CalibrationResult
        Result to check.
    n_gcps : int
        Number of GCPs of the report.
    """
    p = len(result.names)
    for attr in ("values", "initial_values"):
        if np.asarray(getattr(result, attr)).shape != (p,):
            raise InputError(f"{attr} has shape {np.shape(getattr(result, attr))} for {p} parameters", field="result")
    if result.covariance is not None and np.shape(result.covariance) != (p, p):
        raise InputError(f"covariance has shape {np.shape(result.covariance)} for {p} parameters", field="result")
    for attr in ("residuals_before", "residuals_after"):
        shape = np.shape(getattr(result, attr))
        if shape != (n_gcps, 2):
            raise InputError(f"{attr} has shape {shape} for {n_gcps} GCPs", field="result")
    for attr in ("weights", "inlier", "band", "ccd"):
        size = np.size(getattr(result, attr))
        if size != n_gcps:
            raise InputError(f"{attr} has {size} values for {n_gcps} GCPs", field="result")


class ReportContext:
    """Inputs shared by the figures and tables."""

    def __init__(self, result, before, after, initial, gcps, checks, truth):
        self.result = result
        self.before = before
        self.after = after
        self.initial = initial
        self.calibrated = result.model
        self.gcps = gcps
        self.checks = checks
        self.truth = truth
        # per-CCD look-angle curves need directional-angle interiors on both sides
        self.pushbroom = initial.interior_layout == "per_array" and result.model.interior_layout == "per_array"
        self.bands = _calibrated_bands(result, initial) if self.pushbroom else []
        self.notes: list[str] = []
        self.coverage: list[dict] = []  # coverage-gate rows (calibrate.coverage), set by write_report
        self.status = None  # the run's CalibrationStatus, when known
        self.relative = None  # band-to-band RelativeResult, when given
        self.truth_error = None  # model_difference results against the truth, when given
        shape = getattr(initial, "image_shape", None)
        if shape is not None:
            self.n_rows, self.n_cols = float(shape[0]), float(shape[1])
        else:
            allr = np.concatenate([gcps["row"], checks["row"]])
            allc = np.concatenate([gcps["col"], checks["col"]])
            self.n_rows, self.n_cols = float(np.nanmax(allr)), float(np.nanmax(allc))


def _calibrated_bands(result, model) -> list:
    """Bands whose interior was estimated, else the bands of the GCPs."""
    names = [n for n in result.names if ".tan_psi_" in n]
    bands = [b for b in model.bands if any(n.startswith(f"{b}.") for n in names)]
    if not bands:
        seen = {str(b) for b in result.band if b is not None}
        bands = [b for b in model.bands if b in seen]
    return bands
