"""The record of what gcpcal wrote: how a rerun tells its own earlier outputs from a user's files.

Each folder gcpcal writes into holds a small JSON file, :data:`LEDGER_NAME`, listing the files
it wrote there (paths relative to the folder; a folder output lists its whole tree) with their
size, SHA-256, inode and modification time, the command and the *unit* they belong to (``"."``
for the files of a folder output, the main file's name for a file output and its sidecars). A
file is gcpcal's own (:func:`owned`) when a ledger in its folder or one of the three above lists
it and it is unchanged: same size and either the same inode and modification time or the same
SHA-256. A file a user edited after gcpcal wrote it is the user's.

The ledger is written before the outputs are moved in, listing the new checksum and the one it
replaces, so that whatever the moment a run is killed, every file in the folder is either
listed or the user's (:func:`record`).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from pathlib import Path

from calibrate.actions._staging import make_temp_file

__all__ = ["LEDGER_NAME", "digest", "ledger_entries", "owned", "owned_entry", "record"]

LEDGER_NAME = ".gcpcal-outputs.json"
_FORMAT = "gcpcal-outputs"
#: How many folders above a file may hold the ledger that lists it (a folder output's subfolders).
_LEDGER_LEVELS = 4


def digest(path) -> str:
    """SHA-256 of a file, hex.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    str
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def ledger_entries(folder) -> dict:
    """The entries of ``folder``'s ledger: relative path -> entry (empty when none or unreadable).

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    dict
    """
    path = Path(folder) / LEDGER_NAME
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(doc, dict) or doc.get("format") != _FORMAT or not isinstance(doc.get("files"), dict):
        return {}
    return {k: v for k, v in doc["files"].items() if isinstance(v, dict)}


def _matches(path: Path, entry: dict, st) -> bool:
    """Whether the file at ``path`` (stat ``st``) is the one ``entry`` records, or the one it replaced."""
    same_size = st.st_size == entry.get("size")
    if same_size and st.st_ino == entry.get("ino") and st.st_mtime_ns == entry.get("mtime_ns"):
        return True
    wanted = {entry.get("sha256")} if same_size else set()
    if st.st_size == entry.get("previous_size"):
        wanted.update(entry.get("previous") or ())
    wanted.discard(None)
    return bool(wanted) and digest(path) in wanted


def owned_entry(path) -> tuple[Path, str, dict] | None:
    """``(ledger folder, relative name, entry)`` of a file gcpcal wrote and nobody changed, else None.

    Parameters
    ----------
    path : str or Path
        An existing regular file (absolute or relative).

    Returns
    -------
    tuple or None
    """
    path = Path(os.path.abspath(path))
    try:
        st = os.stat(path)
    except OSError:
        return None
    root = path.parent
    for _ in range(_LEDGER_LEVELS):
        rel = path.relative_to(root).as_posix()
        entry = ledger_entries(root).get(rel)
        if entry is not None:
            return (root, rel, entry) if _matches(path, entry, st) else None
        if root.parent == root:
            break
        root = root.parent
    return None


def owned(path) -> bool:
    """Whether ``path`` is a file gcpcal wrote and nobody changed since (see the module docstring).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    return owned_entry(path) is not None


def _entry(path: Path, unit: str, command: str, old: dict | None) -> dict:
    st = os.stat(path)
    entry = {"size": st.st_size, "sha256": digest(path), "ino": st.st_ino, "mtime_ns": st.st_mtime_ns,
             "unit": unit, "command": command,
             "written_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    if old:  # the file it replaces: still gcpcal's should the run end before the move
        entry["previous"] = [old.get("sha256")]
        entry["previous_size"] = old.get("size")
    return entry


def record(folder, new: dict, *, unit: str, command: str, drop=(), staged_ledger: Path | None = None) -> None:
    """Add (or replace) entries in ``folder``'s ledger and drop others; written atomically.

    Parameters
    ----------
    folder : str or Path
        The ledger's folder (the output folder, or a file output's folder).
    new : dict
        Relative name -> the file whose size, checksum, inode and time are recorded (the staged
        file: a rename keeps all of them).
    unit : str
        The unit the new files belong to (``"."`` for a folder output).
    command : str
        The command that wrote them.
    drop : iterable of str
        Relative names to remove from the ledger (files removed as stale).
    staged_ledger : Path, optional
        Write the ledger there instead (a staging folder about to become ``folder``).
    """
    folder = Path(folder)
    entries = ledger_entries(folder) if staged_ledger is None else {}
    for rel in drop:
        entries.pop(rel, None)
    for rel, path in new.items():
        old = entries.get(rel)
        entries[rel] = _entry(Path(path), unit, command, old if old and old.get("sha256") else None)
    doc = {"format": _FORMAT, "format_version": 1,
           "about": "files gcpcal wrote in this folder; a rerun may replace or remove these and only these",
           "files": dict(sorted(entries.items()))}
    text = json.dumps(doc, indent=1) + "\n"
    target = staged_ledger if staged_ledger is not None else folder / LEDGER_NAME
    tmp = make_temp_file(target.parent, LEDGER_NAME)
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
