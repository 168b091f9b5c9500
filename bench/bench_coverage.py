"""Coverage of the calibration's 95 % intervals on realistic scenes, before and after the honest covariance.

The scenes and their matches are those of ``bench/bench_matcher_realism.py --coverage-seeds``
(its ``--cache``: ``realistic[_procedural]_seedN`` scenes and ``chain_<scene>_default/gcps.csv``
with the match summary beside it; missing matches are made with the production ``match``
action). Per scene and variant the bench runs the calibration action
(:func:`calibrate.actions.calibrate.calibrate_scene`) twice: on the matched GCPs, and on the same
GCPs observed exactly (each ground point projected through the TRUE model: the model family's
best fit to the truth, same points and weights). For each installation angle
``z = (value - exact value) / reported sigma``; the bench reports the share with ``|z| <= 1.96``
(coverage of the 95 % intervals) and the rms z, over all angles and per source texture
(Sentinel-2 red band, procedural), plus check RMSE and the truth error (px, calibrated model
against the TRUE one on the true DEM).

Variants (:class:`calibrate.config.CalibrationOptions`):

* ``before``: the covariance scaled by ``sigma0^2`` and no reference term (the state before);
* ``floor``: scaled by ``max(1, sigma0^2)``;
* ``after``: floor plus the reference DOM's common shift (the match summary's
  ``reference_accuracy``), the production default of ``gcpcal calibrate``;
* ``after_sigma_only``: as ``after``, GCPs weighted by ``1 / sigma_px^2`` instead of
  ``score / sigma_px^2`` (the ``window`` sigma model already holds the score);
* ``after_field_oracle``: as ``after``, with the simulator's DOM error field (rms and correlation
  length, which no DOM states) given as ``reference_field_m``: what a field term would add.

Usage: ``python bench/bench_coverage.py --cache /tmp/sigma_cache --work /tmp/cov_work
[--seeds 3,5,9] [--out bench/results/coverage.json]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_matcher_realism import _exact_gcps  # noqa: E402  (the same exact-observation GCPs)

INSTALLATION = ("installation.roll", "installation.pitch", "installation.yaw")
ARCSEC_PER_RAD = 206264.806
TEXTURES = ("realistic", "realistic_procedural")
#: variant -> CalibrationOptions changes (``reference_sigma_m=0``: no reference term)
VARIANTS = {
    "before": {"covariance_floor": False, "reference_sigma_m": 0.0},
    "floor": {"covariance_floor": True, "reference_sigma_m": 0.0},
    "after": {},
    "after_sigma_only": {"score_weight": False},
    # diagnostic: the realistic profile's DOM field (0.8 m rms; its generator's correlation
    # exp(-r^2 / (4 L^2)) with L = 3 km, i.e. l = sqrt(2) L) given to the calibration
    "after_field_oracle": {"reference_field_m": (0.8, 3000.0 * 2**0.5)},
}


def _gcps(cache: Path, scene: str) -> Path:
    """The matched GCPs of ``scene`` (matched now with the production action when not cached)."""
    chain = cache / f"chain_{scene}_default"
    if not (chain / "gcps.csv").exists():
        from calibrate.actions.match import match_scene
        from gcpmatch.options import MatchOptions

        chain.mkdir(parents=True, exist_ok=True)
        ref = cache / scene / "reference"
        match_scene(cache / scene / "manifest.json", dom_path=ref / "dom.tif", dem_path=ref / "dem.tif",
                    out_path=chain / "gcps.csv", options=MatchOptions())
    return chain / "gcps.csv"


def _calibrate(scene: Path, gcps: Path, out: Path, changes: dict) -> dict:
    from calibrate.actions.calibrate import calibrate_scene
    from calibrate.config import CalibrationOptions

    shutil.rmtree(out, ignore_errors=True)
    calibrate_scene(scene / "manifest.json", gcps, out, options=CalibrationOptions(**changes), report=False)
    return json.loads((out / "calibration.json").read_text())


def _truth_error_px(scene: Path, cal_dir: Path, band: str) -> float:
    """RMS (px) of the calibrated model of ``band`` against the TRUE model, on the true DEM."""
    from sensor_models.models.compare import model_difference
    from sensor_models.terrain.dem import Dem
    from sensor_models.readers import open_model

    dem = Dem.open(scene / "reference" / "truth" / "dem_true.tif")
    truth, model = open_model(scene / "truth_manifest.json"), open_model(cal_dir / "manifest.json")
    return float(model_difference(truth, model, dem=dem, step_px=16.0, bands=[band])["rms_px"])


def run_scene(cache: Path, work: Path, scene: str, variant: str) -> dict:
    """One scene, one variant: z of the installation angles, check RMSE, truth error."""
    changes = VARIANTS[variant]
    gcps = _gcps(cache, scene)
    out = work / f"{scene}_{variant}"
    out.mkdir(parents=True, exist_ok=True)
    _exact_gcps(cache / scene, gcps, out / "exact.csv")
    cal = _calibrate(cache / scene, gcps, out / "cal", changes)
    exact = _calibrate(cache / scene, out / "exact.csv", out / "cal_exact", changes)
    est = {p["name"]: (p["value"], p["sigma"]) for p in cal["parameters"] if p["name"] in INSTALLATION}
    ref = {p["name"]: p["value"] for p in exact["parameters"] if p["name"] in INSTALLATION}
    after = ((cal.get("check_accuracy") or {}).get("after") or {}).get("absolute") or {}
    return {
        "variance_factor": cal.get("variance_factor"),
        "covariance_factor": cal.get("covariance_factor"),
        "reference_accuracy": cal.get("reference_accuracy"),
        "check_rmse_px": after.get("rmse_px"),
        "truth_error_px": _truth_error_px(cache / scene, out / "cal", cal["points"]["band"][0]),
        "installation_z": {k.split(".")[1]: (est[k][0] - ref[k]) / est[k][1] for k in INSTALLATION},
        "installation_sigma_arcsec": {k.split(".")[1]: est[k][1] * ARCSEC_PER_RAD for k in INSTALLATION},
        "installation_error_arcsec": {k.split(".")[1]: (est[k][0] - ref[k]) * ARCSEC_PER_RAD for k in INSTALLATION},
    }


def _exact_table(truth, table, band):
    """``table``'s GCPs observed exactly through the TRUE model (same ground points, sigma, score)."""
    from gcpmatch.gcps import GcpTable

    row, col = truth.ground_to_image(table.lon, table.lat, table.h, band=band, array=table.ccd)
    ok = np.isfinite(row) & np.isfinite(col)
    cols = {k: np.asarray(getattr(table, k))[ok] for k in ("lon", "lat", "h", "sigma_px", "band", "ccd", "score",
                                                         "kind", "id")}
    return GcpTable.from_arrays(row[ok], col[ok], **cols)


