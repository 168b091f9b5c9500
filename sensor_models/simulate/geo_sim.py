"""Earth views of a geostationary staring camera with known truth (``gcpcal simulate geo-earth``).

A frame of a GF-4-like camera (9 um pixels, 50 m at nadir from 35 786 km; a sub-array of
``image_px`` x ``image_px`` pixels) at the sub-satellite point is rendered from a procedural
(or given) DOM and DEM through a TRUE model: installation errors of arcseconds (tens of pixels at
this focal length), a lens with principal-point, focal-length, radial and decentering errors,
and an attitude bias. The LAB model (the design lens, zero installation) goes into
``manifest.json`` with the frame's raster; ``truth_manifest.json`` and ``truth.json`` hold the
truth. Rendering, radiometry and outputs follow the push-broom simulator
(:mod:`sensor_models.simulate.pushbroom_sim`): per block of lines, the pixels are intersected
with the DEM on an exact node grid, the DOM is blurred to the pixel's response and sampled,
noise is added; files are moved into place only when complete.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from sensor_models.files.atomic import atomic_folder
from sensor_models.errors import InputError

__all__ = ["GeoSimConfig", "load_geo_config", "simulate_geo_earth"]

ARCSEC = math.pi / 180.0 / 3600.0


@dataclass(frozen=True)
class GeoSimConfig:
    """Settings of the Earth-view simulation (units in the names; all have defaults)."""

    seed: int = 7
    lon_deg: float = 105.0
    epoch_utc: str = "2023-06-15T03:00:00"
    image_px: int = 512
    pixel_size_mm: float = 0.009
    gsd_m: float = 50.0
    installation_arcsec: tuple = (6.0, -5.0, 40.0)
    attitude_bias_arcsec: tuple = (2.0, 1.5, -3.0)
    focal_length_ratio: float = 1.0008
    principal_point_shift_px: tuple = (3.0, -2.0)
    radial_k1_px2: float = 2.0e-8
    decentering_px1: tuple = (1.0e-7, -1.5e-7)
    snr: float = 100.0
    psf_sigma_px: float = 0.45
    dom_resolution_m: float = 15.0
    dem_resolution_m: float = 30.0
    relief_m: float = 1200.0
    mean_height_m: float = 400.0
    sea_fraction: float = 0.1
    margin_m: float = 3000.0

    def validate(self, source=None) -> "GeoSimConfig":
        """Check the ranges of the settings.

        Parameters
        ----------
        source : str, optional
            The configuration file, named in errors.

        Returns
        -------
        GeoSimConfig
            ``self``.

        Raises
        ------
        InputError
            Naming the first bad field.
        """
        def bad(name, why):
            return InputError(why, path=source, field=name)

        if not 64 <= self.image_px <= 16384:
            raise bad("image_px", "must be 64 to 16384")
        for name in ("pixel_size_mm", "gsd_m", "snr", "dom_resolution_m", "dem_resolution_m"):
            if not getattr(self, name) > 0:
                raise bad(name, "must be positive")
        if not -180 <= self.lon_deg <= 180:
            raise bad("lon_deg", "must lie in [-180, 180]")
        if len(self.installation_arcsec) != 3 or len(self.attitude_bias_arcsec) != 3:
            raise bad("installation_arcsec", "roll, pitch and yaw: three values")
        if not 0.9 < self.focal_length_ratio < 1.1:
            raise bad("focal_length_ratio", "must lie in (0.9, 1.1)")
        if not 0 <= self.sea_fraction <= 0.9:
            raise bad("sea_fraction", "must lie in [0, 0.9]")
        return self


def load_geo_config(path=None) -> GeoSimConfig:
    """A validated configuration from a JSON file with any subset of the keys (strict).

    Parameters
    ----------
    path : str or os.PathLike, optional
        JSON object whose keys are :class:`GeoSimConfig` fields; default: the defaults.

    Returns
    -------
    GeoSimConfig

    Raises
    ------
    InputError
        Unreadable file, invalid JSON, unknown key or bad value (naming it).
    """
    from sensor_models.simulate.config import coerce_value

    if path is None:
        return GeoSimConfig().validate()
    source = str(path)
    from sensor_models.files.documents import load_json

    doc = load_json(path)
    if not isinstance(doc, dict):
        raise InputError("the configuration must be a JSON object", path=source)
    base = GeoSimConfig()
    known = {f.name for f in fields(base)}
    changes = {}
    for key, value in doc.items():
        if key not in known:
            raise InputError(f"unknown key {key!r}", path=source, field="(root)")
        changes[key] = coerce_value(value, getattr(base, key), key, source)
    return replace(base, **changes).validate(source)


def _models(cfg: GeoSimConfig):
    from sensor_models.models.synthetic import example_geo_staring_model
    from sensor_models.models.staring_camera import StaringLab
    from sensor_models.models.pushbroom_types import Installation

    altitude = 35_786_000.0
    focal = cfg.pixel_size_mm * altitude / cfg.gsd_m
    shape = (cfg.image_px, cfg.image_px)
    centre = (cfg.image_px / 2.0, cfg.image_px / 2.0)
    lab_lens = StaringLab(focal_length_mm=focal, pixel_size_mm=cfg.pixel_size_mm)
    true_lens = StaringLab(
        focal_length_mm=focal * cfg.focal_length_ratio, pixel_size_mm=cfg.pixel_size_mm,
        principal_point_px=(centre[0] + cfg.principal_point_shift_px[0], centre[1] + cfg.principal_point_shift_px[1]),
        radial_k=(cfg.radial_k1_px2, 0.0), decentering_p=tuple(cfg.decentering_px1),
    )
    bias = tuple(np.asarray(cfg.attitude_bias_arcsec) * ARCSEC)
    truth = example_geo_staring_model(camera=true_lens, image_shape=shape, epoch=cfg.epoch_utc, lon_deg=cfg.lon_deg,
                                      installation=Installation(*(np.asarray(cfg.installation_arcsec) * ARCSEC)),
                                      attitude_kwargs={"bias_rad": bias}, name="truth")
    lab = example_geo_staring_model(camera=lab_lens, image_shape=shape, epoch=cfg.epoch_utc, lon_deg=cfg.lon_deg,
                                    name="simulated_geo")
    return truth, lab


def simulate_geo_earth(out_dir, *, config: GeoSimConfig | None = None, dom=None, dem=None, geoid=None,
                       block_lines: int = 256, record_timings: bool = True) -> dict:
    """Render a staring frame into ``out_dir`` (see the module docstring); return the summary.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Output folder (created); files appear only when all are complete.
    config : GeoSimConfig, optional
        Default: ``GeoSimConfig()``.
    dom, dem : path, optional
        Real reference rasters (both or neither); without them a procedural reference is
        generated into ``reference/``.
    geoid : path, optional
        EGM96 grid for an orthometric DEM.
    block_lines : int
        Image lines rendered per block.
    record_timings : bool
        Write ``render_seconds`` and ``seconds`` into the summary (False: outputs depend on the
        configuration only).

    Returns
    -------
    dict
        The summary also written to ``summary.json`` (image size, reference files, LAB versus
        truth error in pixels).
    """
    from sensor_models.readers.geo_manifest import write_geo_manifest

    t0 = time.perf_counter()
    cfg = (config or GeoSimConfig()).validate()
    if (dom is None) != (dem is None):
        raise InputError("give both --dom and --dem, or neither (procedural reference)")
    truth, lab = _models(cfg)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        tmp = tmp.resolve()
        dom_img, dem_obj, reference = _geo_reference(cfg, truth, tmp, dom, dem, geoid)
        dem_figures = reference.pop("dem_figures")
        t_render = time.perf_counter()
        _render_frame(cfg, truth, dom_img, dem_obj, tmp / "B1.tif", block_lines)
        render_s = time.perf_counter() - t_render
        write_geo_manifest(lab, tmp / "manifest.json", raster=tmp / "B1.tif")
        write_geo_manifest(truth, tmp / "truth_manifest.json", raster=tmp / "B1.tif")
        truth_doc, summary = _truth_and_summary(cfg, truth, lab, dem_obj, reference)
        summary.update(dem_coverage=dem_figures["dem_coverage"], dem_void_fraction=dem_figures["dem_void_fraction"],
                       warnings=dem_figures["warnings"])
        if record_timings:
            summary.update(render_seconds=render_s, seconds=time.perf_counter() - t0)
        (tmp / "truth.json").write_text(json.dumps(truth_doc, indent=1) + "\n", encoding="utf-8")
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return summary


def _frame_border(n: int):
    """``(rows, cols)`` of 64 pixel centres along the four edges of an ``n`` x ``n`` frame."""
    border = np.concatenate([np.linspace(0.5, n - 0.5, 16)] * 2 + [np.full(16, 0.5), np.full(16, n - 0.5)])
    other = np.concatenate([np.full(16, 0.5), np.full(16, n - 0.5)] + [np.linspace(0.5, n - 0.5, 16)] * 2)
    return border, other


def _geo_reference(cfg: GeoSimConfig, truth, tmp: Path, dom, dem, geoid):
    """``(dom MapImage, Dem, reference file names)``: given, or procedural under ``tmp/reference``.

    Checks that both cover the frame's footprint between the DEM's lowest and highest heights.
    """
    import pyproj

    from sensor_models.simulate.render_io import check_covers, utm_crs
    from sensor_models.maps.grid import MapGrid
    from sensor_models.maps.raster import MapImage
    from sensor_models.terrain.dem import Dem
    from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

    border, other = _frame_border(cfg.image_px)
    if dom is None:
        from sensor_models.simulate.procedural import generate_reference

        lon, lat, _ = truth.image_to_ground(border, other, height=cfg.mean_height_m)
        crs = utm_crs(float(np.mean(lon)), float(np.mean(lat)))
        x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
        data = generate_reference(float(np.mean(lon)), float(np.mean(lat)), float(np.ptp(x)) + 2 * cfg.margin_m,
                                  float(np.ptp(y)) + 2 * cfg.margin_m, seed=cfg.seed,
                                  dom_resolution_m=cfg.dom_resolution_m, dem_resolution_m=cfg.dem_resolution_m,
                                  relief_m=cfg.relief_m, mean_height_m=cfg.mean_height_m,
                                  sea_fraction=cfg.sea_fraction)
        data.write(tmp / "reference")
        dom_img = MapImage.from_array(data.dom, data.dom_transform, data.crs)
        dem_obj = Dem.from_array(data.dem_m, data.dem_transform, data.crs, vertical_datum="ellipsoid")
        reference = {"dom": "reference/dom.tif", "dem": "reference/dem.tif"}
    else:
        dom_img, dem_obj = MapImage.open(dom), Dem.open(dem, geoid=geoid)
        reference = {"dom": os.path.abspath(dom), "dem": os.path.abspath(dem)}
    h_lo, h_hi = dem_obj.height_range_m
    lon, lat = (np.concatenate(a) for a in zip(*(truth.image_to_ground(border, other, height=h)[:2]
                                                  for h in (h_lo, h_hi))))
    check_covers(dom_img.grid, lon, lat, what="DOM", path=dom_img.path)
    check_covers(MapGrid.of_dem(dem_obj), lon, lat, what="DEM", path=dem_obj.source)
    grid_lon, grid_lat = footprint_sample_lonlat(truth, 0.5 * (h_lo + h_hi), n_side=65)
    reference["dem_figures"] = check_dem_footprint(dem_obj, grid_lon, grid_lat, min_coverage=1.0)
    return dom_img, dem_obj, reference


def _render_frame(cfg: GeoSimConfig, truth, dom_img, dem_obj, path: Path, block_lines: int) -> None:
    """Render the frame through the TRUE model into a uint16 GeoTIFF, block by block (seeded per block)."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.windows import Window

    from sensor_models.simulate.pushbroom_sim import dom_scale
    from sensor_models.imaging.locate import dem_planes, locate_block
    from sensor_models.imaging.psf import psf_sigma_dom_px
    from sensor_models.maps.raster import sample_map_image
    from sensor_models.simulate.radiometry import to_dn

    n = cfg.image_px
    dem_planes(dem_obj)
    sigma = psf_sigma_dom_px(cfg.gsd_m, dom_img.grid.resolution_m, cfg.psf_sigma_px)
    scale = dom_scale(dom_img)
    profile = dict(driver="GTiff", width=n, height=n, count=1, dtype="uint16", compress="deflate", predictor=2,
                   tiled=False, blockysize=16)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as dst:
            for r0 in range(0, n, block_lines):
                r1 = min(n, r0 + block_lines)
                pg = locate_block(truth, dem_obj, [dom_img.grid], band=truth.band, ccd=0, row0=r0, row1=r1)
                u, v = pg.uv[0]
                refl = sample_map_image(dom_img, u, v, sigma_px=sigma) / np.float32(scale)
                rng = np.random.default_rng([cfg.seed, 6, r0])
                dn = to_dn(refl, gain=1.0, offset_dn=40.0, gamma=1.0, seasonal=np.float32(0.0),
                           prnu_gain=np.float32(1.0), snr=cfg.snr, bits=12, rng=rng)
                dst.write(dn, 1, window=Window(0, r0, n, r1 - r0))


def _truth_and_summary(cfg: GeoSimConfig, truth, lab, dem_obj, reference):
    """The ``truth.json`` document and the summary (timings left out)."""
    from sensor_models.simulate.truth import truth_error

    n = cfg.image_px
    initial = truth_error(truth, lab, dem=dem_obj, step_px=max(8, n // 32))
    truth_doc = {
        "format_version": 1, "kind": "gcpcal.simulate.geo_earth", "seed": cfg.seed,
        "true_model": "truth_manifest.json", "lab_model": "manifest.json", "reference": reference,
        "installation_rad": dict(zip(("roll", "pitch", "yaw"), truth.installation.as_array().tolist())),
        "config": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()},
    }
    summary = {"kind": "gcpcal.simulate.geo_earth", "image": {"n_rows": n, "n_cols": n, "bands": [truth.band]},
               "reference": reference, "lab_truth_error_px": {"rms": initial["rms_px"], "max": initial["max_px"]}}
    return truth_doc, summary
