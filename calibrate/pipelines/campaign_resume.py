"""``gcpcal campaign --resume``: which scene folders of an earlier campaign stand, and their rows.

Every scene a campaign runs records in its ``run.summary.json``, under ``campaign``, what it was
made from (:func:`made_from`): every input file it reads (the files named, their sidecars and the
files a manifest names, :class:`calibrate.actions._guard.InputSet`) by absolute path, size and
modification time (``mtime_ns``); the scene's entry of the campaign (DOM, DEM, datum, geoid,
band, QA, star frames, folder); the campaign options that change results (``spacing_px``,
``min_gcps``, ``min_coverage``, ``relative``; not ``threads``, on which the GCPs do not depend);
and the gcpcal version. With ``--resume`` a scene folder stands (:func:`earlier_output`) when

* it is complete and gcpcal's: its ``run.summary.json`` and every other file gcpcal's ledger lists
  for it are there and unchanged (a folder is committed whole, so this means a run ended);
* that run succeeded (a scene that failed runs again);
* it was made from the same inputs and options: the records are equal, or differ only in the
  modification time of files whose SHA-256 (recorded in the summary's provenance) is unchanged.

Its row is then read from its ``run.summary.json`` (:func:`summary_row`, the function that makes
a fresh row from the same summary). Otherwise the scene runs again, and the reason is said.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from calibrate.actions._ledger import LEDGER_NAME, ledger_entries, owned, owned_entry, record

__all__ = ["RECORD_KEY", "RESULT_OPTIONS", "clear_scene", "earlier_output", "fold_ledgers", "made_from",
           "summary_row"]

#: Key of ``run.summary.json`` holding the campaign's record of the scene's run.
RECORD_KEY = "campaign"
#: The campaign options that change a scene's results (``threads`` does not).
RESULT_OPTIONS = ("spacing_px", "min_gcps", "min_coverage", "relative")
#: Ledger unit and command of a campaign's folder (:func:`calibrate.actions._commit.folder_unit`).
_UNIT, _COMMAND = ".:campaign", "campaign"


def summary_row(row: dict, summary: dict) -> dict:
    """Fill a scene's campaign row from its ``gcpcal run`` summary (fresh or read back).

    Parameters
    ----------
    row : dict
        The row with ``name`` and ``folder`` set (keys :data:`calibrate.pipelines.campaign.COLUMNS`).
    summary : dict
        :func:`calibrate.pipelines.run.run_scene`'s summary (``path``, ``gcps``, ``check_rmse_px``,
        ``calibration_status``, ``success``, ``message``).

    Returns
    -------
    dict
        ``row``, updated: ``status`` ``"ok"`` with an empty ``reason`` when the run succeeded,
        else ``"failed"`` with the run's message on one line.
    """
    rmse = summary.get("check_rmse_px") or {}
    row.update(path=summary.get("path"), gcps=summary.get("gcps"), check_rmse_before_px=rmse.get("before"),
               check_rmse_after_px=rmse.get("after"), calibration_status=summary.get("calibration_status"))
    if summary.get("success"):
        row.update(status="ok", reason="")
    else:
        row.update(status="failed", reason=" ".join(str(summary.get("message") or "the calibration failed").split()))
    return row


def _plain(value):
    """``value`` as JSON values, paths absolute (a record compared across runs from other folders)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Path):
        return os.path.abspath(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def made_from(scene, options: dict) -> dict:
    """The record of what a scene's output is made from (module docstring).

    Parameters
    ----------
    scene : calibrate.pipelines.campaign.CampaignScene
    options : dict
        The campaign's options (:data:`RESULT_OPTIONS` are recorded).

    Returns
    -------
    dict
        ``inputs`` (``[absolute path, bytes, mtime_ns]``, sorted), ``scene``, ``options``,
        ``gcpcal_version``; JSON-ready.
    """
    from calibrate.actions._guard import input_set
    from sensor_models import __version__

    found = input_set([scene.inputs])
    paths = {os.path.abspath(p) for p in found.files.values()}
    for folder in found.folders.values():  # a DOM or DEM folder: the files in it
        paths.update(os.path.abspath(p) for p in Path(folder).iterdir() if p.is_file())
    listing = []
    for path in sorted(paths):
        try:
            st = os.stat(path)
            listing.append([path, int(st.st_size), int(st.st_mtime_ns)])
        except OSError:
            listing.append([path, None, None])
    return {"inputs": listing, "scene": _plain(scene), "options": {k: options[k] for k in RESULT_OPTIONS},
            "gcpcal_version": __version__}


def _scene_files(folder: Path) -> dict[str, Path] | None:
    """The files gcpcal's ledger lists for a scene folder (its own ledger, or the campaign's)."""
    hit = owned_entry(folder / "run.summary.json")
    if hit is None:
        return None
    root = hit[0]
    prefix = "" if root == folder else folder.relative_to(root).as_posix() + "/"
    return {rel[len(prefix):]: root / rel for rel in ledger_entries(root) if rel.startswith(prefix)}


def _input_change(old: list, new: list, provenance: dict) -> str | None:
    """Why the input records differ (None when they do not, or only by times of unchanged content)."""
    from calibrate.actions._ledger import digest

    was = {p: (size, t) for p, size, t in old}
    now = {p: (size, t) for p, size, t in new}
    for path in sorted(set(was) | set(now)):
        if path not in now:
            return f"{path} is no longer an input"
        if path not in was:
            return f"{path} is a new input"
        if was[path] == now[path]:
            continue
        if was[path][0] != now[path][0] or now[path][0] is None:
            return f"{path} changed (size)"
        sha = {os.path.abspath(e.get("path", "")): e.get("sha256") for e in provenance.get("inputs") or []}
        if sha.get(path) is None or digest(path) != sha[path]:
            return f"{path} changed"
    return None


def earlier_output(folder: Path, record_now: dict) -> tuple[dict | None, str | None]:
    """Whether a scene's earlier folder stands (module docstring).

    Parameters
    ----------
    folder : Path
        The scene's folder in the campaign folder.
    record_now : dict
        :func:`made_from` of the scene now.

    Returns
    -------
    (dict or None, str or None)
        ``(summary, None)``: the folder stands, ``summary`` is its ``run.summary.json``;
        ``(None, reason)``: the scene runs again because of ``reason``; ``(None, None)``: there
        is no earlier output.
    """
    summary_file = folder / "run.summary.json"
    if not os.path.lexists(folder):
        return None, None
    if folder.is_symlink() or not folder.is_dir():
        return None, "its folder in OUT is a link or a file, not a folder gcpcal wrote"
    if not any(folder.iterdir()):
        return None, None
    files = _scene_files(folder) if summary_file.is_file() else None
    if files is None:
        return None, "its earlier output is incomplete or not gcpcal's"
    missing = [rel for rel, path in files.items() if not owned(path)]
    if missing:
        return None, f"its earlier {missing[0]} is missing or changed"
    try:
        summary = json.loads(summary_file.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None, "its earlier run.summary.json is unreadable"
    record_then = (summary.get(RECORD_KEY) or {}).get("made_from")
    if not summary.get("success"):
        return None, "it failed before"
    if not isinstance(record_then, dict):
        return None, "its earlier output does not record what it was made from"
    for key in ("gcpcal_version", "scene", "options"):
        if record_then.get(key) != record_now[key]:
            what = {"gcpcal_version": "the gcpcal version", "scene": "its campaign entry", "options": "an option"}[key]
            return None, f"{what} changed{_difference(record_then.get(key), record_now[key])}"
    change = _input_change(record_then.get("inputs") or [], record_now["inputs"], summary.get("provenance") or {})
    if change is not None:
        return None, change
    return summary, None


def _difference(then, now) -> str:
    """`` (name: old -> new)`` for the first differing key of two mappings, else ``""``."""
    if not isinstance(then, dict) or not isinstance(now, dict):
        return f" ({then} -> {now})"
    for key in sorted(set(then) | set(now)):
        if then.get(key) != now.get(key):
            return f" ({key}: {then.get(key)!r} -> {now.get(key)!r})"
    return ""


def clear_scene(folder: Path) -> None:
    """Remove the files gcpcal wrote in a scene's folder (an earlier run the scene replaces); keep a user's.

    Each file is removed before its ledger entry, so a run killed in between leaves a ledger
    naming a missing file, never a file of gcpcal's that looks like a user's.

    Parameters
    ----------
    folder : Path
    """
    if folder.is_symlink() or not folder.is_dir():
        return
    drops: dict[Path, list] = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file() and not path.is_symlink() and path.name != LEDGER_NAME:
            hit = owned_entry(path)
            if hit is not None:
                path.unlink()
                drops.setdefault(hit[0], []).append(hit[1])
    for root, rels in drops.items():
        record(root, {}, unit=_UNIT, command=_COMMAND, drop=rels)
    own = folder / LEDGER_NAME
    if own.is_file() and not ledger_entries(folder):
        own.unlink()
    for sub in sorted((p for p in folder.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        if not any(sub.iterdir()):
            sub.rmdir()


def fold_ledgers(out: Path, folders) -> None:
    """Move the ledgers of scene folders committed one by one into the campaign folder's ledger.

    A scene run with ``--resume`` commits its folder into ``out`` with a ledger of its own; a
    campaign staged whole lists every file in ``out``'s ledger. Folding gives one layout, so that
    either kind of run later replaces (and only replaces) gcpcal's files. Ledgers of other
    commands (a folder written by ``gcpcal run``) are left alone.

    Parameters
    ----------
    out : Path
        The campaign folder.
    folders : iterable of Path
        Scene folders inside ``out``.
    """
    for folder in folders:
        entries = ledger_entries(folder)
        if not entries or any(e.get("command") != _COMMAND for e in entries.values()):
            continue
        prefix = folder.relative_to(out).as_posix()
        keep = {}
        for rel in entries:
            hit = owned_entry(folder / rel)
            if hit is not None and hit[0] == folder:
                keep[f"{prefix}/{rel}"] = folder / rel
        record(out, keep, unit=_UNIT, command=_COMMAND)  # listed twice for a moment: still gcpcal's
        (folder / LEDGER_NAME).unlink()