def demo_runs(fixture: Path) -> dict:
    """The demo's match and reference-band calibration on ``fixture``, per variant: variance factor,
    installation sigma and z against the exact-observation fit, truth error of the reference band."""
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions
    from calibrate.pipelines.demo import TRUE_DEM, fixture_profile
    from calibrate.pipelines.scene import GCP_FILE, match_step
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.options import MatchOptions
    from sensor_models.models.compare import model_difference
    from sensor_models.readers import open_model
    from sensor_models.terrain.dem import Dem

    reference = fixture / "reference"
    true_dem = fixture / TRUE_DEM if (fixture / TRUE_DEM).exists() else reference / "dem.tif"
    fx = {"lab": open_model(fixture / "manifest.json"), "truth": open_model(fixture / "truth_manifest.json"),
          "true_dem": Dem.open(true_dem), "profile": fixture_profile(fixture)}
    band = fx["lab"].reference_band
    with tempfile.TemporaryDirectory() as tmp:  # the demo's match step (gcpcal match --spacing 16)
        summary = match_step(fixture / "manifest.json", tmp, dom_path=reference / "dom.tif",
                             dem_path=reference / "dem.tif", options=MatchOptions(spacing_px=16))
        merged = read_gcps(Path(tmp) / GCP_FILE)
    acc = summary["reference_accuracy"]
    gcps = merged.gcps()
    exact = _exact_table(fx["truth"], gcps, band)
    out = {"fixture": fixture.name, "profile": fx["profile"], "gcps": len(gcps), "reference_accuracy": acc,
           "variants": {}}
    for variant, changes in VARIANTS.items():
        opts = {"reference_sigma_m": (acc["east_m"], acc["north_m"]), "reference_source": "match", **changes}
        result = calibrate_model(fx["lab"], gcps, options=CalibrationOptions(**opts))
        ref = calibrate_model(fx["lab"], exact, options=CalibrationOptions(**opts))
        pos = {n: j for j, n in enumerate(result.names)}
        rpos = {n: j for j, n in enumerate(ref.names)}
        sig = result.sigma
        t_err = model_difference(fx["truth"], result.model, dem=fx["true_dem"], step_px=8, bands=[band])
        out["variants"][variant] = {
            "variance_factor": result.variance_factor,
            "installation_sigma_arcsec": {k.split(".")[1]: float(sig[pos[k]]) * ARCSEC_PER_RAD for k in INSTALLATION},
            "installation_z": {k.split(".")[1]: float((result.values[pos[k]] - ref.values[rpos[k]]) / sig[pos[k]])
                               for k in INSTALLATION},
            "truth_error_reference_band_px": float(t_err["rms_px"]),
        }
    return out


