"""Measure: time-varying attitude (``--attitude``) against the static model.

Three parts, each written to ``--out`` (default ``bench/results/attitude.json``):

* ``sensitivity``: truth error against jitter amplitude, static vs auto. A TRUE model
  (:func:`sensor_models.models.synthetic.example_pushbroom_model`, 3000 lines = 22.6 s, an
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
  :func:`sensor_models.models.compare.model_difference` (band-to-band: the other bands).

Usage: ``python bench/bench_attitude.py [--quick] [--scene S --gcps G]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
N_ROWS = 3000


def _truth_models(amplitude_urad, frequency_hz, seed=3):
    from sensor_models.models.pushbroom_types import Installation
    from sensor_models.models.synthetic import example_pushbroom_model

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

    Per CCD (forced, as :func:`sensor_models.models.compare.model_difference` does: CCDs overlap), the
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
    from sensor_models.models.synthetic import example_pushbroom_model

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
    from sensor_models.models.synthetic import example_pushbroom_model

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


def scene(scene_dir: Path, gcps_csv: Path, work: Path, modes=("static", "auto")) -> dict:
    from sensor_models.models.compare import model_difference
    from sensor_models.readers import open_model
    from sensor_models.terrain.dem import Dem

    truth = open_model(scene_dir / "truth_manifest.json")
    dem_path = scene_dir / "reference" / "dem.tif"
    dem = Dem.open(dem_path)
    summary = json.loads((scene_dir / "summary.json").read_text())
    out = {"scene": str(scene_dir), "gcps": str(gcps_csv)}
    for mode in modes:
        cal_mode = "auto" if mode == "joint" else mode
        cal, rel = work / f"cal_{cal_mode}", work / f"rel_{mode}"
        t = time.perf_counter()
        if not (cal / "calibration.json").exists() or mode != "joint":
            shutil.rmtree(cal, ignore_errors=True)
            _gcpcal("calibrate", scene_dir / "manifest.json", "--gcps", gcps_csv, "--out", cal, "--attitude", cal_mode,
                    "--no-report")
        seconds = time.perf_counter() - t
        shutil.rmtree(rel, ignore_errors=True)
        t = time.perf_counter()
        _gcpcal("relative", scene_dir / "manifest.json", "--calibration", cal, "--dem", dem_path, "--out", rel,
                *(["--gcps", gcps_csv] if mode == "joint" else ["--no-parallax"]))
        relative_seconds = time.perf_counter() - t
        rel_summary = json.loads((rel / "relative.summary.json").read_text())
        model = open_model(rel / "manifest.json")
        doc = json.loads((cal / "calibration.json").read_text())
        if mode == "joint":  # the correction the relative stage wrote, with its spectrum
            from calibrate.attitude import jitter_spectrum

            corr = model.attitude_correction
            t_lo, t_hi = sorted(float(v) for v in model.line_timing.seconds(np.array([0.0, float(model.n_rows)])))
            doc = {"attitude": {"selected": rel_summary["parallax"].get("selected"),
                                "jitter": None if corr is None else {a: v["peak"] for a, v in
                                                                     jitter_spectrum(corr, t_lo, t_hi)["axes"].items()}}}
        others = [b for b in truth.bands if b != truth.reference_band]
        grid = model_difference(truth, model, dem=dem, step_px=16.0)
        b2b = model_difference(truth, model, dem=dem, step_px=16.0, bands=others) if others else None
        out[mode] = {"calibrate_seconds_wall": seconds, "relative_seconds_wall": relative_seconds,
                     "parallax": rel_summary.get("parallax"),
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


# --------------------------------------------------------------------------- parallax
def _jittered_truth(lab, lines, seed=5, installation=(2e-4, -1e-4, 3e-4), band_error_px=(0.3, -0.2)):
    """TRUE model: ``lab`` with an installation error, the jitter ``lines`` in its attitude
    (``[(amplitudes_urad (3,), frequency_hz), ...]``, random phases, sampled at 100 Hz) and
    the other bands' CCDs shifted by ``band_error_px`` (along, across track) times the IFOV."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from sensor_models.geometry.ephemeris import Attitude
    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.models.pushbroom_types import Installation

    rng = np.random.default_rng(seed)
    t = np.arange(lab.attitude.seconds[0], lab.attitude.seconds[-1], 0.01)
    angles = np.zeros((t.size, 3))
    for amp, f in lines:
        angles += np.asarray(amp)[None, :] * 1e-6 * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 2 * np.pi, 3))
    quat = (lab.attitude.rotation(t) * Rotation.from_euler("ZYX", angles[:, ::-1])).as_quat()
    ifov = 50.0 / 782_121.0
    bands = {}
    for b in lab.bands:
        shift = (0.0, 0.0) if b == lab.reference_band else band_error_px
        bands[b] = tuple(replace(c, tan_psi_x=c.tan_psi_x + np.r_[shift[0] * ifov, np.zeros(c.tan_psi_x.size - 1)],
                                 tan_psi_y=c.tan_psi_y + np.r_[shift[1] * ifov, np.zeros(c.tan_psi_y.size - 1)])
                         for c in lab.band_ccds(b))
    return PushbroomModel(orbit=lab.orbit, attitude=Attitude(t, quat, frame=lab.attitude.frame),
                          line_timing=lab.line_timing, bands=bands, installation=Installation(*installation),
                          n_rows=lab.n_rows, reference_band=lab.reference_band, name="truth")


