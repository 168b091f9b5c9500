"""The output-path guard: no output of gcpcal lands on an input, a device, or a file of the user's.

Every stage action checks each of its outputs (file, folder, sidecar, summary) here before any
work, through :mod:`calibrate.actions._io`, and the same checks run again just before the
staged outputs are moved into place. An output is refused (:class:`OutputRefusedError`, an
input error: exit 1, one line naming the output and the input) when

* it is one of the command's inputs: the same file by its real path, through a symbolic or a
  hard link, or under another case of its name on a case-insensitive filesystem (the identity
  test is the file's ``(st_dev, st_ino)``, which all of these share);
* it lies inside a folder the command reads as an input (a DOM product folder, DEM tiles, the
  calibration folder, the demo fixture);
* it is a folder that holds an input (a rerun would write where the input is);
* it exists and is not a regular file (a folder output: not a folder): a character or block
  device, a FIFO, a socket. ``-`` is standard output for the commands that can write there
  (:func:`is_stdout`) and refused by the others;
* it is a symbolic link and ``--overwrite`` was not given (with it, the link is written through:
  its target gets the new content and the link stays);
* it is a file that gcpcal did not write (:mod:`calibrate.actions._ledger`) and ``--overwrite``
  was not given.

The inputs of a command are the paths it was given plus what they name: the files a JSON or
YAML manifest lists (rasters, DOM, DEM; followed up to three levels, e.g. sites file -> scene
manifest -> raster), the sources of a ``.vrt``, and the sidecars a raster reader picks up beside a
raster (``.aux.xml``, ``_RPC.TXT``, ``.RPB``, world files).
"""

from __future__ import annotations

import contextvars
import glob
import json
import os
import re
import stat
from contextlib import contextmanager
from pathlib import Path

from sensor_models.files.gdal_paths import is_gdal_virtual
from sensor_models.errors import InputError

__all__ = ["InputSet", "OutputRefusedError", "allow_overwrite", "check_file_target", "check_folder_target",
           "current_command", "input_set", "is_stdout", "overwrite_allowed", "running_command"]

_OVERWRITE = contextvars.ContextVar("gcpcal_overwrite", default=False)
_COMMAND = contextvars.ContextVar("gcpcal_command", default=None)

#: Files a raster reader may read beside a raster ``X.tif``: ``X.tif<suffix>`` and ``X<suffix>``.
_RASTER_SIDECARS = (".aux.xml", ".ovr", ".msk")
_STEM_SIDECARS = ("_RPC.TXT", "_rpc.txt", ".RPB", ".rpb", ".tfw", ".tifw", ".wld", ".hdr", ".IMD", ".imd")
_RASTER_SUFFIXES = (".tif", ".tiff", ".jp2", ".img", ".hgt", ".vrt", ".ntf", ".dt2", ".bil")
#: Text manifests followed for the paths they name (and how deep).
_MANIFEST_SUFFIXES = (".json", ".yaml", ".yml")
_MANIFEST_DEPTH = 3
_MANIFEST_MAX_BYTES = 64 * 2**20


class OutputRefusedError(InputError):
    """An output path that would overwrite an input, a device or a file gcpcal did not write."""


def overwrite_allowed() -> bool:
    """Whether ``--overwrite`` is in effect (:func:`allow_overwrite`).

    Returns
    -------
    bool
    """
    return bool(_OVERWRITE.get())


@contextmanager
def allow_overwrite(flag: bool = True):
    """Within the block, outputs may replace files gcpcal did not write and write through links.

    The CLI enters it for ``--overwrite``; library callers may too. Inputs, devices and folders
    that hold inputs are refused whatever the flag says.

    Parameters
    ----------
    flag : bool
        True to allow.
    """
    token = _OVERWRITE.set(bool(flag))
    try:
        yield
    finally:
        _OVERWRITE.reset(token)


@contextmanager
def running_command(name: str):
    """Within the block, outputs are recorded as written by command ``name`` (e.g. ``"match"``).

    Parameters
    ----------
    name : str
    """
    token = _COMMAND.set(str(name))
    try:
        yield
    finally:
        _COMMAND.reset(token)


def current_command(prefix: str | None = None) -> str:
    """The command recorded for the outputs being written.

    Parameters
    ----------
    prefix : str, optional
        A staging prefix such as ``".calibrate-"``, used when no command is running.

    Returns
    -------
    str
    """
    name = _COMMAND.get()
    if name:
        return name
    stem = (prefix or "").strip(".-")
    return stem if stem and stem != "stage" else "gcpcal"


def is_stdout(path) -> bool:
    """Whether an output path means standard output (``-``).

    Parameters
    ----------
    path : str or Path or None

    Returns
    -------
    bool
    """
    return path is not None and str(path) == "-"


def _identity(st) -> tuple[int, int]:
    return (st.st_dev, st.st_ino)


def _stat(path):
    try:
        return os.stat(path)
    except (OSError, ValueError):
        return None


