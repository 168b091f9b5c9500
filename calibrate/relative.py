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
:func:`registration_error` measures the same quantity against the truth over a dense grid.

With ``parallax=True`` and the reference band's GCPs, the ties then serve a second purpose:
bands at different along-track places see the ground at different line times, so the ties
observe the attitude's change over those time offsets; they enter one least squares with the
GCPs for the time-varying attitude correction, alternated with the interiors
(:mod:`calibrate.parallax`, docs/attitude.md).

The stage action behind ``gcpcal relative`` (files in, files out) is
:func:`calibrate.actions.relative.relative_calibration_stage`; this module writes no file.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from calibrate._json import json_safe
from calibrate.absolute import calibrate_model
from calibrate.calibration_result import CalibrationResult, residual_statistics
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from gcpmatch.outliers import local_consistency, smooth_residuals
from gcpmatch.phase import Reject, phase_correlate
from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel

__all__ = ["BandResult", "RelativeResult", "TiePoints", "match_band", "registration_error",
           "relative_calibration"]

#: Why a window gave no tie point, in the order the tests run.
REASONS = ("no_ground", "outside", "no_data", "flat", "not_finite", "out_of_range", "low_score",
           "low_peak_ratio", "inconsistent", "model_residual")
_PHASE_REASON = {Reject.FLAT: "flat", Reject.NOT_FINITE: "not_finite", Reject.OUT_OF_RANGE: "out_of_range",
                 Reject.LOW_SCORE: "low_score", Reject.LOW_PEAK_RATIO: "low_peak_ratio"}
#: Floor of a tie point's standard deviation, px (the CCD's robust spread is used above it).
SIGMA_FLOOR_PX = 0.01


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class TiePoints:
    """Tie points between the reference band and one band, as control points of that band.

    All arrays have shape (N,).

    Attributes
    ----------
    band : str
    row_ref, col_ref : ndarray
        Window centres in the reference band, px (first pixel centre at 0.5).
    ccd_ref : ndarray of int
        Reference-band CCD index.
    lon, lat, h : ndarray
        Ground the calibrated reference band sees at ``(row_ref, col_ref)`` on the DEM
        (WGS84 degrees, metres above the ellipsoid).
    row, col : ndarray
        Measured position of that ground in ``band``, px.
    ccd : ndarray of int
        CCD index in ``band``.
    predicted_row, predicted_col : ndarray
        Where the model used for matching put it, px.
    score : ndarray
        Phase-correlation score in [0, 1].
    sigma_px : ndarray
        Standard deviation per axis: the CCD's robust residual spread (floored).
    """

    band: str
    row_ref: np.ndarray
    col_ref: np.ndarray
    ccd_ref: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray
    row: np.ndarray
    col: np.ndarray
    ccd: np.ndarray
    predicted_row: np.ndarray
    predicted_col: np.ndarray
    score: np.ndarray
    sigma_px: np.ndarray

    def __len__(self) -> int:
        return int(self.row.size)

    def as_gcp_table(self) -> GcpTable:
        """The tie points as control points of ``band`` (kind "gcp").

        Returns
        -------
        GcpTable
            ``row, col, lon, lat, h, sigma_px, score`` of the tie points, ``band`` and the CCD
            index (as text) of each.
        """
        return GcpTable.from_arrays(self.row, self.col, self.lon, self.lat, self.h, band=self.band,
                                    ccd=self.ccd, sigma_px=self.sigma_px, score=self.score)


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
        Windows without a tie point, by reason (:data:`REASONS`).
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
        coarse windows (``ccd, row_px, col_px``; see :func:`match_band`).
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


# --------------------------------------------------------------------------- the window grid
@dataclass
class _CcdGrid:
    """Reference windows of one CCD: starts on a (n_r, n_c) grid, centres and their ground."""

    ccd: int
    name: str
    n_r: int
    n_c: int
    r0: np.ndarray  # (n_r * n_c,) window start rows, row-major over the grid
    c0: np.ndarray  # start columns (raster)
    row_c: np.ndarray  # centres, px
    col_c: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray


def _grid_starts(n: int, window: int, spacing: int) -> np.ndarray:
    """Window starts ``0, spacing, ...`` plus the last one that fits (empty if none does)."""
    if n < window:
        return np.zeros(0, dtype=np.intp)
    last = n - window
    starts = np.arange(0, last + 1, spacing, dtype=np.intp)
    return starts if starts[-1] == last else np.append(starts, last)


