"""Single-band rasters on map grids (reference DOMs), read by windows and resampled at node indices.

* :class:`MapImage`: a DOM (or any single-band map raster) in memory or on disk, read by
  windows; nodata becomes NaN, values are scaled (``DN * scale + offset``), and pixels a QA
  raster marks (:mod:`sensor_models.maps.reference_qa`) become NaN. Several tiles, a folder, a glob
  or a ``.vrt`` open as one mosaic (:mod:`sensor_models.maps.mosaic`); products (Landsat,
  Sentinel-2) are resolved by :mod:`sensor_models.maps.dom_inputs`.
* :func:`sample_map_image`: blur (Gaussian, no-data aware) and sample (bilinear, cubic or
  Lanczos) at the node indices that :func:`sensor_models.imaging.locate.locate_block` returns.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.maps.reference_qa import MASK_LAYOUT
from sensor_models.maps.grid import MapGrid

__all__ = ["INTERPOLATIONS", "MapImage", "sample_map_image"]


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
    scale, offset : float
        Values read are ``DN * scale + offset`` (e.g. Sentinel-2 reflectance).
    qa_path : str or None
        QA raster in the same CRS (any pixel size): its flagged pixels read as NaN.
    qa_layout : str or None
        How ``qa_path`` is coded (:data:`sensor_models.maps.reference_qa.QA_LAYOUTS`).
    qa_cirrus : bool
        The QA's cirrus flags mask too (by default they do not).
    mask_path : str or None
        A user's mask in the same CRS (any pixel size): nonzero pixels read as NaN.
    """

    grid: MapGrid
    _array: np.ndarray | None = None
    path: str | None = None
    nodata: float | None = None
    scale: float = 1.0
    offset: float = 0.0
    qa_path: str | None = None
    qa_layout: str | None = None
    qa_cirrus: bool = False
    mask_path: str | None = None
    _session: "_ReadSession | None" = field(default=None, init=False, repr=False, compare=False)

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
    def open(cls, path, *, what: str = "DOM", nodata=None, scale: float = 1.0, offset: float = 0.0,
             qa_path=None, qa_layout: str | None = None, qa_cirrus: bool = False,
             mask_path=None) -> "MapImage":
        """A map image on disk, read lazily by windows (band 1).

        Parameters
        ----------
        path : str, os.PathLike or sequence of them
            A raster file GDAL reads, with a coordinate reference system; or several tiles, a
            comma list, a folder, a glob or a ``.vrt`` (:func:`sensor_models.maps.mosaic.mosaic_path`).
        what : str
            What the file is, for error messages.
        nodata : float, optional
            No-data value when the file declares none (Sentinel-2: 0).
        scale, offset : float
            Values read are ``DN * scale + offset``.
        qa_path : str, os.PathLike or sequence of them, optional
            QA raster (or tiles) in the DOM's CRS; pixels it flags read as NaN.
        qa_layout : str, optional
            Layout of the QA raster; from its name or values when None
            (:func:`sensor_models.maps.reference_qa.qa_layout_of`).
        qa_cirrus : bool
            The QA's cirrus flags mask too.
        mask_path : str, os.PathLike or sequence of them, optional
            A user's mask raster (or tiles) in the DOM's CRS: nonzero pixels read as NaN.

        Returns
        -------
        MapImage

        Raises
        ------
        InputError
            The file is missing, unreadable or declares no CRS.
        """
        from sensor_models.maps.mosaic import mosaic_path

        path = mosaic_path(path, what=what, nodata=nodata)
        grid, declared = _open_grid(path, what=what)
        image = cls(grid, None, path, declared if declared is not None else nodata, float(scale), float(offset))
        if qa_path is not None:
            image.qa_path, image.qa_layout = _open_qa(qa_path, qa_layout, grid, what=what)
            image.qa_cirrus = bool(qa_cirrus)
        if mask_path is not None:
            image.mask_path, _ = _open_qa(mask_path, MASK_LAYOUT, grid, what=what, kind="mask")
        return image

    @contextmanager
    def reading(self):
        """Keep the file open (one handle per thread) for a series of :meth:`read` calls.

        Each :meth:`read` otherwise opens the file, and GDAL forgets the tiles it decompressed
        when it closes: windows that share tiles (the blocks of a reference chip and their
        margins) decompress them again. Inside this context the handles, and GDAL's cache of
        decompressed tiles, live until the outermost context exits. Reads return the same
        values either way.

        Yields
        ------
        MapImage
            This image.
        """
        if self.path is None:
            yield self
            return
        with _SESSION_LOCK:
            outermost = self._session is None
            if outermost:
                self._session = _ReadSession(self.path)
            session = self._session
            session.users += 1
        try:
            yield self
        finally:
            with _SESSION_LOCK:
                session.users -= 1
                if session.users == 0:
                    self._session = None
                    session.close()

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
        return self._finish(block, row0, row1, col0, col1)

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
            from rasterio.windows import Window

            block = self._read_file(Window(c0, r0, c1 - c0, r1 - r0))
        out[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = self._finish(block, r0, r1, c0, c1)
        return out

    def _read_file(self, window) -> np.ndarray:
        """Band 1 of the file in ``window`` as float32, NaN where the file's mask says invalid."""
        session = self._session
        if session is not None:
            return _read_band(session.dataset(), window)
        import rasterio

        with rasterio.open(self.path) as ds:
            return _read_band(ds, window)

    def _finish(self, block: np.ndarray, row0: int, row1: int, col0: int, col1: int) -> np.ndarray:
        """``block`` (pixels ``[row0:row1, col0:col1]`` at any shape) with nodata and QA as NaN, scaled."""
        if self.nodata is not None and not np.isnan(self.nodata):
            block[block == self.nodata] = np.nan
        if self.has_mask:
            block[self.qa_invalid(row0, row1, col0, col1, block.shape)] = np.nan
        if self.scale != 1.0 or self.offset != 0.0:
            block = (block * np.float32(self.scale) + np.float32(self.offset)).astype(np.float32)
        return block

    @property
    def has_mask(self) -> bool:
        """Whether a QA raster or a user's mask masks pixels of this image."""
        return self.qa_path is not None or self.mask_path is not None

    def qa_invalid(self, row0: int, row1: int, col0: int, col1: int, out_shape) -> np.ndarray:
        """Where the QA raster or the user's mask flags the pixels ``[row0:row1, col0:col1]``, sampled at ``out_shape``.

        Each output pixel takes the QA pixel under its centre (nearest neighbour, the QA may
        have another pixel size). A large window is read from the QA decimated (nearest) so
        that at most about four QA pixels per output pixel are read. Outside the QA raster
        every pixel counts as flagged (its quality is unknown).

        Parameters
        ----------
        row0, row1, col0, col1 : int
            Half-open window in DOM pixels.
        out_shape : (int, int)
            Rows and columns of the output (the window's shape, or smaller when decimated).

        Returns
        -------
        ndarray of bool, shape ``out_shape``
            True where the DOM pixel must not be used; all False without a QA raster or mask.
        """
        from sensor_models.maps._qa_sampling import sample_qa_invalid

        out = np.zeros(tuple(out_shape), dtype=bool)
        window = (row0, row1, col0, col1)
        if self.qa_path is not None:
            out |= sample_qa_invalid(self.qa_path, self.qa_layout, self.grid.transform, window, tuple(out_shape),
                                     cirrus=self.qa_cirrus)
        if self.mask_path is not None:
            out |= sample_qa_invalid(self.mask_path, MASK_LAYOUT, self.grid.transform, window, tuple(out_shape))
        return out


_SESSION_LOCK = threading.Lock()


class _ReadSession:
    """Open handles of one raster file, one per thread (a GDAL dataset is not thread-safe)."""

    def __init__(self, path: str):
        self.path = path
        self.users = 0
        self._local = threading.local()
        self._handles = []
        self._lock = threading.Lock()

    def dataset(self):
        """This thread's open dataset of the file."""
        ds = getattr(self._local, "dataset", None)
        if ds is None:
            import rasterio

            ds = self._local.dataset = rasterio.open(self.path)
            with self._lock:
                self._handles.append(ds)
        return ds

    def close(self) -> None:
        """Close every handle (the threads that used them have finished their reads)."""
        with self._lock:
            for ds in self._handles:
                ds.close()
            self._handles.clear()


def _read_band(ds, window) -> np.ndarray:
    """Band 1 of an open dataset in ``window``, float32, NaN where its mask (no-data value,
    alpha, mask band) marks pixels invalid; a file without any mask is read without one."""
    from rasterio.enums import MaskFlags

    if ds.mask_flag_enums[0] == [MaskFlags.all_valid]:
        return ds.read(1, window=window, out_dtype=np.float32)  # GDAL converts while copying
    block = ds.read(1, window=window, masked=True)
    return np.ma.filled(block.astype(np.float32), np.nan)


def _open_grid(path: str, *, what: str):
    """The grid and declared no-data value of a raster file; errors become InputError."""
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as ds:
            if ds.crs is None:
                raise InputError(f"the {what} declares no coordinate reference system", path=path)
            grid = MapGrid(ds.transform, pyproj.CRS.from_wkt(ds.crs.to_wkt()), (ds.height, ds.width))
            return grid, ds.nodata
    except RasterioError as exc:
        raise InputError(f"cannot be read as a {what} raster ({exc})", path=path) from None


def _open_qa(qa_path, qa_layout, grid: MapGrid, *, what: str, kind: str = "QA"):
    """``(path GDAL opens, layout)`` of a QA raster (or a user's mask) or its tiles, checked
    against the DOM's CRS."""
    from sensor_models.maps.mosaic import mosaic_path, raster_inputs
    from sensor_models.maps.reference_qa import qa_layout_of

    files = raster_inputs(qa_path, what=f"{what} {kind}")
    layouts = {MASK_LAYOUT if qa_layout == MASK_LAYOUT else qa_layout_of(f, layout=qa_layout) for f in files}
    if len(layouts) > 1:
        raise InputError(f"the QA tiles have different layouts ({', '.join(sorted(layouts))})", path=files[0])
    qa = mosaic_path(files, what=f"{what}-{kind}")
    qa_grid, _ = _open_grid(qa, what=f"{what} {kind}")
    if qa_grid.crs is None or not qa_grid.crs.equals(grid.crs, ignore_axis_order=True):
        crs_name = qa_grid.crs.name if qa_grid.crs is not None else "none"
        raise InputError(f"the {kind} raster's CRS ({crs_name}) differs from the {what}'s ({grid.crs.name})",
                         path=files[0], field="crs")
    return qa, layouts.pop()


#: Interpolations of :func:`sample_map_image` (OpenCV ``remap`` flags): name -> (flag, taps' reach
#: in pixels beyond the sample). ``lanczos``: 8 x 8 Lanczos (a = 4) taps; ``cubic``: 4 x 4 Keys
#: taps with a = -0.75; ``linear``: 2 x 2 bilinear.
INTERPOLATIONS = {"linear": ("INTER_LINEAR", 1), "cubic": ("INTER_CUBIC", 2), "lanczos": ("INTER_LANCZOS4", 4)}


def sample_map_image(image: MapImage, u, v, *, sigma_px: float = 0.0, exact_weights: bool = True,
                     interpolation: str = "linear") -> np.ndarray:
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
    exact_weights : bool
        True: always divide by the blurred weight image. False: a window without any no-data
        is blurred alone (its blurred weights are 1 to float32 rounding, so samples differ by
        about 1e-7 relative, e.g. 1e-4 DN at 1000 DN) at half the cost. The simulator keeps
        True, so its scenes stay bit-identical; the matcher's reference chips use False.
    interpolation : {"linear", "cubic", "lanczos"}
        Resampling kernel (``INTERPOLATIONS``). The simulator keeps ``linear``; the matcher's
        reference chips use ``lanczos`` (docs/matching.md: bilinear upsampling of a coarser DOM
        blurs by an amount that depends on the sample's sub-pixel phase, a structured error in
        the chips). Where the wider taps reach no-data the bilinear sample is used, so the
        NaN samples are the bilinear ones.

    Returns
    -------
    ndarray, float32, shape of ``u``
        Samples (OpenCV ``remap``: positions quantized to 1/32 pixel).
    """
    import cv2

    if interpolation not in INTERPOLATIONS:
        raise InputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}",
                         field="interpolation")
    flag_name, reach = INTERPOLATIONS[interpolation]

    ok = np.isfinite(u) & np.isfinite(v)
    every = bool(ok.all())
    if not every and not ok.any():
        return np.full(u.shape, np.nan, dtype=np.float32)
    u_ok, v_ok = (u, v) if every else (u[ok], v[ok])
    pad = int(np.ceil(4.0 * sigma_px)) + 2 + reach
    c0 = int(np.floor(u_ok.min())) - pad
    c1 = int(np.ceil(u_ok.max())) + pad + 1
    r0 = int(np.floor(v_ok.min())) - pad
    r1 = int(np.ceil(v_ok.max())) + pad + 1
    crop = _blurred_window(image.read(r0, r1, c0, c1), sigma_px, exact_weights)
    if every:
        uu = (u - c0).astype(np.float32, copy=False)
        vv = (v - r0).astype(np.float32, copy=False)
    else:
        uu = np.where(ok, u - c0, -1.0).astype(np.float32)
        vv = np.where(ok, v - r0, -1.0).astype(np.float32)
    out = cv2.remap(crop, uu, vv, getattr(cv2, flag_name), borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    if interpolation != "linear" and np.isnan(out).any():
        # wider taps reach no-data sooner: where they do, the bilinear sample (NaN only where its
        # own 2 x 2 taps touch no-data), so the chips cover what bilinear ones cover
        near = np.isnan(out)  # only those samples again, as rows of at most 4096 (OpenCV: < 32767)
        n = int(near.sum())
        width = min(n, 4096)
        pad = -n % width  # padded with -1: outside, NaN, dropped
        maps = [np.concatenate([m[near], np.full(pad, -1.0, np.float32)]).reshape(-1, width) for m in (uu, vv)]
        out[near] = cv2.remap(crop, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=np.nan).reshape(-1)[:n]
    return out


def _blurred_window(crop: np.ndarray, sigma_px: float, exact_weights: bool) -> np.ndarray:
    """``crop`` (float32, NaN = no data) blurred by normalized convolution; NaN where more than
    1 % of the blur's weight falls on no-data (see :func:`sample_map_image`)."""
    import cv2

    if not exact_weights and (sigma_px <= 0 or np.isfinite(crop.sum(dtype=np.float64))):
        if sigma_px > 0:  # no no-data: the weight image would be 1
            crop = cv2.GaussianBlur(crop, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
        return crop
    valid = np.isfinite(crop).astype(np.float32)
    crop = np.where(valid > 0, crop, 0.0).astype(np.float32)
    if sigma_px > 0:
        crop = cv2.GaussianBlur(crop, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
        valid = cv2.GaussianBlur(valid, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(valid > 0.99, crop / valid, np.nan).astype(np.float32)
