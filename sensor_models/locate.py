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
import pyproj
from affine import Affine

from sensor_models.dem_intersect import _intersect_dem, dem_planes, intersect_dem_adaptive
from sensor_models.errors import InputError
from sensor_models.pushbroom import _catmull_rom_weights
from sensor_models.terrain import Dem

__all__ = ["HEIGHT_TOLERANCE_M", "MapGrid", "MapProjector", "PixelGround", "catmull_rom_matrix", "dem_planes",
           "locate_block"]

#: DEM intersection steps: two Newton then two chord steps (< 1 cm on the test terrains)
NEWTON_ITERATIONS = 4
#: adaptive intersection: the fixed-step solution on every ``COARSE_STEP``-th pixel (odd, so that
#: ``cv2.resize`` puts the coarse samples on pixel centres) starts every pixel
COARSE_STEP = 5
#: adaptive intersection: a pixel is done once its last height step is below this (metres)
HEIGHT_TOLERANCE_M = 1e-3
#: adaptive intersection: Newton steps at most on the pixels that have not converged
MAX_REFINE_STEPS = 6


@dataclass(frozen=True)
class MapGrid:
    """An affine raster grid: pixel-corner ``transform`` (rasterio), ``crs`` and ``shape``.

    Node-index coordinates ``(u, v)`` put the centre of pixel ``[j, i]`` at ``(i, j)``, the
    convention of ``cv2.remap`` and ``scipy.ndimage.map_coordinates``.

    Attributes
    ----------
    transform : affine.Affine
        Map coordinates of pixel corners (rasterio convention).
    crs : pyproj.CRS
        Coordinate reference system of the map coordinates.
    shape : (int, int)
        Number of rows and columns.
    """

    transform: Affine
    crs: pyproj.CRS
    shape: tuple[int, int]

    def index_affine(self) -> Affine:
        """The affine map from map coordinates ``(x, y)`` to node indices ``(u, v)``.

        Returns
        -------
        affine.Affine
            ``~transform`` followed by a shift of half a pixel (pixel centres on integers).
        """
        return Affine.translation(-0.5, -0.5) @ ~self.transform

    @property
    def resolution_m(self) -> float:
        """Approximate pixel size in metres (geographic grids at 111.32 km per degree).

        Returns
        -------
        float
            Square root of the pixel area, metres.
        """
        t = self.transform
        res = float(np.sqrt(abs(t.a * t.e - t.b * t.d)))
        return res * 111_320.0 if self.crs.is_geographic else res

    @classmethod
    def of_dem(cls, dem: Dem) -> "MapGrid":
        """The grid of a DEM's height raster.

        Parameters
        ----------
        dem : Dem
            Terrain whose ``transform``, ``crs`` and ``shape`` are taken.

        Returns
        -------
        MapGrid
        """
        return cls(dem.transform, dem.crs, dem.shape)


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
    w, _ = _catmull_rom_weights(p - k)
    out = np.zeros((p.size, n_nodes))
    rows = np.arange(p.size)
    for j in range(4):
        np.add.at(out, (rows, k - 1 + j), w[:, j])
    return out


def _catmull_rom_taps(positions, n_nodes: int):
    """First node index and the four Catmull-Rom weights (float32) of each position."""
    p = np.asarray(positions, dtype=np.float64)
    k = np.clip(np.floor(p).astype(np.intp), 1, n_nodes - 3)
    w, _ = _catmull_rom_weights(p - k)
    return k - 1, w.astype(np.float32)


def _interp_cols(a, taps) -> np.ndarray:
    """Interpolate the columns of ``a`` (rows, n_nodes) at the tap positions: (rows, n_out)."""
    first, w = taps
    out = a[:, first] * w[:, 0]
    for j in range(1, 4):
        out += a[:, first + j] * w[:, j]
    return out


def _interp_rows(a, taps) -> np.ndarray:
    """Interpolate the rows of ``a`` (n_nodes, cols) at the tap positions: C-contiguous (n_out, cols).

    Row gathers of a C-ordered array keep every full-size temporary C-ordered, so the per-pixel
    arithmetic that follows runs at memory speed (column gathers of the full-size block gave
    Fortran-ordered layers and strided loops).
    """
    first, w = taps
    out = a[first]
    out *= w[:, 0, None]
    tmp = np.empty_like(out)
    for j in range(1, 4):
        np.take(a, first + j, axis=0, out=tmp)
        tmp *= w[:, j, None]
        out += tmp
    return out