def _synthetic_ties(truth, model, band, *, row_step, col_step, height_m, noise_px, seed):
    """Ties of ``band`` on a reference-band grid: the truth's transfer map plus noise; ground from ``model``."""
    from calibrate.tie_points import TiePoints

    rng = np.random.default_rng(seed)
    ref = truth.reference_band
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(16.0, truth.n_rows - 16, row_step),
                                                 np.arange(8.0, truth.n_cols - 8, col_step), indexing="ij"))
    ccd_ref = truth.ccd_index(cols, band=ref).reshape(-1)
    lon, lat, h = truth.image_to_ground(rows, cols, height=height_m, band=ref, array=ccd_ref)
    qr, qc = truth.ground_to_image(lon, lat, h, band=band)
    ok = np.isfinite(qr) & np.isfinite(qc)
    rows, cols, ccd_ref, qr, qc = rows[ok], cols[ok], ccd_ref[ok], qr[ok], qc[ok]
    qr, qc = qr + rng.normal(0, noise_px, qr.size), qc + rng.normal(0, noise_px, qc.size)
    ccd = truth.ccd_index(qc, band=band).reshape(-1)
    glon, glat, gh = model.image_to_ground(rows, cols, height=height_m, band=ref, array=ccd_ref)
    n = rows.size
    return TiePoints(band, rows, cols, ccd_ref, glon, glat, gh, qr, qc, ccd, qr, qc, np.ones(n), np.full(n, noise_px))


def _two_line_fit(correction, t_lo, t_hi, f_lo, f_hi):
    """Per axis: amplitude and frequency of the two sinusoids near ``f_lo`` and ``f_hi`` in a correction."""
    from scipy.optimize import least_squares

    from sensor_models.models.attitude_correction import AXES

    t = np.linspace(t_lo, t_hi, 4096)
    tc = t - t.mean()
    out = {}
    for a, name in enumerate(AXES):
        y = correction.angles(t)[:, a] * 1e6 if correction is not None else np.zeros_like(t)

        def design(f):
            cols = [np.ones_like(tc), tc]
            for fk in f:
                cols += [np.sin(2 * np.pi * fk * tc), np.cos(2 * np.pi * fk * tc)]
            return np.stack(cols, axis=1)

        def resid(f):
            x = design(f)
            return x @ np.linalg.lstsq(x, y, rcond=None)[0] - y

        f = least_squares(resid, [f_lo, f_hi], bounds=([0.7 * f_lo, 0.8 * f_hi], [1.3 * f_lo, 1.2 * f_hi])).x
        c = np.linalg.lstsq(design(f), y, rcond=None)[0]
        out[name] = [{"amplitude_urad": float(np.hypot(c[2 + 2 * k], c[3 + 2 * k])), "frequency_hz": float(f[k])}
                     for k in range(2)]
    return out


