"""Source pixels of an orthoimage and their resampling at the block's image positions.

:class:`SourceBand` reads windows of one band of the scene raster (or of an array) as float32
with NaN for no data; :func:`resolve_source` finds that raster from what the caller gives;
:func:`resample_block` samples it at a :class:`~sensor_models.imaging.ortho_geometry.BlockGeometry`
with OpenCV's ``remap`` (image pixel centres at ``(i + 0.5, j + 0.5)``).

OpenCV's ``remap`` quantizes sample positions to 1/32 pixel (a zero-mean error of at most
1/64 px per axis). Bilinear interpolation reproduces a linear ramp exactly; OpenCV's cubic
(Keys' kernel with ``a = -0.75``, sharper) only to a periodic, zero-mean error below 0.05 px.
Samples whose bilinear/cubic support touches a no-data source pixel are no-data. An output
coarser than the image is point-sampled (no area averaging): choose a resolution near the
scene's ground sampling distance, or decimate afterwards.
"""

from __future__ import annotations

import os
import warnings

import cv2
import numpy as np

from sensor_models.errors import InputError
from sensor_models.files.threads import PerThread
from sensor_models.imaging.ortho_geometry import BlockGeometry

__all__ = ["RESAMPLING", "SourceBand", "resample_block", "resolve_source"]


#: OpenCV interpolation of each resampling name
RESAMPLING = {"nearest": cv2.INTER_NEAREST, "bilinear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
#: source pixels beyond the extreme sample positions read with each block (cubic needs 2)
_READ_PAD = 3


# ---------------------------------------------------------------- source pixels
class SourceBand:
    """Windowed float32 access to one band of a raster in scene geometry (NaN = no data).

    :meth:`read` may be called from several threads at once (each reads through its own handle).

    Parameters
    ----------
    image : ndarray (n_rows, n_cols), str or os.PathLike
        The image itself, or a raster file opened (and kept open until :meth:`close`).
    index : int
        1-based band index in the raster file.

    Raises
    ------
    InputError
        A missing or unreadable file, a band index outside the file, an array that is not 2-D.
    """

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
        self._datasets = PerThread(lambda: rasterio.open(self.path), first=self.dataset)  # one handle per thread
        self.index = index
        self.shape = (self.dataset.height, self.dataset.width)
        self.dtype = np.dtype(self.dataset.dtypes[index - 1])
        self.nodata = self.dataset.nodata

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Pixels ``[r0:r1, c0:c1]`` as float32, NaN where the raster has no data."""
        if self.array is not None:
            return self.array[r0:r1, c0:c1].astype(np.float32)
        from rasterio.windows import Window

        data = self._datasets.get().read(self.index, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
        return np.ma.filled(data.astype(np.float32), np.nan)

    def close(self):
        """Close the raster file, every thread's handle (nothing to do for an array)."""
        if self.dataset is not None:
            self._datasets.close()


def resolve_source(model, image, band, rasters=None):
    """``(source, band)`` from an image argument: array, raster path, band name, or None.

    A band name or None is looked up in ``rasters`` (band -> ``{"path", "index"}``, e.g. a
    Scene's ``rasters``; None: no raster listed).
    """
    rasters = rasters or {}
    if isinstance(image, np.ndarray):
        return SourceBand(image), band
    if isinstance(image, tuple):
        path, index = image
        return SourceBand(path, int(index)), band
    if image is None or (isinstance(image, str) and image in rasters and not os.path.isfile(image)):
        if image is not None:
            if band is not None and band != image:
                raise InputError(f"image names band {image!r} but band={band!r}")
            band = image
        key = band if band is not None else getattr(model, "reference_band", None)
        if key not in rasters:
            raise InputError(f"no raster listed for band {key!r}; give the image raster")
        entry = rasters[key]
        return SourceBand(entry["path"], int(entry.get("index", 1))), key
    return SourceBand(image), band


# ---------------------------------------------------------------- resampling
def resample_block(source: SourceBand, geom: BlockGeometry, interpolation: int) -> np.ndarray:
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
