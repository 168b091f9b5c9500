"""Virtual control points and the four compensation schemes of seed 002 (staring camera).

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
model; X = column, Y = row, pixels), as seed 002 table 3.

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

``ECO`` recovers the installation angles but cannot follow the radial and decentering
distortion (a few pixels at the corners); ``ECBIC``, ``ICBEC`` and ``joint`` reach the noise
of the VCPs. In every scheme the recovered installation equals the truth's plus the parts of
the distortion that are a rotation of the frame (the -8 arcsec array rotation of table 1 appears
in the yaw, the mean decentering shift in roll and pitch): no ground point can tell them apart.

Seed 002 table 1 mapped onto :class:`~sensor_models.models.staring_camera.StaringLab`
--------------------------------------------------------------------------
======================================  =====================================================
seed 002 table 1                        ``StaringLab`` field (GF-4-like 10240 x 10240 array)
======================================  =====================================================
principal point dx = -0.0015 pixel      ``principal_point_px`` col = n_cols/2 - 0.0015
principal point dy = -0.0015 pixel      ``principal_point_px`` row = n_rows/2 - 0.0015
focal length df = 1 mm                  ``focal_length_mm`` = LAB focal length + 1 (6442.5 mm)
radial k1 = 5e-11 pixel^-2              ``radial_k`` = (5e-11, 0) (r in pixels)
eccentric p1 = 6e-8, p2 = -3e-8 px^-1   ``decentering_p`` = (6e-8, -3e-8)
array tilt phi_x = phi_y = -8 arcsec    ``tilt_rad`` = (-8, -8) arcsec in radians
array rotation beta = -8 arcsec         ``rotation_rad`` = -8 arcsec in radians
======================================  =====================================================

Table 1 labels ``k1`` "pixel2" and ``p`` "pixel1": read as px^-2 and px^-1 (the only units
giving pixel displacements: k1 r^3 = 19 px at the corner r = 7240 px). Seed 002 does not give
its sign conventions; ``StaringLab``'s Brown-Conrady form is used. Table 2's installation
errors (alpha, beta, theta) = (72, -72, 72) arcsec are (roll, pitch, yaw). Seed 002's camera
(pixel size, focal length) is not given; 72 arcsec is about 250 pixels of the GF-4-like
camera (0.288 arcsec pixels), hence our larger error before compensation (seed: 43 px).

References
----------
.. [1] Seed 002: Xiao, Li, Sheng et al., Research into image point positioning compensation of
   a high-orbit thermal infrared staring camera, Appl. Sci. 2023, 13(17), 9688: sections 2.1
   to 2.3, 3.1, 3.2; tables 1 to 3; figures 4 to 10.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from calibrate.absolute import calibrate_model
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError

__all__ = [
    "SCHEMES",
    "SEED002_INSTALLATION_ARCSEC",
    "SEED002_TABLE1",
    "SEED002_TABLE3",
    "CompensationStudy",
    "VirtualControlPoints",
    "check_grid",
    "compensate",
    "pointing_difference_px",
    "positioning_errors",
    "run_seed002",
    "seed002_true_lab",
    "summary_markdown",
    "virtual_control_points",
    "write_study",
]

ARCSEC = math.pi / 180.0 / 3600.0

#: seed 002 table 1 (value, unit as printed)
SEED002_TABLE1 = {
    "principal_point_dx": (-0.0015, "pixel"),
    "principal_point_dy": (-0.0015, "pixel"),
    "focal_length_df": (1.0, "mm"),
    "radial_k1": (5e-11, "pixel^-2"),
    "eccentric_p1": (6e-8, "pixel^-1"),
    "eccentric_p2": (-3e-8, "pixel^-1"),
    "tilt_phi_x": (-8.0, "arcsec"),
    "tilt_phi_y": (-8.0, "arcsec"),
    "rotation_beta": (-8.0, "arcsec"),
}
#: seed 002 table 2: relative installation angle errors alpha, beta, theta (roll, pitch, yaw)
SEED002_INSTALLATION_ARCSEC = (72.0, -72.0, 72.0)
#: seed 002 table 3: X, Y and total positioning errors in pixels
SEED002_TABLE3 = {
    "ICO": (-27.459, -38.781, 47.518),
    "ECO": (-2.268, -3.895, 4.507),
    "ECBIC": (-1.859, -2.313, 2.967),
    "ICBEC": (-0.608, -0.875, 1.065),
    "before": (-28.414, -32.701, 43.321),
}

#: scheme name -> (calibrate_model scheme or our gauge-held variant, description)
SCHEMES = {
    "ICO": ("interior", "interior only (free cubic: absorbs the installation error)"),
    "ECO": ("exterior", "exterior only (installation angles; the distortion stays)"),
    "ECBIC": ("exterior-interior", "exterior, then interior, iterated"),
    "ICBEC": ("interior-exterior", "interior, then exterior, iterated (the free interior absorbs all)"),
    "joint": ("joint", "exterior and interior together, camera frame held by the gauge"),
    "ICO-g": ("gauge-interior", "interior only, mean look and rotation held (seed 002's reading)"),
}

#: why each scheme lands where it does (written into table.json and the summary)
EXPLANATIONS = {
    "before": "LAB model: installation error (~250 px at 0.288 arcsec pixels) plus the lens distortion.",
    "ICO": ("The free 20-coefficient interior contains the boresight offset (a00, b00) and rotation "
            "(a01, b10): it absorbs the installation error and the distortion and reaches the noise "
            "level, but the installation angles stay at LAB values (the interior carries 72 arcsec)."),
    "ECO": ("Three angles move the whole frame: they recover the installation error (plus the array "
            "rotation in the yaw) but cannot follow the radial and decentering distortion, which "
            "stays as pixels at the corners (seed 002: 4.5 px)."),
    "ECBIC": ("The exterior takes the installation error (biased by the distortion's mean shift and "
              "rotation), then the interior takes the distortion shape in that frame; the next "
              "exterior step no longer moves: the noise level."),
    "ICBEC": ("The free interior, solved first, absorbs everything; the exterior then has nothing left "
              "to do (installation stays at LAB values): same image accuracy as ICO."),
    "joint": ("Both groups at once with pseudo-observations holding the frame's mean look and rotation: "
              "well conditioned, installation recovered as in ECBIC, noise level."),
    "ICO-g": ("Interior with the camera frame held (our reading of seed 002's interior: distortion "
              "only): it cannot move the frame, the installation error remains and the higher-order "
              "terms bend towards it, worst at the corners (seed 002's ICO: 47.5 px, no better than "
              "before)."),
}


# --------------------------------------------------------------------------- VCPs
@dataclass
class VirtualControlPoints:
    """Image-space-uniform virtual control points (seed 002 section 2.2, figure 1).

    Attributes
    ----------
    row, col : ndarray, shape (N,)
        Pixel coordinates (first pixel centre 0.5), possibly with added noise.
    lon, lat, h : ndarray, shape (N,) or None
        Ground points (WGS84 degrees, metres) of the noise-free pixels; None for sky targets.
    vectors_gcrf : ndarray, shape (N, 3)
        Unit object vectors (apparent directions) of the noise-free pixels in GCRF
        (:meth:`GeoStaringModel.object_vector_gcrf`): the deep-space form.
    grid_shape : (int, int)
        Grid rows and columns before points missing the Earth were dropped.
    noise_px : float
        Standard deviation of the Gaussian noise added to ``row`` and ``col``.
    """

    row: np.ndarray
    col: np.ndarray
    lon: np.ndarray | None
    lat: np.ndarray | None
    h: np.ndarray | None
    vectors_gcrf: np.ndarray
    grid_shape: tuple
    noise_px: float = 0.0

    @property
    def n_points(self) -> int:
        """Number of points.

        Returns
        -------
        int
            ``row.size``.
        """
        return int(self.row.size)


def _grid_axis(start_px, stop_px, step_px, n, field_name):
    """Pixel indices ``start, start + step, ... <= stop`` (default stop: the last pixel)."""
    step = float(step_px)
    if not (math.isfinite(step) and step > 0.0):
        raise InputError(f"must be positive, got {step_px}", field="step_px")
    start = float(start_px)
    stop = float(n - 1) if stop_px is None else float(stop_px)
    if not (math.isfinite(start) and math.isfinite(stop)) or start < 0.0 or stop > n - 1 or stop < start:
        raise InputError(f"needs 0 <= start ({start_px}) <= stop ({stop_px}) <= {n - 1}", field=field_name)
    k = int(math.floor((stop - start) / step + 1e-9)) + 1
    if k < 2:
        raise InputError(f"a step of {step_px} px leaves fewer than 2 grid points per axis", field="step_px")
    return start + step * np.arange(k)


def virtual_control_points(model, *, step_px: float = 100.0, start_px: float = 0.0, stop_px: float | None = None,
                           height_m: float | None = 0.0, dem=None, target: str = "ground", noise_px: float = 0.0,
                           seed: int = 0) -> VirtualControlPoints:
    """Image-space-uniform grid of pixels projected through ``model`` (seed 002 section 2.2).

    The pixels with indices ``start_px, start_px + step_px, ... <= stop_px`` along both axes
    (seed 002: 0 .. 10 000 every 100) are taken at their centres (index + 0.5) and localized
    with ``model`` (the TRUE model in a simulation, a calibrated reference model in practice).

    Parameters
    ----------
    model : GeoStaringModel
    step_px, start_px, stop_px : float
        Grid in pixel indices; ``stop_px`` defaults to the last pixel of the shorter axis.
    height_m : float, optional
        Ellipsoidal height of the ground points (default 0 m) unless ``dem`` is given.
    dem : sensor_models.terrain.dem.Dem, optional
        Intersect the lines of sight with a DEM instead.
    target : {"ground", "sky"}
        ``"sky"``: deep-space views; no ground intersection, only ``vectors_gcrf``.
    noise_px : float
        Standard deviation (pixels) of Gaussian noise added to the returned ``row`` and
        ``col`` (the ground points and vectors stay those of the noise-free pixels).
    seed : int
        Seed of the noise generator.

    Returns
    -------
    VirtualControlPoints
        Grid points whose line of sight misses the Earth are dropped (``target="ground"``).
    """
    if target not in ("ground", "sky"):
        raise InputError(f"must be 'ground' or 'sky', got {target!r}", field="target")
    noise = float(noise_px)
    if not (math.isfinite(noise) and noise >= 0.0):
        raise InputError(f"must be >= 0, got {noise_px}", field="noise_px")
    n_rows, n_cols = model.image_shape
    axis = _grid_axis(start_px, stop_px, step_px, min(n_rows, n_cols), "grid")
    rr, cc = np.meshgrid(axis + 0.5, axis + 0.5, indexing="ij")
    row, col = rr.ravel(), cc.ravel()
    lon = lat = h = None
    if target == "ground":
        if dem is not None:
            lon, lat, h = model.image_to_ground(row, col, dem=dem)
        else:
            if height_m is None:
                raise InputError("give height_m or dem", field="height_m")
            lon, lat, h = model.image_to_ground(row, col, height=float(height_m))
        ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
        row, col, lon, lat, h = row[ok], col[ok], lon[ok], lat[ok], h[ok]
        if row.size < 2:
            raise InputError("fewer than 2 grid points see the Earth", field="grid")
    vectors = model.object_vector_gcrf(row, col)
    if noise > 0.0:
        rng = np.random.default_rng(seed)
        row = row + rng.normal(0.0, noise, row.size)
        col = col + rng.normal(0.0, noise, col.size)
    return VirtualControlPoints(row, col, lon, lat, h, vectors, (axis.size, axis.size), noise)


def check_grid(model, *, step_px: float = 100.0, start_px: float = 0.0, stop_px: float | None = None,
               height_m: float = 0.0) -> VirtualControlPoints:
    """Independent check points: the VCP grid offset by half a step (never used in a fit).

    Parameters
    ----------
    model : GeoStaringModel
        The TRUE model (localizes the grid).
    step_px, start_px, stop_px : float
        Grid of :func:`virtual_control_points`, pixels (shifted by ``step_px / 2``).
    height_m : float
        Ground height above the ellipsoid, metres.

    Returns
    -------
    VirtualControlPoints
        Ground check points.
    """
    n = min(model.image_shape)
    stop = float(n - 1) if stop_px is None else float(stop_px)
    return virtual_control_points(model, step_px=step_px, start_px=float(start_px) + 0.5 * float(step_px),
                                  stop_px=stop, height_m=height_m)


# --------------------------------------------------------------------------- accuracy
def positioning_errors(model, check: VirtualControlPoints) -> dict:
    """Positioning errors (seed 002 table 3) of ``model`` on true check points, pixels.

    The ground point of each check pixel (from the TRUE model) is projected by ``model``;
    ``error = projected - true pixel``; X is the column, Y the row.

    Parameters
    ----------
    model : GeoStaringModel
        Model to score.
    check : VirtualControlPoints
        Ground check points of the TRUE model.

    Returns
    -------
    dict
        ``mean_x_px, mean_y_px`` (signed), ``rms_x_px, rms_y_px``, ``total_px`` =
        ``sqrt(rms_x^2 + rms_y^2)``, ``max_px`` (largest vector length), ``n_points``, and
        the per-point arrays ``dx_px, dy_px`` (N,).
    """
    r, c = model.ground_to_image(check.lon, check.lat, check.h)
    dy, dx = r - check.row, c - check.col
    ok = np.isfinite(dx) & np.isfinite(dy)
    if not ok.any():
        return {"n_points": 0, "mean_x_px": math.nan, "mean_y_px": math.nan, "rms_x_px": math.nan,
                "rms_y_px": math.nan, "total_px": math.nan, "max_px": math.nan, "dx_px": dx, "dy_px": dy}
    rx, ry = float(np.sqrt(np.mean(dx[ok] ** 2))), float(np.sqrt(np.mean(dy[ok] ** 2)))
    return {
        "n_points": int(ok.sum()),
        "mean_x_px": float(np.mean(dx[ok])),
        "mean_y_px": float(np.mean(dy[ok])),
        "rms_x_px": rx,
        "rms_y_px": ry,
        "total_px": float(math.hypot(rx, ry)),
        "max_px": float(np.max(np.hypot(dx[ok], dy[ok]))),
        "dx_px": dx,
        "dy_px": dy,
    }


def pointing_difference_px(model, truth, row, col):
    """Body-frame pointing-angle difference ``model - truth`` (seed 002 figures 4-10), pixels.

    For each pixel the line of sight in the body frame ``R_inst R_ref (tan psi_x, tan psi_y,
    1)`` gives the two pointing angles ``atan(b_x / b_z)``, ``atan(b_y / b_z)``; the
    differences are divided by the truth's IFOV (one pixel = ``truth.ifov_rad`` radians).

    Parameters
    ----------
    model, truth : GeoStaringModel
        Compared models.
    row, col : array_like, shape (N,)
        Pixels, first pixel's centre at 0.5.

    Returns
    -------
    dx_px, dy_px : ndarray, shape (N,)
    """
    row = np.asarray(row, dtype=np.float64).reshape(-1)
    col = np.asarray(col, dtype=np.float64).reshape(-1)

    def angles(m):
        b = m.look_cam(row, col) @ m.generalized_installation.T
        return np.arctan2(b[:, 0], b[:, 2]), np.arctan2(b[:, 1], b[:, 2])

    mx, my = angles(model)
    tx, ty = angles(truth)
    return (mx - tx) / truth.ifov_rad, (my - ty) / truth.ifov_rad


# --------------------------------------------------------------------------- schemes
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


# --------------------------------------------------------------------------- the seed 002 study
def seed002_true_lab(base=None, image_shape=(10240, 10240)):
    """The TRUE laboratory camera: ``base`` (default GF-4-like) with seed 002 table 1 errors.

    See the module docstring for the mapping of table 1 onto :class:`StaringLab`.

    Parameters
    ----------
    base : StaringLab, optional
        Laboratory camera to perturb (default: the GF-4-like one).
    image_shape : (int, int)
        Frame shape (rows, cols).

    Returns
    -------
    StaringLab
        The TRUE laboratory parameters.
    """
    from sensor_models.models.synthetic import GF4_LIKE_CAMERA
    from sensor_models.models.staring_camera import StaringLab

    base = GF4_LIKE_CAMERA if base is None else base
    n_rows, n_cols = (int(x) for x in image_shape)
    t = SEED002_TABLE1
    return StaringLab(
        focal_length_mm=base.focal_length_mm + t["focal_length_df"][0],
        pixel_size_mm=base.pixel_size_mm,
        principal_point_px=(0.5 * n_rows + t["principal_point_dy"][0], 0.5 * n_cols + t["principal_point_dx"][0]),
        radial_k=(t["radial_k1"][0], 0.0),
        decentering_p=(t["eccentric_p1"][0], t["eccentric_p2"][0]),
        tilt_rad=(t["tilt_phi_x"][0] * ARCSEC, t["tilt_phi_y"][0] * ARCSEC),
        rotation_rad=t["rotation_beta"][0] * ARCSEC,
    )


@dataclass
class CompensationStudy:
    """Outcome of :func:`run_seed002`.

    Attributes
    ----------
    rows : list of dict
        One per case (``before`` then the schemes): ``scheme, description, success, message,
        mean_x_px, mean_y_px, rms_x_px, rms_y_px, total_px, max_px, seed_x_px, seed_y_px,
        seed_total_px, installation_arcsec (3), installation_error_arcsec (3), seconds,
        explanation``.
    truth, lab : GeoStaringModel
    models : dict of str to GeoStaringModel
        Compensated models by scheme.
    vcp, check : VirtualControlPoints
    pointing : dict of str to (dx_px, dy_px)
        Pointing-angle differences on the check grid per figure case.
    settings, timings : dict
    """

    rows: list
    truth: object
    lab: object
    models: dict
    vcp: VirtualControlPoints
    check: VirtualControlPoints
    pointing: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    best: str = ""

    def to_dict(self) -> dict:
        """JSON-safe summary of the study.

        Returns
        -------
        dict
            JSON-ready mapping (errors in pixels, angles in arcseconds).
        """
        from calibrate._json import json_safe

        return json_safe({
            "format": "gcpcal.compensation",
            "format_version": 1,
            "reference": "seed 002 (Xiao et al., Appl. Sci. 2023, 13, 9688), tables 1-3",
            "settings": self.settings,
            "best_scheme": self.best,
            "rows": self.rows,
            "timings": self.timings,
            "truth_lab_fit_residual_px": (self.truth.lab_fit_residual or {}).get("max_px"),
        })


def _row(name, description, errors, installation_rad, success=True, message="", seconds=0.0):
    seed = SEED002_TABLE3.get(name, (None, None, None))
    inst = np.asarray(installation_rad) / ARCSEC
    return {
        "scheme": name,
        "description": description,
        "success": bool(success),
        "message": message,
        **{k: v for k, v in errors.items() if not k.endswith("_px") or np.ndim(v) == 0},
        "seed_x_px": seed[0],
        "seed_y_px": seed[1],
        "seed_total_px": seed[2],
        "installation_arcsec": inst.tolist(),
        "installation_error_arcsec": (inst - np.asarray(SEED002_INSTALLATION_ARCSEC)).tolist(),
        "seconds": float(seconds),
        "explanation": EXPLANATIONS.get(name, ""),
    }


def run_seed002(*, step_px: float = 100.0, start_px: float = 0.0, stop_px: float | None = 10000.0,
                noise_px: float = 0.0, seed: int = 0, schemes=None, robust: str = "none",
                image_shape=(10240, 10240), models=None) -> CompensationStudy:
    """Seed 002's simulation (tables 1-3) on a GF-4-like staring camera.

    TRUE model: GF-4-like camera with the table 1 distortion and the table 2 installation
    errors (72, -72, 72 arcsec); LAB model: the distortion-free camera with zero installation.
    VCPs from the TRUE model on the image grid ``start_px .. stop_px`` every ``step_px``
    (seed 002: 0 .. 10 000 every 100 px), with optional Gaussian noise ``noise_px``; check grid
    offset by half a step. Also the figure 4 and 5 cases of section 3.1 (distortion alone,
    interior fit without installation error) as pointing-angle maps.

    Parameters
    ----------
    step_px, start_px, stop_px : float
        VCP grid (pixels); ``stop_px=None``: the frame's last pixel.
    noise_px : float
        Standard deviation of the Gaussian noise added to the VCP image coordinates, pixels.
    seed : int
        Of that noise.
    schemes : sequence of str, optional
        Keys of :data:`SCHEMES` (default: all).
    robust : {"none", "huber", "cauchy"}
        Loss of the fits.
    image_shape : (int, int)
        Frame shape (rows, cols).
    models : (StaringLab, GeoStaringModel, GeoStaringModel), optional
        ``(true_lab, truth, lab)`` to use instead of seed 002's (e.g. a TRUE model evaluating
        the physical lens, :mod:`sensor_models.simulate.staring_truth`); ``image_shape`` must
        be theirs. Default: :func:`seed002_true_lab` fitted by the cubic.

    Returns
    -------
    CompensationStudy
        The table rows (errors in pixels), models, VCPs, check points, pointing maps, settings
        and timings.
    """
    t_all = time.perf_counter()
    image_shape = tuple(int(x) for x in image_shape)
    stop = None if stop_px is None else min(float(stop_px), min(image_shape) - 1.0)
    true_lab, truth, lab = _seed002_models(image_shape) if models is None else models
    t0 = time.perf_counter()
    vcp = virtual_control_points(truth, step_px=step_px, start_px=start_px, stop_px=stop, noise_px=noise_px, seed=seed)
    check = check_grid(truth, step_px=step_px, start_px=start_px, stop_px=stop)
    t_vcp = time.perf_counter() - t0
    runs = compensate(lab, vcp, schemes=schemes, robust=robust)
    rows, pointing, models = _scheme_rows(lab, truth, check, runs)

    # section 3.1 (figures 4 and 5): the distortion alone, and the interior fitted to it
    truth0 = truth.with_parameters(np.concatenate([np.zeros(3), truth.parameters().values[3:]]))
    pointing["distortion"] = pointing_difference_px(lab, truth0, check.row, check.col)
    vcp0 = virtual_control_points(truth0, step_px=step_px, start_px=start_px, stop_px=stop, noise_px=noise_px,
                                  seed=seed)
    ico0 = compensate(lab, vcp0, schemes=["ICO"], robust=robust)["ICO"]["model"]
    pointing["interior_no_installation"] = pointing_difference_px(ico0, truth0, check.row, check.col)

    ok_rows = [r for r in rows[1:] if r["success"] and math.isfinite(r.get("total_px", math.nan))]
    best = min(ok_rows, key=lambda r: r["total_px"])["scheme"] if ok_rows else ""
    settings = {
        "image_shape": list(image_shape),
        "step_px": float(step_px), "start_px": float(start_px), "stop_px": stop,
        "noise_px": float(noise_px), "seed": int(seed), "robust": robust,
        "n_vcp": vcp.n_points, "n_check": check.n_points,
        **_seed002_truth_settings(true_lab, truth),
    }
    timings = {"vcp_s": t_vcp, "total_s": time.perf_counter() - t_all,
               "schemes_s": {k: v["seconds"] for k, v in runs.items()}}
    return CompensationStudy(rows, truth, lab, models, vcp, check, pointing, settings, timings, best)


def _seed002_models(image_shape):
    """Seed 002's TRUE lab camera, the TRUE model (table 1 distortion, table 2 installation) and the LAB model."""
    from sensor_models.models.synthetic import GF4_LIKE_CAMERA, example_geo_staring_model
    from sensor_models.models.pushbroom_types import Installation

    true_lab = seed002_true_lab(GF4_LIKE_CAMERA, image_shape)
    inst = Installation(*(a * ARCSEC for a in SEED002_INSTALLATION_ARCSEC))
    truth = example_geo_staring_model(camera=true_lab, image_shape=image_shape, installation=inst, name="truth")
    lab = example_geo_staring_model(camera=GF4_LIKE_CAMERA, image_shape=image_shape, name="lab")
    return true_lab, truth, lab


