"""Broadband attitude jitter of the TRUE attitude (``realistic`` profile).

The ``ideal`` profile (and the configuration's ``errors.jitter_*``) keeps one sinusoid per axis.
Real platforms show a spectrum: a few lines (reaction wheels, solar-array drives, thermal
snapping) over a coloured floor. :class:`JitterSpectrum` adds, on top of the configuration's
dominant line (``errors.jitter_amplitude_urad`` at ``errors.jitter_frequency_hz``, which stays as
it was):

* a second, weaker line per axis (``line2_amplitude_urad`` at ``line2_frequency_hz``; ZY-3 shows
  attitude oscillation near 0.6-0.7 Hz, Tong et al. 2015), random phase;
* a coloured-noise floor with a power spectral density ``S(f) ~ 1 / f^exponent`` between
  ``band_hz[0]`` and ``band_hz[1]`` and zero elsewhere, scaled to ``floor_rms_urad`` per axis over
  the sampled span (:func:`coloured_noise`).

Both are drawn from the pass seed (another pass, another phase and floor), never from the camera
seed. The LAB (measured) attitude knows none of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["JitterSpectrum", "coloured_noise", "jitter_angles", "jitter_spectrum"]


@dataclass(frozen=True)
class JitterSpectrum:
    """The jitter added to the configuration's dominant sinusoid (magnitudes per axis: roll, pitch, yaw).

    Attributes
    ----------
    line2_amplitude_urad : (float, float, float)
        Amplitude of the second line, microradians.
    line2_frequency_hz : float
        Its frequency, Hz.
    floor_rms_urad : (float, float, float)
        Standard deviation of the coloured floor, microradians.
    floor_exponent : float
        ``a`` in ``S(f) ~ 1 / f^a`` (1: pink).
    band_hz : (float, float)
        Frequencies between which the floor has power, Hz.
    """

    line2_amplitude_urad: tuple = (0.0, 0.0, 0.0)
    line2_frequency_hz: float = 0.65
    floor_rms_urad: tuple = (0.0, 0.0, 0.0)
    floor_exponent: float = 1.0
    band_hz: tuple = (0.05, 5.0)

    @property
    def is_zero(self) -> bool:
        """True when it adds nothing (the historical single sinusoid)."""
        return not (np.any(np.asarray(self.line2_amplitude_urad)) or np.any(np.asarray(self.floor_rms_urad)))


def jitter_spectrum(profile) -> JitterSpectrum | None:
    """The :class:`JitterSpectrum` of a push-broom profile (None when it adds nothing).

    Parameters
    ----------
    profile : PushbroomProfile
        ``jitter_line2_*`` and ``jitter_floor_*`` fields.

    Returns
    -------
    JitterSpectrum or None
    """
    v = profile.value
    spec = JitterSpectrum(line2_amplitude_urad=tuple(map(float, v("jitter_line2_amplitude_urad"))),
                          line2_frequency_hz=float(v("jitter_line2_frequency_hz")),
                          floor_rms_urad=tuple(map(float, v("jitter_floor_rms_urad"))),
                          floor_exponent=float(v("jitter_floor_exponent")),
                          band_hz=tuple(map(float, v("jitter_floor_band_hz"))))
    return None if spec.is_zero else spec


def coloured_noise(n: int, dt_s: float, *, exponent: float, band_hz, rms: float, rng: np.random.Generator):
    """A seeded series whose power spectral density is ``~ 1 / f^exponent`` inside ``band_hz``.

    White Gaussian noise is filtered in the Fourier domain by ``f^(-exponent / 2)`` inside the
    band and 0 outside, then scaled to the requested standard deviation.

    Parameters
    ----------
    n : int
        Samples.
    dt_s : float
        Sampling interval, s.
    exponent : float
        Spectral slope ``a``.
    band_hz : (float, float)
        Lowest and highest frequency with power, Hz.
    rms : float
        Standard deviation of the result (any unit).
    rng : numpy.random.Generator
        Noise source.

    Returns
    -------
    ndarray of float64, shape (n,)
        Zero mean, standard deviation ``rms`` (0 when ``rms`` is 0 or the band holds no bin).
    """
    white = rng.standard_normal(n)
    f = np.fft.rfftfreq(n, dt_s)
    inside = (f >= band_hz[0]) & (f <= band_hz[1])
    gain = np.zeros_like(f)
    gain[inside] = f[inside] ** (-0.5 * exponent)
    x = np.fft.irfft(np.fft.rfft(white) * gain, n)
    x -= x.mean()
    sd = x.std()
    return x * (rms / sd) if sd > 0 and rms > 0 else np.zeros(n)


def jitter_angles(spectrum: JitterSpectrum, seconds, seed: int):
    """Roll, pitch, yaw added to the TRUE attitude by ``spectrum`` at ``seconds`` (uniform samples).

    Parameters
    ----------
    spectrum : JitterSpectrum
        The added jitter.
    seconds : ndarray, shape (N,)
        Uniformly spaced sample times, s.
    seed : int
        Pass seed.

    Returns
    -------
    angles_rad : ndarray, shape (N, 3)
        Roll, pitch, yaw, radians.
    record : dict
        JSON-safe description for ``truth.json`` (lines with phases, floor with its realized rms).
    """
    t = np.asarray(seconds, dtype=np.float64)
    ss = np.random.SeedSequence([int(seed), 50])
    phase_rng, floor_seq = np.random.default_rng(ss.spawn(1)[0]), ss.spawn(1)[0]
    phase = phase_rng.uniform(0.0, 2.0 * np.pi, 3)
    amp = np.asarray(spectrum.line2_amplitude_urad, np.float64) * 1e-6
    angles = amp[None, :] * np.sin(2.0 * np.pi * spectrum.line2_frequency_hz * t[:, None] + phase[None, :])
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    floor_rng = np.random.default_rng(floor_seq)
    floor = np.stack([coloured_noise(t.size, dt, exponent=spectrum.floor_exponent, band_hz=spectrum.band_hz,
                                     rms=r * 1e-6, rng=floor_rng) for r in spectrum.floor_rms_urad], axis=1)
    record = {"axes": ["roll", "pitch", "yaw"],
              "line2": {"amplitude_urad": list(spectrum.line2_amplitude_urad),
                        "frequency_hz": spectrum.line2_frequency_hz, "phase_rad": phase.tolist()},
              "floor": {"psd": f"1/f^{spectrum.floor_exponent:g}", "band_hz": list(spectrum.band_hz),
                        "rms_urad": list(spectrum.floor_rms_urad),
                        "realized_rms_urad": (floor.std(axis=0) * 1e6).round(4).tolist()}}
    return angles + floor, record
