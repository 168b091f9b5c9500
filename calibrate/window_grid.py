"""The grid of reference-band windows that band-to-band matching cuts, CCD by CCD.

On every CCD of the reference band, windows of a given ``(rows, cols)`` shape
(:func:`window_shape`) start every ``spacing`` pixels along and across track
(:func:`grid_starts`); :func:`reference_grid` gives their starts, centres and the ground the
reference band sees at each centre on the DEM. :func:`target_ccd` names the CCD of another band
that shares a reference CCD's chip. Used by :mod:`calibrate.tie_points` and
:mod:`calibrate.relative`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel

__all__ = ["grid_starts", "reference_grid", "target_ccd", "window_shape"]


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


def grid_starts(n: int, window: int, spacing: int) -> np.ndarray:
    """Window starts ``0, spacing, ...`` plus the last one that fits (empty if none does).

    Parameters
    ----------
    n : int
        Pixels available (lines or detectors).
    window : int
        Window size, px.
    spacing : int
        Step between starts, px.

    Returns
    -------
    ndarray of int
        Window starts, px from the first pixel.
    """
    if n < window:
        return np.zeros(0, dtype=np.intp)
    last = n - window
    starts = np.arange(0, last + 1, spacing, dtype=np.intp)
    return starts if starts[-1] == last else np.append(starts, last)


def reference_grid(model: PushbroomModel, dem, reference_band: str, rows, window, spacing: int):
    """Per CCD of the reference band, the window grid and the ground of its centres.

    Parameters
    ----------
    model : PushbroomModel
        The reference band calibrated.
    dem : Dem
        Terrain on which the centres are localized.
    reference_band : str
        Band whose CCDs carry the windows.
    rows : (int, int)
        Lines ``[r0, r1)`` holding the windows.
    window : (int, int)
        Window shape ``(rows, cols)``, px.
    spacing : int
        Grid spacing, px.

    Returns
    -------
    list
        One grid per CCD: ``ccd, name, n_r, n_c``, window starts ``r0, c0``, centres
        ``row_c, col_c`` (px) and their ground ``lon, lat, h``.
    """
    r_lo, r_hi = rows
    wh, ww = window
    rs = r_lo + grid_starts(r_hi - r_lo, wh, spacing)
    grids = []
    for i, look in enumerate(model.band_ccds(reference_band)):
        cs = look.first_col + grid_starts(look.n_detectors, ww, spacing)
        rr, cc = (a.ravel() for a in np.meshgrid(rs, cs, indexing="ij"))
        row_c, col_c = rr + wh / 2.0, cc + ww / 2.0
        if rr.size:
            lon, lat, h = model.image_to_ground(row_c, col_c, dem=dem, band=reference_band, array=i)
        else:
            lon = lat = h = np.zeros(0)
        grids.append(_CcdGrid(i, look.name, rs.size, cs.size, rr, cc, row_c, col_c,
                              np.asarray(lon), np.asarray(lat), np.asarray(h)))
    return grids


def window_shape(window_px) -> tuple[int, int]:
    """``(rows, cols)`` of a window given as one side or a pair; even sizes >= 16 px.

    Parameters
    ----------
    window_px : int or (int, int)
        One side (square) or ``(rows, cols)``, px.

    Returns
    -------
    tuple of int
        ``(rows, cols)``.

    Raises
    ------
    InputError
        Not one or two even sizes of at least 16 px.
    """
    try:
        shape = (int(window_px),) * 2 if np.ndim(window_px) == 0 else tuple(int(v) for v in window_px)
    except (TypeError, ValueError):
        shape = ()
    if len(shape) != 2 or any(v < 16 or v % 2 for v in shape):
        raise InputError(f"window must be one or two even numbers of pixels >= 16, got {window_px!r}",
                         field="window_px")
    return shape


def target_ccd(model: PushbroomModel, band: str, reference_band: str, i: int) -> int | None:
    """The band's CCD of the same name as reference CCD ``i`` (multi-colour chips), else None.

    Parameters
    ----------
    model : PushbroomModel
        The camera.
    band, reference_band : str
        The band searched and the reference band.
    i : int
        Reference CCD index.

    Returns
    -------
    int or None
        The band's CCD index, or None when no CCD of ``band`` has that name.
    """
    name = model.band_ccds(reference_band)[i].name
    names = [c.name for c in model.band_ccds(band)]
    return names.index(name) if name in names else None