class InputSet:
    """The files and folders a command reads, by identity (``st_dev``, ``st_ino``).

    Parameters
    ----------
    items : iterable
        Paths, sequences of paths, comma lists, globs, or values with a ``paths`` attribute (a DOM
        source); None entries are skipped. Manifests are followed for the paths they name.
    """

    def __init__(self, items=()):
        self.files: dict[tuple[int, int], Path] = {}
        self.folders: dict[tuple[int, int], Path] = {}
        self.virtual: set[str] = set()  # GDAL virtual paths (/vsizip/...): read, never written
        for path in _expand(items, self.virtual):
            self._add(path, 0)

    def _add(self, path: Path, depth: int) -> None:
        st = _stat(path)
        if st is None:
            return
        key = _identity(st)
        if stat.S_ISDIR(st.st_mode):
            self.folders.setdefault(key, path)
            return
        if key in self.files:
            return
        self.files[key] = path
        for extra in _sidecars(path):
            self._add(extra, depth)
        if depth < _MANIFEST_DEPTH:
            for named in _named_paths(path, st):
                self._add(named, depth + 1)

    def add(self, *items) -> "InputSet":
        """Add more inputs (as the constructor takes them); returns self."""
        for path in _expand(items, self.virtual):
            self._add(path, 0)
        return self

    def same_file(self, path) -> Path | None:
        """The input that IS ``path`` (following links; any case on a case-insensitive filesystem)."""
        st = _stat(path)
        if st is None:
            return None
        key = _identity(st)
        return self.files.get(key) or self.folders.get(key)

    def folder_holding(self, path) -> Path | None:
        """The input folder that ``path`` (existing or not) would lie in."""
        if not self.folders:
            return None
        here = Path(os.path.abspath(path)).parent
        while True:
            st = _stat(here)
            if st is not None and _identity(st) in self.folders:
                return self.folders[_identity(st)]
            if here.parent == here:
                return None
            here = here.parent

    def held_by(self, folder) -> Path | None:
        """An input that lies inside ``folder`` (an existing folder), or None."""
        st = _stat(folder)
        if st is None or not stat.S_ISDIR(st.st_mode):
            return None
        target = _identity(st)
        for path in list(self.files.values()) + list(self.folders.values()):
            here = Path(os.path.realpath(path))
            for parent in [here, *here.parents]:
                pst = _stat(parent)
                if pst is not None and _identity(pst) == target:
                    return path
        return None


def input_set(inputs) -> InputSet:
    """An :class:`InputSet` of ``inputs`` (an InputSet is returned as is).

    Parameters
    ----------
    inputs : InputSet or iterable
        As :class:`InputSet` takes them.

    Returns
    -------
    InputSet
    """
    return inputs if isinstance(inputs, InputSet) else InputSet(inputs)


def _expand(items, virtual: set | None = None):
    """Paths of ``items``: flattened; comma lists and globs that name no file split or expanded;
    GDAL virtual paths (``/vsizip/...``) go into ``virtual`` instead (no local file to guard)."""
    for item in items:
        if item is None:
            continue
        if hasattr(item, "paths"):
            yield from _expand(item.paths, virtual)
        elif isinstance(item, (list, tuple, set, frozenset)):
            yield from _expand(item, virtual)
        else:
            text = os.fspath(item) if isinstance(item, os.PathLike) else str(item)
            if not text or text == "-":
                continue
            if is_gdal_virtual(text):
                if virtual is not None:
                    virtual.add(text)
                continue
            if os.path.lexists(text):
                yield Path(text)
            elif "," in text:
                yield from _expand([part.strip() for part in text.split(",") if part.strip()], virtual)
            elif glob.has_magic(text):
                yield from (Path(p) for p in glob.glob(text))
            else:
                yield Path(text)


def _sidecars(path: Path):
    if path.suffix.lower() not in _RASTER_SUFFIXES:
        return
    for suffix in _RASTER_SIDECARS:
        yield path.with_name(path.name + suffix)
    for suffix in _STEM_SIDECARS:
        yield path.with_name(path.stem + suffix)


_VRT_SOURCE = re.compile(r"<SourceFilename([^>]*)>([^<]+)</SourceFilename>")


def _named_paths(path: Path, st):
    """Existing paths named inside a manifest (JSON/YAML) or a VRT, relative to its folder or absolute."""
    suffix = path.suffix.lower()
    if st.st_size > _MANIFEST_MAX_BYTES or suffix not in _MANIFEST_SUFFIXES + (".vrt",):
        return []
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError, ValueError):
        return []  # the reader names the problem; the guard only looks for paths
    if suffix == ".vrt":
        strings = [name for _, name in _VRT_SOURCE.findall(text)]
    else:
        strings = list(_strings(_parse(text, suffix)))
    found = []
    for s in strings:
        if not s or len(s) > 4096 or "\n" in s or s.startswith(("http:", "https:", "/vsicurl")):
            continue
        candidate = Path(s) if os.path.isabs(s) else path.parent / s
        if candidate != path and os.path.isfile(candidate):  # files only: a folder named in passing is no input
            found.append(candidate)
    return found


