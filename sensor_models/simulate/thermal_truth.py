"""Day-to-day variation of a staring camera's TRUE installation (not a function of the time of day).

A daily thermal cycle repeats only approximately: the Sun's declination, eclipses, heater duty
and the bracket's history change it from one day to the next. The project's realistic
range for that variation is 3-6 arcsec a day (docs/error_budget.md). It is modelled as a random walk of per-day offsets (one independent Gaussian
step of ``sigma_arcsec_per_day`` per axis and day), interpolated smoothly through the days'
midpoints (cubic Hermite, monotone, so no overshoot), added to the TRUE installation only:
no harmonic model of the time of day can predict it.

References
----------
.. [1] Seed 002 section 3.3 and figure 11 (installation angles against time of day).
.. [2] Seed 000 section 4 ("periodic, with a cycle of one day approximately").
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

__all__ = ["ARCSEC", "DAY_S", "day_to_day_offsets"]

ARCSEC = np.pi / (180.0 * 3600.0)
DAY_S = 86_400.0


def day_to_day_offsets(times_s, sigma_arcsec_per_day: float, *, seed: int = 0) -> np.ndarray:
    """Smooth day-to-day offsets of the three installation angles.

    Parameters
    ----------
    times_s : array_like, shape (N,)
        Epochs, seconds from midnight of the first day.
    sigma_arcsec_per_day : float
        Standard deviation of each day's step, arcsec, per axis (0: all zeros).
    seed : int
        Of the steps (independent of any other noise of the simulation).

    Returns
    -------
    ndarray, shape (N, 3)
        Roll, pitch, yaw offsets, radians; zero on the first day's midpoint.
    """
    t = np.asarray(times_s, dtype=np.float64).reshape(-1)
    if float(sigma_arcsec_per_day) == 0.0 or t.size == 0:
        return np.zeros((t.size, 3))
    n_days = int(np.floor(t.max() / DAY_S)) + 2
    rng = np.random.default_rng([int(seed), 13])
    steps = rng.normal(0.0, float(sigma_arcsec_per_day), (n_days, 3))
    steps[0] = 0.0
    walk = np.cumsum(steps, axis=0)
    mid = (np.arange(n_days) + 0.5) * DAY_S
    knots = np.concatenate([[mid[0] - DAY_S], mid])
    values = np.concatenate([walk[:1], walk])
    return PchipInterpolator(knots, values, axis=0, extrapolate=True)(t) * ARCSEC
