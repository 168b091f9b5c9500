"""Rational polynomial camera model (RPC00B): evaluate, invert, bias-correct.

The model
---------
Ground coordinates are normalized with the ten RPC offsets and scales::

    L = (lon - lon_off) / lon_scale,  P = (lat - lat_off) / lat_scale,
    H = (h - height_off) / height_scale

and the normalized image coordinates are ratios of cubic polynomials::

    line_n = Num_L(P, L, H) / Den_L(P, L, H),   samp_n = Num_S(P, L, H) / Den_S(P, L, H)
    line_rpc = line_n * line_scale + line_off,  samp_rpc = samp_n * samp_scale + samp_off

Each cubic has 20 coefficients ``c[0..19]`` multiplying, in the RPC00B order (NITF STDI-0002,
RPC00B tagged record extension; also the order of GDAL's RPC metadata and of OSSIM's
``polynomial_format: B``), the terms :data:`RPC00B_TERMS`::

    1, L, P, H, L*P, L*H, P*H, L^2, P^2, H^2,
    P*L*H, L^3, L*P^2, L*H^2, L^2*P, P^3, P*H^2, L^2*H, P^2*H, H^3

Pixel convention
----------------
In RPC space (RPC00B, GDAL's RPC metadata, OSSIM, .RPB and _RPC.TXT files) the *centre* of the
first pixel is at ``(line, samp) = (0, 0)``. gcpcal puts the first pixel's centre at
``(row, col) = (0.5, 0.5)``, as GDAL's and rasterio's transformers do, so at this module's
boundary::

    row = line_rpc + 0.5,   col = samp_rpc + 0.5

(GDAL's ``GDALRPCTransform`` adds the same 0.5 internally; its output therefore equals ours.)

Calibration parameters: image-space affine bias correction
----------------------------------------------------------
Following Grodecki & Dial [1]_, systematic errors of a vendor RPC are absorbed by an affine
correction in image space. With ``row_rpc, col_rpc`` the RPC projection of a ground point in
gcpcal's convention (first pixel centre at 0.5), the model's image coordinates are::

    row = row_rpc + a0 + a1 * row_rpc + a2 * col_rpc
    col = col_rpc + b0 + b1 * row_rpc + b2 * col_rpc

``a0, b0`` are in pixels, ``a1, a2, b1, b2`` are dimensionless. Their names in
:meth:`RpcModel.parameters` are ``bias.row.a0, bias.row.a1, bias.row.a2, bias.col.b0,
bias.col.b1, bias.col.b2``; all default to zero. The correction is applied by
:meth:`~RpcModel.ground_to_image` and inverted (exactly, a 2x2 linear solve) by
:meth:`~RpcModel.image_to_ground`. Note that ``a1, a2`` multiply full-scene pixel coordinates
(up to ~4e4 for a Pleiades scene): scale the Jacobian columns when you estimate them.

Files
-----
The RPC files (OSSIM ``.geom``, ``.RPB``, ``_RPC.TXT``, GeoTIFF RPC tags, GDAL's ``RPC``
metadata) are read and written by :mod:`sensor_models.readers.rpc_files`.

Fitting
-------
:func:`sensor_models.models.rpc_fit.fit_rpc` fits a terrain-independent RPC
to any :class:`~sensor_models.base.SensorModel` from a 3-D grid of image points localized at
several heights, by the iteratively reweighted linearized least squares of Tao & Hu [2]_ with a
Tikhonov (ridge) term chosen on a validation grid, and certifies that the denominators have no
zero over the normalized cube.

References
----------
.. [1] J. Grodecki and G. Dial, "Block adjustment of high-resolution satellite images described
   by rational polynomials", Photogrammetric Engineering & Remote Sensing 69(1), 59-68 (2003).
.. [2] C. V. Tao and Y. Hu, "A comprehensive study of the rational function model for
   photogrammetric processing", Photogrammetric Engineering & Remote Sensing 67(12),
   1347-1357 (2001).
.. [3] NGA, "The Compendium of Controlled Extensions (CE) for the National Imagery Transmission
   Format (NITF)", STDI-0002, appendix E: RPC00B.
"""

from __future__ import annotations

import math

import numpy as np

