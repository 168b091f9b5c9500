"""The reference orthoimage resampled into scene geometry, so matching compares like with like.

For each CCD of a band, every scene pixel is intersected with the DEM through the current model
(:func:`sensor_models.imaging.locate.locate_block`: exact model on a node grid every 16 lines and 32
columns, per-pixel DEM intersection stopped at 1e-3 DOM px of position) and the DOM is sampled
there after a Gaussian blur that mimics what one scene
pixel integrates (:func:`sensor_models.imaging.psf.psf_sigma_dom_px`), with 8 x 8 Lanczos taps
(``CHIP_INTERPOLATION``). DOMs in any CRS and resolution work; DOM no-data and areas outside
the DOM or the DEM become NaN.

Why Lanczos: a DOM coarser than the scene (a 30 m Landsat-like reference under a 20 m scene) is
upsampled; bilinear weights blur a sample by an amount that depends on where it falls between
DOM pixels, a structured error that phase correlation reads as shift. Measured on the demo-size
scenes of ``bench/bench_matcher_realism.py`` (GCP truth error rms, px, linear -> Lanczos):
`realistic` without DOM error (the matcher's own error) 0.0659 -> 0.0560, `realistic` 0.1050 ->
0.0996, procedural source 0.1219 -> 0.1158, held-out seeds 0.0927 -> 0.0859 and 0.1110 -> 0.1054,
`ideal` 0.0171 -> 0.0166, with 0-3 more GCPs each (docs/matching.md).
"""

from __future__ import annotations

import numpy as np
import rasterio

from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES
from sensor_models.imaging.locate import HEIGHT_TOLERANCE_M, locate_block
from sensor_models.imaging.psf import psf_sigma_dom_px
from sensor_models.maps.raster import MapImage, sample_map_image

__all__ = ["CHIP_INTERPOLATION", "POSITION_TOLERANCE_DOM_PX", "grid_resolution_m", "reference_for_ccd",
           "reference_for_image", "scene_gsd_m"]

#: resampling kernel of the reference chips (module docstring; ``sensor_models.maps.raster.INTERPOLATIONS``)
CHIP_INTERPOLATION = "lanczos"

#: the DEM intersection of the chips stops once its bound on the horizontal position error is
#: below this many DOM pixels (``locate_block(position_tolerance_m=...)``): a tenth of the
#: 0.01 DOM px the chips may differ from the exact model, far below the matcher's 0.005 px noise
POSITION_TOLERANCE_DOM_PX = 1e-3
#: the chips' exactly localized nodes lie every 16 lines (the attitude) and every 32 columns
#: (the interior model across a CCD is smoother: tests/test_locate.py)
NODE_STEP_COLS = 32
#: blocks rendered at once hold about this many bytes a block pixel (positions, DOM windows,
#: filter scratch: measured at half the seed-003 geometry, 512 x 2 725 px blocks, peak RSS with 16
#: threads 1 981 MiB against 976 MiB with 2)
REFERENCE_BYTES_PER_PX = 52
#: the blocks in flight together stay within this (more threads than it allows wait their turn)
REFERENCE_BLOCKS_BYTES = 1 << 30
#: GDAL's cache of decompressed DOM tiles while a chip renders, bytes: it holds the tiles the
#: blocks in flight share
REFERENCE_GDAL_CACHE_BYTES = GDAL_BLOCK_CACHE_BYTES


def grid_resolution_m(grid) -> float:
    """Approximate pixel size of a map grid in metres (:attr:`MapGrid.resolution_m`).

    Parameters
    ----------
    grid : MapGrid
        The DOM's grid (any CRS).

    Returns
    -------
    float
        Pixel size, metres.
    """
    return grid.resolution_m


