"""The gcpcal manifest of a geostationary staring-camera frame (``sensor: "geo_staring"``).

Same family as the push-broom scene manifest (``docs/manifest.md``): JSON, ``format_version``
1, every field typed, and a missing field, an unknown key, a wrong type, a NaN or
non-increasing times raise :class:`ManifestError` naming the file and the field. The format is
documented in ``docs/geo_manifest.md``; one manifest describes one frame (one exposure
instant) of :class:`~sensor_models.models.geo_staring.GeoStaringModel`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sensor_models.errors import GcpcalError, InputError, ManifestError
from sensor_models.models.geo_staring import GeoStaringModel
from sensor_models.models.staring_camera import PointingMirror, StaringInterior, StaringLab, fit_interior
from sensor_models.readers._common import (calibration_from_fields, FORMAT_VERSION, attitude_from_fields, check_format_version, epoch_field,
                                           exterior_to_dict, installation_from_fields, iso_utc, load_json,
                                           orbit_from_fields, raster_from_fields, raster_to_dict, write_document)
from sensor_models.readers._strict import Fields

__all__ = ["SENSOR", "geo_manifest_to_dict", "geo_model_and_rasters", "geo_model_from_document", "read_geo_manifest",
           "read_geo_manifest_and_rasters", "write_geo_manifest"]

SENSOR = "geo_staring"


def _interior(f: Fields, image_shape):
    """``(StaringInterior, lab or None, fit residual or None)`` from the ``interior`` object."""
    model = f.string("model", choices=("directional_angles", "lab"))
    if model == "directional_angles":
        tx = f.array("tan_psi_x", (10,))
        ty = f.array("tan_psi_y", (10,))
        f.finish()
        try:
            return StaringInterior(tx, ty), None, None
        except InputError as exc:
            raise f.error("tan_psi_x", exc.reason) from None
    focal = f.number("focal_length_mm", positive=True)
    pitch = f.number("pixel_size_mm", positive=True)
    pp = f.array("principal_point_px", (2,), None)
    radial = f.array("radial_k", (2,), np.zeros(2))
    decentering = f.array("decentering_p", (2,), np.zeros(2))
    tilt = f.array("tilt_rad", (2,), np.zeros(2))
    rotation = f.number("rotation_rad", 0.0)
    grid = f.integer("fit_grid", 65, minimum=4)
    f.finish()
    lab = StaringLab(
        focal_length_mm=focal,
        pixel_size_mm=pitch,
        principal_point_px=None if pp is None else tuple(pp),
        radial_k=tuple(radial),
        decentering_p=tuple(decentering),
        tilt_rad=tuple(tilt),
        rotation_rad=rotation,
    )
    try:
        interior, residual = fit_interior(lab, image_shape, grid=grid)
    except InputError as exc:
        raise f.error("model", exc.reason) from None
    return interior, lab, residual


def _image(img: Fields, path: Path):
    """``((n_rows, n_cols), band, rasters)`` from the ``image`` object."""
    shape = (img.integer("n_rows", minimum=1), img.integer("n_cols", minimum=1))
    band = img.string("band", "B1")
    rasters = {}
    if img.has("raster"):
        rasters[band] = raster_from_fields(img.sub("raster"), path)
    img.finish()
    return shape, band, rasters


def _mirror(root: Fields):
    """The optional ``mirror`` object as a :class:`PointingMirror` (``None`` when absent)."""
    if not root.has("mirror"):
        return None
    fm = root.sub("mirror")
    normal = fm.array("normal_cam", (3,))
    angles = fm.array("angles_rad", (2,))
    fm.finish()
    if not np.linalg.norm(normal) > 0.0:
        raise fm.error("normal_cam", "must not be the zero vector")
    return PointingMirror(tuple(normal), float(angles[0]), float(angles[1]))


def geo_model_from_document(doc, path) -> GeoStaringModel:
    """Build a model from an already decoded manifest document (the model alone).

    Parameters
    ----------
    doc : object
        The decoded JSON document (``sensor: "geo_staring"``).
    path : str or Path
        The manifest file: errors name it.

    Returns
    -------
    GeoStaringModel
        As :func:`read_geo_manifest`.
    """
    return geo_model_and_rasters(doc, path)[0]


def geo_model_and_rasters(doc, path) -> tuple[GeoStaringModel, dict]:
    """Build a model and its raster from an already decoded manifest document.

    For a dispatcher that has read the JSON and looked at ``sensor``
    (:func:`sensor_models.readers.scene.read_manifest_and_rasters`).

    Parameters
    ----------
    doc : object
        The decoded JSON document (``sensor: "geo_staring"``).
    path : str or Path
        The manifest file: a relative raster path is resolved against its folder and errors
        name it.

    Returns
    -------
    model : GeoStaringModel
        As :func:`read_geo_manifest`.
    rasters : dict
        ``{band: RasterRef}`` of ``image.raster`` (absolute path), empty without one.
    """
    path = Path(path)
    root = Fields(doc, "", str(path))
    check_format_version(root)
    root.string("sensor", choices=(SENSOR,))
    name = root.string("name", "")
    epoch = epoch_field(root, "epoch_utc")
    shape, band, rasters = _image(root.sub("image"), path)
    ff = root.sub("frame")
    seconds = ff.number("seconds")
    ff.finish()
    orbit = orbit_from_fields(root.sub("orbit"), epoch)
    attitude = attitude_from_fields(root.sub("attitude"))
    installation = installation_from_fields(root.sub("installation"))
    mirror = _mirror(root)
    interior, lab, residual = _interior(root.sub("interior"), shape)
    calibration = calibration_from_fields(root)
    root.finish()
    try:
        model = GeoStaringModel(
            orbit=orbit,
            attitude=attitude,
            frame_seconds=seconds,
            interior=interior,
            image_shape=shape,
            installation=installation,
            mirror=mirror,
            band=band,
            name=name,
        )
    except InputError as exc:
        raise ManifestError(exc.reason, path=str(path), field=exc.field) from None
    except GcpcalError as exc:  # OutOfRangeError: the frame lies outside the orbit/attitude data
        raise ManifestError(str(exc), path=str(path), field="frame.seconds") from None
    model.lab = lab
    model.lab_fit_residual = residual
    if calibration is not None:
        model.calibration = calibration
    return model, rasters


def read_geo_manifest(path) -> GeoStaringModel:
    """Read a ``geo_staring`` manifest (``docs/geo_manifest.md``) into a model.

    Parameters
    ----------
    path : str or Path
        The manifest JSON file.

    Returns
    -------
    GeoStaringModel
        For a ``"lab"`` interior with ``model.lab`` and ``model.lab_fit_residual``; the frame's
        raster: :func:`read_geo_manifest_and_rasters`.

    Raises
    ------
    ManifestError
        One line: ``<file>: field '<dotted.path>': <what is wrong>``.
    """
    return read_geo_manifest_and_rasters(path)[0]


def read_geo_manifest_and_rasters(path) -> tuple[GeoStaringModel, dict]:
    """Read a ``geo_staring`` manifest into a model and the raster it names.

    Parameters
    ----------
    path : str or Path
        The manifest JSON file.

    Returns
    -------
    model : GeoStaringModel
        As :func:`read_geo_manifest`.
    rasters : dict
        ``{band: RasterRef}`` (absolute path) of ``image.raster``; empty without one.

    Raises
    ------
    ManifestError
        As :func:`read_geo_manifest`.
    """
    path = Path(path)
    return geo_model_and_rasters(load_json(path), path)


def geo_manifest_to_dict(model: GeoStaringModel, *, raster=None, base_dir=None) -> dict:
    """The manifest document of a model; the interior is written as its 20 coefficients.

    Parameters
    ----------
    model : GeoStaringModel
        The model to write.
    raster : str, Path or RasterRef, optional
        The frame's pixels (e.g. ``Scene.rasters[model.band]``); default: none written.
    base_dir : Path, optional
        When given, an absolute raster path is written relative to this folder.

    Returns
    -------
    dict
        The JSON-ready document (``format_version`` 1, ``sensor: "geo_staring"``).
    """
    if not isinstance(model, GeoStaringModel):
        raise InputError(f"expected a GeoStaringModel, got {type(model).__name__}")
    image = {"n_rows": model.n_rows, "n_cols": model.n_cols, "band": model.band}
    if raster is not None:
        image["raster"] = raster_to_dict(raster, base_dir)
    doc = {
        "format_version": FORMAT_VERSION,
        "sensor": SENSOR,
        "name": model.name,
        "epoch_utc": iso_utc(model.epoch),
        "image": image,
        "frame": {"seconds": model.frame_seconds},
        **exterior_to_dict(model),
    }
    if model.mirror is not None:
        doc["mirror"] = {
            "normal_cam": list(model.mirror.normal_cam),
            "angles_rad": [model.mirror.angle_x, model.mirror.angle_y],
        }
    doc["interior"] = {
        "model": "directional_angles",
        "tan_psi_x": model.interior.tan_psi_x.tolist(),
        "tan_psi_y": model.interior.tan_psi_y.tolist(),
    }
    if model.calibration is not None:  # what the calibration that wrote the model achieved
        doc["calibration"] = model.calibration.to_dict()
    return doc


def write_geo_manifest(model: GeoStaringModel, path, *, raster=None) -> Path:
    """Write a model's manifest atomically (temporary file in the same folder, then rename).

    Parameters
    ----------
    model : GeoStaringModel
        The model.
    path : str or Path
        Destination ``.json``; the raster path is written relative to its folder.
    raster : str, Path or RasterRef, optional
        The frame's pixels; default: none written.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    return write_document(geo_manifest_to_dict(model, raster=raster, base_dir=path.parent.resolve()), path)
