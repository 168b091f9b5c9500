"""Exterior orientation of a SPOT 1-5 DIMAP scene: SPOT frames, ITRF orbit, body -> ITRF attitude.

:func:`spot_orbital_to_itrf_mat` and :func:`spot_satellite_to_orbital_mat` are the SPOT local
orbital and satellite frames; :func:`attitude_angles` gives the file's yaw, pitch and roll at
any time (SPOT 5 corrected angles interpolated, SPOT 1-4 angular speeds integrated from an
absolute sample); :func:`dimap_orbit` and :func:`body_to_itrf` give the orbit and the
attitude the model is built with. Conventions: :mod:`sensor_models.readers.dimap`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.errors import InputError, ManifestError
from sensor_models.readers.dimap_common import EARTH_ROTATION_RAD_S
from sensor_models.readers.dimap_parse import DimapAngles, DimapMetadata

__all__ = [
    "ATTITUDE_MODES",
    "CAMERA_TO_SPOT",
    "attitude_angles",
    "attitude_sample_seconds",
    "body_to_itrf",
    "dimap_orbit",
    "spot_orbital_to_itrf_mat",
    "spot_satellite_to_orbital_mat",
]

#: rotation taking gcpcal camera-frame vectors to the SPOT satellite (navigation) frame:
#: SPOT X (across track) = camera Y, SPOT Y (along track) = camera X, SPOT Z (up) = -camera Z
CAMERA_TO_SPOT = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: attitude samples of the model: spacing (s) and margin beyond the image lines (s)
ATTITUDE_STEP_S = 0.1
#: attitude choices of :func:`~sensor_models.readers.dimap.read_dimap`
ATTITUDE_MODES = ("measured", "nominal")
ATTITUDE_MARGIN_S = 1.0


def spot_orbital_to_itrf_mat(position_m, velocity_m_s) -> np.ndarray:
    """SPOT local orbital frame -> ITRF, shape (N, 3, 3) (columns: X, Y, Z axes in ITRF).

    ``Z = P/|P|``, ``X = V x Z / |V x Z|``, ``Y = Z x X`` with the ITRF position and the
    Earth-relative velocity (SPOT Geometry Handbook; as OSSIM's ``ossimSpot5Model``).

    Parameters
    ----------
    position_m : array_like, shape (N, 3) or (3,)
        ITRF positions, metres.
    velocity_m_s : array_like, shape (N, 3) or (3,)
        Earth-relative ITRF velocities, m/s.

    Returns
    -------
    ndarray, shape (N, 3, 3)
        Rotation matrices orbital -> ITRF.
    """
    p = np.atleast_2d(np.asarray(position_m, dtype=np.float64))
    v = np.atleast_2d(np.asarray(velocity_m_s, dtype=np.float64))
    z = p / np.linalg.norm(p, axis=-1, keepdims=True)
    x = np.cross(v, z)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def spot_satellite_to_orbital_mat(yaw, pitch, roll) -> np.ndarray:
    """SPOT satellite (navigation) frame -> local orbital frame, shape (N, 3, 3).

    ``Rx(-pitch) @ Ry(-roll) @ Rz(yaw)`` (active rotations): the file's roll and pitch are
    given about the reversed (-X, -Y) axes (SPOT Geometry Handbook).

    Parameters
    ----------
    yaw, pitch, roll : array_like, shape (N,) or scalar
        Attitude angles as the DIMAP file gives them (SPOT convention), radians.

    Returns
    -------
    ndarray, shape (N, 3, 3)
        Rotation matrices satellite -> local orbital frame.
    """
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (yaw, pitch, roll))
    angles = np.stack([-pitch, -roll, yaw], axis=-1)
    return Rotation.from_euler("XYZ", angles).as_matrix()  # intrinsic X-Y-Z = Rx @ Ry @ Rz


def _integrate_speeds(t, speeds: DimapAngles, t0: float, a0: np.ndarray) -> np.ndarray:
    """``a(t) = a0 + integral_{t0}^{t} w(tau) dtau`` for yaw, pitch, roll, shape (N, 3).

    ``w`` is the piecewise-linear interpolant of the valid angular-speed samples, held
    constant beyond the first and the last sample (exact trapezoid integration).
    """
    ok = ~speeds.out_of_range
    ts = speeds.seconds[ok]
    w = np.stack([speeds.yaw[ok], speeds.pitch[ok], speeds.roll[ok]], axis=-1)
    # knots: sample times plus the query and the start, integrate piecewise-linear exactly
    grid = np.unique(np.concatenate([ts, np.atleast_1d(t), [t0]]))
    wg = np.stack([np.interp(grid, ts, w[:, k]) for k in range(3)], axis=-1)  # held beyond the ends
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (wg[1:] + wg[:-1]) * np.diff(grid)[:, None], axis=0)])
    at = np.stack([np.interp(t, grid, cum[:, k]) for k in range(3)], axis=-1)
    a_t0 = np.array([np.interp(t0, grid, cum[:, k]) for k in range(3)])
    return a0 + at - a_t0


def attitude_angles(meta: DimapMetadata, seconds) -> np.ndarray:
    """Yaw, pitch, roll (SPOT convention, radians) at ``seconds``, shape (N, 3).

    SPOT 5: the corrected (absolute) angles, interpolated linearly. SPOT 1-4: the first
    valid absolute AOCS sample plus the integral of the angular speeds from its time.

    Parameters
    ----------
    meta : DimapMetadata
        The parsed file.
    seconds : array_like, shape (N,) or scalar
        SI seconds since ``meta.epoch``.

    Returns
    -------
    ndarray, shape (N, 3)
        Yaw, pitch, roll in radians (not yet converted to gcpcal's frames).

    Raises
    ------
    ManifestError
        Fewer than two valid corrected-attitude or angular-speed samples.
    """
    t = np.atleast_1d(np.asarray(seconds, dtype=np.float64))
    if meta.corrected_angles is not None:
        c = meta.corrected_angles
        ok = ~c.out_of_range
        if ok.sum() < 2:
            raise ManifestError("fewer than two valid corrected attitude samples", path=meta.path, field=c.field)
        return np.stack([np.interp(t, c.seconds[ok], a[ok]) for a in (c.yaw, c.pitch, c.roll)], axis=-1)
    if meta.angular_speeds is None:
        raise ManifestError("neither corrected attitudes nor angular speeds", path=meta.path, field=meta.raw_angles.field)
    raw = meta.raw_angles
    valid = np.nonzero(~raw.out_of_range)[0]
    if valid.size:
        i = int(valid[0])
        t0, a0 = raw.seconds[i], np.array([raw.yaw[i], raw.pitch[i], raw.roll[i]])
    else:  # no valid absolute sample: the nominal attitude (zero) at the first speed sample
        t0, a0 = meta.angular_speeds.seconds[0], np.zeros(3)
    if (~meta.angular_speeds.out_of_range).sum() < 2:
        raise ManifestError("fewer than two valid angular speed samples", path=meta.path, field=meta.angular_speeds.field)
    return _integrate_speeds(t, meta.angular_speeds, t0, a0)


def attitude_sample_seconds(meta: DimapMetadata) -> np.ndarray:
    """Times of the model's attitude samples: every ``ATTITUDE_STEP_S`` over the image lines plus a
    margin, within the ephemeris span (SI seconds since ``meta.epoch``)."""
    t_first = meta.seconds(0.0)
    t_last = meta.seconds(float(meta.n_rows))
    lo = min(t_first, t_last) - ATTITUDE_MARGIN_S - 0.1 * abs(t_last - t_first)
    hi = max(t_first, t_last) + ATTITUDE_MARGIN_S + 0.1 * abs(t_last - t_first)
    lo = max(lo, meta.ephemeris_seconds[0])
    hi = min(hi, meta.ephemeris_seconds[-1])
    n = int(np.ceil((hi - lo) / ATTITUDE_STEP_S)) + 1
    return np.linspace(lo, hi, n)


def dimap_orbit(meta: DimapMetadata):
    """The ITRF orbit of a DIMAP file.

    Parameters
    ----------
    meta : DimapMetadata
        The parsed file.

    Returns
    -------
    Orbit
        Frame ``"itrf"``, seconds since ``meta.epoch``, positions in metres and Earth-relative
        velocities in m/s (inertial file velocities are converted).
    """
    from sensor_models.geometry.ephemeris import Orbit

    return Orbit(meta.epoch, meta.ephemeris_seconds, meta.position_m, meta.earth_relative_velocity_m_s, frame="itrf")


def body_to_itrf(meta: DimapMetadata, seconds, orbit=None, *, attitude: str = "measured") -> np.ndarray:
    """gcpcal body (= camera) frame -> ITRF rotations at ``seconds``, shape (N, 3, 3).

    The SPOT local orbital frame is built with the velocity of the kind the file gives
    (inertial for SPOT 1-4, Earth-relative for SPOT 5): that is the frame the ground segment
    used (the other choice misplaces the frame vertices by 0.2 to 20 km).

    Parameters
    ----------
    meta : DimapMetadata
        The parsed file.
    seconds : array_like, shape (N,) or scalar
        SI seconds since ``meta.epoch``.
    orbit : Orbit, optional
        The ITRF orbit (default :func:`dimap_orbit`).
    attitude : {"measured", "nominal"}
        ``"measured"``: the file's attitude (see :func:`attitude_angles`); ``"nominal"``: zero
        yaw, pitch and roll (the satellite frame on the local orbital frame).

    Returns
    -------
    ndarray, shape (N, 3, 3)
        Rotation matrices body -> ITRF (body = camera, ``CAMERA_TO_SPOT`` included).
    """
    if attitude not in ATTITUDE_MODES:
        raise InputError(f"must be one of {ATTITUDE_MODES}, got {attitude!r}", field="attitude")
    seconds = np.atleast_1d(np.asarray(seconds, dtype=np.float64))
    if orbit is None:
        orbit = dimap_orbit(meta)
    pos, vel = orbit.state(seconds)
    if meta.velocity_kind == "inertial":
        vel = vel + np.cross([0.0, 0.0, EARTH_ROTATION_RAD_S], pos)
    if attitude == "measured":
        ypr = attitude_angles(meta, seconds)
    else:
        ypr = np.zeros((seconds.size, 3))
    sat_to_orb = spot_satellite_to_orbital_mat(ypr[:, 0], ypr[:, 1], ypr[:, 2])
    return spot_orbital_to_itrf_mat(pos, vel) @ sat_to_orb @ CAMERA_TO_SPOT
