"""Helpers shared by the stage actions: JSON summaries, DEMs, and transactional outputs.

Transactional outputs
---------------------
Every action checks its output paths before it computes (:func:`check_output_folder`,
:func:`check_output_files`), writes everything into a staging folder BESIDE the target (same
filesystem), and swaps it in only when the whole stage succeeded (:func:`staged_folder`,
:func:`staged_files`). A folder output replaces an existing folder whole (no stale file of an
earlier run survives), but only a folder that gcpcal wrote (it holds :data:`OUTPUT_MARKER` or a
``*summary.json``) or an empty one. On any failure or interrupt the staging folder and any
parent folder the stage created are removed: nothing new and nothing stale is left.
Because the staging folder is a sibling of the target, relative paths from it to files outside
equal those from the final folder.
"""

from __future__ import annotations

import errno
import functools
import inspect
import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from calibrate._json import json_default
from sensor_models.atomic import atomic_write_text, replace_tree
from sensor_models.errors import InputError

__all__ = ["OUTPUT_MARKER", "check_output_files", "check_output_folder", "final_paths", "open_dem", "staged_files",
           "staged_folder", "staged_output", "write_summary"]

#: File written into every output folder: gcpcal may replace such a folder whole on a rerun.
OUTPUT_MARKER = ".gcpcal-output"

# errors of a write that the machine causes (full disk, read-only filesystem, quota, permission)
_WRITE_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EPERM}


def write_summary(path, summary: dict) -> Path:
    """Write a stage's JSON summary atomically.

    Parameters
    ----------
    path : str or Path
        Destination file.
    summary : dict
        JSON-ready mapping (numpy scalars, arrays and paths are converted).

    Returns
    -------
    Path
        ``path``.
    """
    atomic_write_text(Path(path), json.dumps(summary, indent=2, default=json_default) + "\n")
    return Path(path)


#: Heights (m above the ellipsoid) at which a scene's footprint is localized to bound a DEM read.
_FOOTPRINT_HEIGHTS_M = (-500.0, 9000.0)
#: Margin around that footprint, as a share of its larger side (at least 0.1 degree): room for an
#: uncalibrated model that is off by hundreds of pixels.
_FOOTPRINT_MARGIN = 0.5


def open_dem(dem_path, datum=None, geoid=None, *, model=None, band=None):
    """Open a DEM, its vertical datum declared when the file does not say.

    Parameters
    ----------
    dem_path : str, Path or sequence of them
        DEM raster (any CRS rasterio reads), or tiles: a list, a comma list, a folder, a glob
        or a ``.vrt`` (mosaicked through a GDAL VRT, :mod:`sensor_models.mosaic`).
    datum : {"ellipsoid", "egm96"} or None
        Vertical datum of the heights when the file does not declare it.
    geoid : str or Path or None
        Geoid grid for EGM96 heights (default: the EGM96 grid in PROJ's data directories,
        :func:`sensor_models.terrain.find_egm96_grid`).
    model : SensorModel, optional
        The scene's model. With several tiles (or a ``.vrt``), only the part of the mosaic
        under the scene's footprint (localized from -500 to 9000 m, plus half its size, at
        least 0.1 degree, on each side) is read. A single file is read whole, as before. The
        heights over the footprint are checked
        (:func:`calibrate.plausibility.check_dem_heights`).
    band : str, optional
        Band of ``model`` whose footprint counts (default: its reference band).

    Returns
    -------
    sensor_models.terrain.Dem
    """
    from sensor_models.mosaic import raster_inputs
    from sensor_models.terrain import Dem

    bounds, margin = None, 0.0
    if model is not None:
        files = raster_inputs(dem_path, what="DEM")
        if len(files) > 1 or files[0].lower().endswith(".vrt"):
            bounds, margin = _footprint_box(model, band)
    dem = Dem.open(dem_path, vertical_datum=datum, geoid=geoid, bounds=bounds, margin_deg=margin)
    if model is not None:  # before any work: heights a terrain cannot have (a DEM in centimetres)
        from calibrate.plausibility import check_dem_heights

        check_dem_heights(dem, model, band=band)
    return dem


def _footprint_box(model, band):
    """``(lon_min, lat_min, lon_max, lat_max), margin_deg`` around a model's footprint, or ``(None, 0)``."""
    import numpy as np

    from sensor_models.terrain import footprint_sample_lonlat

    lon, lat = zip(*(footprint_sample_lonlat(model, h, n_side=9, band=band) for h in _FOOTPRINT_HEIGHTS_M))
    lon, lat = np.concatenate(lon), np.concatenate(lat)
    if lon.size == 0 or np.ptp(lon) > 180.0:  # off the Earth, or across the antimeridian: read it all
        return None, 0.0
    margin = max(0.1, _FOOTPRINT_MARGIN * max(np.ptp(lon), np.ptp(lat)))
    return (float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())), margin


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _check_writable_folder(folder: Path, what: Path) -> None:
    """Raise InputError unless files can be created in ``folder`` (or in the folders made for it)."""
    base = _nearest_existing(folder)
    if not base.is_dir():
        raise InputError(f"cannot create a folder under {base}: it is a file, not a folder", path=str(what))
    reason = None if os.access(base, os.W_OK | os.X_OK) else "permission denied"
    if reason is None:
        try:  # a real probe: os.access says yes to root on a read-only mount
            fd, probe = tempfile.mkstemp(prefix=".gcpcal-probe-", dir=base)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            reason = (exc.strerror or str(exc)).lower()
    if reason is not None:
        raise InputError(f"cannot write into {base}: {reason}", path=str(what))


