"""Diagnostic: match a full-width strip with a widened coarse stage, then calibrate and grade.

On a 512-line strip of the seed's full width, ``gcpcal match`` reduces the 21 800-column strip
twice (``MIN_REDUCED_SIDE_PX``) and runs SIFT by tiles under its memory budget
(docs/matching.md, "The coarse stage by tiles"); its outermost CCD gets no coarse match
(docs/experiments.md). This script runs the library's match action
(:func:`calibrate.actions.match.match_scene`, everything else as ``gcpcal match``) with the coarse
stage's reduction target and SIFT feature cap raised (``--target-px``, ``--n-features``:
``gcpmatch.coarse.coarse_match`` arguments the CLI does not expose), then ``gcpcal calibrate``
(auto, static) and ``gcpcal truth error`` as a user would, and the GCP truth error by off-nadir
angle (``bench/gcp_truth.py``). NOT what ``gcpcal match`` does by default: a diagnostic of what
the full width gives with more features in the coarse stage.

The match runs in this process; the later commands are forked from it, so their ``peak_rss_mib``
includes this process's resident memory at the fork (not a figure to report).

Usage::

    python bench/bench_fullwidth_match.py --cache /tmp/fw/scale1_lines512_realistic_B2B4_dom45m \\
        [--user-dem given|true] --out bench/results/fullwidth_match_widened_lines512_realistic.json
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import bench_fullsize  # noqa: E402  (the measured child runs and truth summaries)
from gcp_truth import gcp_truth_by_angle  # noqa: E402


def widened_match(cache: Path, work: Path, dem: Path, *, target_px: int, n_features: int) -> dict:
    """The match action with ``coarse_match(target_px=..., n_features=...)``; its summary and wall time.

    Parameters
    ----------
    cache : Path
        ``bench_fullsize.py`` cache folder (``scene/`` inside).
    work : Path
        Output folder (``gcps.csv`` and its summary).
    dem : Path
        The user's DEM.
    target_px, n_features : int
        Coarse stage: longest side of the reduced scene, most SIFT keypoints per image.

    Returns
    -------
    dict
        GCP and check-point counts, the coarse stage's summary, ``wall_s``; or ``error``.
    """
    import gcpmatch.extract as extract
    from calibrate.actions.match import match_scene

    scene = cache / "scene"
    original = extract.coarse_match
    extract.coarse_match = functools.partial(original, target_px=target_px, n_features=n_features)
    t0 = time.perf_counter()
    try:
        summ = match_scene(scene / "manifest.json", dom_path=scene / "reference" / "dom.tif", dem_path=dem,
                           out_path=work / "gcps.csv")
    except Exception as exc:  # noqa: BLE001 - a diagnostic records why the match failed
        return {"error": f"{type(exc).__name__}: {exc}", "wall_s": round(time.perf_counter() - t0, 1)}
    finally:
        extract.coarse_match = original
    return {"gcps": summ.get("gcps"), "check_points": summ.get("check_points"), "coarse": summ.get("coarse"),
            "per_ccd": summ.get("per_ccd"), "wall_s": round(time.perf_counter() - t0, 1)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--user-dem", default="given", choices=["given", "true"])
    ap.add_argument("--target-px", type=int, default=11000)
    ap.add_argument("--n-features", type=int, default=40000)
    ap.add_argument("--truth-step", type=float, default=16.0)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    fs = bench_fullsize
    refs = fs.reference_paths(args.cache, "realistic", args.user_dem)
    work = args.cache / f"widened_{args.user_dem}"
    (work / "logs").mkdir(parents=True, exist_ok=True)
    result = {"cache": str(args.cache), "user_dem": str(refs["dem"]), "target_px": args.target_px,
              "n_features": args.n_features, "loadavg_start": fs.loadavg()}
    result["match"] = widened_match(args.cache, work, refs["dem"], target_px=args.target_px,
                                    n_features=args.n_features)
    if "error" not in result["match"]:
        result["gcp_truth_error"] = gcp_truth_by_angle(args.cache / "scene" / "truth_manifest.json", work / "gcps.csv")
        cmds = fs.stage_commands(args.cache, "realistic", 2, args.user_dem)
        for att in ("auto", "static"):
            cmd = [str(work / "gcps.csv") if str(c).endswith("gcps.csv") else
                   str(work / f"cal_{att}") if str(c).endswith(f"cal_{att}") else c for c in cmds[f"calibrate_{att}"]]
            result[f"calibrate_{att}"] = fs.run_measured(f"calibrate_{att}", cmd, work / "logs", 1800)
        result["accuracy"] = fs.check_figures(work)
        result["truth_error"] = {m: fs.truth_error_of(args.cache, "realistic", m, args.truth_step, work / "logs",
                                                      1800, work) for m in ("lab", "cal_auto", "cal_static")}
    result["loadavg_end"] = fs.loadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1, default=str) + "\n")
    print(json.dumps({k: result.get(k) for k in ("match", "gcp_truth_error", "accuracy")}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
