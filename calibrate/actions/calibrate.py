"""Stage action of ``gcpcal calibrate``: GCP file in, calibrated model and report out.

:func:`calibrate_scene` reads any model :func:`sensor_models.readers.open_model` reads and a GCP
table (:func:`gcpmatch.gcp_files.read_gcps`, strict), calibrates on the points of kind ``gcp`` and
scores before and after on the points of kind ``check`` (never used in the fit), then writes
into ``out_dir``:

* ``calibration.json``: parameters, covariance, correlation, condition numbers, convergence
  log, per-point residuals, check-point accuracy before and after;
* the calibrated model: ``manifest.json`` for a push-broom or staring-camera scene,
  ``<name>_RPC.TXT`` for an RPC product (bias-compensated RPC, Grodecki and Dial 2003);
* ``report.html`` with PNG figures (:mod:`calibrate.report`);
* ``residuals.gpkg``: the residual layer after calibration (:mod:`calibrate.residual_layer`),
  one point per GCP (kind ``gcp``, or ``outlier`` where the fit rejected it) and per check
  point (kind ``check``);
* ``calibrate.summary.json``.

When the GCP table has a match summary beside it (``<name>.summary.json``, written by
``gcpcal match``), its ``reference_accuracy`` (the DOM's stated geolocation accuracy, or the
matcher's assumed one) becomes ``CalibrationOptions.reference_sigma_m`` unless the options already
give one (:func:`options_from_match_summary`): the covariance then holds the reference's common
shift (:mod:`calibrate.reference_covariance`).

Everything goes to a temporary folder inside ``out_dir`` first and is moved into place at the
end, so a failure leaves no partial output.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from calibrate.actions._io import check_output_folder, staged_folder
from calibrate.actions._status import record_product_check
from calibrate.actions._provenance import note, provenance_record, with_provenance
from calibrate.plausibility import check_gcps_on_scene
from calibrate.config import CalibrationOptions
from calibrate.from_gcps import apply_calibration, points_of
from calibrate.residual_layer import LAYER_NAMES, concatenate_layers, residual_layer, write_residual_layer
from sensor_models.readers.rpc_files import write_rpc

__all__ = ["calibrate_scene", "match_summary_path", "options_from_match_summary"]


def match_summary_path(gcps_path) -> Path:
    """The match summary ``gcpcal match`` writes beside a GCP table: ``<name>.summary.json``.

    Parameters
    ----------
    gcps_path : str or Path
        The GCP table.

    Returns
    -------
    Path
        ``gcps_path`` with the suffix ``.summary.json`` (it may not exist).
    """
    return Path(gcps_path).with_suffix(".summary.json")


def note_gcp_origin(gcps_path) -> None:
    """Record in the provenance where the GCP table came from: the match summary's command line,
    inputs (scene, DOM, DEM with their checksums) and terrain, when a summary is beside it.

    Parameters
    ----------
    gcps_path : str or Path
    """
    from sensor_models.errors import InputError
    from sensor_models.files.documents import load_json

    try:
        upstream = load_json(match_summary_path(gcps_path)).get("provenance")
    except (InputError, AttributeError):
        return
    if isinstance(upstream, dict):
        note("gcps_from", {k: upstream.get(k) for k in ("command_line", "created_utc", "inputs", "terrain",
                                                         "reference_accuracy")})


def options_from_match_summary(options: CalibrationOptions, gcps_path) -> CalibrationOptions:
    """``options`` with the reference accuracy of the GCP table's match summary, when it has one.

    Parameters
    ----------
    options : CalibrationOptions
        A ``reference_sigma_m`` already given (``--reference-sigma-m``) wins.
    gcps_path : str or Path
        The GCP table; its summary is :func:`match_summary_path`.

    Returns
    -------
    CalibrationOptions
        ``reference_sigma_m = (east_m, north_m)`` and ``reference_source`` naming the summary and
        the value's own source (a DOM tag, an MTL, ``assumed``); unchanged without a readable
        summary holding ``reference_accuracy``.
    """
    if options.reference_sigma_m is not None:
        return options if options.reference_source else options.replace(reference_source="option")
    path = match_summary_path(gcps_path)
    from sensor_models.errors import InputError
    from sensor_models.files.documents import load_json

    try:
        acc = load_json(path).get("reference_accuracy")
        sigma = (float(acc["east_m"]), float(acc["north_m"]))
    except (InputError, ValueError, TypeError, KeyError, AttributeError):
        return options  # no summary (a table from elsewhere or an older run): no reference term
    source = str(acc.get("source", "?")) + (" (assumed by the matcher)" if acc.get("assumed") else "")
    return options.replace(reference_sigma_m=sigma, reference_source=f"match summary {path.name}: {source}")


def _accuracy(model, pts):
    from calibrate.accuracy import check_point_accuracy

    if pts["row"].size == 0:
        return None
    return check_point_accuracy(model, pts["row"], pts["col"], pts["lon"], pts["lat"], pts["h"],
                                band=pts["band"], ccd=pts["ccd"])


def _read_inputs(scene_path, gcps_path, band, image, self_check):
    """The scene (its model cropped to ``image`` when that is a crop of the scene) and the GCP table."""
    from gcpmatch.gcp_files import read_gcps
    from sensor_models.readers import open_scene

    scene = open_scene(scene_path, image=image, band=band, self_check=self_check)
    return scene, read_gcps(gcps_path, image_shape=scene.model.image_shape)


def calibrate_scene(scene_path, gcps_path, out_dir, *, options: CalibrationOptions = CalibrationOptions(), band=None,
                    image=None, report=True, progress=None, self_check: str = "refuse", on_result=None) -> dict:
    """Run the calibration stage (see the module docstring).

    Parameters
    ----------
    scene_path : str or Path
        Scene manifest, RPC file or any model file.
    gcps_path : str or Path
        GCP table (CSV, GeoPackage or GeoTIFF) with points of kind ``gcp`` and ``check``.
    out_dir : str or Path
        Output folder (created when missing).
    options : CalibrationOptions
        Scheme, robust loss and solver settings; without ``reference_sigma_m`` the match
        summary's is taken (:func:`options_from_match_summary`).
    band : str, optional
        Band of the GCPs that name none (default: the reference band).
    image : str or Path, optional
        The raster the GCPs were measured in, when it is a crop of the scene the model describes
        (an RPC product's sub-image with a pixel geotransform): the model is cropped to it, as
        ``gcpcal match --image`` does.
    report : bool
        Write ``report.html`` and its figures.
    progress : callable(str), optional
        Receives progress messages.
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in the summary.
    on_result : callable, optional
        Receives the fit (:class:`calibrate.absolute.CalibrationResult`, or the
        :class:`calibrate.rpc_bias.RpcBiasResult` of an RPC; ``result.model`` the calibrated model,
        its ``calibration`` the run's status) once the outputs are in place: for a pipeline that
        reports on it (:mod:`calibrate.pipelines.demo`).

    Returns
    -------
    dict
        The summary written to ``calibrate.summary.json`` (``success``, ``message``, ``gcps``,
        ``check_points``, ``check_rmse_px {before, after}``, ``check_points_used {before, after}``
        (the check points each model projects into the image, over which those RMSE are taken),
        ``model``, ``product_check``, ``warnings``, ``seconds``).
    """
    t0 = time.perf_counter()
    check_output_folder(out_dir, inputs=[scene_path, gcps_path, image])  # before any work
    scene, table = _read_inputs(scene_path, gcps_path, band, image, self_check)
    model = scene.model
    implausible = check_gcps_on_scene(model, table.lon, table.lat, table.h, source=gcps_path, band=band)
    options = options_from_match_summary(options, gcps_path)
    note_gcp_origin(gcps_path)
    say = progress or (lambda message: None)
    say(f"{len(table.gcps())} GCPs, {len(table.checks())} check points")
    say(f"fitting the model ({options.scheme})")
    result, g = apply_calibration(model, table, options=options, band=band)
    checks = points_of(table.checks(), model)
    acc_before, acc_after = _accuracy(model, checks), _accuracy(result.model, checks)
    coverage, status = _gate(model, table, result, band, acc_before, acc_after)
    result.model.calibration = status
    out_dir = Path(out_dir)
    with staged_folder(out_dir, ".calibrate-", inputs=[scene_path, gcps_path, image]) as tmp:
        doc = _calibration_doc(result, scene_path, gcps_path, acc_before, acc_after, coverage, status)
        (tmp / "calibration.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        model_file = _write_model(result.model, scene, tmp, out_dir, failed=status.status == "failed",
                                  errors_m=rpc_error_estimates(acc_after, options.reference_sigma_m))
        write_residual_layer(_residual_layer(result, table, acc_after, band), tmp / "residuals.gpkg",
                             layer=LAYER_NAMES["calibrate"])
        if report and acc_before is not None:
            from calibrate.report import write_report

            say("writing the report")
            write_report(tmp, result=getattr(result, "calibration", result), accuracy_before=acc_before,
                         accuracy_after=acc_after, initial_model=model, gcps=g, checks=checks,
                         coverage=coverage, status=status, provenance=provenance_record())
        summary = _summary(result, status, options, g, checks, acc_before, acc_after, doc, coverage, model_file, t0)
        record_product_check(summary, scene.product_check)
        if implausible:
            summary["implausible_accepted"] = implausible
        (tmp / "calibrate.summary.json").write_text(json.dumps(with_provenance(summary), indent=1) + "\n", encoding="utf-8")
    if on_result is not None:
        on_result(result)
    return summary


def _summary(result, status, options, g, checks, acc_before, acc_after, doc, coverage, model_file, t0) -> dict:
    """The ``calibrate.summary.json`` document (without the product check and provenance)."""
    return {
        "kind": "gcpcal.calibrate",
        "success": bool(result.success),
        "status": status.status,
        "status_message": status.message,
        "message": result.message,
        "scheme": options.scheme,
        "gcps": int(g["row"].size),
        "check_points": int(checks["row"].size),
        "check_rmse_px": {
            "before": None if acc_before is None else acc_before.absolute.rmse_px,
            "after": None if acc_after is None else acc_after.absolute.rmse_px,
        },
        # the check points each model projects into the image: the RMSE above is over these
        "check_points_used": {
            "before": None if acc_before is None else acc_before.absolute.n,
            "after": None if acc_after is None else acc_after.absolute.n,
        },
        "variance_factor": doc["variance_factor"],
        "covariance_factor": doc.get("covariance_factor"),
        "reference_accuracy": doc.get("reference_accuracy"),
        "coverage": coverage,
        "attitude": _attitude_summary(getattr(result, "calibration", result)),
        "model": model_file,
        "residual_layer": "residuals.gpkg",
        "warnings": [],
        "seconds": time.perf_counter() - t0,
    }


def _gate(model, table, result, band, acc_before, acc_after):
    """Per-CCD coverage rows (with check RMSE before/after) and the run's CalibrationStatus."""
    from calibrate.coverage import apply_check_accuracy, calibration_coverage, calibration_status

    fitted = points_of(table.gcps(), model)
    if band is not None and fitted["band"] is None:
        fitted["band"] = np.full(fitted["row"].size, band)
    checks = points_of(table.checks(), model)
    if band is not None and checks["band"] is None and checks["row"].size:
        checks["band"] = np.full(checks["row"].size, band)
    lsq = getattr(result, "calibration", result)
    rows = calibration_coverage(model, fitted, checks, success=bool(result.success),
                                skipped=getattr(lsq, "skipped", ()), weight=fitted["score"])
    rmse = [(_group_rmse(acc_before, c, len(rows)), _group_rmse(acc_after, c, len(rows))) for c in rows]
    rows = apply_check_accuracy(rows, rmse)
    gated = {c.band or model.reference_band for c in rows}  # a blank band is the reference band
    bands_left = [b for b in model.bands if b is not None and b not in gated] if rows else []
    status = calibration_status(bool(result.success), result.message, rows, bands_left=bands_left)
    coverage = []
    for c, (before, after) in zip(rows, rmse):
        entry = c.to_dict()
        entry["check_rmse_px"] = {"before": before, "after": after}
        coverage.append(entry)
    return coverage, status


def _residual_layer(result, table, acc_after, band):
    """Residual layer after calibration: the fit's own residuals of the GCPs, the check points'."""
    from gcpmatch.gcps import GcpTable

    def with_band(t):
        if band is not None and len(t) and np.all(t.band == ""):
            return GcpTable.from_arrays(**{**t.as_dict(), "band": band})
        return t

    lsq = getattr(result, "calibration", result)
    kind = np.where(np.asarray(lsq.inlier, dtype=bool), "gcp", "outlier")
    layers = [residual_layer(result.model, with_band(table.gcps()), lsq.residuals_after, kind)]
    if acc_after is not None:
        layers.append(residual_layer(result.model, with_band(table.checks()), acc_after.residuals_px, "check"))
    return concatenate_layers(layers)


def _group_rmse(accuracy, coverage, n_arrays):
    """Check-point RMSE (px) of one CCD, None without check points on it."""
    if accuracy is None or coverage.check_points == 0:
        return None
    summary = accuracy.groups.get(f"{coverage.band}.{coverage.ccd}")
    if summary is None and n_arrays == 1:
        summary = accuracy.absolute
    return None if summary is None else summary.to_dict()["rmse_px"]


def _attitude_summary(result):
    """The time-varying attitude chosen (``calibration.json`` ``attitude``, short): None when not tried."""
    info = getattr(result, "attitude", None)
    if not info:
        return None
    out = {"mode": info["mode"], "selected": info["selected"]}
    if "jitter" in info:
        out["jitter"] = info["jitter"]
    return out


def _finite(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _calibration_doc(result, scene_path, gcps_path, acc_before, acc_after, coverage, status) -> dict:
    """The content of ``calibration.json``."""
    doc = result.to_dict()
    doc["scene"] = str(scene_path)
    doc["gcp_file"] = str(gcps_path)
    doc["status"] = status.to_dict()
    doc["coverage"] = coverage
    doc["variance_factor"] = _finite(getattr(result, "calibration", result).variance_factor)
    doc["check_accuracy"] = {
        "before": None if acc_before is None else acc_before.to_dict(),
        "after": None if acc_after is None else acc_after.to_dict(),
    }
    return doc


def rpc_error_estimates(accuracy, reference_sigma_m) -> tuple[float, float] | None:
    """``(ERR_BIAS, ERR_RAND)`` of a calibrated RPC, metres per horizontal axis, from its check points.

    RPC00B's error fields (GDAL RFC 22) are the RMS bias error per horizontal axis of all points
    and the RMS random error per horizontal axis of each point. After a calibration against a
    reference, what stays common to every point is the reference's own geolocation error plus the
    check points' mean residual; what varies is their scatter:

    ``ERR_BIAS = sqrt(sigma_ref^2 + (mean_along^2 + mean_across^2) / 2)``,
    ``ERR_RAND = sqrt((var_along + var_across) / 2)``,

    with ``sigma_ref`` the reference's per-axis accuracy (``reference_sigma_m``; 0 when unknown)
    and the residuals the check points' along- and across-track metres.

    Parameters
    ----------
    accuracy : AccuracyReport or None
        Check-point accuracy of the calibrated model (``residuals_m``: along, across, planar).
    reference_sigma_m : (float, float) or None
        The reference's accuracy, east and north, metres (1 sigma).

    Returns
    -------
    (float, float) or None
        None without at least two check points with metres.
    """
    res = None if accuracy is None else accuracy.residuals_m
    if res is None:
        return None
    res = np.asarray(res, dtype=np.float64)[:, :2]
    res = res[np.isfinite(res).all(axis=1)]
    if res.shape[0] < 2:
        return None
    mean, var = res.mean(axis=0), res.var(axis=0, ddof=1)
    ref = 0.0 if reference_sigma_m is None else float(np.mean(np.square(reference_sigma_m)))
    return float(np.sqrt(ref + 0.5 * np.sum(mean**2))), float(np.sqrt(0.5 * np.sum(var)))


def _write_model(calibrated, scene, tmp: Path, out_dir: Path, *, failed=False, errors_m=None) -> str | None:
    """Write the calibrated model; its file name (None: a failed RPC bias fit writes none).

    An RPC goes under the name GDAL pairs with the scene's raster (``<raster>_RPC.TXT``), in that
    raster's pixels, with ``ERR_BIAS``/``ERR_RAND`` from ``errors_m``. A crop's calibration also
    writes the full scene's RPC as ``<product>_full_scene_RPC.TXT`` and returns that name: it is
    the model the other commands open (the crop's sidecar is for GIS tools).
    """
    # the writer follows the model's kind: serialization, not geometry
    if calibrated.kind == "pushbroom":
        from sensor_models.readers.manifest import manifest_to_dict

        rasters = {b: {"path": os.path.relpath(r["path"], out_dir.resolve()), "index": r.get("index", 1)}
                   for b, r in scene.rasters.items()}
        doc = manifest_to_dict(calibrated, rasters=rasters)
        doc["name"] = (getattr(scene.model, "name", "") or "scene") + " (calibrated)"
        (tmp / "manifest.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        return "manifest.json"
    if calibrated.kind == "geo_staring":
        from sensor_models.readers.geo_manifest import geo_manifest_to_dict

        ref = scene.rasters.get(scene.model.band)
        raster = None if ref is None else {"path": os.path.relpath(ref["path"], out_dir.resolve()),
                                            "index": ref.get("index", 1)}
        doc = geo_manifest_to_dict(calibrated, raster=raster)
        (tmp / "manifest.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        return "manifest.json"
    if failed:
        return None
    if errors_m is not None:
        calibrated = type(calibrated)(**{**calibrated.init_kwargs(), "err_bias": errors_m[0], "err_rand": errors_m[1]})
    raster = scene.rasters.get(getattr(scene.model, "reference_band", None) or "")
    raster = raster or next(iter(scene.rasters.values()), None)
    source_stem = Path(getattr(scene.model, "source", "model") or "model").stem
    # GDAL pairs X_RPC.TXT with X.tif: the RPC of the raster's own pixels goes under the raster's name
    sidecar = f"{Path(raster['path']).stem if raster else source_stem}_RPC.TXT"
    write_rpc(calibrated, tmp / sidecar)
    crop = scene.crop
    if crop is None:
        return sidecar
    # GCPs measured in a crop: the model is the full scene's, as the product's own RPC, under a name
    # no raster pairs with; gcpcal crops it through the raster's geotransform when it opens the crop
    row0, col0, full_shape = crop
    full = f"{source_stem}_full_scene_RPC.TXT"
    write_rpc(calibrated.cropped(-row0, -col0, full_shape), tmp / full)
    return full
