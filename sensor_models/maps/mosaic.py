"""Several raster tiles read as one: a GDAL VRT mosaic, written beside nothing the user gave.

A DOM or a DEM often comes as tiles: SRTM ``N44E005.hgt``, Copernicus GLO-30
``Copernicus_DSM_COG_10_N44_00_E005_00_DEM.tif``, or a user's own cut. :func:`raster_inputs`
turns what a user gives (one file, a list, a comma-separated list, a folder, a glob, a ``.vrt``)
into a list of files; :func:`mosaic_path` returns one path GDAL opens: the file itself for a
single file or a ``.vrt``, else a VRT XML written here into a private temporary folder (removed
when the process ends). The VRT only references the tiles; pixels are read by window through
GDAL when a caller reads, so a mosaic is never held whole in memory.

Tiles must share one CRS (refused otherwise, naming the first tile that differs), one pixel size
(within 1e-9 relative), one data type and one pixel grid, and be north-up. The mosaic covers
the union of the tiles. Where tiles overlap (SRTM tiles share their edge row and column) the
later tile in sorted order wins. Metadata items that every tile carries with one value (as
gcpcal's ``VERTICAL_DATUM``) are kept. Where no tile covers, the mosaic has no data (the tiles'
no-data value, or, when they declare none, 0 for unsigned integers, the type's minimum for
signed ones, NaN for floats).

VRT format: GDAL, "VRT -- GDAL Virtual Format" (``VRTDataset``, ``VRTRasterBand``,
``ComplexSource`` with ``SrcRect``/``DstRect`` and ``NODATA``), https://gdal.org/drivers/raster/vrt.html.
"""

from __future__ import annotations

import atexit
import glob
import os
import shutil
import tempfile
from dataclasses import dataclass
from xml.sax.saxutils import escape

from sensor_models.errors import InputError
from sensor_models.files.gdal_paths import is_gdal_virtual, virtual_exists

__all__ = ["RASTER_SUFFIXES", "mosaic_path", "raster_inputs", "write_vrt"]

#: File name endings taken from a folder (case-insensitive).
RASTER_SUFFIXES = (".tif", ".tiff", ".hgt", ".jp2", ".vrt", ".img", ".dt1", ".dt2", ".bil", ".nc")

_GLOB_CHARS = set("*?[")
_TMP_DIR: str | None = None


def _split_items(items) -> list[str]:
    """Flatten ``items`` (a path, or a list of paths) and split comma lists that are not files."""
    if items is None:
        return []
    if isinstance(items, (str, os.PathLike)):
        items = [items]
    out = []
    for item in items:
        text = os.fspath(item)
        if "," in text and not os.path.exists(text):
            out += [part.strip() for part in text.split(",") if part.strip()]
        else:
            out.append(text)
    return out


def _folder_rasters(folder: str) -> list[str]:
    names = sorted(os.listdir(folder))
    return [os.path.join(folder, n) for n in names
            if n.lower().endswith(RASTER_SUFFIXES) and os.path.isfile(os.path.join(folder, n))]


def raster_inputs(items, *, what: str = "raster") -> list[str]:
    """The files named by ``items``: files, comma lists, folders and globs, in a stable order.

    Parameters
    ----------
    items : str, os.PathLike or sequence of them
        Each item is a file (a ``.vrt`` included), a GDAL virtual path (``/vsizip/...``,
        ``/vsicurl/...``), a comma-separated list of files, a folder (its files ending in
        :data:`RASTER_SUFFIXES`, sorted by name) or a glob pattern (its matches, sorted).
    what : str
        What the files are ("DOM", "DEM"), for messages.

    Returns
    -------
    list of str
        Distinct files, in the order given (folders and globs sorted by name).

    Raises
    ------
    InputError
        Nothing given, a file not found, a folder or glob naming no raster.
    """
    files: list[str] = []
    for text in _split_items(items):
        if is_gdal_virtual(text):  # /vsizip/, /vsicurl/, ...: GDAL says whether it is there
            if not virtual_exists(text):
                raise InputError(f"{what} file not found (GDAL virtual path)", path=text)
            found = [text]
        elif os.path.isdir(text):
            found = _folder_rasters(text)
            if not found:
                raise InputError(f"the {what} folder holds no raster ({', '.join(RASTER_SUFFIXES)})", path=text)
        elif os.path.isfile(text):
            found = [text]
        elif _GLOB_CHARS & set(text):
            found = sorted(p for p in glob.glob(text) if os.path.isfile(p))
            if not found:
                raise InputError(f"the {what} pattern matches no file", path=text)
        else:
            raise InputError(f"{what} file not found", path=text)
        files += [f for f in found if f not in files]
    if not files:
        raise InputError(f"no {what} file given")
    return files