def _scheme_rows(lab, truth, check, runs):
    """Table rows (LAB first, then each scheme), pointing-difference maps and the fitted models."""
    rows = [_row("before", "LAB model, no compensation", positioning_errors(lab, check), lab.installation.as_array())]
    pointing = {"before": pointing_difference_px(lab, truth, check.row, check.col)}
    models = {}
    for name, run in runs.items():
        m = run["model"]
        models[name] = m
        res = run["result"]
        rows.append(_row(name, SCHEMES[name][1], positioning_errors(m, check), m.installation.as_array(),
                         res.success, res.message, run["seconds"]))
        pointing[name] = pointing_difference_px(m, truth, check.row, check.col)
    return rows, pointing, models


def _seed002_truth_settings(true_lab, truth) -> dict:
    """The TRUE camera and the seed 002 tables, as recorded in the study's settings."""
    return {
        "true_lab": {
            "focal_length_mm": true_lab.focal_length_mm, "pixel_size_mm": true_lab.pixel_size_mm,
            "principal_point_px": true_lab.principal_point_px, "radial_k": true_lab.radial_k,
            "decentering_p": true_lab.decentering_p, "tilt_rad": true_lab.tilt_rad,
            "rotation_rad": true_lab.rotation_rad,
        },
        "seed002_table1": {k: {"value": v, "unit": u} for k, (v, u) in SEED002_TABLE1.items()},
        "installation_error_arcsec": list(SEED002_INSTALLATION_ARCSEC),
        "ifov_arcsec": truth.ifov_rad / ARCSEC,
    }


