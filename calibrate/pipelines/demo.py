"""``gcpcal demo``: the scene pipeline a user runs, on an embedded HY-1C-like scene, graded against the truth.

Two embedded fixtures (:data:`FIXTURES`, ``fixtures/make_hy1c_fixture.py``) hold a simulated
level-1A scene (two cameras x two CCDs x 192 detectors, four bands, 512 lines, 30 m) whose LAB
model is about 260 px off, the reference DOM and DEM a user matches against, and the TRUE model
that rendered it:

* ``realistic`` (the default, ``fixtures/hy1c_czi_realistic``): the ``realistic`` error profile
  (docs/error_budget.md): the scene rendered by the simulator's own kernel with attitude jitter, an
  orbit bias and a lens beyond the cubic; the user's DOM is another date and sensor at 30 m with
  1-3 m of geolocation error, the user's DEM SRTM-like (90 m, 8 m error, voids); the TRUE DEM is
  kept apart (``reference/truth/dem_true.tif``);
* ``ideal`` (``fixtures/hy1c_czi``): the ``ideal`` profile, whose DOM and DEM are what rendered the
  scene: a unit-test scene, not an accuracy claim.

The demo does what an analyst does with a new scene, through the very stage actions the commands
call (:func:`calibrate.pipelines.scene.scene_pipeline`, folder layout there), then grades it
against the truth:

1. **match** (``gcpcal match --spacing 16``) the reference band against the DOM and DEM (coarse
   SIFT pre-correction, dense phase correlation), a fifth of the matches kept apart as check
   points (``gcps.csv``);
2. **calibrate** (``gcpcal calibrate``, into ``calibration/``) the reference band: exterior
   (installation roll, pitch, yaw, and the time-varying attitude correction chosen by BIC,
   :mod:`calibrate.attitude`) then interior (directional angles of each CCD), iterated (seed 003
   section 2.2.1); then (``gcpcal relative``, ``manifest.json``) every other band against the
   calibrated reference band from dense band-to-band tie points, with the band parallax (seed 003
   section 2.2.2, :mod:`calibrate.relative`);
3. **report**: check-point accuracy before and after (never used in a fit), overall and per CCD,
   the HTML report with figures, and ``summary.json`` with ``fixture``, ``profile``, ``gcps``,
   ``check_points``, ``check_rmse_px {before, after}``, ``check_rmse_per_ccd_px``,
   ``truth_error_px {rms, max}`` (the calibrated model of every CCD and band against the TRUE
   model over a dense grid, both localizing on the TRUE DEM named by ``truth_dem``: the user's DEM
   only under the ``ideal`` profile, where it is the TRUE one), ``status`` (the coverage gate of the reference band's calibration,
   :mod:`calibrate.coverage`, made ``partial`` when a band-to-band calibration fails or
   leaves a CCD's interior unestimated),
   ``variance_factor``, ``attitude`` (the correction selected), ``coverage``, ``model`` (the
   final model's file, ``relative/manifest.json``) and ``seconds``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from calibrate.actions._io import staged_output, write_summary
from calibrate.actions._provenance import provenance_record

__all__ = ["DEFAULT_FIXTURE", "FIXTURES", "FIXTURE_DIR", "TRUE_DEM", "fixture_profile", "run_demo"]

_FIXTURES_ROOT = Path(__file__).resolve().parents[2] / "fixtures"
#: the embedded scenes by name (``gcpcal demo --fixture NAME``), written by ``fixtures/make_hy1c_fixture.py``
FIXTURES = {"realistic": _FIXTURES_ROOT / "hy1c_czi_realistic", "ideal": _FIXTURES_ROOT / "hy1c_czi"}
#: the scene ``gcpcal demo`` calibrates without ``--fixture``
DEFAULT_FIXTURE = "realistic"
FIXTURE_DIR = FIXTURES[DEFAULT_FIXTURE]
#: a fixture's TRUE DEM, relative to the fixture, when the user's ``reference/dem.tif`` is not it
TRUE_DEM = Path("reference") / "truth" / "dem_true.tif"


def fixture_profile(fixture_dir) -> str:
    """The error profile a simulated scene was rendered with.

    Parameters
    ----------
    fixture_dir : str or Path
        A folder written by ``gcpcal simulate pushbroom`` (``summary.json``).

    Returns
    -------
    str
        ``summary.json``'s ``profile`` (``"ideal"`` when absent: the simulator writes none for it).
    """
    import json

    summary = json.loads((Path(fixture_dir) / "summary.json").read_text(encoding="utf-8"))
    return str(summary.get("profile", "ideal"))


def _open_fixture(fixture_dir: Path) -> dict:
    """The LAB and TRUE models, the TRUE DEM and the paths the user's path takes (scene, DOM, DEM)."""
    from sensor_models.readers import open_model
    from sensor_models.terrain.dem import Dem

    # under the ideal profile the user's DEM is the one that rendered the scene
    true_dem_path = TRUE_DEM if (fixture_dir / TRUE_DEM).exists() else Path("reference") / "dem.tif"
    return {"scene": fixture_dir / "manifest.json", "dom": fixture_dir / "reference" / "dom.tif",
            "dem": fixture_dir / "reference" / "dem.tif", "lab": open_model(fixture_dir / "manifest.json"),
            "truth": open_model(fixture_dir / "truth_manifest.json"), "true_dem": Dem.open(fixture_dir / true_dem_path),
            "true_dem_path": true_dem_path.as_posix(), "profile": fixture_profile(fixture_dir)}