def _parse(text: str, suffix: str):
    try:
        if suffix == ".json":
            return json.loads(text)
        import yaml

        return yaml.safe_load(text)
    except Exception:  # a malformed manifest: its reader says so, with the file named
        return None


def _strings(doc, depth: int = 0):
    if depth > 64:
        return
    if isinstance(doc, str):
        yield doc
    elif isinstance(doc, dict):
        for value in doc.values():
            yield from _strings(value, depth + 1)
    elif isinstance(doc, list):
        for value in doc:
            yield from _strings(value, depth + 1)


# ------------------------------------------------------------------------------------------ targets
def _refuse(path, message: str):
    raise OutputRefusedError(message, path=str(path))


def _kind(mode: int) -> str:
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISDIR(mode):
        return "a folder"
    return "not a regular file"


def _check_against_inputs(path: Path, inputs: InputSet) -> None:
    same = inputs.same_file(path)
    if same is not None:
        _refuse(path, f"this output would overwrite the input {same}: choose another output name")
    holder = inputs.folder_holding(path)
    if holder is not None:
        _refuse(path, f"this output lies inside the input folder {holder}: write it elsewhere")


def _resolve_link(path: Path, what: str) -> Path:
    """``path``, or the target of the link ``path`` (written through with ``--overwrite`` only)."""
    if not path.is_symlink():
        return path
    target = Path(os.path.realpath(path))
    if not overwrite_allowed():
        _refuse(path, f"is a symbolic link (to {target}); give --overwrite to write {what} through it, or another "
                      "name")
    return target


def check_file_target(path, inputs=(), *, stdout_ok: bool = False) -> Path:
    """Check one output FILE; return the path to write (a link's target with ``--overwrite``).

    Parameters
    ----------
    path : str or Path
        The output file (``-`` for standard output where ``stdout_ok``).
    inputs : InputSet or iterable
        The command's inputs.
    stdout_ok : bool
        Whether this output may be standard output.

    Returns
    -------
    Path
        The absolute path to write (``Path("-")`` for standard output).

    Raises
    ------
    OutputRefusedError
        See the module docstring.
    """
    from calibrate.actions._ledger import owned

    if is_stdout(path):
        if stdout_ok:
            return Path("-")
        _refuse("-", "this output cannot go to standard output: give a file name")
    inputs = input_set(inputs)
    given = Path(os.path.abspath(path))
    _check_against_inputs(given, inputs)
    followed = _stat(given)  # through links: /dev/stdout is a link to a pipe, a terminal or a file
    if followed is not None and not (stat.S_ISREG(followed.st_mode) or stat.S_ISDIR(followed.st_mode)):
        _refuse(given, f"is {_kind(followed.st_mode)}, not a file gcpcal may replace: give a file name"
                       + (" (or - for standard output)" if stdout_ok else ""))
    final = _resolve_link(given, "the file")
    _check_against_inputs(final, inputs)
    try:
        st = os.lstat(final)
    except OSError:
        return final
    if stat.S_ISDIR(st.st_mode):
        _refuse(given, "is a folder; give a file name")
    if not stat.S_ISREG(st.st_mode):
        _refuse(given, f"is {_kind(st.st_mode)}, not a file gcpcal may replace: give a file name"
                       + (" (or - for standard output)" if stdout_ok else ""))
    if not overwrite_allowed() and not owned(final):
        _refuse(given, "exists and gcpcal did not write it (or it changed since): give --overwrite to replace it, or "
                       "another name")
    return final


def check_folder_target(path, inputs=()) -> Path:
    """Check one output FOLDER; return the folder to write (a link's target with ``--overwrite``).

    An existing folder is merged into, never wiped: the files gcpcal wrote there earlier may be
    replaced, the others are kept (a new file of the same name as one of them is refused at the
    end unless ``--overwrite``, :mod:`calibrate.actions._io`).

    Parameters
    ----------
    path : str or Path
        The output folder.
    inputs : InputSet or iterable
        The command's inputs.

    Returns
    -------
    Path
        The absolute folder.

    Raises
    ------
    OutputRefusedError
        See the module docstring; also a folder that holds one of the inputs.
    """
    if is_stdout(path):
        _refuse("-", "this output is a folder: give a folder name, not -")
    inputs = input_set(inputs)
    given = Path(os.path.abspath(path))
    _check_against_inputs(given, inputs)
    final = _resolve_link(given, "the folder")
    _check_against_inputs(final, inputs)
    try:
        st = os.lstat(final)
    except OSError:
        return final
    if not stat.S_ISDIR(st.st_mode):
        if stat.S_ISREG(st.st_mode):
            _refuse(given, "exists and is not a folder")
        _refuse(given, f"is {_kind(st.st_mode)}, not a folder")
    held = inputs.held_by(final)
    if held is not None:
        _refuse(given, f"this output folder holds the input {held}: choose another --out")
    return final
