"""Texture statistics a matcher cares about, measured alike on real crops and procedural textures.

Used to calibrate the procedural texture of the ``realistic`` profile on real imagery (issue 13
item 1; ``bench/bench_texture_stats.py`` measures every source, docs/error_budget.md "Texture
calibrated on real crops"):

* :func:`rms_contrast_median`: median over ``window x window`` blocks of ``std / mean`` of the
  radiance (the RMS contrast of Pelli & Bex 2013, Vision Res. 90:10-14), after block-averaging to
  a common ground sample distance;
* :func:`spectral_slope`: ``beta`` of the radially averaged power spectrum ``P(k) ~ k^-beta``
  (natural images: 1.88-2.13, van der Schaaf & van Hateren 1996, Vision Res. 36(17):2759-2770).
"""

from __future__ import annotations

import numpy as np

__all__ = ["block_average", "block_rms_contrast", "rms_contrast_median", "scale_contrast", "spectral_slope"]


def block_average(data: np.ndarray, valid: np.ndarray, factor: int) -> tuple:
    """Mean over ``factor x factor`` blocks; a block with any invalid pixel is invalid.

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance.
    valid : ndarray of bool, shape (H, W)
    factor : int
        Block size, pixels (1: unchanged).

    Returns
    -------
    data, valid : ndarray, shape (H // factor, W // factor)
    """
    if factor <= 1:
        return data, valid
    h, w = (s // factor * factor for s in data.shape)
    d = data[:h, :w].reshape(h // factor, factor, w // factor, factor)
    v = valid[:h, :w].reshape(h // factor, factor, w // factor, factor)
    return d.mean(axis=(1, 3)), v.all(axis=(1, 3))


def block_rms_contrast(data: np.ndarray, valid: np.ndarray | None = None, *, window: int = 32) -> np.ndarray:
    """RMS contrast ``std / mean`` of every ``window x window`` block without an invalid pixel.

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance (positive).
    valid : ndarray of bool, shape (H, W), optional
        Blocks with an invalid pixel are left out (default: the finite pixels).
    window : int
        Block size, pixels.

    Returns
    -------
    ndarray, shape (n,)
        One value per usable block (a positive mean), row-major.
    """
    valid = np.isfinite(data) if valid is None else valid
    h, w = (s // window * window for s in data.shape)
    shape = (h // window, window, w // window, window)
    d = np.where(valid, data, 0.0)[:h, :w].reshape(shape)
    ok = valid[:h, :w].reshape(shape).all(axis=(1, 3))
    mean = d.mean(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        contrast = d.std(axis=(1, 3)) / mean
    return contrast[ok & (mean > 0) & np.isfinite(contrast)]


def rms_contrast_median(data: np.ndarray, valid: np.ndarray | None = None, *, window: int = 32) -> float:
    """Median RMS contrast ``std / mean`` over ``window x window`` blocks (:func:`block_rms_contrast`).

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance (positive).
    valid : ndarray of bool, shape (H, W), optional
        Blocks with an invalid pixel are left out.
    window : int
        Block size, pixels.

    Returns
    -------
    float
        The median (NaN when no block is usable).
    """
    c = block_rms_contrast(data, valid, window=window)
    return float(np.median(c)) if c.size else float("nan")


def scale_contrast(radiance: np.ndarray, gsd_m: float, target: float, *, common_gsd_m: float = 30.0,
                   window: int = 32, passes: int = 3) -> tuple:
    """Radiance with its deviations from the mean scaled so that its median RMS contrast at
    ``common_gsd_m`` is ``target``.

    ``L' = m + g (L - m)`` with ``m`` the mean radiance; ``g`` from the ratio of the target to
    the measured median, refined ``passes`` times (the local means move with ``g`` too);
    values are kept above 1 % of ``m``.

    Parameters
    ----------
    radiance : ndarray, shape (H, W)
        Positive radiance.
    gsd_m : float
        Its pixel size, metres.
    target : float
        Median RMS contrast wanted at ``common_gsd_m``.
    common_gsd_m : float
        Ground sample distance of the measurement (block average).
    window : int
        Block size of the measurement, pixels at ``common_gsd_m``.
    passes : int
        Refinements of ``g``.

    Returns
    -------
    radiance : ndarray, shape (H, W), float32
    gain : float
        The ``g`` applied.
    measured : (float, float)
        Median RMS contrast before and after.
    """
    factor = max(1, int(round(common_gsd_m / gsd_m)))
    src = np.asarray(radiance, dtype=np.float64)
    valid = np.isfinite(src)
    m = float(src[valid].mean())

    def contrast(x):
        return rms_contrast_median(*block_average(x, valid, factor), window=window)

    before = contrast(src)
    gain, out = 1.0, src
    for _ in range(max(1, int(passes))):
        now = contrast(out)
        if not np.isfinite(now) or now <= 0.0:
            break
        gain *= float(target) / now
        out = np.maximum(m + gain * (src - m), 0.01 * m)
    return out.astype(np.float32), float(gain), (float(before), float(contrast(out)))


def spectral_slope(img: np.ndarray, *, lo_px: float = 4.0, hi_px: float = 64.0) -> float:
    """Slope ``beta`` of ``P(k) ~ k^-beta`` (radial average, Hann window) between wavelengths
    ``lo_px`` and ``hi_px`` pixels.

    Parameters
    ----------
    img : ndarray, shape (n, n)
        A fully valid square of radiance.
    lo_px, hi_px : float
        Wavelength band of the fit, pixels.

    Returns
    -------
    float
        ``beta`` (dimensionless; about 2 for a scale-invariant natural image).
    """
    n = img.shape[0]
    win = np.outer(np.hanning(n), np.hanning(n))
    p = np.abs(np.fft.fft2((img - img.mean()) * win)) ** 2
    k = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    band = (k >= 1.0 / hi_px) & (k <= 1.0 / lo_px)
    edges = np.geomspace(1.0 / hi_px, 1.0 / lo_px, 17)
    idx = np.digitize(k[band], edges)
    kk, pp = [], []
    for i in range(1, len(edges)):
        sel = idx == i
        if sel.any():
            kk.append(np.exp(np.log(k[band][sel]).mean()))
            pp.append(p[band][sel].mean())
    return float(-np.polyfit(np.log(kk), np.log(pp), 1)[0])
