"""Pieces shared by the two scene-manifest readers (push-broom and geostationary staring).

Both manifest kinds (``docs/manifest.md``, ``docs/geo_manifest.md``) share the JSON loading,
the ``format_version`` check, the epoch, the ``orbit``, ``attitude`` and ``installation``
objects and the raster reference. They live here so that neither reader imports the other;
the dispatch on ``sensor`` is in :mod:`sensor_models.readers.scene`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from sensor_models.files.atomic import atomic_write_text
from sensor_models.base import CALIBRATION_STATUSES, CalibrationStatus
from sensor_models.geometry.ephemeris import ATTITUDE_FRAMES, ORBIT_FRAMES, Attitude, Orbit
from sensor_models.errors import InputError, ManifestError
from sensor_models.models.pushbroom_types import Installation
from sensor_models.readers._strict import Fields

FORMAT_VERSION = 1
SENSOR_TYPES = ("pushbroom", "geo_staring")


class RasterRef(dict):
    """``{"path": str, "index": int}``: where a band's pixels are (path relative to the manifest)."""


def load_json(path: Path):
    """Decode a manifest file.

    Parameters
    ----------
    path : Path
        The JSON file.

    Returns
    -------
    object
        The decoded document (normally a dict; the readers check).

    Raises
    ------
    ManifestError
        If the file cannot be read, is not UTF-8 text, is too large or too deeply nested, or is
        not valid JSON (with line and column): :func:`sensor_models.files.documents.load_json`.
    """
    from sensor_models.files.documents import load_json as _load

    return _load(path, error=ManifestError)


def check_format_version(root: Fields) -> int:
    """Read ``format_version`` and reject any version other than :data:`FORMAT_VERSION`.

    Parameters
    ----------
    root : Fields
        The document's root object.

    Returns
    -------
    int
        The version (always :data:`FORMAT_VERSION`).
    """
    version = root.integer("format_version")
    if version != FORMAT_VERSION:
        raise root.error("format_version", f"unsupported version {version}; this gcpcal reads {FORMAT_VERSION}")
    return version


def epoch_field(fields: Fields, key: str) -> np.datetime64:
    """An ISO-8601 UTC timestamp field (``"2019-05-01T03:12:00.000Z"``).

    Parameters
    ----------
    fields : Fields
        The object holding the field.
    key : str
        The field name (``"epoch_utc"``).

    Returns
    -------
    numpy.datetime64
        The epoch in UTC, nanosecond resolution (:func:`sensor_models.geometry.timescales.parse_utc`).
    """
    from sensor_models.geometry.timescales import parse_utc

    text = fields.string(key)
    try:
        return parse_utc(text)
    except InputError as exc:
        raise fields.error(key, exc.reason) from None


def orbit_from_fields(f: Fields, epoch) -> Orbit:
    """The ``orbit`` object: state vectors at seconds after the epoch.

    Parameters
    ----------
    f : Fields
        The ``orbit`` object (``frame``, ``seconds`` ``(N,)``, ``position_m`` ``(N, 3)``,
        ``velocity_m_s`` ``(N, 3)``).
    epoch : numpy.datetime64
        Scene epoch (UTC) the seconds count from.

    Returns
    -------
    Orbit
    """
    frame = f.string("frame", choices=ORBIT_FRAMES)
    seconds = f.array("seconds", (None,))
    pos = f.array("position_m", (seconds.size, 3))
    vel = f.array("velocity_m_s", (seconds.size, 3))
    f.finish()
    try:
        return Orbit(epoch, seconds, pos, vel, frame=frame)
    except InputError as exc:
        raise ManifestError(exc.reason, path=f.path, field=exc.field) from None


def attitude_from_fields(f: Fields) -> Attitude:
    """The ``attitude`` object: body-to-reference quaternions, scalar last.

    Parameters
    ----------
    f : Fields
        The ``attitude`` object (``frame``, ``seconds`` ``(N,)``, ``quaternions_xyzw``
        ``(N, 4)``).

    Returns
    -------
    Attitude
    """
    frame = f.string("frame", choices=ATTITUDE_FRAMES)
    seconds = f.array("seconds", (None,))
    quat = f.array("quaternions_xyzw", (seconds.size, 4))
    f.finish()
    try:
        return Attitude(seconds, quat, frame=frame)
    except InputError as exc:
        raise ManifestError(exc.reason, path=f.path, field=exc.field) from None


