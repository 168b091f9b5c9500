"""Private adapter over SEP (Source Extractor as a library, K. Barbary, JOSS 1(6), 58, 2016).

Only this module imports :mod:`sep`. SEP wants C-contiguous, native-byte-order float arrays and
reports its failures as bare ``Exception``; both are dealt with here.
"""

from __future__ import annotations

import numpy as np
import sep

from sensor_models.errors import InputError


def background_maps(image: np.ndarray, *, mesh_px: int, filter_size: int):
    """SEP's spline-interpolated background level and noise maps of ``image`` (H, W).

    Non-finite pixels are masked (and set to 0 for SEP). Returns ``(level, rms)`` as float32
    arrays of shape (H, W), in the image's units.
    """
    data = np.ascontiguousarray(image, dtype=np.float32)
    bad = ~np.isfinite(data)
    mask = None
    if bad.any():
        data = np.where(bad, np.float32(0.0), data)
        mask = bad
    try:
        bkg = sep.Background(data, mask=mask, bw=int(mesh_px), bh=int(mesh_px),
                             fw=int(filter_size), fh=int(filter_size))
        return bkg.back(dtype=np.float32), bkg.rms(dtype=np.float32)
    except MemoryError:
        raise
    except Exception as exc:  # SEP raises bare Exception with its C library's message
        raise InputError(f"SEP background estimation failed: {exc}", field="image") from exc
