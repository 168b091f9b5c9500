"""Private: sample a QA raster under the pixels of a DOM window (the rasterio side of QA masks)."""

from __future__ import annotations

import math

import numpy as np

from sensor_models.maps.reference_qa import invalid_from_qa

#: Most QA pixels read per output pixel before the QA window is read decimated.
_MAX_READ_RATIO = 4


def _centre_indices(start: int, stop: int, n_out: int, origin: float, step: float, q_origin: float,
                    q_step: float) -> np.ndarray:
    """QA pixel index (int64, may lie outside) under the centres of ``n_out`` output pixels along one axis."""
    pos = start + (np.arange(n_out, dtype=np.float64) + 0.5) * ((stop - start) / n_out)
    ground = origin + pos * step
    return np.floor((ground - q_origin) / q_step).astype(np.int64)


def sample_qa_invalid(qa_path: str, layout: str, transform, window, out_shape, *, cirrus: bool = False) -> np.ndarray:
    """Flagged DOM pixels of ``window``, from the QA pixel under each output pixel's centre.

    Parameters
    ----------
    qa_path : str
        QA raster, north-up, in the DOM's CRS.
    layout : str
        Its layout (:data:`sensor_models.maps.reference_qa.QA_LAYOUTS` or ``"mask"``).
    transform : affine.Affine
        The DOM's pixel-corner geotransform (north-up).
    window : (int, int, int, int)
        ``row0, row1, col0, col1`` in DOM pixels (half-open).
    out_shape : (int, int)
        Output rows and columns (the window's shape, or smaller for a decimated read).
    cirrus : bool
        Mask cirrus too (:func:`~sensor_models.maps.reference_qa.invalid_from_qa`).

    Returns
    -------
    ndarray of bool, shape ``out_shape``
        True where the QA flags the pixel, or where the pixel lies outside the QA raster.
    """
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.windows import Window

    row0, row1, col0, col1 = window
    with rasterio.open(qa_path) as ds:
        q = ds.transform
        rows = _centre_indices(row0, row1, out_shape[0], transform.f, transform.e, q.f, q.e)
        cols = _centre_indices(col0, col1, out_shape[1], transform.c, transform.a, q.c, q.a)
        inside_r = (rows >= 0) & (rows < ds.height)
        inside_c = (cols >= 0) & (cols < ds.width)
        out = np.ones(tuple(out_shape), dtype=bool)
        if not inside_r.any() or not inside_c.any():
            return out
        r_lo, r_hi = int(rows[inside_r].min()), int(rows[inside_r].max()) + 1
        c_lo, c_hi = int(cols[inside_c].min()), int(cols[inside_c].max()) + 1
        n_read = (r_hi - r_lo) * (c_hi - c_lo)
        k = max(1, math.ceil(math.sqrt(n_read / (_MAX_READ_RATIO * max(1, out_shape[0] * out_shape[1])))))
        shape = (math.ceil((r_hi - r_lo) / k), math.ceil((c_hi - c_lo) / k))
        values = ds.read(1, window=Window(c_lo, r_lo, c_hi - c_lo, r_hi - r_lo), out_shape=shape,
                         resampling=Resampling.nearest)
    flagged = invalid_from_qa(values, layout, cirrus=cirrus)
    rr = np.clip((rows[inside_r] - r_lo) // k, 0, shape[0] - 1)
    cc = np.clip((cols[inside_c] - c_lo) // k, 0, shape[1] - 1)
    out[np.ix_(inside_r, inside_c)] = flagged[np.ix_(rr, cc)]
    return out
