"""Level-1A rasters for the stages: which raster holds a band, and a copy of it with RPC tags.

:func:`write_l1a_with_rpc` writes a COPY of one band of the scene raster (optionally the columns
of one CCD) as a tiled GeoTIFF whose georeferencing is an RPC (the GDAL ``RPC`` metadata domain,
which GDAL stores in the GeoTIFF RPC tag, RPCCoefficientTag 50844), with the RPC's fit errors
in the dataset metadata (:data:`FIT_TAGS`). The user's raster is only read.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from sensor_models.files.atomic import temporary_beside
from sensor_models.errors import InputError
from sensor_models.readers.rpc_files import rpc_to_rasterio

__all__ = ["FIT_TAGS", "scene_raster", "write_l1a_with_rpc"]

#: Dataset metadata items (default domain) of the L1A GeoTIFF, from the fit report of
#: :func:`sensor_models.models.rpc_fit.fit_rpc`: item -> report key (pixels).
FIT_TAGS = {
    "GCPCAL_RPC_CHECK_MAX_PX": "check_max_px",
    "GCPCAL_RPC_CHECK_RMS_PX": "check_rms_px",
    "GCPCAL_RPC_FIT_MAX_PX": "fit_max_px",
    "GCPCAL_RPC_FIT_RMS_PX": "fit_rms_px",
}


def scene_raster(scene, band, image=None) -> tuple[str, int]:
    """The raster file and 1-based band index holding ``band`` of the scene.

    Parameters
    ----------
    scene : Scene
        The scene opened (:func:`sensor_models.readers.open_scene`; ``rasters``: band ->
        ``{"path", "index"}``).
    band : str or None
        The band.
    image : str or Path, optional
        A raster the user gave (``--image``): its first band.

    Returns
    -------
    path : str
    index : int

    Raises
    ------
    InputError
        The scene lists no raster for the band and no ``image`` was given.
    """
    if image is not None:
        return str(image), 1
    rasters = scene.rasters
    if band not in rasters:
        raise InputError(f"the scene lists no raster for band {band!r}; give --image")
    return str(rasters[band]["path"]), int(rasters[band].get("index", 1))


def _open(raster):
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            return rasterio.open(raster)
    except (RasterioError, OSError) as exc:
        raise InputError(f"cannot open the scene raster: {exc}", path=str(raster)) from None


def write_l1a_with_rpc(raster, index: int, out_path, rpc, *, image_shape, first_col: int = 0, first_row: int = 0,
                       fit_report: dict | None = None, extra_tags: dict | None = None) -> Path:
    """Write band ``index`` of ``raster`` (a window from ``first_row, first_col``) with ``rpc`` as RPC tags.

    Parameters
    ----------
    raster : str or Path
        The scene raster; it must be ``image_shape`` pixels. Only read.
    index : int
        Its band to copy (1-based).
    out_path : str or Path
        Destination GeoTIFF; written beside, checked (GDAL reads the RPC back) and renamed.
    rpc : sensor_models.models.rpc.RpcModel
        The RPC of the copied pixels: its ``image_shape`` is the output's shape.
    image_shape : (int, int)
        ``(n_rows, n_cols)`` of the whole scene the raster must have.
    first_col : int
        First scene column copied (a CCD's ``first_col``); ``rpc.image_shape[1]`` columns follow.
    first_row : int
        First scene row copied (a tile's); ``rpc.image_shape[0]`` rows follow.
    fit_report : dict, optional
        Of :func:`sensor_models.models.rpc_fit.fit_rpc`: its errors go to the :data:`FIT_TAGS` items.
    extra_tags : dict of str to str, optional
        More dataset metadata items.

    Returns
    -------
    Path
        ``out_path``.

    Raises
    ------
    InputError
        Unreadable raster, wrong shape or band, or GDAL could not write or read back the file.
    """
    from rasterio.errors import RasterioError

    out_path = Path(out_path)
    if Path(raster).resolve() == out_path.resolve():
        raise InputError("the output would replace the scene raster; write elsewhere", path=str(out_path))
    tags = {k: repr(float(fit_report[v])) for k, v in FIT_TAGS.items()} if fit_report else {}
    tags.update(extra_tags or {})
    src = _open(raster)
    tmp = temporary_beside(out_path, ".tif")
    try:
        _check_source(src, raster, index, image_shape, first_row, first_col, rpc.image_shape)
        _copy_with_rpc(src, index, tmp, rpc, first_row, first_col, tags)
        _check_written(tmp, out_path, rpc.image_shape)
        os.replace(tmp, out_path)
    except RasterioError as exc:
        raise InputError(f"GDAL could not write the GeoTIFF: {exc}", path=str(out_path)) from None
    finally:
        src.close()
        tmp.unlink(missing_ok=True)
    return out_path


def _check_source(src, raster, index, image_shape, first_row, first_col, out_shape) -> None:
    if (src.height, src.width) != tuple(image_shape):
        raise InputError(f"the raster is {src.height} x {src.width} px but the model describes "
                         f"{tuple(image_shape)}", path=str(raster))  # fmt: skip
    if not 1 <= int(index) <= src.count:
        raise InputError(f"has {src.count} band(s); band {index} was asked for", path=str(raster))
    if first_row < 0 or first_row + out_shape[0] > src.height or first_col < 0 or first_col + out_shape[1] > src.width:
        raise InputError(f"rows {first_row}..{first_row + out_shape[0]}, columns {first_col}.."
                         f"{first_col + out_shape[1]} are not inside the raster", path=str(raster))  # fmt: skip


def _copy_with_rpc(src, index: int, tmp: Path, rpc, first_row: int, first_col: int, tags: dict) -> None:
    """Tiled deflate GeoTIFF: pixels in row blocks of ~16 MiB, RPC tags, metadata."""
    import rasterio
    from rasterio.windows import Window

    n_rows, n_cols = rpc.image_shape
    dtype = src.dtypes[index - 1]
    profile = dict(driver="GTiff", width=n_cols, height=n_rows, count=1, dtype=dtype, nodata=src.nodata,
                   tiled=True, compress="deflate", BIGTIFF="IF_SAFER", rpcs=rpc_to_rasterio(rpc))
    step = max(1, 2**24 // (n_cols * np.dtype(dtype).itemsize))
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(tmp, "w", **profile) as dst:
        for r0 in range(0, n_rows, step):
            h = min(step, n_rows - r0)
            dst.write(src.read(index, window=Window(first_col, first_row + r0, n_cols, h)), 1,
                      window=Window(0, r0, n_cols, h))
        if src.descriptions[index - 1]:
            dst.set_band_description(1, src.descriptions[index - 1])
        dst.update_tags(**tags)


def _check_written(tmp: Path, out_path: Path, shape) -> None:
    """GDAL must read the RPC back from the file itself (no side-car)."""
    import rasterio

    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(tmp) as ds:
        if ds.rpcs is None or (ds.height, ds.width) != tuple(shape):
            raise InputError("GDAL did not read the RPC back from the written GeoTIFF", path=str(out_path))
