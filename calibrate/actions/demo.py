"""Stage action of ``gcpcal demo``: the main job, end to end, on the embedded HY-1C-like scene.

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
   report with figures (band-to-band section per band, error against the TRUE model per band
   and CCD with its curve against the detector), and ``summary.json`` with ``gcps``, ``check_points``,
   ``check_rmse_px {before, after}``, ``truth_error_px {rms, max}`` (calibrated model against
   the TRUE model over a dense grid of every CCD and band, on the DEM), ``status`` (the coverage
   gate of the reference band's calibration, :mod:`calibrate.coverage`: the demo must end
   ``calibrated``), ``variance_factor``, ``coverage`` and ``seconds``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from calibrate.actions._io import staged_output, write_summary
from calibrate.config import CalibrationOptions

__all__ = ["FIXTURE_DIR", "run_demo"]

FIXTURE_DIR = Path(__file__).resolve().parents[2] / "fixtures" / "hy1c_czi"


def _open_fixture(fixture_dir: Path) -> dict:
    """The LAB and TRUE models, DEM, DOM and band order of the fixture."""
    from sensor_models.readers import open_model
    from sensor_models.raster import MapImage
    from sensor_models.terrain import Dem

    lab = open_model(fixture_dir / "manifest.json")
    reference_band = lab.reference_band
    return {"lab": lab, "truth": open_model(fixture_dir / "truth_manifest.json"),
            "dem": Dem.open(fixture_dir / "reference" / "dem.tif"),
            "dom": MapImage.open(fixture_dir / "reference" / "dom.tif"),
            "reference_band": reference_band,
            "bands": [reference_band] + [b for b in lab.bands if b != reference_band]}


def _match(fx: dict, out_dir: Path, spacing_px: int):
    """Phase 1: GCPs of the reference band against the DOM and DEM; writes ``gcps.csv``."""
    from gcpmatch.extract import extract_gcps, read_band
    from gcpmatch.options import MatchOptions
    from gcpmatch.gcps import write_gcps_csv

    lab, band = fx["lab"], fx["reference_band"]
    merged, summary = extract_gcps(lab, read_band(lab, band), fx["dem"], fx["dom"], band=band,
                                   options=MatchOptions(spacing_px=spacing_px))
    if merged is None:
        raise RuntimeError(f"band {band}: no GCP ({summary.get('message')})")
    match_summaries = {band: {key: summary[key] for key in ("gcps", "check_points", "usable_fraction",
                                                            "cloud_fraction")}}
    match_summaries[band]["coarse_inliers"] = summary["coarse"]["inliers"]
    match_summaries[band]["seconds"] = summary["timings"]["total_s"]
    write_gcps_csv(merged, out_dir / "gcps.csv")
    return merged, match_summaries


def _calibrate(fx: dict, merged, out_dir: Path, step):
    """Phase 2: the reference band absolutely, then every other band against it; writes the manifest.

    Returns the reference band's CalibrationResult, the RelativeResult (its ``model``: the final
    model), the GCP columns and the per-band summary rows.
    """
    from calibrate.absolute import calibrate_model
    from calibrate.from_gcps import points_of
    from calibrate.relative import relative_calibration
    from gcpmatch.extract import read_band
    from sensor_models.readers.manifest import write_manifest

    lab, reference_band = fx["lab"], fx["reference_band"]
    step(f"calibrating {reference_band}: exterior then interior")
    ref_pts = points_of(merged.gcps())
    # seed 003 2.2.1: exterior then interior (the default scheme)
    result = calibrate_model(lab, merged.gcps(), options=CalibrationOptions())
    band_results = {reference_band: {"success": bool(result.success), "message": result.message}}
    step(f"band-to-band calibration against {reference_band}")  # seed 003 2.2.2
    # with the band parallax: the GCPs and the tie points estimate the attitude correction together
    relative = relative_calibration(result.model, {b: read_band(lab, b) for b in fx["bands"]}, fx["dem"],
                                    reference_band=reference_band, gcps=merged.gcps(), parallax=True)
    for band, r in relative.bands.items():
        band_results[band] = {"success": bool(r.success), "message": r.message,
                              "tie_rms_before_px": r.before.get("rms_px"), "tie_rms_after_px": r.after.get("rms_px")}
    write_manifest(relative.model, out_dir / "manifest.json",
                   rasters={b: ref["path"] for b, ref in (lab.rasters or {}).items()})
    return result, relative, ref_pts, band_results


def _score(fx: dict, merged, model, ref_pts, step) -> dict:
    """Phase 3: accuracy on the check points, against the truth, and versus the number of GCPs."""
    from calibrate.accuracy import check_point_accuracy, error_versus_gcp_count
    from calibrate.from_gcps import points_of
    from sensor_models.compare import model_difference

    lab, truth, dem = fx["lab"], fx["truth"], fx["dem"]
    step("scoring on check points and against the true model")
    checks = points_of(merged.checks(), lab)
    acc = {name: check_point_accuracy(m, checks["row"], checks["col"], checks["lon"], checks["lat"], checks["h"],
                                      band=checks["band"], ccd=checks["ccd"])
           for name, m in (("before", lab), ("after", model))}
    t_err = model_difference(truth, model, dem=dem, step_px=8)
    t_err_lab = model_difference(truth, lab, dem=dem, step_px=32)
    n_ref = int(ref_pts["row"].size)
    counts = sorted({c for c in (20, 50, 100, 200, 400, n_ref) if c <= n_ref})
    step("error versus number of GCPs")
    evc = error_versus_gcp_count(lab, ref_pts, checks, counts, repeats=2, seed=0)
    return {"checks": checks, "before": acc["before"], "after": acc["after"], "truth": t_err,
            "truth_lab": t_err_lab, "evc": evc}


def _gate(lab, merged, result, sc: dict) -> dict:
    """Coverage gate of the reference band's calibration (:mod:`calibrate.coverage`)."""
    from calibrate.coverage import calibration_coverage, calibration_status
    from calibrate.from_gcps import points_of

    fitted = points_of(merged.gcps(), lab)
    rows = calibration_coverage(lab, fitted, sc["checks"], success=bool(result.success), skipped=result.skipped,
                                weight=fitted["score"])
    status = calibration_status(bool(result.success), result.message, rows)
    return {"status": status.status, "status_message": status.message,
            "variance_factor": result.variance_factor, "coverage": [c.to_dict() for c in rows]}


