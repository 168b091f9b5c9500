"""Synthetic orbits, attitudes, push-broom and staring cameras with known geometry.

The building blocks of the scene simulator and of the tests: a circular Keplerian orbit in GCRF,
Earth-pointing attitude in the orbital frame with bias, drift and jitter, an HY-1C-like
multi-CCD, multi-band directional-angle camera (seed 003 section 1, scaled by ``scale``), and a
geostationary orbit with seed 000's (or a GF-4-like) staring camera
(:func:`example_geo_staring_model`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.errors import InputError
from sensor_models.geometry.ephemeris import Attitude, Orbit
from sensor_models.models.geo_staring import GeoStaringModel
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.models.pushbroom_types import CcdLook, Installation, LineTiming
from sensor_models.models.staring_camera import PointingMirror, StaringLab

__all__ = [
    "GEO_RADIUS_M",
    "GF4_LIKE_CAMERA",
    "GF4_LIKE_SHAPE",
    "GM_EARTH_M3_S2",
    "SEED000_CAMERA",
    "SEED000_SHAPE",
    "CameraDesign",
    "circular_orbit",
    "earth_pointing_attitude",
    "example_geo_staring_model",
    "example_pushbroom_model",
    "geostationary_orbit",
    "hy1c_like_bands",
]

#: WGS84 / EGM96 geocentric gravitational constant
GM_EARTH_M3_S2 = 3.986004418e14


def circular_orbit(
    epoch,
    seconds,
    *,
    altitude_m: float = 782_121.0,
    inclination_deg: float = 98.5,
    raan_deg: float = 0.0,
    argument_of_latitude_deg: float = 0.0,
) -> Orbit:
    """Circular Keplerian orbit sampled in GCRF.

    ``r(t) = a (cos u, sin u, 0)`` rotated by the inclination about X and the right ascension of
    the ascending node about Z, with ``u = u0 + n t`` and ``n = sqrt(GM / a^3)``.

    Parameters
    ----------
    epoch : numpy.datetime64 or str
        UTC epoch of the sample times.
    seconds : array_like, shape (N,)
        Sample times, SI seconds since ``epoch`` (strictly increasing).
    altitude_m : float
        Height of the circle above the equatorial radius (6 378 137 m), metres.
    inclination_deg, raan_deg, argument_of_latitude_deg : float
        Inclination, right ascension of the ascending node and argument of latitude at
        ``t = 0``, degrees.

    Returns
    -------
    Orbit
        Frame ``"gcrf"``; positions in metres, velocities in m/s, shape (N, 3).
    """
    t = np.asarray(seconds, dtype=np.float64)
    a = 6_378_137.0 + altitude_m
    n = np.sqrt(GM_EARTH_M3_S2 / a**3)
    u = np.radians(argument_of_latitude_deg) + n * t
    inc, raan = np.radians(inclination_deg), np.radians(raan_deg)
    rot = Rotation.from_euler("ZX", [raan, inc]).as_matrix()  # R3(raan) @ R1(inc)
    plane_pos = np.stack([np.cos(u), np.sin(u), np.zeros_like(u)], axis=-1) * a
    plane_vel = np.stack([-np.sin(u), np.cos(u), np.zeros_like(u)], axis=-1) * (a * n)
    return Orbit(epoch, t, plane_pos @ rot.T, plane_vel @ rot.T, frame="gcrf")


def earth_pointing_attitude(
    seconds,
    *,
    bias_rad=(0.0, 0.0, 0.0),
    drift_rad_s=(0.0, 0.0, 0.0),
    jitter_amplitude_rad=(0.0, 0.0, 0.0),
    jitter_frequency_hz: float = 0.0,
    noise_rad: float = 0.0,
    seed: int | None = None,
) -> Attitude:
    """Body -> orbital-frame attitude: roll, pitch, yaw about X, Y, Z, small-angle errors.

    Angles ``a(t) = bias + drift t + A sin(2 pi f t + phase) + noise``; the rotation is
    ``Rz(yaw) Ry(pitch) Rx(roll)`` (same composition as :class:`Installation`).

    Parameters
    ----------
    seconds : array_like, shape (N,)
        Sample times, SI seconds since the scene epoch.
    bias_rad, drift_rad_s, jitter_amplitude_rad : (float, float, float)
        Roll, pitch, yaw bias (rad), drift (rad/s) and jitter amplitude (rad).
    jitter_frequency_hz : float
        Jitter frequency; the three phases are drawn from ``seed``.
    noise_rad : float
        Standard deviation of white noise added per sample, radians.
    seed : int, optional
        Seed of ``numpy.random.default_rng`` (phases and noise).

    Returns
    -------
    Attitude
        Frame ``"orbital"``, quaternions scalar-last, shape (N, 4).
    """
    t = np.asarray(seconds, dtype=np.float64)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    angles = (
        np.asarray(bias_rad)[None, :]
        + np.asarray(drift_rad_s)[None, :] * t[:, None]
        + np.asarray(jitter_amplitude_rad)[None, :]
        * np.sin(2.0 * np.pi * jitter_frequency_hz * t[:, None] + phase[None, :])
    )
    if noise_rad > 0.0:
        angles = angles + rng.normal(0.0, noise_rad, angles.shape)
    # Rz(yaw) Ry(pitch) Rx(roll) == intrinsic "ZYX" with (yaw, pitch, roll)
    quat = Rotation.from_euler("ZYX", angles[:, ::-1]).as_quat()
    return Attitude(t, quat, frame="orbital")


@dataclass(frozen=True)
class CameraDesign:
    """Geometry of a multi-CCD push-broom camera in directional-angle form.

    Attributes
    ----------
    n_ccds, detectors_per_ccd : int
    ifov_rad : float
        Instantaneous field of view of one detector.
    boresight_offset_rad : float
        Along-track look offset (seed 003: 0.12 degrees between optical and view axes).
    ccd_overlap_detectors : int
        Detectors shared (in look) by neighbouring CCDs.
    band_offsets_px : tuple of float
        Along-track focal-plane offset of each band, in detectors.
    distortion_px : float
        Amplitude of the cubic across-track distortion at the CCD ends, in pixels.
    """

    n_ccds: int = 2
    detectors_per_ccd: int = 1024
    ifov_rad: float = 50.0 / 782_121.0
    boresight_offset_rad: float = np.radians(0.12)
    ccd_overlap_detectors: int = 16
    band_names: tuple[str, ...] = ("B1", "B2", "B3", "B4")
    band_offsets_px: tuple[float, ...] = (-6.0, -2.0, 2.0, 6.0)
    distortion_px: float = 3.0


def hy1c_like_bands(design: CameraDesign = CameraDesign()) -> dict[str, tuple[CcdLook, ...]]:
    """Directional-angle polynomials of every CCD and band of a design (cubic in ``s``).

    Parameters
    ----------
    design : CameraDesign
        CCD count and size, IFOV, boresight and band offsets, distortion.

    Returns
    -------
    dict of str to tuple of CcdLook
        Band name -> CCDs; CCD ``k`` starts at raster column ``k * detectors_per_ccd``.
    """
    n = design.detectors_per_ccd
    step = n - design.ccd_overlap_detectors
    total = step * (design.n_ccds - 1) + n
    bands = {}
    for b, (name, offset) in enumerate(zip(design.band_names, design.band_offsets_px)):
        ccds = []
        for k in range(design.n_ccds):
            # across-track look of detector s: centred on the whole array, plus a cubic distortion
            s0 = k * step - 0.5 * (total - 1)
            u = np.array([s0, 1.0, 0.0, 0.0])  # detector position relative to the array centre
            half = 0.5 * (total - 1)
            d = design.distortion_px * design.ifov_rad / half**3
            # tan psi_y(s) = ifov (s + s0) + d (s + s0)^3 ; expand the cube
            cub = np.array([s0**3, 3 * s0**2, 3 * s0, 1.0]) * d
            tan_y = design.ifov_rad * u + cub
            # along track: boresight offset, band offset, and a slight CCD tilt (0.5 px over CCD)
            tilt = (0.5 if k % 2 else -0.5) * design.ifov_rad / n
            tan_x = np.array([design.boresight_offset_rad + offset * design.ifov_rad, tilt, 0.0, 0.0])
            ccds.append(CcdLook(f"ccd{k + 1}", k * n, n, tan_x, tan_y))
        bands[name] = tuple(ccds)
    return bands


def example_pushbroom_model(
    *,
    n_rows: int = 2000,
    design: CameraDesign = CameraDesign(),
    epoch: str = "2023-06-15T03:00:00",
    installation: Installation = Installation(),
    attitude_kwargs: dict | None = None,
    center_lon_deg: float = 5.5,
    center_lat_deg: float = 44.5,
    name: str = "synthetic",
) -> PushbroomModel:
    """An HY-1C-like push-broom model with a GCRF orbit and orbital-frame attitude.

    The orbit's node and phase are chosen so that the image centre (at zero height) falls on
    ``(center_lon_deg, center_lat_deg)`` within a few hundred metres (default: the SRTM tile
    N44E005 under the Ventoux test data). Line period = ground sampling distance / ground speed,
    so pixels are roughly square. Ephemeris is sampled every 1 s and attitude every 0.25 s,
    covering the image plus 20 s on each side.

    Parameters
    ----------
    n_rows : int
        Image lines.
    design : CameraDesign
        Camera geometry (:func:`hy1c_like_bands`).
    epoch : str
        UTC scene epoch.
    installation : Installation
        Camera -> body angles, radians.
    attitude_kwargs : dict, optional
        Passed to :func:`earth_pointing_attitude` (bias, drift, jitter, noise, seed).
    center_lon_deg, center_lat_deg : float
        WGS84 position of the image centre at zero height, degrees.
    name : str
        Model name.

    Returns
    -------
    PushbroomModel
        Reference band: the second band of the design (the first if there is one).
    """
    kwargs = dict(n_rows=n_rows, design=design, epoch=epoch, installation=installation, attitude_kwargs=attitude_kwargs, name=name)
    raan, arg_lat = center_lon_deg, center_lat_deg / np.sin(np.radians(98.5))
    for _ in range(3):
        model = _example(raan_deg=raan, argument_of_latitude_deg=arg_lat, **kwargs)
        lon, lat, _ = model.image_to_ground([n_rows / 2], [model.n_cols / 2], height=0.0)
        raan += center_lon_deg - float(lon[0])
        arg_lat += (center_lat_deg - float(lat[0])) / np.sin(np.radians(98.5))
    return _example(raan_deg=raan, argument_of_latitude_deg=arg_lat, **kwargs)


def _example(*, n_rows, design, epoch, installation, attitude_kwargs, argument_of_latitude_deg, raan_deg, name):
    altitude = 782_121.0
    a = 6_378_137.0 + altitude
    ground_speed = np.sqrt(GM_EARTH_M3_S2 / a) * 6_378_137.0 / a
    line_period = design.ifov_rad * altitude / ground_speed
    duration = n_rows * line_period
    t_orbit = np.arange(-20.0, duration + 20.0, 1.0)
    t_att = np.arange(-20.0, duration + 20.0, 0.25)
    orbit = circular_orbit(
        np.datetime64(epoch, "ns"),
        t_orbit,
        altitude_m=altitude,
        raan_deg=raan_deg,
        argument_of_latitude_deg=argument_of_latitude_deg,
    )
    attitude = earth_pointing_attitude(t_att, **(attitude_kwargs or {}))
    return PushbroomModel(
        orbit=orbit,
        attitude=attitude,
        line_timing=LineTiming(0.5, 0.0, line_period),
        bands=hy1c_like_bands(design),
        installation=installation,
        n_rows=n_rows,
        reference_band=design.band_names[min(1, len(design.band_names) - 1)],
        name=name,
    )


# --------------------------------------------------------------------------- geostationary staring
#: mean equatorial radius of the geostationary orbit (GM / omega^2)^(1/3), metres
GEO_RADIUS_M = 42_164_172.0
#: seed 000 table 1: 1250 mm focal length, 1024 x 1024 HgCdTe array of 25 um pixels
SEED000_CAMERA = StaringLab(focal_length_mm=1250.0, pixel_size_mm=0.025)
SEED000_SHAPE = (1024, 1024)
#: a GF-4-like panchromatic camera: 10240 x 10240 pixels of 50 m at nadir (9 um pixels; the
#: focal length is chosen to give 50 m from 35 786 km, not taken from GF-4 documents)
GF4_LIKE_CAMERA = StaringLab(focal_length_mm=0.009 * (GEO_RADIUS_M - 6_378_137.0) / 50.0, pixel_size_mm=0.009)
GF4_LIKE_SHAPE = (10240, 10240)


def geostationary_orbit(epoch, seconds, *, lon_deg: float = 105.0, radius_m: float = GEO_RADIUS_M) -> Orbit:
    """State vectors in GCRF of a satellite fixed above the equator at ``lon_deg``.

    The ITRF position ``radius_m (cos lon, sin lon, 0)`` with zero ITRF velocity is rotated
    into GCRF at every sample (IAU 2006/2000A), so the satellite is exactly geostationary.

    Parameters
    ----------
    epoch : str or numpy.datetime64
        UTC epoch of ``seconds``.
    seconds : array_like, shape (N,)
        Sample times, SI seconds since ``epoch``.
    lon_deg : float
        Sub-satellite longitude, degrees.
    radius_m : float
        Orbit radius, metres.

    Returns
    -------
    Orbit
        GCRF state vectors at ``seconds``.
    """
    from sensor_models.geometry.frames import EarthRotation

    t = np.asarray(seconds, dtype=np.float64).reshape(-1)
    lon = np.radians(float(lon_deg))
    pos_i = np.broadcast_to(np.array([np.cos(lon), np.sin(lon), 0.0]) * float(radius_m), (t.size, 3))
    earth = EarthRotation(epoch, float(t.min()), float(t.max()))
    pos_g, vel_g = earth.itrf_to_gcrf_state(t, np.ascontiguousarray(pos_i), np.zeros((t.size, 3)))
    return Orbit(np.datetime64(epoch, "ns"), t, pos_g, vel_g, frame="gcrf")


def example_geo_staring_model(
    *,
    camera: str | StaringLab = "seed000",
    image_shape=None,
    epoch: str = "2023-06-15T03:00:00",
    lon_deg: float = 105.0,
    frame_seconds: float = 0.0,
    span_s: tuple[float, float] = (-600.0, 600.0),
    installation: Installation = Installation(),
    attitude_kwargs: dict | None = None,
    mirror: PointingMirror | None = None,
    name: str = "synthetic_geo",
) -> GeoStaringModel:
    """A geostationary staring camera with Earth-pointing attitude in the orbital frame.

    Parameters
    ----------
    camera : {"seed000", "gf4"} or StaringLab
        Seed 000 table 1 camera (1250 mm, 1024 x 1024 pixels of 25 um, about 716 m at nadir),
        a GF-4-like camera (10240 x 10240 pixels, 50 m at nadir) or a laboratory model (then
        ``image_shape`` is required). The interior is fitted to it (:meth:`GeoStaringModel.from_lab`).
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``; default: the named camera's.
    epoch : str
        UTC epoch of the orbit and attitude samples.
    lon_deg : float
        Sub-satellite longitude (seed 000's satellite; 105 E by default).
    frame_seconds : float
        Exposure instant of the frame.
    span_s : (float, float)
        Span of the orbit (sampled every 60 s) and attitude (every 1 s) samples.
    installation : Installation
    attitude_kwargs : dict, optional
        Passed to :func:`sensor_models.models.synthetic.earth_pointing_attitude` (bias, drift,
        jitter...). With zero attitude and installation the array centre looks at the
        geocentric nadir: the sub-satellite point ``(lon_deg, 0)``.
    mirror : PointingMirror, optional
    name : str
        Free text.

    Returns
    -------
    GeoStaringModel
    """
    if isinstance(camera, StaringLab):
        if image_shape is None:
            raise InputError("image_shape is required with a StaringLab camera", field="image_shape")
        lab = camera
    elif camera == "seed000":
        lab, image_shape = SEED000_CAMERA, image_shape or SEED000_SHAPE
    elif camera == "gf4":
        lab, image_shape = GF4_LIKE_CAMERA, image_shape or GF4_LIKE_SHAPE
    else:
        raise InputError(f"must be 'seed000', 'gf4' or a StaringLab, got {camera!r}", field="camera")
    t0, t1 = float(span_s[0]), float(span_s[1])
    if not t0 <= frame_seconds <= t1:
        raise InputError(f"frame_seconds {frame_seconds} lies outside span_s {span_s}", field="frame_seconds")
    t_orbit = np.linspace(t0, t1, max(4, int(np.ceil((t1 - t0) / 60.0)) + 1))
    t_att = np.linspace(t0, t1, max(4, int(np.ceil(t1 - t0)) + 1))
    epoch64 = np.datetime64(epoch, "ns")
    orbit = geostationary_orbit(epoch64, t_orbit, lon_deg=lon_deg)
    attitude = earth_pointing_attitude(t_att, **(attitude_kwargs or {}))
    return GeoStaringModel.from_lab(
        lab,
        image_shape=image_shape,
        orbit=orbit,
        attitude=attitude,
        frame_seconds=frame_seconds,
        installation=installation,
        mirror=mirror,
        name=name,
    )
