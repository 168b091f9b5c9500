"""Offset search for a CCD the coarse stage's SIFT matches left out.

The coarse stage removes each CCD's offset from its own SIFT matches
(:func:`gcpmatch.precorrect.fit_ccd_offsets`); a CCD with fewer than ``min_points`` of them keeps
the offset the whole-scene fit leaves it, which can exceed the fine stage's capture radius
(``window_px / 4``). For such a CCD, after the whole-scene pre-correction:

1. the search radius ``R`` is the larger of twice the capture radius and three times the largest
   offset removed from the other CCDs (what the camera-to-camera and placement errors of this
   camera amount to); the window side ``S`` is the smallest power of two with ``S / 4 >= R``,
   capped by the CCD's width and the scene's lines (the radius actually searched is then
   ``S / 4``);
2. the DOM is rendered through the pre-corrected model in that CCD's geometry
   (:func:`gcpmatch.reference.reference_for_ccd`); windows of ``S`` x ``S`` pixels, half
   overlapping, with data on 90 % of both or more (the rest filled with the window's mean), are
   averaged down by ``r = S / 128`` (``r >= 1``) and phase-correlated with the
   scene's (:func:`gcpmatch.phase.phase_correlate`, its own null-based score and peak-ratio
   tests);
3. the offset is accepted only when at least :data:`MIN_WINDOWS` windows give a valid peak and
   they agree: robust spread (1.4826 MAD) at most :data:`MAX_SPREAD_PX` on both axes, and at
   least :data:`MIN_WINDOWS` of them, and half, within 3 spreads plus one reduced pixel of the
   median (windows over the sea or a cloud deck find no peak: a coastal CCD is judged on its
   land). The agreeing windows then become matches at their centres and the CCD's ``tan psi`` terms are
   fitted to them as for SIFT matches. Otherwise the CCD is left as it is and reported.

A CCD whose ground has no texture (open sea, a cloud deck) gives no agreeing windows: it is
reported "not pre-corrected", never given an offset.
"""

from __future__ import annotations

import numpy as np

from gcpmatch.precorrect import fit_ccd_offsets

__all__ = ["MAX_SPREAD_PX", "MIN_DATA_FRACTION", "MIN_WINDOWS", "REDUCED_WINDOW_PX", "search_ccd_offsets",
           "search_missing_ccds", "search_radius_px", "window_side_px"]

#: fewest valid, agreeing windows for an offset to be accepted
MIN_WINDOWS = 6
#: largest robust spread (1.4826 MAD, full-resolution pixels) of the windows' offsets that still
#: counts as agreement: a CCD's own scale error spreads them by about a pixel across the CCD
#: (the tan psi c1 terms removed from the other CCDs are below 1e-4 of the field), while windows
#: on noise scatter over the whole search range
MAX_SPREAD_PX = 2.0
#: side of the windows after the reduction, pixels
REDUCED_WINDOW_PX = 128
#: least share of a window with scene and reference data (DEM voids and DOM holes are filled
#: with the window's mean: a 256-pixel window rarely misses them all)
MIN_DATA_FRACTION = 0.9


def search_radius_px(capture_px: float, removed: dict) -> float:
    """Radius of the search: ``max(2 capture, 3 max |removed offset|)``, pixels.

    Parameters
    ----------
    capture_px : float
        The fine stage's capture radius, pixels.
    removed : dict of int to (float, float)
        Offsets ``(d_row, d_col)`` removed from the other CCDs, pixels.

    Returns
    -------
    float
        The radius, pixels.
    """
    worst = max((float(np.hypot(*v)) for v in removed.values()), default=0.0)
    return max(2.0 * capture_px, 3.0 * worst)


def window_side_px(radius_px: float, n_detectors: int, n_rows: int) -> int:
    """Side ``S`` of the search windows: smallest power of two with ``S / 4 >= radius``, capped.

    Parameters
    ----------
    radius_px : float
        Radius to search, pixels.
    n_detectors, n_rows : int
        The CCD's width and the scene's lines (the cap: the largest power of two within both).

    Returns
    -------
    int
        ``S``, pixels (0 when the CCD or the scene is narrower than 32 pixels).
    """
    cap = 1 << int(np.floor(np.log2(max(min(n_detectors, n_rows), 1))))
    side = 1 << int(np.ceil(np.log2(max(4.0 * radius_px, 32.0))))
    side = min(side, cap)
    return side if side >= 32 else 0


