"""Benchmark ``gcpcal match`` end to end on a large simulated scene.

The target case: 10 000 GCPs from a 6000 x 8192 scene (2 cameras x 2 CCDs of 2048 detectors)
in at most 60 s on 2 cores. The scene (16 m pixels over a procedural 15 m DOM) is simulated
first (not timed; cached in ``bench/results/match_scene`` between runs), then one band is
matched with 64 px windows every ``--spacing`` pixels; the GCPs are graded against the truth.

Usage: ``python bench/bench_match.py [--rows 6000] [--detectors 2048] [--spacing 64] [--out F]``
Writes ``--out`` (default ``bench/results/match.json``, ``match_baseline.json`` with ``--baseline``).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=6000)
    ap.add_argument("--detectors", type=int, default=2048)
    ap.add_argument("--gsd", type=float, default=16.0)
    ap.add_argument("--spacing", type=int, default=64)
    ap.add_argument("--backend", default="cpu")
    ap.add_argument("--baseline", action="store_true",
                    help="match with the base revision's DEM intersection (locate_block) and cloud detector "
                         "(bench/baseline.py), for the time shares of the straightforward stages")
    ap.add_argument("--out", type=Path, default=None, help="JSON written")
    args = ap.parse_args()
    if args.baseline:
        _use_baseline_stages()

    from gcpmatch.extract import extract_gcps, read_band
    from gcpmatch.options import MatchOptions
    from sensor_models.readers import open_model, open_scene
    from sensor_models.simulate.config import SimConfig
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom
    from sensor_models.maps.raster import MapImage
    from sensor_models.terrain.dem import Dem

    scene = ROOT / "bench" / "results" / f"match_scene_{args.rows}x{args.detectors}"
    if not (scene / "summary.json").exists():
        cfg = SimConfig()
        cfg = replace(cfg, scene=replace(cfg.scene, n_rows=args.rows, gsd_m=args.gsd),
                      camera=replace(cfg.camera, detectors_per_ccd=args.detectors, overlap_detectors=16),
                      reference=replace(cfg.reference, margin_m=1500.0)).validate()
        t = time.perf_counter()
        simulate_pushbroom(scene, config=cfg)
        print(f"simulated {scene} in {time.perf_counter() - t:.0f} s")
    lab = open_model(scene / "manifest.json")
    truth = open_model(scene / "truth_manifest.json")
    dem = Dem.open(scene / "reference" / "dem.tif")
    dom = MapImage.open(scene / "reference" / "dom.tif")
    t0 = time.perf_counter()
    img = read_band(open_scene(scene / "manifest.json"), "B2")
    table, summary = extract_gcps(lab, img, dem, dom, band="B2",
                                  options=MatchOptions(spacing_px=args.spacing, backend=args.backend))
    seconds = time.perf_counter() - t0
    names = {c.name: i for i, c in enumerate(truth.band_ccds("B2"))}
    idx = np.array([names[c] for c in table.ccd])
    r, c = np.empty(len(table)), np.empty(len(table))
    for i in range(len(names)):
        s = idx == i
        r[s], c[s] = truth.ground_to_image(table.lon[s], table.lat[s], table.h[s], band="B2", array=i)
    err = np.hypot(table.row - r, table.col - c)
    result = {
        "scene": [int(v) for v in lab.image_shape], "gcps_and_checks": len(table), "seconds": seconds,
        "timings": summary["timings"], "windows": summary["windows"],
        "matches_per_second_phase": summary["matches_per_second"],
        "error_vs_truth_px": {"rms": float(np.sqrt(np.mean(err**2))), "max": float(err.max()),
                              "over_1px": int((err > 1).sum())},
        "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2,
        "target": "10000 GCPs in <= 60 s on 2 cores",
    }
    result["code"] = "base revision's locate_block and detect_clouds" if args.baseline else "current"
    result["shares"] = {k: v / summary["timings"]["total_s"] for k, v in summary["timings"].items() if k != "total_s"}
    print(json.dumps(result, indent=1))
    out = args.out or ROOT / "bench" / "results" / ("match_baseline.json" if args.baseline else "match.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")


def _use_baseline_stages() -> None:
    """Patch the matcher to use the base revision's DEM intersection and cloud detector."""
    sys.path.insert(0, str(ROOT / "bench"))
    from baseline import load_baseline

    import gcpmatch.extract as extract
    import gcpmatch.reference as reference

    base_locate = load_baseline("sensor_models/imaging/locate.py")
    reference.locate_block = lambda *a, tolerance_m=None, **k: base_locate.locate_block(*a, **k)
    extract.detect_clouds = load_baseline("gcpmatch/clouds.py").detect_clouds


if __name__ == "__main__":
    main()
