"""GCP tables as OGC GeoPackage layers, written and read by GDAL through :mod:`pyogrio`.

Format (``*.gpkg``)
-------------------
OGC GeoPackage 1.3 [1]_ written and read by GDAL through :mod:`pyogrio` (its ``raw`` numpy-array
API: no pandas): one features layer (default name ``gcps``) in EPSG:4326 whose ``POINT Z``
geometry holds ``(lon, lat, h)`` and whose attribute columns hold every field of
:mod:`gcpmatch.gcps`. On reading, the file must carry a GeoPackage ``application_id``, the
attributes are authoritative and the geometry must agree with them (1e-9 degree, 1e-6 m); one
SQL scan (run by GDAL) rejects NULLs and values of the wrong SQLite storage class, which GDAL
would otherwise convert silently. Geometries are ISO WKB points, decoded here with numpy.

:func:`write_point_layer` writes any points with attribute columns the same way (the
calibration's residual layers use it).

References
----------
.. [1] Open Geospatial Consortium, "OGC GeoPackage Encoding Standard", version 1.3.1,
   OGC 12-128r18 (2021): sections 1.1.1 (SQLite container, ``application_id`` and
   ``user_version``), 1.1.2 (``gpkg_spatial_ref_sys``), 1.1.3 (``gpkg_contents``), 2.1.3
   (GeoPackageBinary geometry encoding), 2.1.5 (``gpkg_geometry_columns``), 2.1.6 (features
   tables).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from gcpmatch.gcps import (
    COLUMNS,
    FLOAT_COLUMNS,
    REQUIRED_COLUMNS,
    GcpTable,
    check_output,
    default_column,
    first_flagged,
    format_float,
    validate_columns,
)
from sensor_models.errors import InputError
from sensor_models.files.atomic import temporary_beside

__all__ = ["read_gcps_gpkg", "write_gcps_gpkg", "write_point_layer"]

_GPKG_APPLICATION_IDS = (0x47504B47, 0x47503130, 0x47503131)  # 'GPKG', 'GP10', 'GP11'
_SQLITE_MAGIC = b"SQLite format 3\x00"
# ISO WKB POINT Z, little-endian: byte order, geometry type, x, y, z (29 bytes)
_WKB_POINT_Z = np.dtype([("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
assert _WKB_POINT_Z.itemsize == 29
_WKB_POINT_DIMS = {1: 2, 1001: 3, 0x80000001: 3, 2001: 3, 3001: 4}  # 2D, Z (ISO, 2.5D), M, ZM
_WKB_HAS_Z = frozenset((1001, 0x80000001, 3001))
_OGR_NUMBER = frozenset(("OFTReal", "OFTInteger", "OFTInteger64"))
_OGR_TEXT = frozenset(("OFTString", "OFTInteger", "OFTInteger64"))


def _pyogrio_errors() -> tuple:
    """The exception types pyogrio raises for unreadable or unwritable data sources."""
    from pyogrio import errors

    return (errors.DataSourceError, errors.DataLayerError, errors.FieldError, errors.FeatureError,
            errors.GeometryError, errors.CRSError)  # fmt: skip


def _q(name: str) -> str:
    """An SQL identifier, double-quoted."""
    return '"' + name.replace('"', '""') + '"'


def read_gcps_gpkg(path: Path, image_shape, layer) -> GcpTable:
    """Read and validate a GeoPackage GCP layer (:func:`gcpmatch.gcp_files.read_gcps` for ``*.gpkg``).

    Parameters
    ----------
    path : Path
        The file.
    image_shape : (int, int) or None
        ``(n_rows, n_cols)``, already checked: points outside the image are errors.
    layer : str or None
        The features layer; None: the only one, else ``"gcps"``.

    Returns
    -------
    GcpTable
        The features in fid order.
    """
    source = str(path)
    if not path.is_file():
        raise InputError("cannot read: no such file", path=source)
    _check_gpkg_header(path, source)
    gdal_errors = _pyogrio_errors()
    try:
        layer = _pick_gpkg_layer(path, source, layer)
        names, fid_column = _gpkg_layer_schema(path, source, layer)
        _check_gpkg_value_types(path, source, layer, names, fid_column)
        fids, geometry, cols = _read_gpkg_columns(path, source, layer, names)
    except gdal_errors as exc:
        raise InputError(f"not a readable GeoPackage: {exc}", path=source) from None

    def where(i):
        return f"feature fid {fids[i]}"

    _check_geometry(geometry, cols, where, source)
    validate_columns(cols, where=where, path=source, image_shape=image_shape)
    return GcpTable.from_validated_columns(cols)


def _check_gpkg_header(path: Path, source: str) -> None:
    """Require an SQLite 3 file whose header carries a GeoPackage ``application_id``."""
    try:
        with open(path, "rb") as fh:
            header = fh.read(100)
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=source) from None
    if len(header) < 100 or not header.startswith(_SQLITE_MAGIC):
        raise InputError("not a GeoPackage (not an SQLite 3 database file)", path=source)
    app_id = int.from_bytes(header[68:72], "big")
    if app_id not in _GPKG_APPLICATION_IDS:
        raise InputError(f"not a GeoPackage (SQLite application_id {app_id:#x}, expected "
                         "0x47504b47 'GPKG')", path=source)  # fmt: skip


def _pick_gpkg_layer(path: Path, source: str, layer) -> str:
    """The features layer to read: ``layer``, else the only one, else ``"gcps"``."""
    import pyogrio

    layers = sorted(str(name) for name, geometry_type in pyogrio.list_layers(path)
                    if geometry_type is not None)  # fmt: skip
    if layer is None:
        if len(layers) == 1 or "gcps" in layers:
            return layers[0] if len(layers) == 1 else "gcps"
        raise InputError(f"has {len(layers)} feature layers ({', '.join(layers) or 'none'}); "
                         "choose one with layer=", path=source)  # fmt: skip
    if layer not in layers:
        raise InputError(f"no features layer {layer!r}; layers: {', '.join(layers) or 'none'}",
                         path=source)  # fmt: skip
    return layer


def _gpkg_layer_schema(path: Path, source: str, layer: str) -> tuple[list[str], str]:
    """The layer's attribute column names and its FID column, after checking both."""
    import pyogrio

    info = pyogrio.read_info(path, layer=layer)
    if not info.get("fid_column") or not info.get("geometry_name"):
        raise InputError(f"layer {layer!r} has no geometry column or no single integer primary "
                         "key", path=source)  # fmt: skip
    if info["crs"] != "EPSG:4326":
        raise InputError(f"layer {layer!r} is in {info['crs']}; GCP tables are in EPSG:4326 "
                         "(WGS84 lon/lat)", path=source)  # fmt: skip
    names = [str(name) for name in info["fields"]]
    for name, ogr_type in zip(names, info["ogr_types"]):
        if name not in COLUMNS:
            raise InputError(f"layer {layer!r}: unknown column {name!r}; columns are "
                             f"{', '.join(COLUMNS)}", path=source, field=name)  # fmt: skip
        allowed = _OGR_NUMBER if name in FLOAT_COLUMNS else _OGR_TEXT
        if ogr_type not in allowed:
            what = "a number" if name in FLOAT_COLUMNS else "text"
            raise InputError(f"layer {layer!r}: column {name!r} has GDAL type {ogr_type}; it must "
                             f"hold {what}", path=source, field=name)  # fmt: skip
    for name in REQUIRED_COLUMNS:
        if name not in names:
            raise InputError(f"layer {layer!r}: missing required column {name!r}", path=source,
                             field=name)  # fmt: skip
    return names, str(info["fid_column"])


