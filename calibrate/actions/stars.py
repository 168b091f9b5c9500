"""Stage action of ``gcpcal stars`` (and the star path of ``gcpcal run``): star-track calibration.

``frames_path`` is a frame list (``frames.json``, format in :func:`calibrate.star_frames.read_frame_list`)
or the folder holding it; the frame times come from it and the model from the manifest it names
(``manifest`` overrides). Writes ``OUT/stars.json`` (tracks, calibration, accuracy, track
points), ``OUT/manifest.json`` (the calibrated model of frame 0, its ``calibration`` status
``calibrated``; a failed estimation's model is kept with status ``failed``, which every command
refuses) and ``OUT/report.html`` with ``OUT/figures/*.png``
(:func:`calibrate.report.star_report.write_star_report`). Frames of another camera than the manifest's
are refused before any work (:func:`read_star_inputs`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from calibrate.actions._io import staged_output
from calibrate.actions._provenance import with_provenance
from calibrate.config import StarOptions
from sensor_models.errors import InputError

__all__ = ["read_star_inputs", "stars_sequence"]


def read_star_inputs(frames_path, manifest=None, *, scene_model=None, scene_source=None):
    """Read a frame list and the camera it calibrates; refuse frames of another camera.

    Parameters
    ----------
    frames_path : str or Path
        ``frames.json`` or its folder.
    manifest : str or Path, optional
        LAB manifest of the camera; default: the one the frame list names.
    scene_model : SensorModel, optional
        The scene whose camera the frames must belong to (``gcpcal run``); checked too.
    scene_source : str or Path, optional
        The scene's file (named in the message).

    Returns
    -------
    frames : list of Path
        The frame rasters.
    seconds : ndarray, shape (F,)
        Frame times from the manifest's epoch, s.
    manifest : Path
        The LAB manifest used.
    lab : GeoStaringModel
        Its model.
    lab_rasters : dict
        The raster the LAB manifest names (``{band: RasterRef}``, empty without one); the
        calibrated manifest names it too.

    Raises
    ------
    InputError
        A malformed list, no manifest, or frames whose image size or pixel angle differ from
        the camera's (:func:`calibrate.star_frames.check_frames_camera`).
    """
    from calibrate.star_frames import check_frames_camera, read_frame_list
    from sensor_models.readers.geo_manifest import read_geo_manifest, read_geo_manifest_and_rasters

    frames, seconds, listed = read_frame_list(frames_path)
    manifest = Path(manifest) if manifest else listed
    if manifest is None:
        raise InputError("the frame list names no manifest; give --manifest", path=str(frames_path))
    lab, lab_rasters = read_geo_manifest_and_rasters(manifest)
    listed_model = lab if listed is None or Path(listed) == manifest else read_geo_manifest(listed)
    check_frames_camera(frames, listed_model, lab, frames_source=frames_path, model_source=manifest)
    if scene_model is not None:
        check_frames_camera(frames, lab, scene_model, frames_source=frames_path, model_source=scene_source)
    return frames, seconds, manifest, lab, lab_rasters


@staged_output("out_dir", inputs=("frames_path", "manifest"), prefix=".stars-")
def stars_sequence(frames_path, out_dir, *, manifest=None, options: StarOptions = StarOptions(),
                   versus_points=(10, 15, 20, 25)) -> dict:
    """Read the frames, calibrate from the star tracks, write ``stars.json``, the manifest, the report.

    Parameters
    ----------
    frames_path : str or Path
        ``frames.json`` or its folder.
    out_dir : str or Path
        Output folder (created when missing).
    manifest : str or Path, optional
        LAB manifest; default: the one the frame list names.
    options : StarOptions
        Catalogue, magnitude limit, scheme, centroid and seed of the held-out points.
    versus_points : tuple of int
        Track lengths of the accuracy-versus-points study.

    Returns
    -------
    dict
        The document written to ``stars.json`` (``success``, ``message``, ``accuracy``, ...).
    """
    from calibrate.star_calibration import process_frames
    from sensor_models.files.atomic import atomic_write_text
    from sensor_models.base import CalibrationStatus
    from sensor_models.readers.geo_manifest import write_geo_manifest

    t0 = time.perf_counter()
    frames, seconds, manifest, lab, lab_rasters = read_star_inputs(frames_path, manifest)
    catalog, mag_limit = options.catalog, options.mag_limit
    result = process_frames(frames, seconds, lab, options=options, versus_points=versus_points)
    out_dir = Path(out_dir)  # the staging folder (staged_output)
    doc = result.to_dict(points=True)
    doc["inputs"] = {"frames": str(frames_path), "manifest": str(manifest), "catalog": str(catalog),
                     "mag_limit": mag_limit}
    if result.success:
        result.model.calibration = CalibrationStatus("calibrated")
        write_geo_manifest(result.model, out_dir / "manifest.json", raster=lab_rasters.get(result.model.band))
        doc["calibrated_manifest"] = "manifest.json"
    elif getattr(result, "model", None) is not None:  # kept for diagnosis, marked unusable
        result.model.calibration = CalibrationStatus("failed", result.message)
        write_geo_manifest(result.model, out_dir / "manifest.json", raster=lab_rasters.get(result.model.band))
    doc["calibration_status"] = "calibrated" if result.success else "failed"
    doc["timings"]["command_s"] = time.perf_counter() - t0
    atomic_write_text(out_dir / "stars.json", json.dumps(with_provenance(doc), indent=1, allow_nan=False) + "\n")
    from calibrate.report.star_report import write_star_report

    write_star_report(out_dir, doc, result=result)
    return doc
