"""Laboratory (physical) camera parameters -> directional angles of every detector.

A linear CCD of ``n`` detectors lies in the focal plane; detector ``s`` (``0 .. n-1``) sits at
``(x_ccd, y_ccd + s p)`` (pixel size ``p``) plus its band's focal-plane offset, in the
positive-image convention (focal-plane axes parallel to the camera X, along track, and Y,
across track). The physical model (the kind of terms of seed 002 table 1) is then:

1. rotation of the CCD assembly by ``rotation_rad`` about the camera Z axis (the boresight);
2. tilt of the focal plane by ``tilt_rad`` about the X axis: a point at ``y`` moves to
   ``(y cos(tau), f + y sin(tau))`` in ``(Y, Z)``;
3. principal point ``(x0, y0)`` and Brown-Conrady distortion with ``r^2 = x^2 + y^2``
   (coordinates relative to the principal point):

   .. math::

       \\Delta x = x (k_1 r^2 + k_2 r^4 + k_3 r^6) + p_1 (r^2 + 2 x^2) + 2 p_2 x y

       \\Delta y = y (k_1 r^2 + k_2 r^4 + k_3 r^6) + p_2 (r^2 + 2 y^2) + 2 p_1 x y

   the distortion displaces the image, so the ideal direction uses ``x - dx``, ``y - dy``;
4. ``tan psi_x = (x - dx) / Z``, ``tan psi_y = (y - dy) / Z`` with ``Z = f + y sin(tau)``.

The angles of all detectors are fitted per CCD and band by a polynomial in ``s`` (cubic by
default, seed 003 eq. 2); the fit residual is reported so a caller can raise the degree.
Lengths are millimetres; ``k1`` in mm^-2, ``k2`` mm^-4, ``k3`` mm^-6, ``p1``, ``p2`` mm^-1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sensor_models.errors import InputError
from sensor_models.models.pushbroom_types import CcdLook

__all__ = ["LabBand", "LabCamera", "LabCcd", "lab_to_directional_angles"]


@dataclass(frozen=True)
class LabCcd:
    """One CCD: its raster columns and focal-plane position of detector 0 (mm)."""

    name: str
    first_col: int
    n_detectors: int
    x_mm: float
    y_mm: float


@dataclass(frozen=True)
class LabBand:
    """One band: focal-plane offset ``(dx, dy)`` in mm (filter position) and its CCDs."""

    name: str
    ccds: tuple[LabCcd, ...]
    offset_mm: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class LabCamera:
    """Physical interior parameters of a push-broom camera (see the module docstring)."""

    focal_length_mm: float
    pixel_size_mm: float
    bands: tuple[LabBand, ...]
    principal_point_mm: tuple[float, float] = (0.0, 0.0)
    radial_k: tuple[float, float, float] = (0.0, 0.0, 0.0)
    decentering_p: tuple[float, float] = (0.0, 0.0)
    tilt_rad: float = 0.0
    rotation_rad: float = 0.0
    polynomial_degree: int = 3
    fit_residual_rad: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if not self.focal_length_mm > 0:
            raise InputError("must be positive", field="interior.focal_length_mm")
        if not self.pixel_size_mm > 0:
            raise InputError("must be positive", field="interior.pixel_size_mm")
        if not 1 <= self.polynomial_degree <= 7:
            raise InputError("must be 1 to 7", field="interior.polynomial_degree")


def detector_angles(camera: LabCamera, band: LabBand, ccd: LabCcd, s):
    """``tan psi_x(s)``, ``tan psi_y(s)`` of detectors ``s``, exactly from the lab model.

    The detector's focal-plane position (CCD position + band offset + ``s`` pixel pitches along
    the array), turned by the array rotation and tilt, relative to the principal point, with
    radial (k1, k2, k3) and decentering (p1, p2) distortion removed, over the focal length.

    Parameters
    ----------
    camera : LabCamera
        Focal length, pixel size, principal point, distortion, tilt and rotation (mm, rad).
    band : LabBand
        The band (its focal-plane offset in mm).
    ccd : LabCcd
        The CCD (its first detector's position in mm).
    s : array_like
        Detector indices (0 at the first detector's centre).

    Returns
    -------
    tan_psi_x, tan_psi_y : ndarray
        Camera-frame direction tangents, shape of ``s``.
    """
    s = np.asarray(s, dtype=np.float64)
    x = ccd.x_mm + band.offset_mm[0] + 0.0 * s
    y = ccd.y_mm + band.offset_mm[1] + s * camera.pixel_size_mm
    c, sn = np.cos(camera.rotation_rad), np.sin(camera.rotation_rad)
    x, y = c * x - sn * y, sn * x + c * y
    z = camera.focal_length_mm + y * np.sin(camera.tilt_rad)
    y = y * np.cos(camera.tilt_rad)
    xr = x - camera.principal_point_mm[0]
    yr = y - camera.principal_point_mm[1]
    r2 = xr * xr + yr * yr
    k1, k2, k3 = camera.radial_k
    p1, p2 = camera.decentering_p
    radial = k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    dx = xr * radial + p1 * (r2 + 2 * xr * xr) + 2 * p2 * xr * yr
    dy = yr * radial + p2 * (r2 + 2 * yr * yr) + 2 * p1 * xr * yr
    return (xr - dx) / z, (yr - dy) / z


def lab_to_directional_angles(camera: LabCamera):
    """Fit directional-angle polynomials to every CCD and band of a lab camera.

    Parameters
    ----------
    camera : LabCamera
        The lab model; ``camera.polynomial_degree`` is the fitted degree (at most
        ``n_detectors - 1``).

    Returns
    -------
    bands : dict of str to tuple of CcdLook
    residual_rad : dict of (band, ccd) to float
        Maximum absolute fit residual of ``tan psi`` over the detectors (radians).
    """
    from numpy.polynomial import polynomial as P

    bands, residual = {}, {}
    for band in camera.bands:
        looks = []
        for ccd in band.ccds:
            s = np.arange(ccd.n_detectors, dtype=np.float64)
            tx, ty = detector_angles(camera, band, ccd, s)
            deg = min(camera.polynomial_degree, ccd.n_detectors - 1)
            # fit in a scaled variable for conditioning, then expand to powers of s
            half = max(1.0, 0.5 * (ccd.n_detectors - 1))
            u = s / half
            cx = P.polyfit(u, tx, deg) / half ** np.arange(deg + 1)
            cy = P.polyfit(u, ty, deg) / half ** np.arange(deg + 1)
            residual[(band.name, ccd.name)] = float(
                max(np.abs(P.polyval(s, cx) - tx).max(), np.abs(P.polyval(s, cy) - ty).max())
            )
            looks.append(CcdLook(ccd.name, ccd.first_col, ccd.n_detectors, cx, cy))
        bands[band.name] = tuple(looks)
    return bands, residual
