"""The gcpcal scene manifest (JSON, ``format_version`` 1): read strictly, write atomically.

The format is documented in ``docs/manifest.md``. Every field is typed; a missing field, an
unknown key, a wrong type, a NaN, or non-increasing times raise :class:`ManifestError` naming
the file and the field.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from sensor_models.atomic import atomic_write_text
from sensor_models.ephemeris import ATTITUDE_FRAMES, ORBIT_FRAMES, Attitude, Orbit
from sensor_models.errors import GcpcalError, InputError, ManifestError
from sensor_models.pushbroom import PushbroomModel
from sensor_models.pushbroom_types import CcdLook, Installation, LineTiming
from sensor_models.readers._strict import Fields

__all__ = ["FORMAT_VERSION", "manifest_to_dict", "read_manifest", "write_manifest", "RasterRef"]

FORMAT_VERSION = 1


class RasterRef(dict):
    """``{"path": str, "index": int}``: where a band's pixels are (path relative to the manifest)."""


def _load_json(path: Path):
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ManifestError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ManifestError(f"is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})", path=str(path)) from None


def _epoch(fields: Fields, key: str) -> np.datetime64:
    from sensor_models.timescales import parse_utc

    text = fields.string(key)
    try:
        return parse_utc(text)
    except InputError as exc:
        raise fields.error(key, exc.reason) from None


def _orbit(f: Fields, epoch) -> Orbit:
    frame = f.string("frame", choices=ORBIT_FRAMES)
    seconds = f.array("seconds", (None,))
    pos = f.array("position_m", (seconds.size, 3))
    vel = f.array("velocity_m_s", (seconds.size, 3))
    f.finish()
    try:
        return Orbit(epoch, seconds, pos, vel, frame=frame)
    except InputError as exc:
        raise ManifestError(exc.reason, path=f.path, field=exc.field) from None


def _attitude(f: Fields) -> Attitude:
    frame = f.string("frame", choices=ATTITUDE_FRAMES)
    seconds = f.array("seconds", (None,))
    quat = f.array("quaternions_xyzw", (seconds.size, 4))
    f.finish()
    try:
        return Attitude(seconds, quat, frame=frame)
    except InputError as exc:
        raise ManifestError(exc.reason, path=f.path, field=exc.field) from None


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


def _interior(f: Fields):
    model = f.string("model", choices=("directional_angles", "lab"))
    if model == "lab":
        from sensor_models.lab import lab_from_fields

        bands = lab_from_fields(f)
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


def read_manifest(path) -> PushbroomModel:
    """Read a scene manifest into a sensor model.

    Parameters
    ----------
    path : str or Path
        The manifest JSON file.

    Returns
    -------
    PushbroomModel
        With ``model.rasters`` (band -> :class:`RasterRef` with an absolute path) and
        ``model.manifest_path`` set.
    """
    path = Path(path)
    doc = _load_json(path)
    if isinstance(doc, dict) and doc.get("sensor") == "geo_staring":
        from sensor_models.readers.geo_manifest import geo_model_from_document

        return geo_model_from_document(doc, path)
    root = Fields(doc, "", str(path))
    version = root.integer("format_version")
    if version != FORMAT_VERSION:
        raise root.error("format_version", f"unsupported version {version}; this gcpcal reads {FORMAT_VERSION}")
    root.string("sensor", choices=("pushbroom", "geo_staring"))
    name = root.string("name", "")
    epoch = _epoch(root, "epoch_utc")

    img = root.sub("image")
    n_rows = img.integer("n_rows", minimum=1)
    reference_band = img.string("reference_band", None)
    rasters = {}
    if img.has("rasters"):
        fr = img.sub("rasters")
        for band in fr.obj:
            rf = Fields(fr.raw(band), f"{fr.where}.{band}", fr.path)
            rel = rf.string("path")
            index = rf.integer("index", 1, minimum=1)
            rf.finish()
            rasters[band] = RasterRef(path=str((path.parent / rel).resolve()), index=index)
        fr.finish()
    img.finish()

    lt = root.sub("line_timing")
    timing = LineTiming(lt.number("reference_row"), lt.number("reference_seconds"), lt.number("line_period_s", positive=True))
    lt.finish()
    orbit = _orbit(root.sub("orbit"), epoch)
    attitude = _attitude(root.sub("attitude"))
    fi = root.sub("installation")
    installation = Installation(fi.number("roll_rad"), fi.number("pitch_rad"), fi.number("yaw_rad"))
    fi.finish()
    bands = _interior(root.sub("interior"))
    root.finish()

    unknown = sorted(set(rasters) - set(bands))
    if unknown:
        raise ManifestError(f"band {unknown[0]!r} has no interior model", path=str(path), field="image.rasters")
    if reference_band is not None and reference_band not in bands:
        raise ManifestError(f"unknown band {reference_band!r}", path=str(path), field="image.reference_band")
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
        )
    except InputError as exc:
        raise ManifestError(exc.reason, path=str(path), field=exc.field) from None
    except GcpcalError as exc:  # OutOfRangeError: the data spans do not cover the lines
        raise ManifestError(str(exc), path=str(path), field="orbit/attitude") from None
    model.rasters = rasters
    model.manifest_path = str(path)
    return model


def _iso(epoch) -> str:
    return str(np.datetime_as_string(np.datetime64(epoch, "ns"), unit="ns")) + "Z"


def exterior_to_dict(model) -> dict:
    """The ``orbit``, ``attitude`` and ``installation`` objects of a manifest (any model kind)."""
    return {
        "orbit": {
            "frame": model.orbit.frame,
            "seconds": model.orbit.seconds.tolist(),
            "position_m": model.orbit.position_m.tolist(),
            "velocity_m_s": model.orbit.velocity_m_s.tolist(),
        },
        "attitude": {
            "frame": model.attitude.frame,
            "seconds": model.attitude.seconds.tolist(),
            "quaternions_xyzw": model.attitude.quaternions_xyzw.tolist(),
        },
        "installation": {
            "roll_rad": model.installation.roll,
            "pitch_rad": model.installation.pitch,
            "yaw_rad": model.installation.yaw,
        },
    }


def manifest_to_dict(model: PushbroomModel, *, rasters=None, base_dir=None) -> dict:
    """The manifest document of a push-broom model (``rasters``: band -> path or RasterRef)."""
    out_rasters = {}
    for band, ref in (rasters or getattr(model, "rasters", {}) or {}).items():
        ref = ref if isinstance(ref, dict) else {"path": str(ref), "index": 1}
        p = Path(ref["path"])
        if base_dir is not None and p.is_absolute():
            p = Path(os.path.relpath(p, base_dir))
        out_rasters[band] = {"path": p.as_posix(), "index": int(ref.get("index", 1))}
    image = {"n_rows": model.n_rows, "reference_band": model.reference_band}
    if out_rasters:
        image["rasters"] = out_rasters
    return {
        "format_version": FORMAT_VERSION,
        "sensor": "pushbroom",
        "name": model.name,
        "epoch_utc": _iso(model.epoch),
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


def write_manifest(model: PushbroomModel, path, *, rasters=None) -> Path:
    """Write a manifest atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    doc = manifest_to_dict(model, rasters=rasters, base_dir=path.parent.resolve())
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path