def _reference_grid(model: PushbroomModel, dem, reference_band: str, rows, window, spacing: int):
    """Per CCD of the reference band, the window grid and the ground of its centres."""
    r_lo, r_hi = rows
    wh, ww = window
    rs = r_lo + _grid_starts(r_hi - r_lo, wh, spacing)
    grids = []
    for i, look in enumerate(model.band_ccds(reference_band)):
        cs = look.first_col + _grid_starts(look.n_detectors, ww, spacing)
        rr, cc = (a.ravel() for a in np.meshgrid(rs, cs, indexing="ij"))
        row_c, col_c = rr + wh / 2.0, cc + ww / 2.0
        if rr.size:
            lon, lat, h = model.image_to_ground(row_c, col_c, dem=dem, band=reference_band, ccd=i)
        else:
            lon = lat = h = np.zeros(0)
        grids.append(_CcdGrid(i, look.name, rs.size, cs.size, rr, cc, row_c, col_c,
                              np.asarray(lon), np.asarray(lat), np.asarray(h)))
    return grids


def _window_shape(window_px) -> tuple[int, int]:
    """``(rows, cols)`` of a window given as one side or a pair; even sizes >= 16 px."""
    try:
        shape = (int(window_px),) * 2 if np.ndim(window_px) == 0 else tuple(int(v) for v in window_px)
    except (TypeError, ValueError):
        shape = ()
    if len(shape) != 2 or any(v < 16 or v % 2 for v in shape):
        raise InputError(f"window must be one or two even numbers of pixels >= 16, got {window_px!r}",
                         field="window_px")
    return shape


def _target_ccd(model: PushbroomModel, band: str, reference_band: str, i: int) -> int | None:
    """The band's CCD of the same name as reference CCD ``i`` (multi-colour chips), else None."""
    name = model.band_ccds(reference_band)[i].name
    names = [c.name for c in model.band_ccds(band)]
    return names.index(name) if name in names else None


# --------------------------------------------------------------------------- matching
def match_band(model: PushbroomModel, reference_image, image, dem, *, band: str, reference_band=None,
               window_px=64, spacing_px: int = 24, rows=None, coarse: bool = True, batch: int = 1024,
               _grids=None):
    """Tie points between the reference band and ``band`` (step 1 and 2 of the module docstring).

    Parameters
    ----------
    model : PushbroomModel
        Reference band calibrated; ``band`` as currently known (predicts the window positions:
        its band-to-band error must stay below a quarter of the coarse windows, or of
        ``window_px`` without ``coarse``).
    reference_image, image : ndarray, shape (n_rows, >= the band's last column)
        Raw rasters of the reference band and of ``band`` (0 or NaN = no data).
    dem : Dem
    band : str
    reference_band : str, optional
        Default: ``model.reference_band``.
    window_px : int or (int, int)
        Phase-correlation window, px: one side (square) or ``(rows, cols)``; even, >= 16.
        Narrow windows (e.g. ``(64, 32)``) bring tie points closer to the CCD ends.
    spacing_px : int
        Grid spacing, px, along and across track.
    rows : (int, int), optional
        Reference-band lines ``[r0, r1)`` holding the windows (default: all).
    coarse : bool
        First measure, per CCD, the mean band-to-band error of the model with a few windows of
        up to four times ``window_px`` (:func:`_coarse_offset`), and cut the fine windows where
        it says: the model's error may then reach a quarter of the coarse window instead of a
        quarter of ``window_px``.
    batch : int
        Window pairs per phase-correlation call (bounds the memory: ~20 bytes per pixel).

    Returns
    -------
    ties : TiePoints
    windows : int
        Windows tried.
    rejected : dict of str to int
        By reason (:data:`REASONS`).
    coarse_offsets : list of dict
        Per reference CCD, the coarse offset applied (``ccd, row_px, col_px``; empty without
        ``coarse``).
    """
    reference_band = reference_band or model.reference_band
    window = _window_shape(window_px)
    rows = _check_rows(rows, model.n_rows)
    ref_img = _check_image(reference_image, model, reference_band)
    img = _check_image(image, model, band)
    grids = _grids if _grids is not None else _reference_grid(model, dem, reference_band, rows, window, int(spacing_px))
    setup = _MatchSetup(model, dem, band, reference_band, window, rows, ref_img, img,
                        sliding_window_view(ref_img, window), sliding_window_view(img, window), int(batch))
    rejected = {r: 0 for r in REASONS}
    parts, n_windows, coarse_offsets = [], 0, []
    for g in grids:
        n_windows += g.r0.size
        if g.r0.size == 0:
            continue
        offset = np.zeros(2)
        if coarse:
            j = _target_ccd(model, band, reference_band, g.ccd)
            offset = _coarse_offset(model, dem, ref_img, img, band, reference_band, g.ccd, j, rows, max(window))
            coarse_offsets.append({"ccd": g.name, "row_px": float(offset[0]), "col_px": float(offset[1])})
        w = _place_windows(setup, g, offset)
        _correlate_windows(setup, w)
        parts.append(_screen_ties(setup, g, w, rejected))
    if parts:
        cols = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    else:
        cols = {k: np.zeros(0, dtype=np.intp if k in ("ccd", "ccd_ref") else np.float64)
                for k in TiePoints.__dataclass_fields__ if k != "band"}
    return TiePoints(band=band, **cols), n_windows, rejected, coarse_offsets


