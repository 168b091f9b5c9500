"""``gcpcal run``: calibrate from GCPs, or from stars when clouds hide the ground.

A composition of the stage actions a user runs, in the scene pipeline's layout
(:mod:`calibrate.pipelines.scene`):

1. The scene is matched against the DOM and DEM (:func:`calibrate.pipelines.scene.match_step`:
   :func:`calibrate.actions.match.match_scene` into ``gcps.csv``).
2. The GCPs are judged sufficient when there are at least ``min_gcps`` of kind ``gcp`` and they
   cover at least ``min_coverage`` of a 4 x 4 partition of the image (clustered GCPs under a
   hole in the clouds cannot fix a 20-coefficient interior). The matching's own verdict counts
   too: a coarse stage that found no consistent SIFT matches (all clouds, no texture) means no
   GCPs at all.
3. Sufficient GCPs: the model is calibrated from them (:func:`calibrate.pipelines.scene.calibrate_step`:
   :func:`calibrate.actions.calibrate.calibrate_scene` into ``calibration/``).
   Otherwise, with star frames (a ``frames.json`` sequence of the same camera with its mirror
   turned to deep space), the camera is calibrated from the stars
   (:mod:`calibrate.actions.stars`); without them the run fails with the reason.
4. With ``relative``, after a calibration from the GCPs the other bands are calibrated against
   the calibrated reference band (:func:`calibrate.pipelines.scene.relative_step`: ``relative/``;
   ``gcpcal run --relative``), as ``gcpcal relative`` would.

``run.summary.json`` says which path was taken and why (``path``: ``"gcps"`` or ``"stars"``,
``reason``), with the matching figures that decided it.

Star frames of another camera (image size, pixel angle) are refused before any work
(:func:`calibrate.actions.stars.read_star_inputs`). The run's own result is checked like any
model a command uses (:mod:`calibrate.actions._status`): a failed step gives ``success: false``
and ``model: null`` (the manifest it left is marked ``failed``, so no command uses it); a partial
one is reported in ``calibration_status`` and ``warnings``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from calibrate.actions._io import staged_output
from calibrate.actions._status import FailedCalibrationError, record_product_check, require_usable, status_fields
from calibrate.actions.stars import read_star_inputs, stars_sequence
from calibrate.actions._provenance import with_provenance
from calibrate.pipelines.scene import CALIBRATION_DIR, FINAL_MODEL, GCP_FILE, calibrate_step, match_step, relative_step
from gcpmatch.options import MatchOptions
from sensor_models.errors import GcpcalError, InputError

__all__ = ["MIN_COVERAGE", "MIN_GCPS", "gcp_coverage", "run_scene"]

#: GCPs of kind ``gcp`` needed to calibrate from the ground.
MIN_GCPS = 60
#: Share of a 4 x 4 partition of the image the GCPs must cover.
MIN_COVERAGE = 0.5


def gcp_coverage(row, col, image_shape, cells: int = 4) -> float:
    """Fraction of a ``cells`` x ``cells`` partition of the image holding at least one point.

    Parameters
    ----------
    row, col : array_like, shape (N,)
        Image coordinates, pixels.
    image_shape : tuple of int
        ``(n_rows, n_cols)``.
    cells : int
        Partition cells per side.

    Returns
    -------
    float
        In ``[0, 1]``.
    """
    row, col = np.asarray(row, dtype=np.float64), np.asarray(col, dtype=np.float64)
    if row.size == 0:
        return 0.0
    i = np.clip((row / image_shape[0] * cells).astype(int), 0, cells - 1)
    j = np.clip((col / image_shape[1] * cells).astype(int), 0, cells - 1)
    return float(np.unique(i * cells + j).size / cells**2)


def _match(scene_path, out_dir: Path, *, dom_path, dem_path, dem_datum, geoid, options, self_check):
    """Match the scene; return ``(match summary, failure message or None)``: a failed match is a
    reason to fall back on the stars, a user's mistake is not."""
    try:
        match = match_step(scene_path, out_dir, dom_path=dom_path, dem_path=dem_path, dem_datum=dem_datum, geoid=geoid,
                           options=options, self_check=self_check)
        return match, None
    except GcpcalError as exc:
        if isinstance(exc, InputError) and not (out_dir / GCP_FILE).with_suffix(".summary.json").exists() and \
                "no GCP" not in str(exc):
            raise  # a user mistake (missing file, bad DEM): not a reason to fall back
        return {}, str(exc)


