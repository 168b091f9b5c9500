"""Interior orientation of a SPOT 1-5 DIMAP scene: detector look angles -> directional-angle polynomials.

:func:`spot_look_to_camera` turns SPOT look angles into gcpcal camera-frame tangents;
:func:`fit_look_polynomials` fits, per band, the ``tan psi_x(s)``, ``tan psi_y(s)`` polynomials
of the push-broom model to every detector's direction (SPOT 1-4 list only the two end
detectors: the others are reconstructed). Conventions: :mod:`sensor_models.readers.dimap`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensor_models.readers.dimap_parse import DimapLookAngles

__all__ = ["LookFit", "MAX_FIT_RESIDUAL_PX", "fit_look_polynomials", "spot_look_to_camera"]

#: the directional-angle polynomial degree is raised until the fit is this good (pixels)
MAX_FIT_RESIDUAL_PX = 0.01
MAX_DEGREE = 7


def spot_look_to_camera(psi_x, psi_y):
    """SPOT look angles -> gcpcal camera-frame ``(tan psi_x, tan psi_y)``.

    The SPOT direction ``(-tan PSI_Y, tan PSI_X, -1)`` is, in the camera frame
    (``CAMERA_TO_SPOT``), ``(tan PSI_X, -tan PSI_Y, 1)``.

    Parameters
    ----------
    psi_x, psi_y : array_like
        ``PSI_X`` (along track) and ``PSI_Y`` (across track) look angles, radians.

    Returns
    -------
    tan_psi_x, tan_psi_y : ndarray of float64
        Camera-frame direction tangents, same shape as the inputs.
    """
    return np.tan(np.asarray(psi_x, dtype=np.float64)), -np.tan(np.asarray(psi_y, dtype=np.float64))


@dataclass(frozen=True)
class LookFit:
    """A per-detector directional-angle polynomial fit of one band.

    Attributes
    ----------
    tan_psi_x, tan_psi_y : ndarray
        Coefficients in the detector index ``s`` (gcpcal camera frame).
    degree : int
    max_residual_px, rms_residual_px : float
        Fit residuals over the detectors, in pixels (detector IFOVs), the larger of the two
        axes.
    n_samples : int
        Detector directions the fit used (listed or, for SPOT 1-4, reconstructed).
    """

    tan_psi_x: np.ndarray
    tan_psi_y: np.ndarray
    degree: int
    max_residual_px: float
    rms_residual_px: float
    n_samples: int


def _detector_tans(look: DimapLookAngles, n_cols: int):
    """``(s, tan_x, tan_y)`` in the camera frame for every detector of the band.

    SPOT 5 lists every detector. SPOT 1-4 list the first and the last: the array is linear in
    the focal plane and tilted by the mirror, so the directions are interpolated linearly in
    tangent space in the frame turned about the along-track axis by the mean of the two
    ``PSI_Y`` (where the two end directions are symmetric), then turned back.
    """
    if look.detector_id.size == n_cols or look.detector_id.size > 2:
        s = look.detector_id - 1.0
        tx, ty = spot_look_to_camera(look.psi_x, look.psi_y)
        return s, tx, ty
    s_end = look.detector_id - 1.0
    theta = 0.5 * (look.psi_y[0] + look.psi_y[-1])
    # camera vectors of the two ends, rotated about camera X (along track) by the tilt
    tx, ty = spot_look_to_camera(look.psi_x, look.psi_y)
    v = np.stack([tx, ty, np.ones_like(tx)], axis=-1)
    c, sn = np.cos(theta), np.sin(theta)
    # camera tan_y = -tan(PSI_Y): a tilt PSI_Y is the rotation Rx(PSI_Y) of (0, 0, 1)
    rot = np.array([[1.0, 0.0, 0.0], [0.0, c, -sn], [0.0, sn, c]])  # Rx(theta): the tilt
    m = v @ rot  # Rx(theta)^T v: the directions with the tilt removed
    mx, my = m[:, 0] / m[:, 2], m[:, 1] / m[:, 2]
    s = np.arange(n_cols, dtype=np.float64)
    fx = np.interp(s, s_end, mx)
    fy = np.interp(s, s_end, my)
    w = np.stack([fx, fy, np.ones_like(fx)], axis=-1) @ rot.T  # tilt back: Rx(theta) m
    return s, w[:, 0] / w[:, 2], w[:, 1] / w[:, 2]


def fit_look_polynomials(look: DimapLookAngles, n_cols: int, *, max_residual_px: float = MAX_FIT_RESIDUAL_PX) -> LookFit:
    """Fit ``tan psi_x(s)``, ``tan psi_y(s)`` polynomials to a band's detector directions.

    The degree starts at 3 (seed 003) and rises, up to 7, until the largest residual is below
    ``max_residual_px`` detector IFOVs (the IFOV being the median across-track step between
    neighbouring detectors). The fit is done in a scaled variable for conditioning, then
    converted to powers of ``s``.

    Parameters
    ----------
    look : DimapLookAngles
        The band's detector look angles.
    n_cols : int
        Detectors (image columns) of the band.
    max_residual_px : float
        Target largest residual, in detector IFOVs (about pixels).

    Returns
    -------
    LookFit
        Coefficients of ``tan psi_x`` and ``tan psi_y`` in powers of the 0-based detector index
        ``s`` (detector ``s`` images column ``s + 0.5``), the degree and the residuals in IFOVs.
    """
    s, tx, ty = _detector_tans(look, n_cols)
    if s.size >= 2:
        ifov = float(np.median(np.abs(np.diff(ty) / np.diff(s))))
    else:
        ifov = np.nan
    half = max(0.5 * (s[-1] - s[0]), 1.0)
    mid = 0.5 * (s[-1] + s[0])
    u = (s - mid) / half
    best = None
    for degree in range(3, MAX_DEGREE + 1):
        deg = min(degree, s.size - 1)
        cx = np.polynomial.polynomial.polyfit(u, tx, deg)
        cy = np.polynomial.polynomial.polyfit(u, ty, deg)
        rx = tx - np.polynomial.polynomial.polyval(u, cx)
        ry = ty - np.polynomial.polynomial.polyval(u, cy)
        res = np.maximum(np.abs(rx), np.abs(ry)) / ifov
        best = (deg, cx, cy, float(res.max()), float(np.sqrt(np.mean(np.maximum(rx**2, ry**2)))) / ifov)
        if best[3] <= max_residual_px or deg == s.size - 1:
            break
    deg, cx, cy, rmax, rrms = best
    # powers of u = (s - mid)/half -> powers of s
    shift = np.polynomial.Polynomial([-mid / half, 1.0 / half])
    px = np.polynomial.Polynomial(cx)(shift).coef
    py = np.polynomial.Polynomial(cy)(shift).coef
    return LookFit(px, py, deg, rmax, rrms, int(s.size))
