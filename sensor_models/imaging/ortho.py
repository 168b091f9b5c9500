"""Orthorectification: a raw-geometry image resampled onto a map grid through a model and a DEM.

For every output pixel centre ``(x, y)`` of the map grid, the DEM gives the ground height
``h = D(x, y)`` and the model's inverse localization gives the image position
``(row, col) = model.ground_to_image(lon, lat, h)``; the image is sampled there (OpenCV
``remap``, bilinear or cubic; image pixel centres at ``(i + 0.5, j + 0.5)``).

Fast geometry: exact model on a node grid, interpolation per pixel
-------------------------------------------------------------------
Exact inverse localization costs a few microseconds per point (Newton on the collinearity
equations), far too slow for 10^8 - 10^9 output pixels. For a fixed map position ``(x, y)``
the image position is a smooth function of ``(x, y, h)``, so for each block of output pixels
(:class:`OrthoGeometry`):

1. nodes every ``s`` output pixels (``s`` ~ ``node_step_px`` image pixels; one node beyond
   each side of the block) are localized exactly at three heights ``h_lo, h_mid, h_hi``
   spanning the DEM heights of the block (plus 1 m);
2. per node, the three layers give the quadratic in the normalized height
   ``tau = (h - h_mid) / ((h_hi - h_lo) / 2)``: ``f(tau) = a + b tau + c tau^2`` with
   ``a = f_mid``, ``b = (f_hi - f_lo) / 2``, ``c = (f_hi + f_lo) / 2 - f_mid`` (Lagrange
   interpolation through the layers, for ``f`` = row and col). The relief displacement of a
   push-broom is linear in ``h`` up to a term ``~ h^2 tan(theta) / H`` (``H`` the orbit height:
   1 m for 1.5 km of relief at 20 degrees off nadir), which the quadratic term carries;
3. ``a, b, c`` are interpolated to every pixel by separable uniform Catmull-Rom cubics written
   as matrix products ``W_r A W_c^T`` (the weights of
   :func:`sensor_models.imaging.locate.catmull_rom_matrix`), and evaluated at the pixel's own
   DEM height (bilinear between DEM nodes, like :meth:`Dem.height_m`).

The interpolation error is measured, not assumed: :func:`orthorectify_to_file` compares the
interpolated positions of random output pixels with exact ``ground_to_image`` at the same
``(lon, lat, h)`` and reports the maximum (``geometry_check_max_px``). With 16-pixel nodes it is
~1e-4 px where the attitude is smooth; it peaks at ~0.008 px next to the samples of an attitude
interpolated piecewise (a kink in the derivative every 0.25 s on the fixture's LAB and
calibrated models); ``tests/test_ortho.py`` requires <= 0.01 px.

Multi-CCD push-broom rasters stitch CCDs side by side, so the ground -> raster mapping jumps at
the seams. Each CCD's own mapping is smooth: the node fields are computed per CCD (inverse
localization forced onto that CCD) at the nodes a coarse pre-check finds near that CCD, and a
pixel takes the first CCD (in column order) whose interpolated column falls inside its columns,
which is the rule of :meth:`PushbroomModel.ground_to_image` (first CCD wins on overlaps).

Output
------
:func:`orthorectify_to_file` writes blocks of ``block x block`` pixels into a tiled GeoTIFF
beside the target (only the source window each block needs is read), then copies it with
GDAL's COG driver (DEFLATE, internal overviews by averaging) to a second temporary file and
renames that onto the target: there is never a partial output. Memory per block is
``O(block^2)`` and does not grow with the output size: ``bench/bench_ortho.py`` measured a peak
RSS of 436, 444 and 442 MiB for outputs of 5000, 10000 and 20000 px a side (about 135 MiB of it
for 1024-pixel blocks), and 5.5 output Mpx/s on one core for the largest (70 s, 13 s of it in
the COG copy). That bench holds a small DEM in memory; a DEM file as large as the scene (SRTM-1
under a 30 m scene) is read by windows too: with ``dem_windows``
(:func:`sensor_models.terrain.dem_windows.open_ortho_dem`, which ``gcpcal ortho`` uses) each block reads
only the DEM nodes its pixels need, with the same heights to the bit (docs/memory.md).

OpenCV's ``remap`` quantizes sample positions to 1/32 pixel (a zero-mean error of at most
1/64 px per axis). Bilinear interpolation reproduces a linear ramp exactly; OpenCV's cubic
(Keys' kernel with ``a = -0.75``, sharper) only to a periodic, zero-mean error below 0.05 px. Samples whose bilinear/cubic support touches a no-data source pixel are
no-data. An output coarser than the image is point-sampled (no area averaging): choose a
resolution near the scene's ground sampling distance, or decimate afterwards.
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.terrain.dem_windows import bilinear_nodes

__all__ = [
    "BlockGeometry",
    "OrthoGeometry",
    "orthorectify",
    "orthorectify_to_file",
    "ortho_grid",
    "scene_gsd_m",
    "utm_crs",
]

#: OpenCV interpolation of each resampling name
RESAMPLING = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
#: source pixels beyond the extreme sample positions read with each block (cubic needs 2)
_READ_PAD = 3
#: node fields whose largest magnitude is below this (px) are dropped (exactly zero effect)
_NEGLIGIBLE_PX = 1e-5
#: largest output raster accepted (either side, pixels)
MAX_SIDE_PX = 200_000
#: source pixels (per side) a block may need; larger blocks are shrunk (coarse outputs)
_MAX_SOURCE_SIDE = 2048
#: smallest node spacing in output pixels: an output 4x coarser than the image has nodes every
#: 32 image pixels (interpolation error still <= 0.005 output px), not every 16
MIN_NODE_STEP = 8


# ---------------------------------------------------------------- grid of the orthoimage
def utm_crs(lon_deg: float, lat_deg: float) -> pyproj.CRS:
    """The WGS84 UTM zone CRS (EPSG:326zz north, 327zz south) containing ``(lon, lat)``.

    Parameters
    ----------
    lon_deg, lat_deg : float
        WGS84 longitude and latitude, degrees.

    Returns
    -------
    pyproj.CRS
    """
    zone = int(np.floor((float(lon_deg) + 180.0) / 6.0)) % 60 + 1
    return pyproj.CRS.from_epsg((32600 if lat_deg >= 0.0 else 32700) + zone)


def _centre_column(model, band) -> float:
    """A column at the middle of the image that is not on a CCD seam."""
    arrays = model.detector_arrays(band)  # one array covering the image for area arrays and RPCs
    middle = arrays[len(arrays) // 2]
    return middle.first_col + 0.5 * middle.n_detectors


def _kw(band):
    return {} if band is None else {"band": band}


def scene_gsd_m(model, *, band=None, height_m: float = 0.0) -> float:
    """Ground sampling distance (m) at the image centre: ``sqrt(d_row * d_col)``.

    ``d_row`` and ``d_col`` are the ground distances between the centre pixel and its
    neighbours one line and one column away, localized at ``height_m`` (ellipsoidal).

    Parameters
    ----------
    model : SensorModel
        Any model with ``image_shape`` and ``image_to_ground``; push-broom models are measured
        in the middle of their central CCD.
    band : str, optional
        Band of the geometry.
    height_m : float
        Ellipsoidal height of the localization, metres.

    Returns
    -------
    float
        GSD in metres.
    """
    from sensor_models.geometry.geodesy import geodetic_to_ecef

    row = 0.5 * model.image_shape[0]
    col = _centre_column(model, band)
    lon, lat, h = model.image_to_ground(np.array([row, row + 1.0, row]), np.array([col, col, col + 1.0]),
                                        height=float(height_m), **_kw(band))
    p = geodetic_to_ecef(lon, lat, h)
    d_row, d_col = np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[2] - p[0])
    gsd = float(np.sqrt(d_row * d_col))
    if not (np.isfinite(gsd) and gsd > 0.0):
        raise InputError("cannot measure the ground sampling distance at the image centre")
    return gsd


def _border(n_rows: int, n_cols: int, per_side: int = 64):
    """Points along the image border (pixel-edge coordinates), corners included."""
    r = np.linspace(0.0, float(n_rows), per_side + 1)
    c = np.linspace(0.0, float(n_cols), per_side + 1)
    rows = np.concatenate([np.zeros_like(c), np.full_like(c, n_rows), r, r])
    cols = np.concatenate([c, c, np.zeros_like(r), np.full_like(r, n_cols)])
    return rows, cols


def _footprint_lonlat(model, dem, band):
    """WGS84 ``lon, lat`` of the image border on the DEM (mean DEM height where it misses)."""
    rows, cols = _border(*model.image_shape)
    lon, lat, _ = model.image_to_ground(rows, cols, dem=dem, **_kw(band))
    miss = ~(np.isfinite(lon) & np.isfinite(lat))
    if miss.any():
        h_mean = float(np.nanmean(dem.heights_m))
        lon_m, lat_m, _ = model.image_to_ground(rows[miss], cols[miss], height=h_mean, **_kw(band))
        lon, lat = lon.copy(), lat.copy()
        lon[miss], lat[miss] = lon_m, lat_m
    return lon, lat


def ortho_grid(model, dem, *, crs=None, resolution_m=None, band=None):
    """The map grid of an orthoimage: the scene footprint's bounding box in ``crs``.

    Parameters
    ----------
    model : SensorModel
    dem : sensor_models.terrain.dem.Dem
        The image border is localized on it (its mean height where a ray misses it).
    crs : anything pyproj accepts, optional
        Output CRS (projected, metres); default: the UTM zone of the footprint's centre.
    resolution_m : float, optional
        Pixel size in CRS units; default: the scene's GSD (:func:`scene_gsd_m` at the DEM's
        mean height) rounded to 3 significant digits.
    band : str, optional

    Returns
    -------
    MapGrid
        North-up grid whose corners lie on multiples of the resolution.
    """
    from sensor_models.maps.grid import MapGrid

    lon, lat = _footprint_lonlat(model, dem, band)
    if crs is None:
        crs = utm_crs(float(np.mean([lon.min(), lon.max()])), float(np.mean([lat.min(), lat.max()])))
    try:
        crs = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"unknown CRS {crs!r} ({exc})", field="crs") from None
    if crs.is_geographic:
        raise InputError(f"the output CRS {crs.name!r} is geographic; give a projected CRS (metres)", field="crs")
    if resolution_m is None:
        gsd = scene_gsd_m(model, band=band, height_m=float(np.nanmean(dem.heights_m)))
        resolution_m = float(f"{gsd:.3g}")
    resolution_m = float(resolution_m)
    if not (np.isfinite(resolution_m) and resolution_m > 0.0):
        raise InputError(f"must be a positive number, got {resolution_m}", field="resolution_m")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    x, y = np.asarray(x), np.asarray(y)
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InputError(f"the scene footprint does not map into {crs.name!r}", field="crs")
    x0, x1 = np.floor(x.min() / resolution_m), np.ceil(x.max() / resolution_m)
    y0, y1 = np.floor(y.min() / resolution_m), np.ceil(y.max() / resolution_m)
    shape = (int(y1 - y0), int(x1 - x0))
    if max(shape) > MAX_SIDE_PX:
        raise InputError(f"the orthoimage would be {shape[0]} x {shape[1]} px; choose a coarser resolution "
                         f"than {resolution_m} m", field="resolution_m")
    transform = Affine(resolution_m, 0.0, round(x0 * resolution_m, 6), 0.0, -resolution_m, round(y1 * resolution_m, 6))
    return MapGrid(transform, crs, shape)


# ---------------------------------------------------------------- geometry of a block
@dataclass(frozen=True)
class _Solver:
    """Exact inverse localization onto one smooth part of the raster (one CCD)."""

    first_col: float
    last_col: float
    index: int | None  # CCD index for push-broom models, None for the whole image


def _solvers(model, band):
    arrays = model.detector_arrays(band)
    if len(arrays) == 1 and model.detector_view(band, 0) is model:  # the whole image is one array
        return [_Solver(0.0, float(model.image_shape[1]), None)]
    return [_Solver(float(a.first_col), float(a.last_col), i) for i, a in enumerate(arrays)]


@dataclass
class BlockGeometry:
    """Image positions of a block of output pixels.

    Attributes
    ----------
    row, col : ndarray (n_rows, n_cols), float64
        Continuous image coordinates (first pixel centre at 0.5) of every output pixel centre;
        NaN where ``valid`` is False.
    h_m : ndarray (n_rows, n_cols), float64
        DEM height (ellipsoidal) at the pixel centre; NaN off the DEM.
    ccd : ndarray (n_rows, n_cols), int16
        Index of the CCD (in ``model.band_ccds(band)``) that sees the pixel, -1 if none
        (0 for models without CCDs).
    valid : ndarray (n_rows, n_cols), bool
        The pixel is on the DEM and inside the image.
    """

    row: np.ndarray
    col: np.ndarray
    h_m: np.ndarray
    ccd: np.ndarray
    valid: np.ndarray


class OrthoGeometry:
    """Fast ground -> image positions for blocks of an output grid (module docstring).

    Parameters
    ----------
    model : SensorModel
        Any model with ``ground_to_image(lon, lat, h, band=)``; push-broom models (with
        ``band_ccds``) are handled per CCD.
    dem : sensor_models.terrain.dem.Dem
    grid : MapGrid
        Output grid (``transform``, ``crs``, ``shape``).
    band : str, optional
    node_step_px : float
        Node spacing in image pixels (converted to output pixels with the grid's scale, and
        at least :data:`MIN_NODE_STEP` output pixels).
    dem_windows : sensor_models.terrain.dem_windows.DemWindows, optional
        Full-resolution heights read by windows, block by block; ``dem`` is then a coarse copy
        used only for the mean height. None: the pixels' heights come from ``dem``.
    """

    def __init__(self, model, dem, grid, *, band=None, node_step_px: float = 16.0, dem_windows=None):
        if not node_step_px > 0:
            raise InputError(f"must be positive, got {node_step_px}", field="node_step_px")
        self.model = model
        self.dem = dem
        self.grid = grid
        self.band = band
        self.n_rows, self.n_cols = (int(v) for v in model.image_shape)
        self.solvers = _solvers(model, band)
        self.dem_windows = dem_windows
        heights_grid = dem if dem_windows is None else dem_windows  # where the pixels' heights come from
        self._to_lonlat = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True)
        self._same_crs = grid.crs.equals(heights_grid.crs)
        self._to_dem = (None if self._same_crs
                        else pyproj.Transformer.from_crs(grid.crs, heights_grid.crs, always_xy=True))
        # DEM CRS -> node index
        self._dem_index = Affine.translation(-0.5, -0.5) @ ~heights_grid.transform
        self._z = np.asarray(dem.heights_m, dtype=np.float64)
        self.scale = self._scale()
        # node_step_px image pixels, but at least MIN_NODE_STEP output pixels (coarse outputs)
        self.node_step = int(max(MIN_NODE_STEP, min(256, round(node_step_px / self.scale))))

    # -- helpers -------------------------------------------------------------------------
    def _scale(self) -> float:
        """Image pixels per output pixel at the grid centre (largest singular value)."""
        rows, cols = self.grid.shape
        t = self.grid.transform
        pc = np.array([0.5 * cols, 0.5 * cols + 1.0, 0.5 * cols])
        pr = np.array([0.5 * rows, 0.5 * rows, 0.5 * rows + 1.0])
        lon, lat = self._lonlat(t.a * pc + t.b * pr + t.c, t.d * pc + t.e * pr + t.f)
        h = np.full(3, float(np.nanmean(self._z)))
        r, c = self.model.ground_to_image(lon, lat, h, **_kw(self.band))
        if not (np.isfinite(r).all() and np.isfinite(c).all()):
            return 1.0
        jac = np.array([[r[1] - r[0], r[2] - r[0]], [c[1] - c[0], c[2] - c[0]]])
        s = float(np.linalg.svd(jac, compute_uv=False)[0])
        return s if np.isfinite(s) and s > 0 else 1.0

    def _lonlat(self, x, y):
        lon, lat = self._to_lonlat.transform(x, y)
        return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)

    def _heights(self, u, v):
        """Bilinear DEM heights at node indices ``(u, v)`` (NaN outside or next to no-data)."""
        if self.dem_windows is not None:
            return self.dem_windows.heights(u, v)
        return bilinear_nodes(self._z, u, v)

    def _solve(self, solver: _Solver, lon, lat, h):
        kw = _kw(self.band)
        if solver.index is not None:
            kw["ccd"] = solver.index
        return self.model.ground_to_image(lon, lat, h, **kw)

    # -- the block -----------------------------------------------------------------------
    def block(self, row0: int, row1: int, col0: int, col1: int) -> BlockGeometry:
        """Image positions of output pixels ``[row0:row1, col0:col1]``.

        Parameters
        ----------
        row0, row1, col0, col1 : int
            The output window (end exclusive), in output-grid pixels.

        Returns
        -------
        BlockGeometry
            Arrays of shape ``(row1 - row0, col1 - col0)``.
        """
        from sensor_models.imaging.locate import catmull_rom_matrix

        nr, nc = row1 - row0, col1 - col0
        if not (nr > 0 and nc > 0):
            raise InputError(f"empty block rows {row0}..{row1}, cols {col0}..{col1}")
        s = self.node_step
        kr = np.arange(-1, int(np.ceil((nr - 1) / s)) + 2)  # node k at output pixel offset s * k
        kc = np.arange(-1, int(np.ceil((nc - 1) / s)) + 2)
        wr = catmull_rom_matrix(1.0 + np.arange(nr) / s, kr.size).astype(np.float32)
        wc = catmull_rom_matrix(1.0 + np.arange(nc) / s, kc.size).astype(np.float32)
        t = self.grid.transform
        pr, pc = np.meshgrid(row0 + 0.5 + s * kr, col0 + 0.5 + s * kc, indexing="ij")
        x_n, y_n = t.a * pc + t.b * pr + t.c, t.d * pc + t.e * pr + t.f
        lon_n, lat_n = self._lonlat(x_n.ravel(), y_n.ravel())

        # DEM height of every pixel
        a = self._dem_index
        if self._same_crs:
            m = a @ t
            jj, ii = np.meshgrid(row0 + 0.5 + np.arange(nr), col0 + 0.5 + np.arange(nc), indexing="ij")
            u = m.a * ii + m.b * jj + m.c
            v = m.d * ii + m.e * jj + m.f
        else:
            xd, yd = self._to_dem.transform(x_n.ravel(), y_n.ravel())
            xd, yd = np.asarray(xd).reshape(pr.shape), np.asarray(yd).reshape(pr.shape)
            u = _interp(a.a * xd + a.b * yd + a.c, wr, wc)
            v = _interp(a.d * xd + a.e * yd + a.f, wr, wc)
        h = self._heights(u, v)
        shape = (nr, nc)
        row = np.full(shape, np.nan)
        col = np.full(shape, np.nan)
        ccd = np.full(shape, -1, dtype=np.int16)
        on_dem = np.isfinite(h)
        if not on_dem.any():
            return BlockGeometry(row, col, h, ccd, on_dem)
        h_lo, h_hi = float(np.min(h[on_dem])) - 1.0, float(np.max(h[on_dem])) + 1.0
        h_mid, half = 0.5 * (h_lo + h_hi), 0.5 * (h_hi - h_lo)
        tau = ((h - h_mid) / half).astype(np.float32)
        tau[~on_dem] = 0.0

        todo = on_dem.copy()
        for solver, nodes in self._plan(lon_n, lat_n, pr.shape, h_lo, h_hi):
            idx = np.arange(lon_n.size) if nodes is None else np.flatnonzero(nodes)
            n = idx.size
            r3 = np.full((3, lon_n.size), np.nan)
            c3 = np.full((3, lon_n.size), np.nan)
            r_exact, c_exact = self._solve(solver, np.tile(lon_n[idx], 3), np.tile(lat_n[idx], 3),
                                           np.repeat([h_lo, h_mid, h_hi], n))
            r3[:, idx] = r_exact.reshape(3, n)
            c3[:, idx] = c_exact.reshape(3, n)
            r_ccd = _quadratic_field(r3.reshape(3, *pr.shape), wr, wc, tau)
            c_ccd = _quadratic_field(c3.reshape(3, *pr.shape), wr, wc, tau)
            bad_nodes = ~(np.isfinite(r3) & np.isfinite(c3)).reshape(3, *pr.shape).all(axis=0)
            ok = todo & (c_ccd >= solver.first_col) & (c_ccd <= solver.last_col)
            if bad_nodes.any():
                ok &= ~_stencil_bad(bad_nodes, nr, nc, s)
            row[ok] = r_ccd[ok]
            col[ok] = c_ccd[ok]
            ccd[ok] = 0 if solver.index is None else solver.index
            todo &= ~ok
            if not todo.any():
                break
        valid = (ccd >= 0) & (row >= 0.0) & (row <= self.n_rows) & (col >= 0.0) & (col <= self.n_cols)
        row[~valid] = np.nan
        col[~valid] = np.nan
        ccd[~valid] = -1
        return BlockGeometry(row, col, h, ccd, valid)

    def _plan(self, lon_n, lat_n, node_shape, h_lo, h_hi):
        """Per solver (CCD) that can reach the block, the dense nodes worth localizing exactly.

        Nodes every ``stride`` dense nodes (<= 48 image px apart, plus the last row and column)
        are localized at ``h_lo`` and ``h_hi`` on every CCD. A coarse node is *near* a CCD when
        either position lies within ``margin`` of the CCD's columns and of the image rows
        (``margin`` = the Catmull-Rom reach of two dense node spacings, plus one and a half
        coarse spacings, plus 8 px); the near set is dilated by one coarse node and a dense node
        is localized when the coarse cell holding it is near. Nodes left out are never in the
        stencil of a pixel that the CCD sees, so the fields stay exact where they are used,
        and a wide block does not localize every node on every CCD (nor far outside the image,
        where Newton iterations run to the edge of the orbit data).

        Returns
        -------
        list of (_Solver, ndarray of bool (node_shape) or None)
            None: every node (a model without CCDs).
        """
        from scipy.ndimage import binary_dilation

        if len(self.solvers) == 1 and self.solvers[0].index is None:
            return [(self.solvers[0], None)]
        stride = max(1, int(48.0 / (self.node_step * self.scale)))
        ir = np.unique(np.r_[np.arange(0, node_shape[0], stride), node_shape[0] - 1])
        ic = np.unique(np.r_[np.arange(0, node_shape[1], stride), node_shape[1] - 1])
        sel = (ir[:, None] * node_shape[1] + ic[None, :]).ravel()
        lon, lat = np.tile(lon_n[sel], 2), np.tile(lat_n[sel], 2)
        hh = np.repeat([h_lo, h_hi], sel.size)
        spacing = stride * self.node_step * self.scale
        margin = 2.0 * self.node_step * self.scale + 1.5 * spacing + 8.0
        cell_r = np.searchsorted(ir, np.arange(node_shape[0]), side="right") - 1
        cell_c = np.searchsorted(ic, np.arange(node_shape[1]), side="right") - 1
        plan = []
        for solver in self.solvers:
            r, c = self._solve(solver, lon, lat, hh)
            r, c = r.reshape(2, ir.size, ic.size), c.reshape(2, ir.size, ic.size)
            with np.errstate(invalid="ignore"):
                near = ((c >= solver.first_col - margin) & (c <= solver.last_col + margin)
                        & (r >= -margin) & (r <= self.n_rows + margin)).any(axis=0)
            if not near.any():
                continue
            near = binary_dilation(near, structure=np.ones((3, 3), dtype=bool))
            plan.append((solver, near[np.ix_(cell_r, cell_c)]))
        return plan


def _interp(nodes, wr, wc):
    """Separable Catmull-Rom interpolation ``W_r N W_c^T`` in float32 around the mean, as float64."""
    ref = float(np.mean(nodes))
    out = wr @ (nodes - ref).astype(np.float32) @ wc.T
    return out.astype(np.float64) + ref


def _quadratic_field(layers, wr, wc, tau):
    """Per-pixel ``a + b tau + c tau^2`` from three node layers (low, mid, high height).

    Non-finite nodes are replaced by the finite mean (the caller masks the pixels whose
    stencils touch them); ``b`` and ``c`` are skipped when negligible everywhere.
    """
    lo, mid, hi = layers
    fin = np.isfinite(lo) & np.isfinite(mid) & np.isfinite(hi)
    if not fin.any():
        return np.full(tau.shape, np.nan)
    a = np.where(fin, mid, 0.0)
    ref = float(np.mean(a[fin]))
    a = np.where(fin, a, ref)
    b = np.where(fin, 0.5 * (hi - lo), 0.0)
    c = np.where(fin, 0.5 * (hi + lo) - mid, 0.0)
    out = _interp(a, wr, wc)
    if np.max(np.abs(c)) > _NEGLIGIBLE_PX:
        poly = (wr @ b.astype(np.float32) @ wc.T) + tau * (wr @ c.astype(np.float32) @ wc.T)
        out += tau * poly
    elif np.max(np.abs(b)) > _NEGLIGIBLE_PX:
        out += tau * (wr @ b.astype(np.float32) @ wc.T)
    return out


def _stencil_bad(bad_nodes, nr, nc, step):
    """Pixels whose 4 x 4 Catmull-Rom node stencil holds a bad node, shape (nr, nc)."""
    n_r, n_c = bad_nodes.shape
    kr = np.clip(np.floor(1.0 + np.arange(nr) / step).astype(np.intp), 1, n_r - 3)
    kc = np.clip(np.floor(1.0 + np.arange(nc) / step).astype(np.intp), 1, n_c - 3)
    padded = np.zeros((n_r + 3, n_c + 3), dtype=bool)
    padded[1:n_r + 1, 1:n_c + 1] = bad_nodes
    cell = np.zeros((n_r, n_c), dtype=bool)  # cell[k, l]: nodes k-1..k+2 x l-1..l+2
    for i in range(4):
        for j in range(4):
            cell |= padded[i:i + n_r, j:j + n_c]
    return cell[np.ix_(kr, kc)]


# ---------------------------------------------------------------- source pixels
class _Source:
    """Windowed float32 access to one band of a raster in scene geometry (NaN = no data)."""

    def __init__(self, image, index: int = 1):
        self.array = None
        self.dataset = None
        self.path = None
        if isinstance(image, np.ndarray):
            if image.ndim != 2:
                raise InputError(f"the image must be 2-D, got shape {image.shape}")
            self.array = image
            self.shape = image.shape
            self.dtype = np.dtype(np.float32) if image.dtype.kind == "f" else image.dtype
            self.nodata = None
            return
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning, RasterioError

        self.path = os.fspath(image)
        if not os.path.isfile(self.path):
            raise InputError("image raster not found", path=self.path)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                self.dataset = rasterio.open(self.path)
        except (RasterioError, OSError) as exc:
            raise InputError(f"cannot be read as a raster ({exc})", path=self.path) from None
        if not 1 <= index <= self.dataset.count:
            self.dataset.close()
            raise InputError(f"band index {index} outside 1..{self.dataset.count}", path=self.path)
        self.index = index
        self.shape = (self.dataset.height, self.dataset.width)
        self.dtype = np.dtype(self.dataset.dtypes[index - 1])
        self.nodata = self.dataset.nodata

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        if self.array is not None:
            return self.array[r0:r1, c0:c1].astype(np.float32)
        from rasterio.windows import Window

        data = self.dataset.read(self.index, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
        return np.ma.filled(data.astype(np.float32), np.nan)

    def close(self):
        if self.dataset is not None:
            self.dataset.close()


def _resolve_source(model, image, band):
    """``(source, band)`` from an image argument: array, raster path, band name, or None."""
    rasters = getattr(model, "rasters", None) or {}
    if isinstance(image, np.ndarray):
        return _Source(image), band
    if isinstance(image, tuple):
        path, index = image
        return _Source(path, int(index)), band
    if image is None or (isinstance(image, str) and image in rasters and not os.path.isfile(image)):
        if image is not None:
            if band is not None and band != image:
                raise InputError(f"image names band {image!r} but band={band!r}")
            band = image
        key = band if band is not None else getattr(model, "reference_band", None)
        if key not in rasters:
            raise InputError(f"the model lists no raster for band {key!r}; give the image raster")
        entry = rasters[key]
        return _Source(entry["path"], int(entry.get("index", 1))), key
    return _Source(image), band


def _default_band(model, band):
    if band is None and any(a.name for a in model.detector_arrays()):  # multi-band CCD models
        return model.reference_band
    return band


# ---------------------------------------------------------------- resampling
def _resample(source: _Source, geom: BlockGeometry, interpolation: int) -> np.ndarray:
    """Source samples (float32, NaN = none) at the block's image positions."""
    out = np.full(geom.row.shape, np.nan, dtype=np.float32)
    if not geom.valid.any():
        return out
    rows, cols = geom.row[geom.valid], geom.col[geom.valid]
    n_rows, n_cols = source.shape
    r0 = max(0, int(np.floor(rows.min() - 0.5)) - _READ_PAD)
    r1 = min(n_rows, int(np.ceil(rows.max() - 0.5)) + _READ_PAD + 1)
    c0 = max(0, int(np.floor(cols.min() - 0.5)) - _READ_PAD)
    c1 = min(n_cols, int(np.ceil(cols.max() - 0.5)) + _READ_PAD + 1)
    window = source.read(r0, r1, c0, c1)
    mx = np.where(geom.valid, geom.col - (0.5 + c0), -10.0).astype(np.float32)
    my = np.where(geom.valid, geom.row - (0.5 + r0), -10.0).astype(np.float32)
    # replicate: samples between the raster edge and the first pixel centre take the edge value
    sampled = cv2.remap(window, mx, my, interpolation, borderMode=cv2.BORDER_REPLICATE)
    out[geom.valid] = sampled[geom.valid]
    return out


