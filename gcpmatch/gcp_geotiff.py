"""GCP tables inside GeoTIFFs: GDAL ground control points plus the whole table as metadata.

Format (``*.tif``, ``*.tiff``)
------------------------------
GDAL ground control points (GeoTIFF tie points) in EPSG:4326, readable by any GIS. GDAL's GCP
``(pixel, line)`` use the corner convention (``(0, 0)`` is the upper-left corner of the first
pixel), the same as ours, so ``line = row`` and ``pixel = col`` with no shift. GeoTIFF tie
points cannot carry ids or the other fields, so the whole table is also stored, as CSV text
(:mod:`gcpmatch.gcp_csv`), in the GDAL metadata item ``GCP_TABLE_CSV`` of domain ``gcpcal``
(inside the TIFF); the reader uses it and checks it against the tie points. A GeoTIFF written
by another tool (no such item) reads with ids from GDAL (``"1"``, ``"2"``, ...) and default
optional fields. At most :data:`GEOTIFF_MAX_GCPS` (10922) points, GDAL's limit for the
tie-point tag; use CSV or GeoPackage for more (or thin the table first).

Only the points of kind ``gcp`` become GDAL GCPs: a warp (``gdalwarp``, QGIS's georeferencer)
uses every GDAL GCP, and independent check points must stay out of the fit to stay independent.
Check points (and outliers) are in the stored table only, where ``read_gcps`` finds them.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from gcpmatch.gcp_csv import csv_chunks, parse_gcps_csv
from gcpmatch.gcps import (
    OPTIONAL_COLUMNS,
    GcpTable,
    check_image_shape,
    check_output,
    default_column,
    first_flagged,
    format_float,
    validate_columns,
)
from sensor_models.errors import InputError
from sensor_models.files.atomic import temporary_beside

__all__ = ["GEOTIFF_MAX_GCPS", "read_gcps_geotiff", "write_gcps_geotiff"]

_TIFF_DOMAIN, _TIFF_ITEM = "gcpcal", "GCP_TABLE_CSV"
# GDAL writes at most 10922 GCPs into the GeoTIFF tie-point tag (6 doubles each, a uint16
# count: GDAL issue #10164, pull request #10166); beyond that it falls back to a .aux.xml file.
GEOTIFF_MAX_GCPS = 10922


def read_gcps_geotiff(path: Path, image_shape) -> GcpTable:
    """Read and check the GCPs of a GeoTIFF (:func:`gcpmatch.gcp_files.read_gcps` for ``*.tif``).

    Parameters
    ----------
    path : Path
        The raster.
    image_shape : (int, int) or None
        ``(n_rows, n_cols)``, already checked; must equal the raster's shape when given.

    Returns
    -------
    GcpTable
        gcpcal's stored table (checked against the GDAL GCPs), else the GDAL GCPs with default
        optional fields.
    """
    import rasterio
    from rasterio.errors import RasterioError

    source = str(path)
    try:
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path) as src:
            gcps, crs = src.gcps
            shape = (src.height, src.width)
            stored = src.tags(ns=_TIFF_DOMAIN).get(_TIFF_ITEM)
    except (RasterioError, OSError) as exc:
        raise InputError(f"cannot open as a raster: {exc}", path=source) from None
    if image_shape is not None and tuple(image_shape) != shape:
        raise InputError(f"image_shape {tuple(image_shape)} contradicts the raster's {shape}",
                         path=source)  # fmt: skip
    if not gcps:
        raise InputError("the raster carries no GDAL ground control points", path=source)
    if crs is None or crs.to_epsg() != 4326:
        raise InputError(f"the GCPs are in {crs}; gcpcal reads GCPs in EPSG:4326 (WGS84 "
                         "lon/lat degrees) only", path=source)  # fmt: skip
    gdal = {name: np.array([getattr(g, attr) for g in gcps], dtype=np.float64)
            for name, attr in (("row", "row"), ("col", "col"), ("lon", "x"), ("lat", "y"),
                               ("h", "z"))}  # fmt: skip
    if stored is None:
        n = len(gcps)
        cols = {name: gdal[name] for name in ("row", "col", "lon", "lat", "h")}
        cols["id"] = np.array([str(g.id) for g in gcps])
        for name in OPTIONAL_COLUMNS:
            cols[name] = default_column(name, n)
        validate_columns(cols, where=lambda i: f"GCP {i + 1}", path=source, image_shape=shape)
        return GcpTable.from_validated_columns(cols)
    table = parse_gcps_csv(stored.encode("utf-8"), f"{source} [metadata {_TIFF_DOMAIN}:"
                           f"{_TIFF_ITEM}]", shape)  # fmt: skip
    fit = table.kind == "gcp"  # only these are GDAL GCPs (check points are in the table alone)
    if int(np.count_nonzero(fit)) != len(gcps):
        raise InputError(f"holds {len(gcps)} GDAL GCPs but its gcpcal table has {int(np.count_nonzero(fit))} "
                         "points of kind gcp; the GCPs were edited by another tool", path=source)  # fmt: skip
    for name, values in gdal.items():
        found = first_flagged(getattr(table, name)[fit] != values)
        if found is not None:
            i, count = found
            raise InputError(f"GCP {i + 1}: the GDAL GCP's {name} = {format_float(values[i])} "
                             f"differs from the gcpcal table's "
                             f"{format_float(getattr(table, name)[fit][i])} ({count} "
                             "GCPs); the GCPs were edited by another tool", path=source,
                             field=name)  # fmt: skip
    return table


def write_gcps_geotiff(table: GcpTable, path, *, image_shape, source_raster=None, source_band=None) -> Path:
    """Write ``table`` as GDAL GCPs (EPSG:4326) inside a GeoTIFF; atomically.

    The points of kind ``gcp`` become GDAL GCPs: ``line = row`` and ``pixel = col`` (both corner
    based, see the module notes), ``x = lon``, ``y = lat``, ``z = h``; the full table (check
    points too) is stored as CSV text in the metadata item ``GCP_TABLE_CSV`` of domain
    ``gcpcal``, since GeoTIFF tie points keep neither ids nor the other fields.

    Parameters
    ----------
    table : GcpTable
        1 to :data:`GEOTIFF_MAX_GCPS` points, all inside ``[0, n_rows] x [0, n_cols]``.
    path : str or Path
        Destination; its folder must exist. Replaced atomically.
    image_shape : (int, int)
        ``(n_rows, n_cols)`` of the image the GCPs refer to.
    source_raster : str or Path, optional
        A raster of ``image_shape`` whose pixels (every band, its dtype, nodata and band
        descriptions) are copied into the output; it is only read. Its own georeferencing
        (geotransform, CRS, RPCs) is not copied: the GCPs take its place. Without it the output
        is a single-band uint8 raster of zeros (tiled, sparse, deflate: a few kilobytes).
    source_band : int, optional
        Copy only this band of ``source_raster`` (1-based, as GDAL counts): the band the GCPs
        were measured in. Default: every band.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        Too many points, points outside the image, an unreadable or mis-shaped
        ``source_raster``, or GDAL could not write the file.
    """
    path = check_output(table, path)
    image_shape = _check_geotiff_table(table, path, image_shape)
    src = _open_source_raster(source_raster, path)
    try:
        if src is not None and (src.height, src.width) != image_shape:
            raise InputError(f"raster shape {(src.height, src.width)} differs from image_shape "
                             f"{image_shape}", path=str(source_raster))  # fmt: skip
        bands = _source_bands(src, source_band, source_raster)
        _write_geotiff_atomically(table, path, image_shape, src, bands)
    finally:
        if src is not None:
            src.close()
    return path


def _check_geotiff_table(table: GcpTable, path: Path, image_shape) -> tuple[int, int]:
    """The checked ``(n_rows, n_cols)``, after checking the table fits a GeoTIFF and the image."""
    image_shape = check_image_shape(image_shape)
    if image_shape is None:
        raise InputError("image_shape (n_rows, n_cols) is required", path=str(path))
    if len(table) > GEOTIFF_MAX_GCPS:
        raise InputError(f"{len(table)} points; a GeoTIFF holds at most {GEOTIFF_MAX_GCPS} GCPs "
                         "(GDAL's tie-point tag limit): write CSV or GeoPackage, or thin the "
                         "table", path=str(path))  # fmt: skip
    validate_columns(table.as_dict(), where=lambda i: f"point {i} (id {str(table.id[i])!r})",
                     path=str(path), image_shape=image_shape)  # fmt: skip
    if not np.any(table.kind == "gcp"):
        raise InputError("the table has no point of kind gcp: a GeoTIFF's GDAL GCPs hold only those (check "
                         "points stay out of a warp); write CSV or GeoPackage", path=str(path))
    return image_shape


def _open_source_raster(source_raster, path: Path):
    """The open rasterio dataset of ``source_raster`` (None if not given); never ``path`` itself."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    if source_raster is None:
        return None
    source_raster = Path(source_raster)
    if source_raster.resolve() == path.resolve():
        raise InputError("the output would replace source_raster; write elsewhere",
                         path=str(path))  # fmt: skip
    try:
        with warnings.catch_warnings():  # a level-1A raster has no georeferencing: expected
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            return rasterio.open(source_raster)
    except (RasterioError, OSError) as exc:
        raise InputError(f"cannot open as a raster: {exc}", path=str(source_raster)) from None


