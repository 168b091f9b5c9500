"""Benchmark: peak resident memory and wall time of ``gcpcal ortho`` and ``gcpcal simulate pushbroom``.

Each measured command runs as a child process (the CLI a user runs, with ``PYTHONPATH`` set to
the code under test, ``--code``), and its peak RSS is the ``ru_maxrss`` that ``os.wait4`` returns
for that child; the inputs are prepared beforehand in this process (not measured). Sizes are
``ROWSxCOLS`` of the level-1A scene (default: the issue's 6000 x 4096 and 20000 x 20000).

What runs at each size (all synthetic, seeded; the files go to ``--tmp``):

* ``ortho``: a 4-CCD push-broom model (``sensor_models.models.synthetic.example_pushbroom_model``, GSD
  ``--gsd``; 30 m at 6000 x 4096 as in the issue, 10 m at 20000 x 20000) written as a manifest;
  its raster is uint16, tiled, a 512 x 512 random tile repeated; the DEM is a geographic float32
  GeoTIFF with 1 arc-second nodes (SRTM-1 spacing, ~30 m) over the footprint plus 0.05 degrees,
  smooth hills of 200 - 1700 m, ``VERTICAL_DATUM=ellipsoid``.
  Command: ``gcpcal ortho MANIFEST --dem DEM --out OUT.tif --block 1024`` (the scene's GSD).
* ``simulate``: ``gcpcal simulate pushbroom --config CFG --dom DOM --dem DEM --workers 2`` with
  the default camera (2 cameras x 2 CCDs) of ``COLS / 4`` detectors per CCD, ``ROWS`` lines, the
  same GSD; the DOM is a uint16 tiled UTM raster at twice the GSD's resolution (half the pixel
  size), the DEM a 3 arc-second (~90 m, SRTM-3 spacing; ``--sim-dem-arcsec``) geographic
  GeoTIFF. At 20000 x 20000 the configuration is the cheap one: one band (``B2``) instead of
  four, and the DOM at the GSD.
* ``simulate-procedural`` (only when asked, ``--which``): the same configuration without
  ``--dom``/``--dem``, so the simulator generates its procedural reference (the issue's command).

Usage::

    python bench/bench_memory.py [--sizes 6000x4096,20000x20000] [--which ortho,simulate]
        [--code ROOT] [--label after] [--out bench/results/memory.json]

Run it once with ``--code`` at a checkout of the code before the change (``--label before``)
and once at this one (``--label after``); each run merges its label into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ORBIT_ALTITUDE_M = 782_121.0
#: ground sampling distance (m) of each bench size
GSD_M = {"6000x4096": 30.0, "20000x20000": 10.0}


# ---------------------------------------------------------------- inputs
def _size(text: str) -> tuple[int, int]:
    rows, cols = (int(v) for v in text.lower().split("x"))
    return rows, cols


def _gsd(size: str) -> float:
    return GSD_M.get(size, 30.0)


def build_model(rows: int, cols: int, gsd_m: float):
    """The 4-CCD push-broom model of the ortho case (image ``rows x cols``)."""
    from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model

    design = CameraDesign(n_ccds=4, detectors_per_ccd=cols // 4, ifov_rad=gsd_m / ORBIT_ALTITUDE_M,
                          ccd_overlap_detectors=16)
    return example_pushbroom_model(n_rows=rows, design=design)


def write_tiled_uint16(path: Path, rows: int, cols: int, *, crs=None, transform=None, seed: int = 0) -> None:
    """A tiled uint16 raster: one 512 x 512 random tile (200 - 4000 DN) repeated."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.windows import Window

    from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES

    tile = np.random.default_rng(seed).integers(200, 4000, size=(512, 512), dtype=np.uint16)
    profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype="uint16", tiled=True, blockxsize=512,
                   blockysize=512, BIGTIFF="IF_SAFER")
    if crs is not None:
        profile.update(crs=crs, transform=transform)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES), rasterio.open(path, "w", **profile) as dst:
            for r in range(0, rows, 512):
                for c in range(0, cols, 512):
                    h, w = min(512, rows - r), min(512, cols - c)
                    dst.write(tile[:h, :w], 1, window=Window(c, r, w, h))


