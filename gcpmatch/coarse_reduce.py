"""The coarse stage's reduced scene: block means of the valid pixels and the blocks all valid.

:func:`reduce_scene` averages the scene over ``f`` x ``f`` blocks with OpenCV's area resampling,
no-data (NaN, infinities, values <= 0) counting as 0, and flags the blocks whose pixels are all
valid. When ``f`` divides both sides, every reduced pixel depends on its own block only
(OpenCV's integer-factor area path), so the scene is reduced by bands of lines on threads, each
band's temporaries a few MB. Otherwise OpenCV's area weights span blocks, and the scene is
reduced whole. Lines (a band, or the scene) whose pixels are all valid go to OpenCV as they are,
with no masked copy and no valid mask as float32. Either way the numbers are those of the whole
masked scene at once, to the bit (``tests/test_coarse_reduce.py``).

The copies matter at full size: on the seed-003 geometry (8 192 x 21 800 px, float32, reduced
14 times by the general area path) the masked scene and the valid mask as float32, 714 MB each,
took 3-8 s each to allocate and fill inside the match (0.2-0.4 s in a fresh process), 9.5 s of
a 12.5 s coarse stage on 2 cores (docs/speed.md, "Coarse stage").
"""

from __future__ import annotations

from contextlib import nullcontext

import cv2
import numpy as np

from sensor_models.files.memory import line_bands
from sensor_models.files.threads import map_ordered, opencv_threads

__all__ = ["BAND_PX", "reduce_scene"]

#: Scene pixels per band of the banded reduction (rounded to whole blocks of lines).
BAND_PX = 1 << 20


def reduce_scene(scene: np.ndarray, f: int, *, threads: int = 1):
    """Block means of the valid pixels and the all-valid blocks, by bands when ``f`` divides both sides.

    Parameters
    ----------
    scene : ndarray, shape (n_rows, n_cols)
        The band; NaN, infinities and values <= 0 are no data.
    f : int
        Reduction factor, >= 1.
    threads : int
        Threads over the bands (the result does not depend on it).

    Returns
    -------
    small : ndarray of float32, shape (n_rows // f, n_cols // f)
        ``cv2.resize(INTER_AREA)`` of the scene with no data as 0.
    small_valid : ndarray of bool, same shape
        Blocks whose area-weighted valid fraction is above 0.99.
    """
    n_rows, n_cols = scene.shape
    shape = (n_rows // f, n_cols // f)
    if n_rows % f or n_cols % f:
        return _reduce_rows(scene, shape)
    small = np.empty(shape, np.float32)
    small_valid = np.empty(shape, bool)

    def band(rows):
        out = slice(rows.start // f, rows.stop // f)
        small[out], small_valid[out] = _reduce_rows(scene[rows], (out.stop - out.start, shape[1]))

    threads = max(1, int(threads))
    with opencv_threads(1) if threads > 1 else nullcontext():  # the bands are the parallelism
        for _ in map_ordered(band, line_bands(n_rows, n_cols, BAND_PX, multiple=f), threads):
            pass
    return small, small_valid


def _reduce_rows(rows: np.ndarray, shape: tuple[int, int]):
    """The reduction of a block of lines to ``shape`` (rows, cols): block means and all-valid flags."""
    valid = np.isfinite(rows)
    valid &= rows > 0
    size = (shape[1], shape[0])
    if valid.all():  # the scene as it is, and blocks all valid: no copy of the lines
        small = cv2.resize(np.asarray(rows, dtype=np.float32), size, interpolation=cv2.INTER_AREA)
        return small, np.ones(shape, bool)
    masked = np.where(valid, rows, np.float32(0)).astype(np.float32, copy=False)
    small = cv2.resize(masked, size, interpolation=cv2.INTER_AREA)
    small_valid = cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.99
    return small, small_valid
