"""Atomic file output: write beside the target, then rename, so no partial file is ever left."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

__all__ = ["atomic_write_text", "move_tree_into", "replace_tree", "temporary_beside"]


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
    path = Path(path)
    tmp = temporary_beside(path)
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


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
