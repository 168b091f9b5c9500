"""Benchmark: orthorectification of large scenes into Cloud-Optimized GeoTIFFs.

Synthetic HY-1C-like push-broom scenes (4 CCDs, 10 m GSD, jittered attitude; uint16 rasters of
a repeated random texture, tiled) over a synthetic geographic DEM (150 m nodes, 200 - 1700 m of
relief) are orthorectified with :func:`sensor_models.imaging.ortho.orthorectify_to_file` near their
GSD. Three cases double the scene side each time; the largest (``--scene``) gives an output of
``--side`` pixels on its longer side (the footprint's bounding box; the scene is rotated by the
orbit's heading).

Every case runs in a fresh process and reports its peak resident memory (``VmHWM``) and the
part the orthorectification added after the model and DEM were loaded
(``/proc/self/clear_refs`` resets the peak): bounded memory means these do not grow with the
output size. Side by side: exact inverse localization (``model.ground_to_image``) points/s on
the same machine in the same run, and the ratio of the pipeline's output pixels/s to it.

One core: BLAS and OpenCV threads pinned to 1, GDAL single-threaded.

Usage: ``python bench/bench_ortho.py [--side 20000] [--scene 16400] [--block 1024] [--out FILE]``
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
IFOV_RAD = 10.0 / 782_121.0
OVERLAP = 16


def build_model(scene: int):
    from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model

    design = CameraDesign(n_ccds=4, detectors_per_ccd=scene // 4, ifov_rad=IFOV_RAD, ccd_overlap_detectors=OVERLAP)
    return example_pushbroom_model(n_rows=scene, design=design, attitude_kwargs={
        "jitter_amplitude_rad": (2e-6, 2e-6, 0.0), "jitter_frequency_hz": 0.7, "seed": 0})


def build_dem():
    from rasterio.transform import from_origin

    from sensor_models.terrain.dem import Dem

    step = 1.0 / 720.0  # ~150 m
    n_rows, n_cols = int(2.4 / step), int(3.4 / step)
    lat = 45.7 - step * (np.arange(n_rows) + 0.5)
    lon = 3.8 + step * (np.arange(n_cols) + 0.5)
    hills = np.sin(np.radians(lat)[:, None] * 900.0) * np.cos(np.radians(lon)[None, :] * 700.0)
    heights = 950.0 + 750.0 * hills
    return Dem.from_array(heights, from_origin(3.8, 45.7, step, step), "EPSG:4326")


def write_source(path: Path, scene: int):
    """A tiled, uncompressed uint16 raster: one 512 x 512 random tile repeated."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.windows import Window

    from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES

    warnings.simplefilter("ignore", NotGeoreferencedWarning)  # scene geometry: no georeferencing
    tile = np.random.default_rng(0).integers(200, 4000, size=(512, 512), dtype=np.uint16)
    profile = dict(driver="GTiff", width=scene, height=scene, count=1, dtype="uint16", tiled=True,
                   blockxsize=512, blockysize=512, BIGTIFF="IF_SAFER")
    with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES), rasterio.open(path, "w", **profile) as dst:
        for r in range(0, scene, 512):
            for c in range(0, scene, 512):
                h, w = min(512, scene - r), min(512, scene - c)
                dst.write(tile[:h, :w], 1, window=Window(c, r, w, h))


