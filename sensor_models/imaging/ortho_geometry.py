"""Ground -> image positions of the output pixels of an orthoimage, block by block.

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

The interpolation error is measured, not assumed:
:func:`~sensor_models.imaging.ortho.orthorectify_to_file` compares the interpolated positions of
random output pixels with exact ``ground_to_image`` at the same ``(lon, lat, h)`` and reports
the maximum (``geometry_check_max_px``). With 16-pixel nodes it is ~1e-4 px where the attitude is smooth; it peaks at ~0.008 px next to the samples of an attitude
interpolated piecewise (a kink in the derivative every 0.25 s on the fixture's LAB and
calibrated models); ``tests/test_ortho.py`` requires <= 0.01 px.

Multi-CCD push-broom rasters stitch CCDs side by side, so the ground -> raster mapping jumps at
the seams. Each CCD's own mapping is smooth: the node fields are computed per CCD (inverse
localization forced onto that CCD) at the nodes a coarse pre-check finds near that CCD, and a
pixel takes the first CCD (in column order) whose interpolated column falls inside its columns,
which is the rule of :meth:`PushbroomModel.ground_to_image` (first CCD wins on overlaps).

Accuracy check
--------------
:func:`draw_checks` draws output pixels of each block and :func:`check_geometry` compares their
interpolated image positions with exact ``ground_to_image`` at the same height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.imaging.ortho_grid import band_kwargs
from sensor_models.terrain.dem_windows import bilinear_nodes

__all__ = ["BlockGeometry", "MIN_NODE_STEP", "OrthoGeometry", "check_geometry", "draw_checks"]


#: node fields whose largest magnitude is below this (px) are dropped (exactly zero effect)
_NEGLIGIBLE_PX = 1e-5
#: smallest node spacing in output pixels: an output 4x coarser than the image has nodes every
#: 32 image pixels (interpolation error still <= 0.005 output px), not every 16
MIN_NODE_STEP = 8


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
        r, c = self.model.ground_to_image(lon, lat, h, **band_kwargs(self.band))
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
        kw = band_kwargs(self.band)
        if solver.index is not None:
            kw["array"] = solver.index
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
        return self.blocks([(row0, row1, col0, col1)])[0]

    def blocks(self, windows) -> list[BlockGeometry]:
        """:meth:`block` of several output windows, their inverse localizations solved together.

        Each block's steps run as in :meth:`block`; where they ask the model for image positions
        (the coarse nodes of the plan, then the dense nodes CCD by CCD), the requests of all
        blocks waiting at that step go to the model in one call per CCD. Newton's steps are per
        point, so every block gets the same numbers as alone; one call over several blocks
        takes the interpreter's per-call work once instead of once a block (the geometry is many
        short numpy steps: docs/speed.md, "Every core").

        Parameters
        ----------
        windows : sequence of (int, int, int, int)
            ``(row0, row1, col0, col1)`` output windows.

        Returns
        -------
        list of BlockGeometry
            In the order of ``windows``.
        """
        steps = [self._block_steps(*w) for w in windows]
        out = [None] * len(steps)
        waiting = {}  # block -> its list of (solver, lon, lat, h) requests

        def advance(i, answer):
            try:
                waiting[i] = steps[i].send(answer)
            except StopIteration as done:
                out[i] = done.value

        for i in range(len(steps)):
            advance(i, None)
        while waiting:
            asked, waiting = waiting, {}
            flat = [(i, k, req) for i, reqs in asked.items() for k, req in enumerate(reqs)]
            answers = {i: [None] * len(reqs) for i, reqs in asked.items()}
            for key in dict.fromkeys(req[0].index for _, _, req in flat):  # one call per solver
                group = [(i, k, req) for i, k, req in flat if req[0].index == key]
                solver = group[0][2][0]
                lon, lat, h = (np.concatenate([req[j] for _, _, req in group]) for j in (1, 2, 3))
                r, c = self._solve(solver, lon, lat, h)
                ends = np.cumsum([req[1].size for _, _, req in group])
                for (i, k, _), a, b in zip(group, np.r_[0, ends[:-1]], ends):
                    answers[i][k] = (r[a:b], c[a:b])
            for i in asked:
                advance(i, answers[i])
        return out

    def _block_steps(self, row0: int, row1: int, col0: int, col1: int):
        """:meth:`block` as a generator: yields lists of ``(solver, lon, lat, h)`` localization
        requests, is sent their ``(row, col)`` results, returns the BlockGeometry."""
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
        plan = yield from self._plan(lon_n, lat_n, pr.shape, h_lo, h_hi)
        for solver, nodes in plan:
            idx = np.arange(lon_n.size) if nodes is None else np.flatnonzero(nodes)
            n = idx.size
            r3 = np.full((3, lon_n.size), np.nan)
            c3 = np.full((3, lon_n.size), np.nan)
            [(r_exact, c_exact)] = yield [(solver, np.tile(lon_n[idx], 3), np.tile(lat_n[idx], 3),
                                           np.repeat([h_lo, h_mid, h_hi], n))]
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

        A generator (:meth:`_block_steps`): it yields the coarse nodes' localization requests,
        one per CCD, and is sent their results.

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
        solved = yield [(solver, lon, lat, hh) for solver in self.solvers]
        for solver, (r, c) in zip(self.solvers, solved):
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


def draw_checks(geom: BlockGeometry, row0: int, col0: int, n: int, rng):
    """``n`` random valid pixels of a block: output (row, col), h, ccd, interpolated (row, col)."""
    idx = np.flatnonzero(geom.valid)
    pick = rng.choice(idx, size=min(n, idx.size), replace=False)
    j, i = np.unravel_index(pick, geom.valid.shape)
    return (j + row0 + 0.5, i + col0 + 0.5, geom.h_m.flat[pick], geom.ccd.flat[pick],
            geom.row.flat[pick], geom.col.flat[pick])


def check_geometry(geometry: OrthoGeometry, checks) -> dict:
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
