"""Orthorectification: a raw-geometry image resampled onto a map grid through a model and a DEM.

For every output pixel centre ``(x, y)`` of the map grid, the DEM gives the ground height
``h = D(x, y)`` and the model's inverse localization gives the image position
``(row, col) = model.ground_to_image(lon, lat, h)``; the image is sampled there (OpenCV
``remap``, bilinear or cubic; image pixel centres at ``(i + 0.5, j + 0.5)``).

The output grid is planned in :mod:`sensor_models.imaging.ortho_grid`, the image position of
every output pixel computed block by block in :mod:`sensor_models.imaging.ortho_geometry` (exact
model on a node grid, interpolation per pixel), and the image sampled there in
:mod:`sensor_models.imaging.ortho_resample`. This module drives the blocks: into an array
(:func:`orthorectify`) or into a Cloud-Optimized GeoTIFF (:func:`orthorectify_to_file`).

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
"""

from __future__ import annotations

import os
import time
from contextlib import closing
from pathlib import Path

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES
from sensor_models.files.threads import libraries_single_threaded, map_ordered, thread_count
from sensor_models.imaging.ortho_geometry import OrthoGeometry, check_geometry, draw_checks
from sensor_models.imaging.ortho_grid import ortho_grid
from sensor_models.imaging.ortho_resample import RESAMPLING, SourceBand, resample_block, resolve_source

__all__ = ["orthorectify", "orthorectify_to_file"]

#: source pixels (per side) a block may need; larger blocks are shrunk (coarse outputs)
_MAX_SOURCE_SIDE = 2048
#: blocks one thread computes together (their inverse localizations in one call per CCD:
#: :meth:`OrthoGeometry.blocks`), consecutive in the write order
GROUP_BLOCKS = 4


def _default_band(model, band):
    if band is None and any(a.name for a in model.detector_arrays()):  # multi-band CCD models
        return model.reference_band
    return band


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
                 resampling: str = "bilinear", node_step_px: float = 16.0, threads: int | None = None) -> np.ndarray:
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
        Node spacing of the geometry grid in image pixels
        (:class:`~sensor_models.imaging.ortho_geometry.OrthoGeometry`).
    threads : int or None
        Blocks computed at once (:func:`sensor_models.files.threads.thread_count`: None for
        ``GCPCAL_THREADS`` or every core); the output does not depend on it.

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
    source = SourceBand(np.ascontiguousarray(image, dtype=np.float32))
    out = np.full(grid.shape, np.nan, dtype=np.float32)
    step = max(16, int(block_rows))
    blocks = [(a, min(a + step, grid.shape[0]), b, min(b + step, grid.shape[1]))
              for a in range(0, grid.shape[0], step) for b in range(0, grid.shape[1], step)]

    def compute(block):
        return resample_block(source, geometry.block(*block), RESAMPLING[resampling])

    threads = thread_count(threads)
    computed = map_ordered(compute, blocks, threads, in_flight=threads)
    with closing(computed), libraries_single_threaded():  # the blocks fill the cores
        for (a, b, c, d), values in zip(blocks, computed):
            out[a:b, c:d] = values
    return out


