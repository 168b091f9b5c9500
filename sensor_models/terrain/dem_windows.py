"""DEM access for orthorectification with bounded memory: windows of the file, a coarse copy.

A :class:`sensor_models.terrain.dem.Dem` holds the whole height grid in float64 plus its ray-marching
aids (a cell-maximum grid and a range pyramid); building one peaks at about 11 times the float64
grid (a 6000 x 4300 node DEM: ~2.3 GB). Orthorectification needs the full-resolution heights
only block by block, and the whole DEM only for steps that tolerate a coarse one (the footprint
of the image border, the default resolution, the DEM coverage figures). So
:func:`open_ortho_dem` returns

* for a DEM of at most ``max_nodes`` nodes: the ordinary :class:`Dem` and no windows (the
  orthoimage is exactly what it was before this module existed);
* for a larger DEM: a coarse :class:`Dem` (block-averaged to at most ``coarse_nodes`` nodes) for
  the global steps, and :class:`DemWindows`, which reads, per output block, only the DEM window
  the block's pixels need and interpolates it exactly as :class:`Dem` would (same nodes, same
  datum conversion, same bilinear formula), so the heights of every output pixel are the ones
  of the full-resolution DEM. The output grid, though, comes from the footprint on the coarse
  DEM: its bounding box can move by a pixel against the whole DEM's when the output pixel is
  much finer than the coarse nodes (a 0.5 m Pleiades crop over a coarsened SRTM tile moves by
  4 rows), which is why DEMs up to :data:`MAX_DEM_NODES` stay whole.
"""

from __future__ import annotations

import os
import threading

import numpy as np
import pyproj

from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES
from sensor_models.errors import InputError
from sensor_models.files.threads import PerThread

__all__ = ["COARSE_DEM_NODES", "MAX_DEM_NODES", "DemWindows", "bilinear_nodes", "open_ortho_dem"]

#: DEMs up to this many nodes are loaded whole, as before: an SRTM-1 1 x 1 degree tile (3601 x 3601
#: nodes) still is, so orthoimages over such tiles keep their grid to the bit (~1.1 GB while it is
#: built); larger DEMs (a mosaic under a large scene) are read by windows
MAX_DEM_NODES = 13_000_000
#: nodes of the coarse copy of a larger DEM (footprint, default resolution, coverage): ~90 MB built
COARSE_DEM_NODES = 1_000_000


def bilinear_nodes(z: np.ndarray, u, v, *, shape=None, row0: int = 0, col0: int = 0) -> np.ndarray:
    """Bilinear heights at node indices ``(u, v)`` from a grid or a window of it.

    Parameters
    ----------
    z : ndarray (rows, cols), float64
        Heights of nodes ``row0 ..``, ``col0 ..`` of the full grid (NaN = no data).
    u, v : ndarray, float64
        Column and row node indices in the full grid (first node centre at 0).
    shape : (int, int), optional
        Shape of the full grid (default: ``z.shape``).
    row0, col0 : int
        Position of ``z[0, 0]`` in the full grid.

    Returns
    -------
    ndarray, float64, shape of ``u``
        NaN outside the node hull or next to a no-data node.
    """
    n_r, n_c = z.shape if shape is None else shape
    inside = (u >= 0.0) & (u <= n_c - 1) & (v >= 0.0) & (v <= n_r - 1)
    u = np.where(inside, u, 0.0)
    v = np.where(inside, v, 0.0)
    i = np.minimum(u.astype(np.intp), n_c - 2)
    j = np.minimum(v.astype(np.intp), n_r - 2)
    fu, fv = u - i, v - j
    w = z.shape[1]
    k = np.clip(j - row0, 0, z.shape[0] - 2) * w + np.clip(i - col0, 0, w - 2)
    zf = z.reshape(-1)
    z00, z01, z10, z11 = zf.take(k), zf.take(k + 1), zf.take(k + w), zf.take(k + w + 1)
    top = z00 + fu * (z01 - z00)
    out = top + fv * (z10 + fu * (z11 - z10) - top)
    out[~inside] = np.nan
    return out