def _all_bands_error(truth, model, height_m):
    per = {b: every_line_error(truth, model, band=b, height_m=height_m) for b in truth.bands}
    other = [per[b] for b in truth.bands if b != truth.reference_band]
    return {"reference_band": per[truth.reference_band],
            "other_bands_rms_px": float(np.sqrt(np.mean([o["rms_px"] ** 2 for o in other]))),
            "other_bands_max_px": float(max(o["max_px"] for o in other)), "per_band": per}


def parallax_case(*, n_rows, lines, n_gcps, tie_row_step, tie_col_step, tie_noise_px, gcp_noise_px=0.1,
                  height_m=300.0, seed=3, yaw_sigma_urad=None) -> dict:
    """Static vs GCP-only auto vs joint (GCPs + band parallax) on one synthetic scene.

    TRUE model: the example camera (4 bands 6, 2, 2, 6 detectors off the centre line along
    track; B2 the reference), an installation error, the other bands 0.3 px along and -0.2 px
    across track off the laboratory interiors, and the jitter ``lines`` in its attitude (sampled
    at 100 Hz: outside the spline family). GCPs of B2 (rows every 24 lines when ``n_gcps`` is 0)
    with ``gcp_noise_px`` Gaussian noise; ties of every other band on a grid of the reference band
    (``tie_row_step`` x ``tie_col_step`` px) from the TRUE transfer map with ``tie_noise_px``;
    the terrain is a plane at ``height_m`` for the ties. No image matching. With
    ``yaw_sigma_urad``, the joint fit is also run with that yaw prior (``joint_yaw_prior``).
    """
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions
    from calibrate.parallax import calibrate_with_parallax
    from sensor_models.models.synthetic import example_pushbroom_model

    lab = example_pushbroom_model(n_rows=n_rows)
    truth = _jittered_truth(lab, lines, seed=seed)
    rng = np.random.default_rng(seed)
    band = truth.reference_band
    # GCP rows every 24 lines, as a dense matching grid gives them (n_gcps = 0), or random pixels
    if n_gcps:
        rows, cols = rng.uniform(1, n_rows - 1, n_gcps), rng.uniform(1, truth.n_cols - 1, n_gcps)
    else:
        rows, cols = (a.ravel() for a in np.meshgrid(np.arange(12.0, n_rows, 24.0), np.linspace(4, truth.n_cols - 4, 40)))
        n_gcps = rows.size
    lon, lat, h = truth.image_to_ground(rows, cols, height=rng.uniform(0, 1500, n_gcps), band=band)
    from gcpmatch.gcps import GcpTable

    gcps = GcpTable.from_arrays(rows + rng.normal(0, gcp_noise_px, n_gcps), cols + rng.normal(0, gcp_noise_px, n_gcps),
                                lon, lat, h, band=np.full(n_gcps, band), sigma_px=gcp_noise_px)
    t_img = sorted(float(t) for t in lab.line_timing.seconds(np.array([0.0, float(n_rows)])))
    f_lo, f_hi = sorted(f for _, f in lines)[0], sorted(f for _, f in lines)[-1]
    out = {"n_rows": n_rows, "seconds": t_img[1] - t_img[0], "lines": [{"amplitude_urad": list(a), "frequency_hz": f}
                                                                          for a, f in lines],
           "n_gcps": n_gcps, "gcp_noise_px": gcp_noise_px, "tie_noise_px": tie_noise_px,
           "tie_grid_px": [tie_row_step, tie_col_step], "band_offsets_lines": [-6, -2, 2, 6]}
    for mode in ("static", "auto"):
        t0 = time.process_time()
        ref = calibrate_model(lab, gcps, options=CalibrationOptions(attitude=mode))
        model = ref.model
        ties = {}
        for b in (b for b in lab.bands if b != band):  # the relative calibration: interiors from ties
            ties[b] = _synthetic_ties(truth, model, b, row_step=tie_row_step, col_step=tie_col_step,
                                      height_m=height_m, noise_px=tie_noise_px, seed=seed + len(ties))
            model = calibrate_model(model, ties[b].as_gcp_table(), options=CalibrationOptions(scheme="interior")).model
        out[mode] = {"seconds_cpu": time.process_time() - t0, "truth_error_px": _all_bands_error(truth, model, height_m),
                     "selected": (ref.attitude or {}).get("selected", {"kind": "static"}),
                     "jitter": _two_line_fit(model.attitude_correction, *t_img, f_lo, f_hi)}
        print(json.dumps({"mode": mode, "ref": out[mode]["truth_error_px"]["reference_band"]["rms_px"],
                          "other": out[mode]["truth_error_px"]["other_bands_rms_px"], "sel": out[mode]["selected"]}))
    variants = {"joint": None} | ({"joint_yaw_prior": yaw_sigma_urad} if yaw_sigma_urad else {})
    for name, yaw in variants.items():
        t0 = time.process_time()
        joint = calibrate_with_parallax(model, dict(ties), gcps, height=height_m,
                                        options=CalibrationOptions(attitude="auto", attitude_yaw_sigma_urad=yaw))
        angles = joint.correction.angles(np.linspace(*t_img, 2048)) * 1e6 if joint.correction is not None else None
        out[name] = {"seconds_cpu": time.process_time() - t0 + out["auto"]["seconds_cpu"], "success": joint.success,
                     "message": joint.message, "n_ties": joint.n_ties, "n_gcps": joint.n_gcps, "yaw_sigma_urad": yaw,
                     "truth_error_px": _all_bands_error(truth, joint.model, height_m),
                     "selected": joint.to_dict()["selected"],
                     "yaw_peak_to_peak_urad": None if angles is None else float(np.ptp(angles[:, 2])),
                     "jitter": _two_line_fit(joint.correction, *t_img, f_lo, f_hi)}
        print(json.dumps({"mode": name, "ref": out[name]["truth_error_px"]["reference_band"]["rms_px"],
                          "other": out[name]["truth_error_px"]["other_bands_rms_px"], "sel": out[name]["selected"],
                          "msg": joint.message}))
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
    ap.add_argument("--parallax", action="store_true",
                    help="Band parallax (writes bench/results/attitude_parallax.json): synthetic jitter cases at "
                         "--parallax-frequencies (with the 0.3 Hz line), and --scene with static, auto, joint.")
    ap.add_argument("--parallax-frequencies", default="1.5,3.0", help="High jitter lines, Hz, comma-separated.")
    ap.add_argument("--parallax-rows", type=int, default=3000, help="Lines of the synthetic parallax scene.")
    ap.add_argument("--yaw-sigma", type=float, default=None, help="Also run the joint fit with this yaw prior, urad.")
    args = ap.parse_args()
    if args.parallax:
        return main_parallax(args)
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


