"""Skip the coarse SIFT stage when the model is already within the fine search radius.

A calibrated model (``gcpcal validate``) lands within a pixel or two of the truth, so the
coarse stage (SIFT over the whole scene and the DOM, about 85 % of a validation's time) has
nothing to correct: the dense phase correlation that follows absorbs any offset below its
search radius (``window_px / 4``). The check is cheap: a few windows per CCD, spread along the
scene, are rendered from the DOM through the model (:func:`gcpmatch.reference.reference_for_ccd`
on their lines only) and phase-correlated with the scene. The stage is skipped only when

* at least :data:`MIN_WINDOWS` windows (and half of those with data) give a valid peak, and
* their offsets agree (1.4826 MAD below :data:`MAX_SPREAD_PX` on both axes), and
* the largest offset is below half the radius (a margin: the fine stage is then well inside).

Otherwise (an uncalibrated model hundreds of pixels off, clouds, a model that is not a set of
CCDs) :func:`gcpmatch.coarse.coarse_match` runs SIFT as before.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_SPREAD_PX", "MIN_WINDOWS", "model_offset_px", "within_fine_radius"]

#: fewest valid windows for a decision
MIN_WINDOWS = 6
#: largest spread (robust, pixels) of the windows' offsets that still counts as agreement
MAX_SPREAD_PX = 1.0


def model_offset_px(scene: np.ndarray, model, dem, dom, *, band: str, window_px: int = 64, rows_per_ccd: int = 3,
                    cols_per_ccd: int = 2, radius_px: float = 16.0):
    """Offsets between the scene and the DOM seen through ``model`` at a few windows.

    Parameters
    ----------
    scene : ndarray, shape (n_rows, n_cols)
        The scene band (NaN or 0 = no data).
    model : PushbroomModel
        The current model; a model that is one detector array (not split in CCDs) is not
        checked.
    dem : sensor_models.terrain.dem.Dem
        Terrain heights above the ellipsoid, metres.
    dom : MapImage
        Reference orthoimage.
    band : str
        Band of ``model``.
    window_px : int
        Side of the windows, pixels.
    rows_per_ccd, cols_per_ccd : int
        Windows per CCD along the scene and across each CCD.
    radius_px : float
        Largest offset the phase correlation accepts, pixels.

    Returns
    -------
    shifts : ndarray, shape (n_valid, 2)
        Offsets ``(d_row, d_col)`` of the windows with a valid peak, pixels.
    n_windows : int
        Windows with scene and reference data everywhere.
    """
    from gcpmatch.phase import phase_correlate
    from gcpmatch.reference import reference_for_ccd

    n_rows = scene.shape[0]
    arrays = model.detector_arrays(band)
    if len(arrays) < 2 and model.detector_view(band, 0) is model:
        return np.zeros((0, 2)), 0
    w = int(window_px)
    row_starts = np.linspace(0, n_rows - w, rows_per_ccd + 2)[1:-1].astype(int) if n_rows > 2 * w else []
    refs, scenes = [], []
    for i, look in enumerate(arrays):
        if look.n_detectors < 2 * w:
            continue
        col_starts = np.linspace(0, look.n_detectors - w, cols_per_ccd + 2)[1:-1].astype(int)
        for r0 in row_starts:
            ref = reference_for_ccd(model, dem, dom, band=band, ccd=i, row0=int(r0), row1=int(r0) + w, workers=1)
            for c0 in col_starts:
                a = ref[:, c0 : c0 + w]
                b = scene[r0 : r0 + w, look.first_col + c0 : look.first_col + c0 + w]
                if np.isfinite(a).all() and np.isfinite(b).all() and (b > 0).all():
                    refs.append(a)
                    scenes.append(b)
    if not refs:
        return np.zeros((0, 2)), 0
    result = phase_correlate(np.stack(refs).astype(np.float32), np.stack(scenes).astype(np.float32),
                             max_shift_px=radius_px)
    return np.asarray(result.shift_px)[result.valid], len(refs)


def within_fine_radius(scene: np.ndarray, model, dem, dom, *, band: str, radius_px: float,
                       window_px: int = 64) -> str | None:
    """The note "coarse stage skipped: ..." when ``model`` is within half the fine radius.

    Parameters
    ----------
    scene, model, dem, dom, band
        As :func:`model_offset_px`.
    radius_px : float
        The fine stage's search radius, pixels (``window_px / 4`` in :func:`extract_gcps`).
    window_px : int
        Side of the check's windows, pixels.

    Returns
    -------
    str or None
        "coarse stage skipped: model within N px (fine search radius R px; K of M windows
        agree)", or None when the check cannot tell or the model is not within half the radius
        (run SIFT).
    """
    shifts, n_windows = model_offset_px(scene, model, dem, dom, band=band, window_px=window_px, radius_px=radius_px)
    if shifts.shape[0] < max(MIN_WINDOWS, 0.5 * n_windows):
        return None
    med = np.median(shifts, axis=0)
    spread = 1.4826 * np.median(np.abs(shifts - med), axis=0)
    worst = float(np.hypot(*shifts.T).max())
    if spread.max() > MAX_SPREAD_PX or worst >= 0.5 * radius_px:
        return None
    return (f"coarse stage skipped: model within {worst:.1f} px (fine search radius {radius_px:g} px; "
            f"{shifts.shape[0]} of {n_windows} windows agree)")
