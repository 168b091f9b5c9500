"""The four compensation schemes of seed 002 (staring camera) run on virtual control points.

Seed 002 (Xiao et al., Appl. Sci. 2023, 13, 9688) compensates the image-point positioning of a
high-orbit staring camera without real ground control: an image-space-uniform grid of pixels
(section 2.2, section 2.3 third bullet: pixels 0 .. 10 000 every 100 px) is projected through a
model onto the Earth (figure 1); each pixel and its ground point form a *virtual control point*
(VCP). The exterior (installation angles alpha, beta, theta = our ``installation.roll, pitch,
yaw``, section 2.1 first equation) and the interior (the 20-coefficient two-dimensional
pointing-angle cubic, section 2.1 second equation) are then estimated from the VCPs by the
linearized error equations ``V = A X - L`` (exterior) and ``V = B Y - L`` (interior) of
section 2.2, in four orders (section 2.3, figure 2):

========  ============================================================================
``ICO``   interior compensation only
``ECO``   exterior compensation only
``ECBIC`` exterior, then interior in the frame it fixes (iterated)
``ICBEC`` interior, then exterior (iterated)
``joint`` both at once, the camera frame held by gauge pseudo-observations (ours)
========  ============================================================================

Each is run by :func:`calibrate.absolute.calibrate_model` from the LAB model with the VCPs of
the TRUE model; the accuracy is the positioning error on an independent check grid offset by
half a grid step (true ground point of each check pixel, projected back by the compensated
model; X = column, Y = row, pixels), as seed 002 table 3. The VCPs, the check grid and the
positioning errors are built in :mod:`calibrate.schemes.virtual_points`; seed 002's simulation
(tables 1-3) in :mod:`calibrate.schemes.compensation_study` and its outputs in
:mod:`calibrate.schemes.compensation_outputs`.

Two readings of "interior"
--------------------------
Our 20-coefficient interior contains the boresight offset (``a00``, ``b00``) and the in-plane
rotation (``a01``, ``b10``): over the ~0.8 degree field of a GF-4-like camera a small
installation rotation is, to ~1e-8 rad, a change of those terms. From ground points alone the
two groups are therefore interchangeable (the *gauge*):

* the free interior (``ICO``, ``ICBEC``) absorbs the installation error into the interior and
  reaches the noise level, but leaves the installation angles at their LAB values (the interior
  then carries the 72 arcsec), so a temperature-driven change of the installation (seed 002
  section 3.3) cannot be tracked by the exterior alone;
* the *gauge-held* interior (``ICO-g``: :func:`calibrate_model` joint over the interior names
  with the mean look and rotation of the frame held at LAB values) may model the distortion
  shape only - our reading of seed 002's internal model (section 3.1: the interior is fitted
  to camera-frame pointing-angle differences). It cannot move the frame, so the installation
  error remains and the higher-order terms bend to follow part of it: the error barely drops
  and grows at the corners (seed 002's ICO row: 47.5 px, no better than before, 43.3 px).

Seed 002 itself solves the interior from a third data set, the grid's camera-frame pointing
angles measured in the lab (section 3.1), and the exterior from the VCPs:
:mod:`calibrate.schemes.paper_flow` runs its four schemes that way.

``ECO`` recovers the installation angles but cannot follow the radial and decentering
distortion (a few pixels at the corners); ``ECBIC``, ``ICBEC`` and ``joint`` reach the noise
of the VCPs. In every scheme the recovered installation equals the truth's plus the parts of
the distortion that are a rotation of the frame (the -8 arcsec array rotation of table 1 appears
in the yaw, the mean decentering shift in roll and pitch): no ground point can tell them apart.

References
----------
.. [1] Seed 002: Xiao, Li, Sheng et al., Research into image point positioning compensation of
   a high-orbit thermal infrared staring camera, Appl. Sci. 2023, 13(17), 9688: sections 2.1
   to 2.3, 3.1, 3.2; tables 1 to 3; figures 4 to 10.
"""

from __future__ import annotations

import time

from calibrate.absolute import calibrate_model
from calibrate.config import CalibrationOptions
from calibrate.schemes.virtual_points import VirtualControlPoints
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError

__all__ = ["SCHEMES", "compensate"]


#: scheme name -> (calibrate_model scheme or our gauge-held variant, description)
SCHEMES = {
    "ICO": ("interior", "interior only (free cubic: absorbs the installation error)"),
    "ECO": ("exterior", "exterior only (installation angles; the distortion stays)"),
    "ECBIC": ("exterior-interior", "exterior, then interior, iterated"),
    "ICBEC": ("interior-exterior", "interior, then exterior, iterated (the free interior absorbs all)"),
    "joint": ("joint", "exterior and interior together, camera frame held by the gauge"),
    "ICO-g": ("gauge-interior", "interior only, mean look and rotation held (seed 002's reading)"),
}


def _gauge_interior(model, table, options):
    names = tuple(model.interior_parameter_names(3))
    return calibrate_model(model, table, options=options.replace(scheme="joint", parameters=names, gauge=True))


def compensate(lab_model, vcp: VirtualControlPoints, *, schemes=None, robust: str = "none", sigma_px=None) -> dict:
    """Run compensation schemes (seed 002 section 2.3) from the LAB model on VCPs.

    Parameters
    ----------
    lab_model : GeoStaringModel
        Starting (laboratory) model.
    vcp : VirtualControlPoints
        Ground virtual control points (``target="ground"``).
    schemes : sequence of str, optional
        Keys of :data:`SCHEMES` (default: all).
    robust : {"none", "huber", "cauchy"}
        Loss of :func:`calibrate_model` (VCPs hold no outliers: least squares by default).
    sigma_px : float, optional
        Standard deviation of the VCP coordinates (default: the added noise, else 1 px).

    Returns
    -------
    dict
        Scheme name -> ``{"result": CalibrationResult, "model": GeoStaringModel, "seconds":
        float, "rounds": int}``.
    """
    if vcp.lon is None:
        raise InputError("the compensation needs ground VCPs (target='ground')", field="target")
    names = list(SCHEMES) if schemes is None else list(schemes)
    unknown = [s for s in names if s not in SCHEMES]
    if unknown:
        raise InputError(f"unknown schemes {', '.join(unknown)}; choose from {', '.join(SCHEMES)}", field="schemes")
    sigma = sigma_px if sigma_px is not None else (vcp.noise_px if vcp.noise_px > 0 else 1.0)
    table = GcpTable.from_arrays(vcp.row, vcp.col, vcp.lon, vcp.lat, vcp.h, sigma_px=sigma)
    options = CalibrationOptions(robust=robust)
    out = {}
    for name in names:
        kind = SCHEMES[name][0]
        t0 = time.perf_counter()
        rounds = 1
        if kind == "gauge-interior":
            res = _gauge_interior(lab_model, table, options)
        else:
            res = calibrate_model(lab_model, table, options=options.replace(scheme=kind))
            rounds = len({s.get("outer", 0) for s in res.steps}) if res.steps else 1
        out[name] = {"result": res, "model": res.model, "seconds": time.perf_counter() - t0, "rounds": rounds}
    return out


