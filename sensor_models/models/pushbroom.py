"""Linear-array push-broom directional-angle model (seed 003 eq. 1-3).

For an image point ``(row, col)`` of band ``b`` seen by CCD ``c``:

.. math::

    t = t_{ref} + (row - row_{ref})\\,\\Delta t, \\qquad s = col - col_{c} - 0.5

    \\mathbf{u}_{cam} = (\\tan\\psi_x(s), \\tan\\psi_y(s), 1)^T,
    \\qquad \\tan\\psi_{x,y}(s) = \\sum_k c_{k} s^k

    \\mathbf{X}_{itrf} = \\mathbf{P}_{itrf}(t) + \\lambda\\, R^{itrf}_{body}(t)\\,
    R^{body}_{cam}(roll, pitch, yaw)\\, \\mathbf{u}_{cam}

which is seed 003 eq. 3 read from the camera to the ground. ``R^{itrf}_{body}`` is built from
the attitude samples (body -> GCRF, ITRF or orbital frame) and, for GCRF, the IAU 2006/2000A
celestial-to-terrestrial rotation (:mod:`sensor_models.geometry.frames`).

Implementation: at construction the satellite position ``P_itrf`` and ``R_body_to_itrf`` are
tabulated at every image line (plus a margin) and interpolated with a C1 cubic (Catmull-Rom) in
the row, whose error is far below 1e-9 of the values for line periods of milliseconds. That makes
every evaluation a few vectorized multiply-adds, gives analytic derivatives in the row, and keeps
the frame computations (ERFA) out of the hot path.

Inverse localization solves, for each ground point ``G``, the two collinearity conditions

.. math::

    F(row, s) = \\left(\\frac{v_x}{v_z} - \\tan\\psi_x(s),\\;
                       \\frac{v_y}{v_z} - \\tan\\psi_y(s)\\right) = 0,
    \\qquad \\mathbf{v} = (R^{itrf}_{body} R^{body}_{cam})^T (\\mathbf{G} - \\mathbf{P})

by Newton's method (quadratic convergence, vectorized over points). The implicit-function
theorem gives the analytic image-space Jacobian with respect to the installation angles and the
directional-angle coefficients: ``d(row, s)/dp = -J_{(row,s)}^{-1} \\partial F / \\partial p``.

The line table is :class:`~sensor_models.models.line_table.LineTable`; the inverse localization
and the Jacobians are in :mod:`sensor_models.models.pushbroom_inverse`; one CCD seen as a model of
its own image is :class:`~sensor_models.models.ccd_view.CcdView` (:meth:`PushbroomModel.detector_view`).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from types import MappingProxyType

import numpy as np

from sensor_models.models.attitude_correction import AttitudeCorrection, rotation_matrices
from sensor_models.base import ParameterVector, SensorModel, array_positions, as_float_arrays
from sensor_models.geometry.ephemeris import Attitude, Orbit
from sensor_models.errors import InputError, OutOfRangeError
from sensor_models.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef
from sensor_models.models.ccd_view import CcdView
from sensor_models.models.line_table import LineTable
from sensor_models.models.pushbroom_inverse import (
    CHUNK,
    body_angle_jacobian,
    ccd_chunk,
    ground_to_image_chunk,
    parameter_jacobian,
)
from sensor_models.models.pushbroom_types import CcdLook, Installation, LineTiming

__all__ = ["PushbroomModel"]

#: lines tabulated beyond each end of the image (clipped to the orbit/attitude span)
MIN_ROW_MARGIN = 64
#: at most this many knots in the line table (the knot spacing grows beyond)
MAX_KNOTS = 400_000


class PushbroomModel(SensorModel):
    """Push-broom camera with several CCDs and bands, directional-angle interior.

    Parameters
    ----------
    orbit : Orbit
        State vectors (ITRF or GCRF).
    attitude : Attitude
        Body -> reference rotations (GCRF, ITRF or orbital frame).
    line_timing : LineTiming
        Row -> time model shared by all bands.
    bands : mapping of str to sequence of CcdLook
        Per band, the CCDs with their columns in the band raster and directional-angle
        polynomials. CCD column ranges within a band must not overlap.
    installation : Installation
        Camera -> body installation angles (the exterior calibration parameters).
    n_rows : int
        Number of image lines.
    reference_band : str, optional
        Default band of the methods (default: the first band).
    name : str
        Free text (scene or camera identifier).
    attitude_correction : AttitudeCorrection, optional
        Time-varying body-frame correction of the attitude (drift or spline,
        :mod:`sensor_models.models.attitude_correction`); its coefficients are the parameter group
        ``"attitude"`` (``attitude.<roll|pitch|yaw>.k<j>``, radians), after the interior groups.

    Notes
    -----
    The model is defined for rows within the image plus a margin of ``max(64, 5 %)`` lines
    (clipped to the orbit and attitude spans). ``image_to_ground`` raises
    :class:`OutOfRangeError` outside it; ``ground_to_image`` returns NaN for ground points
    not imaged within it.

    In the :class:`~sensor_models.base.SensorModel` protocol the detector arrays are the CCDs
    (:class:`CcdLook`; every method names one with ``array=``), and the parameter groups are
    ``"exterior"`` (``installation.roll|pitch|yaw``) then one ``"interior.<band>.<ccd>"`` per
    CCD of each band (``<band>.<ccd>.tan_psi_x.c0`` ... ``<band>.<ccd>.tan_psi_y.c3``).
    """

    kind = "pushbroom"
    is_rigorous = True

    def __init__(
        self,
        *,
        orbit: Orbit,
        attitude: Attitude,
        line_timing: LineTiming,
        bands: Mapping[str, Sequence[CcdLook]],
        installation: Installation = Installation(),
        n_rows: int,
        reference_band: str | None = None,
        name: str = "",
        attitude_correction: AttitudeCorrection | None = None,
    ):
        if not isinstance(orbit, Orbit):
            raise InputError("orbit must be an Orbit")
        if not isinstance(attitude, Attitude):
            raise InputError("attitude must be an Attitude")
        if int(n_rows) < 1:
            raise InputError("must be >= 1", field="n_rows")
        self.orbit = orbit
        self.attitude = attitude
        self.line_timing = line_timing
        self.installation = installation
        self.n_rows = int(n_rows)
        self.name = name
        self.epoch = orbit.epoch
        self._looks = self._check_bands(bands)
        if reference_band is None:
            reference_band = next(iter(self._looks))
        if reference_band not in self._looks:
            raise InputError(f"unknown band {reference_band!r}", field="reference_band")
        self._reference_band = reference_band
        self.n_cols = max(ccd.last_col for ccds in self.bands.values() for ccd in ccds)
        self._table = self._build_table()
        if attitude_correction is not None and not isinstance(attitude_correction, AttitudeCorrection):
            raise InputError("must be an AttitudeCorrection", field="attitude_correction")
        self.attitude_correction = attitude_correction

    # ------------------------------------------------------------------ construction
    @staticmethod
    def _check_bands(bands) -> dict[str, tuple[CcdLook, ...]]:
        if not isinstance(bands, Mapping) or not bands:
            raise InputError("needs at least one band", field="bands")
        out = {}
        for band, ccds in bands.items():
            ccds = tuple(ccds)
            if not ccds or not all(isinstance(c, CcdLook) for c in ccds):
                raise InputError("needs one or more CcdLook", field=f"bands.{band}")
            names = [c.name for c in ccds]
            if len(set(names)) != len(names):
                raise InputError("CCD names must be unique", field=f"bands.{band}")
            ordered = sorted(ccds, key=lambda c: c.first_col)
            for a, b in zip(ordered, ordered[1:]):
                if b.first_col < a.last_col:
                    raise InputError(
                        f"CCD {b.name} columns overlap CCD {a.name}", field=f"bands.{band}"
                    )
            out[str(band)] = tuple(ordered)
        return out

    def _build_table(self) -> LineTable:
        lt = self.line_timing
        t_lo = max(self.orbit.span[0], self.attitude.span[0])
        t_hi = min(self.orbit.span[1], self.attitude.span[1])
        if t_hi <= t_lo:
            raise InputError("orbit and attitude time spans do not overlap", field="attitude.seconds")
        row_a, row_b = sorted((float(lt.row(t_lo)), float(lt.row(t_hi))))
        margin = max(MIN_ROW_MARGIN, 0.05 * self.n_rows)
        lo = max(row_a, 0.0 - margin)
        hi = min(row_b, self.n_rows + margin)
        step = max(1.0, (hi - lo) / (MAX_KNOTS - 1))
        n_knots = int(np.floor((hi - lo) / step)) + 1
        if n_knots < 4 or lo + step > 0.0 or lo + (n_knots - 2) * step < self.n_rows:
            t0, t1 = lt.seconds(0.0), lt.seconds(float(self.n_rows))
            raise OutOfRangeError(
                f"the orbit and attitude data [{t_lo:.3f}, {t_hi:.3f}] s do not cover the image "
                f"lines [{min(t0, t1):.3f}, {max(t0, t1):.3f}] s plus one line on each side"
            )
        rows = lo + step * np.arange(n_knots)
        seconds = lt.seconds(rows)
        pos_itrf, rot_body_to_itrf = self._exterior_at(seconds)
        values = np.concatenate([pos_itrf, rot_body_to_itrf.reshape(-1, 9)], axis=1)
        return LineTable(lo, step, values)

    def _exterior_at(self, seconds):
        """Exact ``P_itrf`` (N,3) and ``R_body_to_itrf`` (N,3,3) at ``seconds``."""
        from sensor_models.geometry.frames import EarthRotation, orbital_to_frame_mat

        earth = None
        if self.orbit.frame == "gcrf" or self.attitude.frame == "gcrf":
            earth = EarthRotation(self.epoch, float(seconds.min()), float(seconds.max()))
        pos, vel = self.orbit.state(seconds)
        if self.orbit.frame == "gcrf":
            pos_itrf, _ = earth.gcrf_to_itrf_state(seconds, pos, vel)
        else:
            pos_itrf = pos
        att = self.attitude.matrix(seconds)
        if self.attitude.frame == "itrf":
            rot = att
        elif self.attitude.frame == "gcrf":
            rot = earth.gcrf_to_itrf_mat(seconds) @ att
        else:  # orbital frame built from the orbit's own state vectors
            rot = orbital_to_frame_mat(pos, vel) @ att
            if self.orbit.frame == "gcrf":
                rot = earth.gcrf_to_itrf_mat(seconds) @ rot
        return pos_itrf, rot

    # ------------------------------------------------------------------ basics
    @property
    def image_shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)``: image lines and the columns of the widest band."""
        return (self.n_rows, self.n_cols)

    @property
    def bands(self) -> Mapping[str, tuple[CcdLook, ...]]:
        """Read-only mapping band name -> its CCDs ordered by first column.

        Its keys are the protocol's band names (iterate it, or ``tuple(model.bands)``).
        """
        return MappingProxyType(self._looks)

    @property
    def reference_band(self) -> str:
        """The band used when a method gets ``band=None``."""
        return self._reference_band

    @property
    def row_range(self) -> tuple[float, float]:
        """Rows over which the model is defined (image plus margin)."""
        return (self._table.row_min, self._table.row_max)

    def band_ccds(self, band: str | None = None) -> tuple[CcdLook, ...]:
        """The CCDs of a band, ordered by first column.

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.

        Returns
        -------
        tuple of CcdLook
        """
        return self._looks[self._band(band)]

    def detector_arrays(self, band: str | None = None) -> tuple[CcdLook, ...]:
        """The CCDs of a band (:meth:`SensorModel.detector_arrays`; same as :meth:`band_ccds`).

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.

        Returns
        -------
        tuple of CcdLook
            Each a :class:`~sensor_models.base.DetectorArray`.
        """
        return self.band_ccds(band)

    def detector_index(self, col, *, band=None, array=None) -> np.ndarray:
        """Index of the CCD that images each column (:meth:`ccd_index` with ``ccd=array``).

        Parameters
        ----------
        col : array_like, shape (N,)
            Continuous image columns.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Forces the CCD (name or index, or one per point).

        Returns
        -------
        ndarray of intp, shape of ``col``
        """
        return self.ccd_index(col, band=band, array=array)

    def detector_view(self, band=None, array=None) -> "CcdView":
        """One CCD of one band as a model of its own image (columns ``0 .. n_detectors``).

        A stitched multi-CCD raster maps the ground discontinuously where CCDs overlap, so an
        RPC (or any smooth approximation) describes one CCD at a time.

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int, optional
            CCD name or index; may be omitted when the band has one CCD.

        Returns
        -------
        CcdView
        """
        return CcdView(self, band=self._band(band), ccd=self._one_array(band, array))

    def _band(self, band):
        if band is None:
            return self.reference_band
        if band not in self.bands:
            raise InputError(f"unknown band {band!r}; the model has {', '.join(self.bands)}", field="band")
        return band

    def ccd_index(self, col, *, band=None, array=None) -> np.ndarray:
        """Index (in ``band_ccds(band)``) of the CCD that images each column.

        A column inside a CCD's range belongs to it; a column outside every CCD belongs to the
        nearest CCD (its polynomial is extrapolated).

        Parameters
        ----------
        col : array_like, shape (N,)
            Continuous image columns.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Forces the choice: a name, an index, or an array of names or indices.

        Returns
        -------
        ndarray of intp, shape of ``col``
        """
        ccds = self.band_ccds(band)
        col = np.asarray(col, dtype=np.float64)
        if array is not None:
            return array_positions(ccds, array, col.shape, noun="CCD", field="array")
        firsts = np.array([c.first_col for c in ccds], dtype=np.float64)
        lasts = np.array([c.last_col for c in ccds], dtype=np.float64)
        dist = np.maximum(firsts[None, :] - col.reshape(-1, 1), col.reshape(-1, 1) - lasts[None, :])
        return np.argmin(np.maximum(dist, 0.0) + 1e-9 * np.arange(len(ccds)), axis=1).reshape(col.shape)

    # ------------------------------------------------------------------ attitude correction
    def correction_at_rows(self, row, *, derivative: bool = True):
        """The attitude correction's rotation at image rows.

        Parameters
        ----------
        row : ndarray, shape (N,)
            Continuous image rows.
        derivative : bool
            Also return the derivatives.

        Returns
        -------
        tuple or ndarray or None
            ``C(delta(t))`` (N,3,3) and, with ``derivative``, ``dC/ddelta`` (3,N,3,3) and
            ``ddelta/drow`` (N,3); None without a correction.
        """
        corr = self.attitude_correction
        if corr is None:
            return None
        seconds = self.line_timing.seconds(row)
        if not derivative:
            return rotation_matrices(corr.angles(seconds), derivatives=False)
        angles, rates = corr.angles(seconds, derivative=True)
        c, dc = rotation_matrices(angles)
        return c, dc, rates * self.line_timing.line_period_s

    def exterior_at_rows(self, row, *, derivative: bool = False):
        """``P_itrf`` and the corrected ``R_body_to_itrf`` (and row derivatives) at ``row``.

        Interpolated in the line table, then multiplied by the attitude correction if any.

        Parameters
        ----------
        row : array_like, shape (N,)
            Continuous image rows within :attr:`row_range`.
        derivative : bool
            Also return the derivatives in the row.

        Returns
        -------
        p : ndarray, shape (N, 3)
            Satellite positions, metres.
        r : ndarray, shape (N, 3, 3)
            Body -> ITRF rotations.
        dp, dr : ndarray, shapes (N, 3) and (N, 3, 3)
            With ``derivative``: their derivatives per row.
        """
        row = np.asarray(row, dtype=np.float64).reshape(-1)
        out = self._table.evaluate(row, derivative=derivative)
        corr = self.correction_at_rows(row, derivative=derivative)
        if corr is None:
            return out
        if not derivative:
            p, r = out
            return p, r @ corr
        c, dc, rates = corr
        p, r, dp, dr = out
        dc_row = np.einsum("anij,na->nij", dc, rates)
        return p, r @ c, dp, dr @ c + r @ dc_row

    # ------------------------------------------------------------------ direct
    def _check_rows(self, row):
        lo, hi = self.row_range
        bad = (row < lo) | (row > hi)
        if np.any(bad):
            raise OutOfRangeError(
                f"row {row[bad][0]:.3f} lies outside the rows the orbit and attitude data cover "
                f"[{lo:.3f}, {hi:.3f}]"
            )

    def look_cam(self, col, *, band=None, array=None) -> np.ndarray:
        """Unit lines of sight in the camera frame for image columns.

        Parameters
        ----------
        col : array_like, shape (N,)
            Continuous image columns.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Forces the CCD (see :meth:`ccd_index`).

        Returns
        -------
        ndarray, shape (N, 3)
            Unit vectors in the camera frame (seed 003 eq. 1).
        """
        ccds = self.band_ccds(band)
        col = np.asarray(col, dtype=np.float64).reshape(-1)
        idx = self.ccd_index(col, band=band, array=array).reshape(-1)
        los = np.empty((col.size, 3))
        los[:, 2] = 1.0
        for i, c in enumerate(ccds):
            sel = idx == i
            if np.any(sel):
                tx, ty, _, _ = c.look(c.detector_index(col[sel]))
                los[sel, 0] = tx
                los[sel, 1] = ty
        return los / np.linalg.norm(los, axis=1, keepdims=True)

    def rays_itrf(self, row, col, *, band=None, array=None):
        """Lines of sight of image points in ITRF.

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Forces the CCD (see :meth:`ccd_index`).

        Returns
        -------
        origin_itrf_m : ndarray, shape (N, 3)
            Satellite positions, metres.
        direction_itrf : ndarray, shape (N, 3)
            Unit directions.

        Raises
        ------
        OutOfRangeError
            A row lies outside :attr:`row_range`.
        """
        row, col = as_float_arrays(row, col, names=("row", "col"))
        row, col = row.reshape(-1), col.reshape(-1)
        self._check_rows(row)
        los_body = self.look_cam(col, band=band, array=array) @ self.installation.matrix().T
        origin = np.empty((row.size, 3))
        direction = np.empty((row.size, 3))
        for a in range(0, row.size, CHUNK):
            b = a + CHUNK
            p, r = self.exterior_at_rows(row[a:b])
            origin[a:b] = p
            direction[a:b] = np.einsum("nij,nj->ni", r, los_body[a:b])
        return origin, direction

    def image_to_ground(self, row, col, *, height=None, dem=None, band=None, array=None):
        """Direct localization (see :meth:`SensorModel.image_to_ground`).

        Parameters
        ----------
        row, col : array_like
            Continuous image coordinates (first pixel centre at 0.5).
        height : float or array_like, optional
            Ellipsoidal heights, metres (exactly one of ``height`` and ``dem``).
        dem : sensor_models.terrain.dem.Dem, optional
            Terrain to intersect.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Force the CCD (see :meth:`ccd_index`).

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape of the broadcast ``row, col``
        """
        from sensor_models.terrain.ellipsoid import intersect_ellipsoid

        ccd = array
        if (height is None) == (dem is None):
            raise InputError("give exactly one of height= and dem=")
        shape = np.broadcast(np.asarray(row), np.asarray(col)).shape
        origin, direction = self.rays_itrf(row, col, band=band, array=ccd)
        if dem is not None:
            lon, lat, h, _ = dem.intersect(origin, direction)
        else:
            (h_m,) = as_float_arrays(height, names=("height",))
            h_m = np.broadcast_to(h_m, shape).reshape(-1)
            xyz = intersect_ellipsoid(origin, direction, h_m)
            lon, lat, h = ecef_to_geodetic(xyz)
        return lon.reshape(shape), lat.reshape(shape), h.reshape(shape)

    # ------------------------------------------------------------------ inverse
    def ground_to_image(self, lon, lat, h, *, band=None, array=None):
        """Inverse localization (see :meth:`SensorModel.ground_to_image`).

        With ``array=None`` each point goes to the CCD whose detectors see it (the first one on an
        overlap, the nearest one when none does); ``array`` (name or index) forces a CCD.
        Points not imaged within the rows the data cover get NaN.

        Parameters
        ----------
        lon, lat : array_like
            WGS84 longitude and latitude, degrees.
        h : array_like
            Height above the ellipsoid, metres.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Force the CCD (a name or index, or one per point).

        Returns
        -------
        row, col : ndarray, shape of the broadcast inputs
        """
        ccd = array
        lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
        shape = lon.shape
        ground = geodetic_to_ecef(lon.reshape(-1), lat.reshape(-1), h.reshape(-1))
        row = np.empty(ground.shape[0])
        col = np.empty(ground.shape[0])
        for a in range(0, ground.shape[0], CHUNK):
            b = a + CHUNK
            row[a:b], col[a:b], _ = ground_to_image_chunk(self, ground[a:b], band, ccd_chunk(ccd, a, b))
        return row.reshape(shape), col.reshape(shape)

    # ------------------------------------------------------------------ parameters
    def parameter_groups(self) -> dict[str, tuple[str, ...]]:
        """``"exterior"``, one ``"interior.<band>.<ccd>"`` per CCD, then ``"attitude"`` if any.

        Returns
        -------
        dict of str to tuple of str
            Ordered as :meth:`parameter_names`; every CCD's group lists ``tan_psi_x``'s
            coefficients ``c0..`` then ``tan_psi_y``'s.
        """
        groups = {"exterior": tuple(f"installation.{a}" for a in Installation.NAMES)}
        for band, ccds in self._looks.items():
            for c in ccds:
                names = []
                for axis in ("tan_psi_x", "tan_psi_y"):
                    names += [f"{band}.{c.name}.{axis}.c{k}" for k in range(getattr(c, axis).size)]
                groups[f"interior.{band}.{c.name}"] = tuple(names)
        if self.attitude_correction is not None:
            groups["attitude"] = self.attitude_correction.names()
        return groups

    def interior_group(self, band=None, array=None) -> str:
        """The group of one CCD's directional-angle coefficients.

        Parameters
        ----------
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int, optional
            CCD name or index; may be omitted when the band has one CCD.

        Returns
        -------
        str
            ``"interior.<band>.<ccd>"``.
        """
        band = self._band(band)
        return f"interior.{band}.{self._looks[band][self._one_array(band, array)].name}"

    def parameter_names(self) -> tuple[str, ...]:
        """Installation angles, then per band and CCD the directional-angle coefficients.

        Returns
        -------
        tuple of str
            ``installation.roll|pitch|yaw`` (radians), then
            ``<band>.<ccd>.tan_psi_x.c<k>`` and ``<band>.<ccd>.tan_psi_y.c<k>``
            (dimensionless per detector**k).
        """
        return tuple(name for names in self.parameter_groups().values() for name in names)

    def parameters(self) -> ParameterVector:
        """The installation angles and directional-angle coefficients.

        Returns
        -------
        ParameterVector
            In the order of :meth:`parameter_names`.
        """
        values = [self.installation.as_array()]
        for ccds in self._looks.values():
            for c in ccds:
                values += [c.tan_psi_x, c.tan_psi_y]
        if self.attitude_correction is not None:
            values.append(self.attitude_correction.coefficients_rad.reshape(-1))
        return ParameterVector(self.parameter_names(), np.concatenate(values))

    def with_parameters(self, values) -> "PushbroomModel":
        """A copy with new installation angles and directional-angle coefficients.

        The tabulated orbit and attitude are shared with this model (they do not depend on the
        parameters), so this is cheap.

        Parameters
        ----------
        values : array_like, shape (P,)
            In the order of :meth:`parameter_names`; finite.

        Returns
        -------
        PushbroomModel
        """
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        names = self.parameter_names()
        if values.size != len(names):
            raise InputError(f"expected {len(names)} parameter values, got {values.size}")
        if not np.all(np.isfinite(values)):
            raise InputError("parameter values must be finite")
        new = copy.copy(self)
        new.installation = Installation(*values[:3])
        pos = 3
        bands = {}
        for band, ccds in self._looks.items():
            out = []
            for c in ccds:
                kx, ky = c.tan_psi_x.size, c.tan_psi_y.size
                out.append(
                    CcdLook(c.name, c.first_col, c.n_detectors, values[pos : pos + kx], values[pos + kx : pos + kx + ky])
                )
                pos += kx + ky
            bands[band] = tuple(out)
        new._looks = bands
        if self.attitude_correction is not None:
            new.attitude_correction = self.attitude_correction.with_coefficients(values[pos:])
        return new

    def with_attitude_correction(self, correction: AttitudeCorrection | None) -> "PushbroomModel":
        """A copy with another attitude correction (None: the measured attitude alone).

        The parameter vector changes: the ``"attitude"`` group follows the correction.

        Parameters
        ----------
        correction : AttitudeCorrection or None

        Returns
        -------
        PushbroomModel
        """
        if correction is not None and not isinstance(correction, AttitudeCorrection):
            raise InputError("must be an AttitudeCorrection", field="attitude_correction")
        new = copy.copy(self)
        new.attitude_correction = correction
        return new

    def image_jacobian(self, lon, lat, h, *, band=None, names=None, array=None):
        """Analytic ``d(row, col)/d(parameters)`` at the projections of ground points.

        Parameters
        ----------
        lon, lat, h : array_like, shape (N,)
            Ground points: degrees, degrees, metres above the ellipsoid.
        band : str, optional
            Default: :attr:`reference_band`.
        names : sequence of str, optional
            Parameters (default: all, in :meth:`parameter_names` order).
        array : str or int or array_like, optional
            Force the CCD as in :meth:`ground_to_image`.

        Returns
        -------
        row, col : ndarray, shape (N,)
        jac : ndarray, shape (N, 2, P)
            For the parameters ``names`` (default: all, in :meth:`parameter_names` order).
            Interior coefficients of other bands or CCDs have zero derivatives.
        """
        ccd = array
        band = self._band(band)
        return parameter_jacobian(self, lon, lat, h, band=band, names=names, ccd=ccd)

    def attitude_angle_jacobian(self, lon, lat, h, *, band=None, array=None):
        """``d(row, col)/d(delta)`` of body-frame attitude angles at the projections of ground points.

        The derivative of a correction coefficient ``attitude.<axis>.k<j>`` is this column
        times the basis function ``j`` at the point's time; the calibration uses it to choose
        the basis (:mod:`calibrate.attitude`). Without a correction it is taken at ``delta = 0``.

        Parameters
        ----------
        lon, lat, h : array_like, shape (N,)
            Ground points: degrees, degrees, metres above the ellipsoid.
        band : str, optional
            Default: :attr:`reference_band`.
        array : str or int or array_like, optional
            Force the CCD as in :meth:`ground_to_image`.

        Returns
        -------
        row, col : ndarray, shape (N,)
        jac : ndarray, shape (N, 2, 3)
            Pixels per radian of roll, pitch, yaw.
        """
        model = self
        if self.attitude_correction is None:
            lo, hi = self.line_timing.seconds(np.array(self.row_range))
            model = self.with_attitude_correction(AttitudeCorrection("drift", min(lo, hi), max(lo, hi), 1))
        ccd = array
        band = model._band(band)
        return body_angle_jacobian(model, lon, lat, h, band=band, ccd=ccd)

    def __repr__(self):
        bands = ", ".join(f"{b}: {len(c)} CCD" for b, c in self.bands.items())
        return f"PushbroomModel({self.name!r}, {self.n_rows}x{self.n_cols}, {bands})"


