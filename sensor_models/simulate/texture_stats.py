"""Texture statistics a matcher cares about, measured alike on real crops and procedural textures.

Used to calibrate the procedural texture of the ``realistic`` profile on real imagery
(``bench/bench_texture_stats.py`` measures every source, docs/error_budget.md "Texture
calibrated on real crops"):

* :func:`rms_contrast_median`: median over ``window x window`` blocks of ``std / mean`` of the
  radiance (the RMS contrast of Pelli & Bex 2013, Vision Res. 90:10-14), after block-averaging to
  a common ground sample distance;
* :func:`spectral_slope`: ``beta`` of the radially averaged power spectrum ``P(k) ~ k^-beta``
  (natural images: 1.88-2.13, van der Schaaf & van Hateren 1996, Vision Res. 36(17):2759-2770);
* :func:`textured_fraction`: share of ``window x window`` blocks whose relative gradient energy
  ``mean |grad L|^2 / mean(L)^2`` exceeds :data:`TEXTURED_GRADIENT_ENERGY` (ten times ``2 s^2``,
  a flat block with a noise of ``s`` = 1 % of its mean, two axes: a margin of 10 over what sensor
  noise alone gives), i.e. where a phase correlation has structure to lock on;
* :func:`matcher_gate_fraction`: share of blocks the matcher's own texture gate keeps
  (:func:`gcpmatch.clouds.low_texture`: block standard deviation at least 0.2 of the median
  over the image); relative to the image, so it cannot say that a whole image is texture-poor.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TEXTURED_GRADIENT_ENERGY", "block_average", "block_gradient_energy", "block_rms_contrast",
           "matcher_gate_fraction", "rms_contrast_median", "scale_contrast", "spectral_slope", "textured_fraction",
           "untextured_gradient_ratio"]

#: relative gradient energy ``mean |grad L|^2 / mean(L)^2`` above which a block has texture:
#: 10 x (2 x 0.01^2), ten times that of a flat block with 1 % noise (module docstring)
TEXTURED_GRADIENT_ENERGY = 10.0 * 2.0 * 0.01**2
#: pixels of the raster :func:`scale_contrast` converts to float64 at a time (whole rows of blocks)
_STRIP_PIXELS = 1 << 18


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


def _blocks(a: np.ndarray, window: int) -> np.ndarray:
    """``(H // window, window, W // window, window)`` view of the whole blocks of ``a``."""
    h, w = (s // window * window for s in a.shape)
    return a[:h, :w].reshape(h // window, window, w // window, window)


def block_gradient_energy(data: np.ndarray, valid: np.ndarray | None = None, *, window: int = 32) -> np.ndarray:
    """Relative gradient energy ``mean |grad L|^2 / mean(L)^2`` of every fully valid block.

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance (positive); gradients by central differences (``numpy.gradient``), per pixel.
    valid : ndarray of bool, shape (H, W), optional
        Blocks with an invalid pixel are left out (default: the finite pixels).
    window : int
        Block size, pixels.

    Returns
    -------
    ndarray, shape (n,)
        One value per usable block (fully valid, positive mean), row-major; dimensionless, per pixel^2.
    """
    data = np.asarray(data, dtype=np.float64)
    valid = np.isfinite(data) if valid is None else valid
    gy, gx = np.gradient(data)
    ok = _blocks(valid, window).all(axis=(1, 3))
    mean = _blocks(data, window).mean(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        energy = _blocks(gx * gx + gy * gy, window).mean(axis=(1, 3)) / mean**2
    return energy[ok & (mean > 0) & np.isfinite(energy)]


def textured_fraction(data: np.ndarray, valid: np.ndarray | None = None, *, window: int = 32,
                      threshold: float = TEXTURED_GRADIENT_ENERGY) -> float:
    """Share of the usable blocks whose relative gradient energy exceeds ``threshold``.

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance (positive).
    valid : ndarray of bool, shape (H, W), optional
        Blocks with an invalid pixel are left out.
    window : int
        Block size, pixels.
    threshold : float
        Relative gradient energy of a textured block (default :data:`TEXTURED_GRADIENT_ENERGY`).

    Returns
    -------
    float
        In [0, 1] (NaN when no block is usable).
    """
    e = block_gradient_energy(data, valid, window=window)
    return float(np.mean(e > threshold)) if e.size else float("nan")


def untextured_gradient_ratio(data: np.ndarray, valid: np.ndarray | None = None, *, window: int = 32,
                              threshold: float = TEXTURED_GRADIENT_ENERGY) -> float:
    """Median relative gradient RMS of the untextured blocks over that of the textured ones.

    How much texture the texture-poor ground of an image keeps (the ``realistic`` profile's
    ``texture_poor_attenuation`` is this figure on the Sentinel-2 crop).

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance (positive).
    valid : ndarray of bool, shape (H, W), optional
        Blocks with an invalid pixel are left out.
    window : int
        Block size, pixels.
    threshold : float
        Relative gradient energy of a textured block (:func:`textured_fraction`).

    Returns
    -------
    float
        ``sqrt(median E_untextured / median E_textured)`` (NaN without both kinds of block).
    """
    e = block_gradient_energy(data, valid, window=window)
    textured = e > threshold
    if not textured.any() or textured.all():
        return float("nan")
    return float(np.sqrt(np.median(e[~textured]) / np.median(e[textured])))


def matcher_gate_fraction(data: np.ndarray, valid: np.ndarray | None = None, *, window: int = 32,
                          gate: float = 0.2) -> float:
    """Share of the usable blocks whose standard deviation is at least ``gate`` times the median's.

    The matcher's texture gate (``gcpmatch.clouds.low_texture``, ``MatchOptions.texture_fraction``
    0.2) applied to blocks of an image.

    Parameters
    ----------
    data : ndarray, shape (H, W)
        Radiance.
    valid : ndarray of bool, shape (H, W), optional
        Blocks with an invalid pixel are left out.
    window : int
        Block size, pixels.
    gate : float
        Share of the median block standard deviation below which a block is featureless.

    Returns
    -------
    float
        In [0, 1] (NaN when no block is usable).
    """
    data = np.asarray(data, dtype=np.float64)
    valid = np.isfinite(data) if valid is None else valid
    ok = _blocks(valid, window).all(axis=(1, 3))
    std = _blocks(np.where(valid, data, 0.0), window).std(axis=(1, 3))[ok]
    return float(np.mean(std >= gate * np.median(std))) if std.size else float("nan")


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
    src = np.asarray(radiance)
    valid = np.isfinite(src)
    # strips of whole measurement blocks: no float64 copy of the whole raster is held
    step = factor * window * max(1, _STRIP_PIXELS // max(1, src.shape[1]) // (factor * window))
    strips = [slice(r0, min(r0 + step, src.shape[0])) for r0 in range(0, src.shape[0], step)]
    total, count = 0.0, 0
    for rows in strips:
        total += float(src[rows][valid[rows]].sum(dtype=np.float64))
        count += int(np.count_nonzero(valid[rows]))
    m = total / max(count, 1)

    def scaled(rows, gain):
        s = src[rows].astype(np.float64)
        return s if gain is None else np.maximum(m + gain * (s - m), 0.01 * m)

    def contrast(gain):
        c = [block_rms_contrast(*block_average(scaled(rows, gain), valid[rows], factor), window=window) for rows in strips]
        c = np.concatenate(c) if c else np.empty(0)
        return float(np.median(c)) if c.size else float("nan")

    before = contrast(None)
    gain, applied = 1.0, None
    for _ in range(max(1, int(passes))):
        now = before if applied is None else contrast(applied)
        if not np.isfinite(now) or now <= 0.0:
            break
        gain *= float(target) / now
        applied = gain
    out = np.empty(src.shape, dtype=np.float32)
    for rows in strips:
        out[rows] = scaled(rows, applied)
    return out, float(gain), (float(before), float(before if applied is None else contrast(applied)))


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