from sensor_models.base import ParameterVector, SensorModel, as_float_arrays
from sensor_models.errors import InputError, RpcError
from sensor_models.models.rpc_dem import (
    derivative_coefficients, fit_approximate_inverse, intersect_dem_newton, rpc00b_monomials,
)

__all__ = ["RPC00B_TERMS", "RpcModel"]

#: The 20 monomials of an RPC00B cubic, in coefficient order (L = lon, P = lat, H = height,
#: all normalized).
RPC00B_TERMS = (
    "1", "L", "P", "H", "L*P", "L*H", "P*H", "L^2", "P^2", "H^2",
    "P*L*H", "L^3", "L*P^2", "L*H^2", "L^2*P", "P^3", "P*H^2", "L^2*H", "P^2*H", "H^3",
)  # fmt: skip

#: Names of the bias-correction parameters, in parameter-vector order.
BIAS_NAMES = (
    "bias.row.a0", "bias.row.a1", "bias.row.a2",
    "bias.col.b0", "bias.col.b1", "bias.col.b2",
)  # fmt: skip

#: The ten offsets and scales, in the order of the constructor's keywords.
_NORM_NAMES = (
    "line_off", "samp_off", "lat_off", "lon_off", "height_off",
    "line_scale", "samp_scale", "lat_scale", "lon_scale", "height_scale",
)  # fmt: skip

_CHUNK = 1 << 12  # points per block in vectorized evaluation (bounds temporary memory)
_NEWTON_TOL_PX = 1e-9
#: image-space tolerance of the inversions inside the DEM intersection: every returned point
#: reprojects within it (max norm, pixels); the height search itself stops at _DEM_TOL_M
_DEM_NEWTON_TOL_PX = 1e-4
_NEWTON_MAX_ITER = 30
_DEM_TOL_M = 1e-3
_DEM_MAX_ITER = 100


# ---------------------------------------------------------------------------------------------
# Polynomial kernel
# ---------------------------------------------------------------------------------------------
def _terms_dL(L, P, H):
    z, o = np.zeros_like(L), np.ones_like(L)
    return np.stack(
        [z, o, z, z, P, H, z, 2 * L, z, z,
         P * H, 3 * L * L, P * P, H * H, 2 * L * P, z, z, 2 * L * H, z, z],
        axis=0,
    )  # fmt: skip


