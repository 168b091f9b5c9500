"""Point spread functions: what one detector pixel integrates.

* :func:`pixel_integrals` and :func:`render_stars`: a circular Gaussian PSF integrated over
  unit pixels, and point sources (stars, point-like targets) drawn with it; used by star
  detection (:mod:`gcpmatch.star_tracks`), the star-field simulator and their tests.
* :func:`psf_sigma_dom_px`: the Gaussian equivalent of one scene pixel's response (detector
  box, line-time smear, optics) expressed in pixels of a reference map image, the blur that
  :func:`sensor_models.maps.raster.sample_map_image` applies before resampling a DOM into scene
  geometry.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

__all__ = ["dn_uint16", "pixel_integrals", "psf_sigma_dom_px", "render_stars"]

_SQRT2 = np.sqrt(2.0)


def pixel_integrals(centres, mu, sigma):
    """Integral of a unit 1-D Gaussian over unit pixels and its derivatives.

    ``E_i = (erf(b_i) - erf(a_i)) / 2`` with ``a, b = (x_i -+ 1/2 - mu) / (sqrt(2) sigma)``;
    ``dE/dmu = (exp(-a^2) - exp(-b^2)) / (sqrt(2 pi) sigma)`` and
    ``dE/dsigma = (a exp(-a^2) - b exp(-b^2)) / (sqrt(pi) sigma)``.

    Parameters
    ----------
    centres : ndarray of float, shape (N, w)
        Pixel centres along one axis (project convention: pixel ``k`` centred at ``k + 0.5``),
        ``w`` pixels for each of ``N`` sources.
    mu : ndarray of float, shape (N,)
        Gaussian centre of each source, pixels.
    sigma : ndarray of float, shape (N,)
        Gaussian standard deviation of each source, pixels (> 0).

    Returns
    -------
    e, d_mu, d_sigma : ndarray of float64, shape (N, w)
        The pixel integrals ``E`` and their derivatives with respect to ``mu`` and ``sigma``
        (per pixel).
    """
    s = sigma[:, None]
    a = (centres - 0.5 - mu[:, None]) / (_SQRT2 * s)
    b = (centres + 0.5 - mu[:, None]) / (_SQRT2 * s)
    ea, eb = np.exp(-a * a), np.exp(-b * b)
    e = 0.5 * (erf(b) - erf(a))
    d_mu = (ea - eb) / (np.sqrt(2.0 * np.pi) * s)
    d_sigma = (a * ea - b * eb) / (np.sqrt(np.pi) * s)
    return e, d_mu, d_sigma


def render_stars(shape, rowcol, flux, *, sigma_px: float, background: float = 0.0,
                 gain_e_per_adu: float = 1.0, read_noise_e: float = 0.0, rng=None,
                 half_width_px: int | None = None, out: np.ndarray | None = None) -> np.ndarray:
    """Render pixel-integrated circular Gaussian stars, optionally with shot and read noise.

    Parameters
    ----------
    shape : (int, int)
        Image shape (H, W).
    rowcol : array_like, shape (N, 2)
        Star centres, project convention.
    flux : array_like, shape (N,)
        Total flux of each star, ADU.
    sigma_px : float
        PSF sigma in pixels.
    background : float, optional
        Constant background, ADU.
    gain_e_per_adu : float, optional
        Electrons per ADU, for the shot noise (variance ``signal / gain`` ADU^2).
    read_noise_e : float, optional
        Read noise, electrons.
    rng : numpy.random.Generator, optional
        Noise generator; ``None`` renders a noiseless image.
    half_width_px : int, optional
        Stars are drawn within this many pixels of their centre (default ``ceil(5 sigma)``).
    out : ndarray of float64, shape ``shape``, optional
        C-contiguous array to render into (a frame loop reuses one buffer instead of touching a
        fresh 8 MB allocation per 1024 x 1024 frame); returned.

    Returns
    -------
    ndarray of float64, shape ``shape``
        ``background + sum F_k Er Ec`` plus Gaussian noise of variance
        ``max(signal, 0) / gain + (read_noise / gain)^2`` when ``rng`` is given (the same
        draws, and the same bits, with or without ``out``).

    Notes
    -----
    The star sums are formed only at the pixels a star touches (each pixel's terms added in the
    order of the stars), the untouched background being one value.
    """
    h, w = int(shape[0]), int(shape[1])
    rc = np.asarray(rowcol, dtype=np.float64).reshape(-1, 2)
    flux = np.broadcast_to(np.asarray(flux, dtype=np.float64), (rc.shape[0],))
    half = int(np.ceil(5.0 * sigma_px)) if half_width_px is None else int(half_width_px)
    bg = float(background)
    if out is not None and (out.shape != (h, w) or out.dtype != np.float64 or not out.flags.c_contiguous):
        raise ValueError(f"out must be a C-contiguous float64 array of shape {(h, w)}")
    touched, star = _star_sums(h, w, rc, flux, float(sigma_px), half, bg)
    if rng is None:
        image = np.empty((h, w)) if out is None else out
        image.fill(bg)
        image.reshape(-1)[touched] = star
        return image
    # noise sigma sqrt(max(signal, 0) / gain + (read / gain)^2): one value on the untouched
    # background, evaluated per pixel only where a star adds (the same arithmetic, fewer passes)
    read_var = (read_noise_e / gain_e_per_adu) ** 2
    noisy = rng.standard_normal((h, w)) if out is None else rng.standard_normal(out=out)
    z = noisy.reshape(-1)[touched]
    noisy *= np.sqrt(max(bg, 0.0) / gain_e_per_adu + read_var)
    noisy += bg
    noisy.reshape(-1)[touched] = star + z * np.sqrt(np.maximum(star, 0.0) / gain_e_per_adu + read_var)
    return noisy


def _star_sums(h: int, w: int, rc: np.ndarray, flux: np.ndarray, sigma_px: float, half: int, bg: float):
    """Flat indices of the pixels the stars touch (sorted) and ``bg + sum F_k Er Ec`` there.

    Each pixel's terms are added to ``bg`` one star after the other (:func:`numpy.add.at` in
    the stars' order), as a full-frame accumulation would add them.
    """
    if not rc.shape[0]:
        return np.zeros(0, dtype=np.intp), np.zeros(0)
    centre = np.floor(rc).astype(np.intp)
    offs = np.arange(-half, half + 1)
    rr = centre[:, 0:1] + offs
    cc = centre[:, 1:2] + offs
    s = np.full(rc.shape[0], sigma_px)
    er, _, _ = pixel_integrals(rr + 0.5, rc[:, 0], s)
    ec, _, _ = pixel_integrals(cc + 0.5, rc[:, 1], s)
    stamps = flux[:, None, None] * er[:, :, None] * ec[:, None, :]
    inside = ((rr >= 0) & (rr < h))[:, :, None] & ((cc >= 0) & (cc < w))[:, None, :]
    r_idx = np.broadcast_to(rr[:, :, None], stamps.shape)[inside]
    c_idx = np.broadcast_to(cc[:, None, :], stamps.shape)[inside]
    touched, where = np.unique(r_idx * w + c_idx, return_inverse=True)
    star = np.full(touched.size, bg)
    np.add.at(star, where, stamps[inside])
    return touched, star


def psf_sigma_dom_px(gsd_m: float, dom_resolution_m: float, psf_sigma_px: float) -> float:
    """Sigma (DOM pixels) of the Gaussian equivalent of one scene pixel's response.

    Variance in scene pixels: detector box ``1/12`` across track, box plus one line of motion
    ``2/12`` along track (averaged: ``1.5/12``), plus the optics ``psf_sigma_px^2``; the DOM's own
    pixel box (``1/12`` DOM px^2) is already in the data and is taken out.

    Parameters
    ----------
    gsd_m : float
        Ground sample distance of the scene, metres.
    dom_resolution_m : float
        Pixel size of the reference map image (DOM), metres.
    psf_sigma_px : float
        Standard deviation of the optics' Gaussian PSF, scene pixels.

    Returns
    -------
    float
        Standard deviation of the equivalent Gaussian blur, DOM pixels (0 when the DOM is
        already coarser than the scene's response).
    """
    ratio = gsd_m / dom_resolution_m
    var = ratio**2 * (1.5 / 12.0 + psf_sigma_px**2) - 1.0 / 12.0
    return float(np.sqrt(max(var, 0.0)))


def dn_uint16(image: np.ndarray, offset: float = 0.0) -> np.ndarray:
    """Digital numbers of a rendered frame: ``image + offset`` rounded and saturated to uint16.

    The values of ``np.clip(np.rint(image + offset), 0, 65535).astype(np.uint16)`` (rounding
    half to even, the sum formed in float64), computed in one pass by OpenCV's saturating
    conversion instead of four passes over the frame (0.6 against 2.3 ms on a 1024 x 1024
    frame).

    Parameters
    ----------
    image : ndarray of float64, shape (H, W)
        Rendered values, ADU.
    offset : float, optional
        Added before rounding (a background level), ADU.

    Returns
    -------
    ndarray of uint16, shape (H, W)
    """
    import cv2

    image = np.ascontiguousarray(image, dtype=np.float64)
    return cv2.add(image, float(offset), dtype=cv2.CV_16U)
