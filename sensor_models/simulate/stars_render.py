"""Rendering of point sources (stars, point-like targets) with a pixel-integrated Gaussian PSF.

Shared by the star-field simulator (:mod:`sensor_models.simulate.geo_stars`) and the tests
and benchmarks of star detection (:mod:`gcpmatch.stars`, which re-exports both names).
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

__all__ = ["pixel_integrals", "render_stars"]

_SQRT2 = np.sqrt(2.0)


def pixel_integrals(centres, mu, sigma):
    """Integral of a unit 1-D Gaussian over unit pixels and its derivatives.

    ``E_i = (erf(b_i) - erf(a_i)) / 2`` with ``a, b = (x_i -+ 1/2 - mu) / (sqrt(2) sigma)``;
    ``dE/dmu = (exp(-a^2) - exp(-b^2)) / (sqrt(2 pi) sigma)`` and
    ``dE/dsigma = (a exp(-a^2) - b exp(-b^2)) / (sqrt(pi) sigma)``. Shapes (N, w).
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
                 half_width_px: int | None = None) -> np.ndarray:
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

    Returns
    -------
    ndarray of float64, shape ``shape``
        ``background + sum F_k Er Ec`` plus Gaussian noise of variance
        ``max(signal, 0) / gain + (read_noise / gain)^2`` when ``rng`` is given.
    """
    h, w = int(shape[0]), int(shape[1])
    rc = np.asarray(rowcol, dtype=np.float64).reshape(-1, 2)
    flux = np.broadcast_to(np.asarray(flux, dtype=np.float64), (rc.shape[0],))
    half = int(np.ceil(5.0 * sigma_px)) if half_width_px is None else int(half_width_px)
    image = np.full((h, w), float(background))
    if rc.shape[0]:
        centre = np.floor(rc).astype(np.intp)
        offs = np.arange(-half, half + 1)
        rr = centre[:, 0:1] + offs
        cc = centre[:, 1:2] + offs
        s = np.full(rc.shape[0], float(sigma_px))
        er, _, _ = pixel_integrals(rr + 0.5, rc[:, 0], s)
        ec, _, _ = pixel_integrals(cc + 0.5, rc[:, 1], s)
        stamps = flux[:, None, None] * er[:, :, None] * ec[:, None, :]
        inside = ((rr >= 0) & (rr < h))[:, :, None] & ((cc >= 0) & (cc < w))[:, None, :]
        r_idx = np.broadcast_to(rr[:, :, None], stamps.shape)[inside]
        c_idx = np.broadcast_to(cc[:, None, :], stamps.shape)[inside]
        np.add.at(image, (r_idx, c_idx), stamps[inside])
    if rng is not None:
        var = np.maximum(image, 0.0) / gain_e_per_adu + (read_noise_e / gain_e_per_adu) ** 2
        image = image + rng.standard_normal((h, w)) * np.sqrt(var)
    return image
