"""Map grids: an affine raster grid and the projection of WGS84 points onto its node indices."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pyproj
from affine import Affine


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
    def of_dem(cls, dem) -> "MapGrid":
        """The grid of a DEM's height raster.

        Parameters
        ----------
        dem : sensor_models.terrain.dem.Dem
            Terrain (or any raster) whose ``transform``, ``crs`` and ``shape`` are taken.

        Returns
        -------
        MapGrid
        """
        return cls(dem.transform, dem.crs, dem.shape)


@functools.lru_cache(maxsize=32)
def _transformer_from_wgs84(crs_srs: str) -> pyproj.Transformer:
    """WGS84 lon/lat -> the CRS given by its definition string, built once per CRS.

    Building a PROJ transformer costs about 0.4 ms, as much as localizing a thousand nodes;
    :func:`locate_block` needs one per block. pyproj's ``Transformer`` is thread-safe (3.1+).
    """
    return pyproj.Transformer.from_crs("EPSG:4326", pyproj.CRS.from_user_input(crs_srs), always_xy=True)


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
        crs = grid.crs if isinstance(grid.crs, pyproj.CRS) else pyproj.CRS.from_user_input(grid.crs)
        self.to_crs = _transformer_from_wgs84(crs.srs or crs.to_wkt())
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
