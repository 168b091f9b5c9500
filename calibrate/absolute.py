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
                        ``_gauge_prior``) and the largest correlation is reported
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from calibrate import attitude as _attitude
from calibrate.pspline import recovered_spectrum
from calibrate._json import json_safe
from calibrate.config import CalibrationOptions
from calibrate.lsq import LsqResult, solve
from calibrate.normal_equations import PROBE_POINTS
from calibrate.lsq_inputs import Chunk, Prior
from calibrate.robust_loss import robust_weights
from calibrate.reference_covariance import floor_factor, with_honest_covariance
from gcpmatch.gcps import GcpTable
from sensor_models.base import SensorModel
from sensor_models.errors import InputError

__all__ = ["CalibrationResult", "calibrate_model", "parameter_unit", "residual_statistics"]

_EXTERIOR = ("installation.roll", "installation.pitch", "installation.yaw")
_ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


# --------------------------------------------------------------------------- result
@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate_model`.

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
        ``"joint"`` or ``"conditional-blocks"`` (stepwise schemes, module docstring).
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
        if self.covariance is None:
            return None
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

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
        return _json_safe(out)


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


_json_safe = json_safe


# --------------------------------------------------------------------------- inputs
@dataclass
class _Group:
    band: object  # band name or None
    ccd: int  # CCD index in the band, -1 for models without CCDs
    ccd_name: str
    idx: np.ndarray  # point indices (input order)
    interior: tuple = ()  # interior parameter names of this CCD (estimable or not)
    estimable: bool = False


def _as_points(row, col, lon, lat, h, sigma_px, score, score_weight=True):
    """Point arrays and prior weights: ``score / sigma_px^2``, or ``1 / sigma_px^2`` with
    ``score_weight=False`` (a score of 0 still drops the point)."""
    arrays = {}
    for name, a in (("row", row), ("col", col), ("lon", lon), ("lat", lat), ("h", h)):
        a = np.asarray(a, dtype=np.float64).reshape(-1)
        arrays[name] = a
    n = arrays["row"].size
    if n == 0:
        raise InputError("no GCPs given")
    for name, a in arrays.items():
        if a.size != n:
            raise InputError(f"{name} has {a.size} values for {n} GCPs", field=name)
        if not np.all(np.isfinite(a)):
            raise InputError("holds NaN or infinite values", field=name)
    weight = np.ones(n)
    if sigma_px is not None:
        s = _per_point_float(sigma_px, n)
        if s.size != n or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
            raise InputError(f"needs {n} positive finite values", field="sigma_px")
        weight = weight / s**2
    if score is not None:
        q = _per_point_float(score, n)
        if q.size != n or not np.all(np.isfinite(q)) or np.any(q < 0.0):
            raise InputError(f"needs {n} finite values >= 0", field="score")
        weight = weight * (q if score_weight else (q > 0.0))
    return arrays, np.ascontiguousarray(weight)


def _per_point_float(value, n):
    a = np.asarray(value, dtype=np.float64)
    return np.full(n, float(a)) if a.ndim == 0 else a.reshape(-1)


def _per_point(value, n, field_name):
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or np.ndim(value) == 0:
        return np.full(n, value, dtype=object)
    arr = np.asarray(value).reshape(-1)
    if arr.size != n:
        raise InputError(f"has {arr.size} values for {n} GCPs", field=field_name)
    return arr


def _pushbroom_groups(model, points, band, ccd, interior_terms):
    n = points["row"].size
    bands = _per_point(band, n, "band")
    if bands is None:
        bands = np.full(n, model.reference_band, dtype=object)
    bands = np.asarray(bands).astype(str)
    unknown = sorted(set(np.unique(bands)) - set(model.bands))
    if unknown:
        known = ", ".join(model.bands)
        raise InputError(f"unknown band(s) {', '.join(unknown)}; the model has {known}", field="band")
    present = [b for b in model.bands if np.any(bands == b)]
    ccds = _per_point(ccd, n, "ccd")
    ccd_idx = np.empty(n, dtype=np.intp)
    for b in present:
        sel = np.nonzero(bands == b)[0]
        look = model.detector_arrays(b)
        if ccds is None:
            ccd_idx[sel] = model.detector_index(points["col"][sel], band=b).reshape(-1)
            continue
        names = [c.name for c in look]
        values = ccds[sel]
        # resolve each distinct value once: a CCD name, an index, or missing (None, "", NaN:
        # the CCD whose columns hold the point)
        unique, inverse = np.unique(values.astype(str), return_inverse=True)
        from_col = model.detector_index(points["col"][sel], band=b).reshape(-1)
        resolved = np.array([_resolve_ccd(v, names, b) for v in unique], dtype=np.intp)
        chosen = resolved[inverse.reshape(-1)]
        ccd_idx[sel] = np.where(chosen < 0, from_col, chosen)
    all_names = set(model.parameter_names())
    groups = []
    for b in present:
        in_band = bands == b
        for ci, look in enumerate(model.detector_arrays(b)):
            idx = np.nonzero(in_band & (ccd_idx == ci))[0]
            if idx.size == 0:
                continue
            interior = _interior_names(b, look, interior_terms, all_names)
            groups.append(_Group(b, ci, look.name, idx, interior))
    return groups, bands, ccd_idx


def _staring_groups(model, points, band, ccd, interior_terms):
    """One group (the whole frame) for an area-array staring camera (20-coefficient interior)."""
    n = points["row"].size
    if ccd is not None and not all(str(v) in ("", "None", "nan", "-1") for v in np.atleast_1d(ccd)):
        raise InputError("ccd does not apply to an area-array camera", field="ccd")
    bands = _per_point(band, n, "band")
    if bands is not None:
        other = sorted(set(np.asarray(bands).astype(str)) - {model.band, "", "None"})
        if other:
            raise InputError(f"unknown band(s) {', '.join(other)}; the camera has {model.band}", field="band")
    if isinstance(interior_terms, (int, np.integer)):
        if interior_terms < 0:
            raise InputError("must be >= 0", field="interior_terms")
        interior = tuple(model.interior_parameter_names(min(int(interior_terms), 3)))
    else:
        interior = tuple(t if t.startswith("interior.") else f"interior.{t}" for t in interior_terms)
        bad = [t for t in interior if t not in set(model.parameter_names())]
        if bad:
            raise InputError(f"unknown interior terms {', '.join(bad)}", field="interior_terms")
    groups = [_Group(model.band, -1, "frame", np.arange(n), interior)]
    return groups, np.full(n, model.band, dtype=object), np.full(n, -1, dtype=np.intp)


def _check_estimable_staring(model, group, weight, points, min_points_factor, min_span_fraction):
    """Whether the frame's interior can be estimated: enough points spread over the frame."""
    used = group.idx[weight[group.idx] > 0.0]
    n_unknown = len(group.interior)
    needed = int(math.ceil(min_points_factor * n_unknown))
    if used.size:
        u, v = model.normalized(points["row"][used], points["col"][used])
        span = float(min(np.ptp(u), np.ptp(v)) / 2.0)
    else:
        span = 0.0
    record = {"band": group.band, "ccd": group.ccd_name, "n_points": int(used.size), "needed": needed, "span": span}
    if n_unknown == 0:
        return None
    if used.size < needed:
        record["reason"] = (f"{group.band}: {used.size} GCPs < {needed} needed ({min_points_factor:g} x "
                            f"{n_unknown} unknowns); the interior is not estimated")
        return record
    needs_span = any(not (n.endswith("a00") or n.endswith("b00")) for n in group.interior)
    if needs_span and span < min_span_fraction:
        record["reason"] = (f"{group.band}: GCPs span {100 * span:.0f} % of the frame < "
                            f"{100 * min_span_fraction:.0f} %; the interior is not estimated")
        return record
    group.estimable = True
    return None


def _staring_gauge_prior(model, free, gauge_sigma_px):
    """Joint scheme of a staring camera: hold its mean look and in-plane rotation (the gauge)."""
    rows, scale = model.gauge_rows()
    names = list(model.parameter_names())
    idx = [names.index(n) for n in free]
    matrix = np.asarray(rows)[:, idx]
    keep = np.any(matrix != 0.0, axis=1)
    if not keep.any():
        return None
    x0 = model.parameters().values[idx]
    return Prior(matrix[keep], matrix[keep] @ x0, gauge_sigma_px * np.asarray(scale)[keep])


def _resolve_ccd(value: str, names, band) -> int:
    """CCD index of a name or an index given as text; -1 for a missing value."""
    if value in ("None", "", "nan"):
        return -1
    if value in names:
        return names.index(value)
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"unknown CCD {value!r} of band {band}; it has {', '.join(names)}", field="ccd") from None
    if not number.is_integer() or not 0 <= number < len(names):
        raise InputError(f"CCD index {value} out of range 0..{len(names) - 1} for band {band}", field="ccd")
    return int(number)


def _interior_names(band, look, terms, all_names):
    if isinstance(terms, (int, np.integer)):
        if terms < 0:
            raise InputError("must be >= 0", field="interior_terms")
        names = [
            f"{band}.{look.name}.{axis}.c{k}"
            for axis in ("tan_psi_x", "tan_psi_y")
            for k in range(min(int(terms) + 1, getattr(look, axis).size))
        ]
    else:
        names = [f"{band}.{look.name}.{t}" for t in terms]
        bad = [n for n in names if n not in all_names]
        if bad:
            raise InputError(f"unknown interior terms {', '.join(bad)}", field="interior_terms")
    return tuple(names)


def _check_estimable(model, group, weight, points, min_points_factor, min_span_fraction):
    """Decide whether a CCD's interior can be estimated; a skip record if not."""
    col = points["col"]
    look = model.detector_arrays(group.band)[group.ccd]
    used = group.idx[weight[group.idx] > 0.0]
    n_unknown = len(group.interior)
    needed = int(math.ceil(min_points_factor * n_unknown))
    s = look.detector_index(col[used])
    span = float((s.max() - s.min()) / max(look.n_detectors - 1, 1)) if used.size else 0.0
    needs_span = any(not n.endswith(".c0") for n in group.interior)
    record = {
        "band": group.band,
        "ccd": group.ccd_name,
        "n_points": int(used.size),
        "needed": needed,
        "span": span,
    }
    if n_unknown == 0:
        return None
    if used.size < needed:
        record["reason"] = (
            f"{group.band}.{group.ccd_name}: {used.size} GCPs < {needed} needed "
            f"({min_points_factor:g} x {n_unknown} unknowns); its interior is not estimated"
        )
        return record
    if needs_span and span < min_span_fraction:
        record["reason"] = (
            f"{group.band}.{group.ccd_name}: GCPs span {100 * span:.0f} % of its detectors "
            f"< {100 * min_span_fraction:.0f} %; its interior is not estimated"
        )
        return record
    group.estimable = True
    return None


# --------------------------------------------------------------------------- the problem
class _Problem:
    """GCPs grouped by band and CCD, and the chunked residual/Jacobian function of a step."""

    def __init__(self, model, points, weight, groups, chunk_points, *, attitude_free=False):
        self.model = model
        self.points = points
        self.weight = weight
        self.groups = groups
        self.chunk_points = int(chunk_points)
        self.all_names = tuple(model.parameters().names)
        self.exterior = _EXTERIOR + (tuple(model.parameter_groups().get("attitude", ())) if attitude_free else ())
        self.lookup = {n: i for i, n in enumerate(self.all_names)}
        layout = model.interior_layout
        self.pushbroom = layout == "per_array"  # one interior per detector array (CCD)
        self.staged = layout != "none"  # exterior + interior groups
        # yield order: first a strided sample of every group (the solver takes its provisional
        # robust scale from the first points it sees), then the rest in chunks
        n = sum(g.idx.size for g in groups)
        stride = max(1, n // PROBE_POINTS)
        probes, rests = [], []
        for k, g in enumerate(groups):
            take = np.zeros(g.idx.size, dtype=bool)
            take[::stride] = True
            probes.append((k, g.idx[take]))
            rest = g.idx[~take]
            rests += [(k, rest[a : a + self.chunk_points]) for a in range(0, rest.size, self.chunk_points)]
        self.segments = [(k, idx) for k, idx in probes + rests if idx.size]
        self.order = np.concatenate([idx for _k, idx in self.segments])

    def chunks_for(self, theta, free, active, max_extrapolation=np.inf):
        """Residual function over the free names; ``active(group) -> bool`` selects the fit.

        Points whose projection, shifted by the chunk's median column residual, falls more
        than ``max_extrapolation`` (a fraction of the CCD's detectors) outside their CCD are
        left out of that evaluation: where the interior is estimated the cubic's Jacobian there
        gives them unbounded leverage, and a point observed on one CCD but projected far beyond
        it is a mismatch.
        """
        free = tuple(free)
        free_idx = np.array([self.lookup[n] for n in free], dtype=np.intp)
        position = {n: j for j, n in enumerate(free)}
        plan = []
        for g in self.groups:
            if not active(g):
                plan.append((g, (), np.zeros(0, dtype=np.intp), False))  # evaluated, not fitted
                continue
            names = [n for n in free if n in self.exterior] if self.staged else list(free)
            if self.staged and g.estimable:
                names += [n for n in g.interior if n in position]
            cols = np.array([position[n] for n in names], dtype=np.intp)
            bounds = None
            if self.pushbroom and np.isfinite(max_extrapolation):
                look = self.model.detector_arrays(g.band)[g.ccd]
                margin = max_extrapolation * look.n_detectors
                lo = look.first_col + 0.5 - margin
                bounds = (lo, lo + look.n_detectors - 1.0 + 2.0 * margin)
            plan.append((g, tuple(names), cols, bounds))
        p = self.points

        def chunks(x):
            values = theta.copy()
            values[free_idx] = x
            model = self.model.with_parameters(values)
            for k, sel in self.segments:
                g, names, cols, bounds = plan[k]
                kw = {"band": g.band, "array": g.ccd} if self.pushbroom else {"band": g.band}
                if names:
                    r, c, jac = model.image_jacobian(
                        p["lon"][sel], p["lat"][sel], p["h"][sel], names=names, **kw
                    )
                else:
                    r, c = model.ground_to_image(p["lon"][sel], p["lat"][sel], p["h"][sel], **kw)
                    jac = np.zeros((sel.size, 2, 0))
                res = np.stack([p["row"][sel] - r, p["col"][sel] - c], axis=-1)
                if bounds is False:
                    w = np.zeros(sel.size)
                elif bounds is None:
                    w = self.weight[sel]
                else:
                    # the chunk's median column residual removes a common offset (a model
                    # still hundreds of pixels off) before the extrapolation test
                    c_shifted = c + _median_or_zero(p["col"][sel] - c)
                    w = np.where((c_shifted >= bounds[0]) & (c_shifted <= bounds[1]), self.weight[sel], 0.0)
                yield Chunk(res, jac, w, cols)

        return chunks

    def to_input_order(self, grouped):
        out = np.full((self.order.size,) + grouped.shape[1:], np.nan)
        out[self.order] = grouped
        return out


# --------------------------------------------------------------------------- entry point
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
    points, weight = _as_points(fitted.row, fitted.col, fitted.lon, fitted.lat, fitted.h, fitted.sigma_px,
                                fitted.score, options.score_weight)  # fmt: skip
    if options.covariance_floor is None:  # a table without sigma_px (all 1): its scale is the variance factor's
        options = options.replace(covariance_floor=bool(np.any(fitted.sigma_px != 1.0)))
    groups, bands, ccd_idx = _group_points(model, points, fitted, options)
    if not np.any(weight > 0.0):
        raise InputError("every GCP has zero weight", field="score")
    time_varying = options.attitude != "static" and options.scheme != "interior" and hasattr(model, "with_attitude_correction")
    if time_varying and model.attitude_correction is not None:
        model = model.with_attitude_correction(None)  # estimated afresh below
    skipped = _mark_estimable(model, groups, weight, points, options)
    problem = _Problem(model, points, weight, groups, options.chunk_points)
    stepper = _Stepper(problem, options)
    unsettled = _run_scheme(stepper, model, groups, options)
    result = _assemble(model, problem, stepper, skipped, options, bands, ccd_idx, unsettled)
    if time_varying and result.success:
        result = _time_varying(model, result, points, weight, groups, skipped, options, bands, ccd_idx)
    return with_honest_covariance(result, points, weight, groups, options)  # the reference DOM's common shift


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


def _time_varying(model, static, points, weight, groups, skipped, options, bands, ccd_idx):
    """Choose the attitude basis around the static solution; solve it with exterior and interior.

    Then up to :data:`ATTITUDE_REFINE_ROUNDS` rounds choose it again around the new exterior and
    interior (which no longer carry what the attitude error had bent them by) and solve them
    once more, until the correction moves by less than :data:`ATTITUDE_REFINE_TOL_URAD` rms.
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
    problem = _Problem(start, points, weight, groups, options.chunk_points)
    stepper = _Stepper(problem, options)
    stepper.theta0 = np.concatenate([model.parameters().values, chosen.coefficients_rad.reshape(-1)])
    once = options.replace(max_outer=1)
    unsettled = _run_scheme(stepper, start, groups, once)
    result = _assemble(start, problem, stepper, skipped, once, bands, ccd_idx, unsettled)
    if not result.success:  # keep the static solution, say why
        info["failed"] = result.message
        return replace(static, attitude=info)
    return replace(result, residuals_before=static.residuals_before, attitude=info)


def _blank_to_none(column: np.ndarray):
    """A text column of the table, or None when every entry is empty."""
    return None if np.all(column == "") else column


def _group_points(model, points, table, options):
    """Groups of points (band, CCD) by model kind; per-point band names and CCD indices."""
    band, ccd = _blank_to_none(table.band), _blank_to_none(table.ccd)
    scheme = options.scheme
    layout = model.interior_layout
    if layout == "frame":
        groups, bands, ccd_idx = _staring_groups(model, points, band, ccd, options.interior_terms)
    elif layout == "per_array":
        if band is not None:
            band = np.where(band == "", model.reference_band, band)
        groups, bands, ccd_idx = _pushbroom_groups(model, points, band, ccd, options.interior_terms)
    else:
        groups, bands, ccd_idx = _single_group(model, points, band, ccd, scheme)
    if options.parameters is not None and scheme != "joint":
        raise InputError("parameters= applies to scheme='joint' only", field="parameters")
    return groups, bands, ccd_idx


def _single_group(model, points, band, ccd, scheme):
    """One group for a model without CCDs (RPC...): joint scheme only, one band at most."""
    n = points["row"].size
    if scheme != "joint":
        raise InputError(
            f"scheme {scheme!r} needs a push-broom model (installation and directional angles); "
            f"use scheme='joint' for a {getattr(model, 'kind', type(model).__name__)} model",
            field="scheme",
        )
    if ccd is not None:
        raise InputError("ccd applies to push-broom models only", field="ccd")
    if band is not None:
        names = set(np.unique(band)) - {""}
        if len(names) > 1:
            raise InputError("a single band for this model", field="band")
        band = names.pop() if names else None
    groups = [_Group(band, -1, "", np.arange(n))]
    return groups, np.full(n, band, dtype=object), np.full(n, -1, dtype=np.intp)


def _mark_estimable(model, groups, weight, points, options):
    """Flag the groups whose interior can be estimated; skip records of the others."""
    layout = model.interior_layout
    if layout == "per_array":
        check = _check_estimable
    elif layout == "frame":
        check = _check_estimable_staring
    else:
        return []
    skipped = []
    for g in groups:
        rec = check(model, g, weight, points, options.min_points_factor, options.min_span_fraction)
        if rec is not None:
            skipped.append(rec)
    return skipped


def _every(_group):
    return True


def _estimable(group):
    return group.estimable


class _Stepper:
    """Runs the solver step after step on one problem, keeping the parameter vector and log."""

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


def _run_scheme(stepper, model, groups, options):
    """Run the steps of ``options.scheme``; a message when the stepwise schemes did not settle."""
    problem = stepper.problem
    staged = problem.staged
    exterior = list(problem.exterior) if staged else []
    interior = [n for g in groups if g.estimable for n in g.interior]
    scheme = options.scheme
    if scheme == "joint":
        free = _joint_free(problem, exterior, interior, options.parameters)
        prior = None
        if options.gauge and problem.pushbroom:
            prior = _gauge_prior(model, groups, free, options.reference_ccd, options.gauge_sigma_px)
        elif options.gauge and staged:
            prior = _staring_gauge_prior(model, free, options.gauge_sigma_px)
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


def _median_or_zero(values):
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else 0.0


def _moved_sigmas(before, result):
    sd = result.sigma
    if sd is None or not result.success:
        return np.inf
    return float(np.max(np.abs(result.x - before) / np.where(sd > 0, sd, np.inf)))


def _gauge_prior(model, groups, free, reference_ccd, gauge_sigma_px):
    """Pseudo-observations fixing the camera frame in the joint scheme.

    A rotation of the camera shifts every detector's look: roll moves ``tan psi_y``, pitch
    ``tan psi_x``, and yaw tilts ``tan psi_x`` along the CCD. Three linear functionals of the
    reference CCD's polynomials, taken over its detectors ``s = 0 .. n-1``, are held at their
    initial values: the mean of ``tan psi_x(s)``, its least-squares slope in ``s``, and the
    mean of ``tan psi_y(s)``. (Holding single coefficients is not enough: the cubic's higher
    terms can mimic a tilt.) No gauge is added when a CCD with GCPs keeps its interior: its
    points already fix the frame.
    """
    if not any(n in free for n in _EXTERIOR):
        return None
    if any(not any(n in free for n in g.interior) for g in groups):
        return None  # a CCD whose interior is held already anchors the frame
    candidates = [g for g in groups if g.estimable and any(n in free for n in g.interior)]
    if not candidates:
        return None
    if reference_ccd is not None:
        band, name = reference_ccd
        chosen = [g for g in candidates if g.band == band and g.ccd_name == name]
        if not chosen:
            raise InputError(f"reference CCD {band}.{name} has no estimable interior", field="reference_ccd")
        ref = chosen[0]
    else:
        in_ref = [g for g in candidates if g.band == model.reference_band] or candidates
        ref = max(in_ref, key=lambda g: g.idx.size)
    look = model.detector_arrays(ref.band)[ref.ccd]
    ifov = abs(float(look.tan_psi_y[1])) if look.tan_psi_y.size > 1 else 0.0
    if not ifov > 0.0:
        ifov = 1e-5
    s = np.arange(look.n_detectors, dtype=np.float64)
    sc = s - s.mean()
    position = {n: j for j, n in enumerate(free)}
    rows, sigmas = [], []
    for axis, kind, sigma in (
        ("tan_psi_x", "mean", gauge_sigma_px * ifov),
        ("tan_psi_x", "slope", gauge_sigma_px * ifov / max(look.n_detectors / 2.0, 1.0)),
        ("tan_psi_y", "mean", gauge_sigma_px * ifov),
    ):
        row = np.zeros(len(free))
        for k in range(getattr(look, axis).size):
            j = position.get(f"{ref.band}.{look.name}.{axis}.c{k}")
            if j is None:
                continue
            row[j] = np.mean(s**k) if kind == "mean" else np.sum(sc * s**k) / np.sum(sc * sc)
        if np.any(row):
            rows.append(row)
            sigmas.append(sigma)
    if not rows:
        return None
    matrix = np.array(rows)
    lookup = {n: i for i, n in enumerate(model.parameters().names)}
    x0 = model.parameters().values[[lookup[n] for n in free]]
    return Prior(matrix, matrix @ x0, np.array(sigmas))


def _assemble(model, problem, stepper, skipped, options, bands, ccd_idx, unsettled=""):
    """The :class:`CalibrationResult` of the steps ``stepper`` ran."""
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
    ext = [j for j, nm in enumerate(names) if nm in _EXTERIOR]
    other = [j for j, nm in enumerate(names) if nm not in _EXTERIOR]
    if not ext or not other:
        return ""
    block = np.abs(correlation[np.ix_(ext, other)])
    i, j = np.unravel_index(np.nanargmax(block), block.shape)
    return (
        f"largest installation/interior correlation {block[i, j]:.4f} "
        f"({names[ext[i]]} vs {names[other[j]]})"
    )