def _user_path(fx: dict, out_dir: Path, spacing_px: int, step):
    """Phases 1 and 2: the user's match -> calibrate -> relative (:func:`calibrate.pipelines.scene.scene_pipeline`).

    Returns the final model's file (relative to ``out_dir``), the GCP table the match stage
    wrote, the reference band's CalibrationResult, the RelativeResult (its ``model``: the final
    model; None when the calibration failed), the reference band's GCP columns, the per-band
    summary rows and the match figures.
    """
    from calibrate.from_gcps import points_of
    from calibrate.pipelines.scene import GCP_FILE, scene_pipeline
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.options import MatchOptions

    run = scene_pipeline(fx["scene"], dom_path=fx["dom"], dem_path=fx["dem"], out_dir=out_dir,
                         match_options=MatchOptions(spacing_px=spacing_px), report=False, progress=step)
    merged, match, result, relative = read_gcps(out_dir / GCP_FILE), run.match, run.calibration, run.relative_result
    reference_band = match["band"]
    match_summaries = {reference_band: {key: match[key] for key in ("gcps", "check_points", "usable_fraction",
                                                                    "cloud_fraction")}}
    match_summaries[reference_band].update(coarse_inliers=match["coarse"]["inliers"],
                                           seconds=match["timings"]["total_s"],
                                           reference_accuracy=match.get("reference_accuracy"))
    band_results = {reference_band: {"success": bool(result.success), "message": result.message}}
    for band, r in (relative.bands.items() if relative is not None else ()):
        skipped = [] if r.calibration is None else r.calibration.skipped
        band_results[band] = {"success": bool(r.success), "message": r.message,
                              "tie_rms_before_px": r.before.get("rms_px"), "tie_rms_after_px": r.after.get("rms_px"),
                              "ccds_not_calibrated": [f"{band}.{k['ccd']}" for k in skipped]}
    return run.model, merged, result, relative, points_of(merged.gcps()), band_results, match_summaries


def _score(fx: dict, merged, model, ref_pts, step) -> dict:
    """Phase 3: accuracy on the check points, against the truth, and versus the number of GCPs."""
    from calibrate.accuracy import check_point_accuracy, error_versus_gcp_count
    from calibrate.from_gcps import points_of
    from sensor_models.models.compare import model_difference

    lab, truth, true_dem = fx["lab"], fx["truth"], fx["true_dem"]
    step("scoring on check points and against the true model")
    checks = points_of(merged.checks(), lab)
    acc = {name: check_point_accuracy(m, checks["row"], checks["col"], checks["lon"], checks["lat"], checks["h"],
                                      band=checks["band"], ccd=checks["ccd"])
           for name, m in (("before", lab), ("after", model))}
    # both models localize on the TRUE terrain: the user's DEM errors are part of what is graded
    t_err = model_difference(truth, model, dem=true_dem, step_px=8)
    t_err_lab = model_difference(truth, lab, dem=true_dem, step_px=32)
    n_ref = int(ref_pts["row"].size)
    counts = sorted({c for c in (20, 50, 100, 200, 400, n_ref) if c <= n_ref})
    step("error versus number of GCPs")
    evc = error_versus_gcp_count(lab, ref_pts, checks, counts, repeats=2, seed=0)
    return {"checks": checks, "before": acc["before"], "after": acc["after"], "truth": t_err,
            "truth_lab": t_err_lab, "evc": evc}


def _gate(lab, merged, result, band_results: dict, sc: dict) -> dict:
    """Coverage gate of the reference band's calibration (:mod:`calibrate.coverage`), then the other bands.

    A band whose band-to-band calibration failed, or a CCD whose interior it could not estimate,
    makes a calibrated run ``partial``, named.
    """
    from calibrate.coverage import calibration_coverage, calibration_status
    from calibrate.from_gcps import points_of

    fitted = points_of(merged.gcps(), lab)
    rows = calibration_coverage(lab, fitted, sc["checks"], success=bool(result.success), skipped=result.skipped,
                                weight=fitted["score"])
    status = calibration_status(bool(result.success), result.message, rows)
    state, message = status.status, status.message
    failed = [f"{band} ({r['message']})" for band, r in band_results.items() if not r["success"]]
    left = [name for r in band_results.values() if r["success"] for name in r.get("ccds_not_calibrated", ())]
    texts = ([f"band-to-band calibration failed: {'; '.join(failed)}"] if failed else []) + \
        ([f"not calibrated by band-to-band: {', '.join(left)}"] if left else [])
    if texts and state != "failed":
        text = "; ".join(texts)
        state, message = "partial", text if state == "calibrated" else f"{message}; {text}"
    return {"status": state, "status_message": message,
            "variance_factor": result.variance_factor, "coverage": [c.to_dict() for c in rows]}