def _written_by_gcpcal(folder: Path) -> bool:
    if (folder / OUTPUT_MARKER).is_file():
        return True
    return any(p.name.endswith("summary.json") for p in folder.iterdir())


def _input_paths(inputs):
    """The paths of ``inputs``: a path, a sequence of paths, or a value with ``paths`` (a DOM source)."""
    for item in inputs:
        if item is None:
            continue
        if hasattr(item, "paths"):
            yield from _input_paths(item.paths)
        elif isinstance(item, (list, tuple)):
            yield from _input_paths(item)
        else:
            yield item


def _refuse_inputs_inside(out_dir: Path, inputs) -> None:
    for item in _input_paths(inputs):
        resolved = Path(item).resolve()
        if resolved == out_dir or out_dir in resolved.parents:
            raise InputError(f"the output folder would replace the input {item}: choose another --out",
                             path=str(out_dir))


def check_output_folder(out_dir, *, inputs=()) -> Path:
    """Check, before any computation, that a stage may write (or replace) folder ``out_dir``.

    Parameters
    ----------
    out_dir : str or Path
        The stage's output folder.
    inputs : iterable of str or Path, optional
        The stage's input files: none may lie inside an existing ``out_dir`` (it is replaced).

    Returns
    -------
    Path
        ``out_dir``, absolute.

    Raises
    ------
    InputError
        ``out_dir`` is a file, lies under a file, cannot be created or written, is a non-empty
        folder gcpcal did not write, or holds one of ``inputs``.
    """
    out_dir = Path(out_dir).absolute()
    if out_dir.exists():
        if not out_dir.is_dir():
            raise InputError("exists and is not a folder", path=str(out_dir))
        if not _written_by_gcpcal(out_dir) and any(out_dir.iterdir()):
            raise InputError("refusing to replace a non-empty folder gcpcal did not write (choose another --out, "
                             "or empty it)", path=str(out_dir))
        _refuse_inputs_inside(out_dir.resolve(), inputs)
    _check_writable_folder(out_dir.parent, out_dir)
    return out_dir


def check_output_files(*paths) -> list[Path]:
    """Check, before any computation, that a stage may write (or replace) the files ``paths``.

    Parameters
    ----------
    *paths : str or Path or None
        Output files (None entries, options not given, are skipped).

    Returns
    -------
    list of Path
        The given paths, absolute, in order.

    Raises
    ------
    InputError
        Two outputs share a name, a path is a folder, lies under a file, or its folder cannot be
        created or written.
    """
    finals = [Path(p).absolute() for p in paths if p is not None]
    if len(set(finals)) != len(finals):
        raise InputError("two outputs of this command have the same name", path=str(finals[0]))
    for path in finals:
        if path.is_dir():
            raise InputError("is a folder; give a file name", path=str(path))
        _check_writable_folder(path.parent, path)
    return finals