def _status(key: str) -> float:
    """``VmRSS`` / ``VmHWM`` of this process in MiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def worker(args):
    """One case in this (fresh) process; prints one JSON line."""
    import cv2

    from sensor_models.imaging.ortho import orthorectify_to_file
    from sensor_models.imaging.ortho_grid import ortho_grid

    cv2.setNumThreads(1)
    model = build_model(args.scene)
    dem = build_dem()
    grid = ortho_grid(model, dem)
    resolution = grid.transform.a * max(grid.shape) / args.target
    out = Path(args.tmp) / f"ortho_{args.target}.tif"
    Path("/proc/self/clear_refs").write_text("5\n")  # reset the peak (VmHWM) to the current RSS
    base = _status("VmRSS")
    summary = orthorectify_to_file(model, args.source, dem, out, resolution_m=resolution, block=args.block)
    peak = _status("VmHWM")
    result = {
        "output_shape": summary["shape"],
        "output_pixels": summary["shape"][0] * summary["shape"][1],
        "resolution_m": summary["resolution_m"],
        "valid_fraction": summary["valid_fraction"],
        "seconds": summary["seconds"],
        "cog_seconds": summary["cog_seconds"],
        "pixels_per_s": summary["pixels_per_s"],
        "valid_pixels_per_s": summary["pixels_per_s"] * summary["valid_fraction"],
        "node_step_out_px": summary["node_step_out_px"],
        "geometry_check_max_px": summary["geometry_check_max_px"],
        "geometry_check_rms_px": summary["geometry_check_rms_px"],
        "file_mib": out.stat().st_size / 2**20,
        "rss_before_mib": base,
        "peak_rss_mib": peak,
        "peak_added_mib": peak - base,
    }
    result["scene_px"] = [args.scene, args.scene]
    out.unlink()
    print(json.dumps(result))


def exact_rate(scene: int, n: int = 200_000) -> float:
    """Points/s of exact inverse localization on the bench scene."""
    model = build_model(scene)
    rng = np.random.default_rng(1)
    rows, cols = rng.uniform(0, scene, n), rng.uniform(0, scene, n)
    lon, lat, _ = model.image_to_ground(rows, cols, height=900.0)
    t0 = time.perf_counter()
    model.ground_to_image(lon, lat, np.full(n, 900.0))
    return n / (time.perf_counter() - t0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--side", type=int, default=20000, help="Output side of the finest case, px.")
    ap.add_argument("--scene", type=int, default=16400, help="Scene side, px (4 CCDs).")
    ap.add_argument("--block", type=int, default=1024)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "ortho.json")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--target", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--source", help=argparse.SUPPRESS)
    ap.add_argument("--tmp", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(args)
        return
    tmp = Path(tempfile.mkdtemp(prefix="bench_ortho_"))
    try:
        rate = exact_rate(args.scene)
        print(f"exact ground_to_image: {rate:,.0f} points/s")
        cases = []
        for k in (4, 2, 1):
            scene, target = args.scene // k, args.side // k
            source = tmp / f"scene_{scene}.tif"
            write_source(source, scene)
            cmd = [sys.executable, __file__, "--worker", "--target", str(target), "--source", str(source),
                   "--tmp", str(tmp), "--scene", str(scene), "--block", str(args.block)]
            res = subprocess.run(cmd, capture_output=True, text=True, check=False)
            source.unlink()
            if res.returncode != 0:
                raise SystemExit(f"case {target} failed:\n{res.stderr}")
            case = json.loads(res.stdout.strip().splitlines()[-1])
            case["ratio_to_exact"] = case["pixels_per_s"] / rate
            cases.append(case)
            rows, cols = case["output_shape"]
            print(f"scene {scene:>5} px -> {cols:>6} x {rows:<6} px at {case['resolution_m']:5.2f} m: "
                  f"{case['seconds']:6.1f} s (COG copy {case['cog_seconds']:5.1f} s), "
                  f"{case['pixels_per_s'] / 1e6:5.2f} Mpx/s ({case['ratio_to_exact']:.1f}x exact), peak RSS "
                  f"{case['peak_rss_mib']:.0f} MiB (+{case['peak_added_mib']:.0f} after loading), "
                  f"geometry max {case['geometry_check_max_px']:.4f} px")
        pixels = cases[-1]["output_pixels"] / cases[0]["output_pixels"]
        added = [c["peak_added_mib"] for c in cases]
        print(f"{pixels:.0f}x more output pixels: memory added by the orthorectification "
              f"{added[0]:.0f} -> {added[-1]:.0f} MiB")
        result = {
            "benchmark": "ortho",
            "machine": {"platform": platform.platform(), "python": platform.python_version(), "cores_used": 1},
            "block_px": args.block,
            "exact_ground_to_image_points_per_s": rate,
            "cases": cases,
            "output_pixels_growth": pixels,
            "peak_added_mib": added,
        }
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