def _terms_dP(L, P, H):
    z, o = np.zeros_like(L), np.ones_like(L)
    return np.stack(
        [z, z, o, z, L, z, H, z, 2 * P, z,
         L * H, z, 2 * L * P, z, L * L, 3 * P * P, H * H, z, 2 * P * H, z],
        axis=0,
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------
class RpcModel(SensorModel):
    """An RPC00B rational polynomial camera model with an image-space affine bias correction.

    Parameters
    ----------
    line_num, line_den, samp_num, samp_den : array_like, shape (20,)
        Coefficients in RPC00B term order (see :data:`RPC00B_TERMS`).
    line_off, samp_off : float
        Image offsets in RPC space (first pixel centre at 0), pixels.
    lat_off, lon_off : float
        Ground offsets, degrees.
    height_off : float
        Height offset, metres above the WGS84 ellipsoid.
    line_scale, samp_scale, lat_scale, lon_scale, height_scale : float
        Scales (non-zero), in the units of the matching offsets.
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``. Default: ``(round(2 * line_off + 1), round(2 * samp_off + 1))``,
        the image the offsets would centre.
    bias : array_like, shape (6,), optional
        ``(a0, a1, a2, b0, b1, b2)`` of the affine correction (module docstring); default 0.
    err_bias, err_rand : float, optional
        Vendor error estimates (metres), carried through to the writers
        (:mod:`sensor_models.readers.rpc_files`).
    source : str, optional
        Where the model was read from (for messages).

    Raises
    ------
    RpcError
        A coefficient vector does not have 20 finite values, or an offset or scale is not a
        finite number, or a scale is zero.

    Notes
    -----
    In the :class:`~sensor_models.base.SensorModel` protocol an RPC has no named band
    (``bands == (None,)``), one detector array covering the image (named ``""``), one parameter
    group ``"bias"`` (:data:`BIAS_NAMES`), and ``is_rigorous`` is False.
    """

    kind = "rpc"
    is_rigorous = False

    def __init__(
        self,
        *,
        line_num,
        line_den,
        samp_num,
        samp_den,
        line_off,
        samp_off,
        lat_off,
        lon_off,
        height_off,
        line_scale,
        samp_scale,
        lat_scale,
        lon_scale,
        height_scale,
        image_shape=None,
        bias=None,
        err_bias=None,
        err_rand=None,
        source=None,
    ):
        self.source = None if source is None else str(source)
        coefs = []
        for name, value in (
            ("line_num", line_num),
            ("line_den", line_den),
            ("samp_num", samp_num),
            ("samp_den", samp_den),
        ):
            c = np.asarray(value, dtype=np.float64).reshape(-1)
            if c.shape != (20,) or not np.all(np.isfinite(c)):
                raise RpcError(
                    f"needs 20 finite RPC00B coefficients, got {c.size}", path=self.source,
                    field=name,
                )
            coefs.append(c)
        self._coef = np.stack(coefs, axis=1)  # (20, 4): line_num, line_den, samp_num, samp_den
        self._coef.setflags(write=False)
        norm = dict(
            line_off=line_off, samp_off=samp_off, lat_off=lat_off, lon_off=lon_off,
            height_off=height_off, line_scale=line_scale, samp_scale=samp_scale,
            lat_scale=lat_scale, lon_scale=lon_scale, height_scale=height_scale,
        )  # fmt: skip
        for name, value in norm.items():
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise RpcError(f"not a number: {value!r}", path=self.source, field=name) from None
            if not math.isfinite(v) or (name.endswith("_scale") and v == 0.0):
                raise RpcError(f"must be finite (and non-zero for a scale), got {v}",
                               path=self.source, field=name)  # fmt: skip
            setattr(self, name, v)
        if image_shape is None:
            image_shape = (
                max(1, int(round(2.0 * self.line_off + 1.0))),
                max(1, int(round(2.0 * self.samp_off + 1.0))),
            )
        shape = tuple(int(n) for n in image_shape)
        if len(shape) != 2 or min(shape) < 1:
            raise InputError(f"image_shape must be two positive integers, got {image_shape!r}")
        self._image_shape = shape
        b = np.zeros(6) if bias is None else np.asarray(bias, dtype=np.float64).reshape(-1)
        if b.shape != (6,) or not np.all(np.isfinite(b)):
            raise InputError(f"bias needs 6 finite values {BIAS_NAMES}, got {b!r}")
        self._bias = b.copy()
        self._bias.setflags(write=False)
        self.err_bias = None if err_bias is None else float(err_bias)
        self.err_rand = None if err_rand is None else float(err_rand)

    # -- small accessors ----------------------------------------------------------------------
    @property
    def image_shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)`` of the image."""
        return self._image_shape

    @property
    def line_num(self) -> np.ndarray:
        """Line numerator coefficients, shape (20,), RPC00B order, read-only."""
        return self._coef[:, 0]

    @property
    def line_den(self) -> np.ndarray:
        """Line denominator coefficients, shape (20,), read-only."""
        return self._coef[:, 1]

    @property
    def samp_num(self) -> np.ndarray:
        """Sample numerator coefficients, shape (20,), read-only."""
        return self._coef[:, 2]

    @property
    def samp_den(self) -> np.ndarray:
        """Sample denominator coefficients, shape (20,), read-only."""
        return self._coef[:, 3]

    @property
    def bias(self) -> np.ndarray:
        """``(a0, a1, a2, b0, b1, b2)``, read-only."""
        return self._bias

    def init_kwargs(self) -> dict:
        """The constructor's keywords that rebuild this model (``RpcModel(**model.init_kwargs())``).

        Returns
        -------
        dict
            Offsets, scales, coefficients, ``image_shape``, ``bias``, ``err_bias``,
            ``err_rand`` and ``source``.
        """
        kw = {name: getattr(self, name) for name in _NORM_NAMES}
        kw.update(
            line_num=self.line_num, line_den=self.line_den, samp_num=self.samp_num,
            samp_den=self.samp_den, image_shape=self._image_shape, bias=self._bias,
            err_bias=self.err_bias, err_rand=self.err_rand, source=self.source,
        )  # fmt: skip
        return kw

    def __repr__(self) -> str:
        where = f" from {self.source}" if self.source else ""
        return (
            f"RpcModel(image_shape={self._image_shape}, lon_off={self.lon_off:.6f}, "
            f"lat_off={self.lat_off:.6f}, bias={tuple(float(x) for x in self._bias)}{where})"
        )

    # -- parameters ---------------------------------------------------------------------------
    def parameters(self) -> ParameterVector:
        """The six bias-correction parameters (module docstring).

        Returns
        -------
        ParameterVector
            :data:`BIAS_NAMES`; ``a0, b0`` in pixels, the others in pixels per pixel.
        """
        return ParameterVector(BIAS_NAMES, self._bias.copy())

    def parameter_groups(self) -> dict[str, tuple[str, ...]]:
        """One group, ``"bias"``: the six bias-correction parameters.

        Returns
        -------
        dict of str to tuple of str
            ``{"bias": BIAS_NAMES}``.
        """
        return {"bias": tuple(BIAS_NAMES)}

    def with_parameters(self, values) -> "RpcModel":
        """A copy with new bias values.

        Parameters
        ----------
        values : array_like, shape (6,)
            In the order of :meth:`parameters`.

        Returns
        -------
        RpcModel
        """
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if values.shape != (6,):
            raise InputError(f"expected 6 parameter values {BIAS_NAMES}, got {values.size}")
        kw = self.init_kwargs()
        kw["bias"] = values
        return RpcModel(**kw)

    def cropped(self, row_off: int, col_off: int, shape=None) -> "RpcModel":
        """The same model for a sub-image whose first pixel is pixel ``(row_off, col_off)``.

        A crop pixel ``(r, c)`` is full-image pixel ``(r + row_off, c + col_off)``; the RPC
        offsets move by the same amounts and the bias is re-expressed in crop coordinates
        (``a0 += a1 * row_off + a2 * col_off``, likewise ``b0``), so both models give the same
        ground point for corresponding pixels.

        Parameters
        ----------
        row_off, col_off : int
            Full-image pixel of the crop's first pixel.
        shape : (int, int), optional
            ``(n_rows, n_cols)`` of the crop; default: the rest of the image.

        Returns
        -------
        RpcModel
        """
        row_off, col_off = float(row_off), float(col_off)
        if shape is None:
            shape = (
                max(1, self._image_shape[0] - int(row_off)),
                max(1, self._image_shape[1] - int(col_off)),
            )
        a0, a1, a2, b0, b1, b2 = self._bias
        kw = self.init_kwargs()
        kw.update(
            line_off=self.line_off - row_off,
            samp_off=self.samp_off - col_off,
            image_shape=shape,
            bias=(a0 + a1 * row_off + a2 * col_off, a1, a2, b0 + b1 * row_off + b2 * col_off,
                  b1, b2),
        )  # fmt: skip
        return RpcModel(**kw)

    # -- kernels ------------------------------------------------------------------------------
    def _normalize(self, lon, lat, h):
        return (
            (lon - self.lon_off) / self.lon_scale,
            (lat - self.lat_off) / self.lat_scale,
            (h - self.height_off) / self.height_scale,
        )

    def _rpc_rowcol(self, lon, lat, h):
        """Pure RPC projection (no bias), gcpcal convention; 1-D float64 inputs."""
        n = lon.shape[0]
        row = np.empty(n)
        col = np.empty(n)
        for s in range(0, n, _CHUNK):
            sl = slice(s, s + _CHUNK)
            L, P, H = self._normalize(lon[sl], lat[sl], h[sl])
            v = self._coef.T @ rpc00b_monomials(L, P, H)  # (4, n)
            row[sl] = v[0] / v[1] * self.line_scale + (self.line_off + 0.5)
            col[sl] = v[2] / v[3] * self.samp_scale + (self.samp_off + 0.5)
        return row, col

    def _rpc_rowcol_normalized(self, L, P, H, *, derivatives=False):
        """Pure RPC projection from normalized ground coordinates, with optional derivatives.

        Returns ``row, col`` (gcpcal convention) and, if asked, ``d(row, col)/d(L, P)`` as an
        array of shape (N, 2, 2) in pixels per normalized unit.
        """
        v = self._coef.T @ rpc00b_monomials(L, P, H)  # (4, N)
        row = v[0] / v[1] * self.line_scale + (self.line_off + 0.5)
        col = v[2] / v[3] * self.samp_scale + (self.samp_off + 0.5)
        if not derivatives:
            return row, col
        jac = np.empty((L.shape[0], 2, 2))
        for k, dterms in enumerate((_terms_dL, _terms_dP)):
            dv = self._coef.T @ dterms(L, P, H)
            # d(N/D) = (dN * D - N * dD) / D^2
            jac[:, 0, k] = (dv[0] * v[1] - v[0] * dv[1]) / v[1] ** 2
            jac[:, 1, k] = (dv[2] * v[3] - v[2] * dv[3]) / v[3] ** 2
        jac[:, 0, :] *= self.line_scale
        jac[:, 1, :] *= self.samp_scale
        return row, col, jac

    def _apply_bias(self, row_rpc, col_rpc):
        a0, a1, a2, b0, b1, b2 = self._bias
        return (
            row_rpc + a0 + a1 * row_rpc + a2 * col_rpc,
            col_rpc + b0 + b1 * row_rpc + b2 * col_rpc,
        )

    def _remove_bias(self, row, col):
        """Invert the affine correction: solve [[1+a1, a2], [b1, 1+b2]] @ rc_rpc = rc - (a0, b0)."""
        a0, a1, a2, b0, b1, b2 = self._bias
        if not np.any(self._bias):
            return row, col
        m00, m01, m10, m11 = 1.0 + a1, a2, b1, 1.0 + b2
        det = m00 * m11 - m01 * m10
        if abs(det) < 1e-12:
            raise RpcError("the bias correction is singular (1+a1)(1+b2) - a2*b1 = 0",
                           path=self.source)  # fmt: skip
        r, c = row - a0, col - b0
        return (m11 * r - m01 * c) / det, (m00 * c - m10 * r) / det

    # -- forward ------------------------------------------------------------------------------
    def ground_to_image(self, lon, lat, h, *, band=None, array=None):
        """Project ground points into the image (RPC, then the bias correction).

        Parameters
        ----------
        lon, lat : array_like
            WGS84 longitude and latitude, degrees.
        h : array_like
            Height above the WGS84 ellipsoid, metres.
        band : None
            RPC models have one band; anything else raises :class:`InputError`.
        array : str or int, optional
            None, 0 or ``""`` (the image is one detector array).

        Returns
        -------
        row, col : ndarray, shape of the broadcast inputs
            Continuous image coordinates, first pixel centre at (0.5, 0.5).
        """
        self._check_band(band)
        self._check_array(band, array)
        lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
        shape = lon.shape
        row, col = self._rpc_rowcol(lon.reshape(-1), lat.reshape(-1), h.reshape(-1))
        row, col = self._apply_bias(row, col)
        return row.reshape(shape), col.reshape(shape)

    def image_jacobian(self, lon, lat, h, *, band=None, names=None, array=None):
        """Projections and their derivatives with respect to the bias parameters.

        ``d row / d(a0, a1, a2) = (1, row_rpc, col_rpc)``, ``d col / d(b0, b1, b2)`` likewise,
        the cross derivatives are zero.

        Parameters
        ----------
        lon, lat, h : array_like, shape (N,)
            Ground points: degrees, degrees, metres above the ellipsoid.
        band : None
            Must be None.
        names : sequence of str, optional
            Bias parameters (default: all six).
        array : str or int, optional
            None, 0 or ``""``.

        Returns
        -------
        row, col : ndarray, shape (N,)
        jac : ndarray, shape (N, 2, P)
            For the parameters ``names`` (default: all six, in :data:`BIAS_NAMES` order).
        """
        self._check_band(band)
        self._check_array(band, array)
        lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
        lon, lat, h = lon.reshape(-1), lat.reshape(-1), h.reshape(-1)
        row_rpc, col_rpc = self._rpc_rowcol(lon, lat, h)
        row, col = self._apply_bias(row_rpc, col_rpc)
        full = np.zeros((row.shape[0], 2, 6))
        one = np.ones_like(row_rpc)
        full[:, 0, 0:3] = np.stack([one, row_rpc, col_rpc], axis=-1)
        full[:, 1, 3:6] = np.stack([one, row_rpc, col_rpc], axis=-1)
        if names is not None:
            try:
                idx = self.parameters().index(list(names))
            except KeyError as err:
                raise InputError(str(err.args[0])) from None
            full = full[:, :, idx]
        return row, col, full

    # -- inverse ------------------------------------------------------------------------------
    def _invert_at_height(self, row_rpc, col_rpc, H, L0=None, P0=None, tol_px=_NEWTON_TOL_PX):
        """Newton solve of the pure RPC for normalized (L, P) at normalized heights H.

        Returns ``L, P`` (NaN where the iteration did not reach ``tol_px``, max norm, pixels).
        Blocks of points bound the temporary memory.
        """
        n = row_rpc.shape[0]
        block = 16 * _CHUNK
        if n <= block:
            return self._invert_block(row_rpc, col_rpc, H, L0, P0, tol_px)
        L = np.empty(n)
        P = np.empty(n)
        for s in range(0, n, block):
            sl = slice(s, s + block)
            L[sl], P[sl] = self._invert_block(
                row_rpc[sl], col_rpc[sl], H[sl],
                None if L0 is None else L0[sl], None if P0 is None else P0[sl], tol_px,
            )  # fmt: skip
        return L, P

    def _invert_block(self, row_rpc, col_rpc, H, L0, P0, tol_px=_NEWTON_TOL_PX):
        n = row_rpc.shape[0]
        L = np.zeros(n) if L0 is None else np.where(np.isfinite(L0), L0, 0.0)
        P = np.zeros(n) if P0 is None else np.where(np.isfinite(P0), P0, 0.0)
        active = np.arange(n)
        done = np.zeros(n, dtype=bool)
        for _ in range(_NEWTON_MAX_ITER):
            if active.size == 0:
                break
            # residuals first (no derivatives): from a good start most points stop here
            r, c = self._rpc_rowcol_normalized(L[active], P[active], H[active])
            fr, fc = r - row_rpc[active], c - col_rpc[active]
            conv = np.maximum(np.abs(fr), np.abs(fc)) <= tol_px
            done[active[conv]] = True
            if conv.all():
                break
            active, fr, fc = active[~conv], fr[~conv], fc[~conv]
            conv = np.zeros(active.size, dtype=bool)
            jac = self._rpc_rowcol_normalized(L[active], P[active], H[active], derivatives=True)[2]
            j00, j01 = jac[:, 0, 0], jac[:, 0, 1]
            j10, j11 = jac[:, 1, 0], jac[:, 1, 1]
            det = j00 * j11 - j01 * j10
            with np.errstate(divide="ignore", invalid="ignore"):
                dL = (j11 * fr - j01 * fc) / det
                dP = (j00 * fc - j10 * fr) / det
            ok = ~conv & np.isfinite(dL) & np.isfinite(dP)
            # limit steps to the size of the normalized domain, so a bad start cannot fly off
            step = np.maximum(np.abs(dL), np.abs(dP))
            damp = np.where(step > 0.5, 0.5 / np.maximum(step, 1e-300), 1.0)
            idx = active[ok]
            L[idx] -= (damp * dL)[ok]
            P[idx] -= (damp * dP)[ok]
            active = idx
        L = np.where(done, L, np.nan)
        P = np.where(done, P, np.nan)
        return L, P

    def _denormalize_lonlat(self, L, P):
        return L * self.lon_scale + self.lon_off, P * self.lat_scale + self.lat_off

    def image_to_ground(self, row, col, *, height=None, dem=None, band=None, array=None):
        """Localize image points at given heights or on a DEM.

        At a given height, the RPC is inverted by Newton's method on normalized (lon, lat),
        to 1e-9 px. On a DEM that gives its slopes (``height_and_slope_m``, as
        :class:`~sensor_models.terrain.dem.Dem`), Newton's method solves the two image equations
        and ``dem(lon, lat) = h`` together in (lon, lat, h), with the DEM's bilinear slope in its
        Jacobian, from a quadratic approximate inverse of the RPC
        (:mod:`sensor_models.models.rpc_dem`); a point stops when it reprojects within 1e-4 px
        (max norm) and lies within 1 mm of the DEM at the same evaluation. Points it leaves
        (Newton cycling between DEM cells on a slope seen at a grazing angle, an iterate over a
        void or off the DEM), and every point on a DEM without slopes, go through a bracketed
        secant search (Illinois false position) on ``f(h) = dem(lon(h), lat(h)) - h`` between
        the DEM's minimum and maximum heights, to 1e-3 m, with inversions to 1e-4 px (each
        height step starts from the previous solution moved along the line of sight); the
        bracket keeps it stable on slopes where the plain fixed point
        ``h <- dem(lon(h), lat(h))`` would oscillate. When several intersections lie within the
        DEM's height range, one of them is returned (not necessarily the one nearest the sensor).

        Parameters
        ----------
        row, col : array_like
            Continuous image coordinates (first pixel centre at 0.5), including the bias.
        height : float or array_like, optional
            Ellipsoidal heights in metres (exclusive with ``dem``).
        dem : object, optional
            Terrain with ``height_m(lon_deg, lat_deg)`` returning ellipsoidal heights (NaN
            outside) and ``height_range_m`` (``(min, max)``, attribute or method); with
            ``height_and_slope_m(lon_deg, lat_deg)`` (heights and their derivatives in lon and
            lat, as :meth:`Dem.height_and_slope_m <sensor_models.terrain.dem.Dem.height_and_slope_m>`)
            it is intersected by Newton's method.
        band : None
            Must be None.
        array : str or int, optional
            None, 0 or ``""``.

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape of the broadcast inputs
            NaN where the inversion did not converge or the line of sight leaves the DEM.

        Raises
        ------
        InputError
            Neither or both of ``height`` and ``dem`` given, or ``band`` is not None.
        """
        self._check_band(band)
        self._check_array(band, array)
        if (height is None) == (dem is None):
            raise InputError("image_to_ground needs exactly one of height= or dem=")
        if dem is not None:
            row, col = as_float_arrays(row, col, names=("row", "col"))
            shape = row.shape
            lon, lat, h = self._intersect_dem(row.reshape(-1), col.reshape(-1), dem)
            return lon.reshape(shape), lat.reshape(shape), h.reshape(shape)
        row, col, height = as_float_arrays(row, col, height, names=("row", "col", "height"))
        shape = row.shape
        row_rpc, col_rpc = self._remove_bias(row.reshape(-1), col.reshape(-1))
        h = height.reshape(-1)
        L, P = self._invert_at_height(row_rpc, col_rpc, (h - self.height_off) / self.height_scale)
        lon, lat = self._denormalize_lonlat(L, P)
        h = np.where(np.isfinite(lon), h, np.nan)
        return lon.reshape(shape), lat.reshape(shape), h.reshape(shape)

    def rpc_kernel(self):
        """Matrices of the fast kernels, computed once per model.

        Returns
        -------
        coef16 : ndarray, shape (20, 16)
            The four cubics and their L, P, H derivatives on the RPC00B monomials
            (:func:`~sensor_models.models.rpc_dem.derivative_coefficients`).
        inverse : ndarray, shape (10, 2)
            A quadratic approximate inverse (:func:`~sensor_models.models.rpc_dem.fit_approximate_inverse`),
            a starting point for Newton.
        """
        kernel = getattr(self, "_kernel", None)
        if kernel is None:
            def project(L, P, H):
                v = self._coef.T @ rpc00b_monomials(L, P, H)
                return v[0] / v[1], v[2] / v[3]

            kernel = self._kernel = (derivative_coefficients(self._coef), fit_approximate_inverse(project))
        return kernel

    def _intersect_dem(self, row, col, dem):
        """Newton's method on the line of sight and the DEM (when the DEM gives its slopes), the
        bracketed search for the points it leaves."""
        h_lo, h_hi = self._dem_bracket(dem)
        row_rpc, col_rpc = self._remove_bias(row, col)
        if not hasattr(dem, "height_and_slope_m"):
            return self._intersect_dem_bracketed(row_rpc, col_rpc, dem, h_lo, h_hi)
        lon, lat, h, done = intersect_dem_newton(self, row_rpc, col_rpc, dem, (h_lo, h_hi),
                                                 tol_px=_DEM_NEWTON_TOL_PX, tol_m=_DEM_TOL_M)
        rest = np.flatnonzero(~done)
        if rest.size:
            lon[rest], lat[rest], h[rest] = self._intersect_dem_bracketed(row_rpc[rest], col_rpc[rest], dem,
                                                                          h_lo, h_hi)
        return lon, lat, h

    @staticmethod
    def _dem_bracket(dem):
        """The DEM's height range, widened by 1 m on both sides."""
        hr = dem.height_range_m
        if callable(hr):
            hr = hr()
        try:
            h_lo, h_hi = (float(x) for x in hr)
        except (TypeError, ValueError):
            raise InputError(f"dem.height_range_m must be (min, max) metres, got {hr!r}") from None
        if not (math.isfinite(h_lo) and math.isfinite(h_hi) and h_lo <= h_hi):
            raise InputError(f"dem.height_range_m must be finite (min <= max), got {hr!r}")
        # strict bracket even where the DEM touches its extremes
        return h_lo - 1.0, h_hi + 1.0

    def _intersect_dem_bracketed(self, row_rpc, col_rpc, dem, h_lo, h_hi):
        """Illinois (modified false position) search of the line-of-sight height on a DEM."""
        n = row_rpc.shape[0]

        def to_norm(h):
            return (h - self.height_off) / self.height_scale

        def f(h, idx, L0=None, P0=None):
            L, P = self._invert_at_height(row_rpc[idx], col_rpc[idx], to_norm(h), L0, P0, _DEM_NEWTON_TOL_PX)
            lon, lat = self._denormalize_lonlat(L, P)
            with np.errstate(invalid="ignore"):
                z = np.asarray(dem.height_m(lon, lat), dtype=np.float64).reshape(-1)
            return z - h, L, P

        all_idx = np.arange(n)
        a = np.full(n, h_lo)
        b = np.full(n, h_hi)
        fa, La, Pa = f(a, all_idx)
        fb, Lb, Pb = f(b, all_idx, La, Pa)
        out_h = np.full(n, np.nan)
        out_L = np.full(n, np.nan)
        out_P = np.full(n, np.nan)
        # exact hits at the bracket ends
        for fv, hv, Lv, Pv in ((fa, a, La, Pa), (fb, b, Lb, Pb)):
            hit = np.abs(fv) <= _DEM_TOL_M
            out_h[hit], out_L[hit], out_P[hit] = hv[hit], Lv[hit], Pv[hit]
        with np.errstate(invalid="ignore"):
            active = np.flatnonzero(np.isnan(out_h) & (fa * fb < 0.0))
        a, b, fa, fb = a[active], b[active], fa[active], fb[active]
        Lc, Pc, hc = La[active], Pa[active], a.copy()
        # the line of sight is nearly straight in normalized (L, P, h): each height step starts
        # from the last solution moved along the bracket ends' slope, so that one residual
        # evaluation usually confirms it (Newton steps only where it does not)
        with np.errstate(invalid="ignore"):
            dL_dh = (Lb[active] - La[active]) / (h_hi - h_lo)
            dP_dh = (Pb[active] - Pa[active]) / (h_hi - h_lo)
        for _ in range(_DEM_MAX_ITER):
            if active.size == 0:
                break
            c = b - fb * (b - a) / (fb - fa)
            fc, Lc, Pc = f(c, active, Lc + (c - hc) * dL_dh, Pc + (c - hc) * dP_dh)
            hc = c
            good = np.isfinite(fc)
            conv = good & ((np.abs(fc) <= _DEM_TOL_M) | (np.abs(b - a) <= _DEM_TOL_M))
            ids = active[conv]
            out_h[ids], out_L[ids], out_P[ids] = c[conv], Lc[conv], Pc[conv]
            # new bracket [a, c] or [b, c]: keep the end whose f has the sign opposite to f(c);
            # Illinois: when the old `a` is kept, halve its f so the next secant point moves it
            keep_a = fc * fb > 0.0
            a, fa = np.where(keep_a, a, b), np.where(keep_a, 0.5 * fa, fb)
            b, fb = c, fc
            keep = good & ~conv
            active, a, b, fa, fb, Lc, Pc, hc, dL_dh, dP_dh = (
                x[keep] for x in (active, a, b, fa, fb, Lc, Pc, hc, dL_dh, dP_dh))
        lon, lat = self._denormalize_lonlat(out_L, out_P)
        bad = ~(np.isfinite(lon) & np.isfinite(lat))
        out_h[bad] = np.nan
        lon[bad] = np.nan
        lat[bad] = np.nan
        return lon, lat, out_h

    @staticmethod
    def _check_band(band):
        if band is not None:
            raise InputError(f"an RPC model has a single band; band must be None, got {band!r}")
