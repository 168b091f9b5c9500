"""Moving staged outputs into place: whole when the folder is gcpcal's, merged when it holds a user's files.

Called by :func:`calibrate.actions._io.staged_files` and :func:`calibrate.actions._io.staged_folder`
once a stage has written everything. The moves are renames on one filesystem, done with SIGINT,
SIGTERM and SIGHUP held back (:func:`calibrate.actions._staging.signals_deferred`), and the
ledger (:mod:`calibrate.actions._ledger`) is written before them, so a run killed at any point
leaves every file either gcpcal's (and listed) or the user's (untouched).

A folder output is one *unit* ``.:<command>`` of its folder's ledger. Its earlier files are
replaced or, when the new run did not write them, removed; files of another unit (a file another
command wrote into the folder, e.g. ``gcps.csv`` from ``match``) and files gcpcal did not write
are kept. A new file whose name a user's file holds is refused unless ``--overwrite``.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from calibrate.actions._guard import OutputRefusedError, overwrite_allowed
from calibrate.actions._ledger import LEDGER_NAME, owned, owned_entry, record
from calibrate.actions._staging import ASIDE_TAG, fault_point, make_stage_dir, signals_deferred, write_journal

__all__ = ["commit_files", "commit_folder", "folder_unit"]


def folder_unit(command: str) -> str:
    """The ledger unit of a folder output written by ``command``.

    Parameters
    ----------
    command : str

    Returns
    -------
    str
    """
    return f".:{command}"


def commit_files(pairs, *, command: str) -> None:
    """Move staged files onto their targets; remove a target gcpcal wrote whose new file was not written.

    Parameters
    ----------
    pairs : list of (Path, Path)
        ``(staged file, final file)``; a staged file that does not exist means "no such output
        this time".
    command : str
        Recorded in the ledger.
    """
    by_folder: dict[Path, list] = {}
    for src, final in pairs:
        by_folder.setdefault(final.parent, []).append((src, final))
    stale = [final for src, final in pairs if not src.exists() and final.is_file() and owned(final)]
    moves = [(src, final) for src, final in pairs if src.exists()]
    with signals_deferred():
        for folder, items in by_folder.items():
            written = {final.name: src for src, final in items if src.exists()}
            drop = [final.name for final in stale if final.parent == folder]
            record(folder, written, unit=items[0][1].name, command=command, drop=drop)
        for stage in {src.parent for src, _ in pairs}:  # a run killed while moving is finished by the next
            write_journal(stage, moves, stale)
        for src, final in pairs:
            if src.exists():
                os.replace(src, final)
                fault_point("moving")
        for final in stale:
            final.unlink(missing_ok=True)


def _files_under(folder: Path) -> dict[str, Path]:
    """Relative POSIX name -> path of every file (or link) under ``folder``, the ledger excepted."""
    found = {}
    for path in folder.rglob("*"):
        if path.is_symlink() or path.is_file():
            rel = path.relative_to(folder).as_posix()
            if rel != LEDGER_NAME:
                found[rel] = path
    return found


def _ours(path: Path, out: Path, unit: str) -> bool:
    hit = owned_entry(path)
    return hit is not None and hit[0] == out and hit[2].get("unit") == unit


def commit_folder(stage: Path, out: Path, *, command: str) -> None:
    """Move the staged folder's files into ``out`` (see the module docstring).

    Parameters
    ----------
    stage : Path
        The complete staging folder (beside ``out``).
    out : Path
        The output folder (may exist).
    command : str
        The command: the files are unit ``.:<command>`` of the ledger.

    Raises
    ------
    OutputRefusedError
        A new file would replace a file gcpcal did not write (without ``--overwrite``), or a
        folder where the new output has a file (or the reverse).
    """
    unit = folder_unit(command)
    for nested in stage.rglob(LEDGER_NAME):  # ledgers of the steps that wrote into the stage: this one lists all
        nested.unlink()
    new = _files_under(stage)
    if not os.path.lexists(out):
        record(out, new, unit=unit, command=command, staged_ledger=stage / LEDGER_NAME)
        with signals_deferred():
            os.rename(stage, out)
            fault_point("moving")
        return
    existing = _files_under(out)
    for rel in new:
        there = out / rel
        if there.is_dir() and not there.is_symlink():
            raise OutputRefusedError(f"a folder is where this output writes the file {rel}: move it away", path=str(out))
    collisions = [rel for rel in new if rel in existing and not owned(existing[rel])]
    if collisions and not overwrite_allowed():
        raise OutputRefusedError(f"exists and gcpcal did not write it (or it changed since): give --overwrite to "
                                 f"replace it, or another --out", path=str(out / collisions[0]))
    ours = {rel for rel, path in existing.items() if _ours(path, out, unit)}
    if ours == set(existing):  # nothing but this output's earlier files: swap the folder whole
        record(out, new, unit=unit, command=command, staged_ledger=stage / LEDGER_NAME)
        aside = make_stage_dir(out.parent, out.name, ASIDE_TAG)
        with signals_deferred():
            os.replace(out, aside)  # a folder may replace an empty folder (POSIX rename)
            fault_point("moving")
            try:
                os.rename(stage, out)
            except BaseException:
                os.replace(aside, out)
                raise
        shutil.rmtree(aside, ignore_errors=True)
        return
    stale = sorted(ours - set(new))
    with signals_deferred():
        record(out, new, unit=unit, command=command, drop=stale)
        write_journal(stage, [(src, out / rel) for rel, src in new.items()], [out / rel for rel in stale])
        for rel, src in new.items():
            dst = out / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)
            fault_point("moving")
        for rel in stale:
            (out / rel).unlink(missing_ok=True)
            _remove_empty_parents(out / rel, out)
    shutil.rmtree(stage, ignore_errors=True)


def _remove_empty_parents(path: Path, top: Path) -> None:
    here = path.parent
    while here != top and top in here.parents:
        try:
            here.rmdir()
        except OSError:
            return
        here = here.parent