def _check_gpkg_value_types(path: Path, source: str, layer: str, names, fid_column: str) -> None:
    """Raise on the first feature (by fid) holding a value of the wrong SQLite storage class.

    SQLite columns are dynamically typed and GDAL converts silently (text in a REAL column reads
    as 0), so one SQL scan run by GDAL finds NULLs and wrong types before the bulk read.
    """
    import pyogrio.raw

    bad, shown = [], []
    for j, name in enumerate(names):
        allowed = ("'real', 'integer'" if name in FLOAT_COLUMNS else
                   "'text', 'integer', 'null'" if name in ("band", "ccd") else "'text', 'integer'")
        bad.append(f"typeof({_q(name)}) NOT IN ({allowed})")  # band/ccd NULL: ""
        shown.append(f"typeof({_q(name)}) AS t{j}, CAST({_q(name)} AS TEXT) AS v{j}")
    sql = (f"SELECT {_q(fid_column)}, {', '.join(shown)} FROM {_q(layer)} "
           f"WHERE {' OR '.join(bad)} ORDER BY {_q(fid_column)} LIMIT 1")  # fmt: skip
    _, fids, _, values = pyogrio.raw.read(path, sql=sql, read_geometry=False, return_fids=True)
    if fids is None or len(fids) == 0:
        return
    for j, name in enumerate(names):
        storage, text = values[2 * j][0], values[2 * j + 1][0]
        ok = (storage in ("real", "integer") if name in FLOAT_COLUMNS
              else storage in ("text", "integer") or (storage == "null" and name in ("band", "ccd")))
        if not ok:
            what = "NULL" if storage == "null" else f"{text!r} is not a " + (
                "number" if name in FLOAT_COLUMNS else "text")  # fmt: skip
            raise InputError(f"feature fid {int(fids[0])}: {what}", path=source, field=name)