@dataclass(frozen=True)
class _Tile:
    path: str
    crs_wkt: str
    transform: tuple  # (a, b, c, d, e, f) of affine.Affine, pixel corners
    width: int
    height: int
    dtype: str
    nodata: float | None
    block: tuple
    tags: tuple  # (key, value) of the default metadata domain


def _read_tile(path: str, *, what: str) -> _Tile:
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as ds:
            if ds.crs is None:
                raise InputError(f"the {what} tile declares no coordinate reference system", path=path)
            t = ds.transform
            if t.b != 0 or t.d != 0 or t.e >= 0:
                raise InputError(f"the {what} tile is not north-up (rotated or flipped geotransform); warp it first",
                                 path=path)
            return _Tile(path, ds.crs.to_wkt(), tuple(t)[:6], ds.width, ds.height, ds.dtypes[0], ds.nodata,
                         tuple(ds.block_shapes[0]), tuple(sorted(ds.tags().items())))
    except RasterioError as exc:
        raise InputError(f"cannot be read as a {what} raster ({exc})", path=path) from None


def _check_alike(tiles: list[_Tile], *, what: str) -> None:
    import pyproj

    first = tiles[0]
    crs0 = pyproj.CRS.from_wkt(first.crs_wkt)
    for tile in tiles[1:]:
        if tile.crs_wkt != first.crs_wkt and not pyproj.CRS.from_wkt(tile.crs_wkt).equals(crs0, ignore_axis_order=True):
            raise InputError(f"the {what} tiles mix coordinate reference systems: this one is "
                             f"{pyproj.CRS.from_wkt(tile.crs_wkt).name!r}, {os.path.basename(first.path)} is "
                             f"{crs0.name!r}; warp them to one CRS first", path=tile.path)
        for k, name in ((0, "width"), (4, "height")):
            if abs(tile.transform[k] - first.transform[k]) > 1e-9 * abs(first.transform[k]):
                raise InputError(f"the {what} tiles differ in pixel {name}: {abs(tile.transform[k])} here, "
                                 f"{abs(first.transform[k])} in {os.path.basename(first.path)}", path=tile.path)
        if tile.dtype != first.dtype:
            raise InputError(f"the {what} tiles differ in data type: {tile.dtype} here, {first.dtype} in "
                             f"{os.path.basename(first.path)}", path=tile.path)


def _fill_value(dtype: str) -> float:
    """No-data value of a mosaic whose tiles declare none: where no tile covers, it has no data."""
    import numpy as np

    if dtype.startswith("float"):
        return float("nan")
    info = np.iinfo(dtype)
    return 0 if info.min == 0 else int(info.min)


def _metadata_xml(tiles: list[_Tile]) -> list[str]:
    """Metadata items every tile carries with the same value (e.g. gcpcal's ``VERTICAL_DATUM``)."""
    common = set(tiles[0].tags).intersection(*(t.tags for t in tiles[1:]))
    if not common:
        return []
    items = [f'    <MDI key="{escape(k, {chr(34): "&quot;"})}">{escape(v)}</MDI>' for k, v in sorted(common)]
    return ["  <Metadata>", *items, "  </Metadata>"]