def main_parallax(args) -> None:
    """``--parallax``: synthetic jitter cases and (with ``--scene``) the scene with the joint path."""
    out_path = args.out.parent / "attitude_parallax.json" if args.out.name == "attitude.json" else args.out
    results = json.loads(out_path.read_text()) if out_path.exists() else {}
    out_path.parent.mkdir(parents=True, exist_ok=True)
    skip = set(filter(None, args.skip.split(",")))
    if "synthetic" not in skip:
        cases = results.setdefault("synthetic", {})
        for f_hi in (float(f) for f in args.parallax_frequencies.split(",")):
            key = f"0.3+{f_hi:g}Hz" + (f"_{args.parallax_rows}lines" if args.parallax_rows != 3000 else "")
            cases[key + ("_yaw_prior" if args.yaw_sigma else "")] = parallax_case(
                n_rows=600 if args.quick else args.parallax_rows, lines=[((5.0, 5.0, 2.0), 0.3), ((5.0, 5.0, 2.0), f_hi)],
                n_gcps=0, tie_row_step=8, tie_col_step=64, tie_noise_px=0.02, gcp_noise_px=0.2,
                yaw_sigma_urad=args.yaw_sigma)
            out_path.write_text(json.dumps(results, indent=1))
    if args.scene is not None:
        work = Path(tempfile.mkdtemp(prefix="gcpcal-attitude-parallax-"))  # outputs of the stages, not kept
        work.mkdir(parents=True, exist_ok=True)
        results[f"scene_{args.scene.name}"] = scene(args.scene, args.gcps, work, modes=("static", "auto", "joint"))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