def _decide(model, gcp_file, match, failure, min_gcps, min_coverage):
    """Whether the GCPs suffice, and why; returns ``(enough, reason, n_gcps, coverage)``."""
    n_gcps, coverage = 0, 0.0
    if failure is None:
        from gcpmatch.gcp_files import read_gcps

        g = read_gcps(gcp_file).gcps()
        n_gcps, coverage = len(g), gcp_coverage(g.row, g.col, model.image_shape)
    enough = failure is None and n_gcps >= min_gcps and coverage >= min_coverage
    if enough:
        reason = f"{n_gcps} GCPs covering {100 * coverage:.0f} % of the image"
    elif failure is not None:
        reason = f"matching failed: {failure}"
    else:
        cloud = match.get("cloud_fraction")
        cloud_text = "unknown" if cloud is None else f"{100 * float(cloud):.0f} %"
        reason = (f"too few or too clustered GCPs: {n_gcps} (need {min_gcps}) covering {100 * coverage:.0f} % "
                  f"of the image (need {100 * min_coverage:.0f} %); cloud fraction {cloud_text}")
    return enough, reason, n_gcps, coverage


def _mark_failed(model_file: Path, message: str) -> None:
    """Record a failed status in a manifest a failed step left (so no command uses it)."""
    from sensor_models.files.atomic import atomic_write_text

    doc = json.loads(model_file.read_text(encoding="utf-8"))
    doc["calibration"] = {"status": "failed", "message": message, "uncalibrated": [], "unverified": []}
    atomic_write_text(model_file, json.dumps(doc, indent=1) + "\n")


def _own_status(out_dir: Path, summary: dict) -> dict:
    """Check the run's own calibration result: a failed one is unusable, a partial one is said.

    Returns the summary fields to update: ``success``, ``model`` (None unless usable),
    ``calibration_status``, ``warnings``.
    """
    from sensor_models.readers import open_model

    model_name = summary.get("model")
    if not model_name:  # only what this run's step wrote, never a file of an earlier run
        model_name = {"gcps": f"{CALIBRATION_DIR}/manifest.json", "stars": "stars/manifest.json"}.get(summary.get("path"))
    model_file = out_dir / model_name if model_name and (out_dir / model_name).is_file() else None
    if not summary.get("success"):
        if model_file is not None and model_file.suffix == ".json":
            status = open_model(model_file).calibration
            if status is None or status.status != "failed":
                _mark_failed(model_file, str(summary.get("message") or "the calibration failed"))
        return {"success": False, "model": None, "calibration_status": "failed", "warnings": []}
    if model_file is None:
        return {"calibration_status": None, "warnings": []}
    calibrated = open_model(model_file)
    try:
        warning = require_usable(calibrated, model_file, command="run")
    except FailedCalibrationError as exc:
        return {"success": False, "model": None, "calibration_status": "failed", "message": exc.reason,
                "warnings": []}
    return status_fields(calibrated, warning)


