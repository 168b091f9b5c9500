"""The camera of a geostationary staring model: its interior, laboratory model and pointing mirror.

Interior (seed 000 eq. 4-5; seed 002 section 2.1): a pixel ``(row, col)`` of an
``n_rows x n_cols`` array has normalized focal-plane coordinates
``u = (col - n_cols/2) / (n_cols/2)``, ``v = (row - n_rows/2) / (n_rows/2)`` (``-1 .. 1`` across
the array) and directional angles given by two cubics of 10 coefficients each,
``tan psi_x = sum a_ij u^i v^j`` and ``tan psi_y = sum b_ij u^i v^j`` over
:data:`MONOMIAL_POWERS` (:class:`StaringInterior`; its :meth:`~StaringInterior.solve` inverts
them by Newton's method). :class:`StaringLab` is the physical (laboratory) camera of seed 002
table 1 (focal length, pixel pitch, principal point, radial and decentring distortion,
rotation) and :func:`fit_interior` fits the 20 coefficients to it over the whole array.
:class:`PointingMirror` is the optional mirror between the camera and the scene (its
reflection ``R_ref = I - 2 n n^T``). The model that uses them is
:class:`~sensor_models.models.geo_staring.GeoStaringModel`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError
from sensor_models.models.pushbroom_types import rot_x, rot_y

__all__ = [
    "MONOMIAL_POWERS",
    "MONOMIAL_SUFFIXES",
    "PointingMirror",
    "StaringInterior",
    "StaringLab",
    "check_image_shape",
    "cubic_monomials",
    "fit_interior",
]


#: powers ``(i, j)`` of ``u^i v^j`` of the ten cubic monomials, in seed 000 eq. 5 order
MONOMIAL_POWERS = ((0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (2, 1), (1, 2), (3, 0), (0, 3))
#: ``"ij"`` of each monomial, in :data:`MONOMIAL_POWERS` order (the parameter names' suffixes)
MONOMIAL_SUFFIXES = tuple(f"{i}{j}" for i, j in MONOMIAL_POWERS)
#: Newton solutions are sought within this many half-frames of the array centre
_UV_LIMIT = 4.0
#: Newton stops when the step is below this (normalized units; 5e-11 px for 1024 pixels)
_UV_TOL = 1e-13


# --------------------------------------------------------------------------- interior
def cubic_monomials(u, v):
    """The ten monomials of seed 000 eq. 5.

    Parameters
    ----------
    u, v : ndarray
        Normalized focal-plane coordinates (same shape).

    Returns
    -------
    ndarray, shape ``u.shape + (10,)``
        ``u^i v^j`` in :data:`MONOMIAL_POWERS` order.
    """
    uu, vv, uv = u * u, v * v, u * v
    one = np.ones_like(u)
    return np.stack([one, u, v, uv, uu, vv, uu * v, u * vv, uu * u, vv * v], axis=-1)


@dataclass(frozen=True)
class StaringInterior:
    """The 20 directional-angle coefficients of an area array (seed 000 eq. 4-5).

    Attributes
    ----------
    tan_psi_x, tan_psi_y : ndarray, shape (10,)
        Coefficients ``a_ij`` and ``b_ij`` of ``u^i v^j`` in :data:`MONOMIAL_POWERS` order
        (seed 000's ``a_0 .. a_9``, ``b_0 .. b_9``); dimensionless (``u``, ``v`` are
        normalized, see the module docstring).
    """

    tan_psi_x: np.ndarray
    tan_psi_y: np.ndarray

    def __post_init__(self):
        for attr in ("tan_psi_x", "tan_psi_y"):
            c = np.asarray(getattr(self, attr), dtype=np.float64).reshape(-1)
            if c.size != 10:
                raise InputError(f"needs 10 coefficients, got {c.size}", field=f"interior.{attr}")
            if not np.all(np.isfinite(c)):
                raise InputError("holds NaN or infinite values", field=f"interior.{attr}")
            c = c.copy()
            c.setflags(write=False)
            object.__setattr__(self, attr, c)
        det = self.tan_psi_x[1] * self.tan_psi_y[2] - self.tan_psi_x[2] * self.tan_psi_y[1]
        if not abs(det) > 0.0:
            raise InputError("the linear terms (a10, a01, b10, b01) are singular: no image scale", field="interior")

    @classmethod
    def pinhole(cls, focal_length_mm: float, pixel_size_mm: float, image_shape) -> "StaringInterior":
        """Ideal pinhole centred on the array: ``tan psi = (pixel offset) * pitch / f``.

        Parameters
        ----------
        focal_length_mm, pixel_size_mm : float
            Focal length and pixel pitch, millimetres.
        image_shape : (int, int)
            ``(n_rows, n_cols)`` of the array.

        Returns
        -------
        StaringInterior
            Only ``a10`` and ``b01`` are non-zero.
        """
        n_rows, n_cols = check_image_shape(image_shape)
        ifov = float(pixel_size_mm) / float(focal_length_mm)
        ax = np.zeros(10)
        by = np.zeros(10)
        ax[1] = ifov * n_cols / 2.0
        by[2] = ifov * n_rows / 2.0
        return cls(ax, by)

    def tangents(self, u, v):
        """The cubic directional angles at normalized coordinates (seed 000 eq. 4-5).

        Parameters
        ----------
        u, v : ndarray
            Normalized frame coordinates (module docstring), one shape.

        Returns
        -------
        tan_psi_x, tan_psi_y : ndarray, shape of ``u``
        """
        a, b = self.tan_psi_x, self.tan_psi_y
        uu, vv, uv = u * u, v * v, u * v
        tx = a[0] + a[1] * u + a[2] * v + a[3] * uv + a[4] * uu + a[5] * vv + a[6] * uu * v + a[7] * u * vv + a[8] * uu * u + a[9] * vv * v
        ty = b[0] + b[1] * u + b[2] * v + b[3] * uv + b[4] * uu + b[5] * vv + b[6] * uu * v + b[7] * u * vv + b[8] * uu * u + b[9] * vv * v
        return tx, ty

    def derivatives(self, u, v):
        """Partial derivatives of :meth:`tangents` in the normalized coordinates.

        Parameters
        ----------
        u, v : ndarray
            Normalized frame coordinates, one shape.

        Returns
        -------
        dx_du, dx_dv, dy_du, dy_dv : ndarray, shape of ``u``
            ``d tan psi_x / du``, ``d tan psi_x / dv``, ``d tan psi_y / du``,
            ``d tan psi_y / dv``.
        """
        a, b = self.tan_psi_x, self.tan_psi_y
        uu, vv, uv = u * u, v * v, u * v
        xu = a[1] + a[3] * v + 2.0 * a[4] * u + 2.0 * a[6] * uv + a[7] * vv + 3.0 * a[8] * uu
        xv = a[2] + a[3] * u + 2.0 * a[5] * v + a[6] * uu + 2.0 * a[7] * uv + 3.0 * a[9] * vv
        yu = b[1] + b[3] * v + 2.0 * b[4] * u + 2.0 * b[6] * uv + b[7] * vv + 3.0 * b[8] * uu
        yv = b[2] + b[3] * u + 2.0 * b[5] * v + b[6] * uu + 2.0 * b[7] * uv + 3.0 * b[9] * vv
        return xu, xv, yu, yv

    def solve(self, tx_target, ty_target, *, max_iter: int = 30):
        """Invert the cubic: ``(u, v)`` with ``tangents(u, v) = (tx, ty)``, vectorized Newton.

        Starts from the ideal pinhole (constant and linear terms only). Solutions outside
        ``|u|, |v| <= 4`` (four half-frames from the centre) or not converged are NaN.

        Parameters
        ----------
        tx_target, ty_target : array_like, shape (N,)
            Wanted ``tan psi_x`` and ``tan psi_y`` (dimensionless).
        max_iter : int
            Newton iterations at most.

        Returns
        -------
        u, v : ndarray, shape (N,)
        """
        tx_target = np.asarray(tx_target, dtype=np.float64).reshape(-1)
        ty_target = np.asarray(ty_target, dtype=np.float64).reshape(-1)
        a, b = self.tan_psi_x, self.tan_psi_y
        det0 = a[1] * b[2] - a[2] * b[1]
        rx, ry = tx_target - a[0], ty_target - b[0]
        u = (b[2] * rx - a[2] * ry) / det0
        v = (a[1] * ry - b[1] * rx) / det0
        ok = np.zeros(u.size, dtype=bool)
        active = np.nonzero(np.isfinite(u) & np.isfinite(v))[0]
        for _ in range(max_iter):
            if active.size == 0:
                break
            ua, va = u[active], v[active]
            fx, fy = self.tangents(ua, va)
            fx -= tx_target[active]
            fy -= ty_target[active]
            xu, xv, yu, yv = self.derivatives(ua, va)
            det = xu * yv - xv * yu
            with np.errstate(divide="ignore", invalid="ignore"):
                du = -(yv * fx - xv * fy) / det
                dv = -(xu * fy - yu * fx) / det
            ua = np.clip(ua + du, -_UV_LIMIT, _UV_LIMIT)
            va = np.clip(va + dv, -_UV_LIMIT, _UV_LIMIT)
            u[active], v[active] = ua, va
            bad = ~(np.isfinite(du) & np.isfinite(dv))
            done = (np.abs(du) < _UV_TOL) & (np.abs(dv) < _UV_TOL)
            ok[active[done]] = True
            active = active[~done & ~bad]
        edge = (np.abs(u) >= _UV_LIMIT) | (np.abs(v) >= _UV_LIMIT)
        u[~ok | edge] = np.nan
        v[~ok | edge] = np.nan
        return u, v


def check_image_shape(image_shape) -> tuple[int, int]:
    """An array's ``(n_rows, n_cols)``, checked.

    Parameters
    ----------
    image_shape : (int, int)

    Returns
    -------
    (int, int)

    Raises
    ------
    InputError
        Not two integers, or not positive.
    """
    try:
        n_rows, n_cols = (int(x) for x in image_shape)
    except (TypeError, ValueError):
        raise InputError(f"must be (n_rows, n_cols), got {image_shape!r}", field="image_shape") from None
    if n_rows < 1 or n_cols < 1:
        raise InputError(f"must be positive, got {(n_rows, n_cols)}", field="image_shape")
    return n_rows, n_cols


# --------------------------------------------------------------------------- lab model
@dataclass(frozen=True)
class StaringLab:
    """Physical (laboratory) interior of an area-array camera (the terms of seed 002 table 1).

    Focal-plane quantities are in pixels (as seed 002 table 1 gives them) except the focal
    length and the pixel pitch (millimetres). For the pixel ``(row, col)``:

    1. array coordinates from the array centre: ``x_a = col - n_cols/2``, ``y_a = row - n_rows/2``;
    2. in-plane rotation of the array by ``rotation_rad`` about the boresight (seed 002's
       array rotation beta);
    3. tilt of the array plane: ``q = Rx(tilt_x) Ry(tilt_y) (x_r, y_r, 0)`` (seed 002's phi_x,
       phi_y), so the pixel lies at ``(q_x, q_y, F + q_z)`` with ``F = f / pitch`` (pixels),
       and its central projection on the ideal focal plane is ``F (q_x, q_y) / (F + q_z)``;
    4. coordinates ``(x, y)`` relative to the principal point ``principal_point_px`` = ``(row,
       col)`` (default: the array centre);
    5. Brown-Conrady distortion with ``r^2 = x^2 + y^2``::

           dx = x (k1 r^2 + k2 r^4) + p1 (r^2 + 2 x^2) + 2 p2 x y
           dy = y (k1 r^2 + k2 r^4) + p2 (r^2 + 2 y^2) + 2 p1 x y

       (``k1`` in px^-2, ``k2`` px^-4, ``p1``, ``p2`` px^-1); the distortion displaces the image,
       so the ideal direction uses ``x - dx``, ``y - dy``;
    6. ``tan psi_x = (x - dx) / F``, ``tan psi_y = (y - dy) / F``.

    A camera looking at the scene with this interior sees a north-up, east-right image when
    the camera frame coincides with seed 000's orbital frame (X east, Y south, Z nadir at GEO).
    """

    focal_length_mm: float
    pixel_size_mm: float
    principal_point_px: tuple[float, float] | None = None
    radial_k: tuple[float, float] = (0.0, 0.0)
    decentering_p: tuple[float, float] = (0.0, 0.0)
    tilt_rad: tuple[float, float] = (0.0, 0.0)
    rotation_rad: float = 0.0

    def __post_init__(self):
        for name in ("focal_length_mm", "pixel_size_mm"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0.0):
                raise InputError(f"must be positive and finite, got {getattr(self, name)}", field=f"interior.{name}")
            object.__setattr__(self, name, value)
        for name, size in (("radial_k", 2), ("decentering_p", 2), ("tilt_rad", 2), ("principal_point_px", 2)):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=np.float64).reshape(-1)
            if arr.size != size or not np.all(np.isfinite(arr)):
                raise InputError(f"needs {size} finite numbers", field=f"interior.{name}")
            object.__setattr__(self, name, tuple(float(x) for x in arr))
        if not np.isfinite(float(self.rotation_rad)):
            raise InputError("must be finite", field="interior.rotation_rad")
        object.__setattr__(self, "rotation_rad", float(self.rotation_rad))

    @property
    def ifov_rad(self) -> float:
        """Angle subtended by one pixel at the principal point, ``pitch / f``."""
        return self.pixel_size_mm / self.focal_length_mm

    def tangents(self, row, col, image_shape):
        """Exact directional angles of pixels from the physical (laboratory) model.

        Parameters
        ----------
        row, col : array_like
            Continuous image coordinates, one shape.
        image_shape : (int, int)
            ``(n_rows, n_cols)`` of the array.

        Returns
        -------
        tan_psi_x, tan_psi_y : ndarray, shape of ``row``
        """
        n_rows, n_cols = check_image_shape(image_shape)
        row = np.asarray(row, dtype=np.float64)
        col = np.asarray(col, dtype=np.float64)
        f_px = self.focal_length_mm / self.pixel_size_mm
        xa, ya = col - 0.5 * n_cols, row - 0.5 * n_rows
        c, s = np.cos(self.rotation_rad), np.sin(self.rotation_rad)
        xr, yr = c * xa - s * ya, s * xa + c * ya
        tilt = rot_x(self.tilt_rad[0]) @ rot_y(self.tilt_rad[1])
        qx = tilt[0, 0] * xr + tilt[0, 1] * yr
        qy = tilt[1, 0] * xr + tilt[1, 1] * yr
        qz = tilt[2, 0] * xr + tilt[2, 1] * yr
        scale = f_px / (f_px + qz)
        pp_row, pp_col = self.principal_point_px or (0.5 * n_rows, 0.5 * n_cols)
        x = qx * scale - (pp_col - 0.5 * n_cols)
        y = qy * scale - (pp_row - 0.5 * n_rows)
        r2 = x * x + y * y
        k1, k2 = self.radial_k
        p1, p2 = self.decentering_p
        radial = k1 * r2 + k2 * r2 * r2
        dx = x * radial + p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * x * y
        dy = y * radial + p2 * (r2 + 2.0 * y * y) + 2.0 * p1 * x * y
        return (x - dx) / f_px, (y - dy) / f_px


def fit_interior(lab: StaringLab, image_shape, *, grid: int = 65):
    """Least-squares fit of the 20 coefficients to a laboratory camera over the whole array.

    The physical model is sampled on a ``grid x grid`` lattice of pixel positions from edge to
    edge of the array (``u, v`` from -1 to 1) and each cubic is fitted by linear least squares.

    Parameters
    ----------
    lab : StaringLab
    image_shape : (int, int)
        ``(n_rows, n_cols)``.
    grid : int
        Samples per axis (>= 4).

    Returns
    -------
    interior : StaringInterior
    residual : dict
        ``max_px`` and ``rms_px``: the largest and RMS fit residuals over the lattice,
        converted to pixels with the nominal IFOV (``pitch / f``); ``max_rad`` the largest in
        ``tan psi``. A residual above ~0.01 px means the physical model holds terms the cubic
        cannot follow (e.g. ``k2`` on a large array).
    """
    n_rows, n_cols = check_image_shape(image_shape)
    if int(grid) < 4:
        raise InputError("must be >= 4", field="grid")
    t = np.linspace(-1.0, 1.0, int(grid))
    u, v = (a.reshape(-1) for a in np.meshgrid(t, t, indexing="xy"))
    row = 0.5 * n_rows * (1.0 + v)
    col = 0.5 * n_cols * (1.0 + u)
    tx, ty = lab.tangents(row, col, (n_rows, n_cols))
    design = cubic_monomials(u, v)
    coef, *_ = np.linalg.lstsq(design, np.stack([tx, ty], axis=1), rcond=None)
    res = design @ coef - np.stack([tx, ty], axis=1)
    res_px = np.hypot(res[:, 0], res[:, 1]) / lab.ifov_rad
    residual = {
        "max_px": float(res_px.max()),
        "rms_px": float(np.sqrt(np.mean(res_px**2))),
        "max_rad": float(np.abs(res).max()),
    }
    return StaringInterior(coef[:, 0], coef[:, 1]), residual


# --------------------------------------------------------------------------- mirror
@dataclass(frozen=True)
class PointingMirror:
    """A two-axis pointing mirror in front of the camera (seed 000 eq. 3, ``R_ref``).

    The mirror normal in the camera frame is ``n = Rx(angle_x) Ry(angle_y) n0``: the nominal
    normal ``normal_cam`` (normalized here) turned by the two mirror angles about the camera
    Y axis, then X. A line of sight ``l`` leaves the mirror as ``R_ref l`` with the reflection
    ``R_ref = I - 2 n n^T`` (symmetric, its own inverse, determinant -1: a mirror flips the
    image). Turning the normal by ``delta`` about an axis in the mirror plane and normal to the
    plane of incidence turns the reflected view by ``2 delta``.

    Attributes
    ----------
    normal_cam : tuple of 3 float
        Nominal mirror normal in the camera frame (e.g. ``(0, 1, -1)`` for a 45-degree fold
        of the boresight +Z onto +Y).
    angle_x, angle_y : float
        Mirror angles (radians) of this frame.
    """

    normal_cam: tuple[float, float, float] = (0.0, 0.0, -1.0)
    angle_x: float = 0.0
    angle_y: float = 0.0

    def __post_init__(self):
        n = np.asarray(self.normal_cam, dtype=np.float64).reshape(-1)
        if n.size != 3 or not np.all(np.isfinite(n)) or not np.linalg.norm(n) > 0.0:
            raise InputError("needs 3 finite numbers, not all zero", field="mirror.normal_cam")
        object.__setattr__(self, "normal_cam", tuple(float(x) for x in n / np.linalg.norm(n)))
        for name in ("angle_x", "angle_y"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise InputError("must be finite", field=f"mirror.{name}_rad")
            object.__setattr__(self, name, value)

    def normal(self) -> np.ndarray:
        """The mirror normal at this frame's angles.

        Returns
        -------
        ndarray, shape (3,)
            Unit vector in the camera frame.
        """
        return rot_x(self.angle_x) @ rot_y(self.angle_y) @ np.asarray(self.normal_cam)

    def matrix(self) -> np.ndarray:
        """The reflection ``R_ref = I - 2 n n^T``.

        Returns
        -------
        ndarray, shape (3, 3)
            Symmetric, determinant -1.
        """
        n = self.normal()
        return np.eye(3) - 2.0 * np.outer(n, n)

    def with_angles(self, angle_x: float, angle_y: float) -> "PointingMirror":
        """The same mirror at other angles.

        Parameters
        ----------
        angle_x, angle_y : float
            Mirror angles, radians.

        Returns
        -------
        PointingMirror
        """
        return PointingMirror(self.normal_cam, angle_x, angle_y)
