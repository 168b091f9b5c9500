"""Benchmark: GCP table IO (CSV, GeoPackage, GeoTIFF): seconds to write and read N points.

Prints wall and CPU seconds per step (CPU time is the fairer figure on a shared machine) and
writes JSON (default ``bench/results/gcps_io.json``). One core (BLAS threads pinned to 1).

Usage: ``python bench/bench_gcps.py [--points 1000000] [--tiff-points 10922] [--out FILE]``
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from gcpmatch.gcp_csv import write_gcps_csv  # noqa: E402
from gcpmatch.gcp_files import read_gcps  # noqa: E402
from gcpmatch.gcp_geotiff import GEOTIFF_MAX_GCPS, write_gcps_geotiff  # noqa: E402
from gcpmatch.gcps import GcpTable  # noqa: E402
from gcpmatch.geopackage import write_gcps_gpkg  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def example_table(n: int, seed: int = 0) -> GcpTable:
    rng = np.random.default_rng(seed)
    return GcpTable.from_arrays(
        rng.uniform(0, 20000, n), rng.uniform(0, 30000, n), rng.uniform(5, 6, n),
        rng.uniform(44, 45, n), rng.uniform(0, 3000, n), sigma_px=rng.uniform(0.2, 1, n),
        band=np.where(rng.random(n) < 0.5, "B1", "B2"), ccd=np.where(rng.random(n) < 0.5, "1", "2"),
        score=rng.random(n), kind=np.where(rng.random(n) < 0.2, "check", "gcp"),
    )


def timed(func, *args, **kwargs):
    w0, c0 = time.perf_counter(), time.process_time()
    out = func(*args, **kwargs)
    return time.perf_counter() - w0, time.process_time() - c0, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--tiff-points", type=int, default=GEOTIFF_MAX_GCPS)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "gcps_io.json"))
    args = ap.parse_args()
    res = {"points": args.points, "tiff_points": args.tiff_points}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        *_, table = timed(example_table, args.points)
        steps = [
            ("construct", lambda: GcpTable(**table.as_dict())),
            ("csv_write", lambda: write_gcps_csv(table, d / "g.csv")),
            ("csv_read", lambda: read_gcps(d / "g.csv")),
            ("gpkg_write", lambda: write_gcps_gpkg(table, d / "g.gpkg")),
            ("gpkg_read", lambda: read_gcps(d / "g.gpkg")),
        ]
        small = table.select(np.arange(min(args.tiff_points, args.points)))
        steps += [
            ("tiff_write", lambda: write_gcps_geotiff(small, d / "g.tif", image_shape=(20000, 30000))),
            ("tiff_read", lambda: read_gcps(d / "g.tif")),
        ]
        for name, func in steps:
            wall, cpu, _ = timed(func)
            res[f"{name}_wall_s"], res[f"{name}_cpu_s"] = round(wall, 3), round(cpu, 3)
            print(f"{name:12s} wall {wall:7.3f} s   cpu {cpu:7.3f} s")
        for ext in ("csv", "gpkg", "tif"):
            res[f"{ext}_MB"] = round((d / f"g.{ext}").stat().st_size / 1e6, 2)
    res["max_rss_MB"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(res))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
