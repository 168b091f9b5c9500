"""Helpers shared by the stage actions: JSON summaries, DEMs, and transactional outputs.

Transactional outputs
---------------------
Every action checks its output paths before it computes (:func:`check_output_folder`,
:func:`check_output_files`, through the output guard :mod:`calibrate.actions._guard`: no output
is an input, lies in an input folder, holds an input, is a device, or replaces a file gcpcal did
not write without ``--overwrite``), writes everything into a staging folder BESIDE the target
(same filesystem, named so that a later run can tell a dead run's staging,
:mod:`calibrate.actions._staging`), and moves it in only when the whole stage succeeded
(:func:`staged_folder`, :func:`staged_files`, :mod:`calibrate.actions._commit`). What gcpcal
wrote is recorded in each folder (:mod:`calibrate.actions._ledger`): a rerun replaces or removes
those files and only those; a user's files in an output folder are kept. On any failure or
interrupt the staging folder and any parent folder the stage created are removed: nothing new
and nothing stale is left. Because the staging folder is a sibling of the target, relative paths
from it to files outside equal those from the final folder.
"""

from __future__ import annotations

import errno
import functools
import inspect
import json
import os
import shutil
from contextlib import contextmanager
from pathlib import Path

from calibrate._json import json_default
from calibrate.actions._guard import (check_file_target, check_folder_target, current_command, input_set,
                                      is_stdout)
from calibrate.actions._ledger import LEDGER_NAME
from calibrate.actions._provenance import note_terrain, stage_inputs, with_provenance
from calibrate.actions._staging import clean_stale, fault_point, make_stage_dir, make_temp_file
from sensor_models.files.atomic import atomic_write_text
from sensor_models.errors import InputError

__all__ = ["OUTPUT_MARKER", "check_output_files", "check_output_folder", "final_paths", "open_dem", "staged_files",
           "staged_folder", "staged_output", "write_summary"]

#: File written into every output folder: the record of the files gcpcal wrote there.
OUTPUT_MARKER = LEDGER_NAME

# errors of a write that the machine causes (full disk, read-only filesystem, quota, permission)
_WRITE_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EPERM}


def write_summary(path, summary: dict) -> Path:
    """Write a stage's JSON summary atomically, with its ``provenance`` block
    (:func:`calibrate.actions._provenance.provenance_record`) unless it holds one.

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
    summary = with_provenance(summary)
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
        or a ``.vrt`` (mosaicked through a GDAL VRT, :mod:`sensor_models.maps.mosaic`).
    datum : {"ellipsoid", "egm96"} or None
        Vertical datum of the heights when the file does not declare it.
    geoid : str or Path or None
        Geoid grid for EGM96 heights (default: the EGM96 grid in PROJ's data directories,
        :func:`sensor_models.terrain.geoid.find_egm96_grid`).
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
    sensor_models.terrain.dem.Dem
    """
    from sensor_models.maps.mosaic import raster_inputs
    from sensor_models.terrain.dem import Dem

    bounds, margin = None, 0.0
    if model is not None:
        files = raster_inputs(dem_path, what="DEM")
        if len(files) > 1 or files[0].lower().endswith(".vrt"):
            bounds, margin = _footprint_box(model, band)
    dem = Dem.open(dem_path, vertical_datum=datum, geoid=geoid, bounds=bounds, margin_deg=margin)
    note_terrain(dem)
    if model is not None:  # before any work: heights a terrain cannot have (a DEM in centimetres)
        from calibrate.plausibility import check_dem_heights

        check_dem_heights(dem, model, band=band)
    return dem