def share(z) -> dict:
    """Coverage of the 95 % intervals (``|z| <= 1.96``) and rms z."""
    v = np.abs(np.asarray(z, dtype=float))
    return {"angles": int(v.size), "covered_95": float(np.mean(v <= 1.96)), "rms_z": float(np.sqrt(np.mean(v**2)))}


def summarize(runs: dict) -> dict:
    """Per variant: coverage over every angle, per texture, and per angle; mean check and truth errors."""
    out = {}
    for variant, scenes in runs.items():
        z_all = [z for r in scenes.values() for z in r["installation_z"].values()]
        entry = {"all": share(z_all)}
        for t in TEXTURES:
            entry[t] = share([z for s, r in scenes.items() if s.rsplit("_seed", 1)[0] == t
                              for z in r["installation_z"].values()])
        for axis in ("roll", "pitch", "yaw"):
            entry[axis] = share([r["installation_z"][axis] for r in scenes.values()])
        entry["mean_check_rmse_px"] = float(np.mean([r["check_rmse_px"] for r in scenes.values()]))
        entry["mean_truth_error_px"] = float(np.mean([r["truth_error_px"] for r in scenes.values()]))
        out[variant] = entry
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--seeds", default="3,5,9")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "coverage.json")
    ap.add_argument("--demo", default="hy1c_czi_realistic,hy1c_czi",
                    help="Fixtures (under fixtures/) whose demo match and calibration are also measured ('' for none).")
    args = ap.parse_args()
    scenes = [f"{t}_seed{s}" for s in map(int, args.seeds.split(",")) for t in TEXTURES]
    runs = {}
    t0 = time.perf_counter()
    for variant in args.variants.split(","):
        runs[variant] = {}
        for scene in scenes:
            r = runs[variant][scene] = run_scene(args.cache, args.work, scene, variant)
            z = " ".join(f"{k} {v:+.2f}" for k, v in r["installation_z"].items())
            print(f"{variant:>16} {scene:>28}: vf {r['variance_factor']:.2f} check {r['check_rmse_px']:.4f} px "
                  f"truth {r['truth_error_px']:.4f} px  z {z}", flush=True)
    summary = summarize(runs)
    for variant, s in summary.items():
        print(f"{variant:>16}: coverage {100 * s['all']['covered_95']:.0f} % rms z {s['all']['rms_z']:.2f}  "
              + "  ".join(f"{t} {100 * s[t]['covered_95']:.0f} % / {s[t]['rms_z']:.2f}" for t in TEXTURES), flush=True)
    demo = {}
    for name in filter(None, args.demo.split(",")):
        demo[name] = d = demo_runs(ROOT / "fixtures" / name)
        for variant, r in d["variants"].items():
            z = " ".join(f"{k} {v:+.2f}" for k, v in r["installation_z"].items())
            sg = " ".join(f"{k} {v:.3f}" for k, v in r["installation_sigma_arcsec"].items())
            print(f"demo {name} ({d['profile']}) {variant:>16}: vf {r['variance_factor']:.2f} truth (ref band) "
                  f"{r['truth_error_reference_band_px']:.4f} px  sigma {sg} arcsec  z {z}", flush=True)
    doc = {"kind": "gcpcal.bench.coverage", "profile": "realistic", "scenes": scenes,
           "variants": {k: VARIANTS[k] for k in runs}, "summary": summary, "runs": runs, "demo": demo,
           "seconds": time.perf_counter() - t0}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