class MapProjector:
    """WGS84 longitude and latitude -> node indices ``(u, v)`` of one map grid.

    The PROJ transformer is built once per grid and reused for every call.

    Parameters
    ----------
    grid : MapGrid
        The target grid (any CRS PROJ knows).
    """

    def __init__(self, grid: MapGrid):
        self.grid = grid
        self.to_crs = pyproj.Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True)
        self.index = grid.index_affine()

    def __call__(self, lon, lat):
        """Node indices of ground points.

        Parameters
        ----------
        lon, lat : array_like of float, same shape
            WGS84 longitude and latitude, degrees.

        Returns
        -------
        u, v : ndarray of float64, shape of ``lon``
            Column and row node indices in the grid (pixel ``[j, i]`` centre at ``(i, j)``).
        """
        x, y = self.to_crs.transform(lon, lat)
        a = self.index
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return a.a * x + a.b * y + a.c, a.d * x + a.e * y + a.f


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
    height_margin_m: float = 50.0,
    newton_iterations: int = NEWTON_ITERATIONS,
    tolerance_m: float | None = None,
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
        Spacing of the exactly localized nodes, in pixels.
    height_margin_m : float
        Margin added to the DEM's height range for the two localization layers, metres.
    newton_iterations : int
        Steps of the per-pixel DEM intersection (two Newton, then chord steps).
    tolerance_m : float, optional
        None (default): ``newton_iterations`` fixed steps on every pixel. A height in metres
        (e.g. :data:`HEIGHT_TOLERANCE_M`): the adaptive solver of
        :func:`sensor_models.dem_intersect.intersect_dem_adaptive` (coarse-grid start, one
        step everywhere, more steps only where the last one exceeded ``tolerance_m``), about
        3x faster at the same accuracy (``bench/bench_match.py --stages``).

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
    h_min, h_max = dem.height_range_m
    h_lo, h_hi = h_min - height_margin_m, h_max + height_margin_m
    # grids in the DEM's CRS follow from the DEM indices by an affine map; others need PROJ
    own = [g for g in grids if not g.crs.equals(dem.crs)]
    projectors = [MapProjector(MapGrid.of_dem(dem))] + [MapProjector(g) for g in own]
    # the fixed solver keeps its layers bit for bit (simulated scenes are pinned by digests)
    layers = _pixel_layers(model, kw, projectors, row0, row1, col0, col1, float(max(1, node_step)), h_lo, h_hi,
                           rows_last=tolerance_m is not None)
    if tolerance_m is None:
        h, u_dem, v_dem = _intersect_dem(dem, *layers[0], np.float32(h_lo), newton_iterations)
    else:
        h, u_dem, v_dem = intersect_dem_adaptive(dem, *layers[0], np.float32(h_lo), tolerance_m=tolerance_m,
                                                 coarse_step=COARSE_STEP, max_refine_steps=MAX_REFINE_STEPS)
    return PixelGround(h, _grid_indices(grids, dem, layers[1:], h - np.float32(h_lo), u_dem, v_dem))


def _grid_indices(grids, dem, other_layers, dh, u_dem, v_dem) -> list:
    """Node indices in each grid: by an affine map of the DEM's in its CRS, else on the layers."""
    uv, k = [], 0
    for g in grids:
        if g.crs.equals(dem.crs):
            a = g.index_affine() @ dem.transform @ Affine.translation(0.5, 0.5)
            uv.append(((a.a * u_dem + a.b * v_dem + a.c).astype(np.float32),
                       (a.d * u_dem + a.e * v_dem + a.f).astype(np.float32)))
        else:
            u_lo, v_lo, du, dv = other_layers[k]
            k += 1
            uv.append((u_lo + dh * du, v_lo + dh * dv))
    return uv


def _block_columns(model, band: str, ccd: int):
    """First raster column, width and localization keywords of one CCD (or a whole frame)."""
    array = model.detector_arrays(band)[ccd]  # a CCD, or the whole frame of an area array
    return array.first_col, array.n_detectors, {"band": band, "array": ccd}


def _pixel_layers(model, kw, projectors, row0, row1, col0, col1, step, h_lo, h_hi, rows_last: bool = True):
    """Per projector, full-resolution float32 ``u_lo, v_lo, du/dh, dv/dh`` of the block's pixels.

    The model localizes a node grid (every ``step`` pixels, one node beyond each side) at the
    heights ``h_lo`` and ``h_hi``; the node values are interpolated to every pixel centre by
    separable Catmull-Rom cubics. ``rows_last``: columns on the node rows first, then rows by
    row gathers (faster); otherwise rows by a matrix product, then columns (the original order,
    whose float32 rounding the fixed solver keeps). Either way the layers are C-ordered.
    """
    n_lines, n_cols = row1 - row0, col1 - col0
    # nodes: one before the first pixel centre and enough to pass the last one plus one
    r_nodes = row0 + 0.5 + step * np.arange(-1, int(np.ceil((n_lines - 1) / step)) + 3)
    c_nodes = col0 + 0.5 + step * np.arange(-1, int(np.ceil((n_cols - 1) / step)) + 3)
    row_taps = _catmull_rom_taps(1.0 + np.arange(n_lines) / step, r_nodes.size)
    wr = None if rows_last else catmull_rom_matrix(1.0 + np.arange(n_lines) / step, r_nodes.size).astype(np.float32)
    col_taps = _catmull_rom_taps(1.0 + np.arange(n_cols) / step, c_nodes.size)
    rr, cc = np.meshgrid(r_nodes, c_nodes, indexing="ij")
    ground = [
        model.image_to_ground(rr.ravel(), cc.ravel(), height=h, **kw)[:2]
        for h in (h_lo, h_hi)
    ]
    span = h_hi - h_lo
    layers = []
    for proj in projectors:
        u_lo, v_lo = proj(*ground[0])
        u_hi, v_hi = proj(*ground[1])
        nodes = (u_lo, v_lo, (u_hi - u_lo) / span, (v_hi - v_lo) / span)
        if rows_last:
            layers.append([_interp_rows(np.ascontiguousarray(_interp_cols(a.reshape(rr.shape).astype(np.float32),
                                                                          col_taps)), row_taps) for a in nodes])
        else:
            layers.append([np.ascontiguousarray(_interp_cols(wr @ a.reshape(rr.shape).astype(np.float32), col_taps))
                           for a in nodes])
    return layers