def _make_folders(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; return those created, outermost first."""
    missing = []
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    missing.reverse()
    for made in missing:
        made.mkdir()
    return missing


def _remove_folders(made: list[Path]) -> None:
    for folder in reversed(made):
        try:
            folder.rmdir()
        except OSError:
            pass


def _name_write_error(exc: BaseException, target: Path) -> BaseException:
    """An OSError that names ``target`` for a nameless write failure (full disk, read-only)."""
    if not isinstance(exc, OSError) or exc.filename is not None:
        return exc
    text = " ".join(str(exc).split())
    if exc.errno in _WRITE_ERRNOS:
        return OSError(exc.errno, exc.strerror or text, str(target))
    if "write failed" in text.lower():
        return OSError(errno.EIO, text, str(target))
    return exc


def final_paths(value, stage, out_dir):
    """``value`` with every path (or string) under the staging folder moved under ``out_dir``.

    Parameters
    ----------
    value : dict, list, tuple, str, Path or any
        A summary returned by a writer that wrote into ``stage`` (walked recursively).
    stage : str or Path
        The staging folder of :func:`staged_folder`.
    out_dir : str or Path
        The final folder.

    Returns
    -------
    same type as ``value``
        A copy naming the final folder (other values unchanged).
    """
    stage, final = str(Path(stage)), str(Path(out_dir).absolute())
    if isinstance(value, dict):
        return {k: final_paths(v, stage, final) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(final_paths(v, stage, final) for v in value)
    if isinstance(value, Path) and str(value).startswith(stage):
        return Path(final + str(value)[len(stage):])
    if isinstance(value, str) and value.startswith(stage):
        return final + value[len(stage):]
    return value


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _name_final_folder(tmp: Path, out_dir: Path) -> None:
    """Make the JSON files of ``tmp`` that name the staging folder name ``out_dir`` instead."""
    for path in tmp.rglob("*.json"):
        text = path.read_text(encoding="utf-8")
        if str(tmp) in text:
            atomic_write_text(path, text.replace(str(tmp), str(out_dir)))


@contextmanager
def staged_folder(out_dir, prefix: str = ".stage-", *, inputs=()):
    """A staging folder beside ``out_dir`` that replaces ``out_dir`` whole on success.

    The output path is checked first (:func:`check_output_folder`), so enter this before the
    computation. On success a :data:`OUTPUT_MARKER` file is added (unless a ``*summary.json``
    marks the folder already) and the staging folder is
    renamed to ``out_dir`` (an existing ``out_dir`` is renamed aside and removed). On any
    exception or interrupt the staging folder, and any parent folder created for it, are removed.

    Parameters
    ----------
    out_dir : str or Path
        The stage's output folder.
    prefix : str
        Middle part of the staging folder's hidden name (``.<out name><prefix>XXXX``).
    inputs : iterable of str or Path, optional
        The stage's inputs: refused when inside an existing ``out_dir``.

    Yields
    ------
    Path
        The staging folder: write every output there, under its final relative name.
    """
    out_dir = check_output_folder(out_dir, inputs=inputs)
    made = _make_folders(out_dir.parent)
    tmp = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}{prefix}", dir=out_dir.parent))
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; the output folder gets the usual mode
        yield tmp
        _name_final_folder(tmp, out_dir)
        if not _written_by_gcpcal(tmp):  # a summary already says it; else the marker does
            (tmp / OUTPUT_MARKER).write_text("written by gcpcal; a rerun may replace this folder whole\n",
                                             encoding="utf-8")
        replace_tree(tmp, out_dir)
    except BaseException as exc:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        _remove_folders(made)
        named = _name_write_error(exc, out_dir)
        if named is exc:
            raise
        raise named from exc


@contextmanager
def staged_files(*paths):
    """Staging paths for a command's output files, all moved onto their targets together.

    The paths are checked first (:func:`check_output_files`), so enter this before the
    computation. Each staged file lies in a hidden folder beside its target, under the target's
    own name (GDAL drivers see the right extension). On success every staged file replaces its
    target; a target whose staged file was not written is removed (it would be stale). On any
    exception or interrupt nothing is moved and every staging and created folder is removed.

    Parameters
    ----------
    *paths : str or Path or None
        The output files (None entries are skipped and yield None).

    Yields
    ------
    list of Path or None
        One staging path per entry of ``paths``, in order.
    """
    finals = check_output_files(*paths)
    made, stages, staged = [], {}, []
    try:
        for final in finals:
            made += _make_folders(final.parent)
            if final.parent not in stages:
                stages[final.parent] = Path(tempfile.mkdtemp(prefix=f".{final.name}.stage-", dir=final.parent))
            staged.append(stages[final.parent] / final.name)
        it = iter(staged)
        yield [None if p is None else next(it) for p in paths]
        for src, final in zip(staged, finals):
            if src.exists():
                os.replace(src, final)
            elif final.is_file():
                final.unlink()
    except BaseException as exc:
        for stage in stages.values():
            shutil.rmtree(stage, ignore_errors=True)
        _remove_folders(made)
        named = _name_write_error(exc, finals[0] if finals else Path("."))
        if named is exc:
            raise
        raise named from exc
    finally:
        for stage in stages.values():
            shutil.rmtree(stage, ignore_errors=True)


def staged_output(parameter: str = "out_dir", *, inputs=(), prefix: str = ".stage-"):
    """Decorator: the action writes its output folder through :func:`staged_folder`.

    The wrapped action receives the staging folder in place of its ``parameter`` argument; the
    folder's path is checked before the action runs, and it replaces the final folder whole when
    the action returns. Paths under the staging folder in the returned value name the final one.

    Parameters
    ----------
    parameter : str
        Name of the action's output-folder argument.
    inputs : tuple of str
        Names of the action's input-path arguments (refused when inside the output folder).
    prefix : str
        Middle part of the staging folder's name.

    Returns
    -------
    callable
        The decorator.
    """
    def wrap(func):
        signature = inspect.signature(func)

        @functools.wraps(func)
        def staged(*args, **kwargs):
            bound = signature.bind(*args, **kwargs)
            out_dir = bound.arguments[parameter]
            given = [bound.arguments.get(name) for name in inputs]
            with staged_folder(out_dir, prefix, inputs=given) as stage:
                bound.arguments[parameter] = stage
                result = func(*bound.args, **bound.kwargs)
            return final_paths(result, stage, out_dir)

        return staged

    return wrap