def _vrt_xml(tiles: list[_Tile], nodata=None) -> str:
    """The VRT XML of ``tiles`` (alike, north-up) covering their union; ``nodata`` for tiles declaring none."""
    res_x, res_y = tiles[0].transform[0], tiles[0].transform[4]  # res_y < 0
    x0 = min(t.transform[2] for t in tiles)
    y0 = max(t.transform[5] for t in tiles)
    x1 = max(t.transform[2] + t.width * res_x for t in tiles)
    y1 = min(t.transform[5] + t.height * res_y for t in tiles)
    width, height = int(round((x1 - x0) / res_x)), int(round((y1 - y0) / res_y))
    for t in tiles:
        col, row = (t.transform[2] - x0) / res_x, (t.transform[5] - y0) / res_y
        if abs(col - round(col)) > 1e-3 or abs(row - round(row)) > 1e-3:
            raise InputError(f"the tile's pixels are not aligned with those of {os.path.basename(tiles[0].path)} "
                             f"(offset of {col % 1:.3f}, {row % 1:.3f} pixel); resample the tiles to one grid first",
                             path=t.path)
    if nodata is None:
        nodata = tiles[0].nodata if tiles[0].nodata is not None else _fill_value(tiles[0].dtype)
    gdal_type = {"uint8": "Byte", "int8": "Int8", "uint16": "UInt16", "int16": "Int16", "uint32": "UInt32",
                 "int32": "Int32", "float32": "Float32", "float64": "Float64"}.get(tiles[0].dtype, "Float64")
    lines = [f'<VRTDataset rasterXSize="{width}" rasterYSize="{height}">',
             f"  <SRS>{escape(tiles[0].crs_wkt)}</SRS>",
             f"  <GeoTransform>{x0!r}, {res_x!r}, 0.0, {y0!r}, 0.0, {res_y!r}</GeoTransform>",
             *_metadata_xml(tiles),
             f'  <VRTRasterBand dataType="{gdal_type}" band="1">']
    if nodata is not None:
        lines.append(f"    <NoDataValue>{nodata!r}</NoDataValue>")
    for t in tiles:
        col = int(round((t.transform[2] - x0) / res_x))
        row = int(round((t.transform[5] - y0) / res_y))
        lines += ["    <ComplexSource>",
                  f'      <SourceFilename relativeToVRT="0">{escape(os.path.abspath(t.path))}</SourceFilename>',
                  "      <SourceBand>1</SourceBand>",
                  f'      <SourceProperties RasterXSize="{t.width}" RasterYSize="{t.height}" DataType="{gdal_type}" '
                  f'BlockXSize="{t.block[1]}" BlockYSize="{t.block[0]}"/>',
                  f'      <SrcRect xOff="0" yOff="0" xSize="{t.width}" ySize="{t.height}"/>',
                  f'      <DstRect xOff="{col}" yOff="{row}" xSize="{t.width}" ySize="{t.height}"/>']
        lines.append(f"      <NODATA>{nodata if t.nodata is None else t.nodata!r}</NODATA>")
        lines.append("    </ComplexSource>")
    lines += ["  </VRTRasterBand>", "</VRTDataset>", ""]
    return "\n".join(lines)


def write_vrt(files, vrt_path, *, what: str = "raster", nodata=None) -> str:
    """Write a VRT mosaic of the north-up tiles ``files`` (band 1 of each) to ``vrt_path``.

    Parameters
    ----------
    files : sequence of str
        Tiles sharing one CRS, pixel size and data type.
    vrt_path : str or os.PathLike
        Where to write the VRT XML (tiles are referenced by absolute path).
    what : str
        What the tiles are, for messages.
    nodata : float, optional
        No-data value of tiles that declare none (default: 0 for unsigned integers, the type's
        minimum for signed ones, NaN for floats); also the mosaic's where no tile covers.

    Returns
    -------
    str
        ``vrt_path``.

    Raises
    ------
    InputError
        A tile unreadable, without CRS or not north-up; tiles differing in CRS (the message
        names the tile), pixel size or data type.
    """
    tiles = [_read_tile(os.fspath(f), what=what) for f in files]
    _check_alike(tiles, what=what)
    vrt_path = os.fspath(vrt_path)
    with open(vrt_path, "w", encoding="utf-8") as fh:
        fh.write(_vrt_xml(tiles, nodata))
    return vrt_path


def _declares_nodata(path: str) -> bool:
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as ds:
            return ds.nodata is not None
    except RasterioError:
        return True  # let the caller's own open report it


def _remove_if_owner(folder: str, owner_pid: int) -> None:
    """Remove ``folder`` at exit, but only from the process that made it (not from a forked child)."""
    if os.getpid() == owner_pid:
        shutil.rmtree(folder, ignore_errors=True)


def _private_dir() -> str:
    global _TMP_DIR
    if _TMP_DIR is None or not os.path.isdir(_TMP_DIR):
        _TMP_DIR = tempfile.mkdtemp(prefix="gcpcal-mosaic-")
        atexit.register(_remove_if_owner, _TMP_DIR, os.getpid())
    return _TMP_DIR


def mosaic_path(items, *, what: str = "raster", nodata=None) -> str:
    """One path GDAL opens for what the user gave: a file, or a VRT mosaic of several.

    Parameters
    ----------
    items : str, os.PathLike or sequence of them
        As :func:`raster_inputs` takes.
    what : str
        What the files are ("DOM", "DEM"), for messages.
    nodata : float, optional
        No-data value of files that declare none. A single such file is then wrapped in a VRT
        that declares it, so that GDAL's own reads (decimated averages included) skip it.

    Returns
    -------
    str
        The single file (a ``.vrt`` included) when one is named and needs no ``nodata``; else a
        VRT written into a private temporary folder that lives as long as the process.

    Raises
    ------
    InputError
        As :func:`raster_inputs` and :func:`write_vrt`.
    """
    files = raster_inputs(items, what=what)
    if len(files) == 1 and (nodata is None or files[0].lower().endswith(".vrt") or _declares_nodata(files[0])):
        return files[0]
    fd, vrt = tempfile.mkstemp(prefix=f"{what.lower().replace(' ', '-')}-", suffix=".vrt", dir=_private_dir())
    os.close(fd)
    return write_vrt(files, vrt, what=what)