def _read_gpkg_columns(path: Path, source: str, layer: str, names):
    """Fids, WKB geometries and typed columns (defaults filled) of every feature, in fid order."""
    import pyogrio.raw

    _, fids, geometry, values = pyogrio.raw.read(path, layer=layer, columns=names,
                                                 return_fids=True)  # fmt: skip
    if len(fids) == 0:
        raise InputError(f"layer {layer!r} has no features", path=source)
    order = np.argsort(fids, kind="stable") if np.any(np.diff(fids) < 0) else slice(None)
    fids, geometry = np.asarray(fids)[order], np.asarray(geometry, dtype=object)[order]
    cols = {}
    for name, column in zip(names, values):
        column = np.asarray(column)[order]
        if name in FLOAT_COLUMNS:
            cols[name] = np.ascontiguousarray(column, dtype=np.float64)
        else:
            cols[name] = np.char.strip(_text_column(column))
    for name in COLUMNS:
        if name not in cols:
            cols[name] = default_column(name, fids.size)
    return fids, geometry, {name: cols[name] for name in COLUMNS}


def _text_column(column: np.ndarray) -> np.ndarray:
    """A numpy unicode array from what GDAL returns for a text column (NULL, allowed only in
    ``band``/``ccd``, becomes ``""``; integers become their decimal text)."""
    if column.dtype.kind == "f":  # an INTEGER column holding NULLs comes back as float + NaN
        null = np.isnan(column)
        return np.where(null, "", np.where(null, 0, column).astype(np.int64).astype(str))
    if column.dtype.kind in "iu":
        return column.astype(str)
    values = column.tolist()
    if None in values:
        values = ["" if v is None else v for v in values]
    return np.array(values, dtype=str) if values else np.zeros(0, dtype="U1")


def _parse_wkb_point(wkb) -> tuple[float, float, float]:
    """(x, y, z or NaN) of a WKB point (ISO or 2.5D, either byte order); ValueError if not one."""
    if wkb is None:
        raise ValueError("no geometry (NULL)")
    if not isinstance(wkb, bytes) or len(wkb) < 5:
        raise ValueError("not a WKB geometry")
    endian = "<" if wkb[:1] == b"\x01" else ">"
    gtype = int(np.frombuffer(wkb[1:5], dtype=endian + "u4")[0])
    dims = _WKB_POINT_DIMS.get(gtype)
    if dims is None:
        raise ValueError(f"WKB geometry type {gtype} is not a point")
    if len(wkb) < 5 + 8 * dims:
        raise ValueError("truncated WKB point")
    xyz = np.frombuffer(wkb[5:5 + 8 * dims], dtype=endian + "f8")
    if np.isnan(xyz[0]) and np.isnan(xyz[1]):
        raise ValueError("empty geometry")
    z = xyz[2] if gtype in _WKB_HAS_Z else np.nan
    return float(xyz[0]), float(xyz[1]), float(z)


def _geometry_xyz(geometry, where, source) -> np.ndarray:
    """(N, 3) lon, lat, h of the WKB points (h NaN for 2D points); one vectorized pass when
    every point is a little-endian POINT Z, the layout GDAL returns for this module's files."""
    n = len(geometry)
    try:
        joined = b"".join(geometry)  # TypeError on NULL geometries
        same_size = len(joined) == _WKB_POINT_Z.itemsize * n
    except TypeError:
        same_size = False
    if same_size:
        raw = np.frombuffer(joined, dtype=_WKB_POINT_Z)
        if np.all(raw["order"] == 1) and np.all(np.isin(raw["type"], (1001, 0x80000001))):
            return np.stack([raw["x"], raw["y"], raw["z"]], axis=1)
    xyz = np.empty((n, 3))
    for i, wkb in enumerate(geometry):  # any other layout: one geometry at a time
        try:
            xyz[i] = _parse_wkb_point(wkb)
        except ValueError as exc:
            raise InputError(f"{where(i)}: geometry: {exc}", path=source) from None
    return xyz


def _check_geometry(geometry, cols, where, source) -> None:
    """Require every feature's point geometry to agree with its lon/lat/h attributes."""
    xyz = _geometry_xyz(geometry, where, source)
    for k, name, tol in ((0, "lon", 1e-9), (1, "lat", 1e-9), (2, "h", 1e-6)):
        v = cols[name]
        off = np.abs(xyz[:, k] - v) > tol
        if k == 2:
            off &= ~np.isnan(xyz[:, 2])
        found = first_flagged(off)
        if found is not None:
            i, count = found
            raise InputError(f"{where(i)}: the point geometry's {'xyz'[k]} = "
                             f"{format_float(xyz[i, k])} "
                             f"differs from the attribute {name} = {format_float(v[i])} ({count} "
                             "features); the attributes define the GCPs: edit them, not the "
                             "geometry",
                             path=source, field=name)  # fmt: skip


