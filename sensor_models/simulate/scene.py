"""Build the TRUE and the LAB push-broom models of a simulated scene from a configuration.

The camera is seed 003's kind: ``n_cameras`` cameras of ``ccds_per_camera`` linear CCDs each,
all bands on every CCD, stitched across track into one raster per band. Both models come from a
physical lab camera (:mod:`sensor_models.models.lab`):

* LAB (what a user receives, written in the manifest): the design focal length, CCD positions
  and band offsets, no distortion, zero installation angles, the measured attitude (nominal
  Earth pointing plus star-tracker noise, 4 Hz) and the measured orbit (GNSS noise).
* TRUE (what renders the image): focal length, principal point, radial and decentering
  distortion, CCD and band-offset errors; camera 2 rotated against camera 1; installation
  errors; the true orbit; attitude bias, drift and jitter sampled at 20 Hz; a thermal drift of
  the installation folded into the attitude (``R_body->orbital(t) dR_thermal(t)``, exactly
  equivalent to a time-varying installation). Its directional angles are degree-7 fits of the
  physical model (fit residual reported, < 1e-4 px).

The two cameras share one model (one installation); camera 2's relative rotation is therefore
an interior error of its CCDs, which the per-CCD interior calibration absorbs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as P
from scipy.spatial.transform import Rotation

from sensor_models.geometry.ephemeris import Attitude, Orbit
from sensor_models.models.lab import LabBand, LabCamera, LabCcd, detector_angles
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.models.pushbroom_types import CcdLook, Installation, LineTiming, rot_x, rot_y, rot_z
from sensor_models.simulate.config import SimConfig
from sensor_models.models.synthetic import GM_EARTH_M3_S2, circular_orbit

__all__ = ["SceneModels", "build_models"]

ARCSEC = np.pi / (180.0 * 3600.0)
TRUE_DEGREE = 7


@dataclass
class SceneModels:
    """The TRUE and LAB models of a simulated scene and what differs between them."""

    true_model: PushbroomModel
    lab_model: PushbroomModel
    true_camera: LabCamera
    lab_camera: LabCamera
    camera_of_ccd: tuple[int, ...]
    truth: dict  # JSON-safe record of the true parameters


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), *key]))


def ccd_layout(cfg: SimConfig):
    """Names, first raster columns and nominal across-track focal-plane positions of the CCDs.

    Parameters
    ----------
    cfg : SimConfig
        The simulation configuration.

    Returns
    -------
    list of (str, int, int, float)
        Per CCD: name ``"cam<i>_ccd<j>"``, first raster column, camera index (0-based) and the
        across-track position of its detector 0 relative to the array centre, in pixels.
    """
    c = cfg.camera
    n_ccd = c.n_cameras * c.ccds_per_camera
    step = c.detectors_per_ccd - c.overlap_detectors
    total = step * (n_ccd - 1) + c.detectors_per_ccd
    out = []
    for k in range(n_ccd):
        cam, j = divmod(k, c.ccds_per_camera)
        name = f"cam{cam + 1}_ccd{j + 1}"
        y_px = k * step - 0.5 * (total - 1)  # detector 0's across-track position
        out.append((name, k * c.detectors_per_ccd, cam, y_px))
    return out


def lab_camera(cfg: SimConfig) -> LabCamera:
    """The design (laboratory) camera: no distortion, CCDs where the drawing puts them.

    Parameters
    ----------
    cfg : SimConfig
        The simulation configuration.

    Returns
    -------
    LabCamera
        Focal length ``pixel_size_mm * altitude_m / gsd_m`` (mm), CCDs of
        :func:`ccd_layout`, along-track boresight offset and band offsets in mm.
    """
    c, s = cfg.camera, cfg.scene
    p = c.pixel_size_mm
    f = p * s.altitude_m / s.gsd_m
    x0 = f * np.tan(np.radians(c.boresight_offset_deg))
    ccds = tuple(LabCcd(n, col, c.detectors_per_ccd, x0, y_px * p) for n, col, _, y_px in ccd_layout(cfg))
    bands = tuple(LabBand(b, ccds, (off * p, 0.0)) for b, off in zip(c.bands, c.band_offsets_px))
    return LabCamera(focal_length_mm=f, pixel_size_mm=p, bands=bands, polynomial_degree=c.lab_polynomial_degree)


def true_camera(cfg: SimConfig, lab: LabCamera, *, lens=None) -> LabCamera:
    """The camera as it really is in orbit (errors of ``cfg.errors``, random parts seeded).

    Parameters
    ----------
    cfg : SimConfig
        The configuration (its ``errors`` and ``seed``).
    lab : LabCamera
        The design camera (:func:`lab_camera`).
    lens : LensExtras, optional
        Lens terms beyond the cubic (:mod:`sensor_models.simulate.true_lens`); its ``k2_px`` and
        ``k3_px`` become ``radial_k[1:]``. None: ``k2 = k3 = 0``.

    Returns
    -------
    LabCamera
        With focal-length ratio, principal point, radial and decentering distortion, random
        CCD shifts and band-offset errors; fitted at degree ``TRUE_DEGREE``.
    """
    e, p = cfg.errors, cfg.camera.pixel_size_mm
    rng = _rng(cfg.seed, 1)
    layout = ccd_layout(cfg)
    half_mm = 0.5 * (layout[-1][3] - layout[0][3] + cfg.camera.detectors_per_ccd) * p
    # radial: displacement y k1 r^2 = radial_distortion_px * p at the array end
    k1 = e.radial_distortion_px * p / half_mm**3
    k2 = 0.0 if lens is None else lens.k2_px * p / half_mm**5
    k3 = 0.0 if lens is None else lens.k3_px * p / half_mm**7
    # decentering: p2 (r^2 + 2 y^2) ~ 3 p2 y^2 across track, p1 r^2 along track at the end
    p1 = e.decentering_px[0] * p / half_mm**2
    p2 = e.decentering_px[1] * p / (3.0 * half_mm**2)
    shifts = rng.normal(0.0, e.ccd_shift_px * p, (len(layout), 2))
    ccds = tuple(
        LabCcd(c.name, c.first_col, c.n_detectors, c.x_mm + dx, c.y_mm + dy)
        for c, (dx, dy) in zip(lab.bands[0].ccds, shifts)
    )
    band_err = rng.normal(0.0, e.band_offset_error_px * p, len(lab.bands))
    bands = tuple(LabBand(b.name, ccds, (b.offset_mm[0] + d, b.offset_mm[1])) for b, d in zip(lab.bands, band_err))
    return LabCamera(
        focal_length_mm=lab.focal_length_mm * e.focal_length_ratio,
        pixel_size_mm=p,
        bands=bands,
        principal_point_mm=(e.principal_point_px[0] * p, e.principal_point_px[1] * p),
        radial_k=(k1, k2, k3),
        decentering_p=(p1, p2),
        polynomial_degree=TRUE_DEGREE,
    )


def _camera_rotation(angles_rad) -> np.ndarray:
    roll, pitch, yaw = angles_rad
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def true_looks(camera: LabCamera, camera_of_ccd, camera2_rotation_rad, *, extra_tan_x=None):
    """Directional angles of the true camera, camera 2 (and beyond) rotated, degree-7 fits.

    Parameters
    ----------
    camera : LabCamera
        The true camera (:func:`true_camera`).
    camera_of_ccd : sequence of int
        Camera index of every CCD (0: first camera, unrotated).
    camera2_rotation_rad : (float, float, float)
        Roll, pitch, yaw of the second camera relative to the first, radians.
    extra_tan_x : callable, optional
        ``extra_tan_x(ccd_index, s) -> d tan psi_x`` added before the fit (focal-plane curvature,
        CCD bending: :meth:`sensor_models.simulate.true_lens.LensExtras.smooth_tan`).

    Returns
    -------
    bands : dict of str to tuple of CcdLook
        Degree-``TRUE_DEGREE`` polynomials per band and CCD.
    residual_rad : float
        Largest fit residual of ``tan psi`` over all detectors.
    """
    rots = [np.eye(3), _camera_rotation(camera2_rotation_rad)]
    bands, worst = {}, 0.0
    for band in camera.bands:
        looks = []
        for k, ccd in enumerate(band.ccds):
            s = np.arange(ccd.n_detectors, dtype=np.float64)
            tx, ty = detector_angles(camera, band, ccd, s)
            v = np.stack([tx, ty, np.ones_like(tx)], axis=-1) @ rots[min(camera_of_ccd[k], 1)].T
            tx, ty = v[:, 0] / v[:, 2], v[:, 1] / v[:, 2]
            if extra_tan_x is not None:
                tx = tx + extra_tan_x(k, s)
            half = max(1.0, 0.5 * (ccd.n_detectors - 1))
            scale = half ** np.arange(TRUE_DEGREE + 1)
            cx = P.polyfit(s / half, tx, TRUE_DEGREE) / scale
            cy = P.polyfit(s / half, ty, TRUE_DEGREE) / scale
            worst = max(worst, np.abs(P.polyval(s, cx) - tx).max(), np.abs(P.polyval(s, cy) - ty).max())
            looks.append(CcdLook(ccd.name, ccd.first_col, ccd.n_detectors, cx, cy))
        bands[band.name] = tuple(looks)
    return bands, worst


def lab_looks(camera: LabCamera):
    """Directional angles of the lab camera (:func:`sensor_models.models.lab.lab_to_directional_angles`).

    Parameters
    ----------
    camera : LabCamera
        The design camera.

    Returns
    -------
    bands : dict of str to tuple of CcdLook
    residual_rad : float
        Largest fit residual of ``tan psi`` over all CCDs and bands.
    """
    from sensor_models.models.lab import lab_to_directional_angles

    bands, residual = lab_to_directional_angles(camera)
    return bands, max(residual.values())


def _line_period(cfg: SimConfig) -> float:
    a = 6_378_137.0 + cfg.scene.altitude_m
    ground_speed = np.sqrt(GM_EARTH_M3_S2 / a) * 6_378_137.0 / a
    return cfg.scene.gsd_m / ground_speed


def _attitude_quaternions(seconds, angles_rad):
    """Body -> orbital quaternions of roll, pitch, yaw angle series (N, 3): Rz Ry Rx."""
    return Rotation.from_euler("ZYX", angles_rad[:, ::-1]).as_quat()


def _true_attitude(cfg: SimConfig, seconds, jitter=None) -> tuple[Attitude, dict]:
    e = cfg.errors
    rng = _rng(cfg.pass_seed, 2)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    t = seconds[:, None]
    angles = (
        np.asarray(e.attitude_bias_arcsec) * ARCSEC
        + np.asarray(e.attitude_drift_arcsec_s) * ARCSEC * t
        + np.asarray(e.jitter_amplitude_urad) * 1e-6 * np.sin(2 * np.pi * e.jitter_frequency_hz * t + phase)
    )
    info = {"jitter_phase_rad": phase.tolist()}
    if jitter is not None:  # broadband jitter (realistic): a second line and a coloured floor
        from sensor_models.simulate.jitter import jitter_angles

        extra, info["jitter_spectrum"] = jitter_angles(jitter, seconds, cfg.pass_seed)
        angles = angles + extra
    r_att = Rotation.from_euler("ZYX", angles[:, ::-1])
    thermal = np.asarray(e.thermal_drift_arcsec_s) * ARCSEC * t
    r_thermal = Rotation.from_euler("ZYX", thermal[:, ::-1])
    quat = (r_att * r_thermal).as_quat()
    return Attitude(seconds, quat, frame="orbital"), info


def _measured_attitude(cfg: SimConfig, seconds) -> Attitude:
    rng = _rng(cfg.pass_seed, 3)
    angles = rng.normal(0.0, cfg.errors.attitude_noise_urad * 1e-6, (seconds.size, 3))
    return Attitude(seconds, _attitude_quaternions(seconds, angles), frame="orbital")


def smooth_orbit_error(seconds, sigma_m: float, min_period_s: float, rng) -> tuple:
    """A smooth orbit-determination error and its rate: per axis three sinusoids of periods drawn
    in ``[P, 5 P]`` with random phases, ``sigma_m`` rms in all.

    Precise orbit determination leaves errors that vary over a good part of an orbit
    (once-per-revolution terms), not from one 1 s sample to the next; white noise on the samples
    would turn into metres per second of velocity error between them through the interpolant.

    Parameters
    ----------
    seconds : ndarray, shape (N,)
        Sample times, s.
    sigma_m : float
        Rms of the error per axis, metres.
    min_period_s : float
        Shortest period ``P``, seconds.
    rng : numpy.random.Generator

    Returns
    -------
    error_m, rate_m_s : ndarray, shape (N, 3)
    """
    t = np.asarray(seconds, dtype=np.float64)[:, None, None]
    period = rng.uniform(1.0, 5.0, (1, 3, 3)) * float(min_period_s)
    phase = rng.uniform(0.0, 2.0 * np.pi, (1, 3, 3))
    amplitude = float(sigma_m) * np.sqrt(2.0 / 3.0)  # three sinusoids of rms a / sqrt(2) each
    w = 2.0 * np.pi / period
    return (amplitude * np.sin(w * t + phase)).sum(axis=1), (amplitude * w * np.cos(w * t + phase)).sum(axis=1)


def _measured_orbit(cfg: SimConfig, orbit: Orbit, bias_m: float = 0.0) -> Orbit:
    rng = _rng(cfg.pass_seed, 4)
    sigma = cfg.errors.orbit_noise_m
    if cfg.errors.orbit_noise_period_s > 0:
        error, rate = smooth_orbit_error(orbit.seconds, sigma, cfg.errors.orbit_noise_period_s, rng)
        pos, vel = orbit.position_m + error, orbit.velocity_m_s + rate
    else:  # white per sample (the ideal profile's)
        pos = orbit.position_m + rng.normal(0.0, sigma, orbit.position_m.shape)
        vel = None
    if bias_m > 0:  # a constant offset of the navigation solution, direction from the pass seed
        direction = _rng(cfg.pass_seed, 7).normal(size=3)
        pos = pos + bias_m * direction / np.linalg.norm(direction)
    if vel is None:
        vel = orbit.velocity_m_s + rng.normal(0.0, sigma * 1e-3, orbit.velocity_m_s.shape)
    return Orbit(orbit.epoch, orbit.seconds, pos, vel, frame=orbit.frame)


def build_models(cfg: SimConfig, *, lens=None, orbit_bias_m: float = 0.0, jitter=None) -> SceneModels:
    """TRUE and LAB models of the configured scene, centred on ``scene.center_lon/lat_deg``.

    Parameters
    ----------
    cfg : SimConfig
        The simulation configuration.
    lens : LensExtras, optional
        TRUE lens terms beyond the cubic (``realistic`` profile); None: none.
    orbit_bias_m : float
        Norm of a constant offset of the measured orbit, metres (0: none).
    jitter : JitterSpectrum, optional
        Broadband jitter added to the TRUE attitude (:mod:`sensor_models.simulate.jitter`);
        None: the configuration's single sinusoid per axis only.

    Returns
    -------
    SceneModels
        The TRUE model (true camera, true attitude), the LAB model a user receives (design
        camera, noisy orbit and attitude) and a JSON-safe record of the true parameters.
    """
    s, e = cfg.scene, cfg.errors
    lab = lab_camera(cfg)
    tru = true_camera(cfg, lab, lens=lens)
    layout = ccd_layout(cfg)
    camera_of_ccd = tuple(cam for _, _, cam, _ in layout)
    lab_bands, lab_residual = lab_looks(lab)
    true_bands, true_residual = true_looks(tru, camera_of_ccd, np.asarray(e.camera2_rotation_arcsec) * ARCSEC,
                                           extra_tan_x=_lens_sag(cfg, tru, layout, lens))
    line_period = _line_period(cfg)
    duration = s.n_rows * line_period
    t_orbit = np.arange(-20.0, duration + 20.0, 1.0)
    t_true_att = np.arange(-20.0, duration + 20.0, 0.05)
    t_meas_att = np.arange(-20.0, duration + 20.0, 0.25)
    epoch = np.datetime64(s.epoch_utc, "ns")
    timing = LineTiming(0.5, 0.0, line_period)
    inst_true = Installation(*np.radians(e.installation_deg))

    def model(orbit, attitude, bands, installation, name):
        return PushbroomModel(orbit=orbit, attitude=attitude, line_timing=timing, bands=bands,
                              installation=installation, n_rows=s.n_rows,
                              reference_band=cfg.camera.reference_band, name=name)

    # place the nominal scene centre on the requested point (three fixed-point passes)
    inc = np.radians(s.inclination_deg)
    raan, arg_lat = s.center_lon_deg, s.center_lat_deg / np.sin(inc)
    nominal_att = Attitude(t_meas_att, np.tile([0.0, 0.0, 0.0, 1.0], (t_meas_att.size, 1)), frame="orbital")
    for _ in range(4):
        orbit = circular_orbit(epoch, t_orbit, altitude_m=s.altitude_m, inclination_deg=s.inclination_deg,
                               raan_deg=raan, argument_of_latitude_deg=arg_lat)
        m = model(orbit, nominal_att, lab_bands, Installation(), "nominal")
        lon, lat, _ = m.image_to_ground([s.n_rows / 2], [m.n_cols / 2], height=0.0)
        raan += s.center_lon_deg - float(lon[0])
        arg_lat += (s.center_lat_deg - float(lat[0])) / np.sin(inc)
    orbit = circular_orbit(epoch, t_orbit, altitude_m=s.altitude_m, inclination_deg=s.inclination_deg,
                           raan_deg=raan, argument_of_latitude_deg=arg_lat)
    true_att, att_info = _true_attitude(cfg, t_true_att, jitter)
    true_model = model(orbit, true_att, true_bands, inst_true, "truth")
    lab_model = model(_measured_orbit(cfg, orbit, orbit_bias_m), _measured_attitude(cfg, t_meas_att), lab_bands,
                      Installation(), "simulated")
    ifov = s.gsd_m / s.altitude_m
    truth = {
        "installation_rad": {"roll": inst_true.roll, "pitch": inst_true.pitch, "yaw": inst_true.yaw},
        "installation_lab_rad": {"roll": 0.0, "pitch": 0.0, "yaw": 0.0},
        "attitude_bias_arcsec": list(e.attitude_bias_arcsec),
        "attitude_drift_arcsec_s": list(e.attitude_drift_arcsec_s),
        "jitter_amplitude_urad": list(e.jitter_amplitude_urad),
        "jitter_frequency_hz": e.jitter_frequency_hz,
        "thermal_drift_arcsec_s": list(e.thermal_drift_arcsec_s),
        "camera2_rotation_arcsec": list(e.camera2_rotation_arcsec),
        "camera_of_ccd": {name: cam + 1 for name, _, cam, _ in layout},
        "lab_camera": _camera_dict(lab),
        "true_camera": _camera_dict(tru),
        "true_interior_fit_residual_px": true_residual / ifov,
        "lab_interior_fit_residual_px": lab_residual / ifov,
        "line_period_s": line_period,
        "orbit": {"raan_deg": raan, "argument_of_latitude_deg": arg_lat, "altitude_m": s.altitude_m,
                  "inclination_deg": s.inclination_deg},
        **att_info,
    }
    return SceneModels(true_model, lab_model, tru, lab, camera_of_ccd, truth)


def _lens_sag(cfg: SimConfig, camera: LabCamera, layout, lens):
    """``extra_tan_x(ccd_index, s)`` of the lens's curvature and bending (None without them)."""
    if lens is None or (lens.curvature_px == 0 and lens.bending_px == 0):
        return None
    n = cfg.camera.detectors_per_ccd
    half = 0.5 * (layout[-1][3] - layout[0][3] + n)  # layout positions are from the array centre
    ifov = camera.pixel_size_mm / camera.focal_length_mm
    return lambda k, s: lens.smooth_tan(layout[k][3] + s, s, n, half, ifov)


def _camera_dict(cam: LabCamera) -> dict:
    return {
        "focal_length_mm": cam.focal_length_mm,
        "pixel_size_mm": cam.pixel_size_mm,
        "principal_point_mm": list(cam.principal_point_mm),
        "radial_k": list(cam.radial_k),
        "decentering_p": list(cam.decentering_p),
        "tilt_rad": cam.tilt_rad,
        "rotation_rad": cam.rotation_rad,
        "bands": {
            b.name: {
                "offset_mm": list(b.offset_mm),
                "ccds": [{"name": c.name, "first_col": c.first_col, "n_detectors": c.n_detectors,
                          "x_mm": c.x_mm, "y_mm": c.y_mm} for c in b.ccds],
            }
            for b in cam.bands
        },
    }
