"""Tie points between the reference band and another band, matched window by window.

Steps 1 and 2 of the band-to-band calibration (:mod:`calibrate.relative`, seed 003 section
2.2.2): for each reference window of the grid (:mod:`calibrate.window_grid`), the model
predicts where its centre appears in the band; the band's window is cut there (after a coarse
per-CCD offset measured with larger windows) and phase-correlated with the reference window
(:func:`gcpmatch.phase.phase_correlate`). Windows go by phase quality, local consistency and
robust residuals against a smooth per-CCD correction (:mod:`gcpmatch.outliers`); each rejected
window is counted by reason (:data:`REASONS`). :func:`match_band` returns the
:class:`TiePoints`: the ground the reference band sees at each centre, observed at the
measured position in the band. :func:`check_rows` and :func:`check_image` validate the lines
and rasters given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from calibrate.window_grid import grid_starts, reference_grid, target_ccd, window_shape
from gcpmatch.gcps import GcpTable
from gcpmatch.outliers import local_consistency, smooth_residuals
from gcpmatch.phase import Reject, phase_correlate
from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel

__all__ = ["REASONS", "SIGMA_FLOOR_PX", "TiePoints", "check_image", "check_rows", "match_band"]

#: Why a window gave no tie point, in the order the tests run.
REASONS = ("no_ground", "outside", "no_data", "flat", "not_finite", "out_of_range", "low_score",
           "low_peak_ratio", "inconsistent", "model_residual")
_PHASE_REASON = {Reject.FLAT: "flat", Reject.NOT_FINITE: "not_finite", Reject.OUT_OF_RANGE: "out_of_range",
                 Reject.LOW_SCORE: "low_score", Reject.LOW_PEAK_RATIO: "low_peak_ratio"}
#: Floor of a tie point's standard deviation, px (the CCD's robust spread is used above it).
SIGMA_FLOOR_PX = 0.01


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


# --------------------------------------------------------------------------- matching
def match_band(model: PushbroomModel, reference_image, image, dem, *, band: str, reference_band=None,
               window_px=64, spacing_px: int = 24, rows=None, coarse: bool = True, batch: int = 1024,
               grids=None):
    """Tie points between the reference band and ``band`` (steps 1 and 2 of :mod:`calibrate.relative`).

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
    grids : list, optional
        The reference band's window grid from :func:`reference_grid` for these ``rows``,
        ``window_px`` and ``spacing_px``, when the caller already built it (e.g. for several
        bands against one reference); built here when absent.

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
    window = window_shape(window_px)
    rows = check_rows(rows, model.n_rows)
    ref_img = check_image(reference_image, model, reference_band)
    img = check_image(image, model, band)
    grids = grids if grids is not None else reference_grid(model, dem, reference_band, rows, window, int(spacing_px))
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
            j = target_ccd(model, band, reference_band, g.ccd)
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
    j = target_ccd(model, band, reference_band, g.ccd)
    pr, pc = _predict(model, lon, lat, h, band, j)
    ccd_b = model.ccd_index(np.where(np.isfinite(pc), pc, 0.0), band=band, array=j).reshape(-1)
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
                                                                 band=reference_band, array=g.ccd)
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
        pr[ok], pc[ok] = model.ground_to_image(lon[ok], lat[ok], h[ok], band=band, array=ccd)
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
    r0 = rows[0] + grid_starts(rows[1] - rows[0], side, side)
    c0 = np.full(r0.size, look.first_col + (look.n_detectors - side) // 2, dtype=np.intp)
    half = side / 2.0
    lon, lat, h = model.image_to_ground(r0 + half, c0 + half, dem=dem, band=reference_band, array=i)
    ok = np.isfinite(lon)
    if not ok.any():
        return np.zeros(2)
    pr, pc = model.ground_to_image(lon[ok], lat[ok], h[ok], band=band, array=j)
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


def check_rows(rows, n_rows: int) -> tuple[int, int]:
    """The lines ``[r0, r1)`` given, checked against the image (default: every line).

    Parameters
    ----------
    rows : (int, int) or None
        Lines ``[r0, r1)``.
    n_rows : int
        Lines of the image.

    Returns
    -------
    tuple of int
        ``(r0, r1)`` with ``0 <= r0 < r1 <= n_rows``.

    Raises
    ------
    InputError
        Not two line numbers in that range.
    """
    if rows is None:
        return 0, n_rows
    try:
        r0, r1 = (int(v) for v in rows)
    except (TypeError, ValueError):
        raise InputError(f"rows must be two line numbers (r0, r1), got {rows!r}", field="rows") from None
    if not 0 <= r0 < r1 <= n_rows:
        raise InputError(f"rows {r0}:{r1} must satisfy 0 <= r0 < r1 <= {n_rows} (the image lines)", field="rows")
    return r0, r1


def check_image(image, model: PushbroomModel, band: str) -> np.ndarray:
    """A band's raw raster as float32, checked against the model's lines and the band's columns.

    Parameters
    ----------
    image : array_like, shape (n_rows, n_cols)
        Raw raster of ``band`` (0 or NaN = no data).
    model : PushbroomModel
        The camera.
    band : str
        The raster's band.

    Returns
    -------
    ndarray of float32, shape (n_rows, n_cols)

    Raises
    ------
    InputError
        Not 2-D, another line count, or fewer columns than the band's last CCD reaches.
    """
    img = np.asarray(image, dtype=np.float32)
    need = max(c.last_col for c in model.band_ccds(band))
    if img.ndim != 2 or img.shape[0] != model.n_rows or img.shape[1] < need:
        raise InputError(f"the raster of band {band} is {img.shape}; the model needs {model.n_rows} lines "
                         f"and at least {need} columns", field="images")
    return img
