"""Seed 002's own data flow: the interior from the lab's camera-frame grid, the exterior from VCPs.

Seed 002 solves its two parameter groups from two different data sets (section 2.3, bullets
4 to 6; section 3.1):

* the *interior* from the grid's two-dimensional pointing angles *in the camera frame* (the
  "actual" angles of each grid point against the "initial" ones of the design pixel size): a
  laboratory measurement of the camera, which knows nothing of the installation;
* the *exterior* (installation angles alpha, beta, theta) from the virtual control points on
  the ground (section 2.2), through the attitude and orbit measured at each observation
  (section 2.3 bullet 2, section 3.2: "three-direction errors are added to the attitude
  parameters and orbital position parameters").

The four schemes of figure 2 are then one pass each: ``ICO`` the lab interior alone (the
installation error stays), ``ECO`` the exterior alone on the LAB interior, ``ECBIC`` the
exterior first (it absorbs the distortion's mean shift and rotation), then the lab interior
replaces the LAB one (that share is now counted twice), ``ICBEC`` the lab interior first, then
the exterior on it (it absorbs what is left: the paper's "it is better to finally conduct the
external parameter compensation").

:func:`lab_pointing_interior` simulates the lab measurement (TRUE camera-frame tangents on the
grid plus Gaussian noise) and fits the 20-coefficient cubic; :func:`attitude_noise` puts a
white attitude error on each VCP (small-angle image equivalent); :func:`run_paper_flow` runs
the four schemes and scores them on the check grid (:func:`positioning_errors`). The schemes on
VCPs alone (the free cubic) are :mod:`calibrate.schemes.compensate`.

References
----------
.. [1] Seed 002: Xiao, Li, Sheng et al., Research into image point positioning compensation of
   a high-orbit thermal infrared staring camera, Appl. Sci. 2023, 13(17), 9688: sections 2.2,
   2.3, 3.1, 3.2; figure 2; table 3.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from calibrate.absolute import calibrate_model
from calibrate.config import CalibrationOptions
from calibrate.schemes.virtual_points import VirtualControlPoints, positioning_errors
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.staring_camera import cubic_monomials

__all__ = ["PAPER_FLOW_SCHEMES", "PAPER_RANKING", "attitude_noise", "lab_pointing_interior", "ranking",
           "run_paper_flow"]

#: the four schemes of seed 002 figure 2, one pass each (scheme -> description)
PAPER_FLOW_SCHEMES = {
    "ICO": "lab interior only (camera frame; the installation error stays)",
    "ECO": "exterior only from the VCPs, on the LAB interior",
    "ECBIC": "exterior from the VCPs, then the lab interior",
    "ICBEC": "lab interior, then the exterior from the VCPs",
}
#: seed 002 table 3's order, best first (section 3.2)
PAPER_RANKING = ("ICBEC", "ECBIC", "ECO", "ICO")


def lab_pointing_interior(truth, *, step_px: float = 100.0, start_px: float = 0.0, stop_px: float | None = None,
                          noise_px: float = 0.0, seed: int = 0):
    """The 20 coefficients fitted to a lab measurement of the camera-frame pointing angles.

    The TRUE camera's ``tan psi_x, tan psi_y`` (:meth:`GeoStaringModel.look_cam`, camera
    frame: no installation) at the pixel centres of the grid ``start_px .. stop_px`` every
    ``step_px`` along both axes (seed 002 section 2.3 bullet 3: 0 .. 10 000 every 100), plus
    Gaussian noise of ``noise_px`` pixels (times the IFOV) per axis, fitted by linear least
    squares (seed 002 section 3.1, figure 5).

    Parameters
    ----------
    truth : GeoStaringModel
        The TRUE model (its interior is what the lab measures).
    step_px, start_px, stop_px : float
        Grid in pixel indices; ``stop_px`` defaults to the last pixel of the shorter axis.
    noise_px : float
        Standard deviation of the measured angles, pixels (1 sigma, per axis).
    seed : int
        Of that noise.

    Returns
    -------
    a, b : ndarray, shape (10,)
        Coefficients of ``tan psi_x`` and ``tan psi_y`` (the model's monomial order).
    """
    noise = float(noise_px)
    if not (math.isfinite(noise) and noise >= 0.0):
        raise InputError(f"must be >= 0, got {noise_px}", field="lab_noise_px")
    n = min(truth.image_shape)
    stop = float(n - 1) if stop_px is None else min(float(stop_px), n - 1.0)
    axis = np.arange(float(start_px), stop + 1e-9, float(step_px)) + 0.5
    if axis.size < 4:
        raise InputError(f"a step of {step_px} px leaves fewer than 4 grid points per axis", field="step_px")
    rr, cc = np.meshgrid(axis, axis, indexing="ij")
    row, col = rr.ravel(), cc.ravel()
    los = truth.look_cam(row, col)
    tangents = los[:, :2] / los[:, 2:3]
    if noise > 0.0:
        tangents = tangents + np.random.default_rng(seed).normal(0.0, noise * truth.ifov_rad, tangents.shape)
    u, v = truth.normalized(row, col)
    coef, *_ = np.linalg.lstsq(cubic_monomials(u, v), tangents, rcond=None)
    return coef[:, 0], coef[:, 1]


def attitude_noise(vcp: VirtualControlPoints, sigma_rad: float, ifov_rad: float, image_shape, *,
                   seed: int = 0) -> VirtualControlPoints:
    """VCPs whose ground points were computed through a noisy measured attitude.

    Each VCP is observed at its own instant (seed 002 section 2.2: the target's image points
    at their observation times), so each carries its own attitude error: white, ``sigma_rad``
    per axis. To first order (a field of ~0.8 degree) a roll or pitch error moves the true
    image of the VCP's ground point by ``error / ifov`` pixels and a yaw error turns it about
    the frame centre; that displacement is put on ``row``, ``col`` (the ground points stay).

    Parameters
    ----------
    vcp : VirtualControlPoints
    sigma_rad : float
        Attitude error, radians (1 sigma, per axis).
    ifov_rad : float
        Angle of one pixel.
    image_shape : (int, int)
        Frame shape (rows, cols): its centre is the yaw axis.
    seed : int
        Of the attitude errors.

    Returns
    -------
    VirtualControlPoints
        A copy with displaced image coordinates.
    """
    sigma = float(sigma_rad)
    if not (math.isfinite(sigma) and sigma >= 0.0):
        raise InputError(f"must be >= 0, got {sigma_rad}", field="attitude_noise_arcsec")
    if sigma == 0.0:
        return vcp
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = (rng.normal(0.0, sigma, vcp.n_points) for _ in range(3))
    r0, c0 = 0.5 * image_shape[0], 0.5 * image_shape[1]
    row = vcp.row + pitch / ifov_rad + yaw * (vcp.col - c0)
    col = vcp.col + roll / ifov_rad - yaw * (vcp.row - r0)
    return replace(vcp, row=row, col=col)


def ranking(totals: dict) -> tuple:
    """Scheme names sorted by their total error, best first (non-finite last).

    Parameters
    ----------
    totals : dict of str to float

    Returns
    -------
    tuple of str
    """
    return tuple(sorted(totals, key=lambda k: (not math.isfinite(totals[k]), totals[k])))


def run_paper_flow(lab, vcp: VirtualControlPoints, check: VirtualControlPoints, interior, *,
                   sigma_px: float = 1.0) -> dict:
    """Seed 002's four schemes (figure 2), one pass each, scored on the check grid.

    Parameters
    ----------
    lab : GeoStaringModel
        The LAB (starting) model.
    vcp : VirtualControlPoints
        Ground VCPs (the exterior's data).
    check : VirtualControlPoints
        Ground check points of the TRUE model.
    interior : (ndarray, ndarray)
        The lab-measured coefficients (:func:`lab_pointing_interior`).
    sigma_px : float
        Weight of the VCPs (any positive value: one group of equal weights).

    Returns
    -------
    dict
        Scheme (``before`` then :data:`PAPER_FLOW_SCHEMES`) -> ``{"model", "errors",
        "seconds"}`` (errors of :func:`positioning_errors`, pixels).
    """
    if vcp.lon is None:
        raise InputError("the exterior needs ground VCPs (target='ground')", field="target")
    a, b = (np.asarray(x, dtype=np.float64) for x in interior)
    table = GcpTable.from_arrays(vcp.row, vcp.col, vcp.lon, vcp.lat, vcp.h, sigma_px=float(sigma_px))
    options = CalibrationOptions(robust="none", scheme="exterior")

    def with_interior(model):
        return model.with_parameters(np.concatenate([model.installation.as_array(), a, b]))

    def exterior(model):
        return calibrate_model(model, table, options=options).model

    steps = {"before": lambda: lab, "ICO": lambda: with_interior(lab), "ECO": lambda: exterior(lab),
             "ECBIC": lambda: with_interior(exterior(lab)), "ICBEC": lambda: exterior(with_interior(lab))}
    out = {}
    for name, step in steps.items():
        t0 = time.perf_counter()
        model = step()
        out[name] = {"model": model, "errors": positioning_errors(model, check), "seconds": time.perf_counter() - t0}
    return out
