"""Coverage gate of a calibration: which detector arrays (CCDs) were calibrated and verified.

A calibration is only as good as the ground its points cover. Per band and detector array
(push-broom CCD, the frame of a staring camera, the whole image of an RPC) this module counts
the fitted GCPs and the independent check points and measures their spread along track (the
fraction of the image rows between the first and the last point) and across track (the
fraction of the array's detectors between its leftmost and rightmost point). It then decides:

* **calibrated**: the solve succeeded, the array has GCPs and its parameters were estimable
  (the calibration did not skip it for too few points or too little spread:
  ``CalibrationResult.skipped``);
* **verified**: the array has at least one check point (never used in the fit).

Two more rules keep a fit that is wrong from being called calibrated:

* **points far outside the image**: an array with a fitted GCP more than
  :data:`OUTSIDE_MARGIN` of the image's size outside the image (rows ``[0, n_rows]``, columns
  ``[0, n_cols]``) is not calibrated: such a point was measured on another image or mistyped,
  and a fit through it extrapolates;
* **check accuracy worse after than before**: an array whose check-point RMSE after the
  calibration exceeds its RMSE before (:func:`apply_check_accuracy`) is not calibrated.

The run's status (:class:`sensor_models.base.CalibrationStatus`) follows: ``failed`` when the
solve failed, ``partial`` when any array is uncalibrated or unverified, else ``calibrated``.
Only the bands the GCP table holds are gated: the other bands are the job of the band-to-band
relative calibration (:mod:`calibrate.relative`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from sensor_models.base import CalibrationStatus

__all__ = ["BAND_LEFT_FOR_RELATIVE", "OUTSIDE_MARGIN", "CcdCoverage", "apply_check_accuracy", "calibration_coverage",
           "calibration_status"]

_UNVERIFIED = "no check point on this detector array; its accuracy is not verified"

#: Share of the image's size (rows, columns) a fitted GCP may lie outside the image.
OUTSIDE_MARGIN = 0.1


@dataclass(frozen=True)
class CcdCoverage:
    """Points and verdict of one band and detector array.

    Attributes
    ----------
    band : str
        Band name (``""`` for a model without bands).
    ccd : str
        Detector array name (``""`` for a model whose image is one array).
    gcps, check_points : int
        Fitted GCPs (positive weight) and check points on the array.
    spread_along : float
        Fraction of the image rows spanned by the GCPs, in [0, 1].
    spread_across : float
        Fraction of the array's detectors spanned by the GCPs, in [0, 1].
    calibrated : bool
        The array's parameters were estimated by a successful solve.
    verified : bool
        The array has check points.
    reason : str
        Why it is not calibrated or not verified; ``""`` when it is both.
    """

    band: str
    ccd: str
    gcps: int
    check_points: int
    spread_along: float
    spread_across: float
    calibrated: bool
    verified: bool
    reason: str

    @property
    def label(self) -> str:
        """``band.ccd`` (or whichever of the two is not empty)."""
        return ".".join(p for p in (self.band, self.ccd) if p) or "image"

    def to_dict(self) -> dict:
        """JSON-ready mapping of the attributes.

        Returns
        -------
        dict
            ``band, ccd, gcps, check_points, spread_along, spread_across, calibrated, verified,
            reason``.
        """
        return asdict(self)


def _array_index(model, band, points, sel) -> np.ndarray:
    """Detector-array index of the selected points (given indices, else from their columns)."""
    ccd = points.get("ccd")
    if ccd is not None and np.issubdtype(np.asarray(ccd).dtype, np.integer):
        return np.asarray(ccd)[sel]
    return np.asarray(model.detector_index(points["col"][sel], band=band)).reshape(-1)


def _band_of(points, default) -> np.ndarray:
    n = points["row"].size
    band = points.get("band")
    if band is None:
        return np.full(n, "" if default is None else str(default), dtype=object)
    band = np.asarray(band).astype(str)
    return np.where((band == "") | (band == "None"), "" if default is None else str(default), band)


def _spread(values, extent) -> float:
    if values.size < 2 or extent <= 0:
        return 0.0
    return float(min(np.ptp(values) / extent, 1.0))


def _per_array_points(model, points, bands_list, default_band):
    """``{(band, array index): (rows, cols)}`` of a point set."""
    out = {}
    if points is None or points["row"].size == 0:
        return out
    band = _band_of(points, default_band)
    for b in bands_list:
        sel = np.nonzero(band == b)[0]
        if sel.size == 0:
            continue
        idx = _array_index(model, b or None, points, sel)
        for k in np.unique(idx):
            s = sel[idx == k]
            out[(b, int(k))] = (points["row"][s], points["col"][s])
    return out


def _skip_reasons(skipped, layout) -> dict:
    """``{(band, array name or None): reason}`` of the calibration's skip records."""
    reasons = {}
    for rec in skipped or ():
        key = (str(rec.get("band") or ""), None if layout == "frame" else str(rec.get("ccd") or ""))
        reasons[key] = str(rec.get("reason", "not estimable"))
    return reasons


