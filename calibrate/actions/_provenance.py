"""Provenance of every output: what made it, from what, with which terrain and reference.

Every stage's JSON summary gets a ``provenance`` block (:func:`provenance_record`), every report
a header built from it, and every GeoTIFF gcpcal writes a ``GCPCAL_PROVENANCE`` metadata item
(:func:`geotiff_tags`):

``gcpcal_version``, ``command_line``
    The version and the command as typed (``gcpcal match scene.json --dom ...``; empty when a
    stage action is called from Python).
``created_utc``, ``python``, ``platform``
    When and where.
``inputs``
    Every input file the stage read (the files named, their sidecars and the files a manifest
    names): ``path``, ``bytes`` and ``sha256`` (None above :data:`HASH_LIMIT_BYTES`, with the
    reason in ``sha256_note``); input folders by path; GDAL virtual paths (``/vsizip/...``,
    ``/vsicurl/...``) by path in ``virtual_inputs`` (not hashed: they may be remote).
``terrain``
    The DEM's files, its vertical datum as declared or given, and the geoid grid used
    (:func:`note_terrain`).
``reference_accuracy``
    The reference orthoimage's geolocation accuracy and where it was taken from
    (:func:`note`, by the match stage).

The record of the stage running is held in context variables set by the staging helpers
(:func:`stage_inputs`) and the command line (:func:`command_line`), so that no action has to
pass it along.
"""

from __future__ import annotations

import contextvars
import hashlib
import json
import platform
import shlex
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["HASH_LIMIT_BYTES", "PROVENANCE_TAG", "command_line", "current_command_line", "file_digest", "geotiff_tags", "note",
           "note_terrain", "provenance_record", "stage_inputs", "with_provenance"]

#: Files larger than this are listed with their size but not hashed (a large DEM mosaic or DOM
#: would cost seconds per gigabyte for every stage).
HASH_LIMIT_BYTES = 2 * 1024**3
#: GDAL metadata item (default domain) holding the provenance JSON in a GeoTIFF.
PROVENANCE_TAG = "GCPCAL_PROVENANCE"

_COMMAND_LINE: contextvars.ContextVar[tuple | None] = contextvars.ContextVar("gcpcal_command_line", default=None)
_INPUTS: contextvars.ContextVar[object] = contextvars.ContextVar("gcpcal_stage_inputs", default=None)
_NOTES: contextvars.ContextVar[dict | None] = contextvars.ContextVar("gcpcal_provenance_notes", default=None)
#: path -> (size, mtime_ns, sha256): a file read by several stages of one process is hashed once
_DIGESTS: dict[str, tuple[int, int, str]] = {}


@contextmanager
def command_line(argv):
    """Within the block, outputs record ``gcpcal`` followed by ``argv`` as their command line.

    Parameters
    ----------
    argv : sequence of str
        The arguments after the program name.
    """
    token = _COMMAND_LINE.set(tuple(str(a) for a in argv))
    notes = _NOTES.set({})
    try:
        yield
    finally:
        _NOTES.reset(notes)
        _COMMAND_LINE.reset(token)


def current_command_line() -> tuple | None:
    """The arguments of the running command (:func:`command_line`), for work handed to another process.

    Returns
    -------
    tuple of str or None
        None outside a command (a stage action called from Python).
    """
    return _COMMAND_LINE.get()


@contextmanager
def stage_inputs(inputs):
    """Within the block, summaries list ``inputs`` (an :class:`~calibrate.actions._guard.InputSet`).

    Parameters
    ----------
    inputs : InputSet
    """
    token = _INPUTS.set(inputs)
    try:
        yield
    finally:
        _INPUTS.reset(token)


def note(key: str, value) -> None:
    """Record a provenance fact of the running command (e.g. ``reference_accuracy``).

    Parameters
    ----------
    key : str
    value : JSON-ready value
    """
    notes = _NOTES.get()
    if notes is None:
        notes = {}
        _NOTES.set(notes)
    notes[key] = value


