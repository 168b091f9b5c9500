"""Validation series: further acquisitions of one push-broom sensor, with their sites file.

Seed 003 (section 3.4, table 5) checks a calibration on 30 scenes of the same camera taken at
six sites on different dates: once the camera is calibrated, the remaining geolocation error of
another scene is what differs between that acquisition and the calibration scene, mostly the
constant attitude bias of each pass (star-tracker alignment, thermal state), a few pixels.

:func:`simulate_series` renders such a series with :func:`~sensor_models.simulate.pushbroom_sim.simulate_pushbroom`:

* **same sensor**: every scene keeps ``base_config.seed``, which seeds the TRUE camera's random
  parts (CCD shifts, band offsets, PRNU: :mod:`sensor_models.simulate.scene`), and its camera,
  installation, distortion and drift settings; a calibration of the scene rendered from
  ``base_config`` itself (``calibration_scene=True``, or ``gcpcal demo`` for the default
  configuration, which is the embedded fixture's) therefore fits every scene of the series;
* **per scene** (drawn from ``numpy.random.default_rng(SeedSequence([seed, k]))``): the site
  (``sites`` in turn), the scene centre (the site's plus a uniform jitter of
  ``center_jitter_deg``), the date (the previous scene's plus ``revisit_days``), the constant
  attitude bias (``base + N(0, attitude_bias_sigma_arcsec)`` per roll, pitch, yaw) and the
  cloud cover (``cloud_fractions`` in turn);
* **per site**: one procedural reference DOM and DEM (:func:`~sensor_models.simulate.procedural.generate_reference`,
  seeded from ``(seed, site)``) covering the TRUE footprints of all the site's scenes, shared
  by them as a real reference is shared by repeated acquisitions.

A bias difference ``d`` (roll, pitch, yaw; this scene's minus the base's) leaves a mean
check-point residual (observed minus calibrated-model position) of about ``-d_pitch H / GSD``
lines and ``+d_roll H / GSD`` columns (``H`` the altitude, small angles, near-nadir view); yaw
turns the image about its centre (``d_yaw`` times the half swath in pixels at the edges).
These predictions go into ``series.json`` per scene (``expected_offset_px``), the truth a
validation run is checked against.

Each scene has its own ``scene.acquisition_seed``: attitude and orbit noise, jitter phase,
radiometric noise, seasonal change and clouds differ from scene to scene, while the camera (seeded
by ``seed``) is the same.

Outputs in ``out_dir``::

    sites.yaml, sites.csv     the sites file of ``gcpcal validate`` (paths relative to it)
    series.json               the plan and per-scene truth
    references/<site>/        dom.tif, dem.tif
    scenes/<name>/            the scene (manifest.json, B*.tif, truth files)
    calibration/              the base configuration's scene (with calibration_scene=True)
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyproj

from sensor_models.files.atomic import atomic_write_text
from sensor_models.errors import InputError
from sensor_models.simulate.config import SimConfig

__all__ = ["DEFAULT_SITES", "SeriesScene", "plan_series", "simulate_series"]

#: (name, longitude, latitude in degrees): four of seed 003's validation sites and the fixture's
DEFAULT_SITES = (
    ("zhengzhou", 113.65, 34.75),
    ("huairou", 116.63, 40.32),
    ("dalian", 121.60, 38.91),
    ("hohhot", 111.75, 40.84),
    ("provence", 5.50, 44.50),
)

ARCSEC = math.pi / (180.0 * 3600.0)


@dataclass(frozen=True)
class SeriesScene:
    """One planned acquisition of a series.

    Attributes
    ----------
    name : str
        ``"NN_site_YYYYMMDD"`` (also the scene's folder name).
    site : str
    config : SimConfig
        The scene's configuration: ``base_config`` with its centre, epoch, attitude bias and
        cloud cover replaced.
    reference_seed : int
        Seed of the site's procedural reference.
    """

    name: str
    site: str
    config: SimConfig
    reference_seed: int

    def expected_offset_px(self, base: SimConfig) -> dict:
        """Mean check-point residual (row, col, px) predicted from the bias difference to ``base``.

        See the module notes; ``planar`` is the length of (row, col), ``yaw_edge`` the
        displacement the yaw difference adds at the swath edges.

        Parameters
        ----------
        base : SimConfig
            The calibration scene's configuration (its attitude bias).

        Returns
        -------
        dict
            ``row``, ``col``, ``planar``, ``yaw_edge`` in pixels and
            ``bias_difference_arcsec`` (roll, pitch, yaw).
        """
        d = (np.asarray(self.config.errors.attitude_bias_arcsec) - np.asarray(base.errors.attitude_bias_arcsec)) * ARCSEC
        s = self.config.scene
        px_per_rad = s.altitude_m / s.gsd_m
        cam = self.config.camera
        half_swath_px = 0.5 * cam.n_cameras * cam.ccds_per_camera * (cam.detectors_per_ccd - cam.overlap_detectors)
        row, col = float(-d[1] * px_per_rad), float(d[0] * px_per_rad)
        return {"row": row, "col": col, "planar": math.hypot(row, col),
                "yaw_edge": float(d[2] * half_swath_px),
                "bias_difference_arcsec": (d / ARCSEC).tolist()}


def _check_sites(sites) -> tuple:
    out, names = [], set()
    for k, item in enumerate(sites):
        try:
            name, lon, lat = item
            lon, lat = float(lon), float(lat)
        except (TypeError, ValueError):
            raise InputError(f"site {k}: expected (name, lon_deg, lat_deg), got {item!r}", field="sites") from None
        name = str(name)
        if not name or not name.replace("_", "").replace("-", "").isalnum() or name in names:
            raise InputError(f"site {k}: names must be distinct, alphanumeric (- and _ allowed), got {name!r}",
                             field="sites")
        names.add(name)
        out.append((name, lon, lat))
    if not out:
        raise InputError("give at least one site", field="sites")
    return tuple(out)


def plan_series(n_scenes: int, *, base_config: SimConfig | None = None, seed: int = 0, sites=DEFAULT_SITES,
                cloud_fractions=(0.0, 0.0, 0.0, 0.3), attitude_bias_sigma_arcsec=(28.0, 14.0, 20.0),
                center_jitter_deg: float = 0.02, revisit_days=(3, 16)) -> list[SeriesScene]:
    """The acquisitions :func:`simulate_series` renders (no file is written).

    Parameters
    ----------
    n_scenes : int
        Number of validation scenes (>= 1).
    base_config : SimConfig, optional
        The sensor and the calibration scene's acquisition (default: :class:`SimConfig`, the
        embedded fixture's sensor).
    seed : int
        Seed of the per-scene draws and of the references (not of the sensor).
    sites : sequence of (name, lon_deg, lat_deg)
    cloud_fractions : sequence of float
        Cloud cover of scene ``k`` is ``cloud_fractions[k % len]``.
    attitude_bias_sigma_arcsec : (3,) floats
        Standard deviations of the per-scene bias about the base bias (roll, pitch, yaw).
        The defaults give about 1.8 px along and 3.5 px across track at 30 m (seed 003 table 5:
        1.9 and 3.7 px).
    center_jitter_deg : float
        Half-width of the uniform jitter of each scene's centre about its site.
    revisit_days : (int, int)
        Range (inclusive) of the days between consecutive scenes.

    Returns
    -------
    list of SeriesScene
        ``n_scenes`` acquisitions, in date order.
    """
    base = (base_config or SimConfig()).validate()
    if int(n_scenes) < 1:
        raise InputError(f"must be >= 1, got {n_scenes}", field="n_scenes")
    if int(seed) < 0:
        raise InputError("must be >= 0", field="seed")
    sites = _check_sites(sites)
    clouds = [float(c) for c in cloud_fractions] or [0.0]
    if any(not 0.0 <= c <= 1.0 for c in clouds):
        raise InputError("cloud fractions must lie in [0, 1]", field="cloud_fractions")
    sigma = np.asarray(attitude_bias_sigma_arcsec, dtype=np.float64)
    if sigma.shape != (3,) or np.any(sigma < 0) or not np.all(np.isfinite(sigma)):
        raise InputError("must be three finite values >= 0 (roll, pitch, yaw)", field="attitude_bias_sigma_arcsec")
    d0, d1 = (int(v) for v in revisit_days)
    if not 1 <= d0 <= d1:
        raise InputError("must be (low, high) with 1 <= low <= high", field="revisit_days")
    epoch = np.datetime64(base.scene.epoch_utc, "s")
    out = []
    for k in range(int(n_scenes)):
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), k]))
        site_index = k % len(sites)
        site, lon, lat = sites[site_index]
        epoch = epoch + np.timedelta64(int(rng.integers(d0, d1 + 1)) * 86400, "s")
        jitter = rng.uniform(-center_jitter_deg, center_jitter_deg, 2)
        bias = np.asarray(base.errors.attitude_bias_arcsec) + rng.normal(0.0, 1.0, 3) * sigma
        cfg = replace(
            base,
            scene=replace(base.scene, center_lon_deg=float(np.clip(lon + jitter[0], -180.0, 180.0)),
                          center_lat_deg=float(lat + jitter[1]), epoch_utc=str(epoch),
                          acquisition_seed=int(rng.integers(0, 2**31 - 1))),
            errors=replace(base.errors, attitude_bias_arcsec=tuple(float(b) for b in bias)),
            clouds=replace(base.clouds, cover=clouds[k % len(clouds)]),
        ).validate()
        day = str(epoch)[:10].replace("-", "")
        ref_seed = int(np.random.SeedSequence([int(seed), 1_000_003, site_index]).generate_state(1)[0] >> 1)
        out.append(SeriesScene(f"{k + 1:02d}_{site}_{day}", site, cfg, ref_seed))
    return out


def _site_reference(scenes: list[SeriesScene], out_dir: Path) -> tuple[Path, Path]:
    """One procedural DOM and DEM covering the TRUE footprints of ``scenes`` (one site)."""
    from sensor_models.simulate.procedural import generate_reference
    from sensor_models.simulate.pushbroom_sim import footprint_lonlat
    from sensor_models.simulate.scene import build_models

    ref = scenes[0].config.reference
    h_lo, h_hi = ref.mean_height_m - ref.relief_m - 100.0, ref.mean_height_m + ref.relief_m + 100.0
    lons, lats = [], []
    for sc in scenes:
        lon, lat = footprint_lonlat(build_models(sc.config).true_model, (h_lo, h_hi))
        lons.append(lon)
        lats.append(lat)
    lon, lat = np.concatenate(lons), np.concatenate(lats)
    zone = int(np.floor((lon.mean() + 180.0) / 6.0)) % 60 + 1
    crs = pyproj.CRS.from_epsg((32600 if lat.mean() >= 0 else 32700) + zone)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    cx, cy = 0.5 * (np.min(x) + np.max(x)), 0.5 * (np.min(y) + np.max(y))
    clon, clat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(cx, cy)
    data = generate_reference(
        float(clon), float(clat), float(np.ptp(x)) + 2.0 * ref.margin_m, float(np.ptp(y)) + 2.0 * ref.margin_m,
        seed=scenes[0].reference_seed, dom_resolution_m=ref.dom_resolution_m, dem_resolution_m=ref.dem_resolution_m,
        relief_m=ref.relief_m, mean_height_m=ref.mean_height_m, sea_fraction=ref.sea_fraction,
    )
    return data.write(out_dir)


def _sites_documents(entries: list[dict]) -> tuple[str, str]:
    """YAML and CSV texts of the sites file (``name, scene, dom, dem, site``)."""
    import yaml

    text = "# gcpcal validation sites: one scene per entry; paths relative to this file\n"
    text += yaml.safe_dump(entries, sort_keys=False, default_flow_style=False)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(entries[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(entries)
    return text, buf.getvalue()


def simulate_series(out_dir, n_scenes: int, *, base_config: SimConfig | None = None, seed: int = 0,
                    sites=DEFAULT_SITES, cloud_fractions=(0.0, 0.0, 0.0, 0.3),
                    attitude_bias_sigma_arcsec=(28.0, 14.0, 20.0), center_jitter_deg: float = 0.02,
                    revisit_days=(3, 16), calibration_scene: bool = False, workers: int | None = None,
                    progress=None) -> list[Path]:
    """Render a validation series of one sensor and write its sites file (module docstring).

    Parameters
    ----------
    out_dir : str or os.PathLike
    n_scenes : int
    base_config, seed, sites, cloud_fractions, attitude_bias_sigma_arcsec, center_jitter_deg, revisit_days
        As in :func:`plan_series`.
    calibration_scene : bool
        Also render ``base_config`` itself into ``out_dir/calibration`` (a scene to calibrate
        the sensor on, with its own procedural reference).
    workers : int or None
        Rendering threads per scene (None: ``GCPCAL_THREADS`` or every core).
    progress : callable, optional
        ``progress(done, total, name)`` after each scene.

    Returns
    -------
    list of Path
        The manifests of the validation scenes, in order (``sites.yaml`` lists the same).
    """
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    base = (base_config or SimConfig()).validate()
    plan = plan_series(n_scenes, base_config=base, seed=seed, sites=sites, cloud_fractions=cloud_fractions,
                       attitude_bias_sigma_arcsec=attitude_bias_sigma_arcsec, center_jitter_deg=center_jitter_deg,
                       revisit_days=revisit_days)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    total = len(plan) + int(bool(calibration_scene))
    done = 0
    if calibration_scene:
        simulate_pushbroom(out_dir / "calibration", config=base, workers=workers, record_timings=False)
        done += 1
        if progress:
            progress(done, total, "calibration")
    references = {}
    for site in dict.fromkeys(sc.site for sc in plan):
        group = [sc for sc in plan if sc.site == site]
        references[site] = _site_reference(group, out_dir / "references" / site)
    manifests, entries, records = [], [], []
    for sc in plan:
        dom, dem = references[sc.site]
        scene_dir = out_dir / "scenes" / sc.name
        summary = simulate_pushbroom(scene_dir, config=sc.config, dom=dom, dem=dem, workers=workers,
                                     record_timings=False)
        manifests.append(scene_dir / "manifest.json")
        entries.append({"name": sc.name, "scene": f"scenes/{sc.name}/manifest.json",
                        "dom": f"references/{sc.site}/{dom.name}", "dem": f"references/{sc.site}/{dem.name}",
                        "site": sc.site})
        s = sc.config.scene
        records.append({
            "name": sc.name, "site": sc.site, "center_lon_deg": s.center_lon_deg, "center_lat_deg": s.center_lat_deg,
            "epoch_utc": s.epoch_utc, "attitude_bias_arcsec": list(sc.config.errors.attitude_bias_arcsec),
            "cloud_cover": sc.config.clouds.cover, "cloud_fraction": summary["cloud_fraction"],
            "reference_seed": sc.reference_seed, "expected_offset_px": sc.expected_offset_px(base),
            "lab_truth_error_px": summary["lab_truth_error_px"],
        })
        done += 1
        if progress:
            progress(done, total, sc.name)
    yaml_text, csv_text = _sites_documents(entries)
    atomic_write_text(out_dir / "sites.yaml", yaml_text)
    atomic_write_text(out_dir / "sites.csv", csv_text)
    doc = {"format_version": 1, "kind": "gcpcal.simulate.series", "seed": int(seed), "sensor_seed": base.seed,
           "calibration_scene": "calibration/manifest.json" if calibration_scene else None,
           "base_config": base.to_dict(), "scenes": records}
    atomic_write_text(out_dir / "series.json", json.dumps(doc, indent=1) + "\n")
    return manifests
