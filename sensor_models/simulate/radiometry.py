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
    n_rows, n_cols = int(shape[0]), int(shape[1])
    n_half = n_cols // 2 + 1
    # the 2-D transforms of ``irfft2(rfft2(noise) * filt)`` one axis at a time, by strips of rows
    # and of columns of one half spectrum (``rfft2`` is ``rfft`` along the rows then ``fft``
    # along the columns; the noise is drawn in the same order): the same numbers without the
    # whole noise, product and inverse arrays beside the spectrum
    spec = np.empty((n_rows, n_half), dtype=np.complex128)
    rows_step = max(1, _FFT_STRIP_VALUES // n_cols)
    for r0 in range(0, n_rows, rows_step):
        r1 = min(r0 + rows_step, n_rows)
        spec[r0:r1] = np.fft.rfft(rng.standard_normal((r1 - r0, n_cols)), axis=1)
    ky = np.fft.fftfreq(n_rows)[:, None]
    kx = np.fft.rfftfreq(n_cols)
    cols_step = max(1, _FFT_STRIP_VALUES // n_rows)
    for c0 in range(0, n_half, cols_step):
        cols = slice(c0, min(c0 + cols_step, n_half))
        k = np.hypot(ky, kx[None, cols]) * 2.0 * np.pi
        filt = np.exp(-0.5 * (k * scale_px) ** 2) + 0.15 / (1.0 + (k * scale_px) ** 2)
        spec[:, cols] = np.fft.ifft(np.fft.fft(spec[:, cols], axis=0) * filt, axis=0)
    # the field's rows written over the spectrum's bytes: row r ends before spectrum row r + 1 starts
    flat = spec.reshape(-1).view(np.float64)
    for r0 in range(0, n_rows, rows_step):
        r1 = min(r0 + rows_step, n_rows)
        flat[r0 * n_cols:r1 * n_cols] = np.fft.irfft(spec[r0:r1], n=n_cols, axis=1).ravel()
    field = flat[:n_rows * n_cols].reshape(n_rows, n_cols)
    field -= field.mean()
    field /= max(field.std(), 1e-12)
    return field.astype(np.float32)


#: complex values of the half spectrum :func:`smooth_field` transforms at a time
_FFT_STRIP_VALUES = 1 << 20


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