def _footprint_box(model, band):
    """``(lon_min, lat_min, lon_max, lat_max), margin_deg`` around a model's footprint, or ``(None, 0)``."""
    import numpy as np

    from sensor_models.terrain.footprint import footprint_sample_lonlat

    lon, lat = zip(*(footprint_sample_lonlat(model, h, n_side=9, band=band) for h in _FOOTPRINT_HEIGHTS_M))
    lon, lat = np.concatenate(lon), np.concatenate(lat)
    if lon.size == 0 or np.ptp(lon) > 180.0:  # off the Earth, or across the antimeridian: read it all
        return None, 0.0
    margin = max(0.1, _FOOTPRINT_MARGIN * max(np.ptp(lon), np.ptp(lat)))
    return (float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())), margin


def _nearest_existing(path: Path) -> Path:
    while not os.path.lexists(path) and path != path.parent:
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
            make_temp_file(base, "gcpcal-probe").unlink()
        except OSError as exc:
            reason = (exc.strerror or str(exc)).lower()
    if reason is not None:
        raise InputError(f"cannot write into {base}: {reason}", path=str(what))


def check_output_folder(out_dir, *, inputs=()) -> Path:
    """Check, before any computation, that a stage may write into folder ``out_dir``.

    The output guard (:func:`calibrate.actions._guard.check_folder_target`) runs first; then the
    staging that dead gcpcal runs left beside ``out_dir`` is removed
    (:func:`calibrate.actions._staging.clean_stale`) and the parent folder is probed for writing.

    Parameters
    ----------
    out_dir : str or Path
        The stage's output folder.
    inputs : InputSet or iterable, optional
        The stage's inputs (:class:`calibrate.actions._guard.InputSet`).

    Returns
    -------
    Path
        The folder to write, absolute (a link's target with ``--overwrite``).

    Raises
    ------
    InputError
        ``out_dir`` is refused by the guard, is a file, lies under a file, or cannot be created or
        written.
    """
    final = check_folder_target(out_dir, inputs)
    clean_stale(final.parent, final)
    _check_writable_folder(final.parent, final)
    fault_point("guarded")
    return final


def check_output_files(*paths, inputs=(), stdout_ok: bool = False) -> list[Path]:
    """Check, before any computation, that a stage may write (or replace) the files ``paths``.

    Parameters
    ----------
    *paths : str or Path or None
        Output files (None entries, options not given, are skipped).
    inputs : InputSet or iterable, optional
        The stage's inputs: no output may be one of them or lie in an input folder.
    stdout_ok : bool
        Whether ``-`` (standard output) is accepted (it is returned as ``Path("-")``).

    Returns
    -------
    list of Path
        The paths to write, absolute, in order (a link's target with ``--overwrite``).

    Raises
    ------
    InputError
        Two outputs share a name, a path is refused by the guard
        (:func:`calibrate.actions._guard.check_file_target`), lies under a file, or its folder
        cannot be created or written.
    """
    inputs = input_set(inputs)
    finals = [check_file_target(p, inputs, stdout_ok=stdout_ok) for p in paths if p is not None]
    keys = [str(p).casefold() if _case_insensitive(p.parent) else str(p) for p in finals]
    if len(set(keys)) != len(keys):
        raise InputError("two outputs of this command have the same name", path=str(finals[0]))
    for path in finals:
        if is_stdout(path):
            continue
        clean_stale(path.parent)
        _check_writable_folder(path.parent, path)
    fault_point("guarded")
    return finals


def _case_insensitive(folder: Path) -> bool:
    """Whether the filesystem of ``folder`` (its nearest existing parent) ignores the case of names."""
    base = _nearest_existing(folder)
    probe = base.name.swapcase()
    if not base.name or probe == base.name:
        return False
    try:
        return os.path.samefile(base, base.with_name(probe))
    except OSError:
        return False


