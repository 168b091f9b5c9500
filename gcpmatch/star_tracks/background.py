"""Background level and noise maps of a star frame.

Two estimators of the same SExtractor scheme [1]_ (robust statistics on a coarse mesh:
sigma-clipped mode; a median filter over the mesh; interpolation to every pixel):

* :func:`estimate_background_sep` -- SEP's [2]_, on every pixel of each cell, with spline
  interpolation. :func:`gcpmatch.star_tracks.detect_stars` uses it by default: against a simulated
  truth its level error is a third of :func:`estimate_background`'s at its default sampling
  (``bench/bench_starfind.py --versus-sep``).
* :func:`estimate_background` -- ours, on a regular sub-sample of each cell (fast), with
  bicubic interpolation.

References
----------
.. [1] E. Bertin and S. Arnouts, "SExtractor: software for source extraction", A&AS 117,
   393-404 (1996), section 3 (background mesh, mode ``2.5 median - 1.5 mean``).
.. [2] K. Barbary, "SEP: Source Extractor as a library", JOSS 1(6), 58 (2016).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.ndimage as ndi

from gcpmatch.star_tracks._sep import background_maps
from sensor_models.errors import InputError

__all__ = ["Background", "as_image", "estimate_background", "estimate_background_sep"]


@dataclass(frozen=True, eq=False)
class Background:
    """A smooth background level and noise map.

    Attributes
    ----------
    level : ndarray of float32, shape (H, W)
        Background level at every pixel.
    rms : ndarray of float32, shape (H, W)
        Background noise (standard deviation per pixel).
    mesh_level, mesh_rms : ndarray, shape (ny, nx)
        Values at the mesh cells: for :func:`estimate_background` their centres lie at
        ``((i + 0.5) H / ny, (j + 0.5) W / nx)``; for :func:`estimate_background_sep` at
        ``((i + 0.5) mesh_px, (j + 0.5) mesh_px)``, clipped to the image.
    """

    level: np.ndarray
    rms: np.ndarray
    mesh_level: np.ndarray
    mesh_rms: np.ndarray


def _block_edges(n: int, n_blocks: int) -> np.ndarray:
    return np.floor(np.arange(n_blocks + 1) * (n / n_blocks)).astype(np.intp)


def _block_samples(edges: np.ndarray, n_samples: int) -> np.ndarray:
    """``n_samples`` evenly spread pixel indices inside each block, shape (n_blocks, n_samples)."""
    lo, hi = edges[:-1, None], edges[1:, None]
    frac = (np.arange(n_samples) + 0.5) / n_samples
    return (lo + np.floor(frac * (hi - lo))).astype(np.intp)


def _clipped_mode(samples: np.ndarray, clip_sigma: float, iterations: int):
    """Sigma-clipped background statistics of each row of ``samples`` (shape (B, S)).

    Each row is sorted once; a clipping pass then only moves the bounds ``[lo, hi)`` of the
    kept slice: its median is read at the middle, its mean and variance from cumulative sums,
    and the new bounds by one ``searchsorted`` over all rows (the rows are offset so that
    their concatenation stays sorted). The mode is ``2.5 median - 1.5 mean`` unless the
    distribution is very skewed (``|mean - median| > 0.3 std``), where the median is kept
    (Bertin & Arnouts 1996, sec. 3.1).
    """
    s = np.sort(samples.astype(np.float64), axis=1)
    n_blocks, n = s.shape
    rows = np.arange(n_blocks)
    zero = np.zeros((n_blocks, 1))
    c1 = np.concatenate([zero, np.cumsum(s, axis=1)], axis=1)
    c2 = np.concatenate([zero, np.cumsum(s * s, axis=1)], axis=1)
    base = s[:, 0].min()
    span = s[:, -1].max() - base + 1.0
    offset = rows * span
    flat = (s - base + offset[:, None]).ravel()
    first = rows * n

    def stats(lo, hi):
        count = np.maximum(hi - lo, 1)
        median = s[rows, np.minimum(lo + count // 2, n - 1)]
        mean = (c1[rows, hi] - c1[rows, lo]) / count
        var = np.maximum((c2[rows, hi] - c2[rows, lo]) / count - mean * mean, 0.0)
        return median, mean, np.sqrt(var)

    lo = np.zeros(n_blocks, np.intp)
    hi = np.full(n_blocks, n, np.intp)
    for _ in range(iterations):
        median, mean, std = stats(lo, hi)
        low = np.clip(median - clip_sigma * std - base, -0.5, span - 0.5) + offset
        high = np.clip(median + clip_sigma * std - base, -0.5, span - 0.5) + offset
        new_lo = np.searchsorted(flat, low, "left") - first
        new_hi = np.maximum(np.searchsorted(flat, high, "right") - first, new_lo + 1)
        if np.array_equal(new_lo, lo) and np.array_equal(new_hi, hi):
            break
        lo, hi = new_lo, np.minimum(new_hi, n)
    median, mean, std = stats(lo, hi)
    skewed = np.abs(mean - median) > 0.3 * np.maximum(std, 1e-30)
    mode = np.where(skewed, median, 2.5 * median - 1.5 * mean)
    return mode, std


def estimate_background(
    image,
    *,
    mesh_px: int = 64,
    filter_size: int = 3,
    clip_sigma: float = 3.0,
    iterations: int = 8,
    samples_per_mesh: int = 256,
) -> Background:
    """SExtractor-like background and noise maps.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The frame (NaN pixels are replaced by the image median before sampling).
    mesh_px : int, optional
        Approximate mesh cell size in pixels; the image is split into ``round(H / mesh_px)``
        by ``round(W / mesh_px)`` equal cells (at least one).
    filter_size : int, optional
        Size of the median filter applied to the mesh (1 = none).
    clip_sigma : float, optional
        Clipping half-width around the median in standard deviations.
    iterations : int, optional
        Maximum clipping passes.
    samples_per_mesh : int, optional
        Pixels sampled on a regular sub-grid of each cell for the statistics. The mode's
        noise is about ``2.1 rms / sqrt(samples)`` per cell (0.13 rms for the default 256,
        chosen for speed; use ``mesh_px**2`` for SExtractor's all-pixel statistics).

    Returns
    -------
    Background
        Level and noise maps (float32, shape (H, W), ADU) and the mesh values.

    Notes
    -----
    The mesh values are interpolated with OpenCV's bicubic resize, whose sample positions
    coincide with the cell centres because all cells have the same (fractional) size; beyond
    the outer centres the values are extended as constants.
    """
    img = as_image(image)
    h, w = img.shape
    if mesh_px < 4:
        raise InputError("must be at least 4", field="mesh_px")
    ny, nx = max(1, int(round(h / mesh_px))), max(1, int(round(w / mesh_px)))
    side = max(2, int(np.sqrt(samples_per_mesh)))
    rows = _block_samples(_block_edges(h, ny), min(side, h // ny))
    cols = _block_samples(_block_edges(w, nx), min(side, w // nx))
    samples = img[rows[:, None, :, None], cols[None, :, None, :]].reshape(ny * nx, -1)
    if np.isnan(samples).any():
        samples = np.where(np.isnan(samples), np.nanmedian(img), samples)
    mode, std = _clipped_mode(samples, clip_sigma, iterations)
    mesh_level = mode.reshape(ny, nx)
    mesh_rms = std.reshape(ny, nx)
    if filter_size > 1 and (ny > 1 or nx > 1):
        mesh_level = ndi.median_filter(mesh_level, size=filter_size, mode="nearest")
        mesh_rms = ndi.median_filter(mesh_rms, size=filter_size, mode="nearest")
    level = cv2.resize(mesh_level.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    rms = cv2.resize(mesh_rms.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    return Background(level=level, rms=np.maximum(rms, np.float32(1e-12)),
                      mesh_level=mesh_level, mesh_rms=mesh_rms)


def estimate_background_sep(image, *, mesh_px: int = 64, filter_size: int = 3) -> Background:
    """SExtractor's background and noise maps, computed by SEP.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The frame, ADU (non-finite pixels are masked).
    mesh_px : int, optional
        Mesh cell side in pixels (SEP's ``bw = bh``; the last cells of a row or column may be
        partial).
    filter_size : int, optional
        Size of the median filter applied to the mesh (SEP's ``fw = fh``; 1 = none).

    Returns
    -------
    Background
        Level and noise maps (float32, shape (H, W), ADU); the mesh values are the maps read
        at the cell centres ``((i + 0.5) mesh_px, (j + 0.5) mesh_px)`` clipped to the image,
        where SEP's interpolating spline passes through the filtered mesh.
    """
    img = as_image(image)
    if mesh_px < 4:
        raise InputError("must be at least 4", field="mesh_px")
    if filter_size < 1:
        raise InputError("must be at least 1", field="filter_size")
    level, rms = background_maps(img, mesh_px=mesh_px, filter_size=filter_size)
    h, w = img.shape
    rows = np.minimum((np.arange(-(-h // mesh_px)) + 0.5) * mesh_px, h - 0.5).astype(np.intp)
    cols = np.minimum((np.arange(-(-w // mesh_px)) + 0.5) * mesh_px, w - 0.5).astype(np.intp)
    return Background(level=level, rms=np.maximum(rms, np.float32(1e-12)),
                      mesh_level=level[np.ix_(rows, cols)].astype(np.float64),
                      mesh_rms=rms[np.ix_(rows, cols)].astype(np.float64))


def as_image(image) -> np.ndarray:
    """A frame checked and converted for the star pipeline.

    Parameters
    ----------
    image : array_like, shape (H, W)
        A 2-D frame of at least 3 x 3 pixels, any numeric dtype.

    Returns
    -------
    ndarray of float32, shape (H, W)
        The frame itself when it is already float32, else a float32 copy.

    Raises
    ------
    sensor_models.errors.InputError
        Not 2-D, or smaller than 3 x 3 pixels.
    """
    img = np.asarray(image)
    if img.ndim != 2 or min(img.shape) < 3:
        raise InputError(f"expected a 2-D image of at least 3x3 pixels, got shape {img.shape}",
                         field="image")
    if img.dtype != np.float32:
        img = img.astype(np.float32)
    return img


# ============================================================================================
