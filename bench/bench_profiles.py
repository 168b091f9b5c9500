"""Measure: the same scene under the ``ideal`` and the ``realistic`` error profile, end to end.

For each profile: ``gcpcal simulate pushbroom --profile P`` (a demo-size scene: the embedded
fixture's camera, 4 CCDs x 192 detectors, 512 lines, 4 bands, at the GSD of ``--gsd``), then the
user's chain on what the simulation wrote (``match`` against ``reference/dom.tif`` and
``reference/dem.tif``, ``calibrate``, ``relative``, ``truth error``), and the GCPs' own error
against the TRUE model: each GCP's ground point (lon, lat, h as matched on the DOM and DEM the
user has) projected through ``truth_manifest.json``, minus the matched (row, col).

``--source`` gives the realistic profile its source radiance (default: the Sentinel-2 red band
of ``../shared/data/real_textures``, when present; ``procedural`` for the procedural texture).
The ideal profile always uses the default procedural reference (its DOM rendered the scene).

Usage: ``python bench/bench_profiles.py --out /tmp/profiles [--gsd 20] [--source procedural] [--relief 600]``

Ablations (``--profiles``) switch groups of ``realistic`` off one at a time (:data:`ABLATIONS`),
among them ``no_sun``, ``no_broadband_jitter``, ``no_astigmatism``; ``cloudy`` and
``cloudy_no_shadow`` add 20 % of 1 km clouds with and without their shadows.
Writes ``OUT/profiles.json`` and prints one line per profile.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
S2_RED = ROOT.parent / "shared" / "data" / "real_textures" / "sentinel2" / "s2_B04.jp2"
# the end-to-end chain as a library (``gcpcal experiment 003``): calibrate/experiments/simulate_seed003.py


def _gcpcal(*args) -> None:
    cmd = [shutil.which("gcpcal") or "gcpcal", "-q", *map(str, args)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env)
    if done.returncode not in (0, 4):
        raise SystemExit(f"{' '.join(cmd)} -> {done.returncode}\n{done.stderr[-2000:]}")


def gcp_truth_error(scene: Path, gcps_csv: Path) -> dict:
    """RMS / max of (matched row, col) minus the TRUE model's projection of each GCP's ground point
    (:func:`calibrate.experiments.simulate_seed003.gcp_truth_error`)."""
    from calibrate.experiments.simulate_seed003 import gcp_truth_error as _gcp_truth_error
    from gcpmatch.gcp_files import read_gcps
    from sensor_models.readers import open_model

    return _gcp_truth_error(open_model(scene / "truth_manifest.json"), read_gcps(gcps_csv))


#: ``realistic`` with groups of its errors switched off, to explain the figures point by point
ABLATIONS = {
    "no_dom_error": {"dom_bias_m": (0.0, 0.0), "dom_field_rms_m": 0.0},
    "no_dem_error": {"dem_error_rms_m": 0.0, "dem_void_fraction": 0.0},
    "no_date_sensor": {"seasonal_change": 0.0, "haze": 0.0, "reference_gamma": 1.0},
    "no_reference_change": {"dom_bias_m": (0.0, 0.0), "dom_field_rms_m": 0.0, "dem_error_rms_m": 0.0,
                            "dem_void_fraction": 0.0, "seasonal_change": 0.0, "haze": 0.0, "reference_gamma": 1.0},
    "no_attitude_orbit": {"star_tracker_noise_urad": 1.0, "jitter_amplitude_urad": (1.0, 1.0, 0.5),
                          "jitter_frequency_hz": 1.3, "orbit_bias_m": 0.0},
    "no_lens": {"radial_k2_px": 0.0, "radial_k3_px": 0.0, "focal_plane_curvature_px": 0.0, "ccd_bending_px": 0.0,
                "detector_irregularity_px": 0.0},
}
#: sun, broadband jitter, astigmatism, clouds: one at a time (each: realistic minus it)
NO_SUN = {"sun_scene_date_time": None, "sun_dom_date_time": None}
NO_BROADBAND = {"jitter_line2_amplitude_urad": (0.0, 0.0, 0.0), "jitter_floor_rms_urad": (0.0, 0.0, 0.0)}
ABLATIONS.update({"no_sun": NO_SUN, "no_broadband_jitter": NO_BROADBAND,
                  "no_astigmatism": {"astigmatism_edge_px": (0.0, 0.0)}})
ABLATIONS["no_date_sensor"] = {**ABLATIONS["no_date_sensor"], **NO_SUN}
ABLATIONS["no_reference_change"] = {**ABLATIONS["no_reference_change"], **NO_SUN}
ABLATIONS["no_attitude_orbit"] = {**ABLATIONS["no_attitude_orbit"], **NO_BROADBAND}
#: kernel and reference resolution only: every other group of realistic switched off
ABLATIONS["kernel_only"] = {**ABLATIONS["no_reference_change"], **ABLATIONS["no_attitude_orbit"], **ABLATIONS["no_lens"]}
#: a cloudy realistic scene (``clouds.cover`` of the configuration), with and without the clouds' shadows
CLOUDY = {"cloudy": {}, "cloudy_no_shadow": {"cloud_shadow": 0.0}}
CLOUD_COVER = 0.2
CLOUD_SCALE_M = 1000.0
ABLATIONS.update(CLOUDY)


def _simulate(scene: Path, name: str, config: Path, source) -> None:
    """``gcpcal simulate pushbroom`` for a named profile; through the library for an ablation."""
    if name in ABLATIONS:
        from dataclasses import replace

        from sensor_models.simulate.config import load_config
        from sensor_models.simulate.profiles import PROFILES, Sourced
        from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

        changes = {k: Sourced(v, f"ablation {name}") for k, v in ABLATIONS[name].items()}
        profile = replace(PROFILES["realistic"], name=f"realistic-{name}", **changes)
        cfg = load_config(config)
        if name in CLOUDY:  # a field of small clouds, so that each layer holds some
            cfg = replace(cfg, clouds=replace(cfg.clouds, cover=CLOUD_COVER, scale_m=CLOUD_SCALE_M))
        simulate_pushbroom(scene, config=cfg, profile=profile, dom=source)
        return
    sim = ["simulate", "pushbroom", "--out", scene, "--config", config, "--profile", name]
    if name != "ideal" and source is not None:
        sim += ["--dom", source]
    _gcpcal(*sim)


def run_profile(out: Path, profile: str, config: Path, source) -> dict:
    scene = out / profile
    _simulate(scene, profile, config, source)
    dom, dem = scene / "reference" / "dom.tif", scene / "reference" / "dem.tif"
    _gcpcal("match", scene / "manifest.json", "--dom", dom, "--dem", dem, "--out", out / f"{profile}_gcps.csv")
    _gcpcal("calibrate", scene / "manifest.json", "--gcps", out / f"{profile}_gcps.csv", "--out", out / f"{profile}_cal",
            "--no-report")
    _gcpcal("relative", scene / "manifest.json", "--calibration", out / f"{profile}_cal", "--dem", dem,
            "--out", out / f"{profile}_rel")
    _gcpcal("truth", "error", out / f"{profile}_rel" / "manifest.json", "--truth", scene / "truth_manifest.json",
            "--dem", dem, "--out", out / f"{profile}_truth.json")
    cal = json.loads((out / f"{profile}_cal" / "calibration.json").read_text())
    match = json.loads((out / f"{profile}_gcps.summary.json").read_text())
    truth = json.loads((out / f"{profile}_truth.json").read_text())
    sim_summary = json.loads((scene / "summary.json").read_text())
    return {"profile": profile, "match": {k: match.get(k) for k in ("gcps", "check_points")},
            "check_rmse_px": _check_rmse(cal), "truth_error_px": {k: truth.get(k) for k in ("rms_px", "max_px")},
            "gcp_truth_error_px": gcp_truth_error(scene, out / f"{profile}_gcps.csv"),
            "injected": sim_summary.get("injected"), "render_seconds": sim_summary.get("render_seconds")}


def _check_rmse(cal: dict) -> dict:
    """Check-point RMSE before and after calibration (``calibration.json``), pixels."""
    checks = cal.get("check_accuracy") or {}
    return {k: (checks.get(k) or {}).get("absolute", {}).get("rmse_px") for k in ("before", "after")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--gsd", type=float, default=20.0, help="Scene GSD, m (20: the scene fits the Sentinel-2 crop).")
    ap.add_argument("--source", default=str(S2_RED) if S2_RED.exists() else "procedural")
    ap.add_argument("--relief", type=float, default=600.0, help="reference.relief_m of the TRUE DEM, m.")
    ap.add_argument("--profiles", default="ideal,realistic",
                    help=f"Profiles and ablations of realistic ({', '.join(ABLATIONS)}), comma-separated.")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    config = args.out / "config.json"
    config.write_text(json.dumps({"scene": {"gsd_m": args.gsd},
                                  "reference": {"margin_m": 1000.0, "relief_m": args.relief}}))
    source = None if args.source == "procedural" else args.source
    results = {"gsd_m": args.gsd, "source": args.source, "relief_m": args.relief, "profiles": {}}
    for p in args.profiles.split(","):
        r = run_profile(args.out, p, config, source)
        results["profiles"][p] = r
        print(json.dumps({k: r[k] for k in ("profile", "match", "check_rmse_px", "truth_error_px",
                                             "gcp_truth_error_px")}))
    if {"ideal", "realistic"} <= set(results["profiles"]):
        g = {p: results["profiles"][p]["gcp_truth_error_px"]["rms_px"] for p in ("ideal", "realistic")}
        results["gcp_truth_error_ratio_realistic_over_ideal"] = g["realistic"] / g["ideal"]
        print(f"GCP truth-error ratio realistic/ideal: {g['realistic'] / g['ideal']:.2f}")
    (args.out / "profiles.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