def write_dem(path: Path, lon_range, lat_range, step_deg: float) -> tuple[int, int]:
    """A geographic float32 DEM of smooth hills (ellipsoidal heights) written by strips."""
    import rasterio
    from rasterio.transform import from_origin
    from rasterio.windows import Window

    lon0, lon1 = lon_range[0] - 0.05, lon_range[1] + 0.05
    lat0, lat1 = lat_range[0] - 0.05, lat_range[1] + 0.05
    n_rows, n_cols = int(np.ceil((lat1 - lat0) / step_deg)), int(np.ceil((lon1 - lon0) / step_deg))
    profile = dict(driver="GTiff", width=n_cols, height=n_rows, count=1, dtype="float32", crs="EPSG:4326",
                   transform=from_origin(lon0, lat1, step_deg, step_deg), tiled=True, BIGTIFF="IF_SAFER")
    lon = lon0 + step_deg * (np.arange(n_cols) + 0.5)
    with rasterio.open(path, "w", **profile) as dst:
        for r in range(0, n_rows, 512):
            h = min(512, n_rows - r)
            lat = lat1 - step_deg * (r + np.arange(h) + 0.5)
            hills = np.sin(np.radians(lat)[:, None] * 900.0) * np.cos(np.radians(lon)[None, :] * 700.0)
            dst.write((950.0 + 750.0 * hills).astype(np.float32), 1, window=Window(0, r, n_cols, h))
        dst.update_tags(VERTICAL_DATUM="ellipsoid")
    return n_rows, n_cols


def prepare_ortho(folder: Path, rows: int, cols: int, gsd_m: float) -> dict:
    """Manifest, raster and 1" DEM of the ortho case; returns what was written."""
    from sensor_models.readers.manifest import write_manifest
    from sensor_models.simulate.render_io import footprint_lonlat

    model = build_model(rows, cols, gsd_m)
    image = folder / "scene_B2.tif"
    write_tiled_uint16(image, *model.image_shape)
    manifest = write_manifest(model, folder / "manifest.json", rasters={b: image for b in model.bands})
    lon, lat = footprint_lonlat(model, (200.0, 1700.0))
    dem_shape = write_dem(folder / "dem_1s.tif", (lon.min(), lon.max()), (lat.min(), lat.max()), 1.0 / 3600.0)
    return {"manifest": str(manifest), "dem": str(folder / "dem_1s.tif"), "image_shape": list(model.image_shape),
            "dem_nodes": list(dem_shape), "gsd_m": gsd_m}


