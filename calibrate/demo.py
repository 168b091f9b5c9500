"""``gcpcal demo``: the main job, end to end, on the embedded HY-1C-like scene.

``fixtures/hy1c_czi`` holds a simulated level-1A scene (two cameras x two CCDs, four bands)
whose LAB model is about 260 px off, its procedural reference DOM and DEM, and the TRUE model
that rendered it. The demo does what an analyst does with a new scene, then grades it against
the truth:

1. **match** the reference band against the DOM and DEM (coarse SIFT pre-correction, dense phase
   correlation), a fifth of the matches kept apart as check points (``gcps.csv``);
2. **calibrate** the reference band: exterior (installation roll, pitch, yaw) then interior
   (directional angles of each CCD), iterated (seed 003 section 2.2.1); then every other band
   against the calibrated reference band from dense band-to-band tie points (seed 003 section
   2.2.2, :mod:`calibrate.relative`);
3. **report**: check-point accuracy before and after (never used in a fit), per CCD, the HTML
   report with figures, and ``summary.json`` with ``gcps``, ``check_points``,
   ``check_rmse_px {before, after}``, ``truth_error_px {rms, max}`` (calibrated model against
   the TRUE model over a dense grid of every CCD and band, on the DEM) and ``seconds``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from calibrate._json import json_default

__all__ = ["FIXTURE_DIR", "run_demo"]

FIXTURE_DIR = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"


def run_demo(out_dir: Path, *, fixture_dir: Path = FIXTURE_DIR, progress=None, spacing_px: int = 16) -> dict:
    """Run the demo and return its summary (also written to ``out_dir/summary.json``)."""
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions
    from calibrate.accuracy import check_point_accuracy, error_versus_gcp_count
    from calibrate.relative import relative_calibration
    from calibrate.run import points_of
    from gcpmatch.extract import extract_gcps, read_band
    from gcpmatch.options import MatchOptions
    from gcpmatch.gcps import write_gcps_csv
    from sensor_models.atomic import atomic_write_text
    from sensor_models.readers import open_model
    from sensor_models.compare import model_difference
    from sensor_models.raster import MapImage
    from sensor_models.readers.manifest import write_manifest
    from sensor_models.terrain import Dem

    t_start = time.perf_counter()
    step = progress or (lambda message: None)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fixture_dir = Path(fixture_dir)
    lab = open_model(fixture_dir / "manifest.json")
    truth = open_model(fixture_dir / "truth_manifest.json")
    dem = Dem.open(fixture_dir / "reference" / "dem.tif")
    dom = MapImage.open(fixture_dir / "reference" / "dom.tif")
    reference_band = lab.reference_band
    bands = [reference_band] + [b for b in lab.bands if b != reference_band]

    # 1. match the reference band against the DOM and DEM
    step(f"matching band {reference_band} against the DOM")
    merged, summary = extract_gcps(lab, read_band(lab, reference_band), dem, dom, band=reference_band,
                                   options=MatchOptions(spacing_px=spacing_px))
    if merged is None:
        raise RuntimeError(f"band {reference_band}: no GCP ({summary.get('message')})")
    match_summaries = {reference_band: {key: summary[key] for key in ("gcps", "check_points", "usable_fraction",
                                                                      "cloud_fraction")}}
    match_summaries[reference_band]["coarse_inliers"] = summary["coarse"]["inliers"]
    match_summaries[reference_band]["seconds"] = summary["timings"]["total_s"]
    write_gcps_csv(merged, out_dir / "gcps.csv")

    # 2. calibrate the reference band absolutely: exterior then interior (seed 003 2.2.1)
    step(f"calibrating {reference_band}: exterior then interior")
    ref_pts = points_of(merged.gcps())
    result = calibrate_model(lab, merged.gcps(), options=CalibrationOptions(scheme="exterior-interior"))
    band_results = {reference_band: {"success": bool(result.success), "message": result.message}}

    # 3. every other band against the calibrated reference band (seed 003 2.2.2)
    step(f"band-to-band calibration against {reference_band}")
    relative = relative_calibration(result.model, {b: read_band(lab, b) for b in bands}, dem,
                                    reference_band=reference_band)
    model = relative.model
    for band, r in relative.bands.items():
        band_results[band] = {"success": bool(r.success), "message": r.message,
                              "tie_rms_before_px": r.before.get("rms_px"), "tie_rms_after_px": r.after.get("rms_px")}
    write_manifest(model, out_dir / "manifest.json",
                   rasters={b: ref["path"] for b, ref in (lab.rasters or {}).items()})

    # 3. accuracy on the check points, and against the truth
    step("scoring on check points and against the true model")
    checks = points_of(merged.checks(), lab)
    acc_before = check_point_accuracy(lab, checks["row"], checks["col"], checks["lon"], checks["lat"], checks["h"],
                                      band=checks["band"], ccd=checks["ccd"])
    acc_after = check_point_accuracy(model, checks["row"], checks["col"], checks["lon"], checks["lat"], checks["h"],
                                     band=checks["band"], ccd=checks["ccd"])
    t_err = model_difference(truth, model, dem=dem, step_px=8)
    t_err_lab = model_difference(truth, lab, dem=dem, step_px=32)
    ref_checks = checks
    n_ref = int(ref_pts["row"].size)
    counts = sorted({c for c in (20, 50, 100, 200, 400, n_ref) if c <= n_ref})
    step("error versus number of GCPs")
    evc = error_versus_gcp_count(lab, ref_pts, ref_checks, counts, repeats=2, seed=0)
    summary = {
        "kind": "gcpcal.demo",
        "scene": str(fixture_dir / "manifest.json"),
        "gcps": int(np.sum(merged.kind == "gcp")),
        "check_points": int(np.sum(merged.kind == "check")),
        "check_rmse_px": {"before": acc_before.absolute.rmse_px, "after": acc_after.absolute.rmse_px},
        "check_rmse_row_px": {"before": acc_before.absolute.rmse_row_px, "after": acc_after.absolute.rmse_row_px},
        "check_rmse_col_px": {"before": acc_before.absolute.rmse_col_px, "after": acc_after.absolute.rmse_col_px},
        "check_rmse_m": {"before": acc_before.absolute.rmse_m, "after": acc_after.absolute.rmse_m},
        "truth_error_px": {"rms": t_err["rms_px"], "max": t_err["max_px"]},
        "truth_error_before_px": {"rms": t_err_lab["rms_px"], "max": t_err_lab["max_px"]},
        "truth_error_per_ccd": [{k: r[k] for k in ("band", "ccd", "rms_px", "max_px")} for r in t_err["per_ccd"]],
        "per_ccd_after": {k: v.rmse_px for k, v in acc_after.groups.items()},
        "calibration": band_results,
        "installation_arcsec": {
            n.split(".")[1]: float(v) * 180 * 3600 / np.pi
            for n, v in zip(result.names, result.values) if n.startswith("installation.")
        },
        "matching": match_summaries,
        "error_vs_gcp_count": evc,
    }
    try:
        from calibrate.report import write_report

        step("writing the report")
        write_report(out_dir, result=result, accuracy_before=acc_before, accuracy_after=acc_after,
                     initial_model=lab, gcps=ref_pts, checks=checks, error_vs_count=evc, truth_model=truth,
                     title="gcpcal demo: HY-1C-like scene", extra={k: summary[k] for k in ("gcps", "check_points")})
        summary["report"] = "report.html"
    except ImportError:  # pragma: no cover - the report module ships with the package
        summary["report"] = None
    summary["seconds"] = time.perf_counter() - t_start
    atomic_write_text(out_dir / "summary.json", json.dumps(summary, indent=2, default=_json_default) + "\n")
    return summary


_json_default = json_default