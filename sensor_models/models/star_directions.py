"""Directions towards stars: right ascension and declination to and from unit vectors.

A star's direction is a unit vector ``(cos d cos a, cos d sin a, sin d)`` in the celestial frame
(GCRF) from its right ascension ``a`` and declination ``d`` (seed 000 eq. 3 left side). The
geostationary staring model (:mod:`sensor_models.models.geo_staring`) images stars given in
either form; :func:`star_unit_vectors` checks and normalizes them.
"""

from __future__ import annotations

import numpy as np

from sensor_models.base import as_float_arrays
from sensor_models.errors import InputError

__all__ = ["radec_to_vectors", "star_unit_vectors", "vectors_to_radec"]


def radec_to_vectors(ra_deg, dec_deg) -> np.ndarray:
    """Unit vectors ``(cos d cos a, cos d sin a, sin d)`` (seed 000 eq. 3 left side).

    Parameters
    ----------
    ra_deg, dec_deg : array_like
        Right ascension ``a`` and declination ``d``, degrees (broadcast together).

    Returns
    -------
    ndarray, shape (..., 3)
    """
    ra, dec = np.radians(np.asarray(ra_deg, dtype=np.float64)), np.radians(np.asarray(dec_deg, dtype=np.float64))
    cd = np.cos(dec)
    return np.stack(np.broadcast_arrays(cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)), axis=-1)


def vectors_to_radec(vectors):
    """Right ascension and declination of direction vectors.

    Parameters
    ----------
    vectors : array_like, shape (..., 3)
        Directions (any length).

    Returns
    -------
    ra_deg : ndarray, shape (...)
        In ``[0, 360)``.
    dec_deg : ndarray, shape (...)
    """
    w = np.asarray(vectors, dtype=np.float64)
    ra = np.degrees(np.arctan2(w[..., 1], w[..., 0])) % 360.0
    dec = np.degrees(np.arctan2(w[..., 2], np.hypot(w[..., 0], w[..., 1])))
    return ra, dec


def _as_vectors(vectors) -> np.ndarray:
    w = np.asarray(vectors, dtype=np.float64)
    if w.ndim == 1:
        w = w[None, :]
    if w.ndim != 2 or w.shape[1] != 3:
        raise InputError(f"must have shape (N, 3), got {np.shape(vectors)}", field="vectors_gcrf")
    if not np.all(np.isfinite(w)):
        raise InputError("holds NaN or infinite values", field="vectors_gcrf")
    norm = np.linalg.norm(w, axis=1)
    if np.any(norm == 0.0):
        raise InputError("holds zero vectors", field="vectors_gcrf")
    return w / norm[:, None]


def star_unit_vectors(vectors_gcrf, ra_deg, dec_deg) -> np.ndarray:
    """Unit directions towards stars, given as vectors or as right ascension and declination.

    Parameters
    ----------
    vectors_gcrf : array_like, shape (N, 3) or (3,), or None
        Directions (any non-zero length).
    ra_deg, dec_deg : array_like, shape (N,), or None
        Instead of ``vectors_gcrf``: right ascension and declination, degrees.

    Returns
    -------
    ndarray, shape (N, 3)
        Unit vectors.

    Raises
    ------
    InputError
        Both or neither forms given, or a vector is not finite or zero.
    """
    radec = (ra_deg is not None, dec_deg is not None)
    if (vectors_gcrf is not None and any(radec)) or (vectors_gcrf is None and not all(radec)):
        raise InputError("give either vectors_gcrf or both ra_deg= and dec_deg=")
    if vectors_gcrf is None:
        ra, dec = as_float_arrays(ra_deg, dec_deg, names=("ra_deg", "dec_deg"))
        vectors_gcrf = radec_to_vectors(ra.reshape(-1), dec.reshape(-1))
    return _as_vectors(vectors_gcrf)