@dataclass(frozen=True)
class _MatchSetup:
    """What every reference CCD's windows share in :func:`match_band`."""

    model: PushbroomModel
    dem: object
    band: str
    reference_band: str
    window: tuple
    rows: tuple
    ref_img: np.ndarray
    img: np.ndarray
    view_ref: np.ndarray
    view_img: np.ndarray
    batch: int


def _place_windows(setup: _MatchSetup, g, offset) -> dict:
    """Windows of one reference CCD's grid in both bands, moved inside the band's CCDs.

    A band window that overhangs the image or its CCD is moved inside, and the reference
    window with it (by at most a quarter of the window): the CCD ends and the first and last
    lines keep their tie points. Returns the window corners (``r0, c0`` reference, ``rb, cb``
    band), centres, ground, predicted band positions, band CCD and a status per window
    (``""``, ``"no_ground"`` or ``"outside"``).
    """
    model, band, reference_band = setup.model, setup.band, setup.reference_band
    wh, ww = setup.window
    hr, hc = wh // 2, ww // 2
    looks = model.band_ccds(band)
    n = g.r0.size
    status = np.full(n, "", dtype=object)
    r0, c0, row_c, col_c = g.r0.copy(), g.c0.copy(), g.row_c.copy(), g.col_c.copy()
    lon, lat, h = g.lon.copy(), g.lat.copy(), g.h.copy()
    j = _target_ccd(model, band, reference_band, g.ccd)
    pr, pc = _predict(model, lon, lat, h, band, j)
    ccd_b = model.ccd_index(np.where(np.isfinite(pc), pc, 0.0), band=band, ccd=j).reshape(-1)
    with np.errstate(invalid="ignore"):
        rb = np.where(np.isfinite(pr), np.rint(pr + offset[0] - hr), -1).astype(np.intp)
        cb = np.where(np.isfinite(pc), np.rint(pc + offset[1] - hc), -1).astype(np.intp)
    first = np.array([c.first_col for c in looks])[ccd_b]
    last = np.array([c.last_col for c in looks])[ccd_b]
    k_r = np.clip(rb, 0, model.n_rows - wh) - rb
    k_c = np.clip(cb, first, np.maximum(last - ww, first)) - cb
    ref_look = model.band_ccds(reference_band)[g.ccd]
    fits = ((np.abs(k_r) <= wh // 4) & (np.abs(k_c) <= ww // 4) & (r0 + k_r >= 0) & (r0 + k_r <= model.n_rows - wh)
            & (c0 + k_c >= ref_look.first_col) & (c0 + k_c <= ref_look.last_col - ww) & (last - first >= ww))
    moved = np.flatnonzero(fits & ((k_r != 0) | (k_c != 0)) & np.isfinite(pr) & np.isfinite(pc))
    if moved.size:
        r0[moved] += k_r[moved]
        c0[moved] += k_c[moved]
        rb[moved] += k_r[moved]
        cb[moved] += k_c[moved]
        row_c[moved], col_c[moved] = r0[moved] + wh / 2.0, c0[moved] + ww / 2.0
        lon[moved], lat[moved], h[moved] = model.image_to_ground(row_c[moved], col_c[moved], dem=setup.dem,
                                                                 band=reference_band, ccd=g.ccd)
        pr[moved], pc[moved] = _predict(model, lon[moved], lat[moved], h[moved], band, j)
    status[~np.isfinite(lon)] = "no_ground"
    inside = (fits | ((k_r == 0) & (k_c == 0) & (last - first >= ww))) & np.isfinite(pr) & np.isfinite(pc)
    status[(status == "") & ~inside] = "outside"
    return {"status": status, "r0": r0, "c0": c0, "rb": rb, "cb": cb, "row_c": row_c, "col_c": col_c,
            "lon": lon, "lat": lat, "h": h, "pr": pr, "pc": pc, "ccd_b": ccd_b}


def _correlate_windows(setup: _MatchSetup, w: dict) -> None:
    """Phase correlation of the windows still in play; adds ``shift`` (N, 2) and ``score`` to ``w``."""
    wh, ww = setup.window
    status, r0, c0, rb, cb = w["status"], w["r0"], w["c0"], w["rb"], w["cb"]
    n = status.size
    shift = np.full((n, 2), np.nan)
    score = np.full(n, np.nan)
    todo = np.flatnonzero(status == "")
    for a in range(0, todo.size, setup.batch):
        k = todo[a:a + setup.batch]
        wr = setup.view_ref[r0[k], c0[k]]
        wb = setup.view_img[rb[k], cb[k]]
        good = _valid_windows(wr) & _valid_windows(wb)
        status[k[~good]] = "no_data"
        k, wr, wb = k[good], wr[good], wb[good]
        if k.size == 0:
            continue
        pm = phase_correlate(wr, wb, max_shift_px=(wh / 4.0, ww / 4.0))
        shift[k, 0], shift[k, 1] = pm.shift_row_px, pm.shift_col_px
        score[k] = pm.score
        for code, name in _PHASE_REASON.items():
            status[k[pm.reason == code]] = name
    w["shift"], w["score"] = shift, score


def _screen_ties(setup: _MatchSetup, g, w: dict, rejected: dict) -> dict:
    """Tie points of one grid that pass the local-consistency and smooth-residual tests.

    Counts every window's reason into ``rejected``; returns the TiePoints columns.
    """
    wh, ww = setup.window
    status, shift, pr, pc = w["status"], w["shift"], w["pr"], w["pc"]
    row_c, col_c = w["row_c"], w["col_c"]
    # measured position of the reference window centre in the band, and its residual
    q_row, q_col = w["rb"] + wh // 2 + shift[:, 0], w["cb"] + ww // 2 + shift[:, 1]
    resid = np.stack([q_row - pr, q_col - pc], axis=-1)
    grid = np.where((status == "")[:, None], resid, np.nan).reshape(g.n_r, g.n_c, 2)
    consistent = local_consistency(grid).reshape(-1)
    status[(status == "") & ~consistent] = "inconsistent"
    keep = np.flatnonzero(status == "")
    sigma = float("nan")
    if keep.size:
        inl, sigma, _ = smooth_residuals(row_c[keep], col_c[keep], resid[keep, 0], resid[keep, 1])
        status[keep[~inl]] = "model_residual"
        keep = keep[inl]
    for r in REASONS:
        rejected[r] += int(np.sum(status == r))
    sig = max(sigma, SIGMA_FLOOR_PX) if np.isfinite(sigma) else 0.1
    return {
        "row_ref": row_c[keep], "col_ref": col_c[keep], "ccd_ref": np.full(keep.size, g.ccd, dtype=np.intp),
        "lon": w["lon"][keep], "lat": w["lat"][keep], "h": w["h"][keep], "row": q_row[keep], "col": q_col[keep],
        "ccd": w["ccd_b"][keep].astype(np.intp), "predicted_row": pr[keep], "predicted_col": pc[keep],
        "score": w["score"][keep], "sigma_px": np.full(keep.size, sig),
    }


def _predict(model, lon, lat, h, band, ccd):
    """Band positions (row, col), px, of ground points; NaN where the ground is NaN."""
    pr, pc = np.full(lon.shape, np.nan), np.full(lon.shape, np.nan)
    ok = np.isfinite(lon)
    if ok.any():
        pr[ok], pc[ok] = model.ground_to_image(lon[ok], lat[ok], h[ok], band=band, ccd=ccd)
    return pr, pc


def _coarse_offset(model, dem, ref_img, img, band, reference_band, i, j, rows, window) -> np.ndarray:
    """Median (row, col) error, px, of the model's band-to-band prediction on reference CCD ``i``.

    Square windows of side ``W`` (the largest even size up to ``4 * window`` that fits the CCD
    and the lines) along the CCD's centre line, one every ``W`` lines, are matched like the fine
    windows, with shifts up to ``W / 4`` and a pixel-level refinement; the median of the valid
    residuals (zero when there is none, or when ``W`` is not larger than ``window``) is the
    offset. The band's window may reach into a neighbouring CCD's columns when the model's
    across-track error is large: a small part of its content is then discontinuous, which the
    median of a pixel-level estimate tolerates.
    """
    look = model.band_ccds(reference_band)[i]
    side = min(4 * window, look.n_detectors, rows[1] - rows[0], img.shape[0]) // 2 * 2
    if side <= window:
        return np.zeros(2)
    r0 = rows[0] + _grid_starts(rows[1] - rows[0], side, side)
    c0 = np.full(r0.size, look.first_col + (look.n_detectors - side) // 2, dtype=np.intp)
    half = side / 2.0
    lon, lat, h = model.image_to_ground(r0 + half, c0 + half, dem=dem, band=reference_band, ccd=i)
    ok = np.isfinite(lon)
    if not ok.any():
        return np.zeros(2)
    pr, pc = model.ground_to_image(lon[ok], lat[ok], h[ok], band=band, ccd=j)
    with np.errstate(invalid="ignore"):
        rb = np.where(np.isfinite(pr), np.rint(pr - half), -1).astype(np.intp)
        cb = np.where(np.isfinite(pc), np.rint(pc - half), -1).astype(np.intp)
    inside = (rb >= 0) & (rb <= img.shape[0] - side) & (cb >= 0) & (cb <= img.shape[1] - side)
    if not inside.any():
        return np.zeros(2)
    ref_rows, ref_cols = r0[ok][inside], c0[ok][inside]
    wr = np.stack([ref_img[r:r + side, c:c + side] for r, c in zip(ref_rows, ref_cols)])
    wb = np.stack([img[r:r + side, c:c + side] for r, c in zip(rb[inside], cb[inside])])
    good = _valid_windows(wr) & _valid_windows(wb)
    if not good.any():
        return np.zeros(2)
    # a pixel-level estimate suffices here: a coarse sub-pixel refinement, no window following
    pm = phase_correlate(wr[good], wb[good], max_shift_px=side / 4.0, upsample=4, follow=0)
    if not pm.valid.any():
        return np.zeros(2)
    d_row = rb[inside][good] + half + pm.shift_row_px - pr[inside][good]
    d_col = cb[inside][good] + half + pm.shift_col_px - pc[inside][good]
    return np.array([np.median(d_row[pm.valid]), np.median(d_col[pm.valid])])


def _valid_windows(windows: np.ndarray) -> np.ndarray:
    """(N,) flags: every pixel finite and positive (0 is no data, as in gcpmatch.extract)."""
    with np.errstate(invalid="ignore"):
        return (np.isfinite(windows) & (windows > 0)).all(axis=(1, 2))


def _check_rows(rows, n_rows: int) -> tuple[int, int]:
    if rows is None:
        return 0, n_rows
    try:
        r0, r1 = (int(v) for v in rows)
    except (TypeError, ValueError):
        raise InputError(f"rows must be two line numbers (r0, r1), got {rows!r}", field="rows") from None
    if not 0 <= r0 < r1 <= n_rows:
        raise InputError(f"rows {r0}:{r1} must satisfy 0 <= r0 < r1 <= {n_rows} (the image lines)", field="rows")
    return r0, r1


def _check_image(image, model: PushbroomModel, band: str) -> np.ndarray:
    img = np.asarray(image, dtype=np.float32)
    need = max(c.last_col for c in model.band_ccds(band))
    if img.ndim != 2 or img.shape[0] != model.n_rows or img.shape[1] < need:
        raise InputError(f"the raster of band {band} is {img.shape}; the model needs {model.n_rows} lines "
                         f"and at least {need} columns", field="images")
    return img


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
        :func:`match_band`).
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
        :func:`match_band`).
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
    window = _window_shape(window_px)
    if int(spacing_px) < 1:
        raise InputError(f"spacing must be >= 1 pixel, got {spacing_px}", field="spacing_px")
    if int(passes) < 1:
        raise InputError(f"passes must be >= 1, got {passes}", field="passes")
    rows = _check_rows(rows, model.n_rows)
    if rows[1] - rows[0] < window[0]:
        raise InputError(f"rows {rows[0]}:{rows[1]} hold fewer lines than one window ({window[0]} lines)", field="rows")
    say = progress or (lambda message: None)
    ref_img = _check_image(images[reference_band], model, reference_band)
    grids = _reference_grid(model, dem, reference_band, rows, window, int(spacing_px))
    options = CalibrationOptions(scheme="interior", robust=robust, interior_terms=interior_terms)
    results, current = {}, model
    for band in bands:
        img = _check_image(images[band], model, band)
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
                                                    rows=rows, coarse=coarse, _grids=grids)
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
    message = cal.message + ("" if cal.success else f"; the interior of {band} is kept") + hint
    return BandResult(band, bool(cal.success), message, n_windows, rejected, ties, cal,
                      residual_statistics(before, cal.inlier), residual_statistics(after, cal.inlier), per_ccd,
                      offsets)