def _check_nodata(nodata, dtype: np.dtype) -> None:
    """``nodata`` must be a number the output data type holds exactly."""
    try:
        value = float(nodata)
    except (TypeError, ValueError):
        raise InputError(f"must be a number, got {nodata!r}", field="nodata") from None
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        if not (np.isfinite(value) and value == int(value) and info.min <= value <= info.max):
            raise InputError(f"{nodata!r} is not a {dtype.name} value", field="nodata")


def _to_dtype(values: np.ndarray, dtype: np.dtype, nodata) -> np.ndarray:
    ok = np.isfinite(values)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        v = np.clip(np.rint(np.where(ok, values, 0.0)), info.min, info.max).astype(dtype)
    else:
        v = values.astype(dtype)
    v[~ok] = nodata
    return v


# ---------------------------------------------------------------- in memory
def orthorectify(model, image: np.ndarray, dem, transform, crs, shape, *, band=None, block_rows: int = 512,
                 resampling: str = "bilinear", node_step_px: float = 16.0) -> np.ndarray:
    """Orthoimage (float32, ``shape``, NaN = no data) of an in-memory ``image`` on a given grid.

    Parameters
    ----------
    model : SensorModel
        Describes ``image`` (same pixel grid).
    image : ndarray (n_rows, n_cols)
    dem : sensor_models.terrain.dem.Dem
        Heights (ellipsoidal) of the ground.
    transform : affine.Affine
        Pixel-corner transform of the output grid.
    crs : pyproj.CRS or anything pyproj accepts
    shape : (rows, cols)
    band : str, optional
    block_rows : int
        Output rows (and columns) per block.
    resampling : {"nearest", "bilinear", "cubic"}
    node_step_px : float
        Node spacing of the geometry grid in image pixels (:class:`OrthoGeometry`).

    Returns
    -------
    ndarray of float32, shape ``shape``
        The orthoimage; NaN off the image or the DEM.
    """
    from sensor_models.maps.grid import MapGrid

    if resampling not in RESAMPLING:
        raise InputError(f"resampling must be one of {', '.join(RESAMPLING)}, got {resampling!r}")
    grid = MapGrid(Affine(*tuple(transform)[:6]), pyproj.CRS.from_user_input(crs), tuple(int(v) for v in shape))
    band = _default_band(model, band)
    geometry = OrthoGeometry(model, dem, grid, band=band, node_step_px=node_step_px)
    source = _Source(np.ascontiguousarray(image, dtype=np.float32))
    out = np.full(grid.shape, np.nan, dtype=np.float32)
    step = max(16, int(block_rows))
    for a in range(0, grid.shape[0], step):
        for b in range(0, grid.shape[1], step):
            geom = geometry.block(a, min(a + step, grid.shape[0]), b, min(b + step, grid.shape[1]))
            out[a:a + geom.row.shape[0], b:b + geom.row.shape[1]] = _resample(source, geom, RESAMPLING[resampling])
    return out


