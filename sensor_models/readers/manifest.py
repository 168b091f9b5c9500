"""The gcpcal push-broom scene manifest (JSON, ``format_version`` 1): read strictly, write atomically.

The format is documented in ``docs/manifest.md``. Every field is typed; a missing field, an
unknown key, a wrong type, a NaN, or non-increasing times raise :class:`ManifestError` naming
the file and the field. :func:`sensor_models.readers.scene.read_manifest` reads either manifest
kind (it dispatches on ``sensor``); this module knows only ``sensor: "pushbroom"``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sensor_models.models.attitude_correction import AttitudeCorrection
from sensor_models.errors import GcpcalError, InputError, ManifestError
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.models.pushbroom_types import CcdLook, LineTiming
from sensor_models.readers._common import (calibration_from_fields, FORMAT_VERSION, SENSOR_TYPES, attitude_from_fields,
                                           check_format_version, epoch_field, exterior_to_dict,
                                           installation_from_fields, iso_utc, load_json, orbit_from_fields,
                                           raster_from_fields, raster_to_dict, write_document)
from sensor_models.readers._strict import Fields
from sensor_models.models.lab import LabBand, LabCamera, LabCcd, lab_to_directional_angles

__all__ = ["SENSOR", "manifest_to_dict", "pushbroom_model_and_rasters", "pushbroom_model_from_document",
           "read_pushbroom_manifest", "write_manifest"]

SENSOR = "pushbroom"


def _ccd(f: Fields) -> CcdLook:
    name = f.string("name")
    first_col = f.integer("first_col", minimum=0)
    n_det = f.integer("n_detectors", minimum=1)
    tx = f.array("tan_psi_x", (None,))
    ty = f.array("tan_psi_y", (None,))
    f.finish()
    for key, c in (("tan_psi_x", tx), ("tan_psi_y", ty)):
        if not 1 <= c.size <= 8:
            raise f.error(key, f"needs 1 to 8 polynomial coefficients, got {c.size}")
    return CcdLook(name, first_col, n_det, tx, ty)


def _lab_interior(f: Fields):
    """Read the ``interior`` object of a manifest with ``model = "lab"`` (strict).

    Parameters
    ----------
    f : Fields
        The ``interior`` object (``docs/manifest.md``): focal length and pixel size in mm,
        principal point in mm, distortion, tilt and rotation in radians, bands of CCDs.

    Returns
    -------
    dict of str to tuple of CcdLook
        Band name -> directional-angle polynomials per CCD (:func:`lab_to_directional_angles`).
    """
    fb = f.sub("bands")
    bands = []
    for name in fb.obj:
        b = Fields(fb.raw(name), f"{fb.where}.{name}", fb.path)
        offset = b.array("offset_mm", (2,), np.zeros(2))
        entries = b.raw("ccds")
        if not isinstance(entries, list) or not entries:
            raise b.error("ccds", "must be a non-empty list")
        ccds = []
        for i, e in enumerate(entries):
            c = Fields(e, f"{b.where}.ccds[{i}]", b.path)
            ccds.append(
                LabCcd(c.string("name"), c.integer("first_col", minimum=0), c.integer("n_detectors", minimum=1), c.number("x_mm"), c.number("y_mm"))
            )
            c.finish()
        b.finish()
        bands.append(LabBand(name, tuple(ccds), tuple(offset)))
    fb.finish()
    try:
        camera = LabCamera(
            focal_length_mm=f.number("focal_length_mm", positive=True),
            pixel_size_mm=f.number("pixel_size_mm", positive=True),
            bands=tuple(bands),
            principal_point_mm=tuple(f.array("principal_point_mm", (2,), np.zeros(2))),
            radial_k=tuple(f.array("radial_k", (3,), np.zeros(3))),
            decentering_p=tuple(f.array("decentering_p", (2,), np.zeros(2))),
            tilt_rad=f.number("tilt_rad", 0.0),
            rotation_rad=f.number("rotation_rad", 0.0),
            polynomial_degree=f.integer("polynomial_degree", 3),
        )
    except InputError as exc:
        raise f.error(exc.field.split(".")[-1] if exc.field else "interior", exc.reason) from None
    out, _ = lab_to_directional_angles(camera)
    return out


def _interior(f: Fields):
    model = f.string("model", choices=("directional_angles", "lab"))
    if model == "lab":
        bands = _lab_interior(f)
    else:
        fb = f.sub("bands")
        bands = {}
        for band in fb.obj:
            entries = fb.raw(band)
            if not isinstance(entries, list) or not entries:
                raise fb.error(band, "must be a non-empty list of CCDs")
            bands[band] = [_ccd(Fields(e, f"{fb.where}.{band}[{i}]", fb.path)) for i, e in enumerate(entries)]
        fb.finish()
    f.finish()
    if not bands:
        raise f.error("bands", "needs at least one band")
    return bands


def _image(img: Fields, path: Path):
    """``(n_rows, reference_band or None, rasters)`` from the ``image`` object."""
    n_rows = img.integer("n_rows", minimum=1)
    reference_band = img.string("reference_band", None)
    rasters = {}
    if img.has("rasters"):
        fr = img.sub("rasters")
        for band in fr.obj:
            rasters[band] = raster_from_fields(Fields(fr.raw(band), f"{fr.where}.{band}", fr.path), path)
        fr.finish()
    img.finish()
    return n_rows, reference_band, rasters


def _check_bands(rasters, reference_band, bands, path: Path) -> None:
    unknown = sorted(set(rasters) - set(bands))
    if unknown:
        raise ManifestError(f"band {unknown[0]!r} has no interior model", path=str(path), field="image.rasters")
    if reference_band is not None and reference_band not in bands:
        raise ManifestError(f"unknown band {reference_band!r}", path=str(path), field="image.reference_band")


def pushbroom_model_from_document(doc, path) -> PushbroomModel:
    """Build a push-broom model from an already decoded manifest document.

    Parameters
    ----------
    doc : object
        The decoded JSON document (``sensor: "pushbroom"``).
    path : str or Path
        The manifest file: errors name it.

    Returns
    -------
    PushbroomModel
        The model alone; :func:`pushbroom_model_and_rasters` also gives the manifest's rasters.

    Raises
    ------
    ManifestError
        As :func:`pushbroom_model_and_rasters`.
    """
    return pushbroom_model_and_rasters(doc, path)[0]


def pushbroom_model_and_rasters(doc, path) -> tuple[PushbroomModel, dict]:
    """Build a push-broom model and its rasters from an already decoded manifest document.

    Parameters
    ----------
    doc : object
        The decoded JSON document (``sensor: "pushbroom"``).
    path : str or Path
        The manifest file: relative raster paths are resolved against its folder and errors
        name it.

    Returns
    -------
    model : PushbroomModel
        The model the manifest describes.
    rasters : dict
        ``image.rasters``: band -> :class:`RasterRef` with an absolute path (empty when the
        manifest lists none); :func:`~sensor_models.readers.scene_input.open_scene` hands them
        out as ``Scene.rasters``.

    Raises
    ------
    ManifestError
        One line: ``<file>: field '<dotted.path>': <what is wrong>``; also for a
        ``geo_staring`` document (read those with :func:`sensor_models.readers.scene.read_manifest`).
    """
    path = Path(path)
    root = Fields(doc, "", str(path))
    check_format_version(root)
    if root.string("sensor", choices=SENSOR_TYPES) != SENSOR:
        raise root.error("sensor", "is not a push-broom manifest; read_manifest reads every kind")
    name = root.string("name", "")
    epoch = epoch_field(root, "epoch_utc")
    n_rows, reference_band, rasters = _image(root.sub("image"), path)
    lt = root.sub("line_timing")
    line_period_s = lt.number("line_period_s")
    if line_period_s == 0:  # negative: rows run backwards in time (a reverse scan, e.g. WorldView-3)
        raise lt.error("line_period_s", "must be non-zero")
    timing = LineTiming(lt.number("reference_row"), lt.number("reference_seconds"), line_period_s)
    lt.finish()
    orbit = orbit_from_fields(root.sub("orbit"), epoch)
    attitude = attitude_from_fields(root.sub("attitude"))
    installation = installation_from_fields(root.sub("installation"))
    bands = _interior(root.sub("interior"))
    calibration = calibration_from_fields(root)
    correction = _attitude_correction(root, path)
    root.finish()
    _check_bands(rasters, reference_band, bands, path)
    try:
        model = PushbroomModel(
            orbit=orbit,
            attitude=attitude,
            line_timing=timing,
            bands=bands,
            installation=installation,
            n_rows=n_rows,
            reference_band=reference_band,
            name=name,
            attitude_correction=correction,
        )
    except InputError as exc:
        raise ManifestError(exc.reason, path=str(path), field=exc.field) from None
    except GcpcalError as exc:  # OutOfRangeError: the data spans do not cover the lines
        raise ManifestError(str(exc), path=str(path), field="orbit/attitude") from None
    if calibration is not None:
        model.calibration = calibration
    return model, rasters


def _attitude_correction(root: Fields, path: Path):
    """The optional ``attitude_correction`` object (docs/manifest.md), or None."""
    if not root.has("attitude_correction"):
        return None
    try:
        return AttitudeCorrection.from_dict(root.raw("attitude_correction"))
    except InputError as exc:
        raise ManifestError(exc.reason, path=str(path), field=exc.field) from None


def read_pushbroom_manifest(path) -> PushbroomModel:
    """Read a ``pushbroom`` scene manifest (``docs/manifest.md``) into a model.

    Parameters
    ----------
    path : str or Path
        The manifest JSON file.

    Returns
    -------
    PushbroomModel
        As :func:`pushbroom_model_from_document` (the rasters:
        :func:`~sensor_models.readers.scene_input.open_scene`).
    """
    path = Path(path)
    return pushbroom_model_from_document(load_json(path), path)


def manifest_to_dict(model: PushbroomModel, *, rasters=None, base_dir=None) -> dict:
    """The manifest document of a push-broom model.

    Parameters
    ----------
    model : PushbroomModel
        The model to write (directional-angle interior).
    rasters : dict, optional
        Band -> path or :class:`RasterRef` (e.g. ``Scene.rasters``); default: none written.
    base_dir : Path, optional
        When given, absolute raster paths are written relative to this folder.

    Returns
    -------
    dict
        The JSON-ready document (``format_version`` 1, ``sensor: "pushbroom"``).
    """
    out_rasters = {band: raster_to_dict(ref, base_dir) for band, ref in (rasters or {}).items()}
    image = {"n_rows": model.n_rows, "reference_band": model.reference_band}
    if out_rasters:
        image["rasters"] = out_rasters
    doc = {
        "format_version": FORMAT_VERSION,
        "sensor": SENSOR,
        "name": model.name,
        "epoch_utc": iso_utc(model.epoch),
        "image": image,
        "line_timing": {
            "reference_row": model.line_timing.reference_row,
            "reference_seconds": model.line_timing.reference_seconds,
            "line_period_s": model.line_timing.line_period_s,
        },
        **exterior_to_dict(model),
        "interior": {
            "model": "directional_angles",
            "bands": {
                band: [
                    {
                        "name": c.name,
                        "first_col": c.first_col,
                        "n_detectors": c.n_detectors,
                        "tan_psi_x": c.tan_psi_x.tolist(),
                        "tan_psi_y": c.tan_psi_y.tolist(),
                    }
                    for c in ccds
                ]
                for band, ccds in model.bands.items()
            },
        },
    }
    if model.attitude_correction is not None:  # time-varying attitude (calibrate --attitude)
        doc["attitude_correction"] = model.attitude_correction.to_dict()
    if model.calibration is not None:  # what the calibration that wrote the model achieved
        doc["calibration"] = model.calibration.to_dict()
    return doc


def write_manifest(model: PushbroomModel, path, *, rasters=None) -> Path:
    """Write a push-broom manifest atomically (temporary file in the same folder, then rename).

    Parameters
    ----------
    model : PushbroomModel
        The model.
    path : str or Path
        Destination ``.json``; raster paths are written relative to its folder.
    rasters : dict, optional
        Band -> path or :class:`RasterRef` (e.g. ``Scene.rasters``); default: none written.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    return write_document(manifest_to_dict(model, rasters=rasters, base_dir=path.parent.resolve()), path)
