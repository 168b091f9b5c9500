"""Measure: time-varying attitude (``--attitude``) against the static model.

Three parts, each written to ``--out`` (default ``bench/results/attitude.json``):

* ``sensitivity``: truth error against jitter amplitude, static vs auto. A TRUE model
  (:func:`sensor_models.synthetic.example_pushbroom_model`, 3000 lines = 22.6 s, an
  installation error, a sinusoidal jitter of amplitude A on roll and pitch and A/2 on yaw at
  ``--frequency`` Hz) gives ``--n-gcps`` synthetic GCPs (random pixels and heights, 0.1 px
  Gaussian noise, no image matching); the LAB model is calibrated with ``--attitude static``
  and ``auto``; the truth error is the image distance between the calibrated model's and the
  TRUE model's projections over EVERY line (columns every 1/24 of the swath); the recovered
  jitter is the dominant sinusoid of the correction (:func:`calibrate.attitude.jitter_spectrum`).
* ``speed``: process time of static vs auto on ``--speed-gcps`` synthetic GCPs (10 urad jitter).
* ``scene`` (with ``--scene DIR --gcps CSV``): a simulated scene (``gcpcal simulate pushbroom
  --profile realistic``) and its matched GCPs through the user's chain, ``gcpcal calibrate
  --attitude static|auto`` then ``gcpcal relative``; truth error of the reference band over
  every line (columns every 8 px) and of every band on the 16 px grid of
  :func:`sensor_models.compare.model_difference` (band-to-band: the other bands).

Usage: ``python bench/bench_attitude.py [--quick] [--scene S --gcps G]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
N_ROWS = 3000


def _truth_models(amplitude_urad, frequency_hz, seed=3):
    from sensor_models.pushbroom_types import Installation
    from sensor_models.synthetic import example_pushbroom_model

    a = amplitude_urad * 1e-6
    truth = example_pushbroom_model(
        n_rows=N_ROWS, installation=Installation(2e-4, -1e-4, 3e-4),
        attitude_kwargs=dict(jitter_amplitude_rad=(a, a, 0.5 * a), jitter_frequency_hz=frequency_hz, seed=seed))
    return truth


def _gcps(truth, n, seed=0, noise_px=0.1):
    from gcpmatch.gcps import GcpTable

    rng = np.random.default_rng(seed)
    band = truth.reference_band
    rows, cols = rng.uniform(1, N_ROWS - 1, n), rng.uniform(1, truth.n_cols - 1, n)
    lon, lat, h = truth.image_to_ground(rows, cols, height=rng.uniform(0, 1500, n), band=band)
    return GcpTable.from_arrays(rows + rng.normal(0, noise_px, n), cols + rng.normal(0, noise_px, n), lon, lat, h,
                                band=np.full(n, band))  # fmt: skip


def every_line_error(truth, model, *, band=None, col_step=None, dem=None, height_m=500.0) -> dict:
    """RMS / max (px) of ``model`` against ``truth`` over every image line of one band.

    Per CCD (forced, as :func:`sensor_models.compare.model_difference` does: CCDs overlap), the
    pixels of every line at columns every ``col_step`` (default: 6 per CCD) are localized by the
    truth (on ``dem`` or at ``height_m``) and projected back by ``model``.
    """
    band = band or truth.reference_band
    errors = []
    for i, ccd in enumerate(truth.band_ccds(band)):
        step = col_step or ccd.n_detectors / 6.0
        cols = ccd.first_col + np.arange(0.5, ccd.n_detectors, step)
        rows, cols = (a.ravel() for a in np.meshgrid(np.arange(0.5, truth.n_rows, 1.0), cols))
        if dem is not None:
            lon, lat, h = truth.image_to_ground(rows, cols, dem=dem, band=band, array=i)
        else:
            lon, lat, h = truth.image_to_ground(rows, cols, height=height_m, band=band, array=i)
        ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
        r, c = model.ground_to_image(lon[ok], lat[ok], h[ok], band=band, array=i)
        e = np.hypot(r - rows[ok], c - cols[ok])
        errors.append(e[np.isfinite(e)])
    e = np.concatenate(errors)
    return {"rms_px": float(np.sqrt(np.mean(e**2))), "max_px": float(e.max()), "n_points": int(e.size)}


def _calibrate(lab, gcps, mode):
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions

    t = time.process_time()
    result = calibrate_model(lab, gcps, options=CalibrationOptions(attitude=mode))
    return result, time.process_time() - t


def sensitivity(amplitudes, frequency_hz, n_gcps) -> list:
    from sensor_models.synthetic import example_pushbroom_model

    lab = example_pushbroom_model(n_rows=N_ROWS)
    rows = []
    for amp in amplitudes:
        truth = _truth_models(amp, frequency_hz)
        gcps = _gcps(truth, n_gcps)
        row = {"amplitude_urad": amp, "frequency_hz": frequency_hz, "n_gcps": n_gcps}
        for mode in ("static", "auto"):
            result, seconds = _calibrate(lab, gcps, mode)
            row[mode] = {"truth_error_px": every_line_error(truth, result.model), "seconds_cpu": seconds,
                         "selected": (result.attitude or {}).get("selected", {"kind": "static"}),
                         "jitter": (result.attitude or {}).get("jitter")}
        print(json.dumps({"amplitude_urad": amp, **{m: row[m]["truth_error_px"]["rms_px"] for m in ("static", "auto")},
                          "selected": row["auto"]["selected"]}))
        rows.append(row)
    return rows


def speed(n_gcps, frequency_hz) -> dict:
    from sensor_models.synthetic import example_pushbroom_model

    lab = example_pushbroom_model(n_rows=N_ROWS)
    truth = _truth_models(10.0, frequency_hz)
    gcps = _gcps(truth, n_gcps, seed=11)
    out = {"n_gcps": n_gcps}
    for mode in ("static", "auto"):
        result, seconds = _calibrate(lab, gcps, mode)
        out[mode] = {"seconds_cpu": seconds, "truth_error_px": every_line_error(truth, result.model)}
    out["ratio_auto_over_static"] = out["auto"]["seconds_cpu"] / out["static"]["seconds_cpu"]
    print(json.dumps({k: out[k] for k in ("n_gcps", "ratio_auto_over_static")}))
    return out


def _gcpcal(*args) -> None:
    cmd = [shutil.which("gcpcal") or "gcpcal", "-q", *map(str, args)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    if done.returncode not in (0, 4):
        raise SystemExit(f"{' '.join(cmd)} -> {done.returncode}\n{done.stderr[-2000:]}")


def scene(scene_dir: Path, gcps_csv: Path, work: Path) -> dict:
    from sensor_models.compare import model_difference
    from sensor_models.readers import open_model
    from sensor_models.terrain import Dem

    truth = open_model(scene_dir / "truth_manifest.json")
    dem_path = scene_dir / "reference" / "dem.tif"
    dem = Dem.open(dem_path)
    summary = json.loads((scene_dir / "summary.json").read_text())
    out = {"scene": str(scene_dir), "gcps": str(gcps_csv)}
    for mode in ("static", "auto"):
        cal, rel = work / f"cal_{mode}", work / f"rel_{mode}"
        t = time.perf_counter()
        _gcpcal("calibrate", scene_dir / "manifest.json", "--gcps", gcps_csv, "--out", cal, "--attitude", mode,
                "--no-report")
        seconds = time.perf_counter() - t
        _gcpcal("relative", scene_dir / "manifest.json", "--calibration", cal, "--dem", dem_path, "--out", rel)
        model = open_model(rel / "manifest.json")
        doc = json.loads((cal / "calibration.json").read_text())
        others = [b for b in truth.bands if b != truth.reference_band]
        grid = model_difference(truth, model, dem=dem, step_px=16.0)
        b2b = model_difference(truth, model, dem=dem, step_px=16.0, bands=others) if others else None
        out[mode] = {"calibrate_seconds_wall": seconds,
                     "reference_band_every_line": every_line_error(truth, model, col_step=8.0, dem=dem),
                     "all_bands_grid": {k: grid[k] for k in ("rms_px", "max_px", "n_points")},
                     "other_bands_grid": None if b2b is None else {k: b2b[k] for k in ("rms_px", "max_px")},
                     "attitude": {k: v for k, v in (doc.get("attitude") or {}).items()
                                  if k in ("selected", "jitter", "candidates")}}
        print(json.dumps({"mode": mode, "every_line": out[mode]["reference_band_every_line"],
                          "selected": out[mode]["attitude"].get("selected")}))
    out["profile"] = summary.get("profile")
    out["lines_seconds"] = float(abs(truth.line_timing.line_period_s) * truth.n_rows)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "attitude.json")
    ap.add_argument("--frequency", type=float, default=0.3, help="Jitter frequency, Hz.")
    ap.add_argument("--amplitudes", default="0,2,5,10,20,40", help="Jitter amplitudes, urad, comma-separated.")
    ap.add_argument("--n-gcps", type=int, default=4000)
    ap.add_argument("--speed-gcps", type=int, default=100_000)
    ap.add_argument("--quick", action="store_true", help="Two amplitudes, 2e4 GCPs for the speed part.")
    ap.add_argument("--scene", type=Path, help="A simulated scene folder (truth_manifest.json, reference/).")
    ap.add_argument("--gcps", type=Path, help="Its matched GCP table.")
    ap.add_argument("--skip", default="", help="Parts to skip: sensitivity, speed (comma-separated).")
    args = ap.parse_args()
    amplitudes = [0.0, 10.0] if args.quick else [float(a) for a in args.amplitudes.split(",")]
    skip = set(filter(None, args.skip.split(",")))
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    if "sensitivity" not in skip:
        results["sensitivity"] = sensitivity(amplitudes, args.frequency, args.n_gcps)
    if "speed" not in skip:
        results["speed"] = speed(20_000 if args.quick else args.speed_gcps, args.frequency)
    if args.scene is not None:
        work = args.out.parent / "attitude_scene"
        work.mkdir(parents=True, exist_ok=True)
        results["scene"] = scene(args.scene, args.gcps, work)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
