"""Where every pixel of a push-broom scene lands on a map grid, through a sensor model and a DEM.

This is the geometric kernel shared by GCP matching (resample the DOM into scene geometry
through the current model), orthorectification and the scene simulator (render the DOM through
the TRUE model): for a block of lines of one CCD and band it returns, for every pixel centre, the node-index
coordinates of its DEM intersection in any number of map grids (DOM, DEM, cloud field).

Method (exact model on a sparse node grid, per-pixel terrain)
-------------------------------------------------------------
1. On nodes every ``node_step`` lines and detectors (plus one node beyond each side), the
   model's own :meth:`PushbroomModel.image_to_ground` localizes the pixel at two heights
   ``h_lo`` and ``h_hi`` bracketing the DEM, and PROJ maps both points into each grid's
   node-index coordinates ``(u, v)``.
2. The layers are interpolated to every pixel by separable uniform Catmull-Rom cubics written as
   two small matrix products ``W_r X W_c^T`` (the geometry is smooth in row and column; attitude
   jitter of a hundred lines' period is followed to ~1e-4 px with 16-line nodes).
3. In ``(u, v, h)`` the line of sight is straight to a few centimetres over a 2 km height span,
   so ``u(h) = u_lo + (h - h_lo) du/dh``. The DEM height ``D(u, v)`` (bilinear between nodes,
   like :meth:`Dem.height_m`) is intersected per pixel by safeguarded Newton iterations on
   ``f(h) = h - D(u(h), v(h))`` with ``f' = 1 - (dD/du du/dh + dD/dv dv/dh)``.

OpenCV's ``remap`` samples the DEM (and the caller samples images) with positions quantized to
1/32 of a node, i.e. <= 0.5 m on a 30 m DEM: height errors of a few decimetres on steep slopes,
zero-mean. The first-crossing subtlety of :meth:`Dem.intersect` (ridges hiding valleys) is not
handled here: Newton converges to the crossing nearest the layer-interpolated start, which is the
visible one except on slopes facing away steeper than the view angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from affine import Affine

from sensor_models.terrain.intersect import dem_planes, intersect_dem_adaptive, intersect_dem_fixed
from sensor_models.errors import InputError
from sensor_models.models.line_table import catmull_rom_weights
from sensor_models.terrain.dem import Dem
from sensor_models.maps.grid import MapGrid, MapProjector

__all__ = ["catmull_rom_matrix", "dem_planes", "height_tolerance_for_position", "HEIGHT_TOLERANCE_M", "locate_block", "PixelGround"]

#: DEM intersection steps: two Newton then two chord steps (< 1 cm on the test terrains)
NEWTON_ITERATIONS = 4
#: adaptive intersection: the fixed-step solution on every ``COARSE_STEP``-th pixel (odd, so that
#: ``cv2.resize`` puts the coarse samples on pixel centres) starts every pixel
COARSE_STEP = 5
#: adaptive intersection: a pixel is done once its last height step is below this (metres)
HEIGHT_TOLERANCE_M = 1e-3
#: adaptive intersection: Newton steps at most on the pixels that have not converged
MAX_REFINE_STEPS = 6


@dataclass
class PixelGround:
    """Ground of a block of pixels: heights and node indices in each requested grid.

    Attributes
    ----------
    h_m : ndarray, shape (n_lines, n_cols), float32
        Ellipsoidal height of the DEM intersection (NaN where the ray leaves the DEM).
    uv : list of (u, v) pairs of float32 arrays, shape (n_lines, n_cols)
        Node-index coordinates in each grid of ``grids`` (same order).
    """

    h_m: np.ndarray
    uv: list


def catmull_rom_matrix(positions, n_nodes: int) -> np.ndarray:
    """Dense weights ``W`` of uniform Catmull-Rom interpolation on ``n_nodes`` nodes.

    ``W @ values`` interpolates ``values`` (n_nodes, ...) along the node axis.

    Parameters
    ----------
    positions : array_like of float, shape (n,)
        Positions in node units (node ``k`` at ``k``), within ``[1, n_nodes - 2]`` so that the
        four neighbours exist.
    n_nodes : int
        Number of nodes (at least 4).

    Returns
    -------
    ndarray of float64, shape (n, n_nodes)
        Interpolation weights, four non-zero per row.
    """
    p = np.asarray(positions, dtype=np.float64)
    k = np.clip(np.floor(p).astype(np.intp), 1, n_nodes - 3)
    w, _ = catmull_rom_weights(p - k)
    out = np.zeros((p.size, n_nodes))
    rows = np.arange(p.size)
    for j in range(4):
        np.add.at(out, (rows, k - 1 + j), w[:, j])
    return out


def _catmull_rom_taps(positions, n_nodes: int):
    """First node index and the four Catmull-Rom weights (float32) of each position."""
    p = np.asarray(positions, dtype=np.float64)
    k = np.clip(np.floor(p).astype(np.intp), 1, n_nodes - 3)
    w, _ = catmull_rom_weights(p - k)
    return k - 1, w.astype(np.float32)


def _interp_cols(a, taps) -> np.ndarray:
    """Interpolate the columns of ``a`` (rows, n_nodes) at the tap positions: (rows, n_out)."""
    first, w = taps
    out = a[:, first] * w[:, 0]
    for j in range(1, 4):
        out += a[:, first + j] * w[:, j]
    return out


#: output elements (rows x columns) of one small product in :func:`_interp_rows_blocked`: with
#: its four node rows that is 2**17 multiply-adds, below the size (2**18) from which OpenBLAS
#: splits a product over threads; a threaded product of this size waits on the other cores of a
#: loaded machine (measured on the development machine: 70 ms instead of 1 ms per block)
_PRODUCT_ELEMENTS = 2**15


def _interp_rows_blocked(a, taps) -> np.ndarray:
    """Interpolate the rows of each ``a[k]`` (n_nodes, cols) at the tap positions.

    The output rows that share their four node rows (``node_step`` rows per node interval) are
    one small matrix product ``W_g (n_g, 4) @ a[k, first:first + 4]`` per layer ``k``: every
    output element is written once, with no full-size temporaries (four to five times faster
    than four row gathers, multiplications and additions; same weights, the float32 sums
    differ by ~1 ulp).

    Parameters
    ----------
    a : ndarray of float32, shape (n_layers, n_nodes, n_cols)
        Node rows of each layer.
    taps : (ndarray of intp, ndarray of float32)
        First node index ``(n_out,)`` and weights ``(n_out, 4)`` of each output row
        (:func:`_catmull_rom_taps`).

    Returns
    -------
    ndarray of float32, shape (n_layers, n_out, n_cols)
        Each layer C-contiguous.
    """
    first, w = taps
    n_layers, _, n_cols = a.shape
    out = np.empty((n_layers, first.size, n_cols), dtype=np.float32)
    cuts = np.flatnonzero(np.diff(first)) + 1
    for r0, r1 in zip(np.r_[0, cuts], np.r_[cuts, first.size]):
        f = int(first[r0])
        chunk = max(64, _PRODUCT_ELEMENTS // int(r1 - r0))
        for c0 in range(0, n_cols, chunk):
            np.matmul(w[r0:r1], a[:, f : f + 4, c0 : c0 + chunk], out=out[:, r0:r1, c0 : c0 + chunk])
    return out


def locate_block(
    model,
    dem: Dem,
    grids,
    *,
    band: str,
    ccd: int,
    row0: int,
    row1: int,
    col0: int | None = None,
    col1: int | None = None,
    node_step: int = 16,
    node_step_cols: int | None = None,
    height_margin_m: float = 50.0,
    newton_iterations: int = NEWTON_ITERATIONS,
    tolerance_m: float | None = None,
    position_tolerance_m: float | None = None,
) -> PixelGround:
    """DEM intersection of the pixel centres of lines ``row0..row1-1`` of one CCD and band.

    Parameters
    ----------
    model : PushbroomModel or GeoStaringModel
        A push-broom model (one CCD's columns) or an area-array model (the whole frame;
        ``ccd`` is ignored).
    dem : Dem
        Terrain (ellipsoidal heights), sampled bilinearly between nodes.
    grids : sequence of MapGrid
        Grids in which to return node indices (e.g. the DOM's); the DEM's own grid is used
        internally and need not be listed.
    band : str
        Band name.
    ccd : int
        Index of the CCD in ``model.band_ccds(band)``.
    row0, row1 : int
        Half-open range of image lines (pixel centres at ``row + 0.5``).
    col0, col1 : int, optional
        Half-open range of raster columns (default: the CCD's columns).
    node_step : int
        Spacing of the exactly localized nodes, in pixels (lines, and columns unless
        ``node_step_cols`` is given).
    node_step_cols : int, optional
        Spacing of the nodes across the columns, in pixels (default ``node_step``). Across a
        CCD the geometry follows the interior model (a cubic in the detector index) and the
        Earth's curvature, smoother than the attitude along the lines: the reference chips use
        32 (docs/speed.md section 1; ``tests/test_locate.py``, ``tests/test_speed_paths.py``).
    height_margin_m : float
        Margin added to the DEM's height range for the two localization layers, metres.
    newton_iterations : int
        Steps of the per-pixel DEM intersection (two Newton, then chord steps).
    tolerance_m : float, optional
        None (default): ``newton_iterations`` fixed steps on every pixel. A height in metres
        (e.g. :data:`HEIGHT_TOLERANCE_M`): the adaptive solver of
        :func:`sensor_models.terrain.intersect.intersect_dem_adaptive` (coarse-grid start, two
        chord steps everywhere, Newton steps only where the last step exceeded
        ``tolerance_m``), several times faster at the same accuracy
        (``bench/bench_stages.py``).
    position_tolerance_m : float, optional
        With ``tolerance_m``: the adaptive solver stops where the bound on the horizontal
        position error is below this (metres on the ground) rather than the height error,
        i.e. at the height tolerance ``max(tolerance_m, position_tolerance_m / tan_z)``, with
        ``tan_z`` the block's largest horizontal displacement per metre of height (see
        :func:`height_tolerance_for_position`). Heights are then only as good as
        ``position_tolerance_m / tan_z``; positions keep the bound.

    Returns
    -------
    PixelGround
        Heights and node indices, arrays of shape ``(row1 - row0, col1 - col0)``.
    """
    first, width, kw = _block_columns(model, band, ccd)
    col0 = first if col0 is None else int(col0)
    col1 = first + width if col1 is None else int(col1)
    if not (row1 > row0 and col1 > col0):
        raise InputError(f"empty block rows {row0}..{row1}, cols {col0}..{col1}")
    if position_tolerance_m is not None and tolerance_m is None:
        raise InputError("position_tolerance_m needs the adaptive solver: give tolerance_m too",
                         field="position_tolerance_m")
    h_min, h_max = dem.height_range_m
    h_lo, h_hi = h_min - height_margin_m, h_max + height_margin_m
    # grids in the DEM's CRS follow from the DEM indices by an affine map; others need PROJ
    own = [g for g in grids if not g.crs.equals(dem.crs)]
    projectors = [MapProjector(MapGrid.of_dem(dem))] + [MapProjector(g) for g in own]
    # the fixed solver keeps its layers bit for bit (simulated scenes are pinned by digests)
    layers = _pixel_layers(model, kw, projectors, row0, row1, col0, col1, float(max(1, node_step)), h_lo, h_hi,
                           rows_last=tolerance_m is not None,
                           col_step=None if node_step_cols is None else float(max(1, node_step_cols)))
    if tolerance_m is None:
        h, u_dem, v_dem = intersect_dem_fixed(dem, *layers[0], np.float32(h_lo), newton_iterations)
    else:
        if position_tolerance_m is not None:
            tolerance_m = max(tolerance_m, height_tolerance_for_position(dem, *layers[0][2:], position_tolerance_m))
        h, u_dem, v_dem = intersect_dem_adaptive(dem, *layers[0], np.float32(h_lo), tolerance_m=tolerance_m,
                                                 coarse_step=COARSE_STEP, max_refine_steps=MAX_REFINE_STEPS)
    return PixelGround(h, _grid_indices(grids, dem, layers[1:], h, np.float32(h_lo), u_dem, v_dem))


def height_tolerance_for_position(dem: Dem, du, dv, position_tolerance_m: float) -> float:
    """The height tolerance that bounds the horizontal position error of a block's rays.

    A height error ``dh`` moves a ray's ground point horizontally by ``dh tan z``, where
    ``tan z`` is the horizontal displacement per metre of height (the tangent of the view's
    zenith angle at the ground). With ``tan z <= (max|du| + max|dv|) r`` over the block
    (``du, dv`` in DEM nodes per metre, ``r`` the longer side of a DEM cell in metres; the sum
    bounds the hypotenuse), a height tolerance of ``position_tolerance_m / tan z`` keeps every
    pixel within ``position_tolerance_m`` on the ground.

    Parameters
    ----------
    dem : Dem
        The terrain whose node indices ``du, dv`` are in.
    du, dv : ndarray of float32, shape (n_lines, n_cols)
        Derivatives of the rays' DEM node indices with height, nodes per metre.
    position_tolerance_m : float
        Horizontal tolerance on the ground, metres (> 0).

    Returns
    -------
    float
        Height tolerance, metres (``inf`` for vertical rays).
    """
    if not position_tolerance_m > 0:
        raise InputError(f"position_tolerance_m must be > 0, got {position_tolerance_m}", field="position_tolerance_m")
    t = dem.transform
    cell_m = max(np.hypot(t.a, t.d), np.hypot(t.b, t.e)) * (111_320.0 if dem.crs.is_geographic else 1.0)
    slope = (max(abs(float(du.max())), abs(float(du.min()))) + max(abs(float(dv.max())), abs(float(dv.min())))) * cell_m
    if not np.isfinite(slope):
        return 0.0  # no bound: the caller's height tolerance applies
    return float(position_tolerance_m / slope) if slope > 0 else np.inf


def _grid_indices(grids, dem, other_layers, h, h_lo, u_dem, v_dem) -> list:
    """Node indices in each grid: by an affine map of the DEM's in its CRS, else on the layers."""
    uv, k = [], 0
    dh = h - h_lo if other_layers else None
    for g in grids:
        if g.crs.equals(dem.crs):
            uv.append(_affine_indices(g.index_affine() @ dem.transform @ Affine.translation(0.5, 0.5), u_dem, v_dem))
        else:
            u_lo, v_lo, du, dv = other_layers[k]
            k += 1
            uv.append((u_lo + dh * du, v_lo + dh * dv))
    return uv


def _affine_indices(a: Affine, u, v):
    """``(a.a u + a.b v + a.c, a.d u + a.e v + a.f)`` as float32 arrays.

    Grids aligned with the DEM's axes (``a.b = a.d = 0``, the usual case) take two passes per
    coordinate; the values are the same bit for bit as the general formula's (``+ 0 * v`` adds
    zero; the Python scalars keep float32 arithmetic).
    """
    if a.b == 0.0 and a.d == 0.0:
        x = u * a.a
        x += a.c
        y = v * a.e
        y += a.f
        return x, y
    return ((a.a * u + a.b * v + a.c).astype(np.float32), (a.d * u + a.e * v + a.f).astype(np.float32))


def _block_columns(model, band: str, ccd: int):
    """First raster column, width and localization keywords of one CCD (or a whole frame)."""
    array = model.detector_arrays(band)[ccd]  # a CCD, or the whole frame of an area array
    return array.first_col, array.n_detectors, {"band": band, "array": ccd}


def _pixel_layers(model, kw, projectors, row0, row1, col0, col1, step, h_lo, h_hi, rows_last: bool = True,
                  col_step=None):
    """Per projector, full-resolution float32 ``u_lo, v_lo, du/dh, dv/dh`` of the block's pixels.

    The model localizes a node grid (every ``step`` pixels, one node beyond each side) at the
    heights ``h_lo`` and ``h_hi``; the node values are interpolated to every pixel centre by
    separable Catmull-Rom cubics. ``rows_last``: columns on the node rows first, then the rows
    of every layer of every projector in one pass of small matrix products
    (:func:`_interp_rows_blocked`). Otherwise rows by a matrix product, then
    columns (the original order, whose float32 rounding the fixed solver keeps), C-ordered.
    """
    n_lines, n_cols = row1 - row0, col1 - col0
    c_step = step if col_step is None else col_step
    # nodes: one before the first pixel centre and enough to pass the last one plus one
    r_nodes = row0 + 0.5 + step * np.arange(-1, int(np.ceil((n_lines - 1) / step)) + 3)
    c_nodes = col0 + 0.5 + c_step * np.arange(-1, int(np.ceil((n_cols - 1) / c_step)) + 3)
    row_taps = _catmull_rom_taps(1.0 + np.arange(n_lines) / step, r_nodes.size)
    wr = None if rows_last else catmull_rom_matrix(1.0 + np.arange(n_lines) / step, r_nodes.size).astype(np.float32)
    col_taps = _catmull_rom_taps(1.0 + np.arange(n_cols) / c_step, c_nodes.size)
    rr, cc = np.meshgrid(r_nodes, c_nodes, indexing="ij")
    ground = [
        model.image_to_ground(rr.ravel(), cc.ravel(), height=h, **kw)[:2]
        for h in (h_lo, h_hi)
    ]
    span = h_hi - h_lo
    if rows_last:  # every layer of every projector: columns on the node rows, then one row pass
        cols = []
        for proj in projectors:
            u_lo, v_lo = proj(*ground[0])
            u_hi, v_hi = proj(*ground[1])
            for a in (u_lo, v_lo, (u_hi - u_lo) / span, (v_hi - v_lo) / span):
                cols.append(_interp_cols(a.reshape(rr.shape).astype(np.float32), col_taps))
        full = _interp_rows_blocked(np.stack(cols), row_taps)
        return [list(full[4 * p : 4 * p + 4]) for p in range(len(projectors))]
    layers = []
    for proj in projectors:
        u_lo, v_lo = proj(*ground[0])
        u_hi, v_hi = proj(*ground[1])
        nodes = (u_lo, v_lo, (u_hi - u_lo) / span, (v_hi - v_lo) / span)
        layers.append([np.ascontiguousarray(_interp_cols(wr @ a.reshape(rr.shape).astype(np.float32), col_taps))
                       for a in nodes])
    return layers
