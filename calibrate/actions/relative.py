"""Stage action of ``gcpcal relative``: band-to-band relative calibration (seed 003 section 2.2.2).

Tie points between the reference band and each other band become control points through the
calibrated reference band and the DEM; each band's interior is then solved with the exterior
held (:func:`calibrate.relative.relative_calibration`). This action reads the scene's rasters
(the LAB manifest), the model whose reference band was calibrated (the ``manifest.json`` of
``gcpcal calibrate`` or its folder) and the DEM, and writes into the output folder
``manifest.json`` (every band calibrated, raster paths relative to the folder),
``relative.json`` (:meth:`calibrate.relative.RelativeResult.to_dict`) and
``relative.summary.json``; all of them through a temporary folder inside the output folder, so
a failure leaves no partial output.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from calibrate._json import json_safe
from calibrate.actions._io import open_dem, staged_folder
from calibrate.actions._status import record_product_check
from calibrate.actions._provenance import with_provenance
from calibrate.config import CalibrationOptions
from sensor_models.errors import InputError

__all__ = ["relative_calibration_stage"]

_OUTPUTS = ("manifest.json", "relative.json", "relative.summary.json")


def relative_calibration_stage(scene_path, calibration, dem_path, out_dir, *, reference_band=None, dem_datum=None,
                               geoid=None, window_px=64, spacing_px: int = 24, rows=None,
                               options: CalibrationOptions = CalibrationOptions(), parallax: bool = True,
                               gcps_path=None, progress=None, self_check: str = "refuse", on_result=None) -> dict:
    """Calibrate every band of a scene against its calibrated reference band.

    Parameters
    ----------
    scene_path : str or Path
        The LAB scene manifest (its rasters give the pixels).
    calibration : str or Path
        Calibrated ``manifest.json`` of the reference band, or its folder.
    dem_path : str or Path
        DEM raster.
    out_dir : str or Path
        Output folder (created if needed).
    reference_band : str, optional
        Default: the calibrated model's reference band.
    dem_datum : {"ellipsoid", "egm96"}, optional
        Vertical datum of the DEM when the file does not declare it.
    geoid : str or Path, optional
        Geoid grid for an EGM96 DEM.
    window_px : int or (int, int)
        Phase-correlation window, pixels (square, or rows x columns).
    spacing_px : int
        Window grid spacing, pixels.
    rows : (int, int), optional
        Reference-band lines holding the tie points; default: all.
    options : CalibrationOptions
        ``robust`` (the robust loss of the solves) and ``attitude`` (the candidate bases of the
        parallax path; ``"static"`` turns it off) are used.
    parallax : bool
        Estimate the time-varying attitude correction from the reference band's GCPs and every
        band's tie points together (band parallax, docs/attitude.md) and write it into the
        manifest. Needs the GCPs: ``gcps_path``, or the ``gcp_file`` named in the
        ``calibration.json`` beside the calibrated manifest; without them the stage goes on
        without parallax and the summary says why.
    gcps_path : str or Path, optional
        GCP table of the reference band (as given to ``gcpcal calibrate``).
    progress : callable(str), optional
        Receives progress messages.
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in the summary.
    on_result : callable, optional
        Receives the :class:`calibrate.relative.RelativeResult` (``result.model``: every band
        calibrated, its ``calibration`` the output's status) once the outputs are in place: for a
        pipeline that reports on it (:mod:`calibrate.pipelines.demo`).

    Returns
    -------
    dict
        The summary written to ``relative.summary.json`` (``success``, ``bands``,
        ``product_check``, ``seconds``) with ``warnings``.

    Raises
    ------
    InputError
        Missing or malformed files, unknown band, a calibration of another scene.
    """
    from calibrate.relative import relative_calibration
    from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

    from calibrate.actions._status import calibration_input, open_usable_calibration

    t0 = time.perf_counter()
    calibrated, cal_path, warning = open_usable_calibration(calibration, command="relative")  # refuses a failed one
    inputs = [scene_path, calibration_input(calibration), cal_path, dem_path, geoid, gcps_path]
    with staged_folder(out_dir, ".relative-", inputs=inputs) as stage:  # checks the output path first
        scene, reference_band = _open_scene(scene_path, calibrated, cal_path, reference_band, self_check)
        dem = open_dem(dem_path, dem_datum, geoid, model=calibrated)  # tiles: only under the scene
        check_dem_footprint(dem, *footprint_sample_lonlat(calibrated, float(np.mean(dem.height_range_m))))
        images = _LazyBands(scene)  # the reference band and one other band in memory at a time
        gcps, gcp_note = _reference_gcps(gcps_path, cal_path, calibrated) if parallax else (None, "--no-parallax")
        result = relative_calibration(calibrated, images, dem, reference_band=reference_band, window_px=window_px,
                                      spacing_px=spacing_px, rows=rows, robust=options.robust, gcps=gcps,
                                      parallax=parallax, attitude=options.attitude, progress=progress)
        if result.parallax is not None and not result.parallax.get("used") and gcp_note:
            result.parallax["reason"] = gcp_note
        report = result.to_dict()
        report.update({"scene": str(scene_path), "calibration": str(cal_path), "dem": str(dem_path)})
        result.model.calibration = _output_status(result, calibrated.calibration)
        summary = _write_outputs(stage, Path(out_dir), scene, result, report, reference_band, t0)
    if on_result is not None:
        on_result(result)
    return summary | {"warnings": ([warning] if warning else []) + summary.get("warnings", [])}


def _open_scene(scene_path, calibrated, cal_path, reference_band, self_check):
    """The LAB scene, checked against the calibrated model, and the reference band."""
    from sensor_models.readers import open_scene

    scene = open_scene(scene_path, self_check=self_check)
    if scene.model.interior_layout != "per_array":
        raise InputError("relative calibration needs a push-broom scene manifest", path=str(scene_path))
    _same_scene(scene.model, calibrated, str(cal_path))
    reference_band = reference_band or calibrated.reference_band
    if reference_band not in scene.model.bands:
        raise InputError(f"unknown band {reference_band!r}; the scene has {', '.join(scene.model.bands)}",
                         field="reference_band")
    return scene, reference_band


def _write_outputs(stage: Path, out_dir: Path, scene, result, report: dict, reference_band: str, t0: float) -> dict:
    """Write the three outputs into the staging folder; raster paths relative to ``out_dir``."""
    from sensor_models.readers.manifest import manifest_to_dict

    rasters = {b: {"path": os.path.relpath(r["path"], out_dir.absolute()), "index": r.get("index", 1)}
               for b, r in scene.rasters.items()}
    doc = manifest_to_dict(result.model, rasters=rasters)
    doc["name"] = (scene.model.name or "scene") + " (calibrated, band-to-band)"
    (stage / "manifest.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    (stage / "relative.json").write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    summary = record_product_check(_summary(result, reference_band, time.perf_counter() - t0), scene.product_check)
    (stage / "relative.summary.json").write_text(json.dumps(with_provenance(summary), indent=1) + "\n", encoding="utf-8")
    return summary


def _summary(result, reference_band: str, seconds: float) -> dict:
    """The JSON summary of the stage (``relative.summary.json``)."""
    return json_safe({
        "kind": "gcpcal.relative",
        "success": result.success,
        "message": result.message,
        "reference_band": reference_band,
        "bands": {b: {"success": r.success, "ties": len(r.ties), "windows": r.windows,
                      "tie_rms_px": {"before": r.before.get("rms_px"), "after": r.after.get("rms_px")}}
                  for b, r in result.bands.items()},
        "parallax": _parallax_summary(result.parallax),
        "model": "manifest.json",
        "calibration_status": result.model.calibration.status,
        "calibration_message": result.model.calibration.message,
        "report": "relative.json",
        "seconds": seconds,
    })


def _parallax_summary(record) -> dict:
    """The summary's ``parallax``: used, tie points and GCPs that entered, the basis chosen."""
    if not record or not record.get("used"):
        return {"used": False, "reason": (record or {}).get("reason") or (record or {}).get("message", "--no-parallax")}
    return {"used": True, "ties": record["ties"], "gcps": record["gcps"], "rounds": record["rounds"],
            "selected": record["selected"], "gcp_only": record["gcp_only"]}


def _reference_gcps(gcps_path, cal_path: Path, model):
    """The reference band's GCP table for the parallax path, and why there is none (or "")."""
    from gcpmatch.gcp_files import read_gcps

    if gcps_path is None:
        doc_path = Path(cal_path).parent / "calibration.json"
        from sensor_models.files.documents import load_json

        try:
            named = load_json(doc_path).get("gcp_file") if doc_path.is_file() else None
        except (InputError, AttributeError):
            named = None
        if not named:
            return None, f"no GCP table: give --gcps (no gcp_file in {doc_path})"
        candidates = [Path(named), doc_path.parent / named]
        found = [p for p in candidates if p.is_file()]
        if not found:
            return None, f"no GCP table: {named} (named by {doc_path}) is not found; give --gcps"
        gcps_path = found[0]
    from calibrate.plausibility import check_gcps_on_scene

    table = read_gcps(gcps_path, image_shape=model.image_shape)
    check_gcps_on_scene(model, table.lon, table.lat, table.h, source=gcps_path)
    return table, ""


def _same_scene(scene, calibrated, path) -> None:
    """InputError unless ``calibrated`` describes the same image as ``scene``."""
    if calibrated.interior_layout != "per_array":
        raise InputError(f"not a push-broom manifest (a {calibrated.kind} model); give the "
                         "manifest.json written by 'gcpcal calibrate'", path=path)
    if calibrated.image_shape[0] != scene.image_shape[0]:
        raise InputError(f"the calibration describes {calibrated.image_shape[0]} lines, the scene {scene.image_shape[0]}: "
                         "a calibration of another scene", path=path)
    if set(calibrated.bands) != set(scene.bands):
        raise InputError(f"the calibration has bands {', '.join(calibrated.bands)}, the scene "
                         f"{', '.join(scene.bands)}: a calibration of another scene", path=path)
    for band in scene.bands:
        layout = [(a.name, a.first_col, a.n_detectors) for a in scene.detector_arrays(band)]
        if [(a.name, a.first_col, a.n_detectors) for a in calibrated.detector_arrays(band)] != layout:
            raise InputError(f"band {band}: the calibration's CCD layout differs from the scene's: "
                             "a calibration of another scene", path=path)
    if np.datetime64(calibrated.epoch, "ns") != np.datetime64(scene.epoch, "ns"):
        raise InputError(f"the calibration's epoch {calibrated.epoch} differs from the scene's {scene.epoch}: "
                         "a calibration of another scene", path=path)


class _LazyBands(Mapping):
    """Band rasters of a scene manifest, read when asked for and not kept (bounded memory)."""

    def __init__(self, scene):
        self._scene = scene

    def __getitem__(self, band):
        from gcpmatch.extract import read_band

        if band not in self._scene.model.bands:
            raise KeyError(band)
        return read_band(self._scene, band)

    def __contains__(self, band) -> bool:  # without reading the raster
        return band in self._scene.model.bands and band in self._scene.rasters

    def __iter__(self):
        return iter(self._scene.model.bands)

    def __len__(self) -> int:
        return len(self._scene.model.bands)


def _output_status(result, input_status):
    """The status of the band-to-band model: calibrated only when every band and the input were.

    A failed band is named as uncalibrated; the input's uncalibrated and unverified arrays are
    carried forward.
    """
    from sensor_models.base import CalibrationStatus

    if not result.bands:
        return CalibrationStatus("failed", "no band calibrated")
    failed = tuple({"band": b, "ccd": "", "reason": r.message} for b, r in result.bands.items() if not r.success)
    done = {b for b, r in result.bands.items() if r.success}
    carried_u, carried_v = (), ()
    if input_status is not None and input_status.status != "calibrated":
        # a band the absolute calibration left to this step (no GCP in it) is settled when it succeeded
        carried_u = tuple(e for e in input_status.uncalibrated if not (e["ccd"] == "" and e["band"] in done))
        carried_v = tuple(input_status.unverified)
    if not failed and not carried_u and not carried_v:
        return CalibrationStatus("calibrated")
    why = [f"band(s) {', '.join(e['band'] for e in failed)} not calibrated"] if failed else []
    if carried_u or carried_v:
        why.append(f"reference calibration partial: {input_status.message}")
    return CalibrationStatus("partial", "; ".join(why), uncalibrated=carried_u + failed, unverified=carried_v)