def _starts(n: int, side: int) -> np.ndarray:
    """Starts of half-overlapping windows of ``side`` along ``range(n)``."""
    k = max(1, (n - side) // (side // 2) + 1)
    return np.linspace(0, n - side, k).astype(int)


def _filled(win: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """``win`` (float32) with its invalid pixels set to the mean of its valid ones."""
    return np.where(ok, win, np.float32(win[ok].mean())).astype(np.float32)


def _windows(scene, ref, first_col, side, r):
    """Reduced window pairs with data on at least :data:`MIN_DATA_FRACTION` of both (the rest
    filled with the window's mean) and their full-resolution centres."""
    n_rows, n_det = ref.shape
    refs, scenes, centres = [], [], []
    for r0 in _starts(n_rows, side):
        for c0 in _starts(n_det, side):
            a = ref[r0 : r0 + side, c0 : c0 + side]
            b = scene[r0 : r0 + side, first_col + c0 : first_col + c0 + side].astype(np.float32)
            ok_a, ok_b = np.isfinite(a), np.isfinite(b) & (b > 0)
            if min(ok_a.mean(), ok_b.mean()) < MIN_DATA_FRACTION:
                continue
            shape = (side // r, r, side // r, r)
            refs.append(_filled(a, ok_a).reshape(shape).mean(axis=(1, 3)))
            scenes.append(_filled(b, ok_b).reshape(shape).mean(axis=(1, 3)))
            centres.append((r0 + 0.5 * side, first_col + c0 + 0.5 * side))
    return refs, scenes, np.array(centres, dtype=float).reshape(-1, 2)


def _ground(model, dem, band, ccd, row, col, h0, iterations: int = 3):
    """Ground points (lon, lat degrees, DEM height metres) of scene pixels through ``model``."""
    h = np.full(row.size, float(h0))
    lon = lat = None
    for _ in range(iterations):
        lon, lat, _ = model.image_to_ground(row, col, height=h, band=band, array=np.full(row.size, ccd))
        dem_h = dem.height_m(lon, lat)
        h = np.where(np.isfinite(dem_h), dem_h, h)
    return lon, lat, h


def _search_one(scene, model, dem, dom, *, band, ccd, radius_px, h_mid):
    """Phase correlation of one CCD's windows; returns ``(report, points or None)``."""
    from gcpmatch.phase import phase_correlate
    from gcpmatch.reference import reference_for_ccd

    look = model.detector_arrays(band)[ccd]
    side = window_side_px(radius_px, look.n_detectors, scene.shape[0])
    report = {"status": "not pre-corrected", "radius_px": round(side / 4.0, 1), "windows": 0, "agree": 0}
    if side == 0:
        report["reason"] = "CCD or scene too small for a search window"
        return report, None
    r = max(1, side // REDUCED_WINDOW_PX)
    ref = reference_for_ccd(model, dem, dom, band=band, ccd=ccd)
    refs, scenes, centres = _windows(scene, ref, look.first_col, side, r)
    report["windows"] = len(refs)
    if len(refs) < MIN_WINDOWS:
        report["reason"] = f"{len(refs)} windows with scene and reference data < {MIN_WINDOWS}"
        return report, None
    res = phase_correlate(np.stack(refs).astype(np.float32), np.stack(scenes).astype(np.float32))
    shifts = np.asarray(res.shift_px, dtype=float) * r
    valid = np.asarray(res.valid)
    if valid.sum() < MIN_WINDOWS:  # (a coast: the windows over the sea find none, the others count)
        report["reason"] = f"{int(valid.sum())} of {len(refs)} windows found a peak"
        return report, None
    med = np.median(shifts[valid], axis=0)
    spread = 1.4826 * np.median(np.abs(shifts[valid] - med), axis=0)
    agree = valid & np.all(np.abs(shifts - med) <= 3.0 * spread + r, axis=1)
    report.update(agree=int(agree.sum()), shift_px=[round(float(v), 2) for v in med],
                  spread_px=[round(float(v), 2) for v in spread])
    if spread.max() > MAX_SPREAD_PX:
        report["reason"] = f"the windows disagree (spread {spread.max():.1f} px > {MAX_SPREAD_PX:g})"
        return report, None
    if agree.sum() < max(MIN_WINDOWS, 0.5 * valid.sum()):
        report["reason"] = f"{int(agree.sum())} of {int(valid.sum())} windows with a peak agree"
        return report, None
    row_p, col_p = centres[agree, 0], centres[agree, 1]
    lon, lat, h = _ground(model, dem, band, ccd, row_p, col_p, h_mid)
    report["status"] = "pre-corrected"
    return report, (row_p + shifts[agree, 0], col_p + shifts[agree, 1], lon, lat, h)


def search_ccd_offsets(scene, model, dem, dom, *, band: str, ccds, capture_px: float, removed: dict,
                       h_mid: float):
    """Search, and remove where the windows agree, the offsets of ``ccds`` (module docstring).

    Parameters
    ----------
    scene : ndarray, shape (n_rows, n_cols)
        The scene band (NaN or 0 = no data).
    model : PushbroomModel
        The pre-corrected model.
    dem : sensor_models.terrain.dem.Dem
        Terrain heights above the ellipsoid, metres.
    dom : MapImage
        Reference orthoimage.
    band : str
        Band of ``model``.
    ccds : iterable of int
        CCDs to search (those the SIFT matches left out).
    capture_px : float
        The fine stage's capture radius, pixels.
    removed : dict of int to (float, float)
        Offsets removed from the other CCDs by their SIFT matches, pixels.
    h_mid : float
        Height to start the ground points' DEM iteration from, metres.

    Returns
    -------
    model : PushbroomModel
        ``model`` with the accepted CCDs' ``tan psi`` terms refitted (unchanged when none).
    reports : dict of int to dict
        Per searched CCD: ``status`` ("pre-corrected" or "not pre-corrected"), ``radius_px``
        (searched), ``windows`` (with data), ``agree``, ``shift_px`` (median ``(d_row, d_col)``)
        and ``spread_px`` where peaks were found, ``reason`` when not accepted.
    """
    radius = search_radius_px(capture_px, removed)
    reports = {}
    for ccd in ccds:
        report, points = _search_one(scene, model, dem, dom, band=band, ccd=ccd, radius_px=radius, h_mid=h_mid)
        if points is not None:
            row, col, lon, lat, h = points
            model, _ = fit_ccd_offsets(model, row, col, lon, lat, h, np.full(row.size, ccd), band=band,
                                       min_points=MIN_WINDOWS)
        reports[ccd] = report
    return model, reports


def search_missing_ccds(scene, model, dem, dom, *, band: str, removed: dict, capture_px: float, h_mid: float):
    """:func:`search_ccd_offsets` of the CCDs missing from ``removed``, when any CCD is in it.

    A model that is not split in CCDs (``removed`` empty: no CCD offsets fitted) and a scene
    whose CCDs all had enough SIFT matches are returned as they are, with no report.

    Parameters
    ----------
    scene, model, dem, dom, band, capture_px, h_mid
        As :func:`search_ccd_offsets`.
    removed : dict of int to (float, float)
        Offsets removed by :func:`gcpmatch.precorrect.fit_ccd_offsets`, pixels, per CCD.

    Returns
    -------
    model, reports
        As :func:`search_ccd_offsets` (``reports`` empty when nothing was searched).
    """
    if not removed:
        return model, {}
    missing = [i for i in range(len(model.detector_arrays(band))) if i not in removed]
    if not missing:
        return model, {}
    return search_ccd_offsets(scene, model, dem, dom, band=band, ccds=missing, capture_px=capture_px,
                              removed=removed, h_mid=h_mid)
