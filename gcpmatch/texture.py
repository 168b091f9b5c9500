"""Absolute texture measures per window: gradient energy against the band's noise or the pair's mismatch.

The matcher's featureless test (:func:`gcpmatch.clouds.low_texture`, ``texture_fraction``) is relative
to the CCD's typical window, so on a scene with large texture-poor fields it passes most windows.
This module measures a window's texture against the scene band's own noise:

* :func:`band_noise_dn`: the noise standard deviation of an image band, digital numbers, by
  Immerkaer's fast estimator [1]_: the image convolved with the difference of two Laplacians
  ``N = [[1, -2, 1], [-2, 4, -2], [1, -2, 1]]`` (which cancels locally planar signal), then
  ``sigma = sqrt(pi / 2) / (6 (H - 2) (W - 2)) * sum |I * N|``;
* :func:`gradient_snr`: per window and axis, the rms of the forward differences along that axis
  divided by that noise level. The Cramer-Rao bound of a shift between two images of the same
  ground with white noise ``sigma_n`` is ``var(d_axis) >= 2 sigma_n^2 / sum (dI / d_axis)^2``
  [2]_, so a window of ``w x w`` pixels has ``sigma_CR = sqrt(2) / (w * snr)`` px on that axis:
  the snr ranks windows by how well any estimator can place them;
* :func:`mismatch_cr_sigma_px`: the same bound with the pair's own mismatch as the noise (the
  residual of the scene window about a gain and offset of the reference moved by the measured
  shift): what separates a scene from a reference of another sensor and date is rarely the
  sensor's noise. The sigma model (:mod:`gcpmatch.uncertainty`) adds it in quadrature;
* :func:`weak_texture`, :func:`texture_sigma_px`: a gate and a sigma term on the gradient snr,
  measured and left off by default (docs/matching.md, "Texture-poor ground").

References
----------
.. [1] J. Immerkaer, "Fast noise variance estimation", Computer Vision and Image Understanding
   64(2), 1996, pp. 300-302.
.. [2] D. Robinson and P. Milanfar, "Fundamental performance limits in image registration",
   IEEE Transactions on Image Processing 13(9), 2004, pp. 1185-1199.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import convolve

from sensor_models.files.threads import map_ordered, thread_count

__all__ = ["band_noise_dn", "cramer_rao_sigma_px", "gradient_snr", "mismatch_cr_sigma_px", "texture_sigma_px",
           "weak_texture"]

#: Immerkaer's mask: the difference of two Laplacians, blind to locally planar signal
_NOISE_MASK = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])


def band_noise_dn(image: np.ndarray) -> float:
    """Noise standard deviation of an image band, in its digital numbers (Immerkaer 1996).

    Parameters
    ----------
    image : ndarray of float, shape (H, W)
        The band (H, W >= 3); non-finite pixels and their 3 x 3 neighbours are left out.

    Returns
    -------
    float
        ``sqrt(pi / 2) / 6 * mean |I * N|`` over the valid interior pixels; NaN when none.
    """
    img = np.asarray(image, dtype=np.float64)
    finite = np.isfinite(img)
    lap = convolve(np.where(finite, img, 0.0), _NOISE_MASK, mode="nearest")
    valid = convolve(finite.astype(np.float64), np.ones((3, 3)), mode="constant") == 9.0
    valid[[0, -1], :] = False
    valid[:, [0, -1]] = False
    if not valid.any():
        return float("nan")
    return float(np.sqrt(np.pi / 2.0) / 6.0 * np.mean(np.abs(lap[valid])))


def gradient_snr(windows: np.ndarray, noise_dn: float) -> np.ndarray:
    """Per window and axis: rms forward difference over the band's noise level.

    Parameters
    ----------
    windows : ndarray of float, shape (n, w, w)
        Scene windows, digital numbers, finite.
    noise_dn : float
        The band's noise standard deviation (:func:`band_noise_dn`), digital numbers, > 0.

    Returns
    -------
    ndarray of float64, shape (n, 2)
        ``(row, col)``: ``sqrt(mean (I[i+1, j] - I[i, j])^2) / noise_dn`` and the same along
        columns; NaN when ``noise_dn`` is not a positive finite number.
    """
    win = np.asarray(windows, dtype=np.float64)
    if win.shape[0] == 0:
        return np.zeros((0, 2))
    if not (np.isfinite(noise_dn) and noise_dn > 0.0):
        return np.full((win.shape[0], 2), np.nan)
    g_row = np.sqrt(np.mean(np.diff(win, axis=1) ** 2, axis=(1, 2)))
    g_col = np.sqrt(np.mean(np.diff(win, axis=2) ** 2, axis=(1, 2)))
    return np.stack([g_row, g_col], axis=1) / float(noise_dn)


def cramer_rao_sigma_px(snr: np.ndarray, window_px: int) -> np.ndarray:
    """Cramer-Rao bound of a window's shift per axis, pixels, from its gradient snr.

    Parameters
    ----------
    snr : ndarray of float, shape (...)
        :func:`gradient_snr` of the axis.
    window_px : int
        Window side, pixels.

    Returns
    -------
    ndarray of float64, shape (...)
        ``sqrt(2) / (window_px * snr)`` (both images noisy with the band's noise).
    """
    with np.errstate(divide="ignore"):
        return np.sqrt(2.0) / (window_px * np.asarray(snr, dtype=np.float64))


def weak_texture(snr_row: np.ndarray, snr_col: np.ndarray, min_snr: float) -> np.ndarray:
    """Flags of windows whose gradient snr is below ``min_snr`` on either axis (NaN: not flagged).

    Parameters
    ----------
    snr_row, snr_col : ndarray of float, shape (n,)
        :func:`gradient_snr` per axis.
    min_snr : float
        Threshold (0: nothing flagged).

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    with np.errstate(invalid="ignore"):
        return (np.asarray(snr_row) < min_snr) | (np.asarray(snr_col) < min_snr)


def texture_sigma_px(snr_row: np.ndarray, snr_col: np.ndarray, scale_px: float) -> np.ndarray:
    """A weak window's extra matching noise per axis, pixels: ``scale_px / snr`` pooled over the axes.

    The Cramer-Rao shape (:func:`cramer_rao_sigma_px`: proportional to ``1 / snr``) with a scale
    measured on the scenes instead of the band's white noise (what separates a scene from a
    reference of another sensor and date is not the sensor's noise).

    Parameters
    ----------
    snr_row, snr_col : ndarray of float, shape (n,)
        :func:`gradient_snr` per axis.
    scale_px : float
        The extra noise per axis of a window of snr 1, pixels (0: none).

    Returns
    -------
    ndarray of float64, shape (n,)
        ``scale_px sqrt((1 / snr_row^2 + 1 / snr_col^2) / 2)``; 0 where an snr is not finite.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        inv2 = 0.5 * (1.0 / np.asarray(snr_row, float) ** 2 + 1.0 / np.asarray(snr_col, float) ** 2)
    return np.where(np.isfinite(inv2), scale_px * np.sqrt(np.where(np.isfinite(inv2), inv2, 0.0)), 0.0)


#: Windows per task of :func:`mismatch_cr_sigma_px` (fixed: the numbers do not depend on the threads).
MISMATCH_CHUNK = 256


def mismatch_cr_sigma_px(reference: np.ndarray, scene: np.ndarray, shift_px: np.ndarray, *,
                         border_px: int = 8, threads: int | None = None) -> np.ndarray:
    """Per window and axis: the Cramer-Rao shape with the pair's own mismatch as the noise, pixels.

    The reference window is moved by the measured shift (bilinear), the scene window is fitted by
    a gain and offset of it (least squares) inside a border of ``border_px``, and the residual's
    variance ``v`` (what the two windows do not share: noise of both, the change between sensors
    and dates, the reference's resampling) plays the noise of the bound:
    ``sigma_axis = sqrt(v / sum (dI_scene / d_axis)^2)``.

    Parameters
    ----------
    reference, scene : ndarray of float, shape (n, w, w)
        Window pairs (finite).
    shift_px : ndarray of float, shape (n, 2)
        Scene minus reference shift (row, col), pixels (:class:`gcpmatch.window_match.PairMatches`).
    border_px : int
        Border left out of the fit; a pair whose shift exceeds it on an axis gets NaN.
    threads : int or None
        Chunks of ``MISMATCH_CHUNK`` windows computed at once (None: ``GCPCAL_THREADS`` or every
        core, :func:`sensor_models.files.threads.thread_count`); the numbers do not depend on it.

    Returns
    -------
    ndarray of float64, shape (n, 2)
        ``(row, col)`` bound-shaped sigma, pixels; NaN where the shift is not finite or too large.
    """
    reference, scene = np.asarray(reference), np.asarray(scene)
    n = reference.shape[0]
    if n == 0:
        return np.zeros((0, 2))
    spans = [(a, min(n, a + MISMATCH_CHUNK)) for a in range(0, n, MISMATCH_CHUNK)]
    threads = min(thread_count(threads), len(spans))

    def chunk(span):
        a, b = span
        return _mismatch_chunk(reference[a:b], scene[a:b], np.asarray(shift_px)[a:b], border_px)

    return np.concatenate(list(map_ordered(chunk, spans, threads)))


def _mismatch_chunk(reference: np.ndarray, scene: np.ndarray, shift_px: np.ndarray, border_px: int) -> np.ndarray:
    """:func:`mismatch_cr_sigma_px` of one chunk of (k, w, w) windows: (k, 2) sigma, pixels."""
    w = reference.shape[-1]
    d = np.nan_to_num(np.asarray(shift_px, dtype=np.float64), nan=0.0)
    ok = np.isfinite(shift_px).all(axis=1) & (np.abs(np.asarray(shift_px)) <= border_px).all(axis=1)
    d[~ok] = 0.0
    moved = _bilinear_moved(reference, -d, border_px)
    core = np.asarray(scene[:, border_px:w - border_px, border_px:w - border_px], dtype=np.float64)
    x = moved - moved.mean(axis=(1, 2), keepdims=True)
    y = core - core.mean(axis=(1, 2), keepdims=True)
    # sums of products without temporaries: v = (Syy - Sxy^2 / Sxx) / N is the variance of y - gain x
    s_xy = np.einsum("kij,kij->k", x, y)
    s_xx = np.maximum(np.einsum("kij,kij->k", x, x), 1e-30)
    s_yy = np.einsum("kij,kij->k", y, y)
    v = np.maximum(s_yy - s_xy * s_xy / s_xx, 0.0) / (core.shape[1] * core.shape[2])
    d_row = core[:, 1:, :] - core[:, :-1, :]
    d_col = core[:, :, 1:] - core[:, :, :-1]
    g_row = np.einsum("kij,kij->k", d_row, d_row)
    g_col = np.einsum("kij,kij->k", d_col, d_col)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.sqrt(v[:, None] / np.stack([g_row, g_col], axis=1))
    out[~ok] = np.nan
    return out


def _bilinear_moved(windows: np.ndarray, offset_px: np.ndarray, border_px: int) -> np.ndarray:
    """``windows[k]`` sampled bilinearly at ``(i + offset[k, 0], j + offset[k, 1])`` for the pixels
    ``i, j`` inside ``border_px`` (indices clipped to the window), shape (n, w - 2b, w - 2b).

    ``|offset| <= border_px``, so the integer part of each offset selects a slice of the window
    (padded by one edge row and column: the clipping); the windows are grouped by that integer
    part, and each group is moved by slicing and blending its four neighbours, without gathering
    every sample by index.
    """
    n, w = windows.shape[0], windows.shape[-1]
    m = w - 2 * border_px
    base = np.floor(offset_px).astype(np.intp)
    frac = offset_px - base
    padded = np.empty((n, w + 1, w + 1))  # float64; index w reads w - 1, as a clip would
    padded[:, :w, :w] = windows
    padded[:, w, :w] = windows[:, w - 1, :]
    padded[:, :, w] = padded[:, :, w - 1]
    out = np.empty((n, m, m))
    keys = (base[:, 0] + border_px) * (2 * border_px + 2) + (base[:, 1] + border_px)
    order = np.argsort(keys, kind="stable")
    bounds = np.flatnonzero(np.diff(keys[order])) + 1
    for group in np.split(order, bounds):
        r = border_px + base[group[0], 0]
        c = border_px + base[group[0], 1]
        block = padded[group, r:r + m + 1, c:c + m + 1]
        fr, fc = frac[group, 0, None, None], frac[group, 1, None, None]
        cols = block[:, :, :m] + fc * (block[:, :, 1:] - block[:, :, :m])  # (g, m + 1, m)
        out[group] = cols[:, :m] + fr * (cols[:, 1:] - cols[:, :m])
    return out
