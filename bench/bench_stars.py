"""Benchmark: star-track processing and calibration of a geostationary staring camera (seed 000).

A 1024 x 1024 sequence (``--frames``, default 120 frames every 10 s, seed 000 optics) is
rendered by :func:`sensor_models.simulate.star_sky.simulate_geo_stars` and read into memory.
Timed, best of ``--repeat``:

* star processing, per core (every thread pool pinned to one thread): detection + centroid
  (:func:`calibrate.star_frames.detect_frames`), prediction of the catalogue stars with the LAB model,
  identification (offset vote + nearest neighbours) and association into tracks with the
  smoothing spline; frames per second;
* the same on 2 cores: the frames split between two worker processes for detection (frames are
  independent), prediction/identification/tracks in the parent;
* calibration: stepwise exterior-interior and joint least squares on the track points;
* held-out accuracy (RA/DE mean absolute and 2-sigma, pixels) with the ``iwc`` and ``gaussian``
  centroids side by side, and their time ratio.

Usage: ``python bench/bench_stars.py [--frames 120] [--repeat 3] [--out FILE]``
Writes ``bench/results/stars.json``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _detect(frames, centroid="iwc"):
    cv2.setNumThreads(1)
    from calibrate.star_frames import detect_frames

    return detect_frames(frames, centroid=centroid)[0]


def _associate(tables, models, catalog, seconds):
    """Prediction, identification and the tracks of one sequence."""
    from calibrate.star_identification import identify, predict_catalog

    pred = predict_catalog(models, catalog, margin_px=120.0)
    pairs, offset = identify(tables, pred)
    return pairs, offset


def _best(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "stars.json"))
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)

    from calibrate.config import StarOptions
    from calibrate.star_calibration import process_frames
    from calibrate.star_frames import load_frame, read_frame_list
    from calibrate.star_solution import calibrate_tracks
    from sensor_models.geometry.star_catalogue import StarCatalog
    from sensor_models.readers.geo_manifest import read_geo_manifest
    from sensor_models.simulate.star_sky import simulate_geo_stars

    results = {"platform": platform.platform(), "cpus": os.cpu_count(), "frames": args.frames}
    tmp_dir = tempfile.TemporaryDirectory()
    tmp = tmp_dir.name
    t0 = time.perf_counter()
    sim = simulate_geo_stars(Path(tmp) / "sim", n_frames=args.frames, seed=0)
    results["simulation"] = {"seconds": time.perf_counter() - t0,
                             "frames_per_s": args.frames / (time.perf_counter() - t0),
                             "distinct_stars": sim["distinct_stars"],
                             "stars_per_frame": sim["stars_per_frame"]["mean"]}
    paths, seconds, manifest = read_frame_list(Path(tmp) / "sim")
    lab = read_geo_manifest(manifest)
    t_io, frames = _best(lambda: [load_frame(p) for p in paths], 1)
    results["read_frames_per_s"] = len(frames) / t_io
    catalog = StarCatalog.load(mag_limit=10.5)
    models = [lab.at_frame(float(s)) for s in seconds]

    # ---- per core (frames in memory; and read from disk)
    t_det, tables = _best(lambda: _detect(frames), args.repeat)
    t_disk, _ = _best(lambda: _detect(paths), args.repeat)
    t_ass, (pairs, offset) = _best(lambda: _associate(tables, models, catalog, seconds), args.repeat)
    t_models, _ = _best(lambda: [lab.at_frame(float(s)) for s in seconds], args.repeat)
    total_1 = t_det + t_ass + t_models
    results["one_core"] = {"detection_s": t_det, "read_and_detection_s": t_disk, "models_s": t_models,
                           "prediction_identification_s": t_ass,
                           "frames_per_s": len(frames) / total_1,
                           "from_disk_frames_per_s": len(frames) / (t_disk + t_ass + t_models),
                           "detection_frames_per_s": len(frames) / t_det,
                           "identified": int(pairs.shape[0]), "offset_px": offset.tolist()}

    # ---- two cores: frames read and detected by two worker processes (paths, not pixels,
    # cross the process boundary), prediction and identification in the parent
    half = len(paths) // 2
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(_detect, [paths[:2], paths[2:4]]))  # warm the workers (imports)

        def two():
            parts = list(pool.map(_detect, [paths[:half], paths[half:]]))
            tabs = parts[0] + parts[1]
            ms = [lab.at_frame(float(s)) for s in seconds]
            return _associate(tabs, ms, catalog, seconds)

        t_two, _ = _best(two, args.repeat)
    total_disk = t_disk + t_ass + t_models
    results["two_cores"] = {"seconds": t_two, "frames_per_s": len(frames) / t_two,
                            "speedup_vs_one_core_from_disk": total_disk / t_two, "target_frames_per_s": 50.0}

    # ---- calibration and accuracy, iwc vs gaussian centroids
    for centroid in ("iwc", "gaussian"):
        t_c, tabs = _best(lambda: _detect(frames, centroid), 1)
        # the catalogue process_frames loads from these options is the one loaded above
        r = process_frames(frames, seconds, lab, options=StarOptions(mag_limit=10.5, compare_joint=True),
                           detections=tabs, versus_points=(10, 15, 20, 25))
        obs = r.observations
        cal = obs.calibration
        t_step, _ = _best(lambda: calibrate_tracks(models[0], obs.virtual_gcrf[cal], obs.row_smooth[cal],
                                                   obs.col_smooth[cal]), args.repeat)
        t_joint, _ = _best(lambda: calibrate_tracks(models[0], obs.virtual_gcrf[cal], obs.row_smooth[cal],
                                                    obs.col_smooth[cal], scheme="joint"), args.repeat)
        a = r.accuracy
        results[centroid] = {
            "detection_s": t_c, "success": r.success, "tracks": r.frames["n_tracks"],
            "calibration_points": r.frames["n_calibration_points"], "check_points": r.frames["n_check_points"],
            "stepwise_s": t_step, "joint_s": t_joint,
            "before": {k: {"mean_px": a["before"][k]["mean_px"], "two_sigma_px": a["before"][k]["two_sigma_px"]}
                       for k in ("ra", "de")},
            "after": {k: {"mean_abs_px": a["after"][k]["mean_abs_px"], "two_sigma_px": a["after"][k]["two_sigma_px"]}
                      for k in ("ra", "de")},
            "joint_after": {k: {"mean_abs_px": a["joint_after"][k]["mean_abs_px"],
                                "two_sigma_px": a["joint_after"][k]["two_sigma_px"]} for k in ("ra", "de")},
            "versus_points": r.versus_points,
        }
    results["gaussian_over_iwc_detection_time"] = results["gaussian"]["detection_s"] / results["iwc"]["detection_s"]

    tmp_dir.cleanup()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n")
    oc, tc = results["one_core"], results["two_cores"]
    print(f"simulation: {results['simulation']['frames_per_s']:.1f} frames/s, "
          f"{results['simulation']['distinct_stars']} stars")
    print(f"star processing: {oc['frames_per_s']:.1f} frames/s per core in memory (detection alone "
          f"{oc['detection_frames_per_s']:.1f}), {oc['from_disk_frames_per_s']:.1f} from disk; "
          f"{tc['frames_per_s']:.1f} frames/s on 2 cores from disk "
          f"(x{tc['speedup_vs_one_core_from_disk']:.2f}; target 50)")
    for c in ("iwc", "gaussian"):
        r = results[c]
        print(f"{c:8s}: stepwise {1e3 * r['stepwise_s']:.1f} ms, joint {1e3 * r['joint_s']:.1f} ms; "
              f"RA/DE before {r['before']['ra']['mean_px']:.2f}/{r['before']['de']['mean_px']:.2f} px, after "
              f"mean|e| {r['after']['ra']['mean_abs_px']:.3f}/{r['after']['de']['mean_abs_px']:.3f} px, 2-sigma "
              f"{r['after']['ra']['two_sigma_px']:.3f}/{r['after']['de']['two_sigma_px']:.3f} px")
    print(f"gaussian / iwc detection time: {results['gaussian_over_iwc_detection_time']:.2f}")
    print(f"wrote {out}")
    return results


if __name__ == "__main__":
    main()
