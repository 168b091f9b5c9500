"""Star-track truth beyond the default sequence (seed 000): what the LAB model and the catalogue do not know.

:func:`sensor_models.simulate.star_sky.simulate_geo_stars` takes a :class:`StarTruthErrors`
(from a :class:`~sensor_models.simulate.profiles.StarsProfile` by :func:`truth_errors`); with
none (``ideal``) it renders the default sequence byte for byte. Each error is drawn from its own
generator (seeded from the sequence's seed), so switching one on does not change the others.

* **Unmeasured wobble** (:func:`wobble_angles`): a sinusoid per axis in the TRUE attitude only
  (the measured attitude the LAB model reads does not contain it).
* **Catalogue errors** (:func:`perturb_catalogue`): each rendered star is displaced from its
  catalogue direction by a position error plus a proper-motion error times the years from the
  catalogue epoch (J1991.25) to the frame; the pipeline identifies and predicts with the
  unperturbed catalogue.
* **Centroid systematics**: a pixel-phase S-curve (:func:`pixel_phase_shift`: the photocentre
  moves by ``a sin(2 pi f)`` with ``f`` the offset from the pixel centre) and a per-pixel gain
  (PRNU, :func:`prnu_map`) on the star signal.
* **Orbit error**: the LAB orbit is displaced along the geostationary arc by ``orbit_bias_m``.
  Stars are at infinity, so only aberration (``v / c``) could carry it: a displaced GEO position
  does not change the velocity, the effect on star directions is nil and is injected anyway.

References
----------
.. [1] ESA 1997, The Hipparcos and Tycho Catalogues, ESA SP-1200.
.. [2] Jia et al. 2010, Sci. China Tech. Sci. 53(11):3145-3152 (S-curve centroid error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CATALOGUE_EPOCH_YEAR", "StarTruthErrors", "perturb_catalogue", "pixel_phase_shift", "prnu_map",
           "truth_errors", "wobble_angles"]

MAS = np.pi / (180.0 * 3600.0 * 1000.0)
ARCSEC = np.pi / (180.0 * 3600.0)
#: Hipparcos catalogue epoch (Julian year)
CATALOGUE_EPOCH_YEAR = 1991.25


@dataclass(frozen=True)
class StarTruthErrors:
    """Errors of a star sequence that the default simulator path does not inject (module docstring).

    Attributes
    ----------
    wobble_arcsec : float
        Amplitude per axis of the unmeasured sinusoid, arcsec.
    wobble_period_s : float
        Its period, seconds.
    catalogue_position_mas, proper_motion_error_mas_yr : float
        Per-axis standard deviations, milliarcseconds (per year).
    pixel_phase_px : float
        S-curve amplitude, pixels.
    prnu_rms : float
        Relative per-pixel gain, rms.
    orbit_bias_m : float
        Along-track displacement of the LAB orbit, metres.
    """

    wobble_arcsec: float = 0.0
    wobble_period_s: float = 1200.0
    catalogue_position_mas: float = 0.0
    proper_motion_error_mas_yr: float = 0.0
    pixel_phase_px: float = 0.0
    prnu_rms: float = 0.0
    orbit_bias_m: float = 0.0


def truth_errors(profile) -> StarTruthErrors | None:
    """The :class:`StarTruthErrors` of a stars profile; None for ``ideal`` (the default path).

    Parameters
    ----------
    profile : StarsProfile

    Returns
    -------
    StarTruthErrors or None
    """
    if profile is None or profile.is_ideal:
        return None
    names = StarTruthErrors.__dataclass_fields__
    return StarTruthErrors(**{k: float(profile.value(k)) for k in names})


def wobble_angles(t_s, amplitude_arcsec: float, period_s: float, rng) -> np.ndarray:
    """Unmeasured sinusoidal attitude wobble, radians, shape (N, 3) (roll, pitch, yaw).

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Seconds.
    amplitude_arcsec, period_s : float
        Amplitude per axis and period.
    rng : numpy.random.Generator
        Draws the three phases.

    Returns
    -------
    ndarray, shape (N, 3)
    """
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    return amplitude_arcsec * ARCSEC * np.sin(2.0 * np.pi * np.asarray(t_s)[:, None] / period_s + phase[None, :])


def perturb_catalogue(unit_icrs, position_mas: float, pm_mas_yr: float, epoch_year: float, rng) -> np.ndarray:
    """Catalogue directions displaced by position and proper-motion errors.

    Parameters
    ----------
    unit_icrs : ndarray, shape (N, 3)
        Catalogue unit vectors.
    position_mas, pm_mas_yr : float
        Per-axis standard deviations of the position and proper-motion errors.
    epoch_year : float
        Year of the observation (the proper-motion error grows from :data:`CATALOGUE_EPOCH_YEAR`).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (N, 3)
        Unit vectors.
    """
    v = np.asarray(unit_icrs, dtype=np.float64)
    sigma = np.hypot(position_mas, pm_mas_yr * (epoch_year - CATALOGUE_EPOCH_YEAR)) * MAS
    pole = np.where(np.abs(v[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(pole, v)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(v, e1)
    d = rng.normal(0.0, sigma, (v.shape[0], 2))
    out = v + d[:, :1] * e1 + d[:, 1:] * e2
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def pixel_phase_shift(coord_px, amplitude_px: float) -> np.ndarray:
    """Photocentre shift of an S-curve: ``a sin(2 pi f)``, ``f`` the offset from the pixel centre.

    Parameters
    ----------
    coord_px : array_like
        Row or column coordinates (first pixel's centre at 0.5).
    amplitude_px : float

    Returns
    -------
    ndarray, shape of ``coord_px``
        Pixels to add.
    """
    c = np.asarray(coord_px, dtype=np.float64)
    f = c - np.floor(c) - 0.5
    return amplitude_px * np.sin(2.0 * np.pi * f)


def prnu_map(shape, rms: float, rng) -> np.ndarray:
    """Per-pixel relative gain ``1 + N(0, rms)``, shape ``shape``.

    Parameters
    ----------
    shape : (int, int)
    rms : float
    rng : numpy.random.Generator

    Returns
    -------
    ndarray
    """
    return 1.0 + rng.normal(0.0, float(rms), tuple(int(x) for x in shape))