def simulate_config(rows: int, cols: int, gsd_m: float, cheap: bool):
    """The simulator's configuration of a bench size (one band when ``cheap``)."""
    from dataclasses import replace

    from sensor_models.simulate.config import SimConfig

    cfg = SimConfig()
    camera = replace(cfg.camera, detectors_per_ccd=cols // 4, overlap_detectors=16)
    radiometry = cfg.radiometry
    if cheap:
        camera = replace(camera, bands=("B2",), band_offsets_px=(0.0,), reference_band="B2")
        radiometry = replace(radiometry, band_gain=(1.0,), band_offset_dn=(40.0,), band_gamma=(1.0,))
    return replace(cfg, scene=replace(cfg.scene, n_rows=rows, gsd_m=gsd_m), camera=camera,
                   radiometry=radiometry).validate()


def prepare_simulate(folder: Path, rows: int, cols: int, gsd_m: float, cheap: bool, dem_arcsec: float = 3.0) -> dict:
    """Configuration, DOM (UTM, half the GSD) and 3" DEM of the simulate case."""
    import pyproj
    from affine import Affine

    from sensor_models.simulate.render_io import footprint_lonlat
    from sensor_models.simulate.scene import build_models

    cfg = simulate_config(rows, cols, gsd_m, cheap)
    (folder / "config.json").write_text(json.dumps(cfg.to_dict(), indent=1))
    model = build_models(cfg).true_model
    lon, lat = footprint_lonlat(model, (-500.0, 2500.0))
    crs = pyproj.CRS.from_epsg(32631)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
    res = gsd_m if cheap else 0.5 * gsd_m
    x0, y1 = float(np.min(x)) - 3000.0, float(np.max(y)) + 3000.0
    nx, ny = int((np.max(x) + 3000.0 - x0) / res), int((y1 - np.min(y) + 3000.0) / res)
    write_tiled_uint16(folder / "dom.tif", ny, nx, crs=crs.to_wkt(), transform=Affine(res, 0, x0, 0, -res, y1), seed=1)
    dem = folder / f"dem_{dem_arcsec:g}s.tif"
    dem_shape = write_dem(dem, (lon.min(), lon.max()), (lat.min(), lat.max()), dem_arcsec / 3600.0)
    return {"config": str(folder / "config.json"), "dom": str(folder / "dom.tif"), "dem": str(dem),
            "dem_arcsec": dem_arcsec,
            "dom_px": [ny, nx], "dem_nodes": list(dem_shape), "bands": list(cfg.camera.bands), "gsd_m": gsd_m}


# ---------------------------------------------------------------- measurement
def run_child(cmd: list[str], code: Path, timeout_s: float) -> dict:
    """Run ``cmd`` (``PYTHONPATH=code``) from a fresh intermediate process; its wall time and peak RSS.

    The intermediate process has one child, the command, so its ``RUSAGE_CHILDREN.ru_maxrss`` is
    the command's peak RSS."""
    probe = [sys.executable, __file__, "--measure-one", json.dumps({"cmd": cmd, "code": str(code),
                                                                    "timeout_s": timeout_s})]
    res = subprocess.run(probe, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"measurement failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _measure_one(spec: str) -> None:
    import resource

    spec = json.loads(spec)
    env = dict(os.environ, PYTHONPATH=spec["code"], OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    t0 = time.perf_counter()
    try:
        res = subprocess.run(spec["cmd"], cwd=spec["code"], env=env, capture_output=True, text=True,
                             timeout=spec["timeout_s"], check=False)
        status, out = res.returncode, (res.stdout + res.stderr)
    except subprocess.TimeoutExpired as exc:
        status, out = "timeout", str(exc.stdout or "")
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    print(json.dumps({"command": " ".join(spec["cmd"]), "exit_status": status, "wall_s": round(wall, 2),
                      "peak_rss_mib": round(peak, 1), "output_tail": out.strip().splitlines()[-3:]}))


def _gcpcal() -> list[str]:
    return [sys.executable, "-c", "import sys; from calibrate.cli import main; sys.exit(main())"]


def run_size(size: str, which, code: Path, tmp: Path, timeout_s: float, dem_arcsec: float = 3.0) -> dict:
    """Prepare and measure the cases of one size."""
    rows, cols = _size(size)
    gsd = _gsd(size)
    folder = tmp / size
    folder.mkdir(parents=True, exist_ok=True)
    cases = {}
    if "ortho" in which:
        inputs = prepare_ortho(folder, rows, cols, gsd)
        out = folder / "ortho.tif"
        cmd = _gcpcal() + ["ortho", inputs["manifest"], "--dem", inputs["dem"], "--out", str(out),
                               "--block", "1024"]
        cases["ortho"] = {"inputs": inputs, **run_child(cmd, code, timeout_s)}
        summary = out.with_suffix(".summary.json")
        if summary.is_file():
            doc = json.loads(summary.read_text())
            cases["ortho"]["output_shape"] = doc.get("shape")
            cases["ortho"]["dem_read"] = doc.get("dem_read", "whole")
        for p in (out, summary):
            p.unlink(missing_ok=True)
        print(f"{size} ortho: {cases['ortho']['peak_rss_mib']:.0f} MiB, {cases['ortho']['wall_s']:.0f} s")
    if "simulate" in which:
        cheap = rows * cols > 50_000_000
        inputs = prepare_simulate(folder, rows, cols, gsd, cheap, dem_arcsec)
        out = folder / "sim"
        shutil.rmtree(out, ignore_errors=True)
        cmd = _gcpcal() + ["simulate", "pushbroom", "--out", str(out), "--config", inputs["config"],
                               "--dom", inputs["dom"], "--dem", inputs["dem"], "--workers", "2"]
        cases["simulate"] = {"inputs": inputs, "cheap_configuration": cheap, **run_child(cmd, code, timeout_s)}
        summary = out / "summary.json"
        if summary.is_file():
            doc = json.loads(summary.read_text())
            cases["simulate"].update({k: doc.get(k) for k in ("render_seconds", "phase_seconds", "seconds")})
        shutil.rmtree(out, ignore_errors=True)
        print(f"{size} simulate: {cases['simulate']['peak_rss_mib']:.0f} MiB, {cases['simulate']['wall_s']:.0f} s")
    if "simulate-procedural" in which:
        cases["simulate-procedural"] = _procedural_case(folder, rows, cols, gsd, code, timeout_s)
    shutil.rmtree(folder, ignore_errors=True)
    return cases


def _procedural_case(folder: Path, rows: int, cols: int, gsd: float, code: Path, timeout_s: float) -> dict:
    """``gcpcal simulate pushbroom`` with its procedural reference (no --dom/--dem): the issue's command."""
    cfg = simulate_config(rows, cols, gsd, cheap=False)
    config = folder / "config_procedural.json"
    config.write_text(json.dumps(cfg.to_dict(), indent=1))
    out = folder / "sim_procedural"
    shutil.rmtree(out, ignore_errors=True)
    cmd = _gcpcal() + ["simulate", "pushbroom", "--out", str(out), "--config", str(config), "--workers", "2"]
    case = {"inputs": {"config": str(config), "reference": "procedural"}, **run_child(cmd, code, timeout_s)}
    summary = out / "summary.json"
    if summary.is_file():
        doc = json.loads(summary.read_text())
        case.update({k: doc.get(k) for k in ("render_seconds", "phase_seconds", "seconds")})
    shutil.rmtree(out, ignore_errors=True)
    print(f"{rows}x{cols} simulate (procedural reference): {case['peak_rss_mib']:.0f} MiB, {case['wall_s']:.0f} s")
    return case


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="6000x4096,20000x20000")
    ap.add_argument("--which", default="ortho,simulate")
    ap.add_argument("--code", type=Path, default=ROOT, help="Root of the code to measure (PYTHONPATH).")
    ap.add_argument("--label", default="after")
    ap.add_argument("--tmp", type=Path, default=Path("/tmp/bench_memory"))
    ap.add_argument("--timeout", type=float, default=3600.0, help="Seconds per command.")
    ap.add_argument("--sim-dem-arcsec", type=float, default=3.0, help="Node spacing of the simulate case's DEM.")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "memory.json")
    ap.add_argument("--measure-one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.measure_one:
        _measure_one(args.measure_one)
        return
    which = set(args.which.split(","))
    runs = {}
    for size in args.sizes.split(","):
        runs[size] = run_size(size, which, args.code.resolve(), args.tmp, args.timeout, args.sim_dem_arcsec)
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {"benchmark": "memory"}
    doc["machine"] = {"platform": platform.platform(), "python": platform.python_version(),
                      "cpus": os.cpu_count(), "note": "shared machine, 2 cores"}
    doc["measure"] = "peak RSS = ru_maxrss (RUSAGE_CHILDREN) of a process whose only child is the command"
    label = doc.setdefault(args.label, {})
    for size, cases in runs.items():
        label.setdefault(size, {}).update(cases)
    label["code"] = str(args.code.resolve())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
