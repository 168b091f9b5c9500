"""Private adapter over SEP (Source Extractor as a library, K. Barbary, JOSS 1(6), 58, 2016).

Only this module imports :mod:`sep`. SEP wants C-contiguous, native-byte-order float arrays and
reports its failures as bare ``Exception``; both are dealt with here.
"""

from __future__ import annotations

import numpy as np
import sep

from sensor_models.errors import InputError


def background_maps(image: np.ndarray, *, mesh_px: int, filter_size: int):
    """SEP's spline-interpolated background level and noise maps.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The frame (non-finite pixels are masked, and set to 0 for SEP).
    mesh_px : int
        Mesh cell side, pixels (SEP's ``bw = bh``).
    filter_size : int
        Median filter over the mesh, cells (SEP's ``fw = fh``).

    Returns
    -------
    level, rms : ndarray of float32, shape (H, W)
        Background level and noise, in the image's units.
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
