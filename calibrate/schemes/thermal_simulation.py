"""The test bed of the thermal study: a drifting installation and its per-epoch exterior (seed 002).

:class:`ThermalDrift` is the truth of a simulation: two daily harmonics, a trend, random
epoch-to-epoch noise and a lagged-sinusoid telemetry temperature, injected into the
installation of a TRUE model. :func:`simulate_thermal_series` projects virtual control points
(seed 002 section 2.3: grid pixels of the true model projected to the ground) with image noise
at every epoch and fits the LAB model's exterior (:func:`calibrate.schemes.thermal.fit_installation`),
giving a :class:`ThermalSeries`. Only the installation changes between epochs; the orbit,
attitude and interior are those of the model given (a geostationary staring frame barely
changes geometry over a day, and the thermal effect is what is studied).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibrate.schemes.thermal import (
    ARCSEC,
    DAY_S,
    INSTALLATION_NAMES,
    as_seconds,
    check_increasing,
    fit_installation,
    with_installation,
)
from sensor_models.errors import InputError

__all__ = ["ThermalDrift", "ThermalSeries", "simulate_thermal_series"]


@dataclass(frozen=True)
class ThermalDrift:
    """A daily thermal drift of the installation angles (the truth of a simulation).

    ``theta_i(t) = offset_i + trend_i tau + sum_k A_ik cos(k omega t - phi_ik) + n_i(t)``
    with ``tau = t / P`` days from ``t = 0``, ``omega = 2 pi / P`` and ``n_i`` white noise of
    standard deviation ``noise_arcsec`` (epoch to epoch, unpredictable). The telemetry
    temperature is ``T(t) = T0 + dT cos(omega (t - lag) - phi_roll,1) + noise``: the first
    harmonic of the roll seen ``temperature_lag_s`` later (the bracket lags behind the
    thermistor or the other way round).

    Attributes (angles in arcseconds, times in seconds, temperatures in degrees Celsius)
    ----------
    offset_arcsec : (3,)  static installation error (seed 002 table 2: 72, -72, 72)
    amplitude_arcsec : (3, K)  harmonic amplitudes per angle
    phase_rad : (3, K)
    trend_arcsec_per_day : (3,)
    noise_arcsec : float
    temperature_c, temperature_amplitude_c, temperature_lag_s, temperature_noise_c : float
    period_s : float
    """

    offset_arcsec: tuple = (72.0, -72.0, 72.0)
    amplitude_arcsec: tuple = ((30.0, 8.0), (25.0, 6.0), (40.0, 10.0))
    phase_rad: tuple = ((0.8, 2.0), (2.4, -1.0), (-1.3, 0.5))
    trend_arcsec_per_day: tuple = (2.0, -1.5, 3.0)
    noise_arcsec: float = 0.3
    temperature_c: float = 15.0
    temperature_amplitude_c: float = 12.0
    temperature_lag_s: float = 5400.0
    temperature_noise_c: float = 0.1
    period_s: float = DAY_S

    def smooth_angles(self, times_s) -> np.ndarray:
        """The deterministic part of the angles, radians, shape (N, 3).

        Parameters
        ----------
        times_s : array_like, shape (N,)
            Epochs, seconds.

        Returns
        -------
        ndarray, shape (N, 3)
            Roll, pitch, yaw, radians.
        """
        t = as_seconds(times_s)
        amp = np.asarray(self.amplitude_arcsec, dtype=np.float64).reshape(3, -1)
        phase = np.asarray(self.phase_rad, dtype=np.float64).reshape(3, -1)
        k = np.arange(1, amp.shape[1] + 1)
        omega_t = 2.0 * np.pi * t / self.period_s
        harm = np.einsum("ik,nik->ni", amp, np.cos(omega_t[:, None, None] * k[None, None, :] - phase[None]))
        trend = np.outer(t / self.period_s, np.asarray(self.trend_arcsec_per_day, dtype=np.float64))
        return (np.asarray(self.offset_arcsec, dtype=np.float64) + trend + harm) * ARCSEC

    def temperature(self, times_s, rng=None) -> np.ndarray:
        """Telemetry temperature, degrees Celsius, shape (N,) (noisy when ``rng`` is given).

        Parameters
        ----------
        times_s : array_like, shape (N,)
            Epochs, seconds.
        rng : numpy.random.Generator, optional
            Adds Gaussian noise of ``temperature_noise_c``.

        Returns
        -------
        ndarray, shape (N,)
            Degrees Celsius.
        """
        t = as_seconds(times_s)
        phase = float(np.asarray(self.phase_rad, dtype=np.float64).reshape(3, -1)[0, 0])
        temp = self.temperature_c + self.temperature_amplitude_c * np.cos(
            2.0 * np.pi * (t - self.temperature_lag_s) / self.period_s - phase)
        if rng is not None and self.temperature_noise_c > 0:
            temp = temp + rng.normal(0.0, self.temperature_noise_c, t.size)
        return temp


@dataclass
class ThermalSeries:
    """A simulated series of epochs (:func:`simulate_thermal_series`).

    Attributes
    ----------
    times_s : ndarray, shape (N,)
    true_angles, smooth_angles : ndarray, shape (N, 3)
        Installation angles of the TRUE model (with the epoch noise) and their deterministic
        part, radians.
    angles, sigma : ndarray, shape (N, 3)
        Per-epoch exterior solutions and standard deviations, radians.
    temperatures : ndarray, shape (N,)
    rms_px : ndarray, shape (N,)
        Control-point residual RMS after each epoch's fit.
    success : ndarray of bool, shape (N,)
    n_points : int
    sigma_px : float
    """

    times_s: np.ndarray
    true_angles: np.ndarray
    smooth_angles: np.ndarray
    angles: np.ndarray
    sigma: np.ndarray
    temperatures: np.ndarray
    rms_px: np.ndarray
    success: np.ndarray
    n_points: int
    sigma_px: float

    def recovery_arcsec(self) -> np.ndarray:
        """RMS of ``angles - true_angles`` per angle, arcsec, shape (3,).

        Returns
        -------
        ndarray, shape (3,)
            Arcseconds.
        """
        return np.sqrt(np.mean((self.angles - self.true_angles) ** 2, axis=0)) / ARCSEC


def simulate_thermal_series(lab, times_s, drift: ThermalDrift = ThermalDrift(), *, n_points: int = 400,
                            sigma_px: float = 0.1, height_m: float = 0.0, seed: int = 0,
                            solver: str = "direct", truth_offsets_rad=None) -> ThermalSeries:
    """Per-epoch exterior solutions of a staring camera whose installation drifts thermally.

    At each epoch the TRUE model is ``lab`` with installation ``drift`` (+ epoch noise);
    ``n_points`` pixels drawn uniformly over the frame are projected to the ground at
    ``height_m`` through it (virtual control points, seed 002 section 2.3), their image
    coordinates get Gaussian noise of ``sigma_px``, and the exterior of ``lab`` is fitted.

    Parameters
    ----------
    lab : GeoStaringModel
        The model a user has (its installation is the starting point of every fit).
    times_s : array_like, shape (N,)
        Epochs, seconds (``t = 0`` is midnight of the first day for the drift's harmonics).
    solver : {"direct", "calibrate_model"}
        :func:`fit_installation` or ``calibrate.absolute.calibrate_model(scheme="exterior")``.
    truth_offsets_rad : array_like, shape (N, 3), optional
        Added to the TRUE installation at each epoch and to no model of it: e.g. the
        day-to-day variation of :mod:`sensor_models.simulate.thermal_truth`. Default: none.

    Returns
    -------
    ThermalSeries
        True, smooth and estimated angles (rad), their sigmas, temperatures, fit RMS (px) and
        success per epoch.
    """
    t = as_seconds(times_s)
    check_increasing(t)
    if solver not in ("direct", "calibrate_model"):
        raise InputError(f"must be 'direct' or 'calibrate_model', got {solver!r}", field="solver")
    if n_points < 3:
        raise InputError(f"needs at least 3 control points, got {n_points}", field="n_points")
    rng = np.random.default_rng(seed)
    smooth = drift.smooth_angles(t)
    true = smooth + rng.normal(0.0, drift.noise_arcsec * ARCSEC, smooth.shape)
    if truth_offsets_rad is not None:
        offsets = np.asarray(truth_offsets_rad, dtype=np.float64)
        if offsets.shape != true.shape or not np.all(np.isfinite(offsets)):
            raise InputError(f"must be finite with shape {true.shape}", field="truth_offsets_rad")
        true = true + offsets
    temps = drift.temperature(t, rng)
    n_rows, n_cols = lab.image_shape
    est = np.full((t.size, 3), np.nan)
    sig = np.full((t.size, 3), np.nan)
    rms = np.full(t.size, np.nan)
    ok = np.zeros(t.size, dtype=bool)
    for i in range(t.size):  # one exterior solve per epoch (vectorized over the points)
        truth = with_installation(lab, true[i])
        r = rng.uniform(0.0, n_rows, n_points)
        c = rng.uniform(0.0, n_cols, n_points)
        lon, lat, h = truth.image_to_ground(r, c, height=height_m)
        r_obs = r + rng.normal(0.0, sigma_px, n_points)
        c_obs = c + rng.normal(0.0, sigma_px, n_points)
        if solver == "direct":
            fit = fit_installation(lab, r_obs, c_obs, lon, lat, h, sigma_px=sigma_px)
            est[i], sig[i], rms[i], ok[i] = fit.angles, fit.sigma, fit.rms_px, fit.success
        else:
            from calibrate.absolute import calibrate_model
            from calibrate.config import CalibrationOptions
            from gcpmatch.gcps import GcpTable

            table = GcpTable.from_arrays(r_obs, c_obs, lon, lat, h, sigma_px=sigma_px)
            res = calibrate_model(lab, table, options=CalibrationOptions(scheme="exterior"))
            pos = [list(res.names).index(n) for n in INSTALLATION_NAMES]
            est[i], sig[i] = res.values[pos], res.sigma[pos]
            rms[i], ok[i] = res.statistics("after").get("rms_px", np.nan), res.success
    return ThermalSeries(t, true, smooth, est, sig, temps, rms, ok, int(n_points), float(sigma_px))
