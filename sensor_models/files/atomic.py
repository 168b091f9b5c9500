"""Transactional file output, the one helper every writer uses: write beside the target, then rename.

No partial file is ever left: a file is written to a hidden temporary file in its own folder
and renamed onto its name (:func:`atomic_file`, :func:`atomic_write_text`); a folder of outputs
is written into a hidden staging folder beside it and moved in when complete, whole
(:func:`atomic_folder` with ``mode="replace"``, :func:`replace_tree`) or file by file
(``mode="merge"``, :func:`move_tree_into`). On any exception or interrupt the temporary file or
folder is removed and the targets are untouched. The stage actions of ``gcpcal`` add their
checks (inputs never written, files of the user's kept) and the ledger of what gcpcal wrote on
top of these primitives (:mod:`calibrate.actions._staging`, :mod:`calibrate.actions._commit`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_file", "atomic_folder", "atomic_write_text", "move_tree_into", "replace_tree",
           "temporary_beside"]


def temporary_beside(path, suffix: str = ".tmp") -> Path:
    """An empty temporary file in ``path``'s folder (created if needed); rename it onto ``path``.

    Same filesystem as the target, so :func:`os.replace` is atomic. Mode 0644.

    Parameters
    ----------
    path : str or os.PathLike
        The final file; its folder is created when missing.
    suffix : str
        Ending of the temporary name (it starts with ``.<name>.``, a hidden file).

    Returns
    -------
    Path
        The empty temporary file; the caller renames it onto ``path`` or deletes it.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o644)
    return Path(tmp)


@contextmanager
def atomic_file(path, suffix: str = ".tmp"):
    """A temporary file beside ``path`` to write, renamed onto ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or os.PathLike
        The final file (its folder is created when missing; an existing file is replaced).
    suffix : str
        Ending of the temporary name (keep the target's extension when a writer such as GDAL
        picks its format from it).

    Yields
    ------
    Path
        The temporary file (empty, mode 0644): write it completely inside the block.
    """
    path = Path(path)
    tmp = temporary_beside(path, suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


@contextmanager
def atomic_folder(out_dir, *, mode: str = "replace", inside: bool = False):
    """A hidden staging folder whose files become ``out_dir``'s when the block succeeds.

    Parameters
    ----------
    out_dir : str or os.PathLike
        The output folder (created when missing).
    mode : {"replace", "merge"}
        ``"replace"``: the staging folder replaces ``out_dir`` whole (:func:`replace_tree`; no
        file of an earlier run survives). ``"merge"``: its files move into ``out_dir`` one by
        one (:func:`move_tree_into`), other files of ``out_dir`` are kept.
    inside : bool
        Stage inside ``out_dir`` instead of beside it (``"merge"`` only: for an output folder
        that holds other files, e.g. a report written into a calibration folder).

    Yields
    ------
    Path
        The staging folder: write every output there under its final relative name.
    """
    if mode not in ("replace", "merge"):
        raise ValueError(f"mode must be 'replace' or 'merge', got {mode!r}")
    if inside and mode != "merge":
        raise ValueError("a staging folder inside the output folder can only be merged")
    out_dir = Path(out_dir)
    parent = out_dir if inside else out_dir.parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.stage-", dir=parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700; an output folder gets the usual mode
    try:
        yield tmp
        if mode == "replace":
            replace_tree(tmp, out_dir)
        else:
            out_dir.mkdir(parents=True, exist_ok=True)
            move_tree_into(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file and a rename.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced if present; its folder is created).
    text : str
        The content, written as is (no newline translation).

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_file(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
    return Path(path)


def move_tree_into(tmp, out_dir) -> None:
    """Move every file under folder ``tmp`` to the same relative path under ``out_dir``.

    Each move is an atomic rename (``tmp`` lies inside ``out_dir``, on the same filesystem), done
    only once everything has been written, so a failed stage never leaves partial files.

    Parameters
    ----------
    tmp : str or os.PathLike
        The staging folder (inside ``out_dir``); it is left empty of files, not removed.
    out_dir : str or os.PathLike
        The destination folder; existing files of the same names are replaced.
    """
    tmp, out_dir = Path(tmp), Path(out_dir)
    for src in sorted(tmp.rglob("*")):
        if src.is_file():
            dst = out_dir / src.relative_to(tmp)
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)


def replace_tree(staged, target) -> None:
    """Swap folder ``staged`` in as ``target``, replacing an existing ``target`` whole.

    ``staged`` must lie beside ``target`` (same parent, same filesystem). An existing ``target``
    is renamed aside, ``staged`` is renamed in, and the old folder is removed, so no file of an
    earlier run survives. If the second rename fails the old folder is put back.

    Parameters
    ----------
    staged : str or os.PathLike
        The complete new folder.
    target : str or os.PathLike
        The final folder (may or may not exist).
    """
    staged, target = Path(staged), Path(target)
    if not target.exists():
        os.rename(staged, target)
        return
    aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
    os.replace(target, aside)  # a folder may replace an empty folder (POSIX rename)
    try:
        os.rename(staged, target)
    except BaseException:
        os.replace(aside, target)
        raise
    shutil.rmtree(aside, ignore_errors=True)