# --------------------------------------------------------------------------- outputs
#: figure cases: key of CompensationStudy.pointing -> (file name, title; seed 002 figure)
FIGURES = {
    "distortion": ("fig04_distortion.png", "Distortion alone, no installation error (seed 002 fig. 4)"),
    "interior_no_installation": ("fig05_interior_fit.png", "After interior compensation, no installation error (fig. 5)"),
    "before": ("before.png", "Before compensation: LAB model"),
    "ICO": ("fig07_ico.png", "ICO: interior only (seed 002 fig. 7)"),
    "ECO": ("fig08_eco.png", "ECO: exterior only (seed 002 fig. 8)"),
    "ICBEC": ("fig09_icbec.png", "ICBEC: interior, then exterior (seed 002 fig. 9)"),
    "ECBIC": ("fig10_ecbic.png", "ECBIC: exterior, then interior (seed 002 fig. 10)"),
    "joint": ("joint.png", "joint: exterior + interior, gauge held"),
    "ICO-g": ("ico_gauge.png", "ICO-g: gauge-held interior only"),
}
CSV_COLUMNS = ("scheme", "success", "mean_x_px", "mean_y_px", "rms_x_px", "rms_y_px", "total_px", "max_px",
               "seed_x_px", "seed_y_px", "seed_total_px", "roll_arcsec", "pitch_arcsec", "yaw_arcsec", "seconds")


