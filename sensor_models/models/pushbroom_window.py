"""A window of a push-broom model: the same geometry for a rectangle of its rows and columns.

``window_model(model, row0, col0, n_rows, n_cols)`` gives the :class:`PushbroomModel` of the
pixels ``[row0, row0 + n_rows) x [col0, col0 + n_cols)`` of ``model``, in the window's own pixel
coordinates: pixel ``(r, c)`` of the window is pixel ``(r + row0, c + col0)`` of the model. The
orbit, attitude, installation and attitude correction are shared; the line timing's reference
row moves by ``row0``; each CCD keeps the detectors inside the window, its directional-angle
polynomials re-expanded about its new first detector (an exact change of variable
``s -> s + shift``, no refit).
"""

from __future__ import annotations

from math import comb

import numpy as np

from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.models.pushbroom_types import CcdLook, LineTiming

__all__ = ["shifted_polynomial", "window_model"]


def shifted_polynomial(coefficients, shift: float) -> np.ndarray:
    """Coefficients of ``p(s + shift)`` from those of ``p(s)`` (ascending powers).

    Parameters
    ----------
    coefficients : array_like, shape (K,)
        ``c_0 .. c_{K-1}`` of ``p(s) = sum_k c_k s^k``.
    shift : float
        The change of variable.

    Returns
    -------
    ndarray, shape (K,)
        ``d_k = sum_{j >= k} c_j C(j, k) shift^(j - k)``.
    """
    c = np.asarray(coefficients, dtype=np.float64)
    return np.array([sum(c[j] * comb(j, k) * shift ** (j - k) for j in range(k, c.size)) for k in range(c.size)])


def window_model(model: PushbroomModel, row0: int, col0: int, n_rows: int, n_cols: int) -> PushbroomModel:
    """The model of a rectangle of ``model``'s pixels, in the rectangle's own rows and columns.

    Parameters
    ----------
    model : PushbroomModel
        The whole scene's model.
    row0, col0 : int
        The window's first row and column in ``model``'s pixels (0-based, its first pixel's
        corner).
    n_rows, n_cols : int
        The window's size.

    Returns
    -------
    PushbroomModel
        Same orbit, attitude, installation and attitude correction; every band keeps the CCDs
        (and their detectors) that fall inside the window.

    Raises
    ------
    InputError
        The window does not lie inside the image, or leaves a band without a detector.
    """
    row0, col0, n_rows, n_cols = int(row0), int(col0), int(n_rows), int(n_cols)
    full_rows, full_cols = model.image_shape
    if n_rows < 1 or n_cols < 1 or row0 < 0 or col0 < 0 or row0 + n_rows > full_rows or col0 + n_cols > full_cols:
        raise InputError(f"the window {row0},{col0},{n_rows},{n_cols} (row0,col0,rows,cols) does not lie inside "
                         f"the {full_rows} x {full_cols} px image", field="window")
    bands = {}
    for band in model.bands:
        looks = []
        for ccd in model.band_ccds(band):
            first, last = max(ccd.first_col, col0), min(ccd.first_col + ccd.n_detectors, col0 + n_cols)
            if last <= first:
                continue
            shift = float(first - ccd.first_col)  # detector index of the window's first detector of this CCD
            looks.append(CcdLook(name=ccd.name, first_col=first - col0, n_detectors=last - first,
                                 tan_psi_x=shifted_polynomial(ccd.tan_psi_x, shift),
                                 tan_psi_y=shifted_polynomial(ccd.tan_psi_y, shift)))
        if not looks:
            raise InputError(f"the window holds no detector of band {band!r}", field="window")
        bands[band] = looks
    t = model.line_timing
    timing = LineTiming(reference_row=t.reference_row - row0, reference_seconds=t.reference_seconds,
                        line_period_s=t.line_period_s)
    name = f"{model.name} window rows {row0}-{row0 + n_rows}, cols {col0}-{col0 + n_cols}".strip()
    return PushbroomModel(orbit=model.orbit, attitude=model.attitude, line_timing=timing, bands=bands,
                          installation=model.installation, n_rows=n_rows, reference_band=model.reference_band,
                          name=name, attitude_correction=model.attitude_correction)
