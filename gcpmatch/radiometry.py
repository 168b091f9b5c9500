"""Radiometric preparation of window pairs before phase correlation.

Phase correlation with a normalized cross-power spectrum is already invariant to a gain and an
offset per window (:mod:`gcpmatch.phase`, step 1-2). What it is not invariant to is a
non-linear change of the grey levels between the reference and the scene (another sensor's
response, gamma, haze, seasonal change of the ground): the rank (order) transform removes every
monotonic change of grey levels, within each window (Zabih & Woodfill, "Non-parametric local
transforms for computing visual correspondence", ECCV 1994).

Methods (:data:`METHODS`):

* ``"none"``: the windows as they are;
* ``"rank"``: each window replaced by the ranks of its pixels, scaled to [0, 1] (ties get
  their mean rank);
* ``"gradient"``: each window replaced by its gradient magnitude (central differences), which
  weights edges over smooth shading.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata

from sensor_models.errors import InputError

__all__ = ["METHODS", "prepare_windows", "rank_windows"]

METHODS = ("none", "rank", "gradient")


def rank_windows(windows: np.ndarray) -> np.ndarray:
    """Rank transform of each window: pixel ranks scaled to [0, 1] (mean rank for ties).

    Parameters
    ----------
    windows : ndarray of float, shape (n, h, w)
        Windows, finite.

    Returns
    -------
    ndarray of float32, shape (n, h, w)
        ``(rank - 1) / (h w - 1)`` per window: invariant to any increasing grey-level map.
    """
    n, h, w = windows.shape
    ranks = rankdata(windows.reshape(n, -1), axis=1, method="average")
    return ((ranks - 1.0) / max(h * w - 1, 1)).astype(np.float32).reshape(n, h, w)


def _gradient_windows(windows: np.ndarray) -> np.ndarray:
    g_r, g_c = np.gradient(windows.astype(np.float32), axis=(1, 2))
    return np.hypot(g_r, g_c)


def prepare_windows(reference: np.ndarray, scene: np.ndarray, *, method: str = "none"):
    """Both sides of the window pairs through the same radiometric preparation.

    Parameters
    ----------
    reference, scene : ndarray of float, shape (n, h, w)
        Reference and scene windows.
    method : {"none", "rank", "gradient"}
        See the module docstring.

    Returns
    -------
    reference, scene : ndarray, shape (n, h, w)
        The prepared windows (the inputs themselves for ``"none"``).

    Raises
    ------
    InputError
        Unknown ``method``.
    """
    if method == "none":
        return reference, scene
    if method == "rank":
        return rank_windows(reference), rank_windows(scene)
    if method == "gradient":
        return _gradient_windows(reference), _gradient_windows(scene)
    raise InputError(f"radiometry must be one of {', '.join(METHODS)}, got {method!r}", field="radiometry")