def _attitude_selection(result) -> dict:
    """The time-varying attitude correction the calibration chose (:mod:`calibrate.attitude`)."""
    info = result.attitude
    if info is None:
        return {"mode": "static", "selected": {"kind": "static", "n_terms": 0}}
    return {k: info[k] for k in ("mode", "selected", "jitter", "failed") if k in info}


def _per_ccd(sc: dict) -> dict:
    """Check RMSE before and after of every band and CCD (``"B2.cam1_ccd1"``), px."""
    names = sorted(k for k in sc["after"].groups if "." in k)
    return {name: {w: (sc[w].groups[name].rmse_px if name in sc[w].groups else None) for w in ("before", "after")}
            for name in names}


def _summary(fx: dict, fixture_dir: Path, merged, result, band_results, match_summaries, sc: dict) -> dict:
    before, after = sc["before"].absolute, sc["after"].absolute
    return {
        "kind": "gcpcal.demo",
        "scene": str(fixture_dir / "manifest.json"),
        "fixture": fixture_dir.name,
        "profile": fx["profile"],
        **_gate(fx["lab"], merged, result, band_results, sc),
        "gcps": int(np.sum(merged.kind == "gcp")),
        "check_points": int(np.sum(merged.kind == "check")),
        "check_rmse_px": {"before": before.rmse_px, "after": after.rmse_px},
        "check_rmse_row_px": {"before": before.rmse_row_px, "after": after.rmse_row_px},
        "check_rmse_col_px": {"before": before.rmse_col_px, "after": after.rmse_col_px},
        "check_rmse_m": {"before": before.rmse_m, "after": after.rmse_m},
        "check_rmse_per_ccd_px": _per_ccd(sc),
        "truth_dem": fx["true_dem_path"],
        "truth_error_px": {"rms": sc["truth"]["rms_px"], "max": sc["truth"]["max_px"],
                           "mean_row": sc["truth"]["mean_row_px"], "mean_col": sc["truth"]["mean_col_px"]},
        "truth_error_before_px": {"rms": sc["truth_lab"]["rms_px"], "max": sc["truth_lab"]["max_px"]},
        "truth_error_per_ccd": [{k: r[k] for k in ("band", "ccd", "rms_px", "max_px")} for r in sc["truth"]["per_ccd"]],
        "per_ccd_after": {k: v.rmse_px for k, v in sc["after"].groups.items()},
        "calibration": band_results,
        "attitude": _attitude_selection(result),
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
        Output folder: the scene pipeline's (``gcps.csv``, ``calibration/``, ``manifest.json``,
        ``relative.json``, :mod:`calibrate.pipelines.scene`), then ``report.html``, ``figures/``
        and ``summary.json``.
    fixture_dir : Path
        The scene (default: :data:`FIXTURE_DIR`, the embedded ``realistic`` fixture; any folder
        written by ``gcpcal simulate pushbroom`` will do).
    progress : callable(str), optional
        Receives progress messages.
    spacing_px : int
        Matching window spacing, pixels (``gcpcal match --spacing``).

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
    model_file, merged, result, relative, ref_pts, band_results, match_summaries = _user_path(fx, out_dir, spacing_px,
                                                                                           step)
    sc = _score(fx, merged, result.model if relative is None else relative.model, ref_pts, step)
    summary = _summary(fx, fixture_dir, merged, result, band_results, match_summaries, sc)
    summary["parallax"] = {k: v for k, v in ((relative.parallax if relative is not None else None) or {}).items()
                           if k in ("used", "reason", "message", "ties", "gcps", "rounds", "selected", "gcp_only")}
    step("writing the report")
    write_report(out_dir, result=result, accuracy_before=sc["before"], accuracy_after=sc["after"],
                 initial_model=fx["lab"], gcps=ref_pts, checks=sc["checks"], error_vs_count=sc["evc"],
                 truth_model=fx["truth"], title=f"gcpcal demo: HY-1C-like scene, profile {summary['profile']}",
                 extra={k: summary[k] for k in ("fixture", "profile", "truth_dem", "gcps", "check_points", "attitude")},
                 relative=relative,
                 truth_error={"after": sc["truth"], "before": sc["truth_lab"]}, coverage=_report_coverage(summary["coverage"], sc),
                 status=CalibrationStatus(summary["status"], summary["status_message"]),
                 provenance=provenance_record())
    summary["model"] = model_file
    summary["report"] = "report.html"
    summary["seconds"] = time.perf_counter() - t_start
    write_summary(out_dir / "summary.json", summary)
    return summary