def scene_gsd_m(model, *, band=None, height_m: float = 0.0) -> float:
    """Ground distance (m) between the centre pixel and its row and column neighbours (mean).

    Parameters
    ----------
    model : SensorModel
        Model of the scene; a push-broom model is sampled inside its middle CCD.
    band : str, optional
        Band of ``model`` (default: the model's reference band).
    height_m : float
        Height above the ellipsoid of the localization, metres.

    Returns
    -------
    float
        Ground sample distance, metres.
    """
    from sensor_models.geometry.geodesy import geodetic_to_ecef

    n_rows = model.image_shape[0]
    arrays = model.detector_arrays(band)  # stay inside one CCD: stitched CCDs jump at their edges
    middle = arrays[len(arrays) // 2]
    c_mid = middle.first_col + middle.n_detectors / 2.0
    r = n_rows / 2.0 + np.array([0.0, 1.0, 0.0])
    c = c_mid + np.array([0.0, 0.0, 1.0])
    lon, lat, h = model.image_to_ground(r, c, height=height_m, band=band)
    xyz = geodetic_to_ecef(lon, lat, h)
    return float(0.5 * (np.linalg.norm(xyz[1] - xyz[0]) + np.linalg.norm(xyz[2] - xyz[0])))


def reference_for_ccd(model, dem, dom: MapImage, *, band: str, ccd: int, row0: int = 0, row1: int | None = None,
                      psf_sigma_px: float = 0.45, block_lines: int = 512, workers: int | None = None,
                      interpolation: str = CHIP_INTERPOLATION) -> np.ndarray:
    """The DOM seen through ``model`` by one CCD: float32 (row1 - row0, n_detectors), NaN = none.

    Parameters
    ----------
    model : PushbroomModel
        The current model of the scene.
    dem : sensor_models.terrain.dem.Dem
        Terrain heights above the ellipsoid, metres.
    dom : MapImage
        Reference orthoimage (any CRS and resolution).
    band : str
        Band of ``model``.
    ccd : int
        Index of the CCD in ``model.detector_arrays(band)``.
    row0, row1 : int
        Lines to render (default: all).
    psf_sigma_px : float
        Optical PSF sigma in scene pixels added to the pixel's box response.
    block_lines : int
        Lines per block.
    workers : int or None
        Threads rendering blocks; None: :func:`sensor_models.files.threads.thread_count` (``GCPCAL_THREADS``
        or every core), at most as many as keep the blocks in flight within
        :data:`REFERENCE_BLOCKS_BYTES` (7 for the seed-003 geometry's 5 450-detector CCDs). The
        blocks, and so the chips, are the same whatever the count.
    interpolation : {"lanczos", "cubic", "linear"}
        DOM resampling kernel (:func:`sensor_models.maps.raster.sample_map_image`).

    Returns
    -------
    ndarray of float32, shape (row1 - row0, n_detectors)
        The reference in the CCD's geometry: element ``[i, j]`` is the pixel whose centre is
        at ``(row0 + i + 0.5, j + 0.5)`` in CCD coordinates; NaN outside the DOM or the DEM.
    """
    n_rows = model.image_shape[0]
    row1 = n_rows if row1 is None else int(row1)
    look = model.detector_arrays(band)[ccd]
    sigma = psf_sigma_dom_px(scene_gsd_m(model, band=band), grid_resolution_m(dom.grid), psf_sigma_px)
    out = np.empty((row1 - row0, look.n_detectors), dtype=np.float32)
    position_tolerance_m = POSITION_TOLERANCE_DOM_PX * grid_resolution_m(dom.grid)

    def render(a):
        b = min(row1, a + block_lines)
        pg = locate_block(model, dem, [dom.grid], band=band, ccd=ccd, row0=a, row1=b, node_step_cols=NODE_STEP_COLS,
                          tolerance_m=HEIGHT_TOLERANCE_M, position_tolerance_m=position_tolerance_m)
        u, v = pg.uv[0]
        out[a - row0 : b - row0] = sample_map_image(dom, u, v, sigma_px=sigma, exact_weights=False,
                                                    interpolation=interpolation)

    from concurrent.futures import ThreadPoolExecutor

    from sensor_models.files.threads import libraries_single_threaded, thread_count
    from sensor_models.imaging.locate import dem_planes

    dem_planes(dem)  # shared sampling planes, built once before the threads
    starts = list(range(row0, row1, block_lines))
    per_block = REFERENCE_BYTES_PER_PX * min(block_lines, row1 - row0) * look.n_detectors
    workers = max(1, min(thread_count(workers), REFERENCE_BLOCKS_BYTES // max(1, per_block)))
    # one file handle per thread: blocks share decompressed DOM tiles, in a cache of a set size
    # (GDAL's default, 5 % of the RAM, grows the peak with the machine: docs/memory.md)
    with rasterio.Env(GDAL_CACHEMAX=REFERENCE_GDAL_CACHE_BYTES), dom.reading():
        if workers <= 1 or len(starts) == 1:
            for a in starts:
                render(a)
        else:  # numpy, OpenCV and GDAL release the GIL: blocks render in parallel, one OpenCV and BLAS thread each
            with libraries_single_threaded(), ThreadPoolExecutor(max_workers=workers) as pool:
                list(pool.map(render, starts))
    return out


def reference_for_image(model, dem, dom: MapImage, *, band=None, psf_sigma_px: float = 0.45,
                        block_lines: int = 256, interpolation: str = CHIP_INTERPOLATION) -> np.ndarray:
    """The DOM seen through any sensor model (e.g. an RPC): float32 image_shape, NaN = none.

    Every pixel centre is intersected with the DEM by the model's own
    ``image_to_ground(row, col, dem=dem)`` (exact, per pixel: meant for the small images of
    RPC products; push-broom scenes use the faster :func:`reference_for_ccd`).

    Parameters
    ----------
    model : SensorModel
        The current model of the scene.
    dem : sensor_models.terrain.dem.Dem
        Terrain heights above the ellipsoid, metres.
    dom : MapImage
        Reference orthoimage (any CRS and resolution).
    band : str, optional
        Band of ``model``.
    psf_sigma_px : float
        Optical PSF sigma in scene pixels added to the pixel's box response.
    block_lines : int
        Lines localized at a time (bounds the memory).
    interpolation : {"lanczos", "cubic", "linear"}
        DOM resampling kernel (:func:`sensor_models.maps.raster.sample_map_image`).

    Returns
    -------
    ndarray of float32, shape ``model.image_shape``
        The reference at every pixel centre ``(i + 0.5, j + 0.5)``; NaN outside the DOM or DEM.
    """
    from sensor_models.maps.grid import MapProjector

    n_rows, n_cols = model.image_shape
    sigma = psf_sigma_dom_px(scene_gsd_m(model, band=band, height_m=float(np.mean(dem.height_range_m))),
                             grid_resolution_m(dom.grid), psf_sigma_px)
    project = MapProjector(dom.grid)
    out = np.empty((n_rows, n_cols), dtype=np.float32)
    cols = np.arange(n_cols) + 0.5
    for a in range(0, n_rows, block_lines):
        b = min(n_rows, a + block_lines)
        rr, cc = np.meshgrid(np.arange(a, b) + 0.5, cols, indexing="ij")
        lon, lat, _ = model.image_to_ground(rr.ravel(), cc.ravel(), dem=dem, band=band)
        u, v = project(lon, lat)
        out[a:b] = sample_map_image(dom, u.reshape(rr.shape).astype(np.float32),
                                    v.reshape(rr.shape).astype(np.float32), sigma_px=sigma, exact_weights=False,
                                    interpolation=interpolation)
    return out