def _figure(study: CompensationStudy, key: str, path) -> None:
    """Two colour maps (X, Y pointing-angle difference in pixels) over the check grid."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dx, dy = study.pointing[key]
    k = study.check.grid_shape[0]
    n_rows, n_cols = study.truth.image_shape
    fig = Figure(figsize=(12.0, 4.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    fig.subplots_adjust(left=0.06, right=0.97, wspace=0.35)
    extent = (study.check.col.min(), study.check.col.max(), study.check.row.max(), study.check.row.min())
    for ax, values, label in zip(axes, (dx, dy), ("X (column)", "Y (row)")):
        grid = values.reshape(k, k) if values.size == k * k else values
        lim = float(np.nanmax(np.abs(values))) if np.any(np.isfinite(values)) else 1.0
        lim = lim if lim > 0.0 else 1.0
        im = ax.imshow(np.atleast_2d(grid), extent=extent, cmap="RdBu_r", aspect="equal",
                       interpolation="nearest", vmin=-lim, vmax=lim)
        ax.set_title(f"pointing-angle difference {label}")
        ax.set_xlabel("column (px)")
        ax.set_ylabel("row (px)")
        ax.set_xlim(0, n_cols)
        ax.set_ylim(n_rows, 0)
        fig.colorbar(im, ax=ax, label="pixels (x IFOV = angle)")
    fig.suptitle(FIGURES[key][1])
    fig.savefig(path, format="png")


def _fmt(v, digits=4):
    if v is None:
        return ""
    if isinstance(v, float):
        if not math.isfinite(v):
            return "nan"
        return f"{v:.{digits}g}" if abs(v) >= 1e-3 or v == 0.0 else f"{v:.2e}"
    return str(v)


def _csv_rows(rows):
    out = [",".join(CSV_COLUMNS)]
    for r in rows:
        inst = r["installation_arcsec"]
        vals = {**r, "roll_arcsec": inst[0], "pitch_arcsec": inst[1], "yaw_arcsec": inst[2]}
        out.append(",".join("" if vals.get(c) is None else repr(vals[c]) if isinstance(vals[c], float)
                            else str(vals[c]) for c in CSV_COLUMNS))
    return "\n".join(out) + "\n"


def summary_markdown(study: CompensationStudy) -> str:
    """Markdown table (ours beside seed 002 table 3) with the reason for each scheme's result.

    Parameters
    ----------
    study : CompensationStudy
        Of :func:`run_seed002`.

    Returns
    -------
    str
        Markdown text.
    """
    s = study.settings
    lines = [
        "# Seed 002 compensation schemes on a GF-4-like staring camera",
        "",
        f"Array {s['image_shape'][0]} x {s['image_shape'][1]} px (IFOV {s['ifov_arcsec']:.3f} arcsec), "
        f"{s['n_vcp']} virtual control points every {s['step_px']:g} px from {s['start_px']:g} to "
        f"{s['stop_px']:g}, noise {s['noise_px']:g} px; {s['n_check']} check points offset by half a step. "
        f"Installation error {s['installation_error_arcsec']} arcsec (table 2), distortion of table 1.",
        "",
        "| scheme | X mean px | Y mean px | RMS X px | RMS Y px | total px | max px | seed X | seed Y | "
        "seed total | roll, pitch, yaw (arcsec) | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in study.rows:
        inst = ", ".join(f"{a:.2f}" for a in r["installation_arcsec"])
        lines.append("| " + " | ".join([
            r["scheme"], _fmt(r["mean_x_px"]), _fmt(r["mean_y_px"]), _fmt(r["rms_x_px"]), _fmt(r["rms_y_px"]),
            _fmt(r["total_px"]), _fmt(r["max_px"]), _fmt(r["seed_x_px"]), _fmt(r["seed_y_px"]),
            _fmt(r["seed_total_px"]), inst, f"{r['seconds']:.2f}"]) + " |")
    lines += ["", f"Best scheme: **{study.best}**.", "", "## Why the schemes rank as they do", ""]
    for r in study.rows:
        lines.append(f"- **{r['scheme']}**: {r['explanation']}")
    lines += ["", "## Figures (pointing-angle differences, compensated minus true, body frame)", ""]
    for key, (name, title) in FIGURES.items():
        if key in study.pointing:
            lines.append(f"- [{title}](figures/{name})")
    return "\n".join(lines) + "\n"


def write_study(study: CompensationStudy, out_dir, *, figures: bool = True) -> dict:
    """Write ``table.json``, ``table.csv``, ``summary.md`` and ``figures/*.png`` atomically.

    Everything is built in a temporary folder beside ``out_dir`` and moved into place with
    :func:`os.replace` (an existing ``out_dir`` is replaced as a whole), so a failure leaves
    the previous outputs and no partial folder.

    Parameters
    ----------
    study : CompensationStudy
        Of :func:`run_seed002`.
    out_dir : path
        Output folder (replaced as a whole).
    figures : bool
        Also draw the PNG figures.

    Returns
    -------
    dict
        The ``table.json`` document.
    """
    import json
    import os
    import shutil
    import tempfile
    from pathlib import Path

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a folder", path=str(out_dir))
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    old = None
    try:
        t0 = time.perf_counter()
        doc = study.to_dict()
        names = {}
        if figures:
            (tmp / "figures").mkdir()
            for key, (name, _title) in FIGURES.items():
                if key in study.pointing:
                    _figure(study, key, tmp / "figures" / name)
                    names[key] = f"figures/{name}"
        doc["figures"] = names
        doc["timings"]["figures_s"] = time.perf_counter() - t0
        (tmp / "table.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        (tmp / "table.csv").write_text(_csv_rows(study.rows), encoding="utf-8")
        (tmp / "summary.md").write_text(summary_markdown(study), encoding="utf-8")
        os.chmod(tmp, 0o755)
        if out_dir.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old.", dir=out_dir.parent))
            os.replace(out_dir, old / "previous")
        os.replace(tmp, out_dir)
    except BaseException:
        if old is not None and (old / "previous").exists() and not out_dir.exists():
            os.replace(old / "previous", out_dir)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return doc