def _source_bands(src, source_band, source_raster) -> list[int]:
    """The 1-based bands of ``src`` to copy (all of them without ``source_band``)."""
    if src is None:
        if source_band is not None:
            raise InputError("source_band needs source_raster", field="source_band")
        return []
    if source_band is None:
        return list(range(1, src.count + 1))
    if not (isinstance(source_band, (int, np.integer)) and 1 <= int(source_band) <= src.count):
        raise InputError(f"must be a band of the raster, 1 to {src.count}; got {source_band!r}",
                         path=str(source_raster), field="source_band")  # fmt: skip
    return [int(source_band)]


def _write_geotiff_atomically(table: GcpTable, path: Path, image_shape, src, bands) -> None:
    """Write the GeoTIFF to a temporary file beside ``path``, check it, rename it onto ``path``."""
    import rasterio
    from rasterio.errors import RasterioError

    tmp = temporary_beside(path, ".tif")
    try:
        _write_geotiff(table, tmp, image_shape, src, bands)
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(tmp) as check:
            n_written = len(check.gcps[0])
        n_fit = int(np.count_nonzero(table.kind == "gcp"))
        if n_written != n_fit:  # never leave a file with GCPs silently dropped
            raise InputError(f"GDAL kept {n_written} of {n_fit} GCPs in the GeoTIFF",
                             path=str(path))  # fmt: skip
        os.replace(tmp, path)
    except RasterioError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(f"GDAL could not write the GeoTIFF: {exc}", path=str(path)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_geotiff(table: GcpTable, tmp: Path, image_shape, src, bands) -> None:
    """The GeoTIFF itself: pixels (copied from ``src`` or sparse zeros), GCPs, table metadata."""
    import rasterio
    from rasterio.control import GroundControlPoint
    from rasterio.crs import CRS
    from rasterio.errors import NotGeoreferencedWarning

    n_rows, n_cols = image_shape
    fit = table.kind == "gcp"  # check points stay out of any warp's fit
    gcps = [GroundControlPoint(row=r, col=c, x=x, y=y, z=z, id=i, info=k)
            for r, c, x, y, z, i, k in zip(table.row[fit].tolist(), table.col[fit].tolist(),
                                           table.lon[fit].tolist(), table.lat[fit].tolist(),
                                           table.h[fit].tolist(), table.id[fit].tolist(),
                                           table.kind[fit].tolist())]  # fmt: skip
    profile = dict(driver="GTiff", width=n_cols, height=n_rows, tiled=True,
                   compress="deflate", BIGTIFF="IF_SAFER")  # fmt: skip
    if src is None:
        profile.update(count=1, dtype="uint8", sparse_ok=True)
    else:
        profile.update(count=len(bands), dtype=src.dtypes[bands[0] - 1], nodata=src.nodata)
    with warnings.catch_warnings(), rasterio.Env(GDAL_PAM_ENABLED="NO"):
        # the new dataset has no georeferencing until its GCPs are set just below
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        dst = rasterio.open(tmp, "w", **profile)
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), dst:
        if src is not None:
            _copy_pixels(src, dst, n_rows, n_cols, bands)
        dst.gcps = (gcps, CRS.from_epsg(4326))
        dst.update_tags(ns=_TIFF_DOMAIN, **{_TIFF_ITEM: "".join(csv_chunks(table))})


def _copy_pixels(src, dst, n_rows: int, n_cols: int, bands) -> None:
    """Copy ``bands`` of ``src`` into ``dst`` in row blocks of ~16 MiB, with band descriptions."""
    from rasterio.windows import Window

    row_bytes = n_cols * len(bands) * np.dtype(src.dtypes[bands[0] - 1]).itemsize
    step = max(1, 2**24 // row_bytes)  # ~16 MiB of pixels at a time
    for r0 in range(0, n_rows, step):
        win = Window(0, r0, n_cols, min(step, n_rows - r0))
        dst.write(src.read(bands, window=win), window=win)
    for out_band, band in enumerate(bands, start=1):
        text = src.descriptions[band - 1]
        if text:
            dst.set_band_description(out_band, text)
