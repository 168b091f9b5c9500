"""Band-to-band relative geometric calibration of a push-broom camera (seed 003 section 2.2.2).

The reference band (B2 for HY-1C/CZI) is calibrated absolutely first (exterior, then its
interior; :func:`calibrate.absolute.calibrate_model`). Every other band shares the exterior and
needs only its own interior: the directional-angle polynomials of each of its CCDs (seed 003
eq. 2). Seed 003 section 2.2.2 obtains them from tie points between the band and the reference
band, not from the reference orthoimage:

1. **Tie points** (step 1 of 2.2.2). Both bands are raw scene rasters. On every CCD of the
   reference band, windows of ``window_px`` on a grid every ``spacing_px`` cover the CCD's full
   width and a stretch of lines (``rows``; all lines by default). The model predicts where each
   window centre ``p`` appears in band ``b``: ``p`` is localized on the DEM through the
   calibrated reference band, ``G = F_ref^-1(p)``, and projected into band ``b`` through the
   current model, ``q_pred = F_b(G)``. The band's window is cut at ``round(q_pred)`` (an
   integer shift: no resampling) and phase-correlated with the reference window
   (:func:`gcpmatch.phase.phase_correlate`); the measured position of ``p`` in band ``b`` is
   ``q = round(q_pred) + shift``. A coarse step first measures each CCD's mean error of
   ``q_pred`` with a few windows up to four times larger, so that the model may be off by more
   than a quarter of the fine window. Outliers go by phase quality, by local consistency of the
   residuals ``q - q_pred`` on the window grid, and by robust residuals against a smooth
   per-CCD correction (:mod:`gcpmatch.outliers`), never by a fixed fraction.
2. **Ground points** (step 2). ``G`` (the ground the *calibrated* reference band sees at
   ``p``) is a control point observed at ``q`` in band ``b``.
3. **Interior** (step 3). The band's interior is solved from those points with the exterior
   held (``scheme="interior"``, the same estimator as the reference band's interior, in the
   "generalized camera frame" the reference band's exterior fixed).

Measured on the embedded HY-1C-like scene (``tests/test_relative.py``; laboratory band interiors
4.5 px RMS off their true registration on B2): 0.011, 0.009 and 0.016 px RMS for B1, B3 and B4
against the truth with 64 px windows every 24 px (about 1 s for the three bands); 0.010, 0.009
and 0.016 px with ``(64, 32)`` px windows every 16 px, which reach closer to the CCD ends. A
second matching pass (``passes=2``) changes these by less than 0.001 px.

Band-to-band registration is what the tie residuals ``q - F_b(F_ref^-1(p))`` measure; they are
reported per band and CCD for the model before and after. With a simulation's TRUE model,
:func:`calibrate.band_registration.registration_error` measures the same quantity against the
truth over a dense grid.

With ``parallax=True`` and the reference band's GCPs, the ties then serve a second purpose:
bands at different along-track places see the ground at different line times, so the ties
observe the attitude's change over those time offsets; they enter one least squares with the
GCPs for the time-varying attitude correction, alternated with the interiors
(:mod:`calibrate.parallax`, docs/attitude.md).

The stage action behind ``gcpcal relative`` (files in, files out) is
:func:`calibrate.actions.relative.relative_calibration_stage`; this module writes no file.

This module holds :func:`relative_calibration` and its results (:class:`BandResult`,
:class:`RelativeResult`). The reference windows are laid out by :mod:`calibrate.window_grid`,
matched into :class:`~calibrate.tie_points.TiePoints` by :mod:`calibrate.tie_points` (steps 1
and 2), and the registration error against a TRUE model is :mod:`calibrate.band_registration`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from calibrate._json import json_safe
from calibrate.absolute import calibrate_model
from calibrate.calibration_result import CalibrationResult, residual_statistics
from calibrate.config import CalibrationOptions
from calibrate.tie_points import TiePoints, check_image, check_rows, match_band
from calibrate.window_grid import reference_grid, window_shape
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel

__all__ = ["BandResult", "RelativeResult", "relative_calibration"]


@dataclass
class BandResult:
    """Relative calibration of one band.

    Attributes
    ----------
    band : str
    success : bool
        Tie points were found and the interior solve converged.
    message : str
    windows : int
        Reference windows tried.
    rejected : dict of str to int
        Windows without a tie point, by reason (:data:`calibrate.tie_points.REASONS`).
    ties : TiePoints
    calibration : CalibrationResult or None
        The interior solve (None without tie points).
    before, after : dict
        :func:`calibrate.calibration_result.residual_statistics` of the tie residuals (measured minus
        modelled band position, px) under the model before and after, over the inliers of the
        solve.
    per_ccd : list of dict
        ``ccd, ties, before, after`` per CCD of the band.
    coarse_offsets : list of dict
        First pass: per reference CCD, the model's mean band-to-band error measured by the
        coarse windows (``ccd, row_px, col_px``; see :func:`calibrate.tie_points.match_band`).
    residuals_before_px : ndarray, shape (N, 2), or None
        Per tie point, the residual (row, col, px) under the model given to the stage, when the
        band's ``calibration`` is a later joint solve whose own start was already calibrated
        (band parallax); None when ``calibration.residuals_before`` is that already.
    """

    band: str
    success: bool
    message: str
    windows: int
    rejected: dict
    ties: TiePoints
    calibration: CalibrationResult | None = None
    before: dict = field(default_factory=dict)
    after: dict = field(default_factory=dict)
    per_ccd: list = field(default_factory=list)
    coarse_offsets: list = field(default_factory=list)
    residuals_before_px: np.ndarray | None = None

    def to_dict(self) -> dict:
        """JSON-safe summary (tie statistics, rejections and the solve without per-point data).

        Returns
        -------
        dict
            JSON-ready mapping (statistics in pixels).
        """
        return json_safe({
            "band": self.band,
            "success": self.success,
            "message": self.message,
            "windows": self.windows,
            "ties": len(self.ties),
            "rejected": dict(self.rejected),
            "before": self.before,
            "after": self.after,
            "per_ccd": self.per_ccd,
            "coarse_offsets": self.coarse_offsets,
            "calibration": None if self.calibration is None else self.calibration.to_dict(points=False),
        })


@dataclass
class RelativeResult:
    """Outcome of :func:`relative_calibration`.

    Attributes
    ----------
    model : PushbroomModel
        Every band calibrated: the input model with the interiors of the calibrated bands
        replaced (exterior and reference band untouched).
    reference_band : str
    bands : dict of str to BandResult
        One per calibrated band, in model order.
    options : dict
        The matching and solve settings.
    seconds : float
    parallax : dict or None
        With ``parallax=True``: ``used`` (bool), ``reason`` when not used, else
        :meth:`calibrate.parallax.ParallaxResult.to_dict` and ``result`` (the ParallaxResult).
    """

    model: PushbroomModel
    reference_band: str
    bands: dict
    options: dict
    seconds: float = float("nan")
    parallax: dict | None = None

    @property
    def success(self) -> bool:
        """Every band was calibrated.

        Returns
        -------
        bool
            True when every band's interior solve converged.
        """
        return bool(self.bands) and all(b.success for b in self.bands.values())

    @property
    def message(self) -> str:
        """One message per band, joined.

        Returns
        -------
        str
            ``"band: message"`` per band, joined by ``"; "``.
        """
        return "; ".join(f"{b}: {r.message}" for b, r in self.bands.items())

    def to_dict(self) -> dict:
        """JSON-safe summary: per band tie statistics before/after, per CCD (``relative.json``).

        Returns
        -------
        dict
            JSON-ready mapping (statistics in pixels).
        """
        return json_safe({
            "format": "gcpcal.relative",
            "format_version": 1,
            "success": self.success,
            "reference_band": self.reference_band,
            "options": self.options,
            "seconds": self.seconds,
            "bands": {b: r.to_dict() for b, r in self.bands.items()},
            "parallax": None if self.parallax is None else {k: v for k, v in self.parallax.items() if k != "result"},
        })


# --------------------------------------------------------------------------- calibration
def relative_calibration(model: PushbroomModel, images: Mapping[str, np.ndarray], dem, *, reference_band=None,
                         bands: Sequence[str] | None = None, window_px=64, spacing_px: int = 24, rows=None,
                         robust: str = CalibrationOptions.robust,
                         interior_terms: int = CalibrationOptions.interior_terms, passes: int = 1, coarse: bool = True,
                         gcps: GcpTable | None = None, parallax: bool = False,
                         attitude: str = CalibrationOptions.attitude, progress=None) -> RelativeResult:
    """Calibrate every other band's interior against the reference band (module docstring).

    Parameters
    ----------
    model : PushbroomModel
        The reference band calibrated absolutely (exterior and its interior); the other bands
        as known so far (e.g. laboratory values).
    images : mapping of str to ndarray (n_rows, n_cols)
        Raw rasters of the reference band and of every band to calibrate.
    dem : Dem
        Terrain of the scene (localizes the reference band's windows).
    reference_band : str, optional
        Default ``model.reference_band``.
    bands : sequence of str, optional
        Bands to calibrate (default: every band of the model but the reference band).
    window_px : int or (int, int)
        Phase-correlation window, px: one side or ``(rows, cols)`` (even, >= 16; see
        :func:`calibrate.tie_points.match_band`).
    spacing_px : int
        Grid spacing, px.
    rows : (int, int), optional
        Reference-band lines ``[r0, r1)`` for the tie points (seed 003: a short along-track
        stretch over the full width; default all lines).
    robust : {"cauchy", "huber", "none"}
        Robust loss of the interior solve.
    interior_terms : int
        Degree of the estimated directional-angle polynomials (3: cubic, seed 003 eq. 2).
    passes : int
        Matching passes: after each solve, windows are re-cut where the updated model predicts
        them and the interior is solved again from the input model (with the coarse step and
        phase correlation's window following, one pass is as good on the fixture).
    coarse : bool
        Measure each CCD's mean band-to-band error with larger windows first (see
        :func:`calibrate.tie_points.match_band`).
    gcps : GcpTable, optional
        The reference band's GCPs (those its calibration used); needed by ``parallax``.
    parallax : bool
        After the interiors, estimate the time-varying attitude correction from the GCPs and
        every band's ties together (band parallax, :func:`calibrate.parallax.calibrate_with_parallax`),
        alternated with the reference band's exterior and interior and every band's interior.
        Without ``gcps`` it is skipped (``RelativeResult.parallax`` says why).
    attitude : {"static", "drift", "spline", "auto"}
        Candidate bases of the parallax path (``"static"`` skips it).
    progress : callable, optional
        Called with a one-line message per step.

    Returns
    -------
    RelativeResult
        A band without tie points or whose solve fails keeps its interior and is reported with
        ``success=False``.

    Raises
    ------
    InputError
        Not a push-broom model, unknown bands, missing or mis-sized rasters, bad options.
    """
    t0 = time.perf_counter()
    reference_band, bands = _checked_bands(model, images, reference_band, bands)
    window = window_shape(window_px)
    if int(spacing_px) < 1:
        raise InputError(f"spacing must be >= 1 pixel, got {spacing_px}", field="spacing_px")
    if int(passes) < 1:
        raise InputError(f"passes must be >= 1, got {passes}", field="passes")
    rows = check_rows(rows, model.n_rows)
    if rows[1] - rows[0] < window[0]:
        raise InputError(f"rows {rows[0]}:{rows[1]} hold fewer lines than one window ({window[0]} lines)", field="rows")
    say = progress or (lambda message: None)
    ref_img = check_image(images[reference_band], model, reference_band)
    grids = reference_grid(model, dem, reference_band, rows, window, int(spacing_px))
    options = CalibrationOptions(scheme="interior", robust=robust, interior_terms=interior_terms)
    results, current = {}, model
    for band in bands:
        img = check_image(images[band], model, band)
        results[band], cal = _calibrate_band(current, ref_img, img, dem, band, reference_band, window, rows, grids,
                                             options, int(passes), coarse, say)  # fmt: skip
        if results[band].success:
            current = cal.model
    summary = {"window_px": list(window), "spacing_px": int(spacing_px), "rows": list(rows), "robust": robust,
               "interior_terms": interior_terms, "passes": int(passes), "coarse": bool(coarse),
               "parallax": bool(parallax), "attitude": attitude}
    joint = None
    if parallax:
        joint_options = CalibrationOptions(robust=robust, interior_terms=interior_terms, attitude=attitude)
        current, joint = _parallax(current, results, dem, gcps, joint_options, say)
    return RelativeResult(current, reference_band, results, summary, time.perf_counter() - t0, joint)


def _parallax(model, results, dem, gcps, options, say):
    """The joint attitude step over the calibrated bands; the model and the ``parallax`` record."""
    from calibrate.parallax import calibrate_with_parallax

    ties = {b: r.ties for b, r in results.items() if r.success and len(r.ties)}
    if gcps is None or options.attitude == "static" or not ties:
        why = ("no GCP table of the reference band" if gcps is None else
               "attitude 'static'" if options.attitude == "static" else "no band with tie points")
        return model, {"used": False, "reason": why}
    joint = calibrate_with_parallax(model, ties, gcps, dem=dem, options=options, progress=say)
    record = {"used": bool(joint.success), **joint.to_dict()}
    if not joint.success:
        return model, record
    for band, cal in joint.bands.items():
        r = results[band]
        new = _band_result(band, model, ties[band], r.windows, r.rejected, cal, r.coarse_offsets, None, True)
        # "before" stays what the input model gave (as without parallax); "after" is the final model's
        new.before = r.before
        if r.calibration is not None and len(r.calibration.residuals_before) == len(ties[band]):
            new.residuals_before_px = np.asarray(r.calibration.residuals_before)  # per tie, under the input model
        for row, old in zip(new.per_ccd, r.per_ccd):
            row["before"] = old["before"]
        results[band] = new
    return joint.model, record | {"result": joint}


def _checked_bands(model, images, reference_band, bands):
    """The reference band and the bands to calibrate, checked against the model and rasters."""
    if model.interior_layout != "per_array":
        raise InputError("relative calibration needs a model with per-CCD directional angles (push-broom), "
                         f"got a {model.kind} model")
    reference_band = reference_band or model.reference_band
    if reference_band not in model.bands:
        raise InputError(f"unknown reference band {reference_band!r}; the model has {', '.join(model.bands)}",
                         field="reference_band")
    if bands is None:
        bands = [b for b in model.bands if b != reference_band]
    bands = list(bands)
    unknown = [b for b in bands if b not in model.bands]
    if unknown:
        raise InputError(f"unknown band(s) {', '.join(unknown)}; the model has {', '.join(model.bands)}", field="bands")
    if reference_band in bands:
        raise InputError(f"the reference band {reference_band} cannot be calibrated against itself", field="bands")
    if not bands:
        raise InputError("no band to calibrate: the model has only the reference band", field="bands")
    missing = [b for b in [reference_band] + bands if b not in images]
    if missing:
        raise InputError(f"no raster given for band(s) {', '.join(missing)}", field="images")
    return reference_band, bands


def _calibrate_band(current, ref_img, img, dem, band, reference_band, window, rows, grids, options, passes, coarse,
                    say):
    """Match and solve one band's interior ``passes`` times; its BandResult and last calibration."""
    band_model, cal, first_offsets = current, None, None
    for p in range(passes):
        say(f"band {band}: matching against {reference_band} (pass {p + 1}/{passes})")
        ties, n_win, rejected, offsets = match_band(band_model, ref_img, img, dem, band=band,
                                                    reference_band=reference_band, window_px=window,
                                                    rows=rows, coarse=coarse, grids=grids)
        first_offsets = offsets if first_offsets is None else first_offsets
        if len(ties) == 0:
            cal = None
            break
        say(f"band {band}: {len(ties)} tie points; solving its interior")
        # every pass solves from the input model: 'before' always describes the input
        cal = calibrate_model(current, ties.as_gcp_table(), options=options)
        if not cal.success:
            break
        band_model = cal.model
    return _band_result(band, current, ties, n_win, rejected, cal, first_offsets, window, coarse), cal


def _band_result(band, model, ties, n_windows, rejected, cal, offsets, window, coarse) -> BandResult:
    hint = ""
    if n_windows and len(ties) < 0.1 * n_windows:
        reach = "a quarter of the coarse windows, at most the window size" if coarse else "a quarter of the window"
        hint = (f"; only {len(ties)} of {n_windows} windows matched: the model's band-to-band error may exceed "
                f"what the windows reach ({reach}), or the band shares too little texture with the reference band")
    if cal is None:
        reasons = ", ".join(f"{k} {v}" for k, v in rejected.items() if v)
        return BandResult(band, False, f"no tie point with {band} ({reasons or 'no window'}); its interior is kept"
                          + hint, n_windows, rejected, ties, coarse_offsets=offsets)
    before, after = cal.residuals_before, cal.residuals_after
    per_ccd = []
    for j, look in enumerate(model.band_ccds(band)):
        s = cal.ccd == j
        per_ccd.append({
            "ccd": look.name,
            "ties": int(s.sum()),
            "before": residual_statistics(before[s], cal.inlier[s]),
            "after": residual_statistics(after[s], cal.inlier[s]),
        })
    message = cal.message.replace(" GCPs", " tie points") + ("" if cal.success else f"; the interior of {band} is kept") + hint
    return BandResult(band, bool(cal.success), message, n_windows, rejected, ties, cal,
                      residual_statistics(before, cal.inlier), residual_statistics(after, cal.inlier), per_ccd,
                      offsets)


