"""Render a level-1A push-broom scene from a DOM and a DEM through the TRUE model.

``simulate_pushbroom(out_dir, config=...)`` writes, into ``out_dir``:

* ``B1.tif`` ... one raw-geometry raster per band (uint16, no georeferencing, DEFLATE);
* ``cloud_mask.tif`` (uint8, 1 = cloud in the reference band) when clouds are simulated;
* ``manifest.json``: the LAB model with noisy orbit and attitude, what a user receives;
* ``truth_manifest.json``: the TRUE model (degree-7 directional angles, 20 Hz attitude);
* ``truth.json``: the true parameters and the configuration; ``summary.json``: figures;
* ``reference/dom.tif``, ``reference/dem.tif`` (and ``water_mask.tif``) when the reference was
  generated procedurally (no ``dom``/``dem`` given).

A given DEM must cover the whole footprint (the message says which share it covers); voids
under the footprint are reported (``summary.json``: ``dem_coverage``, ``dem_void_fraction``,
``warnings``) and more than :data:`sensor_models.terrain.footprint.MAX_FOOTPRINT_VOID_FRACTION` (5 %) of the
footprint in voids is refused, since void pixels would render as 0.

Every file is written in a hidden temporary folder inside ``out_dir`` and moved into place at
the end, so a failure leaves no partial output. Lines are rendered in blocks (bounded memory:
no full-scene float arrays), the (band, CCD) tasks of a block on a thread pool; every random
draw is seeded from ``(seed, purpose, band, CCD, block)``, so the output does not depend on the
number of workers.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pyproj
import rasterio

from sensor_models.files.atomic import move_tree_into
from sensor_models.errors import InputError
from sensor_models.imaging.locate import dem_planes, locate_block
from sensor_models.maps.grid import MapGrid
from sensor_models.imaging.psf import psf_sigma_dom_px
from sensor_models.maps.raster import MapImage, sample_map_image
from sensor_models.simulate.config import SimConfig
from sensor_models.simulate.radiometry import smooth_field, to_dn
from sensor_models.simulate.render_io import (GDAL_CACHE_MB, PhaseClock, check_covers, footprint_lonlat, render_scene,
                                             step_progress, utm_crs, write_outputs)
from sensor_models.simulate.scene import SceneModels, build_models
from sensor_models.terrain.dem import Dem
from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

__all__ = ["footprint_lonlat", "simulate_pushbroom"]

#: coarse grid factor (DOM pixels per node) of the seasonal and cloud fields
FIELD_FACTOR = 8


def _procedural_reference(cfg: SimConfig, models: SceneModels, out_dir: Path):
    """Generate DOM, DEM and water mask around the TRUE footprint; write them to ``out_dir``."""
    from sensor_models.simulate.procedural import generate_reference

    ref = cfg.reference
    h_lo = ref.mean_height_m - ref.relief_m - 100.0
    h_hi = ref.mean_height_m + ref.relief_m + 100.0
    lon, lat = footprint_lonlat(models.true_model, (h_lo, h_hi))
    crs = utm_crs(float(lon.mean()), float(lat.mean()))
    to_map = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    x, y = to_map.transform(lon, lat)
    width = float(np.ptp(x)) + 2.0 * ref.margin_m
    height = float(np.ptp(y)) + 2.0 * ref.margin_m
    cx, cy = 0.5 * (np.min(x) + np.max(x)), 0.5 * (np.min(y) + np.max(y))
    clon, clat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(cx, cy)
    data = generate_reference(
        float(clon), float(clat), width, height, seed=cfg.seed,
        dom_resolution_m=ref.dom_resolution_m, dem_resolution_m=ref.dem_resolution_m,
        relief_m=ref.relief_m, mean_height_m=ref.mean_height_m, sea_fraction=ref.sea_fraction,
    )
    dom_path, dem_path = data.write(out_dir)
    return data, Path(dom_path), Path(dem_path)


class _Renderer:
    """Renders one (band, CCD, block of lines) task; shared read-only state."""

    def __init__(self, cfg: SimConfig, models: SceneModels, dem: Dem, dom: MapImage):
        self.cfg = cfg
        self.model = models.true_model
        self.dem = dem
        self.dom = dom
        r = cfg.radiometry
        self.sigma_dom = psf_sigma_dom_px(cfg.scene.gsd_m, dom.grid.resolution_m, r.psf_sigma_px)
        self.dom_scale = dom_scale(dom)
        n_rows, n_cols = dom.grid.shape
        shape = (n_rows // FIELD_FACTOR + 2, n_cols // FIELD_FACTOR + 2)
        res = dom.grid.resolution_m * FIELD_FACTOR
        self.seasonal = smooth_field(shape, cfg.radiometry.seasonal_scale_m / res,
                                     np.random.SeedSequence([cfg.pass_seed, 10]))
        self.clouds = None
        if cfg.clouds.cover > 0:
            f = smooth_field(shape, cfg.clouds.scale_m / res, np.random.SeedSequence([cfg.pass_seed, 11]))
            thr = float(np.quantile(f, 1.0 - cfg.clouds.cover)) if cfg.clouds.cover < 1 else -np.inf
            # soft edges: opacity ramps over 0.3 standard deviations of the field
            self.clouds = np.clip((f - thr) / 0.3 + 0.5, 0.0, 1.0).astype(np.float32)
            self.cloud_texture = smooth_field(shape, 2.0, np.random.SeedSequence([cfg.pass_seed, 12]))
        self.band_index = {b: i for i, b in enumerate(cfg.camera.bands)}

    def task(self, band: str, ccd: int, row0: int, row1: int):
        cfg, r = self.cfg, self.cfg.radiometry
        b = self.band_index[band]
        pg = locate_block(self.model, self.dem, [self.dom.grid], band=band, ccd=ccd, row0=row0, row1=row1)
        u, v = pg.uv[0]
        refl = sample_map_image(self.dom, u, v, sigma_px=self.sigma_dom) / np.float32(self.dom_scale)
        fu = (u + 0.5) / FIELD_FACTOR - 0.5
        fv = (v + 0.5) / FIELD_FACTOR - 0.5
        seasonal = r.seasonal_change * cv2.remap(self.seasonal, fu, fv, cv2.INTER_LINEAR,
                                                 borderMode=cv2.BORDER_REPLICATE)
        n_det = u.shape[1]
        prnu = np.random.default_rng([cfg.seed, 5, b, ccd]).normal(1.0, r.prnu, n_det).astype(np.float32)
        rng = np.random.default_rng([cfg.pass_seed, 6, b, ccd, row0])
        dn = to_dn(refl, gain=r.band_gain[b], offset_dn=r.band_offset_dn[b], gamma=r.band_gamma[b],
                   seasonal=seasonal, prnu_gain=prnu[None, :], snr=r.snr, bits=r.bits, rng=rng)
        alpha = None
        if self.clouds is not None:
            alpha = cv2.remap(self.clouds, fu, fv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            tex = cv2.remap(self.cloud_texture, fu, fv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            cloud_dn = (0.82 + 0.06 * tex) * (2**r.bits - 1)
            mixed = (1.0 - alpha) * dn.astype(np.float32) + alpha * cloud_dn
            dn = np.clip(np.rint(mixed), 0, 2**r.bits - 1).astype(np.uint16)
        return dn, alpha


def dom_scale(dom: MapImage) -> float:
    """DN of a bright land pixel (99.5th percentile of a decimated read): reflectance 1.0."""
    n_rows, n_cols = dom.grid.shape
    if dom._array is not None:
        sample = np.asarray(dom._array[:: max(1, n_rows // 512), :: max(1, n_cols // 512)], dtype=np.float64)
    else:
        import rasterio

        with rasterio.open(dom.path) as ds:
            sample = ds.read(1, out_shape=(min(512, n_rows), min(512, n_cols)), masked=True)
            sample = np.ma.filled(sample.astype(np.float64), np.nan)
    sample = sample[np.isfinite(sample)]
    if dom.nodata is not None:
        sample = sample[sample != dom.nodata]
    if sample.size == 0:
        raise InputError("the DOM holds no valid pixel", path=dom.path or "DOM")
    scale = float(np.percentile(sample, 99.5))
    if not scale > 0:
        raise InputError("the DOM is uniformly dark (no texture to simulate from)", path=dom.path or "DOM")
    return scale


def simulate_pushbroom(
    out_dir,
    *,
    config: SimConfig | None = None,
    dom=None,
    dem=None,
    geoid=None,
    workers: int = 2,
    block_lines: int = 256,
    progress=None,
    record_timings: bool = True,
    profile=None,
) -> dict:
    """Simulate a push-broom scene into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    out_dir : str or os.PathLike
    config : SimConfig, optional
        Default: the embedded fixture's configuration.
    dom, dem : path, optional
        Real reference rasters (both or neither). The DEM must declare its vertical datum (or
        be EGM96 with ``geoid``). Without them a procedural reference is generated.
    geoid : path, optional
        EGM96 grid for an orthometric DEM.
    workers : int
        Threads rendering (band, CCD) tasks of a block.
    block_lines : int
        Lines rendered per block (memory ~ block_lines x columns x 40 bytes per worker).
    progress : callable, optional
        ``progress(done, total)``: two set-up steps (models; reference and sampling planes),
        then one step per block of lines written.
    record_timings : bool
        Write render times into ``summary.json`` (False: every output file is a function of
        the configuration and inputs only, e.g. for committed fixtures).
    profile : PushbroomProfile or str, optional
        Error profile (:mod:`sensor_models.simulate.profiles`); None or ``"ideal"``: the
        default path, byte for byte. ``"realistic"``:
        :func:`sensor_models.simulate.realistic_sim.simulate_realistic` (``dom`` is then the
        scene's source radiance, optional; no ``dem``).

    Returns
    -------
    dict
        The summary also written to ``summary.json``.
    """
    t_start = time.perf_counter()
    cfg = (config or SimConfig()).validate()
    if isinstance(profile, str):
        from sensor_models.simulate.profiles import get_profile

        profile = get_profile(profile)
    if profile is not None and not profile.is_ideal:
        return _simulate_with_profile(out_dir, cfg, profile, dom, dem, geoid, workers, block_lines, progress,
                                      t_start, record_timings)
    if (dom is None) != (dem is None):
        raise InputError("give both --dom and --dem, or neither (procedural reference)")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".simulate-", dir=out_dir)).resolve()
    try:
        # a decimated read of a large DOM (its scale) goes through GDAL's block cache (5 % of the
        # RAM by default): capped, the pixels are the same and the memory stays bounded
        with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB):
            summary = _simulate(cfg, out_dir, tmp, dom, dem, geoid, workers, block_lines, progress, t_start,
                                record_timings)
        move_tree_into(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return summary


def _simulate_with_profile(out_dir, cfg, profile, dom, dem, geoid, workers, block_lines, progress, t_start,
                           record_timings):
    from sensor_models.simulate.realistic_sim import simulate_realistic

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".simulate-", dir=out_dir)).resolve()
    try:
        summary = simulate_realistic(tmp, cfg, profile, dom_path=dom, dem_path=dem, geoid=geoid, workers=workers,
                                     block_lines=block_lines, progress=progress, t_start=t_start,
                                     record_timings=record_timings)
        move_tree_into(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return summary


def _simulate(cfg, out_dir, tmp, dom_path, dem_path, geoid, workers, block_lines, progress, t_start, record_timings):
    from sensor_models.simulate.truth import truth_error

    clock = PhaseClock(t_start)
    setup_done, block_progress = step_progress(progress, cfg.scene.n_rows, block_lines)
    models = build_models(cfg)
    model = models.true_model
    clock.mark("models")
    setup_done(1)
    dom, dem, reference_files, dem_figures = _reference(cfg, models, tmp, dom_path, dem_path, geoid)
    renderer = _Renderer(cfg, models, dem, dom)
    dem_planes(dem)  # build the shared sampling planes once, before the threads
    clock.mark("reference")
    setup_done(2)
    bands = list(cfg.camera.bands)
    n_ccd = len(model.band_ccds(cfg.camera.reference_band))
    cloud_pixels, has_mask = render_scene(renderer, model, tmp, bands, cfg.camera.reference_band, n_ccd,
                                          block_lines, workers, block_progress)
    render_seconds = clock.mark("blocks")  # the whole render: models, reference and blocks
    initial = truth_error(model, models.lab_model, dem=dem, step_px=32)
    clock.mark("truth_error")
    return write_outputs(cfg, models, tmp, initial, reference_files, dem_figures, (cloud_pixels, has_mask),
                         render_seconds, workers, t_start, record_timings, phases=clock)


def _reference(cfg, models: SceneModels, tmp: Path, dom_path, dem_path, geoid):
    """``(dom MapImage, Dem, reference file names)``: given, or procedural under ``tmp/reference``.

    Checks that both cover the scene's footprint between the DEM's lowest and highest heights.
    """
    if dom_path is None:
        data, p_dom, p_dem = _procedural_reference(cfg, models, tmp / "reference")
        dom = MapImage.from_array(data.dom, data.dom_transform, data.crs)
        dem = Dem.from_array(data.dem_m, data.dem_transform, data.crs, vertical_datum="ellipsoid")
        reference_files = {"dom": f"reference/{p_dom.name}", "dem": f"reference/{p_dem.name}"}
    else:
        dom = MapImage.open(dom_path)
        dem = Dem.open(dem_path, geoid=geoid)
        reference_files = {"dom": os.path.abspath(dom_path), "dem": os.path.abspath(dem_path)}
    h_lo, h_hi = dem.height_range_m
    lon, lat = footprint_lonlat(models.true_model, (h_lo, h_hi))
    check_covers(dom.grid, lon, lat, what="DOM", path=dom.path)
    # the whole footprint on the DEM (the share covered is said), voids reported, too many refused
    grid_lon, grid_lat = footprint_sample_lonlat(models.true_model, 0.5 * (h_lo + h_hi), n_side=65)
    dem_figures = check_dem_footprint(dem, grid_lon, grid_lat, min_coverage=1.0)
    check_covers(MapGrid.of_dem(dem), lon, lat, what="DEM", path=dem.source)
    return dom, dem, reference_files, dem_figures
