"""Render a level-1A push-broom scene from a DOM and a DEM through the TRUE model.

``simulate_pushbroom(out_dir, config=...)`` writes, into ``out_dir``:

* ``B1.tif`` ... one raw-geometry raster per band (uint16, no georeferencing, DEFLATE);
* ``cloud_mask.tif`` (uint8, 1 = cloud in the reference band) when clouds are simulated;
* ``manifest.json``: the LAB model with noisy orbit and attitude, what a user receives;
* ``truth_manifest.json``: the TRUE model (degree-7 directional angles, 20 Hz attitude);
* ``truth.json``: the true parameters and the configuration; ``summary.json``: figures;
* ``reference/dom.tif``, ``reference/dem.tif`` (and ``water_mask.tif``) when the reference was
  generated procedurally (no ``dom``/``dem`` given).

``simulate_through_model(out_dir, model, dom=..., dem=...)`` renders through a given push-broom
model instead (a vendor product's, or a window of it) with known errors added, and writes the
same files with ``manifest.json`` = the given model as delivered.

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
import time
from pathlib import Path

import cv2
import numpy as np
import pyproj
import rasterio

from sensor_models.files.atomic import atomic_folder
from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES
from sensor_models.errors import InputError
from sensor_models.files.threads import thread_count
from sensor_models.imaging.locate import dem_planes, locate_block
from sensor_models.maps.grid import MapGrid
from sensor_models.imaging.psf import psf_sigma_dom_px
from sensor_models.maps.raster import MapImage, sample_map_image
from sensor_models.simulate.config import SimConfig
from sensor_models.simulate.radiometry import smooth_field, to_dn
from sensor_models.simulate.render_io import (PhaseClock, check_covers, footprint_lonlat, render_scene,
                                             step_progress, utm_crs, write_outputs)
from sensor_models.simulate.scene import SceneModels, build_models
from sensor_models.terrain.dem import Dem
from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

__all__ = ["MODEL_CONFIG_KEYS", "footprint_lonlat", "perturbed_model", "simulate_pushbroom", "simulate_through_model"]

#: coarse grid factor (DOM pixels per node) of the seasonal and cloud fields
FIELD_FACTOR = 8


def _procedural_reference(cfg: SimConfig, models: SceneModels, out_dir: Path, progress=None):
    """Generate DOM, DEM and water mask around the TRUE footprint; write them to ``out_dir``.

    ``progress(done, parts)`` (optional) counts the generator's phases and DOM strips.
    """
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
        progress=progress,
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
    workers: int | None = None,
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
    workers : int or None
        Threads rendering (band, CCD) tasks of a block, each with one OpenCV and BLAS thread; None or 0:
        ``GCPCAL_THREADS`` or every core (:func:`sensor_models.files.threads.thread_count`). The
        files do not depend on it.
    block_lines : int
        Lines rendered per block (memory ~ block_lines x columns x 40 bytes per worker).
    progress : callable, optional
        ``progress(done, total)``: two set-up steps (models; reference and sampling planes),
        then one step per block of lines written; under a non-ideal profile the first step is
        counted in parts too (the procedural source radiance and DEM: its phases and every
        strip of 256 rows), the total growing by those parts when they start.
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
    workers = thread_count(workers)
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
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        tmp = tmp.resolve()
        # a decimated read of a large DOM (its scale) goes through GDAL's block cache (5 % of the
        # RAM by default): capped, the pixels are the same and the memory stays bounded
        with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES):
            summary = _simulate(cfg, out_dir, tmp, dom, dem, geoid, workers, block_lines, progress, t_start,
                                record_timings)
    return summary


def _simulate_with_profile(out_dir, cfg, profile, dom, dem, geoid, workers, block_lines, progress, t_start,
                           record_timings):
    from sensor_models.simulate.realistic_sim import simulate_realistic

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        tmp = tmp.resolve()
        summary = simulate_realistic(tmp, cfg, profile, dom_path=dom, dem_path=dem, geoid=geoid, workers=workers,
                                     block_lines=block_lines, progress=progress, t_start=t_start,
                                     record_timings=record_timings)
    return summary


def _simulate(cfg, out_dir, tmp, dom_path, dem_path, geoid, workers, block_lines, progress, t_start, record_timings):
    from sensor_models.simulate.truth import truth_error

    clock = PhaseClock(t_start)
    setup_done, block_progress = step_progress(progress, cfg.scene.n_rows, block_lines)
    models = build_models(cfg)
    model = models.true_model
    clock.mark("models")
    setup_done(1)
    dom, dem, reference_files, dem_figures = _reference(cfg, models, tmp, dom_path, dem_path, geoid,
                                                        progress=setup_done.part)
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


def _reference(cfg, models: SceneModels, tmp: Path, dom_path, dem_path, geoid, progress=None):
    """``(dom MapImage, Dem, reference file names)``: given, or procedural under ``tmp/reference``.

    ``progress(done, parts)`` (optional) counts the procedural reference's phases and strips.

    Checks that both cover the scene's footprint between the DEM's lowest and highest heights.
    """
    if dom_path is None:
        data, p_dom, p_dem = _procedural_reference(cfg, models, tmp / "reference", progress=progress)
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


# ----------------------------------------------------------------------------- through a given model
#: the sections and keys of the configuration that rendering through a given model uses
MODEL_CONFIG_KEYS = ("seed", "errors.installation_deg", "errors.focal_length_ratio",
                     "errors.attitude_drift_arcsec_s", "radiometry")


def perturbed_model(model, cfg: SimConfig):
    """``model`` with the configuration's known errors: the TRUE model of a scene rendered through it.

    Parameters
    ----------
    model : PushbroomModel
        The delivered geometry (e.g. a vendor product's model, or a window of it).
    cfg : SimConfig
        ``errors.installation_deg`` is added to the installation (roll, pitch, yaw);
        ``errors.focal_length_ratio`` divides every directional-angle tangent (a focal length
        that many times the delivered one); ``errors.attitude_drift_arcsec_s`` is a linear
        attitude drift (body frame, rate about the middle of the image's time span).

    Returns
    -------
    (PushbroomModel, dict)
        The TRUE model and the JSON record of the errors put into it.
    """
    from sensor_models.models.attitude_correction import AttitudeCorrection
    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.models.pushbroom_types import CcdLook, Installation

    e = cfg.errors
    ratio = float(e.focal_length_ratio)
    d_roll, d_pitch, d_yaw = np.radians(np.asarray(e.installation_deg, dtype=np.float64))
    inst = model.installation
    installation = Installation(roll=inst.roll + d_roll, pitch=inst.pitch + d_pitch, yaw=inst.yaw + d_yaw)
    bands = {b: [CcdLook(name=c.name, first_col=c.first_col, n_detectors=c.n_detectors,
                         tan_psi_x=c.tan_psi_x / ratio, tan_psi_y=c.tan_psi_y / ratio)
                 for c in model.band_ccds(b)] for b in model.bands}
    t0, t1 = (float(t) for t in model.line_timing.seconds(np.array([0.0, float(model.n_rows)])))
    rate = np.asarray(e.attitude_drift_arcsec_s, dtype=np.float64) * np.pi / 180.0 / 3600.0
    correction = model.attitude_correction
    if np.any(rate != 0.0):
        if correction is not None:
            raise InputError("the model already carries an attitude correction; an attitude drift cannot be added",
                             field="errors.attitude_drift_arcsec_s")
        # delta(t) = c (2 tau - 1), tau = (t - t0) / (t1 - t0): a rate of 2 c / (t1 - t0)
        correction = AttitudeCorrection(kind="drift", t0_s=min(t0, t1), t1_s=max(t0, t1), n_terms=1,
                                        coefficients_rad=(rate * 0.5 * abs(t1 - t0))[:, None])
    true_model = PushbroomModel(orbit=model.orbit, attitude=model.attitude, line_timing=model.line_timing,
                                bands=bands, installation=installation, n_rows=model.n_rows,
                                reference_band=model.reference_band, name=f"{model.name} (TRUE)".strip(),
                                attitude_correction=correction)
    record = {"installation_rad": [float(d_roll), float(d_pitch), float(d_yaw)], "focal_length_ratio": ratio,
              "attitude_drift_rad_s": rate.tolist()}
    return true_model, record


def _model_config(cfg: SimConfig, model) -> SimConfig:
    """``cfg`` fitted to a given model's bands and ground sampling (what the renderer reads)."""
    from dataclasses import replace

    n = len(model.bands)
    r = cfg.radiometry
    cycle = lambda values: tuple(values[i % len(values)] for i in range(n))  # noqa: E731
    n_rows, n_cols = model.image_shape
    rows = np.array([0.5 * n_rows, 0.5 * n_rows + 1.0, 0.5 * n_rows])
    cols = np.array([0.5 * n_cols, 0.5 * n_cols, 0.5 * n_cols + 1.0])
    lon, lat, _ = model.image_to_ground(rows, cols, height=0.0)
    geod = pyproj.Geod(ellps="WGS84")
    _, _, along = geod.inv(lon[0], lat[0], lon[1], lat[1])
    _, _, across = geod.inv(lon[0], lat[0], lon[2], lat[2])
    return replace(
        cfg,
        scene=replace(cfg.scene, n_rows=n_rows, gsd_m=float(np.sqrt(along * across))),
        camera=replace(cfg.camera, bands=tuple(model.bands), reference_band=model.reference_band,
                       band_offsets_px=(0.0,) * n),
        radiometry=replace(r, band_gain=cycle(r.band_gain), band_offset_dn=cycle(r.band_offset_dn),
                           band_gamma=cycle(r.band_gamma)),
    )


def simulate_through_model(out_dir, model, *, dom, dem, config: SimConfig | None = None, geoid=None,
                           workers: int | None = None, block_lines: int = 256, progress=None,
                           record_timings: bool = True,
                           source: dict | None = None) -> dict:
    """Render a scene through a given push-broom model with known errors; write it as a delivered product.

    The TRUE model is ``model`` with the configuration's errors (:func:`perturbed_model`); the
    scene is rendered through it from ``dom`` on ``dem`` as :func:`simulate_pushbroom` renders;
    ``manifest.json`` is ``model`` itself (the geometry as delivered, what a calibration starts
    from) and ``truth_manifest.json`` the TRUE model. The configuration's keys used are
    :data:`MODEL_CONFIG_KEYS`; the others describe the simulator's own camera and are ignored.

    Parameters
    ----------
    out_dir : str or os.PathLike
    model : PushbroomModel
        The delivered geometry (e.g. a window of a vendor product's model).
    dom, dem : path
        Reference orthoimage and DEM covering the footprint.
    config : SimConfig, optional
        Default: :class:`SimConfig` ().
    geoid : path, optional
        EGM96 grid for an orthometric DEM.
    workers, block_lines, progress, record_timings
        As :func:`simulate_pushbroom`.
    source : dict, optional
        Where ``model`` comes from (e.g. ``{"model": path, "window": [...]}``), recorded in
        ``truth.json`` and ``summary.json``.

    Returns
    -------
    dict
        The summary also written to ``summary.json``.
    """
    from types import SimpleNamespace

    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.simulate.truth import truth_error

    if not isinstance(model, PushbroomModel):
        raise InputError(f"rendering through a model needs a push-broom model, not {type(model).__name__}")
    if dom is None or dem is None:
        raise InputError("rendering through a given model needs both --dom and --dem")
    t_start = time.perf_counter()
    cfg = _model_config(config or SimConfig(), model)
    workers = thread_count(workers)
    true_model, injected = perturbed_model(model, cfg)
    models = SimpleNamespace(true_model=true_model, lab_model=model,
                             truth={"injected": injected, "source": source or {}})
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        tmp = tmp.resolve()
        with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES):
            clock = PhaseClock(t_start)
            setup_done, block_progress = step_progress(progress, model.n_rows, block_lines)
            setup_done(1)
            dom_image, dem_model, reference_files, dem_figures = _reference(cfg, models, tmp, dom, dem, geoid)
            renderer = _Renderer(cfg, models, dem_model, dom_image)
            dem_planes(dem_model)
            clock.mark("reference")
            setup_done(2)
            cloud_pixels, has_mask = render_scene(renderer, true_model, tmp, list(cfg.camera.bands),
                                                  cfg.camera.reference_band, len(true_model.band_ccds()),
                                                  block_lines, workers, block_progress)
            render_seconds = clock.mark("blocks")
            initial = truth_error(true_model, model, dem=dem_model, step_px=32)
            clock.mark("truth_error")
            summary = write_outputs(cfg, models, tmp, initial, reference_files, dem_figures,
                                    (cloud_pixels, has_mask), render_seconds, workers, t_start, record_timings,
                                    extra_summary={"source": source or {}, "injected": injected}, phases=clock)
    return summary
