"""Image motion of a ground shift: ``d(row, col) / d(east, north)`` through any sensor model.

A reference orthoimage whose geolocation is off by ``(east, north)`` metres gives every GCP a
ground point off by that much; what that does in the image is ``A = d(row, col) / d(east, north)``
at each point. The matcher projects the reference's stated accuracy into pixels with it
(:func:`gcpmatch.uncertainty.reference_sigma_px`), and the calibration propagates the common
shift into its parameters with it (:mod:`calibrate.reference_covariance`).

``A`` is measured by central differences: each ground point moved by ``+-STEP_M`` east and north
on the WGS84 ellipsoid (:func:`sensor_models.geometry.geodesy.degrees_per_metre`) and projected by the
model's ``ground_to_image``.
"""

from __future__ import annotations

import numpy as np

from sensor_models.geometry.geodesy import degrees_per_metre

__all__ = ["STEP_M", "ground_shift_jacobian"]

#: half-step of the central differences, metres
STEP_M = 5.0


def ground_shift_jacobian(model, lon, lat, h, **where) -> np.ndarray:
    """Image motion per metre of ground shift east and north, ``A = d(row, col) / d(east, north)``.

    Parameters
    ----------
    model : SensorModel
        Model whose ``ground_to_image`` projects the points.
    lon, lat, h : array_like, shape (n,)
        Ground points: WGS84 degrees and metres above the ellipsoid.
    **where
        Passed to ``ground_to_image`` (``band``, ``array``).

    Returns
    -------
    ndarray, shape (n, 2, 2)
        ``[i, (row, col), (east, north)]``, pixels per metre; NaN where a projection failed.
    """
    lon, lat, h = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (lon, lat, h))
    dlon, dlat = degrees_per_metre(lat)
    out = np.empty((lon.size, 2, 2))
    for k, (ex, ny) in enumerate(((dlon, 0.0), (0.0, dlat))):
        r1, c1 = model.ground_to_image(lon + STEP_M * ex, lat + STEP_M * ny, h, **where)
        r0, c0 = model.ground_to_image(lon - STEP_M * ex, lat - STEP_M * ny, h, **where)
        out[:, 0, k] = (np.asarray(r1) - np.asarray(r0)) / (2.0 * STEP_M)
        out[:, 1, k] = (np.asarray(c1) - np.asarray(c0)) / (2.0 * STEP_M)
    return out
