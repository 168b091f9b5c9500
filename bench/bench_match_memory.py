"""Benchmark: memory of ``gcpcal match`` with the coarse stage by tiles and whole, on a cached render.

For a ``bench/bench_fullsize.py`` cache (profile ``realistic``; its ``scene/`` and references),
each of two coarse-stage settings runs as a child process (peak RSS = its ``ru_maxrss``; this
process stays small, so the figure is the child's own):

* ``tiled``: ``gcpcal match`` as a user types it (the coarse stage's default SIFT budget,
  ``gcpmatch.coarse.SIFT_BUDGET_BYTES``; scenes above it run by tiles);
* ``whole``: the same command through :func:`calibrate.cli.main` with the budget raised to 1 TiB,
  so the coarse stage runs SIFT on the whole reduced scene and DOM window.

Then, for each: the GCP truth error pooled and by off-nadir angle (``bench/gcp_truth.py``),
``gcpcal calibrate`` (default attitude, ``--no-report``) and ``gcpcal truth error`` of the
calibrated model over the TRUE DEM; and the coarse stage alone in a child, its peak resident
memory above what it starts from (``VmHWM`` reset through ``/proc/self/clear_refs``, Linux).

Usage::

    python bench/bench_fullsize.py --profile realistic --scale 1 --lines 512 --bands B2 \\
        --dom-resolution-m 45 --stages simulate --cache /tmp/fw
    python bench/bench_match_memory.py --cache /tmp/fw/scale1_lines512_realistic_B2_dom45m \\
        [--out bench/results/match_memory_scale1_lines512.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import bench_fullsize as fs  # noqa: E402  (the measured child runs and truth summaries)

WHOLE_BUDGET_BYTES = 1 << 40

#: the match through the CLI's entry point with the coarse stage's SIFT budget raised
WHOLE_MATCH = """
import functools, sys
import gcpmatch.coarse, gcpmatch.extract
from calibrate.cli import main
gcpmatch.extract.coarse_match = functools.partial(gcpmatch.coarse.coarse_match, sift_budget_bytes={budget})
sys.exit(main(sys.argv[1:]))
"""

#: the coarse stage alone: its peak resident memory above the start (inputs loaded first)
COARSE_ALONE = """
import json, sys, time
from pathlib import Path
from gcpmatch.coarse import coarse_match
from gcpmatch.extract import read_band
from sensor_models.files.threads import opencv_threads
from sensor_models.maps.raster import MapImage
from sensor_models.readers import open_scene
from sensor_models.terrain.dem import Dem


def mib(key):
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) / 1024 for line in status if line.startswith(key + ":"))


scene_dir, budget = Path(sys.argv[1]), int(sys.argv[2])
scene = open_scene(scene_dir / "manifest.json")
band = scene.model.reference_band
img = read_band(scene, band)
dem, dom = Dem.open(scene_dir / "reference" / "dem.tif"), MapImage.open(scene_dir / "reference" / "dom.tif")
inputs_peak = mib("VmHWM")
with open("/proc/self/clear_refs", "w") as refs:
    refs.write("5")
start, t0 = mib("VmRSS"), time.perf_counter()
with opencv_threads(2):
    res = coarse_match(img, scene.model, dem, dom, band=band, sift_budget_bytes=budget)
print(json.dumps({"inputs_peak_mib": round(inputs_peak), "start_mib": round(start),
                  "coarse_adds_mib": round(mib("VmHWM") - start), "wall_s": round(time.perf_counter() - t0, 1),
                  "tiles": res.tiles, "ransac_inliers": res.n_ransac_inliers, "inliers": res.n_inliers,
                  "ccds_with_matches": sorted(int(k) for k in res.ccd_offsets_px)}))
"""


def run_setting(cache: Path, name: str, budget: int | None, truth_step: float) -> dict:
    """Match (measured child), GCP truth error, calibrate, truth error, coarse stage alone."""
    from gcp_truth import gcp_truth_by_angle

    from gcpmatch.coarse import SIFT_BUDGET_BYTES

    scene, refs = cache / "scene", fs.reference_paths(cache, "realistic")
    work = cache / f"match_{name}"
    (work / "logs").mkdir(parents=True, exist_ok=True)
    args = ["match", str(scene / "manifest.json"), "--dom", str(refs["dom"]), "--dem", str(refs["dem"]),
            "--out", str(work / "gcps.csv"), "-q", "--overwrite"]
    cmd = [fs.gcpcal_command(), *args] if budget is None else \
        [sys.executable, "-c", WHOLE_MATCH.format(budget=budget), *args]
    out = {"match": fs.run_measured(f"match_{name}", cmd, work / "logs", 3600)}
    if out["match"]["rc"] not in (0, 4):
        return out
    summary = json.loads((work / "gcps.summary.json").read_text())
    out["gcps"], out["check_points"], out["coarse"] = summary["gcps"], summary["check_points"], summary["coarse"]
    out["coarse_s"] = summary.get("timings", {}).get("coarse_s")
    cal = [fs.gcpcal_command(), "calibrate", str(scene / "manifest.json"), "--gcps", str(work / "gcps.csv"),
           "--out", str(work / "cal_auto"), "--no-report", "-q", "--overwrite"]
    out["calibrate"] = fs.run_measured(f"calibrate_{name}", cal, work / "logs", 3600)
    out["truth_error"] = fs.truth_error_of(cache, "realistic", "cal_auto", truth_step, work / "logs", 3600, work)
    alone = subprocess.run([sys.executable, "-c", COARSE_ALONE, str(scene), str(budget or SIFT_BUDGET_BYTES)],
                           capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    out["coarse_alone"] = json.loads(alone.stdout) if alone.returncode == 0 else {"error": alone.stderr[-400:]}
    out["gcp_truth_error"] = gcp_truth_by_angle(scene / "truth_manifest.json", work / "gcps.csv")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True, help="a bench_fullsize.py cache (profile realistic)")
    ap.add_argument("--truth-step", type=float, default=16.0, help="truth-error grid spacing, px")
    ap.add_argument("--out", type=Path, default=None, help="JSON of every figure (default: print only)")
    args = ap.parse_args(argv)
    from gcpmatch.coarse import SIFT_BUDGET_BYTES

    result = {"cache": str(args.cache), "loadavg_start": fs.loadavg()}
    for name, budget in (("tiled", None), ("whole", WHOLE_BUDGET_BYTES)):
        result[name] = run_setting(args.cache, name, budget, args.truth_step)
        result[name]["sift_budget_bytes"] = budget or SIFT_BUDGET_BYTES
    result["loadavg_end"] = fs.loadavg()
    for name in ("tiled", "whole"):
        r = result[name]
        m, g = r["match"], r.get("gcp_truth_error", {}).get("all", {})
        print(f"{name}: match rc {m['rc']}, peak RSS {m['peak_rss_mib']:.0f} MiB, wall {m['wall_s']:.1f} s; "
              f"coarse alone {r.get('coarse_alone')}; GCPs {r.get('gcps')} + {r.get('check_points')}; "
              f"GCP truth error {g.get('rms_px')} px rms; calibrated {r.get('truth_error')}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1, default=str) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
