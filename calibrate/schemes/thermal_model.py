r"""A model of the installation angles against time of day, its order chosen by cross-validation.

:class:`ThermalModel` fits, per angle, weighted least squares on

.. math::

    \theta(t) = c_0 + \sum_{d=1}^{D} c_d\,\tau^d
              + \sum_{k=1}^{K} \left(a_k \cos k\omega t + b_k \sin k\omega t\right)
              + \sum_m g_m\,(T_m(t) - \bar T_m),
    \qquad \omega = 2\pi / P,\; \tau = (t - t_{ref}) / P

(``P`` = one day by default, ``t`` in seconds, so with UTC times the harmonics are of the UTC
time of day; ``T_m`` optional temperature telemetry; seed 002 section 3.3, figure 11, and the
module docstring of :mod:`calibrate.schemes.thermal` for the whole study). The harmonic order
``K`` is chosen per angle by cross-validation: leave one day out when the series spans at least
three days, otherwise interleaved k-fold. With temperatures, CV also decides whether they enter
the model. :meth:`ThermalModel.predict` gives the angles (and their standard deviations) at new
epochs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibrate.schemes.thermal import ARCSEC, AXES, DAY_S, as_seconds, as_temperatures, check_increasing
from sensor_models.errors import InputError

__all__ = ["ThermalModel"]


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
    t = as_seconds(times)
    check_increasing(t)
    n = t.size
    y = _as_angles(angles, n, "angles")
    if sigmas is None:
        s = np.ones((n, 3))
    else:
        s = _as_angles(sigmas, n, "sigmas")
        if not np.all(s > 0):
            raise InputError("must be positive", field="sigmas")
    temps = None if temperatures is None else as_temperatures(temperatures, n)
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
                notes.append(f"{AXES[j]}: chosen order is max_order={max_order}; try a larger max_order")
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
        t = as_seconds(times)
        temps = None
        if np.any(self.use_temperature):
            if temperatures is None:
                raise InputError("the model uses temperature telemetry: give temperatures", field="temperatures")
            temps = as_temperatures(temperatures, t.size)
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
            "orders": {a: int(o) for a, o in zip(AXES, self.orders)},
            "use_temperature": {a: bool(u) for a, u in zip(AXES, self.use_temperature)},
            "trend_degree": self.trend_degree,
            "period_s": self.period_s,
            "t_ref_s": self.t_ref_s,
            "cv_scheme": self.cv_scheme,
            "cv_scores_arcsec": {("time+temperature" if v else "time"): {
                a: [None if not np.isfinite(x) else float(x) for x in self.cv_scores_arcsec[v, :, j]]
                for j, a in enumerate(AXES)} for v in range(self.cv_scores_arcsec.shape[0])},
            "coefficients_arcsec": {a: (np.asarray(c) / ARCSEC).tolist() for a, c in zip(AXES, self.coefficients)},
            "residual_rms_arcsec": {a: float(x) for a, x in zip(AXES, self.residual_rms_arcsec)},
            "sigma0": {a: float(x) for a, x in zip(AXES, self.sigma0)},
            "n_epochs": self.n_epochs,
            "notes": list(self.notes),
        }
