"""Benchmark: batch validation of a calibration over simulated scenes, 1 versus 2 Dask workers.

The series: ``--scenes`` (default 12) acquisitions of the embedded fixture's sensor (HY-1C-like,
4 CCDs x 192 detectors, 512 lines, 4 bands; :func:`sensor_models.simulate.series.simulate_series`)
over five sites, one in four cloudy, cached in ``bench/results/batch_series/`` (regenerated when
its plan differs). The calibration: the fixture's reference band matched (dense GCPs) and
calibrated exterior-then-interior, cached beside it.

Each configuration runs :func:`calibrate.actions.validate.run_validation` end to end (LocalCluster start,
one task per scene matching the reference band and scoring the calibrated and LAB models,
outputs) with 1 and with 2 single-threaded worker processes, alternated ``--repeats`` times;
the best wall time of each gives the speed ratio (target >= 1.7 on 2 cores). The load average
before and after each run is recorded: the machine may be shared.

With ``--coarse-skip`` it instead validates each scene in this process with the coarse SIFT
stage always run and with it skipped when the model is within the fine radius, alternated, and
writes ``bench/results/batch_coarse_skip.json`` (times, skip notes, accuracy of both).

Usage: ``python bench/bench_batch.py [--scenes 12] [--repeats 2] [--out bench/results/batch.json] [--coarse-skip]``
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SERIES_SEED = 11


def series(out: Path, n_scenes: int) -> Path:
    """The cached validation series (sites.yaml path)."""
    from sensor_models.simulate.config import SimConfig
    from sensor_models.simulate.series import simulate_series

    doc_path = out / "series.json"
    if doc_path.is_file():
        doc = json.loads(doc_path.read_text())
        if doc.get("seed") == SERIES_SEED and len(doc.get("scenes", [])) == n_scenes \
                and doc.get("base_config") == SimConfig().to_dict():
            return out / "sites.yaml"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    simulate_series(out, n_scenes, seed=SERIES_SEED, workers=2,
                    progress=lambda d, t, name: print(f"  simulated {d}/{t} {name}", flush=True))
    print(f"series of {n_scenes} scenes simulated in {time.perf_counter() - t0:.1f} s")
    return out / "sites.yaml"


def calibration(out: Path) -> Path:
    """The fixture sensor's calibrated manifest (reference band), cached."""
    from calibrate.actions.calibrate import calibrate_scene
    from calibrate.actions.match import match_scene
    from gcpmatch.options import MatchOptions

    manifest = out / "manifest.json"
    if manifest.is_file():
        return manifest
    gcps = out.parent / f"{out.name}_gcps.csv"  # beside the output folder: calibrate refuses inputs inside it
    match_scene(FIXTURE / "manifest.json", dom_path=FIXTURE / "reference" / "dom.tif",
                dem_path=FIXTURE / "reference" / "dem.tif", out_path=gcps,
                options=MatchOptions(spacing_px=16))
    summary = calibrate_scene(FIXTURE / "manifest.json", gcps, out, report=False)
    print(f"calibrated the fixture sensor: check RMSE {summary['check_rmse_px']['before']:.1f} -> "
          f"{summary['check_rmse_px']['after']:.3f} px")
    return manifest


def run_once(sites, calib: Path, out: Path, workers: int) -> dict:
    from calibrate.actions.validate import run_validation

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    rows, summary = run_validation(sites, calib, out, workers=workers)
    wall = time.perf_counter() - t0
    return {
        "workers": workers,
        "wall_s": wall,
        "task_seconds_sum": summary["task_seconds"],
        "task_cpu_seconds_sum": summary["task_cpu_seconds"],
        # CPU the workers got per wall second: 1 worker at most 1, 2 workers at most 2
        "cores_used": summary["task_cpu_seconds"] / wall,
        "scenes_ok": summary["ok"],
        "scenes_failed": summary["failed"],
        "mean_planar_px": summary["mean"]["rmse_planar_px"],
        "mean_along_px": summary["mean"]["rmse_along_px"],
        "mean_across_px": summary["mean"]["rmse_across_px"],
        "load_average_before": list(load_before),
        "load_average_after": list(os.getloadavg()),
    }