def note_terrain(dem) -> None:
    """Record the DEM a stage used: its files, vertical datum and geoid grid.

    Parameters
    ----------
    dem : sensor_models.terrain.dem.Dem
    """
    note("terrain", {"dem": dem.source, "vertical_datum": dem.source_datum, "geoid": dem.geoid_source,
                     "heights_held_as": "WGS84 ellipsoidal"})


def file_digest(path) -> dict:
    """``path``, ``bytes`` and ``sha256`` of a file (``sha256`` None above :data:`HASH_LIMIT_BYTES`).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
    """
    path = Path(path)
    try:
        st = path.stat()
    except OSError as exc:
        return {"path": str(path), "bytes": None, "sha256": None, "sha256_note": f"unreadable: {exc.strerror}"}
    entry = {"path": str(path), "bytes": int(st.st_size)}
    if st.st_size > HASH_LIMIT_BYTES:
        return entry | {"sha256": None, "sha256_note": f"not hashed: larger than {HASH_LIMIT_BYTES} bytes"}
    key = str(path.resolve())
    cached = _DIGESTS.get(key)
    if cached is not None and cached[:2] == (st.st_size, st.st_mtime_ns):
        return entry | {"sha256": cached[2]}
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                digest.update(chunk)
    except OSError as exc:
        return entry | {"sha256": None, "sha256_note": f"unreadable: {exc.strerror}"}
    _DIGESTS[key] = (st.st_size, st.st_mtime_ns, digest.hexdigest())
    return entry | {"sha256": digest.hexdigest()}


def provenance_record(inputs=None) -> dict:
    """The provenance block of the running stage (module docstring).

    Parameters
    ----------
    inputs : InputSet, optional
        Default: the inputs of the stage being staged (:func:`stage_inputs`).

    Returns
    -------
    dict
        JSON-ready.
    """
    from sensor_models import __version__

    inputs = _INPUTS.get() if inputs is None else inputs
    argv = _COMMAND_LINE.get()
    files = sorted({str(p) for p in getattr(inputs, "files", {}).values()})
    folders = sorted({str(p) for p in getattr(inputs, "folders", {}).values()})
    record = {
        "gcpcal_version": __version__,
        "command_line": "" if argv is None else shlex.join(("gcpcal", *argv)),
        "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "python": platform.python_version(),
        "platform": f"{platform.system()} {platform.machine()}",
        "inputs": [file_digest(p) for p in files],
        "input_folders": folders,
        "virtual_inputs": sorted(getattr(inputs, "virtual", ())),
    }
    record.update(_NOTES.get() or {})
    return record


def with_provenance(summary: dict, inputs=None) -> dict:
    """``summary`` with its ``provenance`` block (kept when it holds one already).

    Parameters
    ----------
    summary : dict
    inputs : InputSet, optional
        As :func:`provenance_record`.

    Returns
    -------
    dict
        A new mapping.
    """
    if "provenance" in summary:
        return dict(summary)
    return {**summary, "provenance": provenance_record(inputs)}


def geotiff_tags(inputs=None) -> dict[str, str]:
    """GDAL metadata items for a GeoTIFF gcpcal writes: ``TIFFTAG_SOFTWARE`` and the provenance.

    Parameters
    ----------
    inputs : InputSet, optional
        As :func:`provenance_record`.

    Returns
    -------
    dict of str to str
        ``TIFFTAG_SOFTWARE`` ("gcpcal <version>"), ``TIFFTAG_DATETIME`` and
        :data:`PROVENANCE_TAG` (compact JSON).
    """
    record = provenance_record(inputs)
    stamp = datetime.strptime(record["created_utc"], "%Y-%m-%dT%H:%M:%SZ").strftime("%Y:%m:%d %H:%M:%S")
    return {"TIFFTAG_SOFTWARE": f"gcpcal {record['gcpcal_version']}", "TIFFTAG_DATETIME": stamp,
            PROVENANCE_TAG: json.dumps(record, separators=(",", ":"), default=str)}
