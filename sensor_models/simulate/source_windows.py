"""The scene's source radiance kept on disk and read by windows, filtered by the optics per window.

The realistic renderer (:mod:`sensor_models.simulate.realistic_sim`) samples a source grid that
covers the bounding box of the whole footprint in UTM: at a wide swath it is far larger than the
image (the seed-003 geometry at +-32 degrees: 1252 M pixels at 22.5 m). Two pieces keep what the
blocks of lines hold independent of that grid:

* :class:`RowFile`: a float32 raster of ``(H, W)`` in a scratch file, written by strips of rows
  as each strip is computed and read back by windows. Each access maps only the bytes of its
  rows and copies out its columns, then unmaps them, so the resident memory is the window, not
  the file (a mapping kept open would count every page read in the resident set).
* :class:`FilteredWindows`: the source convolved with the optical PSFs
  (:func:`sensor_models.simulate.kernel.optics_kernel`) over one window at a time. The window is
  read with the kernel's half size ``m`` of neighbours on every side; where it reaches the
  grid's edge the neighbours are the grid mirrored (``BORDER_REFLECT``, ``fedcba|abcdef``), as
  a whole-grid ``cv2.filter2D`` with that border takes them. Each filtered pixel therefore sees
  the same ``(2 m + 1)^2`` source pixels as on the whole grid; only the summation order of
  OpenCV's FFT convolution, which depends on the window's size, moves the last bits.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["FilteredWindows", "RowFile", "read_rows", "read_window"]


class RowFile:
    """A float32 ``(n_rows, n_cols)`` raster in a scratch file (C order, no header).

    Parameters
    ----------
    path : path
        The scratch file (created, truncated to the raster's size; :meth:`remove` deletes it).
    shape : tuple of int
        ``(n_rows, n_cols)``.
    """

    dtype = np.dtype(np.float32)

    def __init__(self, path, shape):
        self.path = Path(path)
        self.shape = (int(shape[0]), int(shape[1]))
        with open(self.path, "wb") as fh:
            fh.truncate(self.shape[0] * self.shape[1] * self.dtype.itemsize)

    def write_rows(self, row0: int, values: np.ndarray) -> None:
        """Write ``values`` (shape ``(k, n_cols)``) as rows ``row0 .. row0 + k - 1``."""
        values = np.ascontiguousarray(values, dtype=self.dtype)
        if values.ndim != 2 or values.shape[1] != self.shape[1] or not 0 <= row0 <= self.shape[0] - values.shape[0]:
            raise ValueError(f"rows {row0}+{values.shape} do not fit a raster of {self.shape}")
        with open(self.path, "r+b") as fh:
            fh.seek(row0 * self.shape[1] * self.dtype.itemsize)
            fh.write(values.tobytes())

    def read(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """Rows ``row0:row1`` and columns ``col0:col1`` (inside the raster), a new float32 array."""
        n_cols = self.shape[1]
        if not (0 <= row0 < row1 <= self.shape[0] and 0 <= col0 < col1 <= n_cols):
            raise ValueError(f"window {(row0, row1, col0, col1)} is not inside a raster of {self.shape}")
        # map from (row0, col0) to (row1 - 1, col1 - 1) only; unmapped when ``flat`` goes
        flat = np.memmap(self.path, dtype=self.dtype, mode="r", offset=(row0 * n_cols + col0) * self.dtype.itemsize,
                         shape=((row1 - 1 - row0) * n_cols + col1 - col0,))
        rows = np.lib.stride_tricks.as_strided(flat, shape=(row1 - row0, col1 - col0),
                                               strides=(n_cols * self.dtype.itemsize, self.dtype.itemsize))
        return np.array(rows, dtype=self.dtype)

    @classmethod
    def from_array(cls, path, values: np.ndarray, strip_pixels: int = 1 << 22) -> "RowFile":
        """A scratch copy of ``values`` (2-D), written by strips of at most ``strip_pixels`` pixels."""
        out = cls(path, values.shape)
        step = max(1, strip_pixels // max(1, values.shape[1]))
        for r0 in range(0, values.shape[0], step):
            out.write_rows(r0, values[r0:r0 + step])
        return out

    def remove(self) -> None:
        """Delete the scratch file."""
        self.path.unlink(missing_ok=True)


def read_rows(raster, row0: int, row1: int) -> np.ndarray:
    """Rows ``row0:row1`` (every column) of an array or a :class:`RowFile`, as float32."""
    if isinstance(raster, RowFile):
        return raster.read(row0, row1, 0, raster.shape[1])
    return np.asarray(raster[row0:row1], dtype=np.float32)


def read_window(raster, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
    """Rows ``row0:row1``, columns ``col0:col1`` of an array or a :class:`RowFile`, as float32 (C order)."""
    if isinstance(raster, RowFile):
        return raster.read(row0, row1, col0, col1)
    return np.ascontiguousarray(raster[row0:row1, col0:col1], dtype=np.float32)


class FilteredWindows:
    """A source radiance convolved with one or more optical PSFs, computed window by window.

    Parameters
    ----------
    source : RowFile or ndarray of float32, shape (H, W)
        The radiance (NaN where unknown: taken as 0 before filtering).
    kernels : list of ndarray of float32, shape (2 m_i + 1, 2 m_i + 1)
        The PSFs (:func:`sensor_models.simulate.kernel.optics_kernel`), one output channel each.

    Attributes
    ----------
    shape : tuple of int
        ``(H, W)`` of the source grid.
    channels : int
        ``len(kernels)``.
    """

    def __init__(self, source, kernels):
        self.source = source
        self.shape = tuple(source.shape[:2])
        self.kernels = [np.asarray(k, dtype=np.float32) for k in kernels]
        self.channels = len(self.kernels)
        self.margin = max(k.shape[0] // 2 for k in self.kernels)

    def _read(self, row0, row1, col0, col1):
        window = read_window(self.source, row0, row1, col0, col1)
        return window.copy() if isinstance(self.source, np.ndarray) else window  # filled in place next

    def window(self, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """The filtered radiance over rows ``row0:row1``, columns ``col0:col1`` (inside the grid).

        Returns
        -------
        ndarray of float32, shape (row1 - row0, col1 - col0) with one kernel, else
        (row1 - row0, col1 - col0, channels)
        """
        m, (n_rows, n_cols) = self.margin, self.shape
        r0, r1, c0, c1 = max(0, row0 - m), min(n_rows, row1 + m), max(0, col0 - m), min(n_cols, col1 + m)
        raw = self._read(r0, r1, c0, c1)
        np.nan_to_num(raw, copy=False, nan=0.0)
        pad = (m - (row0 - r0), m - (r1 - row1), m - (col0 - c0), m - (c1 - col1))
        if any(pad):  # the grid's own edge: mirrored as the whole-grid filter's border mirrors it
            raw = cv2.copyMakeBorder(raw, *pad, cv2.BORDER_REFLECT)
        inner = (slice(m, m + row1 - row0), slice(m, m + col1 - col0))
        planes = [cv2.filter2D(raw, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)[inner] for k in self.kernels]
        return planes[0] if self.channels == 1 else np.ascontiguousarray(np.stack(planes, axis=-1))