def coarse_skip_compare(sites, calib: Path, repeats: int) -> dict:
    """Per scene, in this process: validation with the coarse SIFT stage always run (before)
    and skipped when the check allows (after), alternated; best times and accuracy of both."""
    from calibrate.batch import validate_scene

    per_scene, best = [], {"before": 0.0, "after": 0.0}
    for site in sites:
        t = {"before": float("inf"), "after": float("inf")}
        rows = {}
        for _ in range(repeats):
            for key, skip in (("before", False), ("after", True)):
                rows[key] = validate_scene(site, calib, threads=1, coarse_skip=skip)
                t[key] = min(t[key], rows[key]["seconds"])
        if rows["before"]["status"] != "ok" or rows["after"]["status"] != "ok":
            continue
        best["before"] += t["before"]
        best["after"] += t["after"]
        per_scene.append({"name": site.name, "seconds": t, "coarse": rows["after"]["coarse"],
                          "rmse_planar_px": {k: rows[k]["rmse_planar_px"] for k in rows},
                          "mean_along_px": {k: rows[k]["mean_along_px"] for k in rows},
                          "mean_across_px": {k: rows[k]["mean_across_px"] for k in rows},
                          "points": {k: rows[k]["points"] for k in rows}})
        print(f"  {site.name}: {t['before']:.2f} s -> {t['after']:.2f} s; planar "
              f"{rows['before']['rmse_planar_px']:.3f} -> {rows['after']['rmse_planar_px']:.3f} px; "
              f"{rows['after']['coarse']}", flush=True)
    return {"scenes": len(per_scene), "seconds_sum": best,
            "speedup": best["before"] / best["after"] if best["after"] else None,
            "skipped": sum(1 for p in per_scene if p["coarse"].startswith("coarse stage skipped")),
            "max_planar_rmse_change_px": max((abs(p["rmse_planar_px"]["after"] - p["rmse_planar_px"]["before"])
                                              for p in per_scene), default=None),
            "per_scene": per_scene}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=12)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None,
                        help="JSON written (default bench/results/batch.json, or batch_coarse_skip.json with --coarse-skip)")
    parser.add_argument("--coarse-skip", action="store_true",
                        help="compare validation with and without the coarse-stage skip (one process) "
                             "and write that comparison to --out instead")
    args = parser.parse_args()
    from calibrate.batch import read_sites

    results = ROOT / "bench" / "results"
    sites = read_sites(series(results / "batch_series", args.scenes))
    calib = calibration(results / "batch_calibration")
    if args.coarse_skip:
        doc = coarse_skip_compare(sites, calib, args.repeats)
        doc.update(command=f"python bench/bench_batch.py --coarse-skip --scenes {args.scenes} --repeats {args.repeats}",
                   machine=platform.platform(), cpu_count=os.cpu_count())
        out = args.out or results / "batch_coarse_skip.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"validation of {doc['scenes']} scenes: x{doc['speedup']:.2f} with the coarse skip "
              f"({doc['skipped']} skipped), planar RMSE changed by {doc['max_planar_rmse_change_px']:.3f} px at most; "
              f"wrote {out}")
        return
    runs = []
    for rep in range(args.repeats):
        for workers in (1, 2):
            r = run_once(sites, calib, results / "batch_validation" / f"w{workers}", workers)
            runs.append(r)
            print(f"repeat {rep + 1}, {workers} worker(s): {r['wall_s']:.1f} s wall, {r['task_seconds_sum']:.1f} s of "
                  f"tasks ({r['task_cpu_seconds_sum']:.1f} s CPU, {r['cores_used']:.2f} cores used), "
                  f"{r['scenes_ok']}/{len(sites)} ok, mean planar {r['mean_planar_px']:.3f} px; load "
                  f"{r['load_average_before'][0]:.2f} -> {r['load_average_after'][0]:.2f}", flush=True)
    best = {w: min(r["wall_s"] for r in runs if r["workers"] == w) for w in (1, 2)}
    ratio = best[1] / best[2]
    cpu = {w: min(r["task_cpu_seconds_sum"] for r in runs if r["workers"] == w) for w in (1, 2)}
    doc = {
        "benchmark": "batch",
        "scenes": len(sites),
        "best_wall_s": {"1": best[1], "2": best[2]},
        "speed_ratio_2_over_1": ratio,
        "target_ratio": 1.7,
        "seconds_per_scene_1_worker": best[1] / len(sites),
        "cpu_seconds_per_scene": {"1": cpu[1] / len(sites), "2": cpu[2] / len(sites)},
        "runs": runs,
        "cpu_count": os.cpu_count(),
        "machine": platform.platform(),
        "python": platform.python_version(),
    }
    args.out = args.out or results / "batch.json"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{len(sites)} scenes: 1 worker {best[1]:.1f} s, 2 workers {best[2]:.1f} s -> speed ratio {ratio:.2f} "
          f"(target >= 1.7); load average now {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; wrote {args.out}")


if __name__ == "__main__":
    main()
