"""Stage action behind ``gcpcal calibrate``: GCP file in, calibrated model and report out.

``calibrate_scene(scene, gcps, out_dir)`` reads any model :func:`sensor_models.readers.open_model`
reads and a GCP table (:func:`gcpmatch.gcps.read_gcps`, strict), calibrates on the points of
kind ``gcp`` and scores before and after on the points of kind ``check`` (never used in the
fit), then writes into ``out_dir``:

* ``calibration.json``: parameters, covariance, correlation, condition numbers, convergence
  log, per-point residuals, check-point accuracy before and after;
* the calibrated model: ``manifest.json`` for a push-broom scene, ``<name>_RPC.TXT`` for an
  RPC product (bias-compensated RPC, Grodecki and Dial 2003);
* ``report.html`` with PNG figures (:mod:`calibrate.report`);
* ``calibrate.summary.json``.

Everything goes to a temporary folder inside ``out_dir`` first and is moved into place at the
end, so a failure leaves no partial output.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from sensor_models.atomic import move_tree_into
from sensor_models.errors import InputError

__all__ = ["apply_calibration", "calibrate_scene", "points_of"]


def points_of(table, model=None) -> dict:
    """Arrays ``row, col, lon, lat, h, sigma_px, score, band, ccd`` of a GcpTable.

    ``band`` and ``ccd`` are None when blank. With a push-broom ``model``, CCD names become
    indices into ``model.band_ccds(band)`` (what the accuracy functions take).
    """
    out = {k: np.asarray(getattr(table, k), dtype=np.float64) for k in ("row", "col", "lon", "lat", "h", "sigma_px", "score")}
    for k in ("band", "ccd"):
        v = np.asarray(getattr(table, k)).astype(str)
        out[k] = None if (v.size == 0 or np.all(v == "")) else v
    if model is not None and out["ccd"] is not None and hasattr(model, "band_ccds"):
        idx = np.empty(out["ccd"].size, dtype=np.intp)
        bands = out["band"] if out["band"] is not None else np.full(idx.size, model.reference_band)
        for b in np.unique(bands):
            s = bands == b
            idx[s] = model.ccd_index(out["col"][s], band=str(b), ccd=out["ccd"][s])
        out["ccd"] = idx
    return out


def apply_calibration(model, table, *, scheme="exterior-interior", robust="cauchy", band=None):
    """Calibrate ``model`` on the ``gcp`` points of ``table``; return ``(result, gcp points)``.

    Push-broom and staring-camera models use the stepwise schemes of
    :func:`calibrate.absolute.calibrate_model`; RPC models get an image-space bias compensation (:func:`calibrate.rpc_bias.compensate_rpc_bias`).
    """
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions
    from gcpmatch.gcps import GcpTable
    from sensor_models.rpc import RpcModel

    g = points_of(table.gcps())
    if g["row"].size == 0:
        raise InputError("the GCP table holds no point of kind 'gcp'")
    if band is not None:
        g["band"] = np.full(g["row"].size, band) if g["band"] is None else g["band"]
    if not isinstance(model, RpcModel):  # push-broom or staring camera: the rigorous model
        gcps = table.gcps()
        if band is not None and g["band"] is None:
            gcps = GcpTable.from_arrays(**{**gcps.as_dict(), "band": band})
        result = calibrate_model(model, gcps, options=CalibrationOptions(scheme=scheme, robust=robust))
    else:
        from calibrate.rpc_bias import compensate_rpc_bias

        result = compensate_rpc_bias(model, g["row"], g["col"], g["lon"], g["lat"], g["h"], sigma_px=g["sigma_px"])
    return result, g


def _accuracy(model, pts):
    from calibrate.accuracy import check_point_accuracy

    if pts["row"].size == 0:
        return None
    return check_point_accuracy(model, pts["row"], pts["col"], pts["lon"], pts["lat"], pts["h"],
                                band=pts["band"], ccd=pts["ccd"])


def calibrate_scene(scene_path, gcps_path, out_dir, *, scheme="exterior-interior", robust="cauchy", band=None,
                    image=None, report=True, progress=None) -> dict:
    """Run the calibration stage (see the module docstring); return the summary.

    ``image``: the raster the GCPs were measured in, when it is a crop of the scene the model
    describes (an RPC product's sub-image with a pixel geotransform): the model is cropped to
    it, as ``gcpcal match --image`` does.
    """
    from gcpmatch.extract import _crop_of, read_band
    from gcpmatch.gcps import read_gcps
    from sensor_models.readers import open_model

    t0 = time.perf_counter()
    model = open_model(scene_path)
    if image is not None:
        shape = read_band(model, band or getattr(model, "reference_band", None), image).shape
        if shape != tuple(model.image_shape) and hasattr(model, "cropped"):
            model = _crop_of(model, image, shape)
    table = read_gcps(gcps_path, image_shape=model.image_shape)
    if progress:
        progress(f"{len(table.gcps())} GCPs, {len(table.checks())} check points")
    result, g = apply_calibration(model, table, scheme=scheme, robust=robust, band=band)
    checks = points_of(table.checks(), model)
    acc_before, acc_after = _accuracy(model, checks), _accuracy(result.model, checks)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".calibrate-", dir=out_dir)).resolve()
    try:
        doc = result.to_dict()
        doc["scene"] = str(scene_path)
        doc["gcp_file"] = str(gcps_path)
        doc["check_accuracy"] = {
            "before": None if acc_before is None else acc_before.to_dict(),
            "after": None if acc_after is None else acc_after.to_dict(),
        }
        (tmp / "calibration.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        model_file = _write_model(result.model, model, tmp, out_dir)
        if report and acc_before is not None:
            from calibrate.report import write_report

            write_report(tmp, result=getattr(result, "calibration", result), accuracy_before=acc_before, accuracy_after=acc_after,
                         initial_model=model, gcps=g, checks=checks)
        summary = {
            "kind": "gcpcal.calibrate",
            "success": bool(result.success),
            "message": result.message,
            "scheme": scheme,
            "gcps": int(g["row"].size),
            "check_points": int(checks["row"].size),
            "check_rmse_px": {
                "before": None if acc_before is None else acc_before.absolute.rmse_px,
                "after": None if acc_after is None else acc_after.absolute.rmse_px,
            },
            "model": model_file,
            "seconds": time.perf_counter() - t0,
        }
        (tmp / "calibrate.summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
        move_tree_into(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return summary


def _write_model(calibrated, original, tmp: Path, out_dir: Path) -> str:
    from sensor_models.pushbroom import PushbroomModel

    if isinstance(calibrated, PushbroomModel):
        from sensor_models.readers.manifest import manifest_to_dict

        rasters = {b: {"path": os.path.relpath(r["path"], out_dir.resolve()), "index": r.get("index", 1)}
                   for b, r in (getattr(original, "rasters", None) or {}).items()}
        doc = manifest_to_dict(calibrated, rasters=rasters)
        doc["name"] = (getattr(original, "name", "") or "scene") + " (calibrated)"
        (tmp / "manifest.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        return "manifest.json"
    from sensor_models.geo_staring import GeoStaringModel

    if isinstance(calibrated, GeoStaringModel):
        from sensor_models.readers.geo_manifest import geo_manifest_to_dict

        ref = (getattr(original, "rasters", None) or {}).get(original.band)
        raster = None if ref is None else {"path": os.path.relpath(ref["path"], out_dir.resolve()),
                                            "index": ref.get("index", 1)}
        doc = geo_manifest_to_dict(calibrated, raster=raster)
        (tmp / "manifest.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        return "manifest.json"
    name = f"{Path(getattr(original, 'source', 'model') or 'model').stem}_RPC.TXT"
    calibrated.write(tmp / name)
    return name
