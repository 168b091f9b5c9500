"""Single-band rasters on map grids (reference DOMs), read by windows and resampled at node indices.

* :class:`MapImage`: a DOM (or any single-band map raster) in memory or on disk, read by
  windows; nodata becomes NaN.
* :func:`sample_map_image`: blur (Gaussian, no-data aware) and sample bilinearly at the node
  indices that :func:`sensor_models.locate.locate_block` returns.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.locate import MapGrid

__all__ = ["MapImage", "sample_map_image"]


@dataclass
class MapImage:
    """A single-band raster on a map grid, read by windows (float32, NaN for nodata).

    Build with :meth:`from_array` or :meth:`open`; ``grid`` describes it.

    Attributes
    ----------
    grid : MapGrid
        Transform, CRS and shape of the raster.
    path : str or None
        The file read by windows (None for an image held in memory).
    nodata : float or None
        The file's no-data value, read as NaN.
    """

    grid: MapGrid
    _array: np.ndarray | None = None
    path: str | None = None
    nodata: float | None = None

    @classmethod
    def from_array(cls, values, transform, crs) -> "MapImage":
        """A map image held in memory.

        Parameters
        ----------
        values : array_like, shape (n_rows, n_cols)
            Pixel values (any numeric dtype; read back as float32).
        transform : affine.Affine or sequence of 6 float
            Pixel-corner geotransform (rasterio convention).
        crs : pyproj.CRS, str or int
            Coordinate reference system (anything :meth:`pyproj.CRS.from_user_input` takes).

        Returns
        -------
        MapImage
        """
        values = np.asarray(values)
        return cls(MapGrid(Affine(*tuple(transform)[:6]), pyproj.CRS.from_user_input(crs), values.shape), values)

    @classmethod
    def open(cls, path, *, what: str = "DOM") -> "MapImage":
        """A map image on disk, read lazily by windows (band 1).

        Parameters
        ----------
        path : str or os.PathLike
            A raster file GDAL reads, with a coordinate reference system.
        what : str
            What the file is, for error messages.

        Returns
        -------
        MapImage

        Raises
        ------
        InputError
            The file is missing, unreadable or declares no CRS.
        """
        import rasterio
        from rasterio.errors import RasterioError

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise InputError(f"{what} file not found", path=path)
        try:
            with rasterio.open(path) as ds:
                if ds.crs is None:
                    raise InputError(f"the {what} declares no coordinate reference system", path=path)
                grid = MapGrid(ds.transform, pyproj.CRS.from_wkt(ds.crs.to_wkt()), (ds.height, ds.width))
                nodata = ds.nodata
        except RasterioError as exc:
            raise InputError(f"cannot be read as a {what} raster ({exc})", path=path) from None
        return cls(grid, None, path, nodata)

    def read_decimated(self, row0: int, row1: int, col0: int, col1: int, out_shape) -> np.ndarray:
        """Pixels ``[row0:row1, col0:col1]`` (inside the raster) averaged down to ``out_shape``.

        Parameters
        ----------
        row0, row1, col0, col1 : int
            Half-open window in raster pixels; must lie inside the raster.
        out_shape : (int, int)
            Output shape (rows, cols); pixels are area-averaged.

        Returns
        -------
        ndarray of float32, shape ``out_shape``
            NaN where the raster has no data.
        """
        import cv2

        n_rows, n_cols = self.grid.shape
        if not (0 <= row0 < row1 <= n_rows and 0 <= col0 < col1 <= n_cols):
            raise InputError(f"window rows {row0}..{row1}, cols {col0}..{col1} outside the raster",
                             path=self.path or "image")
        if self._array is None:
            import rasterio
            from rasterio.enums import Resampling
            from rasterio.windows import Window

            with rasterio.open(self.path) as ds:
                block = ds.read(1, window=Window(col0, row0, col1 - col0, row1 - row0), out_shape=tuple(out_shape),
                                resampling=Resampling.average, masked=True)
                block = np.ma.filled(block.astype(np.float32), np.nan)
        else:
            full = self._array[row0:row1, col0:col1].astype(np.float32)
            block = cv2.resize(full, (int(out_shape[1]), int(out_shape[0])), interpolation=cv2.INTER_AREA)
        if self.nodata is not None and not np.isnan(self.nodata):
            block[block == self.nodata] = np.nan
        return block

    def read(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """Pixels ``[row0:row1, col0:col1]`` (clipped to the raster) as float32; NaN = no data.

        Parameters
        ----------
        row0, row1, col0, col1 : int
            Half-open window in raster pixels; may extend beyond the raster.

        Returns
        -------
        ndarray of float32, shape (row1 - row0, col1 - col0)
            NaN outside the raster and where it has no data.
        """
        n_rows, n_cols = self.grid.shape
        r0, r1 = max(0, row0), min(n_rows, row1)
        c0, c1 = max(0, col0), min(n_cols, col1)
        out = np.full((row1 - row0, col1 - col0), np.nan, dtype=np.float32)
        if r1 <= r0 or c1 <= c0:
            return out
        if self._array is not None:
            block = self._array[r0:r1, c0:c1].astype(np.float32)
        else:
            import rasterio
            from rasterio.windows import Window

            with rasterio.open(self.path) as ds:
                block = ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
                block = np.ma.filled(block.astype(np.float32), np.nan)
        if self.nodata is not None and not np.isnan(self.nodata):
            block[block == self.nodata] = np.nan
        out[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = block
        return out


def sample_map_image(image: MapImage, u, v, *, sigma_px: float = 0.0) -> np.ndarray:
    """Sample a map image at node indices ``(u, v)`` after a Gaussian blur of ``sigma_px``.

    Only the window covering the requested positions (plus the blur's reach) is read. No-data
    pixels are excluded by normalized convolution; where more than 1 % of the blur's weight
    falls on no-data, and outside the raster, the result is NaN.

    Parameters
    ----------
    image : MapImage
        The map image (e.g. a DOM).
    u, v : ndarray, float32, same shape
        Node-index coordinates (pixel ``[j, i]`` centre at ``(i, j)``); NaN allowed.
    sigma_px : float
        Standard deviation of the blur in image pixels (0: none).

    Returns
    -------
    ndarray, float32, shape of ``u``
        Bilinear samples (OpenCV ``remap``: positions quantized to 1/32 pixel).
    """
    import cv2

    out = np.full(u.shape, np.nan, dtype=np.float32)
    ok = np.isfinite(u) & np.isfinite(v)
    if not ok.any():
        return out
    pad = int(np.ceil(4.0 * sigma_px)) + 3
    c0 = int(np.floor(u[ok].min())) - pad
    c1 = int(np.ceil(u[ok].max())) + pad + 1
    r0 = int(np.floor(v[ok].min())) - pad
    r1 = int(np.ceil(v[ok].max())) + pad + 1
    crop = image.read(r0, r1, c0, c1)
    valid = np.isfinite(crop).astype(np.float32)
    crop = np.where(valid > 0, crop, 0.0).astype(np.float32)
    if sigma_px > 0:
        crop = cv2.GaussianBlur(crop, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
        valid = cv2.GaussianBlur(valid, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        crop = np.where(valid > 0.99, crop / valid, np.nan).astype(np.float32)
    uu = np.where(ok, u - c0, -1.0).astype(np.float32)
    vv = np.where(ok, v - r0, -1.0).astype(np.float32)
    return cv2.remap(crop, uu, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