# --------------------------------------------------------------------------- truth
def _grid(n: int, step: float) -> np.ndarray:
    k = max(2, int(np.ceil((n - 1) / step)) + 1)
    return np.linspace(0.5, n - 0.5, k)


def registration_error(true_model: PushbroomModel, model: PushbroomModel, *, dem, bands=None, reference_band=None,
                       step_px: float = 16.0) -> dict:
    """Band-to-band registration error of ``model`` against a TRUE model, px.

    For a grid of reference-band pixels ``p`` on every CCD, the truth says where band ``b``
    sees the same ground, ``q_true = T_b(T_ref^-1(p))``; the model says
    ``q = F_b(F_ref^-1(p))`` (both localize on ``dem``). The error is ``q - q_true``: the
    misregistration of band ``b`` on the reference band that products made with the model
    would carry, whatever the reference band's own absolute error.

    Parameters
    ----------
    true_model, model : PushbroomModel
        Same bands, CCD layouts and line count.
    dem : Dem
    bands : sequence of str, optional
        Default: every band but the reference band.
    reference_band : str, optional
        Default ``model.reference_band``.
    step_px : float
        Grid spacing in the reference band, px.

    Returns
    -------
    dict
        ``{band: {"rms_px", "max_px", "rms_row_px", "rms_col_px", "mean_row_px", "mean_col_px",
        "n_points", "per_ccd": [{"ccd", ...same keys}]}}``; grid points either model cannot
        project are left out.
    """
    reference_band = reference_band or model.reference_band
    bands = [b for b in model.bands if b != reference_band] if bands is None else list(bands)
    if true_model.n_rows != model.n_rows:
        raise InputError(f"the models have different line counts ({true_model.n_rows} and {model.n_rows})")
    rows = _grid(model.n_rows, step_px)
    out = {}
    for band in bands:
        per_ccd, all_d = [], []
        for i, look in enumerate(model.band_ccds(reference_band)):
            cols = look.first_col + _grid(look.n_detectors, step_px)
            rr, cc = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
            j = _target_ccd(model, band, reference_band, i)
            q = []
            for m in (true_model, model):
                lon, lat, h = m.image_to_ground(rr, cc, dem=dem, band=reference_band, ccd=i)
                r, c = np.full(rr.size, np.nan), np.full(rr.size, np.nan)
                ok = np.isfinite(lon)
                if ok.any():
                    r[ok], c[ok] = m.ground_to_image(lon[ok], lat[ok], h[ok], band=band, ccd=j)
                q.append(np.stack([r, c], axis=-1))
            d = q[1] - q[0]
            d = d[np.all(np.isfinite(d), axis=1)]
            per_ccd.append({"ccd": look.name, **_error_stats(d)})
            all_d.append(d)
        out[band] = {**_error_stats(np.concatenate(all_d)), "per_ccd": per_ccd}
    return out


def _error_stats(d: np.ndarray) -> dict:
    if d.size == 0:
        return {"rms_px": None, "max_px": None, "rms_row_px": None, "rms_col_px": None,
                "mean_row_px": None, "mean_col_px": None, "n_points": 0}
    planar = np.hypot(d[:, 0], d[:, 1])
    return {
        "rms_px": float(np.sqrt(np.mean(planar**2))),
        "max_px": float(planar.max()),
        "rms_row_px": float(np.sqrt(np.mean(d[:, 0] ** 2))),
        "rms_col_px": float(np.sqrt(np.mean(d[:, 1] ** 2))),
        "mean_row_px": float(d[:, 0].mean()),
        "mean_col_px": float(d[:, 1].mean()),
        "n_points": int(d.shape[0]),
    }