def calibration_coverage(model, gcps: dict, checks: dict | None, *, success: bool, skipped=(),
                         weight=None) -> list[CcdCoverage]:
    """Coverage and verdict of every detector array of the bands the GCPs hold.

    Parameters
    ----------
    model : SensorModel
        The model that was calibrated (its detector arrays and image shape).
    gcps : dict
        Fitted points as :func:`calibrate.from_gcps.points_of` returns them (``row, col`` in
        pixels, shape (N,); ``band`` names or None; ``ccd`` indices, names or None).
    checks : dict or None
        Check points, same layout (``points_of(table.checks(), model)``).
    success : bool
        Whether the solve succeeded.
    skipped : sequence of dict
        ``CalibrationResult.skipped``: ``band, ccd, reason`` of the arrays not estimated.
    weight : ndarray, shape (N,), optional
        Weight of each GCP; points of weight 0 are not counted.

    Returns
    -------
    list of CcdCoverage
        One per band (bands of the GCPs, model order) and detector array, array order.
    """
    default_band = getattr(model, "reference_band", None)
    if weight is not None:
        keep = np.asarray(weight) > 0.0
        gcps = {k: (None if v is None else np.asarray(v)[keep]) for k, v in gcps.items()}
    present = set(_band_of(gcps, default_band))
    model_bands = list(getattr(model, "bands", None) or [])
    bands_list = [b for b in model_bands if b in present] + sorted(present - set(model_bands))
    fitted = _per_array_points(model, gcps, bands_list, default_band)
    checked = _per_array_points(model, checks, bands_list, default_band)
    reasons = _skip_reasons(skipped, getattr(model, "interior_layout", "none"))
    n_rows = float(model.image_shape[0])
    outside = _outside_image(gcps, model.image_shape, bands_list, default_band)
    out = []
    for b in bands_list:
        for k, array in enumerate(model.detector_arrays(b or None)):
            rows, cols = fitted.get((b, k), (np.empty(0), np.empty(0)))
            n_checks = checked.get((b, k), (np.empty(0),))[0].size
            skip = reasons.get((b, array.name), reasons.get((b, None))) or outside.get(b)
            out.append(_verdict(b, array, rows, cols, n_checks, n_rows, success, skip))
    return out


def _outside_image(points, image_shape, bands_list, default_band) -> dict:
    """``{band: reason}`` of the bands with fitted GCPs far outside the image."""
    if points is None or points["row"].size == 0:
        return {}
    n_rows, n_cols = (float(n) for n in image_shape)
    row, col = np.asarray(points["row"], dtype=float), np.asarray(points["col"], dtype=float)
    far = ((row < -OUTSIDE_MARGIN * n_rows) | (row > (1 + OUTSIDE_MARGIN) * n_rows)
           | (col < -OUTSIDE_MARGIN * n_cols) | (col > (1 + OUTSIDE_MARGIN) * n_cols) | ~np.isfinite(row + col))
    band = _band_of(points, default_band)
    out = {}
    for b in bands_list:
        n_far = int(np.count_nonzero(far & (band == b)))
        if n_far:
            out[b] = (f"{n_far} GCP(s) lie more than {100 * OUTSIDE_MARGIN:.0f} % of the image outside it "
                      f"({n_rows:.0f} x {n_cols:.0f} px): measured on another image?")
    return out


