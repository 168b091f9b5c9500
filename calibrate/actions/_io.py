"""Helpers shared by the stage actions: JSON summaries, DEMs, staged output folders."""

from __future__ import annotations

import json
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from calibrate._json import json_default
from sensor_models.atomic import atomic_write_text, move_tree_into

__all__ = ["open_dem", "staged_folder", "write_summary"]


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


def open_dem(dem_path, datum=None, geoid=None):
    """Open a DEM, its vertical datum declared when the file does not say.

    Parameters
    ----------
    dem_path : str or Path
        DEM raster (any CRS rasterio reads).
    datum : {"ellipsoid", "egm96"} or None
        Vertical datum of the heights when the file does not declare it.
    geoid : str or Path or None
        Geoid grid for EGM96 heights.

    Returns
    -------
    sensor_models.terrain.Dem
    """
    from sensor_models.terrain import Dem

    return Dem.open(dem_path, vertical_datum=datum, geoid=geoid)


@contextmanager
def staged_folder(out_dir, prefix: str):
    """A temporary folder inside ``out_dir`` whose files move into ``out_dir`` on success.

    Parameters
    ----------
    out_dir : str or Path
        The stage's output folder (created when missing).
    prefix : str
        Name prefix of the temporary folder (e.g. ``".thermal-"``).

    Yields
    ------
    Path
        The temporary folder: write every output there. On an exception nothing reaches
        ``out_dir`` and the temporary folder is removed.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=out_dir)).resolve()
    try:
        yield tmp
        move_tree_into(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