def installation_from_fields(f: Fields) -> Installation:
    """The ``installation`` object: camera-to-body roll, pitch and yaw.

    Parameters
    ----------
    f : Fields
        The ``installation`` object (``roll_rad``, ``pitch_rad``, ``yaw_rad``).

    Returns
    -------
    Installation
        Angles in radians.
    """
    installation = Installation(f.number("roll_rad"), f.number("pitch_rad"), f.number("yaw_rad"))
    f.finish()
    return installation


def raster_from_fields(f: Fields, manifest_path: Path) -> RasterRef:
    """A raster reference object (``path`` relative to the manifest, 1-based band ``index``).

    Parameters
    ----------
    f : Fields
        The raster object.
    manifest_path : Path
        The manifest file; a relative ``path`` is resolved against its folder.

    Returns
    -------
    RasterRef
        With an absolute ``path``.
    """
    rel = f.string("path")
    index = f.integer("index", 1, minimum=1)
    f.finish()
    return RasterRef(path=str((manifest_path.parent / rel).resolve()), index=index)


def iso_utc(epoch) -> str:
    """An epoch as written in manifests: ISO-8601 with nanoseconds and a ``Z``.

    Parameters
    ----------
    epoch : numpy.datetime64 or str
        UTC epoch.

    Returns
    -------
    str
        ``"YYYY-MM-DDTHH:MM:SS.nnnnnnnnnZ"``.
    """
    return str(np.datetime_as_string(np.datetime64(epoch, "ns"), unit="ns")) + "Z"


def raster_to_dict(ref, base_dir) -> dict:
    """A raster reference as written in manifests.

    Parameters
    ----------
    ref : str, Path or dict
        A path (band index 1) or a :class:`RasterRef`-like mapping.
    base_dir : Path or None
        When given, an absolute path is written relative to this folder.

    Returns
    -------
    dict
        ``{"path": posix str, "index": int}``.
    """
    ref = ref if isinstance(ref, dict) else {"path": str(ref), "index": 1}
    p = Path(ref["path"])
    if base_dir is not None and p.is_absolute():
        p = Path(os.path.relpath(p, base_dir))
    return {"path": p.as_posix(), "index": int(ref.get("index", 1))}


def exterior_to_dict(model) -> dict:
    """The ``orbit``, ``attitude`` and ``installation`` objects of a manifest (any model kind).

    Parameters
    ----------
    model : PushbroomModel or GeoStaringModel
        Any model with ``orbit``, ``attitude`` and ``installation``.

    Returns
    -------
    dict
        Keys ``"orbit"``, ``"attitude"``, ``"installation"``, values JSON-ready.
    """
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


def write_document(doc: dict, path: Path) -> Path:
    """Write a manifest document atomically (temporary file in the same folder, then rename).

    Parameters
    ----------
    doc : dict
        The JSON-ready document.
    path : Path
        Destination file.

    Returns
    -------
    Path
        ``path``.
    """
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path


def calibration_from_fields(root: Fields):
    """The optional ``calibration`` object of a manifest (what the calibration achieved).

    Parameters
    ----------
    root : Fields
        The manifest's top-level object.

    Returns
    -------
    CalibrationStatus or None
        None when the manifest has no ``calibration`` object (no calibration wrote it).
    """
    if not root.has("calibration"):
        return None
    f = root.sub("calibration")
    status = f.string("status", choices=CALIBRATION_STATUSES)
    message = f.string("message", "")
    lists = {}
    for name in ("uncalibrated", "unverified"):
        raw = f.raw(name, [])
        if not isinstance(raw, list):
            raise f.error(name, "must be a list of {band, ccd, reason} objects")
        entries = []
        for i, item in enumerate(raw):
            e = Fields(item, f"{f.where}.{name}[{i}]", f.path)
            entries.append({"band": e.string("band", ""), "ccd": e.string("ccd", ""), "reason": e.string("reason", "")})
            e.finish()
        lists[name] = tuple(entries)
    f.finish()
    return CalibrationStatus(status, message, **lists)