def _make_folders(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; return those created, outermost first."""
    missing = []
    while not os.path.lexists(folder):
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
    """``value`` with every path under the staging folder moved under ``out_dir``, in text too.

    Parameters
    ----------
    value : dict, list, tuple, str, Path or any
        A summary returned by a writer that wrote into ``stage`` (walked recursively; a string
        naming the staging folder anywhere, e.g. a message "see <stage>/x.json", names ``out_dir``).
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
    if isinstance(value, str) and stage in value:  # a path, or a message naming one
        return value.replace(stage, final)
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
    """A staging folder beside ``out_dir`` whose files go into ``out_dir`` on success.

    The output path is checked first (:func:`check_output_folder`), so enter this before the
    computation. On success the files are moved in (:func:`calibrate.actions._commit.commit_folder`):
    a new or gcpcal-only folder is swapped in whole; a folder that also holds a user's files is
    merged into (gcpcal's earlier files of this output are replaced or removed, the user's are
    kept, and a new file that would replace one of them is refused unless ``--overwrite``). On
    any exception or interrupt the staging folder, and any parent folder created for it, are
    removed.

    Parameters
    ----------
    out_dir : str or Path
        The stage's output folder.
    prefix : str
        The stage's name between dots and dashes (``".calibrate-"``): recorded in the ledger.
    inputs : InputSet or iterable, optional
        The stage's inputs (:func:`check_output_folder`).

    Yields
    ------
    Path
        The staging folder: write every output there, under its final relative name.
    """
    from calibrate.actions._commit import commit_folder

    given = Path(out_dir).absolute()
    inputs = input_set(inputs)
    out_dir = check_output_folder(out_dir, inputs=inputs)
    made = _make_folders(out_dir.parent)
    tmp = None
    try:
        tmp = make_stage_dir(out_dir.parent, out_dir.name)
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; the output folder gets the usual mode
        fault_point("staging")
        with stage_inputs(inputs):
            yield tmp
        fault_point("written")
        _name_final_folder(tmp, given)
        check_folder_target(out_dir, inputs)  # again, just before the move: nothing changed meanwhile
        commit_folder(tmp, out_dir, command=current_command(prefix))
    except BaseException as exc:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        _remove_folders(made)
        named = _name_write_error(exc, out_dir)
        if named is exc:
            raise
        raise named from exc


@contextmanager
def staged_files(*paths, inputs=()):
    """Staging paths for a command's output files, all moved onto their targets together.

    The paths are checked first (:func:`check_output_files`), so enter this before the
    computation. Each staged file lies in a hidden folder beside its target, under the target's
    own name (GDAL drivers see the right extension). On success every staged file replaces its
    target (:func:`calibrate.actions._commit.commit_files`); a target whose staged file was not
    written is removed when gcpcal wrote it (it would be stale), kept otherwise. On any exception
    or interrupt nothing is moved and every staging and created folder is removed.

    Parameters
    ----------
    *paths : str or Path or None
        The output files (None entries are skipped and yield None).
    inputs : InputSet or iterable, optional
        The stage's inputs (:func:`check_output_files`).

    Yields
    ------
    list of Path or None
        One staging path per entry of ``paths``, in order.
    """
    from calibrate.actions._commit import commit_files

    inputs = input_set(inputs)
    finals = check_output_files(*paths, inputs=inputs)
    made, stages, staged = [], {}, []
    try:
        for final in finals:
            made += _make_folders(final.parent)
            if final.parent not in stages:
                stages[final.parent] = make_stage_dir(final.parent, final.name)
            staged.append(stages[final.parent] / final.name)
        it = iter(staged)
        fault_point("staging")
        with stage_inputs(inputs):
            yield [None if p is None else next(it) for p in paths]
        fault_point("written")
        for final in finals:  # again, just before the move
            check_file_target(final, inputs)
        commit_files(list(zip(staged, finals)), command=current_command())
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
    folder's path is checked before the action runs, and its files go into the final folder when
    the action returns. Paths under the staging folder in the returned value name the final one.

    Parameters
    ----------
    parameter : str
        Name of the action's output-folder argument.
    inputs : tuple of str
        Names of the action's input-path arguments (:mod:`calibrate.actions._guard`).
    prefix : str
        The stage's name (:func:`staged_folder`).

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
