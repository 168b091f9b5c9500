"""The gcpcal manifest of a geostationary staring-camera frame (``sensor: "geo_staring"``).

Same family as the push-broom scene manifest (``docs/manifest.md``): JSON, ``format_version``
1, every field typed, and a missing field, an unknown key, a wrong type, a NaN or
non-increasing times raise :class:`ManifestError` naming the file and the field. The format is
documented in ``docs/geo_manifest.md``; one manifest describes one frame (one exposure
instant) of :class:`~sensor_models.geo_staring.GeoStaringModel`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from sensor_models.atomic import atomic_write_text
from sensor_models.errors import GcpcalError, InputError, ManifestError
from sensor_models.geo_staring import GeoStaringModel, PointingMirror, StaringInterior, StaringLab, fit_interior
from sensor_models.pushbroom_types import Installation
from sensor_models.readers._strict import Fields
from sensor_models.readers.manifest import (FORMAT_VERSION, RasterRef, _attitude, _epoch, _iso, _load_json, _orbit,
                                           exterior_to_dict)

__all__ = ["SENSOR", "geo_manifest_to_dict", "geo_model_from_document", "read_geo_manifest", "write_geo_manifest"]

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


def geo_model_from_document(doc, path) -> GeoStaringModel:
    """Build a model from an already decoded manifest document (``path`` names it in errors).

    For a dispatcher that has read the JSON and looked at ``sensor``.
    """
    path = Path(path)
    root = Fields(doc, "", str(path))
    version = root.integer("format_version")
    if version != FORMAT_VERSION:
        raise root.error("format_version", f"unsupported version {version}; this gcpcal reads {FORMAT_VERSION}")
    root.string("sensor", choices=(SENSOR,))
    name = root.string("name", "")
    epoch = _epoch(root, "epoch_utc")

    img = root.sub("image")
    shape = (img.integer("n_rows", minimum=1), img.integer("n_cols", minimum=1))
    band = img.string("band", "B1")
    rasters = {}
    if img.has("raster"):
        rf = img.sub("raster")
        rel = rf.string("path")
        index = rf.integer("index", 1, minimum=1)
        rf.finish()
        rasters[band] = RasterRef(path=str((path.parent / rel).resolve()), index=index)
    img.finish()

    ff = root.sub("frame")
    seconds = ff.number("seconds")
    ff.finish()
    orbit = _orbit(root.sub("orbit"), epoch)
    attitude = _attitude(root.sub("attitude"))
    fi = root.sub("installation")
    installation = Installation(fi.number("roll_rad"), fi.number("pitch_rad"), fi.number("yaw_rad"))
    fi.finish()
    mirror = None
    if root.has("mirror"):
        fm = root.sub("mirror")
        normal = fm.array("normal_cam", (3,))
        angles = fm.array("angles_rad", (2,))
        fm.finish()
        if not np.linalg.norm(normal) > 0.0:
            raise fm.error("normal_cam", "must not be the zero vector")
        mirror = PointingMirror(tuple(normal), float(angles[0]), float(angles[1]))
    interior, lab, residual = _interior(root.sub("interior"), shape)
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
    model.rasters = rasters
    model.manifest_path = str(path)
    return model


def read_geo_manifest(path) -> GeoStaringModel:
    """Read a ``geo_staring`` manifest (``docs/geo_manifest.md``) into a model.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    GeoStaringModel
        With ``model.rasters`` (band -> :class:`RasterRef`, absolute path; empty without
        ``image.raster``), ``model.manifest_path``, and for a ``"lab"`` interior ``model.lab``
        and ``model.lab_fit_residual``.

    Raises
    ------
    ManifestError
        One line: ``<file>: field '<dotted.path>': <what is wrong>``.
    """
    path = Path(path)
    return geo_model_from_document(_load_json(path), path)


def geo_manifest_to_dict(model: GeoStaringModel, *, raster=None, base_dir=None) -> dict:
    """The manifest document of a model; the interior is written as its 20 coefficients.

    ``raster``: a path or :class:`RasterRef` of the frame's pixels (default: the model's own
    ``rasters`` entry, if any); made relative to ``base_dir`` when given.
    """
    if not isinstance(model, GeoStaringModel):
        raise InputError(f"expected a GeoStaringModel, got {type(model).__name__}")
    if raster is None:
        raster = (getattr(model, "rasters", None) or {}).get(model.band)
    image = {"n_rows": model.n_rows, "n_cols": model.n_cols, "band": model.band}
    if raster is not None:
        ref = raster if isinstance(raster, dict) else {"path": str(raster), "index": 1}
        p = Path(ref["path"])
        if base_dir is not None and p.is_absolute():
            p = Path(os.path.relpath(p, base_dir))
        image["raster"] = {"path": p.as_posix(), "index": int(ref.get("index", 1))}
    doc = {
        "format_version": FORMAT_VERSION,
        "sensor": SENSOR,
        "name": model.name,
        "epoch_utc": _iso(model.epoch),
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
    return doc


def write_geo_manifest(model: GeoStaringModel, path, *, raster=None) -> Path:
    """Write a model's manifest atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    doc = geo_manifest_to_dict(model, raster=raster, base_dir=path.parent.resolve())
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path