def _summary(fixture_dir: Path, merged, result, band_results, match_summaries, sc: dict, lab=None) -> dict:
    before, after = sc["before"].absolute, sc["after"].absolute
    gate = _gate(lab, merged, result, sc) if lab is not None else {}
    return {
        "kind": "gcpcal.demo",
        "scene": str(fixture_dir / "manifest.json"),
        **gate,
        "gcps": int(np.sum(merged.kind == "gcp")),
        "check_points": int(np.sum(merged.kind == "check")),
        "check_rmse_px": {"before": before.rmse_px, "after": after.rmse_px},
        "check_rmse_row_px": {"before": before.rmse_row_px, "after": after.rmse_row_px},
        "check_rmse_col_px": {"before": before.rmse_col_px, "after": after.rmse_col_px},
        "check_rmse_m": {"before": before.rmse_m, "after": after.rmse_m},
        "truth_error_px": {"rms": sc["truth"]["rms_px"], "max": sc["truth"]["max_px"]},
        "truth_error_before_px": {"rms": sc["truth_lab"]["rms_px"], "max": sc["truth_lab"]["max_px"]},
        "truth_error_per_ccd": [{k: r[k] for k in ("band", "ccd", "rms_px", "max_px")} for r in sc["truth"]["per_ccd"]],
        "per_ccd_after": {k: v.rmse_px for k, v in sc["after"].groups.items()},
        "calibration": band_results,
        "installation_arcsec": {
            n.split(".")[1]: float(v) * 180 * 3600 / np.pi
            for n, v in zip(result.names, result.values) if n.startswith("installation.")
        },
        "matching": match_summaries,
        "error_vs_gcp_count": sc["evc"],
    }


def _report_coverage(coverage: list, sc: dict) -> list:
    """The coverage rows for the report, each with its CCD's check RMSE before and after (px)."""
    def rmse(which, row):
        group = sc[which].groups.get(f"{row['band']}.{row['ccd']}")
        return None if group is None else group.rmse_px

    return [dict(row, check_rmse_px={w: rmse(w, row) for w in ("before", "after")}) for row in coverage]


@staged_output("out_dir", inputs=("fixture_dir",), prefix=".demo-")
def run_demo(out_dir, *, fixture_dir: Path = FIXTURE_DIR, progress=None, spacing_px: int = 16) -> dict:
    """Run the demo (see the module docstring).

    Parameters
    ----------
    out_dir : str or Path
        Output folder: ``gcps.csv``, ``manifest.json``, ``report.html``, ``figures/``,
        ``summary.json``.
    fixture_dir : Path
        The fixture (default: the embedded ``fixtures/hy1c_czi``).
    progress : callable(str), optional
        Receives progress messages.
    spacing_px : int
        Matching window spacing, pixels.

    Returns
    -------
    dict
        The summary also written to ``out_dir/summary.json``.
    """
    from calibrate.report import write_report
    from sensor_models.base import CalibrationStatus

    t_start = time.perf_counter()
    step = progress or (lambda message: None)
    out_dir, fixture_dir = Path(out_dir), Path(fixture_dir)  # out_dir: the staging folder (staged_output)
    fx = _open_fixture(fixture_dir)
    step(f"matching band {fx['reference_band']} against the DOM")
    merged, match_summaries = _match(fx, out_dir, spacing_px)
    result, relative, ref_pts, band_results = _calibrate(fx, merged, out_dir, step)
    sc = _score(fx, merged, relative.model, ref_pts, step)
    summary = _summary(fixture_dir, merged, result, band_results, match_summaries, sc, lab=fx["lab"])
    summary["parallax"] = {k: v for k, v in (relative.parallax or {}).items()
                           if k in ("used", "reason", "message", "ties", "gcps", "rounds", "selected", "gcp_only")}
    step("writing the report")
    write_report(out_dir, result=result, accuracy_before=sc["before"], accuracy_after=sc["after"],
                 initial_model=fx["lab"], gcps=ref_pts, checks=sc["checks"], error_vs_count=sc["evc"],
                 truth_model=fx["truth"], title="gcpcal demo: HY-1C-like scene",
                 extra={k: summary[k] for k in ("gcps", "check_points")}, relative=relative,
                 truth_error={"after": sc["truth"], "before": sc["truth_lab"]}, coverage=_report_coverage(summary["coverage"], sc),
                 status=CalibrationStatus(summary["status"], summary["status_message"]))
    summary["report"] = "report.html"
    summary["seconds"] = time.perf_counter() - t_start
    write_summary(out_dir / "summary.json", summary)
    return summary