def apply_check_accuracy(coverage, check_rmse_px) -> list[CcdCoverage]:
    """Withdraw "calibrated" from the arrays whose check accuracy got worse.

    Parameters
    ----------
    coverage : sequence of CcdCoverage
        From :func:`calibration_coverage`.
    check_rmse_px : sequence of (float or None, float or None)
        Check-point RMSE before and after the calibration, pixels, one pair per entry of
        ``coverage`` (None where unknown: no rule applies).

    Returns
    -------
    list of CcdCoverage
        ``coverage`` with ``calibrated=False`` and the reason added where the RMSE after
        exceeds the RMSE before.
    """
    out = []
    for c, (before, after) in zip(coverage, check_rmse_px):
        if c.calibrated and before is not None and after is not None and after > before:
            why = f"its check RMSE got worse ({before:.3f} -> {after:.3f} px): the fit does not hold there"
            c = replace(c, calibrated=False, reason="; ".join(r for r in (why, c.reason) if r))
        out.append(c)
    return out


def _verdict(band, array, rows, cols, n_checks, n_rows, success, skip) -> CcdCoverage:
    """The :class:`CcdCoverage` of one array from its points and the calibration's outcome."""
    why = []
    if not success:
        why.append("the calibration failed")
    elif rows.size == 0:
        why.append("no GCP on this detector array; its parameters are not estimated")
    elif skip:
        why.append(skip)
    calibrated = not why
    if n_checks == 0:
        why.append(_UNVERIFIED)
    return CcdCoverage(band=band, ccd=array.name, gcps=int(rows.size), check_points=int(n_checks),
                       spread_along=_spread(rows, n_rows),
                       spread_across=_spread(cols - array.first_col, float(array.n_detectors)),
                       calibrated=calibrated, verified=n_checks > 0, reason="; ".join(why))


#: reason recorded for a band that no GCP covers (the band-to-band calibration's job)
BAND_LEFT_FOR_RELATIVE = "no GCP in this band: calibrate it against the reference band with gcpcal relative"


def calibration_status(success: bool, message: str, coverage, *, bands_left=()) -> CalibrationStatus:
    """The run's status from the solve's outcome and the coverage of its detector arrays.

    Parameters
    ----------
    success : bool
        Whether the solve succeeded.
    message : str
        The solve's message (kept for a failed run).
    coverage : sequence of CcdCoverage
        From :func:`calibration_coverage`.
    bands_left : sequence of str
        Bands of the model that no GCP covers: their interiors keep their initial values, so
        they are listed as uncalibrated (:data:`BAND_LEFT_FOR_RELATIVE`) until ``gcpcal
        relative`` calibrates them.

    Returns
    -------
    CalibrationStatus
        ``failed`` when the solve failed; ``partial`` when an array or a band is uncalibrated
        or an array unverified (listed with their reasons); ``calibrated`` otherwise.
    """
    uncalibrated = [{"band": c.band, "ccd": c.ccd, "reason": c.reason.replace("; " + _UNVERIFIED, "")}
                    for c in coverage if not c.calibrated]
    uncalibrated += [{"band": b, "ccd": "", "reason": BAND_LEFT_FOR_RELATIVE} for b in bands_left]
    unverified = [{"band": c.band, "ccd": c.ccd, "reason": _UNVERIFIED} for c in coverage if not c.verified]
    if not success:
        return CalibrationStatus("failed", message, uncalibrated, unverified)
    if uncalibrated or unverified:
        parts = []
        if any(not c.calibrated for c in coverage):
            parts.append("not calibrated: " + ", ".join(c.label for c in coverage if not c.calibrated))
        if bands_left:
            parts.append(f"band(s) {', '.join(bands_left)} without GCPs: run gcpcal relative")
        if unverified:
            parts.append("no check points: " + ", ".join(c.label for c in coverage if not c.verified))
        return CalibrationStatus("partial", "; ".join(parts), uncalibrated, unverified)
    return CalibrationStatus("calibrated", "every detector array calibrated and verified")
