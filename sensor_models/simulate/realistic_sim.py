"""A push-broom scene under a non-ideal error profile (``gcpcal simulate pushbroom --profile realistic``).

Same outputs as :func:`sensor_models.simulate.pushbroom_sim.simulate_pushbroom` (bands, LAB and
TRUE manifests, ``truth.json``, ``summary.json``, ``reference/dom.tif`` and ``reference/dem.tif``),
but:

* the TRUE model carries the profile's attitude jitter, drift, star-tracker noise (in the
  measured attitude) and orbit bias, and a lens beyond the cubic
  (:mod:`sensor_models.simulate.true_lens`);
* the pixels come from the simulator's own kernel (:mod:`sensor_models.simulate.kernel`);
* ``reference/dom.tif`` and ``reference/dem.tif`` are NOT what rendered the scene: they are
  degraded copies (:mod:`sensor_models.simulate.reference_pair`); the TRUE DEM is kept as
  ``reference/truth/dem_true.tif`` for inspection (the source radiance is not written).

The source radiance is a given raster (``dom``: e.g. a real Sentinel-2 red band, see
docs/error_budget.md; the scene is then centred on it) or the procedural texture
(:func:`sensor_models.simulate.procedural.generate_reference`), brought to a real image's contrast
and given texture-poor patches (:mod:`sensor_models.simulate.texture_poor`). The TRUE DEM is procedural.
The scene and the DOM are lit by their own suns (hill shading, cast shadows:
:mod:`sensor_models.simulate.illumination`); clouds (``clouds.cover``) have heights, parallax and
shadows (:mod:`sensor_models.simulate.clouds3d`); the TRUE attitude carries a jitter spectrum
(:mod:`sensor_models.simulate.jitter`) and the optics an astigmatic PSF that worsens towards the
swath edge (:func:`field_weights`).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pyproj

from sensor_models.errors import InputError
from sensor_models.files.threads import thread_count
from sensor_models.imaging.locate import dem_planes, locate_block
from sensor_models.maps.grid import MapGrid
from sensor_models.simulate.config import SimConfig
from sensor_models.simulate.clouds3d import apparent_clouds, cloud_layers, ground_shadow, ray_slope
from sensor_models.simulate.illumination import (Sun, cast_shadow, illumination, resample_to_grid,
                                                 sun_angles_deg)
from sensor_models.simulate.jitter import jitter_spectrum
from sensor_models.simulate.kernel import (detector_response, footprint_offsets, integrate_footprint, optics_kernel,
                                           system_mtf)
from sensor_models.simulate.profiles import profile_table
from sensor_models.simulate.render_io import (PhaseClock, check_covers, footprint_lonlat, render_scene, step_progress,
                                              utm_crs, write_outputs)
from sensor_models.simulate.reference_pair import DEM_NODATA, degrade_dem, degrade_dom, write_raster
from sensor_models.simulate.scene import build_models, ccd_layout
from sensor_models.simulate.source_windows import FilteredWindows, RowFile, read_rows
from sensor_models.simulate.true_lens import cubic_residual_px, lens_extras
from sensor_models.simulate.truth import truth_error
from sensor_models.terrain.dem import Dem
from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

__all__ = ["apply_profile", "detector_gains", "field_weights", "mtf_nyquist", "simulate_realistic", "source_radiance"]


def apply_profile(cfg: SimConfig, profile) -> SimConfig:
    """The configuration with the profile's attitude, orbit and detector magnitudes.

    Parameters
    ----------
    cfg : SimConfig
        The scene configuration (geometry, camera, calibration targets).
    profile : PushbroomProfile
        Sets ``errors.attitude_noise_urad``, ``jitter_*``, ``attitude_drift_arcsec_s``,
        ``orbit_noise_m``, ``orbit_noise_period_s`` and ``radiometry.snr``, ``bits``, ``prnu``, ``seasonal_*``.

    Returns
    -------
    SimConfig
        Validated.
    """
    v = profile.value
    e = replace(cfg.errors, attitude_noise_urad=float(v("star_tracker_noise_urad")),
                jitter_amplitude_urad=tuple(v("jitter_amplitude_urad")), jitter_frequency_hz=float(v("jitter_frequency_hz")),
                attitude_drift_arcsec_s=tuple(v("attitude_drift_arcsec_s")), orbit_noise_m=float(v("orbit_noise_m")),
                orbit_noise_period_s=float(v("orbit_noise_period_s")))
    r = replace(cfg.radiometry, snr=float(v("snr")), bits=int(v("bits")), prnu=float(v("prnu_rms")),
                seasonal_change=float(v("seasonal_change")), seasonal_scale_m=float(v("seasonal_scale_m")))
    return replace(cfg, errors=e, radiometry=r).validate()


def _read_source(path):
    """``(radiance 0..1 float32 with NaN, transform, crs)`` of a north-up raster in metres."""
    import rasterio

    try:
        with rasterio.open(path) as ds:
            a = ds.read(1, masked=True)
            transform, crs = ds.transform, pyproj.CRS.from_user_input(ds.crs.to_wkt()) if ds.crs else None
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"cannot read the source radiance ({exc})", path=str(path)) from None
    if crs is None or not crs.is_projected or transform.b != 0 or transform.d != 0:
        raise InputError("the source radiance must be a north-up raster in a projected CRS (metres)", path=str(path))
    a = np.ma.filled(a.astype(np.float32), np.nan)
    valid = a[np.isfinite(a) & (a > 0)]
    if valid.size < 100:
        raise InputError("the source radiance holds no texture", path=str(path))
    return a / np.float32(np.percentile(valid, 99.5)), transform, crs


def _centred_models(cfg: SimConfig, lens, orbit_bias_m: float, centre_lonlat, jitter=None):
    """Models whose TRUE footprint centre lies on ``centre_lonlat`` (None: the configured centre)."""
    if centre_lonlat is None:
        return cfg, build_models(cfg, lens=lens, orbit_bias_m=orbit_bias_m, jitter=jitter)
    lon, lat = centre_lonlat
    for _ in range(3):
        cfg = replace(cfg, scene=replace(cfg.scene, center_lon_deg=float(lon), center_lat_deg=float(lat))).validate()
        models = build_models(cfg, lens=lens, orbit_bias_m=orbit_bias_m, jitter=jitter)
        m = models.true_model
        tl, tb, _ = m.image_to_ground([m.n_rows / 2], [m.n_cols / 2], height=cfg.reference.mean_height_m)
        lon += centre_lonlat[0] - float(tl[0])
        lat += centre_lonlat[1] - float(tb[0])
    return cfg, build_models(cfg, lens=lens, orbit_bias_m=orbit_bias_m, jitter=jitter)


def _source_and_dem(cfg: SimConfig, models, given_source, contrast: float = 0.0, texture_poor=(0.0, 1.0),
                    progress=None):
    """Source radiance (array, transform, crs: ``given_source`` or procedural) and the TRUE DEM.

    The procedural radiance gets the RMS contrast ``contrast`` of real imagery (0: its own;
    :func:`sensor_models.simulate.texture_stats.scale_contrast`), then texture-poor patches
    ``texture_poor = (fraction of the land, attenuation)``
    (:func:`sensor_models.simulate.texture_poor.texture_poor_cover`; fraction 0: none).
    ``progress(done, total)`` counts the generator's phases and DOM strips
    (:func:`sensor_models.simulate.procedural.generate_reference`)."""
    from sensor_models.simulate.procedural import generate_reference

    ref = cfg.reference
    h = (ref.mean_height_m - ref.relief_m - 100.0, ref.mean_height_m + ref.relief_m + 100.0)
    lon, lat = footprint_lonlat(models.true_model, h)
    crs = utm_crs(float(lon.mean()), float(lat.mean()))
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    width, height = float(np.ptp(x)) + 2.0 * ref.margin_m, float(np.ptp(y)) + 2.0 * ref.margin_m
    cx, cy = 0.5 * (np.min(x) + np.max(x)), 0.5 * (np.min(y) + np.max(y))
    clon, clat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(cx, cy)
    procedural = given_source is None
    # a real texture has its own water; its procedural DOM is not used, so drawn coarse
    data = generate_reference(float(clon), float(clat), width, height, seed=cfg.seed,
                              dom_resolution_m=ref.dom_resolution_m if procedural else 2 * ref.dem_resolution_m,
                              dem_resolution_m=ref.dem_resolution_m, relief_m=ref.relief_m,
                              mean_height_m=ref.mean_height_m, sea_fraction=ref.sea_fraction if procedural else 0.0,
                              progress=progress)
    if not procedural:
        return given_source, replace(data, dom=None, land_cover=None)
    dom = data.dom.astype(np.float32)
    data = replace(data, dom=None, land_cover=None)  # the next steps read the DEM and the water only
    if contrast > 0.0:
        from sensor_models.simulate.texture_stats import scale_contrast

        dom = scale_contrast(dom, abs(data.dom_transform.a), contrast)[0]
    if texture_poor[0] > 0.0:
        from sensor_models.simulate.texture_poor import texture_poor_cover

        dom = texture_poor_cover(dom, abs(data.dom_transform.a), *texture_poor, seed=[cfg.seed, 40],
                                 water=data.water_mask)[0]
    dom /= np.float32(np.percentile(dom, 99.5))  # dom is this function's own float32 array
    return (dom, data.dom_transform, data.crs), data


def detector_gains(profile, seed: int, band_index: int, ccd: int, n_detectors: int, n_ccds: int):
    """Per-detector gain (PRNU times the CCD's gain) and offset (striping) of one band and CCD.

    Parameters
    ----------
    profile : PushbroomProfile
        ``prnu_rms``, ``ccd_gain_step``, ``striping_dn``.
    seed : int
        Camera seed (the detectors are the sensor's, shared by its scenes).
    band_index, ccd : int
        Band position and CCD index.
    n_detectors, n_ccds : int
        Detectors of the CCD; CCDs of the band.

    Returns
    -------
    gain : ndarray of float32, shape (n_detectors,)
    offset_dn : ndarray of float32, shape (n_detectors,)
    """
    v = profile.value
    prnu = np.random.default_rng([seed, 30, band_index, ccd]).normal(1.0, v("prnu_rms"), n_detectors)
    ccd_gain = np.random.default_rng([seed, 31, band_index]).normal(1.0, v("ccd_gain_step"), n_ccds)[ccd]
    stripes = np.random.default_rng([seed, 32, band_index, ccd]).normal(0.0, v("striping_dn"), n_detectors)
    return (prnu * ccd_gain).astype(np.float32), stripes.astype(np.float32)


def field_weights(cfg: SimConfig) -> list:
    """``(y / Y)^2`` of every detector of every CCD: its squared across-track field position.

    Parameters
    ----------
    cfg : SimConfig
        Camera layout (:func:`sensor_models.simulate.scene.ccd_layout`).

    Returns
    -------
    list of ndarray of float32, shape (n_detectors,)
        Per CCD, 0 on the optical axis, 1 at the swath edge.
    """
    layout = ccd_layout(cfg)
    n = cfg.camera.detectors_per_ccd
    half = 0.5 * (layout[-1][3] - layout[0][3] + n)
    s = np.arange(n, dtype=np.float64)
    return [np.clip(((y0 + s) / half) ** 2, 0.0, 1.0).astype(np.float32) for _, _, _, y0 in layout]


class _KernelRenderer:
    """Renders one (band, CCD, block of lines) task with :mod:`sensor_models.simulate.kernel`."""

    clouds = None
    shadows = None

    def __init__(self, cfg: SimConfig, profile, model, dem: Dem, source, lens, sky=None):
        v = profile.value
        radiance, transform, crs = source  # an array or a RowFile
        self.cfg, self.model, self.dem, self.lens = cfg, model, dem, lens
        self.grid = MapGrid(transform, crs, radiance.shape)
        self.scale = cfg.scene.gsd_m / abs(transform.a)
        # centre (and edge, with astigmatism) PSFs, applied per window of the source the blocks read
        self.radiance = FilteredWindows(radiance, _field_kernels(profile, self.scale))
        self.weights = field_weights(cfg)
        self.offsets = footprint_offsets(int(v("supersampling")), float(v("motion_smear_lines")))
        self.profile = profile
        self.band_index = {b: i for i, b in enumerate(cfg.camera.bands)}
        if sky is not None and sky.get("layers") is not None:
            self.clouds, self.shadows = sky["layers"], sky["cloud_shadow"]

    def task(self, band: str, ccd: int, row0: int, row1: int):
        cfg, r, v = self.cfg, self.cfg.radiometry, self.profile.value
        b = self.band_index[band]
        lo = row0 if row1 - row0 >= 2 else max(0, row0 - 1)  # the Jacobian needs two lines
        pg = locate_block(self.model, self.dem, [self.grid], band=band, ccd=ccd, row0=lo, row1=max(row1, lo + 2))
        u, v_ = pg.uv[0]
        n = u.shape[1]
        ir, ic = self.lens.irregularity(b, ccd, n)
        rad = integrate_footprint(self.radiance, u, v_, *self.offsets, irregular_row=ir, irregular_col=ic)
        if rad.ndim == 3:  # the PSF changes across the field: blend centre and edge by (y / Y)^2
            w = self.weights[ccd][None, :]
            rad = (1.0 - w) * rad[..., 0] + w * rad[..., 1]
        keep = slice(row0 - lo, row0 - lo + (row1 - row0))
        rad, alpha, shadow = rad[keep], None, None
        if self.clouds is not None:
            du, dv = ray_slope(self.model, self.grid, band=band, ccd=ccd, row=0.5 * (row0 + row1))
            alpha, tex = apparent_clouds(self.clouds, u[keep], v_[keep], pg.h_m[keep], du, dv)
            rad = (1.0 - alpha) * rad + alpha * (CLOUD_RADIANCE * (1.0 + 0.06 * tex))
            ground = cv2.remap(self.shadows, u[keep], v_[keep], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0.0)
            shadow = ((ground > 0.5) & (alpha <= 0.5)).astype(np.uint8)
        gain, stripes = detector_gains(self.profile, cfg.seed, b, ccd, n, len(self.model.band_ccds(band)))
        dn = detector_response(rad, gain=r.band_gain[b], gamma=r.band_gamma[b], offset_dn=r.band_offset_dn[b],
                               nonlinearity=v("nonlinearity"), pixel_gain=gain, pixel_offset_dn=stripes, snr=r.snr,
                               bits=r.bits, rng=np.random.default_rng([cfg.pass_seed, 33, b, ccd, row0]))
        return dn, alpha, shadow


#: radiance of a thick cloud top (the source radiance is 1 at its 99.5th percentile)
CLOUD_RADIANCE = 1.1


def _field_kernels(profile, scale: float) -> list:
    """Optical PSFs on the source raster: the centre's, and the swath edge's when astigmatic."""
    v = profile.value
    r0 = v("defocus_radius_px")
    kw = dict(halo_fraction=v("halo_fraction"), halo_sigma_px=v("halo_sigma_px"), source_px_per_px=scale)
    kernels = [optics_kernel(r0, **kw)]
    along, across = v("astigmatism_edge_px")
    if along or across:
        kernels.append(optics_kernel(r0 + across, defocus_radius_row_px=r0 + along, **kw))
    return kernels


def _sun(profile, key: str, lat_deg: float):
    """The :class:`Sun` of ``sun_scene_date_time`` or ``sun_dom_date_time`` (None: not simulated)."""
    when = profile.value(key)
    return None if when is None else sun_angles_deg(lat_deg, float(when[0]), float(when[1]))


def _lit_source(cfg: SimConfig, profile, source, data, which: str, out=None):
    """The scene's (``which="scene"``, with its clouds and their shadows) or the DOM's (``"dom"``)
    radiance under its own sun.

    ``out`` (optional): a :class:`sensor_models.simulate.source_windows.RowFile` of the source's
    shape that receives the lit radiance strip by strip (it is then never whole in memory).

    Returns ``(source, sky)``: the source as ``(radiance, transform, crs)`` (``radiance`` is
    ``out`` when given); ``sky`` holds ``layers`` (:class:`CloudLayers` or None),
    ``cloud_shadow`` (ground map) and JSON-safe ``figures`` (both suns; the clouds with
    ``"scene"``). One at a time, so that the DOM's is degraded and let go before the scene's is made.
    """
    radiance, transform, crs = source
    v, res = profile.value, abs(transform.a)
    sun_s, sun_d = _sun(profile, "sun_scene_date_time", cfg.scene.center_lat_deg), \
        _sun(profile, "sun_dom_date_time", cfg.scene.center_lat_deg)
    if cfg.clouds.cover > 0 and int(v("cloud_layers")) <= 0:
        raise InputError(f"clouds need cloud layers under the {profile.name} profile (cloud_layers = 0)",
                         field="clouds.cover")
    k = float(v("skylight_fraction"))
    sky = {"layers": None, "cloud_shadow": None, "figures": {}}
    dim = None  # the cloud shadows' factor on the light, whole grid
    if which == "scene" and cfg.clouds.cover > 0:
        ground = resample_to_grid(data.dem_m, data.dem_transform, radiance.shape, transform,
                                  fill=float(np.nanmean(data.dem_m)))
        layers = cloud_layers(radiance.shape, res, cover=cfg.clouds.cover, scale_m=cfg.clouds.scale_m,
                              heights_km=v("cloud_top_height_km"), n_layers=int(v("cloud_layers")),
                              mean_ground_m=float(np.nanmean(data.dem_m)), seed=cfg.pass_seed)
        shade = ground_shadow(layers, ground, res, sun_s or Sun(89.9, 180.0)) * np.float32(v("cloud_shadow"))
        del ground
        dim = 1.0 - np.float32(1.0 - k) * shade
        sky.update(layers=layers, cloud_shadow=shade)
        sky["figures"]["clouds"] = {**layers.to_dict(),
                                    "ground_shadow_fraction": round(float((shade > 0.5).mean()), 4)}
    suns = {"scene": sun_s, "dom": sun_d} if sun_s is not None and sun_d is not None else None
    if suns is None and dim is None and out is None:
        return (radiance, transform, crs), sky
    lit = out if out is not None else np.empty(radiance.shape, dtype=np.float32)
    sky["figures"] = {**_sunlit(radiance, transform, data, suns, k, which, lit, dim), **sky["figures"]}
    return (lit, transform, crs), sky


#: source pixels :func:`_sunlit` lights at a time (whole rows)
_STRIP_PIXELS = 1 << 18


def _sunlit(radiance, transform, data, suns, skylight: float, which: str, lit, dim=None) -> dict:
    """``radiance`` under ``suns[which]`` into ``lit``: hill shading and cast shadows of the TRUE DEM
    (:func:`sensor_models.simulate.illumination.illumination`, computed on the DEM grid), resampled to the
    source grid strip by strip (:func:`sensor_models.simulate.illumination.resample_to_grid`), times
    ``dim`` (the clouds' shadows) when given.

    ``suns`` None: no sun (``lit`` gets ``radiance`` times ``dim``). ``lit``: a float32 array of the
    source's shape or a :class:`sensor_models.simulate.source_windows.RowFile`, written strip by strip.

    Returns the figures: per sun of ``suns`` (``"scene"`` and ``"dom"``), its angles and
    cast-shadow fraction, with ``light_ratio_rms`` = std of ``log(light_scene / light_dom)`` over
    the source grid (empty without suns).
    """
    dem_res = abs(data.dem_transform.a)
    on_dem = {}
    for name, sun in (suns or {}).items():
        shadow = cast_shadow(data.dem_m, dem_res, sun)
        on_dem[name] = illumination(data.dem_m, dem_res, sun, skylight=skylight, shadow=shadow), shadow
    shaded = dict.fromkeys(on_dem, 0)
    log_sum = log_sq = 0.0
    step = max(1, _STRIP_PIXELS // radiance.shape[1])
    for r0 in range(0, radiance.shape[0], step):
        rows = slice(r0, min(r0 + step, radiance.shape[0]))
        strip = np.array(read_rows(radiance, rows.start, rows.stop), dtype=np.float32)
        if on_dem:
            light = {}
            for name, (on_grid, shadow) in on_dem.items():
                light[name] = resample_to_grid(on_grid, data.dem_transform, radiance.shape, transform, fill=1.0,
                                               rows=rows)
                cast = resample_to_grid(shadow, data.dem_transform, radiance.shape, transform, fill=0.0, rows=rows)
                shaded[name] += int(np.count_nonzero(cast > 0.5))
            np.multiply(strip, light[which], out=strip)
            ratio = np.log(light["scene"] / light["dom"]).astype(np.float64)
            log_sum, log_sq = log_sum + float(ratio.sum()), log_sq + float(np.square(ratio).sum())
        if dim is not None:
            strip = strip * dim[rows]
        if isinstance(lit, np.ndarray):
            lit[rows] = strip
        else:
            lit.write_rows(r0, strip)
    if not on_dem:
        return {}
    n = radiance.shape[0] * radiance.shape[1]
    figures = {f"sun_{name}": {**sun.to_dict(), "cast_shadow_fraction": round(shaded[name] / n, 5)}
               for name, sun in suns.items()}
    figures["light_ratio_rms"] = round(float(np.sqrt(max(log_sq / n - (log_sum / n) ** 2, 0.0))), 4)
    return figures


def _stated_dom_accuracy(profile) -> dict:
    """The DOM's accuracy as its producer would state it (GDAL tags of sensor_models.maps.dom_inputs): the
    profile's per-axis rms, bias and field together, rounded to 0.1 m; not the drawn field's."""
    from sensor_models.maps.dom_inputs import ACCURACY_TAG_X, ACCURACY_TAG_Y

    (bias_e, bias_n), field = profile.value("dom_bias_m"), profile.value("dom_field_rms_m")
    return {ACCURACY_TAG_X: f"{np.hypot(bias_e, field):.1f}", ACCURACY_TAG_Y: f"{np.hypot(bias_n, field):.1f}"}


def _write_reference(tmp: Path, cfg, profile, source, data):
    """Degrade and write ``reference/dom.tif``, ``dem.tif`` (and the truth under ``reference/truth``)."""
    radiance, transform, crs = source
    ref_dir = tmp / "reference"
    (ref_dir / "truth").mkdir(parents=True, exist_ok=True)
    dom = degrade_dom(radiance, transform, profile, seed=cfg.pass_seed)
    dem = degrade_dem(data.dem_m, data.dem_transform, profile, seed=cfg.pass_seed)
    write_raster(ref_dir / "dom.tif", dom.values, dom.transform, crs, tags=_stated_dom_accuracy(profile))
    write_raster(ref_dir / "dem.tif", dem.values, dem.transform, data.crs, tags={"VERTICAL_DATUM": "ellipsoid"},
                 nodata=DEM_NODATA)
    write_raster(ref_dir / "truth" / "dem_true.tif", data.dem_m.astype(np.float32), data.dem_transform, data.crs,
                 tags={"VERTICAL_DATUM": "ellipsoid"})
    files = {"dom": "reference/dom.tif", "dem": "reference/dem.tif", "true_dem": "reference/truth/dem_true.tif"}
    return files, {"dom": dom.figures, "dem": dem.figures}


def mtf_nyquist(profile, source_px_per_px: float) -> dict:
    """System MTF at Nyquist across (``col``) and along (``row``) track, at the field centre and edge.

    Parameters
    ----------
    profile : PushbroomProfile
        Optics and footprint magnitudes (``defocus_radius_px``, ``astigmatism_edge_px``, ...).
    source_px_per_px : float
        Source-raster pixels per detector pitch.

    Returns
    -------
    dict
        ``{"centre": {"col", "row"}, "edge": {"col", "row"}}``.
    """
    v = profile.value
    along, across = v("astigmatism_edge_px")
    r0 = v("defocus_radius_px")
    kw = dict(halo_fraction=v("halo_fraction"), halo_sigma_px=v("halo_sigma_px"), supersampling=int(v("supersampling")),
              smear_lines=v("motion_smear_lines"), source_px_per_px=source_px_per_px)
    out = {}
    for where, (r_col, r_row) in (("centre", (r0, r0)), ("edge", (r0 + across, r0 + along))):
        out[where] = {ax: float(system_mtf([0.5], defocus_radius_px=r_col, defocus_radius_row_px=r_row, axis=ax,
                                           **kw)[0]) for ax in ("col", "row")}
    return out


def _scene_masks(tmp: Path) -> dict:
    """Shares of the scene under cloud and under cloud shadow (when the masks were written)."""
    import rasterio

    out = {}
    for name in ("cloud_mask", "shadow_mask"):
        if (tmp / f"{name}.tif").exists():
            with rasterio.open(tmp / f"{name}.tif") as ds:
                out[f"{name}_fraction"] = round(float((ds.read(1) > 0).mean()), 5)
    return out


def _figures(cfg, profile, models, lens, true_dem: Dem, user: Dem, source_scale: float) -> dict:
    """What the profile injected, measured: MTF at Nyquist, lens residual, DEM error."""
    mtf = mtf_nyquist(profile, source_scale)
    lon, lat = footprint_sample_lonlat(models.true_model, cfg.reference.mean_height_m, n_side=33)
    dh = user.height_m(lon, lat) - true_dem.height_m(lon, lat)
    dh = dh[np.isfinite(dh)]
    return {"mtf_nyquist": mtf["centre"], "mtf_nyquist_edge": mtf["edge"], "lens_beyond_cubic_px": cubic_residual_px(models, lens),
            "dem_error_under_footprint_m": {"rms": float(np.sqrt(np.mean(dh**2))), "max": float(np.abs(dh).max())}}


def simulate_realistic(tmp, cfg: SimConfig, profile, *, dom_path=None, dem_path=None, geoid=None,
                       workers: int | None = None,
                       block_lines: int = 256, progress=None, t_start: float | None = None,
                       record_timings: bool = True) -> dict:
    """Render a scene under ``profile`` into the (temporary) folder ``tmp``; return its summary.

    Parameters
    ----------
    tmp : Path
        Output folder (the caller moves it into place). The source and its lit radiances are
        float32 scratch files there while the scene is made (4 bytes a source pixel each,
        hidden names, removed before returning; :mod:`sensor_models.simulate.source_windows`).
    cfg : SimConfig
        Geometry, camera and calibration targets; the profile overrides attitude, orbit and
        detector magnitudes (:func:`apply_profile`).
    profile : PushbroomProfile
        A non-ideal profile.
    dom_path : path, optional
        Source radiance raster (north-up, projected); the scene is centred on it. None:
        procedural texture around the configured centre.
    dem_path, geoid : None
        Not supported under this profile (the TRUE DEM is procedural); given: an error.
    workers, block_lines, progress, record_timings
        As :func:`sensor_models.simulate.pushbroom_sim.simulate_pushbroom`.
    t_start : float, optional
        ``time.perf_counter()`` at the start of the command.

    Returns
    -------
    dict
        The summary (``summary.json``), with ``profile`` and ``injected`` figures.
    """
    t_start = time.perf_counter() if t_start is None else t_start
    workers = thread_count(workers)
    if dem_path is not None or geoid is not None:
        raise InputError(f"the {profile.name} profile derives the user's DEM from a procedural TRUE DEM: give --dom "
                         "only (the scene's source radiance)", field="dem")
    tmp = Path(tmp)
    clock = PhaseClock(t_start)
    setup_done, block_progress = step_progress(progress, cfg.scene.n_rows, block_lines)
    cfg, models, lens, source, true_dem, data = realistic_setup(cfg, profile, dom_path, progress=setup_done.part)
    data = replace(data, dom=None, water_mask=None, land_cover=None)  # the next steps read its DEM only
    clock.mark("models")
    setup_done(1)
    # the source, the DOM's and the scene's lit radiance live in scratch files, written and read by strips
    shape, scratch = source[0].shape, []
    tmp.mkdir(parents=True, exist_ok=True)

    def scratch_file(name, values=None):
        scratch.append(RowFile(tmp / f".{name}.f32", shape) if values is None
                       else RowFile.from_array(tmp / f".{name}.f32", values))
        return scratch[-1]

    try:
        source = (scratch_file("source_radiance", source[0]),) + tuple(source[1:])  # the array let go
        dom_source, _ = _lit_source(cfg, profile, source, data, "dom", out=scratch_file("dom_radiance"))
        reference_files, degraded = _write_reference(tmp, cfg, profile, dom_source, data)
        scene_source, sky = _lit_source(cfg, profile, source, data, "scene", out=scratch_file("scene_radiance"))
        del source, data, dom_source
        renderer = _KernelRenderer(cfg, profile, models.true_model, true_dem, scene_source, lens, sky)
        del scene_source
        dem_planes(true_dem)
        clock.mark("reference")
        setup_done(2)
        clouds = render_scene(renderer, models.true_model, tmp, list(cfg.camera.bands), cfg.camera.reference_band,
                              len(models.true_model.band_ccds(cfg.camera.reference_band)), block_lines, workers,
                              block_progress)
    finally:
        for f in scratch:
            f.remove()
    render_seconds = clock.mark("blocks")  # the whole render: models, reference and blocks
    user_dem = Dem.open(tmp / "reference" / "dem.tif")
    g_lon, g_lat = footprint_sample_lonlat(models.true_model, float(np.mean(true_dem.height_range_m)), n_side=65)
    dem_figures = check_dem_footprint(user_dem, g_lon, g_lat, min_coverage=1.0)
    dem_figures["warnings"] = [w.replace(f"{tmp}/", "") for w in dem_figures["warnings"]]  # no temporary path
    injected = {**_figures(cfg, profile, models, lens, true_dem, user_dem, renderer.scale),
                **degraded, **sky["figures"], **_scene_masks(tmp),
                "jitter_spectrum": models.truth.get("jitter_spectrum"),
                "source_radiance": str(Path(dom_path).resolve()) if dom_path else "procedural"}
    # the LAB model's error over the TRUE terrain (the user's DEM has voids)
    initial = truth_error(models.true_model, models.lab_model, dem=true_dem, step_px=32)
    clock.mark("truth_error")
    return write_outputs(cfg, models, tmp, initial, reference_files, dem_figures, clouds, render_seconds, workers,
                         t_start, record_timings, extra_truth=_truth_record(cfg, profile, models, lens, injected),
                         extra_summary={"profile": profile.name, "injected": injected}, phases=clock)


def realistic_setup(cfg: SimConfig, profile, dom_path, progress=None):
    """Effective configuration, models (centred on a given source), lens, source radiance, TRUE DEM.

    ``progress(done, total)`` (optional) counts the building of the source radiance and DEM,
    the longest part of the set-up at large sizes (:func:`_source_and_dem`).
    """
    cfg = apply_profile(cfg, profile)
    lens = lens_extras(profile, cfg.seed)
    centre, given = None, None
    if dom_path is not None:
        given = radiance, transform, crs = _read_source(dom_path)
        cx = transform.c + 0.5 * radiance.shape[1] * transform.a
        cy = transform.f + 0.5 * radiance.shape[0] * transform.e
        centre = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(cx, cy)
    cfg, models = _centred_models(cfg, lens, float(profile.value("orbit_bias_m")), centre, jitter_spectrum(profile))
    texture_poor = (float(profile.value("texture_poor_fraction")), float(profile.value("texture_poor_attenuation")))
    source, data = _source_and_dem(cfg, models, given, float(profile.value("procedural_rms_contrast")), texture_poor,
                                   progress=progress)
    true_dem = Dem.from_array(data.dem_m, data.dem_transform, data.crs, vertical_datum="ellipsoid")
    lon, lat = footprint_lonlat(models.true_model, true_dem.height_range_m)
    check_covers(MapGrid(source[1], source[2], source[0].shape), lon, lat, what="source radiance",
                 path=str(dom_path) if dom_path else None)
    check_covers(MapGrid.of_dem(true_dem), lon, lat, what="DEM", path=None)
    return cfg, models, lens, source, true_dem, data


def source_radiance(cfg: SimConfig, profile) -> tuple:
    """The procedural source radiance a scene of ``cfg`` is rendered from under ``profile`` (before the suns).

    What :func:`simulate_realistic` draws without ``dom_path`` (contrast scaling, texture-poor
    patches), for measuring it (``bench/bench_texture_stats.py``).

    Parameters
    ----------
    cfg : SimConfig
        Scene configuration.
    profile : PushbroomProfile
        A non-ideal profile.

    Returns
    -------
    radiance : ndarray of float32, shape (H, W)
        0..1 (1 at the 99.5th percentile).
    transform : affine.Affine
        Pixel-corner affine, UTM metres.
    water : ndarray of bool, shape (H, W)
        Sea, lakes and rivers.
    """
    _, _, _, source, _, data = realistic_setup(cfg, profile, None)
    return source[0], source[1], data.water_mask


def _truth_record(cfg, profile, models, lens, injected) -> dict:
    """What ``truth.json`` adds under a profile: its table, the orbit bias, every detector's irregularity."""
    irregular = {b: [np.stack(lens.irregularity(i, k, look.n_detectors)).round(5).tolist()
                     for k, look in enumerate(models.true_model.band_ccds(b))] for i, b in enumerate(cfg.camera.bands)}
    return {"profile": profile.name, "profile_table": [list(r) for r in profile_table(profile)],
            "orbit_bias_m": profile.value("orbit_bias_m"),
            "detector_irregularity_px": {"axes": ["row", "col"], "bands": irregular}, "injected": injected}