@staged_output("out_dir", inputs=("scene_path", "dom_path", "dem_path", "geoid", "star_frames"), prefix=".run-")
def run_scene(scene_path, *, dom_path, dem_path, out_dir, star_frames=None, dem_datum=None, geoid=None,
              min_gcps: int = MIN_GCPS, min_coverage: float = MIN_COVERAGE, spacing_px: int = 16,
              relative: bool = False, threads: int = 0, progress=None, self_check: str = "refuse",
              record: dict | None = None) -> dict:
    """Match, decide, calibrate (see the module docstring).

    Parameters
    ----------
    scene_path : str or Path
        Scene manifest.
    dom_path, dem_path : str or Path
        Reference orthoimage and DEM; also tiles, products and a
        :class:`sensor_models.maps.dom_inputs.DomSource` (:func:`calibrate.actions.match.match_scene`).
    out_dir : str or Path
        Output folder: ``gcps.csv``, ``calibration/`` or ``stars/``, ``run.summary.json``.
    star_frames : str or Path, optional
        Star sequence (``frames.json`` or its folder) for the fallback.
    dem_datum : {"ellipsoid", "egm96"}, optional
        Vertical datum of the DEM when the file does not declare it.
    geoid : str or Path, optional
        Geoid grid for an EGM96 DEM.
    min_gcps : int
        GCPs needed to calibrate from the ground.
    min_coverage : float
        Share of a 4 x 4 partition of the image the GCPs must cover, in ``[0, 1]``.
    spacing_px : int
        Matching window spacing, pixels.
    relative : bool
        After a calibration from the GCPs, calibrate every other band against the calibrated
        reference band (:func:`calibrate.pipelines.scene.relative_step`, into ``relative/``);
        the run's model is then ``relative/manifest.json``.
    threads : int
        Matching threads (0: every core); the GCPs do not depend on it
        (:class:`gcpmatch.options.MatchOptions`).
    progress : callable(str), optional
        Receives progress messages.
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in every summary.
    record : dict, optional
        Fields added to the summary as they are (``gcpcal campaign`` records there what the run
        was made from, :mod:`calibrate.pipelines.campaign_resume`).

    Returns
    -------
    dict
        The summary written to ``run.summary.json`` (``path``, ``reason``, ``success``,
        ``product_check``, ...).
    """
    from sensor_models.files.atomic import atomic_write_text
    from sensor_models.readers import open_scene

    t0 = time.perf_counter()
    step = progress or (lambda m: None)
    out_dir = Path(out_dir)  # the staging folder (staged_output)
    scene = open_scene(scene_path, self_check=self_check)
    model = scene.model
    if star_frames is not None:  # frames of another camera are refused before any work
        read_star_inputs(star_frames, scene_model=model, scene_source=scene_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    gcp_file = out_dir / GCP_FILE
    step("matching the scene against the DOM")
    match, failure = _match(scene_path, out_dir, dom_path=dom_path, dem_path=dem_path, dem_datum=dem_datum,
                            geoid=geoid, options=MatchOptions(spacing_px=spacing_px, threads=threads),
                            self_check=self_check)
    enough, reason, n_gcps, coverage = _decide(model, gcp_file, match, failure, min_gcps, min_coverage)
    summary = {"kind": "gcpcal.run", "scene": str(scene_path), "gcps": n_gcps, "coverage": coverage,
               "cloud_fraction": match.get("cloud_fraction"), "reason": reason}
    if enough:
        step("calibrating from the GCPs")
        result = calibrate_step(scene_path, out_dir, report=True, self_check=self_check)
        summary.update(path="gcps", success=result["success"], message=result["message"],
                       check_rmse_px=result["check_rmse_px"], model=f"{CALIBRATION_DIR}/{result['model']}" if result.get("model") else None)
        if relative and result["status"] != "failed":
            step("calibrating the other bands against the reference band")
            rel = relative_step(scene_path, out_dir, dem_path=dem_path, dem_datum=dem_datum, geoid=geoid,
                                self_check=self_check)
            summary.update(relative={"success": rel.get("success"), "message": rel.get("message")},
                           model=FINAL_MODEL if rel.get("success") else summary["model"])
    elif star_frames is not None:
        step(f"falling back on the star frames ({reason})")
        doc = stars_sequence(star_frames, out_dir / "stars")
        summary.update(path="stars", success=bool(doc.get("success")), message=doc.get("message"),
                       star_accuracy=doc.get("accuracy"),
                       model="stars/manifest.json" if doc.get("success") else None)
    else:
        summary.update(path=None, success=False,
                       message=f"cannot calibrate: {reason}, and no star frames were given (--star-frames)")
    summary.update(_own_status(out_dir, summary))
    record_product_check(summary, scene.product_check)
    summary["seconds"] = time.perf_counter() - t0
    summary.update(record or {})
    atomic_write_text(out_dir / "run.summary.json", json.dumps(with_provenance(summary), indent=1, default=str) + "\n")
    return summary