class DemWindows:
    """Full-resolution ellipsoidal DEM heights read from the raster by windows.

    :meth:`read` and :meth:`heights` may be called from several threads at once (each reads
    through its own handle).

    Parameters
    ----------
    path : str or os.PathLike
        The DEM raster (band 1; nodata, scale and offset as :class:`Dem` reads them).
    datum : {"ellipsoid", "egm96"}
        Vertical datum of the file's heights (already checked by the caller).
    geoid : Geoid, optional
        Undulation grid, required for ``"egm96"``.

    Attributes
    ----------
    transform : affine.Affine
        Pixel-corner transform of the whole raster.
    crs : pyproj.CRS
        Horizontal CRS of the raster.
    shape : (int, int)
        Nodes of the whole raster.
    nodes_read : int
        Nodes read so far.
    largest_window_nodes : int
        Nodes of the largest window read so far (what one block needed).
    """

    def __init__(self, path, datum: str, geoid=None):
        import rasterio

        from sensor_models.terrain.datum import horizontal_crs
        from sensor_models.terrain.grid_geometry import GridGeometry

        self.path = os.fspath(path)
        self._ds = rasterio.open(self.path)
        self.transform = self._ds.transform
        self.crs = horizontal_crs(pyproj.CRS.from_wkt(self._ds.crs.to_wkt()))
        self.shape = (self._ds.height, self._ds.width)
        self._scale = self._ds.scales[0] if self._ds.scales else 1.0
        self._offset = self._ds.offsets[0] if self._ds.offsets else 0.0
        self._geoid = geoid if datum == "egm96" else None
        self._geometry = GridGeometry(self.transform, self.crs, self.shape)
        self._datasets = PerThread(lambda: rasterio.open(self.path), first=self._ds)  # one handle per thread
        self._count_lock = threading.Lock()
        self.nodes_read = 0
        self.largest_window_nodes = 0

    def read(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """Ellipsoidal heights (float64, NaN = no data) of nodes ``[row0:row1, col0:col1]``.

        Parameters
        ----------
        row0, row1, col0, col1 : int
            Node window, end exclusive.

        Returns
        -------
        ndarray, shape (row1 - row0, col1 - col0), float64
        """
        from rasterio.windows import Window

        band = self._datasets.get().read(1, window=Window(col0, row0, col1 - col0, row1 - row0), masked=True)
        values = np.ma.filled(band.astype(np.float64), np.nan)
        if self._scale != 1.0 or self._offset != 0.0:
            values = values * self._scale + self._offset
        if self._geoid is not None:  # as Dem._with_datum, node by node
            cols, rows = np.meshgrid(np.arange(col0, col1, dtype=np.float64),
                                     np.arange(row0, row1, dtype=np.float64))
            lon, lat = self._geometry.index_to_lonlat(cols, rows)
            values = values + self._geoid.undulation_m(lon, lat)
        with self._count_lock:
            self.nodes_read += values.size
            self.largest_window_nodes = max(self.largest_window_nodes, values.size)
        return values

    def heights(self, u, v) -> np.ndarray:
        """Bilinear heights at full-grid node indices ``(u, v)``, reading one window.

        Parameters
        ----------
        u, v : ndarray, float64
            Column and row node indices (first node centre at 0).

        Returns
        -------
        ndarray, float64, shape of ``u``
            NaN outside the DEM or next to no-data nodes.
        """
        n_r, n_c = self.shape
        inside = (u >= 0.0) & (u <= n_c - 1) & (v >= 0.0) & (v <= n_r - 1)
        if not inside.any():
            return np.full(np.shape(u), np.nan)
        i = np.minimum(u[inside].astype(np.intp), n_c - 2)
        j = np.minimum(v[inside].astype(np.intp), n_r - 2)
        col0, col1 = int(i.min()), int(i.max()) + 2
        row0, row1 = int(j.min()), int(j.max()) + 2
        z = self.read(row0, row1, col0, col1)
        return bilinear_nodes(z, u, v, shape=self.shape, row0=row0, col0=col0)

    def close(self) -> None:
        """Close the raster (every thread's handle)."""
        self._datasets.close()


def open_ortho_dem(path, *, vertical_datum=None, geoid=None, max_nodes: int = MAX_DEM_NODES,
                   coarse_nodes: int = COARSE_DEM_NODES):
    """The DEM of an orthorectification: whole when small, else coarse plus windows.

    Parameters
    ----------
    path : str or os.PathLike
        DEM raster (any CRS rasterio reads).
    vertical_datum : {"ellipsoid", "egm96"}, optional
        As :meth:`sensor_models.terrain.dem.Dem.open`.
    geoid : str, os.PathLike or Geoid, optional
        EGM96 undulation grid.
    max_nodes : int
        Largest DEM loaded whole.
    coarse_nodes : int
        Most nodes of the coarse copy of a larger DEM (at most ``max_nodes``).

    Returns
    -------
    dem : sensor_models.terrain.dem.Dem
        The whole DEM, or a block-averaged copy of at most ``min(coarse_nodes, max_nodes)`` nodes.
    windows : DemWindows or None
        Full-resolution heights by windows; None when ``dem`` is the whole DEM.

    Raises
    ------
    DemError, GeoidGridMissingError, InputError
        As :meth:`Dem.open` (missing file, no datum, contradicting datum, missing geoid).
    """
    import rasterio
    from rasterio.errors import RasterioError

    from sensor_models.errors import DemError
    from sensor_models.terrain.dem import Dem

    source = os.fspath(path)
    try:
        with rasterio.open(source) as ds:
            n_nodes = ds.width * ds.height
    except (RasterioError, OSError):
        n_nodes = 0  # Dem.open says what is wrong
    if n_nodes <= max_nodes:
        return Dem.open(source, vertical_datum=vertical_datum, geoid=geoid), None
    datum = _checked_datum(source, vertical_datum, geoid)
    grid = _as_geoid_or_none(geoid, datum, source)
    values, transform, crs = _read_coarse(source, min(int(coarse_nodes), int(max_nodes)))
    if crs is None:
        raise DemError(f"{source}: the DEM declares no coordinate reference system")
    coarse = Dem._with_datum(values, transform, crs, datum, grid, source=source)
    return coarse, DemWindows(source, datum, grid)


def _checked_datum(source: str, vertical_datum, geoid) -> str:
    """The file's vertical datum, checked as :meth:`Dem.open` checks it (on a 2 x 2 node window)."""
    import rasterio

    from sensor_models.terrain.datum import check_datum_name, declared_datum, tagged_datum
    from sensor_models.terrain.dem import Dem

    with rasterio.open(source) as ds:
        crs = None if ds.crs is None else pyproj.CRS.from_wkt(ds.crs.to_wkt())
        centre = ds.transform * (0.5 * ds.width, 0.5 * ds.height)
    if crs is not None:  # Dem.open on a small window raises the errors a whole read would
        from sensor_models.terrain.datum import horizontal_crs

        lon, lat = pyproj.Transformer.from_crs(horizontal_crs(crs), "EPSG:4326", always_xy=True).transform(*centre)
        Dem.open(source, vertical_datum=vertical_datum, geoid=geoid,
                 bounds=(lon - 1e-6, lat - 1e-6, lon + 1e-6, lat + 1e-6), margin_deg=0.0)
    datum = check_datum_name(vertical_datum)
    return datum or declared_datum(crs, source=source) or tagged_datum(source)


def _as_geoid_or_none(geoid, datum: str, source: str):
    from sensor_models.terrain.geoid import as_geoid

    return as_geoid(geoid, dem_source=source) if datum == "egm96" else None


def _read_coarse(source: str, max_nodes: int):
    """Band 1 block-averaged (GDAL ``average``) to at most ``max_nodes`` nodes, float64, NaN = no data."""
    import rasterio
    from rasterio.enums import Resampling

    # GDAL caps its block cache at 5 % of the RAM by default; a decimated read would fill it
    with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES), rasterio.open(source) as ds:
        factor = int(np.ceil(np.sqrt(ds.width * ds.height / float(max_nodes))))
        out_shape = (max(2, ds.height // factor), max(2, ds.width // factor))
        band = ds.read(1, out_shape=out_shape, masked=True, resampling=Resampling.average)
        scale = ds.scales[0] if ds.scales else 1.0
        offset = ds.offsets[0] if ds.offsets else 0.0
        transform = ds.transform * ds.transform.scale(ds.width / out_shape[1], ds.height / out_shape[0])
        crs = None if ds.crs is None else pyproj.CRS.from_wkt(ds.crs.to_wkt())
    values = np.ma.filled(band.astype(np.float64), np.nan)
    if scale != 1.0 or offset != 0.0:
        values = values * scale + offset
    if not np.isfinite(values).any():
        raise InputError("the DEM holds no valid height", path=source)
    return np.ascontiguousarray(values), transform, crs