# ---------------------------------------------------------------- to a Cloud-Optimized GeoTIFF
def _block_size(block: int, scale: float) -> int:
    """Output block side (multiple of 16) whose source window stays below _MAX_SOURCE_SIDE."""
    b = min(int(block), int(_MAX_SOURCE_SIDE / max(scale, 1e-9)))
    return max(64, b // 16 * 16)


def orthorectify_to_file(model, image, dem, out_path, *, crs=None, resolution_m=None, band=None,
                         resampling: str = "bilinear", block: int = 1024, nodata=0, dtype=None,
                         node_step_px: float = 16.0, check_points: int = 256, seed: int = 0,
                         progress=None, dem_windows=None) -> dict:
    """Orthorectify one band into a Cloud-Optimized GeoTIFF, block by block, atomically.

    Parameters
    ----------
    model : SensorModel
        Geometry of the image (e.g. a calibrated push-broom model).
    image : str, os.PathLike, (path, band_index), ndarray or None
        The image in scene geometry: a raster path (band 1), a path and a 1-based band index,
        a band name listed in the model's ``rasters`` (a scene manifest), None for the model's
        raster of ``band``, or an array.
    dem : sensor_models.terrain.dem.Dem
        Ellipsoidal heights of the ground.
    out_path : str or os.PathLike
        The COG to write (replaced atomically; its folder is created).
    crs, resolution_m
        Output CRS and pixel size; defaults in :func:`ortho_grid` (UTM zone of the scene, the
        scene's GSD).
    band : str, optional
        Band of the geometry (default: the model's reference band).
    resampling : {"nearest", "bilinear", "cubic"}
    block : int
        Output pixels per block side (memory ~ 150 bytes per block pixel; smaller for outputs
        much coarser than the image).
    nodata : number
        Value of output pixels off the image or the DEM.
    dtype : numpy dtype, optional
        Output data type; default: the image's (float32 for float arrays).
    node_step_px : float
        Node spacing of the geometry grid in image pixels.
    check_points : int
        About this many random output pixels are checked against exact inverse localization.
    seed : int
        Seed of the check-point draw.
    progress : callable(done_blocks, total_blocks), optional
        Called after each output block is written.
    dem_windows : sensor_models.terrain.dem_windows.DemWindows, optional
        Read the pixels' heights from the DEM file block by block
        (:func:`sensor_models.terrain.dem_windows.open_ortho_dem`); ``dem`` then only serves the
        footprint, the default resolution and the mean height.

    Returns
    -------
    dict
        JSON-ready summary: output, crs (WKT and EPSG when known), resolution_m, shape,
        transform, band, valid_fraction, node_step_out_px, geometry_check_max_px and _rms_px
        (interpolated versus exact positions), seconds (cog_seconds of them for the COG
        copy), pixels_per_s.

    Raises
    ------
    InputError
        Unreadable image, image shape different from the model's, bad options, or no output
        pixel on both the image and the DEM.
    """
    t_start = time.perf_counter()
    if resampling not in RESAMPLING:
        raise InputError(f"resampling must be one of {', '.join(RESAMPLING)}, got {resampling!r}", field="resampling")
    if int(block) < 64:
        raise InputError(f"must be >= 64 pixels, got {block}", field="block")
    out_path = Path(out_path)
    band = _default_band(model, band)
    source, band = _resolve_source(model, image, band)
    try:
        if tuple(source.shape) != tuple(model.image_shape):
            raise InputError(f"the image is {source.shape[0]} x {source.shape[1]} px, the model describes "
                             f"{model.image_shape[0]} x {model.image_shape[1]}", path=source.path)
        grid = ortho_grid(model, dem, crs=crs, resolution_m=resolution_m, band=band)
        geometry = OrthoGeometry(model, dem, grid, band=band, node_step_px=node_step_px, dem_windows=dem_windows)
        out_dtype = _output_dtype(dtype, source.dtype)
        _check_nodata(nodata, out_dtype)
        step = _block_size(block, geometry.scale)
        plan = _BlockPlan(geometry, source, step, RESAMPLING[resampling], out_dtype, nodata, check_points, seed)
        t_cog = _write_cog(plan, out_path, model=model, band=band, resampling=resampling, progress=progress)
    finally:
        source.close()
    summary = _summary(plan, out_path, band=band, resampling=resampling, step=step)
    seconds = time.perf_counter() - t_start
    summary.update(seconds=round(seconds, 3), cog_seconds=round(t_cog, 3),
                   pixels_per_s=grid.shape[0] * grid.shape[1] / max(seconds, 1e-9))
    return summary


def _output_dtype(dtype, source_dtype) -> np.dtype:
    """``dtype``, else the image's; floats narrower than 32 bits become float32."""
    out_dtype = np.dtype(dtype) if dtype is not None else source_dtype
    if out_dtype.kind == "f" and out_dtype.itemsize < 4:
        out_dtype = np.dtype(np.float32)
    return out_dtype


def _summary(plan: "_BlockPlan", out_path: Path, *, band, resampling, step) -> dict:
    """The JSON-ready summary of a written orthoimage, timings left out."""
    geometry = plan.geometry
    grid = geometry.grid
    err = _check_geometry(geometry, plan.checks)
    n_rows, n_cols = grid.shape
    epsg = grid.crs.to_epsg()
    return {
        "output": str(out_path),
        "format": "COG",
        "crs": f"EPSG:{epsg}" if epsg else grid.crs.to_wkt(),
        "resolution_m": float(grid.transform.a),
        "shape": [int(n_rows), int(n_cols)],
        "transform": list(grid.transform)[:6],
        "band": band,
        "dtype": plan.out_dtype.name,
        "nodata": plan.nodata,
        "resampling": resampling,
        "valid_fraction": plan.n_valid / float(n_rows * n_cols),
        "block_px": step,
        "node_step_out_px": geometry.node_step,
        "image_px_per_output_px": geometry.scale,
        "geometry_check_points": err["n"],
        "geometry_check_max_px": err["max"],
        "geometry_check_rms_px": err["rms"],
        "dem_read": "whole" if geometry.dem_windows is None else "windows",
    }


class _BlockPlan:
    """The output blocks of :func:`orthorectify_to_file` and what writing them gathers.

    ``blocks`` are ``(row0, row1, col0, col1)`` output windows of side ``step``; writing a block
    adds its valid pixels to ``n_valid`` and about ``check_points / len(blocks)`` drawn pixels
    (seeded) to ``checks``.
    """

    def __init__(self, geometry, source, step, interpolation, out_dtype, nodata, check_points, seed):
        self.geometry = geometry
        self.source = source
        self.interpolation = interpolation
        self.out_dtype = out_dtype
        self.nodata = nodata
        n_rows, n_cols = geometry.grid.shape
        self.blocks = [(a, min(a + step, n_rows), b, min(b + step, n_cols))
                       for a in range(0, n_rows, step) for b in range(0, n_cols, step)]
        self.per_block = max(2, int(np.ceil(check_points / len(self.blocks))))
        self.rng = np.random.default_rng(seed)
        self.checks = []
        self.n_valid = 0

    def write(self, dst, progress=None) -> None:
        """Resample every block into band 1 of the open dataset ``dst``."""
        from rasterio.windows import Window

        for k, (a, b, c, d) in enumerate(self.blocks):
            geom = self.geometry.block(a, b, c, d)
            if geom.valid.any():
                values = _resample(self.source, geom, self.interpolation)
                good = geom.valid & np.isfinite(values)
                self.n_valid += int(np.count_nonzero(good))
                dst.write(_to_dtype(values, self.out_dtype, self.nodata), 1, window=Window(c, a, d - c, b - a))
                self.checks.append(_draw_checks(geom, a, c, self.per_block, self.rng))
            if progress is not None:
                progress(k + 1, len(self.blocks))


def _write_cog(plan: _BlockPlan, out_path: Path, *, model, band, resampling, progress) -> float:
    """Write the blocks into a tiled GeoTIFF, copy it to a COG and move that into place.

    Returns the seconds the COG copy took.
    """
    import rasterio
    import rasterio.shutil
    from rasterio.crs import CRS as RioCRS

    from sensor_models.files.atomic import temporary_beside

    grid = plan.geometry.grid
    n_rows, n_cols = grid.shape
    tile = 512 if min(grid.shape) >= 512 else 256
    profile = dict(driver="GTiff", width=n_cols, height=n_rows, count=1, dtype=plan.out_dtype.name,
                   crs=RioCRS.from_wkt(grid.crs.to_wkt()), transform=grid.transform, nodata=plan.nodata,
                   tiled=True, blockxsize=tile, blockysize=tile, sparse_ok=True, BIGTIFF="IF_SAFER")
    tmp = temporary_beside(out_path, ".tif")
    cog = temporary_beside(out_path, ".cog.tif")
    try:
        with rasterio.Env(GDAL_CACHEMAX=64, GDAL_PAM_ENABLED="NO"):
            with rasterio.open(tmp, "w", **profile) as dst:
                dst.set_band_description(1, str(band) if band is not None else "image")
                dst.update_tags(GCPCAL_ORTHO_MODEL=getattr(model, "name", "") or model.kind,
                                GCPCAL_ORTHO_BAND=str(band), GCPCAL_ORTHO_RESAMPLING=resampling)
                plan.write(dst, progress)
            if plan.n_valid == 0:
                raise InputError("no output pixel lies on both the image and the DEM: does the DEM cover the "
                                 "scene, and is the model right?", path=str(out_path))
            t_cog = time.perf_counter()
            cog.unlink(missing_ok=True)
            rasterio.shutil.copy(tmp, cog, driver="COG", COMPRESS="DEFLATE",
                                 PREDICTOR="YES", BLOCKSIZE=tile, OVERVIEW_RESAMPLING="AVERAGE",
                                 BIGTIFF="IF_SAFER")
        os.replace(cog, out_path)
        return time.perf_counter() - t_cog
    finally:
        tmp.unlink(missing_ok=True)
        cog.unlink(missing_ok=True)


def _draw_checks(geom: BlockGeometry, row0: int, col0: int, n: int, rng):
    """``n`` random valid pixels of a block: output (row, col), h, ccd, interpolated (row, col)."""
    idx = np.flatnonzero(geom.valid)
    pick = rng.choice(idx, size=min(n, idx.size), replace=False)
    j, i = np.unravel_index(pick, geom.valid.shape)
    return (j + row0 + 0.5, i + col0 + 0.5, geom.h_m.flat[pick], geom.ccd.flat[pick],
            geom.row.flat[pick], geom.col.flat[pick])


def _check_geometry(geometry: OrthoGeometry, checks) -> dict:
    """Interpolated versus exact positions (same CCD, same height) of the drawn pixels."""
    if not checks:
        return {"n": 0, "max": None, "rms": None}
    pr, pc, h, ccd, row, col = (np.concatenate(v) for v in zip(*checks))
    t = geometry.grid.transform
    lon, lat = geometry._lonlat(t.a * pc + t.b * pr + t.c, t.d * pc + t.e * pr + t.f)
    err = np.full(pr.size, np.nan)
    for solver in geometry.solvers:
        sel = ccd == (0 if solver.index is None else solver.index)
        if sel.any():
            r, c = geometry._solve(solver, lon[sel], lat[sel], h[sel])
            err[sel] = np.hypot(r - row[sel], c - col[sel])
    fin = err[np.isfinite(err)]
    if fin.size == 0:
        return {"n": 0, "max": None, "rms": None}
    return {"n": int(fin.size), "max": float(fin.max()), "rms": float(np.sqrt(np.mean(fin**2)))}
