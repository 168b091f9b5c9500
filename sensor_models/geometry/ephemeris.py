"""Orbit and attitude samples and their interpolation.

Times are float64 SI seconds since a UTC scene epoch (``numpy.datetime64``). Interpolation
never extrapolates: a time outside the sampled span raises :class:`OutOfRangeError`.

* Orbit: piecewise cubic Hermite interpolation of positions using the sampled velocities
  (C1 continuous). For a LEO orbit sampled every 30 s the interpolation error is about
  ``dt^4 |r''''| / 384 ~ 2 cm``; every 60 s about 0.4 m.
* Attitude: :class:`scipy.spatial.transform.RotationSpline` (cubic in the rotation vector,
  continuous angular rate and acceleration). Quaternions are scalar-last ``(x, y, z, w)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.spatial.transform import Rotation, RotationSpline

from sensor_models.errors import InputError, OutOfRangeError

__all__ = ["Attitude", "Orbit", "check_times", "ORBIT_FRAMES", "ATTITUDE_FRAMES"]

ORBIT_FRAMES = ("itrf", "gcrf")
ATTITUDE_FRAMES = ("gcrf", "itrf", "orbital")


def check_times(seconds, *, what: str, minimum: int = 2) -> np.ndarray:
    """Validate a sample-time vector: finite, strictly increasing, at least ``minimum`` long.

    Parameters
    ----------
    seconds : array_like, shape (N,)
        Sample times, SI seconds since an epoch.
    what : str
        Field name used in the error message.
    minimum : int
        Fewest samples accepted.

    Returns
    -------
    ndarray of float64, shape (N,)

    Raises
    ------
    InputError
        Naming ``what`` and the first offending sample.
    """
    t = np.asarray(seconds, dtype=np.float64)
    if t.ndim != 1 or t.shape[0] < minimum:
        raise InputError(f"needs at least {minimum} samples, got {t.size}", field=what)
    if not np.all(np.isfinite(t)):
        raise InputError("holds NaN or infinite times", field=what)
    bad = np.nonzero(np.diff(t) <= 0.0)[0]
    if bad.size:
        raise InputError(
            f"times must increase strictly; sample {bad[0] + 1} ({t[bad[0] + 1]:.6f} s) "
            f"follows {t[bad[0]]:.6f} s",
            field=what,
        )
    return t


def _check_within(t, span, what):
    t = np.asarray(t, dtype=np.float64)
    lo, hi = span
    tol = 1e-9 * max(1.0, abs(lo), abs(hi))
    outside = (t < lo - tol) | (t > hi + tol) | ~np.isfinite(t)
    if np.any(outside):
        first = t[outside].reshape(-1)[0]
        raise OutOfRangeError(
            f"time {first:.6f} s lies outside the {what} data [{lo:.6f}, {hi:.6f}] s; "
            "gcpcal never extrapolates"
        )
    return np.clip(t, lo, hi)


@dataclass(frozen=True)
class Orbit:
    """Sampled satellite state vectors.

    Attributes
    ----------
    epoch : numpy.datetime64
        UTC epoch the sample times refer to.
    seconds : ndarray, shape (N,)
        Sample times in SI seconds since ``epoch``, strictly increasing.
    position_m : ndarray, shape (N, 3)
        Positions of the satellite's centre of mass in ``frame``.
    velocity_m_s : ndarray, shape (N, 3)
        Velocities in ``frame`` (for ITRF: relative to the rotating Earth).
    frame : {"itrf", "gcrf"}
    """

    epoch: np.datetime64
    seconds: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    frame: str = "itrf"
    _spline: CubicHermiteSpline = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        t = check_times(self.seconds, what="orbit.seconds")
        pos = np.asarray(self.position_m, dtype=np.float64)
        vel = np.asarray(self.velocity_m_s, dtype=np.float64)
        for name, arr in (("orbit.position_m", pos), ("orbit.velocity_m_s", vel)):
            if arr.shape != (t.shape[0], 3):
                raise InputError(f"expected shape ({t.shape[0]}, 3), got {arr.shape}", field=name)
            if not np.all(np.isfinite(arr)):
                raise InputError("holds NaN or infinite values", field=name)
        if self.frame not in ORBIT_FRAMES:
            raise InputError(f"must be one of {ORBIT_FRAMES}, got {self.frame!r}", field="orbit.frame")
        radius = np.linalg.norm(pos, axis=1)
        if np.any(radius < 6.3e6) or np.any(radius > 1.0e8):
            raise InputError(
                "positions must be metres from the Earth's centre (radius 6 300 km to 100 000 km)",
                field="orbit.position_m",
            )
        object.__setattr__(self, "seconds", t)
        object.__setattr__(self, "position_m", pos)
        object.__setattr__(self, "velocity_m_s", vel)
        object.__setattr__(self, "epoch", np.datetime64(self.epoch, "ns"))
        object.__setattr__(self, "_spline", CubicHermiteSpline(t, pos, vel, axis=0))

    @property
    def span(self) -> tuple[float, float]:
        """First and last sample times, SI seconds since ``epoch``."""
        return float(self.seconds[0]), float(self.seconds[-1])

    def position(self, seconds) -> np.ndarray:
        """Interpolated positions (cubic Hermite through positions and velocities).

        Parameters
        ----------
        seconds : array_like of float
            SI seconds since the epoch, inside :attr:`span` (never extrapolated).

        Returns
        -------
        ndarray, shape ``seconds.shape + (3,)``
            Positions in ``frame``, metres.
        """
        return self._spline(_check_within(seconds, self.span, "orbit"))

    def velocity(self, seconds) -> np.ndarray:
        """Interpolated velocities (the derivative of the position interpolant).

        Parameters
        ----------
        seconds : array_like of float
            SI seconds since the epoch, inside :attr:`span` (never extrapolated).

        Returns
        -------
        ndarray, shape ``seconds.shape + (3,)``
            Velocities in ``frame``, m/s.
        """
        return self._spline(_check_within(seconds, self.span, "orbit"), 1)

    def state(self, seconds):
        """Interpolated state vectors.

        Parameters
        ----------
        seconds : array_like of float
            SI seconds since the epoch, inside :attr:`span` (never extrapolated).

        Returns
        -------
        position_m, velocity_m_s : ndarray, shape ``seconds.shape + (3,)``
            In ``frame``; metres and m/s.
        """
        t = _check_within(seconds, self.span, "orbit")
        return self._spline(t), self._spline(t, 1)


@dataclass(frozen=True)
class Attitude:
    """Sampled attitude: rotations from the body frame to a reference frame.

    ``v_ref = R(t) @ v_body``; quaternions scalar-last ``(x, y, z, w)``.

    Attributes
    ----------
    seconds : ndarray, shape (M,)
        Sample times in SI seconds since the scene epoch, strictly increasing.
    quaternions_xyzw : ndarray, shape (M, 4)
        Unit quaternions (normalized on entry; a norm off by more than 1e-3 is an error).
    frame : {"gcrf", "itrf", "orbital"}
        The reference frame. ``"orbital"`` is seed 000's orbital frame: X along the
        velocity, Z towards the Earth's centre, Y completing the right-handed triad,
        built from the orbit's own state vectors.
    """

    seconds: np.ndarray
    quaternions_xyzw: np.ndarray
    frame: str = "gcrf"
    _spline: RotationSpline = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        t = check_times(self.seconds, what="attitude.seconds")
        q = np.asarray(self.quaternions_xyzw, dtype=np.float64)
        if q.shape != (t.shape[0], 4):
            raise InputError(
                f"expected shape ({t.shape[0]}, 4), got {q.shape}", field="attitude.quaternions_xyzw"
            )
        if not np.all(np.isfinite(q)):
            raise InputError("holds NaN or infinite values", field="attitude.quaternions_xyzw")
        norm = np.linalg.norm(q, axis=1)
        if np.any(np.abs(norm - 1.0) > 1e-3):
            raise InputError("quaternions must have unit norm", field="attitude.quaternions_xyzw")
        if self.frame not in ATTITUDE_FRAMES:
            raise InputError(
                f"must be one of {ATTITUDE_FRAMES}, got {self.frame!r}", field="attitude.frame"
            )
        q = q / norm[:, None]
        # make the sequence sign-continuous so that interpolation takes the short way
        sign = np.sign(np.einsum("ij,ij->i", q[1:], q[:-1]))
        sign[sign == 0] = 1.0
        q[1:] *= np.cumprod(sign)[:, None]
        object.__setattr__(self, "seconds", t)
        object.__setattr__(self, "quaternions_xyzw", q)
        object.__setattr__(self, "_spline", RotationSpline(t, Rotation.from_quat(q)))

    @property
    def span(self) -> tuple[float, float]:
        """First and last sample times, SI seconds since the scene epoch."""
        return float(self.seconds[0]), float(self.seconds[-1])

    def rotation(self, seconds) -> Rotation:
        """Interpolated body -> reference rotations (``scipy`` rotation spline).

        Parameters
        ----------
        seconds : array_like of float
            SI seconds since the epoch, inside :attr:`span` (never extrapolated).

        Returns
        -------
        scipy.spatial.transform.Rotation
            ``N`` rotations (``seconds`` flattened to at least 1-D).
        """
        t = _check_within(np.atleast_1d(seconds), self.span, "attitude")
        return self._spline(t)

    def matrix(self, seconds) -> np.ndarray:
        """Interpolated body -> reference rotation matrices, ``v_ref = R @ v_body``.

        Parameters
        ----------
        seconds : array_like of float
            SI seconds since the epoch, inside :attr:`span` (never extrapolated).

        Returns
        -------
        ndarray, shape (N, 3, 3)
        """
        return self.rotation(seconds).as_matrix()
