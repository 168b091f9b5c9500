r"""Temperature- and time-driven installation angles of a geostationary staring camera.

Seed 002 section 3.3 (figure 11): a geostationary camera's relative installation angles
``(alpha, beta, theta)`` (here ``installation.roll, pitch, yaw``) move with the temperature of
the bracket, which follows the Sun with a daily period (seed 000 section 4: "periodic, with a
cycle of one day approximately"; seed 002 introduction: annual and diurnal periodicities). The
seed calibrates the exterior at many epochs, builds the curve of the installation angles
against time and compensates the exterior with it. This module does the same in three steps:

1. **Per-epoch exterior** (:func:`fit_installation`): the three installation angles from
   control points by Gauss-Newton on the image residuals with the model's analytic Jacobian
   ``d(row, col)/d(roll, pitch, yaw)``, with their covariance ``sigma_px^2 (J^T J)^{-1}``
   (the same estimate as ``calibrate_model(model, ..., scheme="exterior")`` of
   :mod:`calibrate.absolute`, without its robust weighting, at a fraction of its cost).
2. **A model of the angles against time** (:class:`ThermalModel`): per angle, weighted least
   squares on

   .. math::

       \theta(t) = c_0 + \sum_{d=1}^{D} c_d\,\tau^d
                 + \sum_{k=1}^{K} \left(a_k \cos k\omega t + b_k \sin k\omega t\right)
                 + \sum_m g_m\,(T_m(t) - \bar T_m),
       \qquad \omega = 2\pi / P,\; \tau = (t - t_{ref}) / P

   (``P`` = one day by default, ``t`` in seconds, so with UTC times the harmonics are of
   the UTC time of day; ``T_m`` optional temperature telemetry). The harmonic order ``K`` is
   chosen per angle by cross-validation: leave one day out when the series spans at least
   three days, otherwise interleaved k-fold. With temperatures, CV also decides whether
   they enter the model.
3. **Compensation** (:func:`evaluate_positioning`): at unseen epochs the predicted angles are
   put into the model (``model.with_parameters``) and the positioning error over the frame,
   in pixels, is compared with that of a constant installation (the mean of the per-epoch
   solutions).

:func:`simulate_thermal_series` builds the test bed: a :class:`ThermalDrift` (two daily
harmonics, a trend, random epoch-to-epoch noise, a lagged-sinusoid temperature) injected into
the installation of a TRUE model, virtual control points (seed 002 section 2.3: grid pixels of
the true model projected to the ground) with image noise, and the per-epoch exterior of the
LAB model. Only the installation changes between epochs; the orbit, attitude and interior
are those of the model given (a geostationary staring frame barely changes geometry over a
day, and the thermal effect is what is studied).

References
----------
.. [1] Seed 002: Xiao et al., image point positioning compensation of a high-orbit thermal
   infrared staring camera, Appl. Sci. 2023, 13, 9688: section 2.3 (virtual control points),
   section 3.3 and figure 11 (installation angles against time under temperature changes).
.. [2] Seed 000: on-orbit calibration of a geostationary camera from the relative motion of
   stars, Sensors 2021, section 4 (daily period of the thermal positioning error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sensor_models.errors import InputError

__all__ = [
    "ARCSEC",
    "DAY_S",
    "EpochFit",
    "ThermalDrift",
    "ThermalModel",
    "ThermalSeries",
    "evaluate_positioning",
    "fit_installation",
    "frame_grid",
    "plot_positioning",
    "plot_thermal_angles",
    "simulate_thermal_series",
    "with_installation",
]

#: one arcsecond in radians
ARCSEC = math.pi / 180.0 / 3600.0
#: one mean solar day, seconds
DAY_S = 86_400.0
_EXTERIOR = ("installation.roll", "installation.pitch", "installation.yaw")
_AXES = ("roll", "pitch", "yaw")


# --------------------------------------------------------------------------- helpers
def _as_seconds(times, field_name="times"):
    """Float seconds, shape (N,): float input as is, datetime64 as seconds since 1970-01-01 (UTC)."""
    arr = np.asarray(times)
    if np.issubdtype(arr.dtype, np.datetime64):
        sec = (arr - np.datetime64("1970-01-01T00:00:00", "ns")) / np.timedelta64(1, "ns") * 1e-9
        sec = np.asarray(sec, dtype=np.float64)
    else:
        try:
            sec = np.asarray(arr, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("must be numbers (seconds) or datetime64", field=field_name) from None
    sec = sec.reshape(-1)
    if not np.all(np.isfinite(sec)):
        raise InputError("holds NaN or infinite values", field=field_name)
    return sec


def _check_increasing(t, field_name="times"):
    if t.size > 1 and not np.all(np.diff(t) > 0.0):
        k = int(np.argmin(np.diff(t)))
        raise InputError(f"must be strictly increasing (entry {k + 1} is not after entry {k})", field=field_name)


def _as_angles(values, n, field_name):
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1 and n == 1 and arr.size == 3:
        arr = arr.reshape(1, 3)
    if arr.shape != (n, 3):
        raise InputError(f"must have shape ({n}, 3), got {arr.shape}", field=field_name)
    if not np.all(np.isfinite(arr)):
        bad = int(np.nonzero(~np.all(np.isfinite(arr), axis=1))[0][0])
        raise InputError(f"holds NaN or infinite values (epoch {bad})", field=field_name)
    return arr


def _as_temperatures(values, n, field_name="temperatures"):
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2 or arr.shape[0] != n:
        raise InputError(f"must have shape ({n},) or ({n}, M), got {np.shape(values)}", field=field_name)
    if not np.all(np.isfinite(arr)):
        raise InputError("holds NaN or infinite values", field=field_name)
    return arr


def _installation_positions(model):
    names = tuple(model.parameters().names)
    try:
        return [names.index(n) for n in _EXTERIOR]
    except ValueError:
        raise InputError("the model has no installation.roll/pitch/yaw parameters", field="model") from None


def with_installation(model, angles_rad):
    """A copy of ``model`` with installation angles ``(roll, pitch, yaw)`` (radians, shape (3,)).

    Parameters
    ----------
    model : GeoStaringModel
        Model to copy.
    angles_rad : array_like, shape (3,)
        Installation roll, pitch, yaw, radians.

    Returns
    -------
    GeoStaringModel
        The copy.
    """
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
    if angles.size != 3 or not np.all(np.isfinite(angles)):
        raise InputError("needs 3 finite angles (radians)", field="installation")
    values = np.array(model.parameters().values, dtype=np.float64)
    values[_installation_positions(model)] = angles
    return model.with_parameters(values)


def frame_grid(image_shape, n: int = 21, margin_px: float = 4.0):
    """Pixel grid over the frame, ``row, col`` each shape (n*n,), pixel centres convention.

    Parameters
    ----------
    image_shape : (int, int)
        Frame shape (rows, cols).
    n : int
        Points per axis.
    margin_px : float
        Distance of the outer points from the frame edges, pixels.

    Returns
    -------
    row, col : ndarray, shape (n * n,)
        Pixel coordinates.
    """
    n_rows, n_cols = image_shape
    r = np.linspace(margin_px, n_rows - margin_px, n)
    c = np.linspace(margin_px, n_cols - margin_px, n)
    gr, gc = np.meshgrid(r, c, indexing="ij")
    return gr.ravel(), gc.ravel()


# --------------------------------------------------------------------------- per-epoch exterior
@dataclass
class EpochFit:
    """Exterior solution of one epoch (:func:`fit_installation`).

    Attributes
    ----------
    angles, sigma : ndarray, shape (3,)
        Installation ``roll, pitch, yaw`` and their standard deviations, radians.
    covariance : ndarray, shape (3, 3)
    rms_px : float
        RMS of the image residuals after the fit (row and column together).
    n_points, iterations : int
    success : bool
    message : str
    """

    angles: np.ndarray
    sigma: np.ndarray
    covariance: np.ndarray
    rms_px: float
    n_points: int
    iterations: int
    success: bool
    message: str


def fit_installation(model, row, col, lon, lat, h, *, sigma_px: float = 0.1, max_iter: int = 10,
                     tol_rad: float = 1e-4 * ARCSEC) -> EpochFit:
    """Installation angles of a staring camera from control points (Gauss-Newton, 3 unknowns).

    Minimizes ``sum |(row, col)_obs - ground_to_image(model(theta), lon, lat, h)|^2`` over
    ``theta = (roll, pitch, yaw)``, starting from the model's angles; the normal equations
    use the analytic Jacobian of :meth:`GeoStaringModel.image_jacobian`. The covariance is
    ``sigma^2 (J^T J)^{-1}`` with ``sigma`` the larger of ``sigma_px`` and the a-posteriori
    residual standard deviation.

    Parameters
    ----------
    model : GeoStaringModel
        Initial model (e.g. the laboratory one, or the previous epoch's solution).
    row, col : array_like, shape (N,)
        Observed image coordinates, pixels (first pixel centre at 0.5).
    lon, lat, h : array_like, shape (N,)
        Control points, WGS84 degrees and metres.
    sigma_px : float
        Prior standard deviation of the image coordinates, pixels.

    Returns
    -------
    EpochFit
        ``success=False`` with a message when fewer than 3 points project or the system is
        singular (never raises for a failed estimation).
    """
    row = np.asarray(row, dtype=np.float64).reshape(-1)
    col = np.asarray(col, dtype=np.float64).reshape(-1)
    lon, lat, h = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (lon, lat, h))
    if not (row.size == col.size == lon.size == lat.size == h.size):
        raise InputError("row, col, lon, lat, h must have the same length", field="points")
    theta = np.array(model.parameters().values, dtype=np.float64)[_installation_positions(model)]
    nan3 = np.full(3, np.nan)
    current = model
    it = 0
    for it in range(1, max_iter + 1):
        r, c, jac = current.image_jacobian(lon, lat, h, names=_EXTERIOR)
        ok = np.isfinite(r) & np.isfinite(c)
        if ok.sum() < 3:
            return EpochFit(nan3, nan3, np.full((3, 3), np.nan), float("nan"), int(ok.sum()), it, False,
                            f"only {int(ok.sum())} control points project into the image")
        res = np.concatenate([row[ok] - r[ok], col[ok] - c[ok]])
        a = np.concatenate([jac[ok, 0, :], jac[ok, 1, :]])
        try:
            step, *_ = np.linalg.lstsq(a, res, rcond=None)
            normal_inv = np.linalg.inv(a.T @ a)
        except np.linalg.LinAlgError:
            return EpochFit(nan3, nan3, np.full((3, 3), np.nan), float("nan"), int(ok.sum()), it, False,
                            "singular normal equations")
        theta = theta + step
        current = with_installation(model, theta)
        if np.max(np.abs(step)) < tol_rad:
            break
    r, c = current.ground_to_image(lon, lat, h)
    ok = np.isfinite(r) & np.isfinite(c)
    res = np.concatenate([row[ok] - r[ok], col[ok] - c[ok]])
    dof = max(res.size - 3, 1)
    s0 = math.sqrt(float(res @ res) / dof)
    cov = max(s0, float(sigma_px)) ** 2 * normal_inv
    converged = np.max(np.abs(step)) < tol_rad or it < max_iter
    return EpochFit(theta, np.sqrt(np.diag(cov)), cov, float(np.sqrt(np.mean(res * res) * 2.0)), int(ok.sum()), it,
                    bool(converged), "converged" if converged else f"not converged in {max_iter} iterations")


# --------------------------------------------------------------------------- simulation
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
        t = _as_seconds(times_s)
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
        t = _as_seconds(times_s)
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
    t = _as_seconds(times_s)
    _check_increasing(t)
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
            pos = [list(res.names).index(n) for n in _EXTERIOR]
            est[i], sig[i] = res.values[pos], res.sigma[pos]
            rms[i], ok[i] = res.statistics("after").get("rms_px", np.nan), res.success
    return ThermalSeries(t, true, smooth, est, sig, temps, rms, ok, int(n_points), float(sigma_px))


# --------------------------------------------------------------------------- time model
def _design(t, t_ref, period_s, order, trend_degree, temps, temp_mean, temp_scale):
    """Columns ``1, tau..tau^D, cos/sin(k omega t) k<=order, (T - mean)/scale``, shape (N, P)."""
    tau = (t - t_ref) / period_s
    cols = [np.ones_like(t)] + [tau ** d for d in range(1, trend_degree + 1)]
    wt = 2.0 * np.pi * np.mod(t, period_s) / period_s  # mod keeps the phase exact for large t
    for k in range(1, order + 1):
        cols += [np.cos(k * wt), np.sin(k * wt)]
    if temps is not None:
        cols += list(((temps - temp_mean) / temp_scale).T)
    return np.stack(cols, axis=1)

def _check_fit_options(n: int, max_order: int, trend_degree: int, period_s: float, n_temp: int) -> None:
    """InputError for negative orders, a non-positive period or too few epochs for ``max_order``."""
    if max_order < 0 or trend_degree < 0:
        raise InputError("max_order and trend_degree must be >= 0", field="max_order")
    if not (np.isfinite(period_s) and period_s > 0):
        raise InputError("must be positive", field="period_s")
    needed = _n_params(max_order, trend_degree, n_temp) + 2
    if n < needed:
        raise InputError(f"{n} epochs are too few for harmonic order {max_order} "
                         f"(needs at least {needed}); lower max_order or add epochs", field="times")


def _n_params(order, trend_degree, n_temp):
    return 1 + trend_degree + 2 * order + n_temp


def _wls(a, y, w):
    """Weighted least squares: coefficients (P,) and unscaled covariance (P, P)."""
    sw = np.sqrt(w)
    aw = a * sw[:, None]
    coef, *_ = np.linalg.lstsq(aw, y * sw, rcond=None)
    cov = np.linalg.pinv(aw.T @ aw)
    return coef, cov


def _folds(t, period_s, k_fold):
    """Leave-one-day-out folds (>= 3 days) or interleaved k-fold; list of test masks."""
    day = np.floor((t - t[0]) / period_s).astype(int)
    days = np.unique(day)
    if days.size >= 3:
        return [day == d for d in days], "leave-one-day-out"
    idx = np.arange(t.size)
    return [idx % k_fold == j for j in range(k_fold)], f"{k_fold}-fold interleaved"


def _checked_series(times, angles, sigmas, temperatures):
    """Epochs (s), angles and sigmas (N, 3) and temperatures (N, M) or None, validated."""
    t = _as_seconds(times)
    _check_increasing(t)
    n = t.size
    y = _as_angles(angles, n, "angles")
    if sigmas is None:
        s = np.ones((n, 3))
    else:
        s = _as_angles(sigmas, n, "sigmas")
        if not np.all(s > 0):
            raise InputError("must be positive", field="sigmas")
    temps = None if temperatures is None else _as_temperatures(temperatures, n)
    return t, y, s, temps


def _cv_scores(design, y, w_all, folds, variants, max_order):
    """Cross-validated weighted RMS (arcsec), shape (variants, max_order + 1, 3); inf if infeasible."""
    scores = np.full((len(variants), max_order + 1, 3), np.inf)
    for vi, use_t in enumerate(variants):
        for order in range(max_order + 1):
            a = design(order, use_t)
            sse = np.zeros(3)
            wsum = np.zeros(3)
            feasible = True
            for test in folds:
                train = ~test
                if train.sum() < a.shape[1] + 1 or not test.any():
                    feasible = False
                    break
                for j in range(3):
                    coef, _ = _wls(a[train], y[train, j], w_all[train, j])
                    r = y[test, j] - a[test] @ coef
                    sse[j] += np.sum(w_all[test, j] * r * r)
                    wsum[j] += np.sum(w_all[test, j])
            if feasible:
                scores[vi, order] = np.sqrt(sse / wsum) / ARCSEC
    return scores


def _chosen_order(scores_axis, variants, max_order, trend_degree, n_temp, tie_tolerance):
    """``(order, variant)``: the simplest candidate whose CV score is within the tolerance of the best."""
    best = np.min(scores_axis)
    if not np.isfinite(best):
        raise InputError("no harmonic order could be cross-validated: too few epochs per fold", field="times")
    # fewest parameters first
    cands = sorted((_n_params(o, trend_degree, n_temp if variants[v] else 0), o, v)
                   for v in range(len(variants)) for o in range(max_order + 1)
                   if scores_axis[v, o] <= best * (1.0 + tie_tolerance))
    _, o, v = cands[0]
    return o, v


@dataclass
class ThermalModel:
    """Installation angles against time of day (harmonics + trend [+ temperature]).

    Build with :meth:`fit`. Attributes: ``orders`` (3,) harmonic order per angle,
    ``use_temperature`` (3,) bool, ``coefficients`` (list of 3 arrays),
    ``covariances`` (list of 3), ``cv_scores_arcsec`` (C, max_order + 1, 3) with C = 1 (time
    only) or 2 (time, time + temperature), ``cv_scheme``, ``t_ref_s``, ``period_s``,
    ``trend_degree``, ``residual_rms_arcsec`` (3,), ``sigma0`` (3,) a-posteriori unit weight
    standard deviations.
    """

    orders: np.ndarray
    use_temperature: np.ndarray
    coefficients: list
    covariances: list
    cv_scores_arcsec: np.ndarray
    cv_scheme: str
    t_ref_s: float
    period_s: float
    trend_degree: int
    temp_mean: np.ndarray | None
    temp_scale: np.ndarray | None
    residual_rms_arcsec: np.ndarray
    sigma0: np.ndarray
    n_epochs: int
    max_order: int
    notes: list = field(default_factory=list)

    @classmethod
    def fit(cls, times, angles, sigmas=None, temperatures=None, *, max_order: int = 4, trend_degree: int = 1,
            period_s: float = DAY_S, k_fold: int = 5, tie_tolerance: float = 0.01) -> "ThermalModel":
        """Fit the angles of many epochs and choose the harmonic order by cross-validation.

        Parameters
        ----------
        times : array_like, shape (N,)
            Strictly increasing epochs: float seconds or datetime64 (then seconds since
            1970-01-01 UTC, so the harmonics are of the UTC time of day).
        angles : array_like, shape (N, 3)
            Installation ``roll, pitch, yaw`` per epoch, radians.
        sigmas : array_like, shape (N, 3), optional
            Their standard deviations, radians (weights ``1 / sigma^2``; default equal).
        temperatures : array_like, shape (N,) or (N, M), optional
            Telemetry; each series enters as a linear regressor when CV prefers it.
        max_order : int
            Largest harmonic order tried (0 .. max_order).
        trend_degree : int
            Degree of the polynomial trend in days (0: none, 1: linear).
        period_s : float
            Period of the fundamental harmonic, seconds (default: one day).
        k_fold : int
            Folds when the series spans fewer than three days.
        tie_tolerance : float
            The lowest order whose CV score is within this fraction of the best is chosen.

        Returns
        -------
        ThermalModel
            Chosen orders and temperature use per angle, coefficients, covariances and CV scores.

        Raises
        ------
        InputError
            Times not strictly increasing, NaN or mis-shaped angles/sigmas/temperatures, or
            fewer epochs than ``parameters(max_order) + 2``.
        """
        t, y, s, temps = _checked_series(times, angles, sigmas, temperatures)
        n = t.size
        max_order = int(max_order)
        trend_degree = int(trend_degree)
        n_temp = 0 if temps is None else temps.shape[1]
        _check_fit_options(n, max_order, trend_degree, period_s, n_temp)
        t_ref = float(np.mean(t))
        temp_mean = None if temps is None else temps.mean(axis=0)
        temp_scale = None if temps is None else np.maximum(temps.std(axis=0), 1e-12)
        folds, scheme = _folds(t, period_s, int(k_fold))
        variants = [False] if temps is None else [False, True]
        w_all = 1.0 / s ** 2

        def design(order, use_t):
            return _design(t, t_ref, period_s, order, trend_degree, temps if use_t else None, temp_mean, temp_scale)

        scores = _cv_scores(design, y, w_all, folds, variants, max_order)
        orders = np.zeros(3, dtype=int)
        use_temp = np.zeros(3, dtype=bool)
        coefs, covs = [], []
        rms = np.zeros(3)
        sigma0 = np.zeros(3)
        notes = []
        for j in range(3):
            o, v = _chosen_order(scores[:, :, j], variants, max_order, trend_degree, n_temp, tie_tolerance)
            orders[j], use_temp[j] = o, variants[v]
            if o == max_order and max_order > 0:
                notes.append(f"{_AXES[j]}: chosen order is max_order={max_order}; try a larger max_order")
            a = design(o, variants[v])
            coef, cov = _wls(a, y[:, j], w_all[:, j])
            r = y[:, j] - a @ coef
            dof = max(n - a.shape[1], 1)
            s0 = math.sqrt(float(np.sum(w_all[:, j] * r * r)) / dof)
            coefs.append(coef)
            covs.append(cov * max(s0, 1.0) ** 2 if sigmas is not None else cov * s0 ** 2)
            rms[j] = np.sqrt(np.mean(r * r)) / ARCSEC
            sigma0[j] = s0
        return cls(orders, use_temp, coefs, covs, scores, scheme, t_ref, float(period_s), trend_degree,
                   temp_mean, temp_scale, rms, sigma0, n, max_order, notes)

    def _designs(self, times, temperatures):
        t = _as_seconds(times)
        temps = None
        if np.any(self.use_temperature):
            if temperatures is None:
                raise InputError("the model uses temperature telemetry: give temperatures", field="temperatures")
            temps = _as_temperatures(temperatures, t.size)
            if temps.shape[1] != self.temp_mean.size:
                raise InputError(f"needs {self.temp_mean.size} temperature series, got {temps.shape[1]}",
                                 field="temperatures")
        return [_design(t, self.t_ref_s, self.period_s, int(self.orders[j]), self.trend_degree,
                        temps if self.use_temperature[j] else None, self.temp_mean, self.temp_scale)
                for j in range(3)]

    def predict(self, times, temperatures=None, *, return_sigma: bool = False):
        """Installation angles at ``times``, radians, shape (N, 3) (and their sigmas (N, 3)).

        Temperatures are required when the model uses them (``use_temperature``).

        Parameters
        ----------
        times : array_like, shape (N,)
            Epochs: float seconds or datetime64, as in :meth:`fit`.
        temperatures : array_like, shape (N,) or (N, M), optional
            Telemetry, degrees Celsius.
        return_sigma : bool
            Also return the standard deviations.

        Returns
        -------
        angles : ndarray, shape (N, 3)
            Roll, pitch, yaw, radians.
        sigma : ndarray, shape (N, 3)
            Their standard deviations, radians (only with ``return_sigma``).
        """
        designs = self._designs(times, temperatures)
        out = np.stack([designs[j] @ self.coefficients[j] for j in range(3)], axis=1)
        if not return_sigma:
            return out
        sig = np.stack([np.sqrt(np.einsum("np,pq,nq->n", designs[j], self.covariances[j], designs[j]))
                        for j in range(3)], axis=1)
        return out, sig

    def to_dict(self) -> dict:
        """A JSON-ready summary (angles in arcsec).

        Returns
        -------
        dict
            Orders, coefficients and statistics per angle.
        """
        return {
            "orders": {a: int(o) for a, o in zip(_AXES, self.orders)},
            "use_temperature": {a: bool(u) for a, u in zip(_AXES, self.use_temperature)},
            "trend_degree": self.trend_degree,
            "period_s": self.period_s,
            "t_ref_s": self.t_ref_s,
            "cv_scheme": self.cv_scheme,
            "cv_scores_arcsec": {("time+temperature" if v else "time"): {
                a: [None if not np.isfinite(x) else float(x) for x in self.cv_scores_arcsec[v, :, j]]
                for j, a in enumerate(_AXES)} for v in range(self.cv_scores_arcsec.shape[0])},
            "coefficients_arcsec": {a: (np.asarray(c) / ARCSEC).tolist() for a, c in zip(_AXES, self.coefficients)},
            "residual_rms_arcsec": {a: float(x) for a, x in zip(_AXES, self.residual_rms_arcsec)},
            "sigma0": {a: float(x) for a, x in zip(_AXES, self.sigma0)},
            "n_epochs": self.n_epochs,
            "notes": list(self.notes),
        }


# --------------------------------------------------------------------------- compensation
def evaluate_positioning(lab, true_angles, candidates: dict, *, grid_n: int = 15, height_m: float = 0.0) -> dict:
    """Positioning error over the frame of models with given installations, per epoch.

    For every epoch, ground points of a ``grid_n x grid_n`` pixel grid are located through
    the TRUE model (``lab`` with ``true_angles[i]``) and projected back through ``lab`` with
    each candidate's installation; the error is the RMS image distance, pixels.

    Parameters
    ----------
    lab : GeoStaringModel
    true_angles : array_like, shape (N, 3)
        Radians.
    candidates : dict of str to array_like of shape (N, 3) or (3,)
        E.g. ``{"constant": mean_angles, "predicted": model.predict(times)}``.

    Returns
    -------
    dict
        ``{name: ndarray (N,)}`` RMS pixels per epoch, plus ``"<name>_rms_px"`` over all epochs.
    """
    true = np.asarray(true_angles, dtype=np.float64).reshape(-1, 3)
    n = true.shape[0]
    gr, gc = frame_grid(lab.image_shape, grid_n)
    cands = {}
    for name, value in candidates.items():
        arr = np.asarray(value, dtype=np.float64)
        cands[name] = np.broadcast_to(arr.reshape(-1, 3) if arr.size != 3 else arr.reshape(1, 3), (n, 3))
    out = {name: np.full(n, np.nan) for name in cands}
    for i in range(n):
        lon, lat, h = with_installation(lab, true[i]).image_to_ground(gr, gc, height=height_m)
        for name, arr in cands.items():
            r, c = with_installation(lab, arr[i]).ground_to_image(lon, lat, h)
            out[name][i] = np.sqrt(np.nanmean((r - gr) ** 2 + (c - gc) ** 2))
    for name in cands:
        out[f"{name}_rms_px"] = float(np.sqrt(np.mean(out[name] ** 2)))
    return out


# --------------------------------------------------------------------------- figures
def _figure(width_in, height_in):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def plot_thermal_angles(path, series: ThermalSeries, model: ThermalModel, *, train=None, drift: ThermalDrift | None = None):
    """Seed 002 figure 11: each installation angle against time, fitted curve and residuals.

    Left column: per-epoch solutions (error bars) of the training and held-out epochs, the
    fitted/predicted curve and (with ``drift``) the injected smooth truth, arcsec against
    hours. Right column: per-epoch solution minus curve. Writes a PNG at ``path``.

    Parameters
    ----------
    path : path
        PNG file to write.
    series : ThermalSeries
        Per-epoch solutions.
    model : ThermalModel
        Fitted time model.
    train : array_like of bool, shape (N,), optional
        Epochs used in the fit (the others are drawn as held out); default all.
    drift : ThermalDrift, optional
        Injected drift (its smooth part is drawn).

    Returns
    -------
    path
        ``path``.
    """
    t = series.times_s
    train = np.ones(t.size, dtype=bool) if train is None else np.asarray(train, dtype=bool)
    hours = t / 3600.0
    dense = np.linspace(t[0], t[-1], max(400, 8 * t.size))
    temps_dense = None
    if np.any(model.use_temperature):
        temps_dense = np.interp(dense, t, series.temperatures)
    curve = model.predict(dense, temps_dense)
    at_epochs = model.predict(t, series.temperatures if np.any(model.use_temperature) else None)
    fig = _figure(12.0, 8.0)
    axes = fig.subplots(3, 2, sharex=True, gridspec_kw={"width_ratios": [2.2, 1.0]})
    for j, name in enumerate(_AXES):
        ax, axr = axes[j]
        ax.errorbar(hours[train], series.angles[train, j] / ARCSEC, yerr=series.sigma[train, j] / ARCSEC,
                    fmt=".", ms=3, lw=0.6, color="tab:blue", label="per-epoch exterior (fit)")
        if (~train).any():
            ax.errorbar(hours[~train], series.angles[~train, j] / ARCSEC, yerr=series.sigma[~train, j] / ARCSEC,
                        fmt=".", ms=3, lw=0.6, color="tab:orange", label="per-epoch exterior (held out)")
        if drift is not None:
            ax.plot(dense / 3600.0, drift.smooth_angles(dense)[:, j] / ARCSEC, color="k", lw=0.8, ls="--",
                    label="injected")
        ax.plot(dense / 3600.0, curve[:, j] / ARCSEC, color="tab:red", lw=1.2,
                label=f"model (order {model.orders[j]}{', +T' if model.use_temperature[j] else ''})")
        ax.set_ylabel(f"{name} (arcsec)")
        ax.grid(alpha=0.3)
        res = (series.angles[:, j] - at_epochs[:, j]) / ARCSEC
        axr.plot(hours[train], res[train], ".", ms=3, color="tab:blue")
        if (~train).any():
            axr.plot(hours[~train], res[~train], ".", ms=3, color="tab:orange")
        axr.axhline(0.0, color="k", lw=0.6)
        axr.set_ylabel("residual (arcsec)")
        axr.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel("time (h)")
    axes[-1, 1].set_xlabel("time (h)")
    fig.suptitle("Installation angles against time (seed 002 fig. 11)")
    fig.tight_layout()
    fig.savefig(path)
    return path


def plot_positioning(path, times_s, errors: dict, *, names=("constant", "predicted")):
    """Positioning error over the frame per epoch (log scale), one line per candidate. PNG.

    Parameters
    ----------
    path : path
        PNG file to write.
    times_s : array_like, shape (N,)
        Epochs, seconds.
    errors : dict of str to array_like, shape (N,)
        Positioning error per candidate model, pixels.
    names : sequence of str
        Candidates drawn, keys of ``errors``.

    Returns
    -------
    path
        ``path``.
    """
    fig = _figure(9.0, 3.8)
    ax = fig.add_subplot(1, 1, 1)
    for name in names:
        ax.semilogy(np.asarray(times_s) / 3600.0, errors[name], ".-", ms=3, lw=0.7,
                    label=f"{name}: RMS {errors[f'{name}_rms_px']:.3f} px")
    ax.set_xlabel("time (h)")
    ax.set_ylabel("positioning error over the frame (px)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    return path