# ---------------------------------------------------------------- to a Cloud-Optimized GeoTIFF
def _block_size(block: int, scale: float) -> int:
    """Output block side (multiple of 16) whose source window stays below _MAX_SOURCE_SIDE."""
    b = min(int(block), int(_MAX_SOURCE_SIDE / max(scale, 1e-9)))
    return max(64, b // 16 * 16)


def orthorectify_to_file(model, image, dem, out_path, *, crs=None, resolution_m=None, band=None,
                         resampling: str = "bilinear", block: int = 1024, nodata=0, dtype=None,
                         node_step_px: float = 16.0, check_points: int = 256, seed: int = 0,
                         progress=None, dem_windows=None, tags: dict | None = None, rasters=None,
                         threads: int | None = None) -> dict:
    """Orthorectify one band into a Cloud-Optimized GeoTIFF, block by block, atomically.

    Parameters
    ----------
    model : SensorModel
        Geometry of the image (e.g. a calibrated push-broom model).
    image : str, os.PathLike, (path, band_index), ndarray or None
        The image in scene geometry: a raster path (band 1), a path and a 1-based band index,
        a band name listed in ``rasters``, None for the raster ``rasters`` lists for ``band``,
        or an array.
    dem : sensor_models.terrain.dem.Dem
        Ellipsoidal heights of the ground.
    out_path : str or os.PathLike
        The COG to write (replaced atomically; its folder is created).
    crs, resolution_m
        Output CRS and pixel size; defaults in :func:`~sensor_models.imaging.ortho_grid.ortho_grid`
        (UTM zone of the scene, the scene's GSD).
    band : str, optional
        Band of the geometry (default: the model's reference band).
    resampling : {"nearest", "bilinear", "cubic"}
    block : int
        Output pixels per block side (memory ~ 150 bytes per block pixel, ``GROUP_BLOCKS``
        blocks per thread; smaller for outputs much coarser than the image).
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
    tags : dict of str to str, optional
        More GDAL metadata items of the output (e.g. the caller's provenance).
    rasters : dict, optional
        Band -> ``{"path": str, "index": int}`` where a band name or None as ``image`` is looked
        up (``Scene.rasters`` of :func:`sensor_models.readers.open_scene`).
    threads : int or None
        Groups of ``GROUP_BLOCKS`` blocks computed at once, each with one OpenCV and one BLAS
        thread (None: ``GCPCAL_THREADS`` or every core,
        :func:`sensor_models.files.threads.thread_count`); the blocks are written, and the check
        points drawn, in block order by the calling thread, so the file does not depend on it.
        At most ``threads`` computed groups wait to be written.

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
    source, band = resolve_source(model, image, band, rasters)
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
        plan.threads = thread_count(threads)
        t_cog = _write_cog(plan, out_path, model=model, band=band, resampling=resampling, progress=progress, tags=tags)
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
    err = check_geometry(geometry, plan.checks)
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
        "threads": plan.threads,
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
        self.threads = 1

    def compute(self, blocks):
        """Geometry and resampled values (None off the image) of ``(row0, row1, col0, col1)``
        blocks, their localizations solved together (:meth:`OrthoGeometry.blocks`)."""
        return [(geom, resample_block(self.source, geom, self.interpolation) if geom.valid.any() else None)
                for geom in self.geometry.blocks(blocks)]

    def computed(self):
        """``compute`` of every block, in order: groups of ``GROUP_BLOCKS`` on ``threads`` threads."""
        groups = [self.blocks[a:a + GROUP_BLOCKS] for a in range(0, len(self.blocks), GROUP_BLOCKS)]
        # closing: on an error or early stop the running groups finish before the caller goes on
        with closing(map_ordered(self.compute, groups, self.threads, in_flight=self.threads)) as results:
            for group in results:
                yield from group

    def write(self, dst, progress=None) -> None:
        """Resample every block into band 1 of the open dataset ``dst``, ``threads`` groups at once."""
        from rasterio.windows import Window

        computed = self.computed()
        # closing: on an error the running blocks finish before the caller closes the source
        with closing(computed), libraries_single_threaded():  # the blocks fill the cores
            for k, ((a, b, c, d), (geom, values)) in enumerate(zip(self.blocks, computed)):
                if values is not None:
                    good = geom.valid & np.isfinite(values)
                    self.n_valid += int(np.count_nonzero(good))
                    dst.write(_to_dtype(values, self.out_dtype, self.nodata), 1, window=Window(c, a, d - c, b - a))
                    self.checks.append(draw_checks(geom, a, c, self.per_block, self.rng))
                if progress is not None:
                    progress(k + 1, len(self.blocks))


def _write_cog(plan: _BlockPlan, out_path: Path, *, model, band, resampling, progress, tags=None) -> float:
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
        with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES, GDAL_PAM_ENABLED="NO"):
            with rasterio.open(tmp, "w", **profile) as dst:
                dst.set_band_description(1, str(band) if band is not None else "image")
                dst.update_tags(GCPCAL_ORTHO_MODEL=getattr(model, "name", "") or model.kind,
                                GCPCAL_ORTHO_BAND=str(band), GCPCAL_ORTHO_RESAMPLING=resampling, **(tags or {}))
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


