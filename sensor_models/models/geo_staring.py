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

The camera (interior cubic, laboratory model, pointing mirror) is in
:mod:`sensor_models.models.staring_camera`, the inverse kernels and the Jacobian in
:mod:`sensor_models.models.staring_inverse`, star directions in
:mod:`sensor_models.models.star_directions`, and example models
(:func:`~sensor_models.models.synthetic.example_geo_staring_model`) in
:mod:`sensor_models.models.synthetic`.

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
from functools import lru_cache

import numpy as np

from sensor_models.base import ParameterVector, SensorModel, as_float_arrays
from sensor_models.geometry.ephemeris import Attitude, Orbit
from sensor_models.errors import InputError
from sensor_models.geometry.geodesy import ecef_to_geodetic
from sensor_models.models.pushbroom_types import Installation
from sensor_models.models.star_directions import star_unit_vectors, vectors_to_radec
from sensor_models.models.staring_inverse import camera_to_frame, frame_jacobian, ground_to_camera
from sensor_models.models.staring_camera import (
    MONOMIAL_POWERS,
    MONOMIAL_SUFFIXES,
    PointingMirror,
    StaringInterior,
    StaringLab,
    check_image_shape,
    fit_interior,
)

__all__ = ["GeoStaringModel"]

#: points processed at once (bounds temporary memory to a few tens of MB)
CHUNK = 1 << 16


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
    generalized_installation, mirror_reflection : ndarray, shape (3, 3)
        ``R_inst R_ref`` (seed 000 eq. 6) and ``R_ref`` (the identity without a mirror).
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
        self.n_rows, self.n_cols = check_image_shape(image_shape)
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
        self.mirror_reflection = ref
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
            cam, _, visible = ground_to_camera(self, lon[a:b], lat[a:b], h[a:b])
            u, v = camera_to_frame(self, cam, visible)
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
        w = star_unit_vectors(vectors_gcrf, ra_deg, dec_deg)
        row = np.empty(w.shape[0])
        col = np.empty(w.shape[0])
        for a in range(0, w.shape[0], CHUNK):
            cam = w[a : a + CHUNK] @ self._cam_to_gcrf
            u, v = camera_to_frame(self, cam, np.ones(cam.shape[0], dtype=bool))
            row[a : a + CHUNK], col[a : a + CHUNK] = self.pixel(u, v)
        return row, col

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
            "interior": tuple([f"interior.tan_psi_x.a{s}" for s in MONOMIAL_SUFFIXES]
                              + [f"interior.tan_psi_y.b{s}" for s in MONOMIAL_SUFFIXES]),
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
        names += [f"interior.tan_psi_x.a{s}" for s in MONOMIAL_SUFFIXES]
        names += [f"interior.tan_psi_y.b{s}" for s in MONOMIAL_SUFFIXES]
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
        keep = [s for (i, j), s in zip(MONOMIAL_POWERS, MONOMIAL_SUFFIXES) if i + j <= int(degree)]
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
        for k, s in enumerate(MONOMIAL_SUFFIXES):
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
            cam, body, visible = ground_to_camera(self, lon[a:b], lat[a:b], h[a:b])
            u, v = camera_to_frame(self, cam, visible)
            row[a:b], col[a:b] = self.pixel(u, v)
            ok = np.nonzero(np.isfinite(u))[0]
            if ok.size:
                jac[a + ok] = frame_jacobian(self, cam[ok], body[ok], u[ok], v[ok], positions)
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
        w = star_unit_vectors(vectors_gcrf, ra_deg, dec_deg)
        n = w.shape[0]
        row = np.full(n, np.nan)
        col = np.full(n, np.nan)
        jac = np.zeros((n, 2, len(names)))
        for a in range(0, n, CHUNK):
            b = min(a + CHUNK, n)
            body = w[a:b] @ self.body_to_gcrf
            cam = body @ self.generalized_installation
            u, v = camera_to_frame(self, cam, np.ones(b - a, dtype=bool))
            row[a:b], col[a:b] = self.pixel(u, v)
            ok = np.nonzero(np.isfinite(u))[0]
            if ok.size:
                jac[a + ok] = frame_jacobian(self, cam[ok], body[ok], u[ok], v[ok], positions)
        return row, col, jac

    def __repr__(self):
        mirror = "" if self.mirror is None else ", mirror"
        return (
            f"GeoStaringModel({self.name!r}, {self.n_rows}x{self.n_cols}, "
            f"t={self.frame_seconds:g} s{mirror})"
        )


