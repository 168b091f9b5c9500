"""GDAL virtual file paths (``/vsizip/``, ``/vsicurl/``, ``/vsis3/``, ...) as inputs.

GDAL reads rasters inside archives, over HTTP and from object stores through virtual file
systems whose paths start with ``/vsi``: ``/vsizip/path/to/archive.zip/dem.tif``,
``/vsicurl/https://host/dom.tif``, ``/vsis3/bucket/key.tif``. They are not files of the local
filesystem, so existence is asked of GDAL (``VSIStat`` through rasterio), not of ``os.path``.
Which schemes work depends on the GDAL build and, for remote ones, on the network and its
credentials (GDAL's own configuration options, e.g. ``AWS_*``).
"""

from __future__ import annotations

import os

__all__ = ["VIRTUAL_PREFIX", "is_gdal_virtual", "virtual_exists"]

#: Prefix of every GDAL virtual file system path.
VIRTUAL_PREFIX = "/vsi"


def is_gdal_virtual(path) -> bool:
    """Whether ``path`` is a GDAL virtual file system path (``/vsizip/...``, ``/vsicurl/...``).

    Parameters
    ----------
    path : str or os.PathLike or None

    Returns
    -------
    bool
    """
    if path is None:
        return False
    try:
        text = os.fspath(path)
    except TypeError:
        return False
    return isinstance(text, str) and text.startswith(VIRTUAL_PREFIX) and "/" in text[1:]


def virtual_exists(path) -> bool:
    """Whether GDAL finds a file at a virtual path (``VSIStatL``; no raster driver is involved).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool
        False as well when the virtual file system cannot be reached.
    """
    import rasterio
    import rasterio.shutil
    from rasterio.errors import RasterioError

    try:
        with rasterio.Env():
            return bool(rasterio.shutil.exists(os.fspath(path)))
    except (RasterioError, OSError, ValueError):
        return False