_LAYER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_GPKG_DESCRIPTION = ("gcpcal ground control points (lon, lat, h above the WGS84 ellipsoid; row, "
                     "col with the first pixel's centre at 0.5, 0.5)")  # fmt: skip


def write_gcps_gpkg(table: GcpTable, path, *, layer: str = "gcps") -> Path:
    """Write ``table`` as an OGC GeoPackage 1.3 features layer (EPSG:4326 POINT Z); atomically.

    Written by GDAL through :func:`pyogrio.raw.write`: the mandatory GeoPackage tables (spatial
    reference systems -1, 0 and 4326, contents with the layer's extent, geometry columns) and
    the layer: ``fid`` (integer primary key), ``geom`` (a ``POINT`` with Z holding lon, lat, h;
    GDAL stores points as GeoPackageBinary with no envelope [1]_) and one column per GCP field
    (TEXT or REAL, in :data:`COLUMNS` order), features in table order (fid 1, 2, ...). No
    spatial index (optional in the standard; GIS tools build one on demand).

    Parameters
    ----------
    table : GcpTable
        At least one point.
    path : str or Path
        Destination (``*.gpkg``); its folder must exist. Written to a temporary file beside it,
        then renamed: on any error nothing is left and an existing file is untouched.
    layer : str
        Layer (table) name: letters, digits and underscores, not starting with a digit,
        ``gpkg_``, ``rtree_`` or ``sqlite_``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        Bad table, folder or layer name, or GDAL could not write the file.
    """
    path = check_output(table, path)
    if not (isinstance(layer, str) and _LAYER_NAME.match(layer)
            and not layer.lower().startswith(("gpkg_", "rtree_", "sqlite_"))):  # fmt: skip
        raise InputError(f"layer name {layer!r} must be letters, digits and underscores, not "
                         "starting with a digit, gpkg_, rtree_ or sqlite_",
                         path=str(path))  # fmt: skip
    return write_point_layer(path, table.lon, table.lat, table.h, table.as_dict(), layer=layer,
                             description=_GPKG_DESCRIPTION, what="the GeoPackage")


def write_point_layer(path, lon, lat, h, columns: dict, *, layer: str, description: str,
                      what: str = "the layer") -> Path:
    """Write points as a GeoPackage 1.3 layer (EPSG:4326 POINT Z, ``fid``, ``geom``); atomically.

    One GDAL call (:func:`pyogrio.raw.write`, inserts batched in transactions) into a temporary
    file beside ``path``, renamed at the end; on any error nothing is left and an existing file
    is untouched.

    Parameters
    ----------
    path : Path
        Destination (``*.gpkg``); its folder must exist.
    lon, lat, h : array_like, shape (N,)
        WGS84 degrees and metres above the ellipsoid of each point.
    columns : dict of str to array_like, shape (N,)
        The attribute fields, in order (numpy text columns are written as free-length TEXT).
    layer : str
        Layer (table) name.
    description : str
        The layer's ``gpkg_contents`` description.
    what : str
        What the file is, for the error message.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        GDAL could not write the file.
    """
    import pyogrio.raw

    path = Path(path)
    points = np.zeros(np.asarray(lon).size, dtype=_WKB_POINT_Z)
    points["order"], points["type"] = 1, 1001
    points["x"], points["y"], points["z"] = lon, lat, h
    geometry = np.array(points.view(f"V{_WKB_POINT_Z.itemsize}").tolist(), dtype=object)
    # text as Python str objects: a numpy "U<w>" column would become a TEXT(<w>) field
    fields = [a.astype(object) if a.dtype.kind == "U" else a for a in (np.asarray(v) for v in columns.values())]
    tmp = temporary_beside(path, ".gpkg")
    try:
        tmp.unlink()  # GDAL creates the file itself; the unique name stays reserved to us
        pyogrio.raw.write(tmp, geometry, fields, fields=list(columns), layer=layer, driver="GPKG",
                          crs="EPSG:4326", geometry_type="Point Z", dataset_options={"VERSION": "1.3"},
                          layer_options={"SPATIAL_INDEX": "NO", "FID": "fid", "GEOMETRY_NAME": "geom",
                                         "DESCRIPTION": description})  # fmt: skip
        os.replace(tmp, path)
    except _pyogrio_errors() as exc:
        _remove_sqlite_files(tmp)
        raise InputError(f"GDAL could not write {what}: {exc}", path=str(path)) from None
    except BaseException:
        _remove_sqlite_files(tmp)
        raise
    return path


def _remove_sqlite_files(tmp: Path) -> None:
    """Remove a temporary database and any journal SQLite left beside it."""
    for suffix in ("", "-journal", "-wal", "-shm"):
        Path(str(tmp) + suffix).unlink(missing_ok=True)
