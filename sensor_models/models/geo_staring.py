"""Geostationary area-array staring camera (seed 000 eq. 3-11; seed 002 section 2.1).

All ``n_rows x n_cols`` pixels of a frame are exposed at one instant, ``frame_seconds`` after
the scene epoch. A pixel ``(row, col)`` (continuous, first pixel centre at ``(0.5, 0.5)``) has
normalized focal-plane coordinates

.. math::

    u = \\frac{col - n_{cols}/2}{n_{cols}/2}, \\qquad v = \\frac{row - n_{rows}/2}{n_{rows}/2}

(``-1 .. 1`` across the array: the cubic below is then well conditioned, every monomial being
of order one at the frame edges), and directional angles given by two cubics with 10
coefficients each (seed 000 eq. 4-5, seed 002 section 2.1):

.. math::

    \\tan\\psi_x = a_{00} + a_{10} u + a_{01} v + a_{11} uv + a_{20} u^2 + a_{02} v^2
                 + a_{21} u^2 v + a_{12} u v^2 + a_{30} u^3 + a_{03} v^3

and the same for ``tan psi_y`` with coefficients ``b_ij`` (``a_ij`` multiplies ``u^i v^j``; the
order above is seed 000's ``a_0 .. a_9``). The line of sight in the camera frame is
``(tan psi_x, tan psi_y, 1)`` normalized (camera Z along the boresight towards the scene, X along
increasing columns, Y along increasing rows). It is carried to the Earth-fixed frame by

.. math::

    \\mathbf{d}_{itrf} = C(t)\\, R^{gcrf}_{body}(t)\\, R_{inst}(roll, pitch, yaw)\\,
    R_{ref}\\, \\mathbf{u}_{cam}

where ``R_ref = I - 2 n n^T`` is the reflection on the pointing mirror (optional; its normal
``n`` comes from two mirror angles), ``R_inst R_ref`` is seed 000's generalized installation
matrix (eq. 6), ``R^gcrf_body`` the attitude (built through the orbital frame of eq. 3 when
the attitude is given relative to it) and ``C(t)`` the IAU 2006/2000A GCRF -> ITRF rotation.
Earth views intersect the ray from the satellite position with the ellipsoid at a height or
with a :class:`~sensor_models.terrain.dem.Dem`; star views stop in GCRF and give the object
vector ``R^gcrf_body R_inst R_ref u_cam`` (seed 000 eq. 7-9: the incident direction of a star
is minus the emergent line of sight, so the unit vector towards the star *is* this vector).

Inverse localization (ground or star to image) rotates the object direction ``w`` into the
camera frame, ``(x, y, z) = (R^{itrf}_{body} R_inst R_ref)^T w``, and solves the two equations of
seed 000 eq. 11 (seed 002's ``J``, ``K``)

.. math::

    F(u, v) = (x/z - \\tan\\psi_x(u, v),\\; y/z - \\tan\\psi_y(u, v)) = 0

by Newton's method on the 2-D cubic, vectorized, starting from the ideal pinhole (the linear
terms). The implicit function theorem gives the analytic image-space Jacobian: with ``T'`` the
2x2 derivative of ``(tan psi_x, tan psi_y)`` in ``(u, v)``,
``d(u, v)/dp = T'^{-1} dF/dp``, hence ``d(row, col)/dp`` by the scales ``n/2``.

Calibration parameters: ``installation.roll``, ``installation.pitch``, ``installation.yaw``
(the exterior; :class:`~sensor_models.models.pushbroom_types.Installation`, ``Rz(yaw) Ry(pitch)
Rx(roll)``) and ``interior.tan_psi_x.a00 .. a03``, ``interior.tan_psi_y.b00 .. b03`` (the
interior, in the seed order above).

Object vectors are *apparent* directions (as seen from the moving satellite). Turning catalogue
positions into apparent ones (proper motion, parallax, annual and orbital aberration, ~20
arcsec, several pixels of seed 000's camera) is the caller's job.

References
----------
.. [1] Seed 000: on-orbit geometric calibration of a geostationary camera from the relative
   motion of stars, Sensors 2021: eq. 3 (rigorous model), 4-5 (20-coefficient interior), 6-7
   (generalized installation matrix), 8-9 (object vectors), 11 (residuals); table 1 (camera).
.. [2] Seed 002: image point positioning compensation of a high-orbit thermal infrared
   staring camera, Appl. Sci. 2023: section 2.1 (installation angles alpha, beta, theta and
   the 20-coefficient interior), table 1 (laboratory distortion parameters).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from sensor_models.base import ParameterVector, SensorModel, as_float_arrays
from sensor_models.geometry.ephemeris import Attitude, Orbit
from sensor_models.errors import InputError
from sensor_models.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef
from sensor_models.models.pushbroom_types import Installation, rot_x, rot_y

__all__ = [
    "GF4_LIKE_CAMERA",
    "GF4_LIKE_SHAPE",
    "MONOMIAL_POWERS",
    "SEED000_CAMERA",
    "SEED000_SHAPE",
    "GeoStaringModel",
    "PointingMirror",
    "StaringInterior",
    "StaringLab",
    "example_geo_staring_model",
    "fit_interior",
    "geostationary_orbit",
    "radec_to_vectors",
    "vectors_to_radec",
]

#: points processed at once (bounds temporary memory to a few tens of MB)
CHUNK = 1 << 16
#: powers ``(i, j)`` of ``u^i v^j`` of the ten cubic monomials, in seed 000 eq. 5 order
MONOMIAL_POWERS = ((0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (2, 1), (1, 2), (3, 0), (0, 3))
_SUFFIXES = tuple(f"{i}{j}" for i, j in MONOMIAL_POWERS)
#: Newton solutions are sought within this many half-frames of the array centre
_UV_LIMIT = 4.0
#: Newton stops when the step is below this (normalized units; 5e-11 px for 1024 pixels)
_UV_TOL = 1e-13
#: mean equatorial radius of the geostationary orbit (GM / omega^2)^(1/3), metres
GEO_RADIUS_M = 42_164_172.0


# --------------------------------------------------------------------------- interior
def _monomials(u, v):
    """The ten monomials of seed 000 eq. 5, shape ``u.shape + (10,)``."""
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
        n_rows, n_cols = _check_shape(image_shape)
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


def _check_shape(image_shape) -> tuple[int, int]:
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
        n_rows, n_cols = _check_shape(image_shape)
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
    n_rows, n_cols = _check_shape(image_shape)
    if int(grid) < 4:
        raise InputError("must be >= 4", field="grid")
    t = np.linspace(-1.0, 1.0, int(grid))
    u, v = (a.reshape(-1) for a in np.meshgrid(t, t, indexing="xy"))
    row = 0.5 * n_rows * (1.0 + v)
    col = 0.5 * n_cols * (1.0 + u)
    tx, ty = lab.tangents(row, col, (n_rows, n_cols))
    design = _monomials(u, v)
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


# --------------------------------------------------------------------------- stars
def radec_to_vectors(ra_deg, dec_deg) -> np.ndarray:
    """Unit vectors ``(cos d cos a, cos d sin a, sin d)`` (seed 000 eq. 3 left side).

    Parameters
    ----------
    ra_deg, dec_deg : array_like
        Right ascension ``a`` and declination ``d``, degrees (broadcast together).

    Returns
    -------
    ndarray, shape (..., 3)
    """
    ra, dec = np.radians(np.asarray(ra_deg, dtype=np.float64)), np.radians(np.asarray(dec_deg, dtype=np.float64))
    cd = np.cos(dec)
    return np.stack(np.broadcast_arrays(cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)), axis=-1)


def vectors_to_radec(vectors):
    """Right ascension and declination of direction vectors.

    Parameters
    ----------
    vectors : array_like, shape (..., 3)
        Directions (any length).

    Returns
    -------
    ra_deg : ndarray, shape (...)
        In ``[0, 360)``.
    dec_deg : ndarray, shape (...)
    """
    w = np.asarray(vectors, dtype=np.float64)
    ra = np.degrees(np.arctan2(w[..., 1], w[..., 0])) % 360.0
    dec = np.degrees(np.arctan2(w[..., 2], np.hypot(w[..., 0], w[..., 1])))
    return ra, dec


def _as_vectors(vectors) -> np.ndarray:
    w = np.asarray(vectors, dtype=np.float64)
    if w.ndim == 1:
        w = w[None, :]
    if w.ndim != 2 or w.shape[1] != 3:
        raise InputError(f"must have shape (N, 3), got {np.shape(vectors)}", field="vectors_gcrf")
    if not np.all(np.isfinite(w)):
        raise InputError("holds NaN or infinite values", field="vectors_gcrf")
    norm = np.linalg.norm(w, axis=1)
    if np.any(norm == 0.0):
        raise InputError("holds zero vectors", field="vectors_gcrf")
    return w / norm[:, None]


# --------------------------------------------------------------------------- the model
@lru_cache(maxsize=2048)
def _earth_at(epoch_ns: int, seconds: float):
    """Earth rotation (default IERS tables) over one instant: the models of a frame instant share
    it (a sequence's LAB and TRUE models and their copies are placed at the same instants).

    Parameters
    ----------
    epoch_ns : int
        Epoch, nanoseconds since 1970 (UTC, as ``numpy.datetime64[ns]``).
    seconds : float
        Seconds after the epoch.

    Returns
    -------
    EarthRotation
    """
    from sensor_models.geometry.frames import EarthRotation

    return EarthRotation(np.datetime64(epoch_ns, "ns"), seconds, seconds)


class GeoStaringModel(SensorModel):
    """One frame of a geostationary area-array staring camera (module docstring).

    Parameters
    ----------
    orbit : Orbit
        State vectors (ITRF or GCRF) covering ``frame_seconds``.
    attitude : Attitude
        Body -> reference rotations (GCRF, ITRF or orbital frame) covering ``frame_seconds``.
        The orbital frame (X along the velocity, Z to the Earth's centre) is always built from
        the *inertial* (GCRF) state: a geostationary satellite has almost no ITRF velocity.
    frame_seconds : float
        Exposure instant of the frame, SI seconds since the orbit's epoch.
    interior : StaringInterior or array_like, shape (2, 10)
        The 20 directional-angle coefficients.
    image_shape : (int, int)
        ``(n_rows, n_cols)`` of the array.
    installation : Installation
        Camera -> body angles ``installation.roll|pitch|yaw`` (the exterior parameters).
    mirror : PointingMirror, optional
        Pointing mirror between the camera and the scene (default: none).
    band : str
        Name of the single band (``band=`` arguments must be None or this).
    name : str
        Free text.

    Attributes
    ----------
    position_itrf_m : ndarray, shape (3,)
        Satellite position at the frame instant.
    body_to_itrf, body_to_gcrf : ndarray, shape (3, 3)
        Attitude at the frame instant (``v_itrf = body_to_itrf @ v_body``).
    gcrf_to_itrf : ndarray, shape (3, 3)
    lab, lab_fit_residual : StaringLab, dict or None
        Set by :meth:`from_lab`.

    Notes
    -----
    In the :class:`~sensor_models.base.SensorModel` protocol the model has one band
    (``bands == (band,)``) and one detector array covering the frame (named ``""``); its
    parameter groups are ``"exterior"`` (``installation.roll|pitch|yaw``) and ``"interior"``
    (the 20 coefficients ``interior.tan_psi_x.a<ij>``, ``interior.tan_psi_y.b<ij>``).
    """

    kind = "geo_staring"
    is_rigorous = True

    def __init__(
        self,
        *,
        orbit: Orbit,
        attitude: Attitude,
        frame_seconds: float,
        interior,
        image_shape,
        installation: Installation = Installation(),
        mirror: PointingMirror | None = None,
        band: str = "B1",
        name: str = "",
    ):
        if not isinstance(orbit, Orbit):
            raise InputError("orbit must be an Orbit")
        if not isinstance(attitude, Attitude):
            raise InputError("attitude must be an Attitude")
        if not isinstance(installation, Installation):
            raise InputError("installation must be an Installation")
        if mirror is not None and not isinstance(mirror, PointingMirror):
            raise InputError("mirror must be a PointingMirror or None")
        t = float(frame_seconds)
        if not np.isfinite(t):
            raise InputError("must be finite", field="frame.seconds")
        if not isinstance(interior, StaringInterior):
            arr = np.asarray(interior, dtype=np.float64)
            if arr.shape != (2, 10):
                raise InputError(f"must be a StaringInterior or a (2, 10) array, got shape {arr.shape}", field="interior")
            interior = StaringInterior(arr[0], arr[1])
        self.orbit = orbit
        self.attitude = attitude
        self.epoch = orbit.epoch
        self.frame_seconds = t
        self.interior = interior
        self.n_rows, self.n_cols = _check_shape(image_shape)
        self.installation = installation
        self.mirror = mirror
        self.band = str(band)
        self.name = name
        self.lab = None
        self.lab_fit_residual = None
        self._exterior_at_frame()
        self._update_camera()

    # ------------------------------------------------------------------ construction
    def _exterior_at_frame(self):
        from sensor_models.geometry.frames import orbital_to_frame_mat

        t = np.array([self.frame_seconds])
        earth = _earth_at(int(np.datetime64(self.epoch, "ns").astype(np.int64)), self.frame_seconds)
        c_g2i = earth.gcrf_to_itrf_mat(t)[0]
        pos, vel = self.orbit.state(t)
        if self.orbit.frame == "gcrf":
            pos_g, vel_g = pos, vel
            pos_i = pos @ c_g2i.T
        else:
            pos_i = pos
            pos_g, vel_g = earth.itrf_to_gcrf_state(t, pos, vel)
        att = self.attitude.matrix(t)[0]
        if self.attitude.frame == "gcrf":
            b2g = att
        elif self.attitude.frame == "itrf":
            b2g = c_g2i.T @ att
        else:
            b2g = orbital_to_frame_mat(pos_g, vel_g)[0] @ att
        self.gcrf_to_itrf = c_g2i
        self.position_itrf_m = pos_i[0]
        self.position_gcrf_m = pos_g[0]
        self.body_to_gcrf = b2g
        self.body_to_itrf = c_g2i @ b2g

    def _update_camera(self):
        """Generalized installation ``R_inst R_ref`` (seed 000 eq. 6) and the full rotations."""
        ref = np.eye(3) if self.mirror is None else self.mirror.matrix()
        self._ref = ref
        self.generalized_installation = self.installation.matrix() @ ref
        self._cam_to_itrf = self.body_to_itrf @ self.generalized_installation
        self._cam_to_gcrf = self.body_to_gcrf @ self.generalized_installation

    @classmethod
    def from_lab(cls, lab: StaringLab, *, image_shape, grid: int = 65, **kwargs) -> "GeoStaringModel":
        """A model whose interior is fitted to a laboratory camera (:func:`fit_interior`).

        The fit residual is in ``model.lab_fit_residual`` (``max_px``, ``rms_px``, ``max_rad``).

        Parameters
        ----------
        lab : StaringLab
            Laboratory camera parameters.
        image_shape : (int, int)
            ``(n_rows, n_cols)`` of the array.
        grid : int
            Grid points per axis of the fit.
        **kwargs
            The constructor's other keywords (without ``interior``).

        Returns
        -------
        GeoStaringModel
        """
        interior, residual = fit_interior(lab, image_shape, grid=grid)
        model = cls(interior=interior, image_shape=image_shape, **kwargs)
        model.lab = lab
        model.lab_fit_residual = residual
        return model

    def at_frame(self, frame_seconds: float, *, mirror_angles=None) -> "GeoStaringModel":
        """The same camera at another frame instant (and mirror angles if given).

        Everything else (orbit, attitude, interior, installation) is shared.

        Parameters
        ----------
        frame_seconds : float
            Exposure instant, SI seconds since the orbit's epoch.
        mirror_angles : (float, float), optional
            Pointing-mirror angles ``(x, y)``, radians (the model needs a mirror).

        Returns
        -------
        GeoStaringModel
        """
        new = copy.copy(self)
        new.frame_seconds = float(frame_seconds)
        if not np.isfinite(new.frame_seconds):
            raise InputError("must be finite", field="frame.seconds")
        if mirror_angles is not None:
            if self.mirror is None:
                raise InputError("the model has no pointing mirror", field="mirror_angles")
            ax, ay = (float(a) for a in mirror_angles)
            new.mirror = self.mirror.with_angles(ax, ay)
        new._exterior_at_frame()
        new._update_camera()
        return new

    # ------------------------------------------------------------------ basics
    @property
    def image_shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)`` of the array."""
        return (self.n_rows, self.n_cols)

    @property
    def reference_band(self) -> str:
        """The single band (the push-broom model's attribute of the same name)."""
        return self.band

    @property
    def ifov_rad(self) -> float:
        """Mean angle of one pixel at the array centre (from the linear terms)."""
        a, b = self.interior.tan_psi_x, self.interior.tan_psi_y
        return float(np.sqrt(abs(a[1] * b[2] - a[2] * b[1]) / (0.25 * self.n_rows * self.n_cols)))

    def _band(self, band):
        if band is not None and band != self.band:
            raise InputError(f"unknown band {band!r}; the model has {self.band!r}", field="band")

    def normalized(self, row, col):
        """Normalized frame coordinates of image coordinates (module docstring).

        Parameters
        ----------
        row, col : array_like
            Continuous image coordinates.

        Returns
        -------
        u, v : ndarray
            ``u`` from the columns, ``v`` from the rows; -1 and 1 at the frame's edges.
        """
        hc, hr = 0.5 * self.n_cols, 0.5 * self.n_rows
        return (np.asarray(col, dtype=np.float64) - hc) / hc, (np.asarray(row, dtype=np.float64) - hr) / hr

    def pixel(self, u, v):
        """Image coordinates of normalized coordinates (the inverse of :meth:`normalized`).

        Parameters
        ----------
        u, v : array_like
            Normalized coordinates.

        Returns
        -------
        row, col : ndarray
        """
        hc, hr = 0.5 * self.n_cols, 0.5 * self.n_rows
        return hr * (1.0 + np.asarray(v)), hc * (1.0 + np.asarray(u))

    # ------------------------------------------------------------------ direct
    def look_cam(self, row, col) -> np.ndarray:
        """Unit lines of sight in the camera frame (seed 000 eq. 4).

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates.

        Returns
        -------
        ndarray, shape (N, 3)
        """
        u, v = self.normalized(np.reshape(row, -1), np.reshape(col, -1))
        tx, ty = self.interior.tangents(u, v)
        los = np.stack([tx, ty, np.ones_like(tx)], axis=-1)
        return los / np.linalg.norm(los, axis=1, keepdims=True)

    def rays_itrf(self, row, col):
        """Lines of sight of image points in ITRF.

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates.

        Returns
        -------
        origin_itrf_m : ndarray, shape (N, 3)
            The satellite's position, metres.
        direction_itrf : ndarray, shape (N, 3)
            Unit directions.
        """
        row, col = as_float_arrays(row, col, names=("row", "col"))
        direction = self.look_cam(row, col) @ self._cam_to_itrf.T
        origin = np.broadcast_to(self.position_itrf_m, direction.shape)
        return origin, direction

    def image_to_ground(self, row, col, *, height=None, dem=None, band=None, array=None):
        """Direct localization (see :meth:`SensorModel.image_to_ground`).

        Pixels whose line of sight misses the Earth (or the DEM) give NaN.

        Parameters
        ----------
        row, col : array_like
            Continuous image coordinates.
        height : float or array_like, optional
            Ellipsoidal heights, metres (exactly one of ``height`` and ``dem``).
        dem : sensor_models.terrain.dem.Dem, optional
            Terrain to intersect.
        band : str, optional
            None or the model's band.
        array : str or int, optional
            None, 0 or ``""`` (the frame is one detector array).

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape of the broadcast ``row, col``
        """
        from sensor_models.terrain.ellipsoid import intersect_ellipsoid

        self._band(band)
        self._check_array(band, array)
        if (height is None) == (dem is None):
            raise InputError("give exactly one of height= and dem=")
        shape = np.broadcast(np.asarray(row), np.asarray(col)).shape
        origin, direction = self.rays_itrf(row, col)
        if dem is not None:
            lon, lat, h, _ = dem.intersect(origin, direction)
        else:
            (h_m,) = as_float_arrays(height, names=("height",))
            h_m = np.broadcast_to(h_m, shape).reshape(-1)
            n = direction.shape[0]
            lon, lat, h = np.empty(n), np.empty(n), np.empty(n)
            for a in range(0, n, CHUNK):
                b = a + CHUNK
                xyz = intersect_ellipsoid(origin[a:b], direction[a:b], h_m[a:b])
                with np.errstate(invalid="ignore"):  # rays missing the Earth are NaN
                    lon[a:b], lat[a:b], h[a:b] = ecef_to_geodetic(xyz)
        return lon.reshape(shape), lat.reshape(shape), h.reshape(shape)

    def object_vector_gcrf(self, row, col) -> np.ndarray:
        """Unit object vectors (apparent directions of what the pixels see) in GCRF.

        Seed 000 eq. 7-9: ``R^gcrf_body R_inst R_ref (tan psi_x, tan psi_y, 1)^T`` normalized.

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates.

        Returns
        -------
        ndarray, shape (N, 3)
        """
        row, col = as_float_arrays(row, col, names=("row", "col"))
        return self.look_cam(row, col) @ self._cam_to_gcrf.T

    def object_radec(self, row, col):
        """Right ascension and declination (GCRF) seen by pixels.

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates.

        Returns
        -------
        ra_deg, dec_deg : ndarray, shape (N,)
        """
        return vectors_to_radec(self.object_vector_gcrf(row, col))

    # ------------------------------------------------------------------ inverse
    def _ground_cam(self, lon, lat, h):
        """Camera-frame vectors to ground points, body-frame ones, and visibility."""
        ground = geodetic_to_ecef(lon, lat, h)
        w = ground - self.position_itrf_m
        body = w @ self.body_to_itrf  # R_b2i^T w, row-vector form
        cam = body @ self.generalized_installation
        lam, phi = np.radians(lon), np.radians(lat)
        up = np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)
        # the satellite must be above the point's local horizon (Earth's limb)
        visible = np.einsum("ij,ij->i", up, -w) > 0.0
        return cam, body, visible

    def _cam_to_image(self, cam, usable):
        """Solve the cubic for camera-frame vectors; NaN where unusable or behind."""
        n = cam.shape[0]
        u = np.full(n, np.nan)
        v = np.full(n, np.nan)
        front = usable & (cam[:, 2] > 0.0)
        idx = np.nonzero(front)[0]
        if idx.size:
            z = cam[idx, 2]
            u[idx], v[idx] = self.interior.solve(cam[idx, 0] / z, cam[idx, 1] / z)
        return u, v

    def ground_to_image(self, lon, lat, h, *, band=None, array=None):
        """Inverse localization (see :meth:`SensorModel.ground_to_image`).

        Points behind the Earth's limb, behind the camera, or whose solution lies more than
        four half-frames from the array centre give NaN. Points outside the frame but within
        that range get their (extrapolated) coordinates: filter with :attr:`image_shape`.

        Parameters
        ----------
        lon, lat : array_like
            WGS84 longitude and latitude, degrees.
        h : array_like
            Height above the ellipsoid, metres.
        band : str, optional
            None or the model's band.
        array : str or int, optional
            None, 0 or ``""``.

        Returns
        -------
        row, col : ndarray, shape of the broadcast inputs
        """
        self._band(band)
        self._check_array(band, array)
        lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
        shape = lon.shape
        lon, lat, h = lon.reshape(-1), lat.reshape(-1), h.reshape(-1)
        row = np.empty(lon.size)
        col = np.empty(lon.size)
        for a in range(0, lon.size, CHUNK):
            b = a + CHUNK
            cam, _, visible = self._ground_cam(lon[a:b], lat[a:b], h[a:b])
            u, v = self._cam_to_image(cam, visible)
            row[a:b], col[a:b] = self.pixel(u, v)
        return row.reshape(shape), col.reshape(shape)

    def star_to_image(self, vectors_gcrf=None, *, ra_deg=None, dec_deg=None):
        """Image coordinates of stars (apparent GCRF directions): the inverse of
        :meth:`object_vector_gcrf`.

        Parameters
        ----------
        vectors_gcrf : array_like, shape (N, 3), optional
            Directions towards the stars (normalized here).
        ra_deg, dec_deg : array_like, shape (N,), optional
            Instead of ``vectors_gcrf``: right ascension and declination in degrees.

        Returns
        -------
        row, col : ndarray, shape (N,)
            NaN for stars behind the camera or far outside the frame.
        """
        w = self._star_vectors(vectors_gcrf, ra_deg, dec_deg)
        row = np.empty(w.shape[0])
        col = np.empty(w.shape[0])
        for a in range(0, w.shape[0], CHUNK):
            cam = w[a : a + CHUNK] @ self._cam_to_gcrf
            u, v = self._cam_to_image(cam, np.ones(cam.shape[0], dtype=bool))
            row[a : a + CHUNK], col[a : a + CHUNK] = self.pixel(u, v)
        return row, col

    @staticmethod
    def _star_vectors(vectors_gcrf, ra_deg, dec_deg):
        radec = (ra_deg is not None, dec_deg is not None)
        if (vectors_gcrf is not None and any(radec)) or (vectors_gcrf is None and not all(radec)):
            raise InputError("give either vectors_gcrf or both ra_deg= and dec_deg=")
        if vectors_gcrf is None:
            ra, dec = as_float_arrays(ra_deg, dec_deg, names=("ra_deg", "dec_deg"))
            vectors_gcrf = radec_to_vectors(ra.reshape(-1), dec.reshape(-1))
        return _as_vectors(vectors_gcrf)

    # ------------------------------------------------------------------ parameters
    def parameter_groups(self) -> dict[str, tuple[str, ...]]:
        """``"exterior"`` (installation angles) and ``"interior"`` (20 coefficients).

        Returns
        -------
        dict of str to tuple of str
            Ordered as :meth:`parameter_names`.
        """
        return {
            "exterior": tuple(f"installation.{a}" for a in Installation.NAMES),
            "interior": tuple([f"interior.tan_psi_x.a{s}" for s in _SUFFIXES]
                              + [f"interior.tan_psi_y.b{s}" for s in _SUFFIXES]),
        }

    def interior_group(self, band=None, array=None) -> str:
        """The group of the frame's interior coefficients.

        Parameters
        ----------
        band : str, optional
            None or the model's band.
        array : str or int, optional
            None, 0 or ``""``.

        Returns
        -------
        str
            ``"interior"``.
        """
        self._one_array(band, array)
        return "interior"

    def parameter_names(self) -> tuple[str, ...]:
        """Installation angles then interior coefficients.

        Returns
        -------
        tuple of str
            ``installation.roll|pitch|yaw`` (radians), ``interior.tan_psi_x.a<ij>`` and
            ``interior.tan_psi_y.b<ij>`` (dimensionless), 23 names.
        """
        names = [f"installation.{a}" for a in Installation.NAMES]
        names += [f"interior.tan_psi_x.a{s}" for s in _SUFFIXES]
        names += [f"interior.tan_psi_y.b{s}" for s in _SUFFIXES]
        return tuple(names)

    def interior_parameter_names(self, degree: int = 3) -> tuple[str, ...]:
        """Interior names of the monomials of total degree ``<= degree``.

        Parameters
        ----------
        degree : int
            0 to 3.

        Returns
        -------
        tuple of str
            The ``tan_psi_x`` names, then the ``tan_psi_y`` ones.
        """
        if not 0 <= int(degree) <= 3:
            raise InputError(f"must be 0..3, got {degree}", field="degree")
        keep = [s for (i, j), s in zip(MONOMIAL_POWERS, _SUFFIXES) if i + j <= int(degree)]
        return tuple([f"interior.tan_psi_x.a{s}" for s in keep] + [f"interior.tan_psi_y.b{s}" for s in keep])

    def parameters(self) -> ParameterVector:
        """The installation angles and interior coefficients.

        Returns
        -------
        ParameterVector
            In the order of :meth:`parameter_names`.
        """
        values = np.concatenate([self.installation.as_array(), self.interior.tan_psi_x, self.interior.tan_psi_y])
        return ParameterVector(self.parameter_names(), values)

    def with_parameters(self, values) -> "GeoStaringModel":
        """A copy with new installation angles and interior coefficients (shares the exterior).

        Parameters
        ----------
        values : array_like, shape (23,)
            In the order of :meth:`parameter_names`; finite.

        Returns
        -------
        GeoStaringModel
        """
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if values.size != 23:
            raise InputError(f"expected 23 parameter values, got {values.size}")
        if not np.all(np.isfinite(values)):
            raise InputError("parameter values must be finite")
        new = copy.copy(self)
        new.installation = Installation(*values[:3])
        new.interior = StaringInterior(values[3:13], values[13:23])
        new._update_camera()
        return new

    def gauge_rows(self):
        """Linear functionals of the parameters that the exterior and interior share.

        A small rotation of the camera shifts every pixel's look: roll and pitch move the mean
        ``tan psi`` over the frame, yaw turns it. Holding these three functionals of the
        interior fixes the camera frame when both groups are estimated together.

        Returns
        -------
        rows : ndarray, shape (3, 23)
            Over :meth:`parameter_names`: the mean of ``tan psi_x`` and of ``tan psi_y`` over
            the frame (``u, v`` uniform in [-1, 1]: ``E[u^2] = 1/3``), and the in-plane rotation
            ``(a01 / (n_rows/2) - b10 / (n_cols/2)) / 2`` (a rotation ``epsilon`` of the
            camera about its boresight changes it by ``-epsilon * ifov``).
        scale_rad : ndarray, shape (3,)
            One pixel in each functional: ``ifov`` for the means, and for the rotation the
            ``ifov / (n/2)`` that moves the frame edge by one pixel. Use ``sigma_px * scale_rad``
            as the pseudo-observations' standard deviations.
        """
        rows = np.zeros((3, 23))
        mean = {"00": 1.0, "20": 1.0 / 3.0, "02": 1.0 / 3.0}
        for k, s in enumerate(_SUFFIXES):
            if s in mean:
                rows[0, 3 + k] = mean[s]
                rows[1, 13 + k] = mean[s]
        rows[2, 3 + 2] = 0.5 / (0.5 * self.n_rows)  # a01 / (n_rows / 2): d tan psi_x per row
        rows[2, 13 + 1] = -0.5 / (0.5 * self.n_cols)  # b10 / (n_cols / 2): d tan psi_y per col
        ifov = self.ifov_rad
        return rows, np.array([ifov, ifov, ifov / (0.5 * max(self.n_rows, self.n_cols))])

    # ------------------------------------------------------------------ Jacobians
    def _names(self, names):
        all_names = self.parameter_names()
        names = all_names if names is None else tuple(names)
        lookup = {n: i for i, n in enumerate(all_names)}
        unknown = [n for n in names if n not in lookup]
        if unknown:
            raise InputError(f"unknown parameters: {', '.join(unknown)}")
        return names, [lookup[n] for n in names]

    def _jacobian(self, cam, body, u, v, positions):
        """``d(row, col)/dp`` at solutions ``(u, v)`` for the parameter ``positions``, (N, 2, P)."""
        n = u.size
        xu, xv, yu, yv = self.interior.derivatives(u, v)
        det = xu * yv - xv * yu
        # T'^-1 = [[yv, -xv], [-yu, xu]] / det
        inv = np.stack([np.stack([yv, -xv], -1), np.stack([-yu, xu], -1)], 1) / det[:, None, None]
        dfdp = np.zeros((n, 2, len(positions)))
        x, y, z = cam[:, 0], cam[:, 1], cam[:, 2]
        d_inst = self.installation.matrix_derivatives()
        mono = None
        for j, k in enumerate(positions):
            if k < 3:
                dcam = body @ (d_inst[k] @ self._ref)  # d(M^T body) as a row vector
                dfdp[:, 0, j] = (dcam[:, 0] * z - x * dcam[:, 2]) / (z * z)
                dfdp[:, 1, j] = (dcam[:, 1] * z - y * dcam[:, 2]) / (z * z)
            else:
                if mono is None:
                    mono = _monomials(u, v)
                comp, m = divmod(k - 3, 10)
                dfdp[:, comp, j] = -mono[:, m]
        duv = np.einsum("nij,njp->nip", inv, dfdp)  # rows: (du, dv)
        jac = np.empty_like(duv)
        jac[:, 0] = 0.5 * self.n_rows * duv[:, 1]
        jac[:, 1] = 0.5 * self.n_cols * duv[:, 0]
        return jac

    def image_jacobian(self, lon, lat, h, *, band=None, names=None, array=None):
        """Analytic ``d(row, col)/d(parameters)`` at the projections of ground points.

        Parameters
        ----------
        lon, lat, h : array_like, shape (N,)
            Ground points: degrees, degrees, metres above the ellipsoid.
        band : str, optional
            None or the model's band.
        names : sequence of str, optional
            Parameters (default: all).
        array : str or int, optional
            None, 0 or ``""``.

        Returns
        -------
        row, col : ndarray, shape (N,)
            As :meth:`ground_to_image` (NaN where not imaged).
        jac : ndarray, shape (N, 2, P)
            For ``names`` (default: all, in :meth:`parameter_names` order); zero where not
            imaged.
        """
        self._band(band)
        self._check_array(band, array)
        names, positions = self._names(names)
        lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
        lon, lat, h = lon.reshape(-1), lat.reshape(-1), h.reshape(-1)
        n = lon.size
        row = np.full(n, np.nan)
        col = np.full(n, np.nan)
        jac = np.zeros((n, 2, len(names)))
        for a in range(0, n, CHUNK):
            b = min(a + CHUNK, n)
            cam, body, visible = self._ground_cam(lon[a:b], lat[a:b], h[a:b])
            u, v = self._cam_to_image(cam, visible)
            row[a:b], col[a:b] = self.pixel(u, v)
            ok = np.nonzero(np.isfinite(u))[0]
            if ok.size:
                jac[a + ok] = self._jacobian(cam[ok], body[ok], u[ok], v[ok], positions)
        return row, col, jac

    def star_jacobian(self, vectors_gcrf=None, *, ra_deg=None, dec_deg=None, names=None):
        """Analytic ``d(row, col)/d(parameters)`` at the images of stars (fixed GCRF vectors).

        Parameters
        ----------
        vectors_gcrf : array_like, shape (N, 3), optional
            Directions towards the stars.
        ra_deg, dec_deg : array_like, shape (N,), optional
            Instead of ``vectors_gcrf``: right ascension and declination in degrees.
        names : sequence of str, optional
            Parameters (default: all).

        Returns
        -------
        row, col : ndarray, shape (N,)
        jac : ndarray, shape (N, 2, P)
        """
        names, positions = self._names(names)
        w = self._star_vectors(vectors_gcrf, ra_deg, dec_deg)
        n = w.shape[0]
        row = np.full(n, np.nan)
        col = np.full(n, np.nan)
        jac = np.zeros((n, 2, len(names)))
        for a in range(0, n, CHUNK):
            b = min(a + CHUNK, n)
            body = w[a:b] @ self.body_to_gcrf
            cam = body @ self.generalized_installation
            u, v = self._cam_to_image(cam, np.ones(b - a, dtype=bool))
            row[a:b], col[a:b] = self.pixel(u, v)
            ok = np.nonzero(np.isfinite(u))[0]
            if ok.size:
                jac[a + ok] = self._jacobian(cam[ok], body[ok], u[ok], v[ok], positions)
        return row, col, jac

    def __repr__(self):
        mirror = "" if self.mirror is None else ", mirror"
        return (
            f"GeoStaringModel({self.name!r}, {self.n_rows}x{self.n_cols}, "
            f"t={self.frame_seconds:g} s{mirror})"
        )


# --------------------------------------------------------------------------- synthetic
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
    from sensor_models.models.synthetic import earth_pointing_attitude

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
