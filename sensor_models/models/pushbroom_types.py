"""Value types of the push-broom directional-angle model (seed 003 eq. 1-3).

Frames: the camera frame has X along track (flight direction), Y across track and Z along the
boresight towards the Earth; a detector's line of sight in the camera frame is
``(tan psi_x(s), tan psi_y(s), 1)`` normalized (seed 003 eq. 1), with ``tan psi_x`` and
``tan psi_y`` polynomials (cubic by default) of the detector index ``s`` (eq. 2). The body frame
coincides with seed 000's orbital frame at zero attitude (X along the velocity, Z towards the
Earth's centre, Y completing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensor_models.base import DetectorArray
from sensor_models.errors import InputError

__all__ = ["CcdLook", "Installation", "LineTiming", "rot_x", "rot_y", "rot_z"]


def rot_x(angle):
    """Active rotation matrices about X.

    Parameters
    ----------
    angle : array_like or float
        Rotation angles, radians (counter-clockwise seen from +X).

    Returns
    -------
    ndarray, shape ``angle.shape + (3, 3)``
        ``R @ v`` rotates a vector ``v`` by ``angle`` about X.
    """
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(np.shape(c) + (3, 3))


def rot_y(angle):
    """Active rotation matrices about Y.

    Parameters
    ----------
    angle : array_like or float
        Rotation angles, radians (counter-clockwise seen from +Y).

    Returns
    -------
    ndarray, shape ``angle.shape + (3, 3)``
        ``R @ v`` rotates a vector ``v`` by ``angle`` about Y.
    """
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(np.shape(c) + (3, 3))


def rot_z(angle):
    """Active rotation matrices about Z.

    Parameters
    ----------
    angle : array_like or float
        Rotation angles, radians (counter-clockwise seen from +Z).

    Returns
    -------
    ndarray, shape ``angle.shape + (3, 3)``
        ``R @ v`` rotates a vector ``v`` by ``angle`` about Z.
    """
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(np.shape(c) + (3, 3))


_GEN_X = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])
_GEN_Y = np.array([[0.0, 0, 1], [0, 0, 0], [-1, 0, 0]])
_GEN_Z = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 0]])


@dataclass(frozen=True)
class Installation:
    """Camera installation angles (radians): ``R_cam_to_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    ``v_body = R_cam_to_body @ v_cam``; all rotations active (seed 003 eq. 3, the
    ``R_cam^body`` factor). Zero angles mean the camera frame coincides with the body frame.
    """

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    NAMES = ("roll", "pitch", "yaw")

    def __post_init__(self):
        for name in self.NAMES:
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise InputError("must be finite", field=f"installation.{name}")
            object.__setattr__(self, name, value)

    def matrix(self) -> np.ndarray:
        """The camera -> body rotation.

        Returns
        -------
        ndarray, shape (3, 3)
            ``R_cam_to_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
        """
        return rot_z(self.yaw) @ rot_y(self.pitch) @ rot_x(self.roll)

    def matrix_derivatives(self) -> np.ndarray:
        """Derivatives of the camera -> body rotation in the three angles.

        Returns
        -------
        ndarray, shape (3, 3, 3)
            ``d R_cam_to_body / d(roll, pitch, yaw)`` per radian; the first axis is the angle.
        """
        rx, ry, rz = rot_x(self.roll), rot_y(self.pitch), rot_z(self.yaw)
        return np.stack(
            [rz @ ry @ rx @ _GEN_X, rz @ ry @ _GEN_Y @ rx, rz @ _GEN_Z @ ry @ rx]
        )

    def as_array(self) -> np.ndarray:
        """The angles as an array.

        Returns
        -------
        ndarray, shape (3,)
            ``[roll, pitch, yaw]``, radians.
        """
        return np.array([self.roll, self.pitch, self.yaw])


@dataclass(frozen=True)
class LineTiming:
    """Linear line-time model: ``t(row) = reference_seconds + (row - reference_row) * line_period_s``.

    ``row`` is the continuous image row (first line's centre at 0.5), ``t`` SI seconds since the
    scene epoch. The time of a line is the time of its centre (mid-integration).
    ``line_period_s`` is negative for a reverse scan (the rows advance backwards in time).
    """

    reference_row: float
    reference_seconds: float
    line_period_s: float

    def __post_init__(self):
        for name in ("reference_row", "reference_seconds", "line_period_s"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise InputError("must be finite", field=f"line_timing.{name}")
            object.__setattr__(self, name, value)
        if self.line_period_s == 0.0:
            # negative: a reverse scan (time decreasing with the row, e.g. WorldView "Reverse")
            raise InputError("must be non-zero", field="line_timing.line_period_s")

    def seconds(self, row):
        """Imaging time of continuous rows.

        Parameters
        ----------
        row : array_like
            Continuous image rows (first line's centre at 0.5).

        Returns
        -------
        ndarray of float64
            SI seconds since the scene epoch, same shape.
        """
        return self.reference_seconds + (np.asarray(row, dtype=np.float64) - self.reference_row) * self.line_period_s

    def row(self, seconds):
        """Continuous row imaged at given times (inverse of :meth:`seconds`).

        Parameters
        ----------
        seconds : array_like
            SI seconds since the scene epoch.

        Returns
        -------
        ndarray of float64
            Continuous rows (first line's centre at 0.5), same shape.
        """
        return self.reference_row + (np.asarray(seconds, dtype=np.float64) - self.reference_seconds) / self.line_period_s


@dataclass(frozen=True)
class CcdLook(DetectorArray):
    """Directional-angle polynomials of one CCD in one band (seed 003 eq. 2).

    A :class:`~sensor_models.base.DetectorArray` (what
    :meth:`PushbroomModel.detector_arrays <sensor_models.models.pushbroom.PushbroomModel.detector_arrays>`
    returns) with its look polynomials.

    Attributes
    ----------
    name : str
        CCD name, unique within the band (e.g. ``"ccd1"``).
    first_col : int
        Raster column of the CCD's first detector (its left edge; its centre is
        ``first_col + 0.5``). The detector index is ``s = col - first_col - 0.5``, so ``s = 0``
        at the first detector's centre and ``s = n_detectors - 1`` at the last one's.
    n_detectors : int
    tan_psi_x, tan_psi_y : ndarray, shape (K,)
        Polynomial coefficients ``c0 .. c_{K-1}`` with ``tan psi = sum_k c_k s^k``
        (K = 4: the cubic of seed 003).
    """

    tan_psi_x: np.ndarray
    tan_psi_y: np.ndarray

    def __post_init__(self):
        if int(self.n_detectors) < 1:
            raise InputError("must be >= 1", field=f"ccd {self.name}.n_detectors")
        if int(self.first_col) < 0:
            raise InputError("must be >= 0", field=f"ccd {self.name}.first_col")
        object.__setattr__(self, "n_detectors", int(self.n_detectors))
        object.__setattr__(self, "first_col", int(self.first_col))
        for attr in ("tan_psi_x", "tan_psi_y"):
            c = np.asarray(getattr(self, attr), dtype=np.float64).reshape(-1)
            if c.size < 1 or c.size > 8:
                raise InputError("needs 1 to 8 polynomial coefficients", field=f"ccd {self.name}.{attr}")
            if not np.all(np.isfinite(c)):
                raise InputError("holds NaN or infinite values", field=f"ccd {self.name}.{attr}")
            object.__setattr__(self, attr, c)

    def detector_index(self, col):
        """Detector index of raster columns.

        Parameters
        ----------
        col : array_like
            Continuous raster columns (first column's centre at 0.5).

        Returns
        -------
        ndarray of float64
            ``s = col - first_col - 0.5`` (0 at the first detector's centre), same shape.
        """
        return np.asarray(col, dtype=np.float64) - self.first_col - 0.5

    def look(self, s):
        """Look-direction tangents and their derivatives at detector indices.

        Parameters
        ----------
        s : array_like
            Detector indices (see :meth:`detector_index`).

        Returns
        -------
        tan_psi_x, tan_psi_y, d_tan_psi_x_ds, d_tan_psi_y_ds : ndarray
            The polynomials and their derivatives per unit of ``s``, each of the shape of ``s``.
        """
        s = np.asarray(s, dtype=np.float64)
        tx = np.polynomial.polynomial.polyval(s, self.tan_psi_x)
        ty = np.polynomial.polynomial.polyval(s, self.tan_psi_y)
        dx = np.polynomial.polynomial.polyval(s, np.polynomial.polynomial.polyder(self.tan_psi_x)) if self.tan_psi_x.size > 1 else np.zeros_like(s)
        dy = np.polynomial.polynomial.polyval(s, np.polynomial.polynomial.polyder(self.tan_psi_y)) if self.tan_psi_y.size > 1 else np.zeros_like(s)
        return tx, ty, dx, dy
