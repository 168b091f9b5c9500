"""The radiometry of a simulated scene.

(Map images and their resampling live in :mod:`sensor_models.maps.raster`, the pixel response in
:mod:`sensor_models.imaging.psf`.)

* :func:`smooth_field`: seeded band-limited random fields (seasonal change, clouds) on a coarse
  grid.
* :func:`to_dn`: band response, seasonal change, PRNU, signal-dependent noise, quantization.
"""

from __future__ import annotations

import numpy as np

__all__ = ["smooth_field", "to_dn"]


def smooth_field(shape, scale_px: float, seed_seq) -> np.ndarray:
    """A zero-mean, unit-variance Gaussian random field with correlation length ``scale_px``.

    White noise filtered in the Fourier domain by ``exp(-(k scale)^2 / 2)`` plus a weaker
    ``1/k``-like tail for detail; float32, deterministic for the given seed sequence.

    Parameters
    ----------
    shape : (int, int)
        Field size (rows, cols), in field pixels.
    scale_px : float
        Correlation length, field pixels.
    seed_seq : numpy.random.SeedSequence or int
        Seed of the white noise.

    Returns
    -------
    ndarray of float32, shape ``shape``
        Zero mean, unit standard deviation.
    """
    rng = np.random.default_rng(seed_seq)
    noise = rng.standard_normal(shape)
    ky = np.fft.fftfreq(shape[0])[:, None]
    kx = np.fft.rfftfreq(shape[1])[None, :]
    k = np.hypot(ky, kx) * 2.0 * np.pi
    filt = np.exp(-0.5 * (k * scale_px) ** 2) + 0.15 / (1.0 + (k * scale_px) ** 2)
    field = np.fft.irfft2(np.fft.rfft2(noise) * filt, s=shape)
    field -= field.mean()
    field /= max(field.std(), 1e-12)
    return field.astype(np.float32)


def to_dn(reflectance, *, gain: float, offset_dn: float, gamma: float, seasonal, prnu_gain, snr: float,
          bits: int, rng: np.random.Generator) -> np.ndarray:
    """Digital numbers of a band from the DOM-normalized reflectance (0..1).

    ``L = offset + gain * max_dn * 0.8 * reflectance^gamma * (1 + seasonal)`` times the
    per-detector gain (PRNU), plus Gaussian noise of standard deviation
    ``sigma = (S_ref / snr) sqrt(0.5 + 0.5 L / S_ref)`` (read noise plus shot noise, SNR = ``snr``
    at the reference signal ``S_ref = 0.35 max_dn``), rounded and clipped to ``bits`` bits.
    NaN reflectance (no reference data) gives 0.

    Parameters
    ----------
    reflectance : ndarray of float32
        DOM-normalized reflectance, 0..1 (NaN: no reference data).
    gain, offset_dn, gamma : float
        Band response: relative gain, dark offset (DN) and gamma.
    seasonal : ndarray or float
        Relative seasonal change, broadcast against ``reflectance``.
    prnu_gain : ndarray or float
        Per-detector gain (photo-response non-uniformity), broadcast against ``reflectance``.
    snr : float
        Signal-to-noise ratio at the reference signal ``0.35 max_dn``.
    bits : int
        Significant bits of the digital numbers.
    rng : numpy.random.Generator
        Noise generator.

    Returns
    -------
    ndarray of uint16, shape of ``reflectance``
        Digital numbers in ``0 .. 2**bits - 1``.
    """
    max_dn = float(2**bits - 1)
    refl = np.clip(reflectance, 0.0, None)
    signal = offset_dn + gain * 0.8 * max_dn * np.power(refl, gamma) * (1.0 + seasonal)
    signal = signal * prnu_gain
    s_ref = 0.35 * max_dn
    sigma = (s_ref / snr) * np.sqrt(0.5 + 0.5 * np.clip(signal, 0.0, None) / s_ref)
    dn = signal + sigma * rng.standard_normal(signal.shape, dtype=np.float32)
    dn = np.where(np.isfinite(dn), dn, 0.0)
    return np.clip(np.rint(dn), 0, max_dn).astype(np.uint16)
