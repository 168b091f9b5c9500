"""Benchmark the push-broom scene simulator: render throughput and peak memory.

The issue's case: 6000 lines, 2 cameras x 2 CCDs of 2048 detectors, 4 bands (196 M pixels),
2 workers. The DOM (15 m, uint16) and DEM (30 m) are written to a temporary folder first (not
timed) so the render reads the DOM by windows as it would a real file; ``--procedural`` uses
the procedural generator instead (its time is reported separately).

Usage: ``python bench/bench_simulate.py [--rows 6000] [--detectors 2048] [--workers 2]``
Writes ``bench/results/simulate.json``.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def write_reference(cfg, folder: Path) -> tuple[Path, Path]:
    """A DOM (15 m, uint16, tiled, DEFLATE) and a DEM (30 m, ellipsoidal heights) under the scene of
    ``cfg``, written into ``folder``: ``(dom path, dem path)``."""
    import cv2
    import pyproj
    import rasterio
    from affine import Affine

    from sensor_models.simulate.pushbroom_sim import footprint_lonlat
    from sensor_models.simulate.scene import build_models

    model = build_models(cfg).true_model
    lon, lat = footprint_lonlat(model, (-500.0, 2500.0))
    crs = pyproj.CRS.from_epsg(32631)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
    x0, x1, y0, y1 = min(x) - 2000, max(x) + 2000, min(y) - 2000, max(y) + 2000
    nx, ny = int((x1 - x0) / 15), int((y1 - y0) / 15)
    rng = np.random.default_rng(1)
    coarse = rng.normal(0, 1, (ny // 8 + 2, nx // 8 + 2)).astype(np.float32)
    img = cv2.resize(coarse, (nx, ny), interpolation=cv2.INTER_CUBIC)
    img = np.clip(1500 + 500 * img + rng.normal(0, 150, (ny, nx)).astype(np.float32), 0, 4095)
    dom, dem = folder / "dom.tif", folder / "dem.tif"
    with rasterio.open(dom, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="uint16", crs=crs.to_wkt(),
                       transform=Affine(15, 0, x0, 0, -15, y1), tiled=True, compress="deflate") as ds:
        ds.write(img.astype(np.uint16), 1)
    dz = cv2.resize(rng.normal(0, 1, (ny // 60 + 2, nx // 60 + 2)).astype(np.float32), (nx // 2, ny // 2),
                    interpolation=cv2.INTER_CUBIC)
    with rasterio.open(dem, "w", driver="GTiff", width=nx // 2, height=ny // 2, count=1, dtype="float32",
                       crs=crs.to_wkt(), transform=Affine(30, 0, x0, 0, -30, y1)) as ds:
        ds.write(800 + 400 * dz, 1)
        ds.update_tags(VERTICAL_DATUM="ellipsoid")
    return dom, dem


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=6000)
    ap.add_argument("--detectors", type=int, default=2048)
    ap.add_argument("--gsd", type=float, default=16.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--procedural", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "simulate.json", help="JSON written")
    args = ap.parse_args()

    from sensor_models.simulate.config import SimConfig
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    cfg = SimConfig()
    cfg = replace(cfg, scene=replace(cfg.scene, n_rows=args.rows, gsd_m=args.gsd),
                  camera=replace(cfg.camera, detectors_per_ccd=args.detectors, overlap_detectors=16)).validate()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        dom = dem = None
        t0 = time.perf_counter()
        if not args.procedural:
            dom, dem = write_reference(cfg, tmp)
            print(f"reference written: {dom.name}, {dem.name} in {time.perf_counter() - t0:.1f} s")
        summary = simulate_pushbroom(tmp / "scene", config=cfg, dom=dom, dem=dem, workers=args.workers)
    img = summary["image"]
    pixels = img["n_rows"] * img["n_cols"] * len(img["bands"])
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    result = {
        "rows": img["n_rows"], "cols": img["n_cols"], "bands": len(img["bands"]), "pixels": pixels,
        "workers": args.workers, "render_seconds": summary["render_seconds"],
        "total_seconds": summary["seconds"], "pixels_per_second": summary["pixels_per_second"],
        "peak_rss_gb": peak_gb, "target_seconds": 60.0, "procedural": args.procedural,
    }
    print(json.dumps(result, indent=1))
    out = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
