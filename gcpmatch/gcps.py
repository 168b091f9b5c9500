"""Ground control point (GCP) tables: the :class:`GcpTable` type and its CSV, GeoPackage and
GeoTIFF forms.

A GCP ties a continuous image position ``(row, col)`` to a ground point ``(lon, lat, h)``.

Conventions
-----------
- ``row, col``: continuous image coordinates (line, sample) in pixels, the centre of the first
  pixel at ``(0.5, 0.5)`` and its upper-left corner at ``(0, 0)`` (GDAL/rasterio). A point lies
  in an image of ``(n_rows, n_cols)`` pixels when ``0 <= row <= n_rows`` and
  ``0 <= col <= n_cols``.
- ``lon, lat``: WGS84 degrees, ``lat`` in [-90, 90], ``lon`` in [-180, 360).
- ``h``: metres above the WGS84 ellipsoid (not above the geoid).
- ``sigma_px``: a priori standard deviation of the image measurement, pixels, > 0. Default 1:
  unit weights, the absolute scale being left to the a posteriori variance factor of the
  adjustment. (Not NaN: every numeric value in a table is finite.)
- ``band``, ``ccd``: free text naming the spectral band and the CCD (detector array) the point
  was measured in; default ``""`` (the only band / CCD).
- ``score``: match quality (e.g. the phase-correlation peak), any finite number; default 1.
- ``kind``: ``"gcp"`` (used in the adjustment) or ``"check"`` (independent check point, never
  used in a fit); default ``"gcp"``.

Formats
-------
CSV (``*.csv``)
    UTF-8 (an optional byte-order mark is skipped), comma separated, header on line 1 naming
    the columns in any order: ``id,row,col,lon,lat,h`` are required, ``sigma_px, band, ccd,
    score, kind`` optional (their defaults above apply to the whole column when it is absent).
    Numbers as Python's ``float`` reads them; blank lines are skipped; fields may be quoted
    (RFC 4180). Written with every column, floats in their shortest repr-exact form (reading
    them back gives the same float64 bit for bit) and ``\\n`` line ends.
GeoPackage (``*.gpkg``)
    OGC GeoPackage 1.3 [1]_ written and read by GDAL through :mod:`pyogrio` (its ``raw``
    numpy-array API: no pandas): one features layer (default name ``gcps``) in EPSG:4326 whose
    ``POINT Z`` geometry holds ``(lon, lat, h)`` and whose attribute columns hold every field
    above. On reading, the file must carry a GeoPackage ``application_id``, the attributes are
    authoritative and the geometry must agree with them (1e-9 degree, 1e-6 m); one SQL scan
    (run by GDAL) rejects NULLs and values of the wrong SQLite storage class, which GDAL would
    otherwise convert silently.
GeoTIFF (``*.tif``, ``*.tiff``)
    GDAL ground control points (GeoTIFF tie points) in EPSG:4326, readable by any GIS. GDAL's GCP
    ``(pixel, line)`` use the corner convention (``(0, 0)`` is the upper-left corner of the
    first pixel), the same as ours, so ``line = row`` and ``pixel = col`` with no shift. GeoTIFF
    tie points cannot carry ids or the other fields, so the whole table is also stored, as CSV
    text, in the GDAL metadata item ``GCP_TABLE_CSV`` of domain ``gcpcal`` (inside the TIFF);
    the reader uses it and checks it against the tie points. A GeoTIFF written by another tool
    (no such item) reads with ids from GDAL (``"1"``, ``"2"``, ...) and default optional fields.
    At most :data:`GEOTIFF_MAX_GCPS` (10922) points, GDAL's limit for the tie-point tag; use
    CSV or GeoPackage for more (or thin the table first).

Reading is strict: the first problem in the file (in file order) is raised as a one-line
:class:`~sensor_models.errors.InputError` naming the file, the place (CSV line number with the
header on line 1, GeoPackage feature id, GeoTIFF GCP number), the column and how many rows
share the problem. Validation is vectorized. Writing is atomic: a temporary file beside the
destination, renamed onto it at the end, so an error leaves no partial output (an existing
destination is left untouched).

References
----------
.. [1] Open Geospatial Consortium, "OGC GeoPackage Encoding Standard", version 1.3.1,
   OGC 12-128r18 (2021): sections 1.1.1 (SQLite container, ``application_id`` and
   ``user_version``), 1.1.2 (``gpkg_spatial_ref_sys``), 1.1.3 (``gpkg_contents``), 2.1.3
   (GeoPackageBinary geometry encoding), 2.1.5 (``gpkg_geometry_columns``), 2.1.6 (features
   tables).
.. [2] D. Hilbert, "Ueber die stetige Abbildung einer Linie auf ein Flaechenstueck",
   Mathematische Annalen 38, 459-460 (1891): the space-filling curve whose order
   :meth:`GcpTable.split_check` samples along (computed bit by bit, quadrant by quadrant, with
   the rotation that keeps each sub-curve's ends on its quadrant's corners).
"""

from __future__ import annotations

import csv
import io
import os
import re
import warnings
from dataclasses import dataclass
from operator import itemgetter
from pathlib import Path

import numpy as np

from sensor_models.files.atomic import temporary_beside
from sensor_models.errors import InputError

__all__ = [
    "COLUMNS",
    "GEOTIFF_MAX_GCPS",
    "OPTIONAL_COLUMNS",
    "REQUIRED_COLUMNS",
    "KINDS",
    "GcpTable",
    "read_gcps",
    "write_gcps_csv",
    "write_gcps_geotiff",
    "write_gcps_gpkg",
    "write_point_layer",
]

REQUIRED_COLUMNS = ("id", "row", "col", "lon", "lat", "h")
OPTIONAL_COLUMNS = ("sigma_px", "band", "ccd", "score", "kind")
COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
_FLOAT_COLUMNS = frozenset(("row", "col", "lon", "lat", "h", "sigma_px", "score"))
_DEFAULTS = {"sigma_px": 1.0, "band": "", "ccd": "", "score": 1.0, "kind": "gcp"}
KINDS = ("gcp", "check")

_CHUNK_ROWS = 65536  # rows formatted at a time by the CSV writer
_GPKG_APPLICATION_IDS = (0x47504B47, 0x47503130, 0x47503131)  # 'GPKG', 'GP10', 'GP11'
_TIFF_DOMAIN, _TIFF_ITEM = "gcpcal", "GCP_TABLE_CSV"
# GDAL writes at most 10922 GCPs into the GeoTIFF tie-point tag (6 doubles each, a uint16
# count: GDAL issue #10164, pull request #10166); beyond that it falls back to a .aux.xml file.
GEOTIFF_MAX_GCPS = 10922


# ---------------------------------------------------------------------------------------------
# The table
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GcpTable:
    """A table of N ground control points, one read-only ``(N,)`` array per column.

    Construction coerces every column (floats to float64, the rest to numpy unicode strings)
    and validates the values: finite numbers, ``lat`` in [-90, 90], ``lon`` in [-180, 360),
    ``sigma_px > 0``, ``kind`` in {"gcp", "check"}, non-empty unique ids, no leading or trailing
    spaces in ``id``/``band``/``ccd``. A violation raises
    :class:`~sensor_models.errors.InputError` naming the column and the first offending point.
    Prefer :meth:`from_arrays`, which fills the optional columns and the ids.

    Attributes
    ----------
    id : ndarray of str, shape (N,)
        Unique point identifiers.
    row, col : ndarray of float64, shape (N,)
        Continuous image coordinates, pixels; first pixel's centre at (0.5, 0.5).
    lon, lat : ndarray of float64, shape (N,)
        WGS84 longitude and latitude, degrees.
    h : ndarray of float64, shape (N,)
        Height above the WGS84 ellipsoid, metres.
    sigma_px : ndarray of float64, shape (N,)
        A priori standard deviation of the image measurement, pixels (default 1).
    band, ccd : ndarray of str, shape (N,)
        Band and CCD names (default "").
    score : ndarray of float64, shape (N,)
        Match quality (default 1).
    kind : ndarray of str, shape (N,)
        "gcp" or "check" (default "gcp").
    """

    id: np.ndarray
    row: np.ndarray
    col: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray
    sigma_px: np.ndarray
    band: np.ndarray
    ccd: np.ndarray
    score: np.ndarray
    kind: np.ndarray

    def __post_init__(self):
        cols = {name: _coerce(name, getattr(self, name)) for name in COLUMNS}
        n = cols["id"].shape[0]
        for name, arr in cols.items():
            if arr.shape != (n,):
                raise InputError(f"has shape {arr.shape}; every column must have shape ({n},) "
                                 "like 'id'", field=name)  # fmt: skip
        _validate(cols, where=lambda i: f"point {i} (id {str(cols['id'][i])!r})")
        for name, arr in cols.items():
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def _trusted(cls, cols: dict) -> GcpTable:
        """Build from columns already coerced to owned arrays and validated (no copy, no check)."""
        table = object.__new__(cls)
        for name in COLUMNS:
            arr = cols[name]
            arr.setflags(write=False)
            object.__setattr__(table, name, arr)
        return table

    @classmethod
    def from_arrays(cls, row, col, lon, lat, h, *, id=None, sigma_px=None, band=None, ccd=None,
                    score=None, kind=None) -> GcpTable:  # fmt: skip
        """A table from the required columns; every column but ``row`` may be a scalar (broadcast).

        Parameters
        ----------
        row : array_like, shape (N,)
            Image row (line) coordinates, pixels (first pixel's centre at 0.5).
        col : array_like, shape (N,) or scalar
            Image column (sample) coordinates, pixels.
        lon, lat, h : array_like, shape (N,) or scalar
            WGS84 degrees and metres above the ellipsoid.
        id : array_like of str, shape (N,), optional
            Default ``"g000001"``, ``"g000002"``, ... (at least six digits).
        sigma_px, band, ccd, score, kind : scalar or array_like, shape (N,), optional
            Defaults 1.0, "", "", 1.0, "gcp".

        Returns
        -------
        GcpTable
        """
        row = np.atleast_1d(np.asarray(row))
        n = row.shape[0] if row.ndim == 1 else -1
        if id is None:
            id = np.char.add("g", np.char.zfill(np.arange(1, max(n, 0) + 1).astype(str), 6))
        given = {"col": col, "lon": lon, "lat": lat, "h": h, "sigma_px": sigma_px, "band": band,
                 "ccd": ccd, "score": score, "kind": kind}  # fmt: skip
        cols = {}
        for name, value in given.items():
            value = _DEFAULTS[name] if value is None and name in _DEFAULTS else value
            if np.ndim(value) == 0 and n >= 0:
                value = np.full(n, value, dtype=np.float64 if name in _FLOAT_COLUMNS else object)
            cols[name] = value
        return cls(id=id, row=row, **cols)

    # -- helpers ------------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.id.shape[0])

    def __repr__(self) -> str:
        n_check = int(np.count_nonzero(self.kind == "check"))
        return f"GcpTable({len(self)} points: {len(self) - n_check} gcp, {n_check} check)"

    def as_dict(self) -> dict[str, np.ndarray]:
        """The columns, in :data:`COLUMNS` order, as a ``{name: (N,) array}`` dict.

        Returns
        -------
        dict of str to ndarray, each shape (N,)
            The table's own read-only arrays (no copy).
        """
        return {name: getattr(self, name) for name in COLUMNS}

    def select(self, which) -> GcpTable:
        """The points picked by a boolean mask of shape (N,) or by integer indices.

        Parameters
        ----------
        which : array_like of bool, shape (N,), or of int, shape (M,)
            Mask or indices (indices may repeat only if the ids stay unique).

        Returns
        -------
        GcpTable
            The picked points, in mask order or index order.
        """
        which = np.asarray(which)
        if which.dtype == bool:
            if which.shape != (len(self),):
                raise InputError(f"boolean mask has shape {which.shape}, expected ({len(self)},)")
            return GcpTable._trusted({k: v[which] for k, v in self.as_dict().items()})
        if which.size and not np.issubdtype(which.dtype, np.integer):
            raise InputError(f"select() takes a boolean mask or integer indices, got {which.dtype}")
        which = which.astype(np.intp).reshape(-1)
        return GcpTable(**{k: v[which] for k, v in self.as_dict().items()})  # ids checked unique

    def gcps(self) -> GcpTable:
        """The points of kind "gcp" (the ones a fit may use).

        Returns
        -------
        GcpTable
        """
        return self.select(self.kind == "gcp")

    def checks(self) -> GcpTable:
        """The points of kind "check" (independent check points).

        Returns
        -------
        GcpTable
        """
        return self.select(self.kind == "check")

    @classmethod
    def concatenate(cls, tables) -> GcpTable:
        """One table holding the points of ``tables`` in order; ids must stay unique.

        Parameters
        ----------
        tables : iterable of GcpTable
            At least one table.

        Returns
        -------
        GcpTable
        """
        tables = list(tables)
        if not tables:
            raise InputError("concatenate() needs at least one table")
        for t in tables:
            if not isinstance(t, GcpTable):
                raise InputError(f"concatenate() takes GcpTable objects, got {type(t).__name__}")
        return cls(**{k: np.concatenate([getattr(t, k) for t in tables]) for k in COLUMNS})

    def split_check(self, fraction: float, *, seed, stratify_by=("band", "ccd")) -> GcpTable:
        """Mark a spatially spread, random ``fraction`` of the points as check points.

        Every point's kind is reassigned: the chosen points become "check", all others "gcp".
        Points are grouped into strata by the ``stratify_by`` columns (by default one stratum
        per band and CCD). In a stratum of ``n`` points, ``k = floor(fraction * n + 1/2)``
        check points (at most ``n - 1``, so each stratum keeps a GCP) are drawn by stratified
        sampling along a Hilbert curve: the points are ordered along the curve over their
        ``(row, col)`` bounding box ([2]_), the ordered sequence is cut into ``k``
        consecutive runs of equal length (+-1), and one point is drawn uniformly from each run.
        Since consecutive runs of a Hilbert ordering cover compact neighbouring regions, the
        check points cover the image evenly (like one point per cell of an adaptive grid),
        unlike a plain random draw, which leaves holes and clusters.

        Parameters
        ----------
        fraction : float
            Wanted share of check points, in [0, 1).
        seed : int or numpy.random.Generator
            Seed of the draw (required: the split is reproducible).
        stratify_by : sequence of str
            Columns among "band", "ccd" defining the strata; ``()`` for one stratum.

        Returns
        -------
        GcpTable
            A copy of this table with ``kind`` set.
        """
        fraction = float(fraction)
        if not 0.0 <= fraction < 1.0:
            raise InputError(f"fraction must be in [0, 1), got {fraction}")
        stratify_by = tuple(stratify_by)
        for name in stratify_by:
            if name not in ("band", "ccd"):
                raise InputError(f"stratify_by takes 'band' and/or 'ccd', got {name!r}")
        rng = np.random.default_rng(seed)
        n = len(self)
        stratum = np.zeros(n, dtype=np.intp)
        for name in stratify_by:
            _, codes = np.unique(getattr(self, name), return_inverse=True)
            stratum = stratum * (int(codes.max(initial=0)) + 1) + codes.reshape(-1)
        is_check = np.zeros(n, dtype=bool)
        for s in np.unique(stratum):
            members = np.flatnonzero(stratum == s)
            k = min(int(np.floor(fraction * members.size + 0.5)), members.size - 1)
            if k <= 0:
                continue
            order = members[np.argsort(_hilbert_key(self.row[members], self.col[members]),
                                       kind="stable")]  # fmt: skip
            edges = (np.arange(k + 1) * members.size) // k
            pick = edges[:-1] + (rng.random(k) * np.diff(edges)).astype(np.intp)
            is_check[order[pick]] = True
        cols = self.as_dict()
        cols["kind"] = np.where(is_check, "check", "gcp")
        return GcpTable._trusted(cols)


def _coerce(name: str, values) -> np.ndarray:
    """An owned 1-D array of the column's dtype (float64, or numpy unicode for text)."""
    try:
        if name in _FLOAT_COLUMNS:
            arr = np.array(values, dtype=np.float64)
        else:
            arr = np.array(values)
            if arr.dtype.kind != "U":
                if arr.dtype.kind == "S":
                    arr = np.char.decode(arr, "utf-8")
                elif arr.dtype.kind in "iuO" and arr.size:
                    arr = arr.astype(str)
                elif arr.size == 0:
                    arr = arr.astype("U1")
                else:
                    raise TypeError(f"got dtype {arr.dtype}")
    except (TypeError, ValueError) as err:
        kind = "float64" if name in _FLOAT_COLUMNS else "text"
        raise InputError(f"cannot be converted to {kind}: {err}", field=name) from None
    if arr.ndim != 1:
        raise InputError(f"must be one-dimensional, got shape {arr.shape}", field=name)
    return arr


def _hilbert_key(row: np.ndarray, col: np.ndarray, order: int = 16) -> np.ndarray:
    """Position along a Hilbert curve of ``2**order`` cells a side over the points' bounding box.

    Parameters
    ----------
    row, col : ndarray, shape (N,)
        Coordinates (any units).
    order : int
        Bits per axis (<= 31).

    Returns
    -------
    ndarray of int64, shape (N,)
        Keys in [0, 4**order); consecutive keys are edge-adjacent cells.
    """
    side = 1 << order

    def quantize(v):
        lo, span = v.min(), np.ptp(v)
        if span == 0:
            return np.zeros(v.shape, dtype=np.int64)
        return np.minimum(((v - lo) / span * side).astype(np.int64), side - 1)

    x, y = quantize(np.asarray(col, dtype=np.float64)), quantize(np.asarray(row, dtype=np.float64))
    key = np.zeros(x.shape, dtype=np.int64)
    s = side >> 1
    while s > 0:
        rx = (x & s) > 0
        ry = (y & s) > 0
        key += s * s * ((3 * rx) ^ ry)
        # rotate the quadrant so that the sub-curve starts and ends at the right corners
        flip = ~ry & rx
        x = np.where(flip, side - 1 - x, x)
        y = np.where(flip, side - 1 - y, y)
        x, y = np.where(ry, x, y), np.where(ry, y, x)
        s >>= 1
    return key


# ---------------------------------------------------------------------------------------------
# Validation (shared by the constructor and the readers)
# ---------------------------------------------------------------------------------------------
def _first(mask: np.ndarray):
    """(first index, count) of the True entries of ``mask``, or None."""
    bad = np.flatnonzero(mask)
    return None if bad.size == 0 else (int(bad[0]), int(bad.size))


def _fmt(x) -> str:
    return repr(float(x))


def _validate(cols: dict, *, where, path=None, image_shape=None, problems=()) -> None:
    """Raise the first (in point order) problem of the coerced columns as an InputError.

    ``where(i)`` names point ``i`` in the message (e.g. ``"line 7"``). ``problems`` holds the
    parse errors already found, as ``(index, column order, column, message, count)`` tuples;
    at the same point and column they win over the checks here.
    """
    problems = list(problems)

    def add(name, found, message):
        if found is not None:
            i, count = found
            problems.append((i, COLUMNS.index(name), name, message(i), count))

    ids = cols["id"]
    add("id", _first(np.char.str_len(ids) == 0), lambda i: "empty id")
    for name in ("id", "band", "ccd"):
        a = cols[name]
        add(name, _first(np.char.strip(a) != a),
            lambda i, a=a, name=name: f"{name} {str(a[i])!r} has leading or trailing spaces")
    for name in ("row", "col", "lon", "lat", "h", "sigma_px", "score"):
        a = cols[name]
        add(name, _first(~np.isfinite(a)),
            lambda i, a=a, name=name: f"{name} = {_fmt(a[i])}: NaN and infinity are not allowed")
    lat, lon, sigma = cols["lat"], cols["lon"], cols["sigma_px"]
    add("lat", _first((lat < -90.0) | (lat > 90.0)),
        lambda i: f"lat = {_fmt(lat[i])} is outside [-90, 90] degrees")
    add("lon", _first((lon < -180.0) | (lon >= 360.0)),
        lambda i: f"lon = {_fmt(lon[i])} is outside [-180, 360) degrees")
    add("sigma_px", _first(sigma <= 0.0),
        lambda i: f"sigma_px = {_fmt(sigma[i])} must be > 0 pixels")
    kind = cols["kind"]
    add("kind", _first(~np.isin(kind, KINDS)),
        lambda i: f"kind {str(kind[i])!r} must be 'gcp' or 'check'")
    if image_shape is not None:
        for name, size in (("row", image_shape[0]), ("col", image_shape[1])):
            a = cols[name]
            add(name, _first((a < 0.0) | (a > size)),
                lambda i, a=a, name=name, size=size: f"{name} = {_fmt(a[i])} is outside the "
                f"image [0, {size}] (image_shape {tuple(image_shape)})")
    if not problems:
        dup = _first_duplicate(ids)
        if dup is None:
            return
        first, repeat, count = dup
        problems.append((repeat, 0, "id", f"id {str(ids[repeat])!r} is already used at "
                                            f"{where(first)}", count))  # fmt: skip
    i, _, name, message, count = min(problems, key=itemgetter(0, 1))  # stable: parse errors first
    more = f" ({count} rows have this problem)" if count > 1 else ""
    raise InputError(f"{where(i)}: {message}{more}", path=path, field=name)


def _first_duplicate(ids: np.ndarray):
    """(index of the first occurrence, index of the earliest repeat, number of repeats) or None."""
    if len(set(ids.tolist())) == ids.size:
        return None
    order = np.argsort(ids, kind="stable")
    s = ids[order]
    new_group = np.r_[True, s[1:] != s[:-1]]
    group_start = np.flatnonzero(new_group)[np.cumsum(new_group) - 1]
    repeats = order[~new_group]
    firsts = order[group_start[~new_group]]
    j = int(np.argmin(repeats))
    return int(firsts[j]), int(repeats[j]), int(repeats.size)


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------
def read_gcps(path, *, image_shape=None, layer=None) -> GcpTable:
    """Read a GCP table from CSV (``*.csv``), GeoPackage (``*.gpkg``) or GeoTIFF (``*.tif``).

    Parameters
    ----------
    path : str or Path
        The file; its extension selects the format.
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``: points outside ``[0, n_rows] x [0, n_cols]`` are errors. For a
        GeoTIFF the raster's own shape is used when not given (and must agree when given).
    layer : str, optional
        GeoPackage only: the features layer. Default: the only one, else ``"gcps"``.

    Returns
    -------
    GcpTable

    Raises
    ------
    InputError
        One line naming the file, the place (CSV line number, header = line 1; GeoPackage
        feature id; GeoTIFF GCP number), the column and the problem.
    """
    path = Path(path)
    image_shape = _check_image_shape(image_shape)
    suffix = path.suffix.lower()
    if layer is not None and suffix != ".gpkg":
        raise InputError("layer= applies to GeoPackage (*.gpkg) files only", path=str(path))
    if suffix == ".csv":
        return _read_csv_bytes(_read_bytes(path), str(path), image_shape)
    if suffix == ".gpkg":
        return _read_gpkg(path, image_shape, layer)
    if suffix in (".tif", ".tiff"):
        return _read_geotiff(path, image_shape)
    raise InputError("unknown GCP table format; expected *.csv, *.gpkg, *.tif or *.tiff",
                     path=str(path))  # fmt: skip


def _check_image_shape(image_shape):
    if image_shape is None:
        return None
    try:
        n_rows, n_cols = (int(v) for v in image_shape)
        ok = (n_rows, n_cols) == tuple(image_shape) and n_rows > 0 and n_cols > 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(f"image_shape must be two positive integers (n_rows, n_cols), "
                         f"got {image_shape!r}")  # fmt: skip
    return n_rows, n_cols


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None


def _read_csv_bytes(data: bytes, source: str, image_shape) -> GcpTable:
    """Parse and validate CSV bytes; ``source`` names the file in messages."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"line {line}: not UTF-8 text ({exc.reason})", path=source) from None
    if "\x00" in text:
        line = text.count("\n", 0, text.index("\x00")) + 1
        raise InputError(f"line {line}: NUL byte; this is not a CSV text file", path=source)
    if not text.strip():
        raise InputError(f"empty file; expected the header line {','.join(REQUIRED_COLUMNS)}"
                         f"[,{','.join(OPTIONAL_COLUMNS)}] and data rows", path=source)  # fmt: skip
    if '"' in text:  # quoted fields: the csv module
        names, fields, lines = _split_quoted(text, source)
    else:  # no quotes: split on byte positions, vectorized
        first_line = text.split("\n", 1)[0].rstrip("\r")
        names = _header(first_line.split(",") if first_line.strip() else [], source)
        fields, lines = _split_plain(data, len(names), source)
    if lines.size == 0:
        raise InputError("no data rows after the header (line 1)", path=source)
    cols, problems = _columns_from_text(names, fields, lines)
    _validate(cols, where=lambda i: f"line {lines[i]}", path=source, image_shape=image_shape,
              problems=problems)  # fmt: skip
    return GcpTable._trusted(cols)


def _header(fields: list[str], source: str) -> list[str]:
    """Check the header's column names (line 1) and return them, stripped."""
    names = [name.strip() for name in fields]
    if not any(names):
        raise InputError("line 1: empty header; expected column names "
                         f"{','.join(REQUIRED_COLUMNS)}[,...]", path=source)  # fmt: skip
    for j, name in enumerate(names):
        if name not in COLUMNS:
            raise InputError(f"line 1: unknown column {name!r} (header column {j + 1}); columns "
                             f"are {', '.join(COLUMNS)}", path=source, field=name)  # fmt: skip
        if name in names[:j]:
            raise InputError(f"line 1: column {name!r} appears twice in the header (columns "
                             f"{names.index(name) + 1} and {j + 1})", path=source,
                             field=name)  # fmt: skip
    for name in REQUIRED_COLUMNS:
        if name not in names:
            raise InputError(f"line 1: missing required column {name!r}; the header must name "
                             f"{', '.join(REQUIRED_COLUMNS)}", path=source, field=name)  # fmt: skip
    return names


def _split_plain(data: bytes, ncol: int, source: str):
    """Fields of a quote-free CSV as fixed-width byte-string arrays, plus 1-based line numbers.

    Returns
    -------
    fields : list of ndarray of bytes (S), each shape (N,)
        Column ``j`` of every data record, as written (not stripped).
    lines : ndarray of int64, shape (N,)
        Line number of each record (header = line 1; blank lines skipped).
    """
    b = np.frombuffer(data, dtype=np.uint8)
    newline = np.flatnonzero(b == 10)
    if b.size and b[-1] != 10:
        newline = np.append(newline, b.size)
    start = np.r_[0, newline[:-1] + 1]
    end = newline.copy()
    end[(end > start) & (b[np.maximum(end - 1, 0)] == 13)] -= 1  # CRLF
    commas = np.flatnonzero(b == 44)
    first_comma = np.searchsorted(commas, start)
    n_commas = np.searchsorted(commas, end) - first_comma
    data_line = end > start
    data_line[0] = False  # the header
    wrong = data_line & (n_commas != ncol - 1)
    if wrong.any():
        i = int(np.flatnonzero(wrong)[0])
        raise InputError(f"line {i + 1}: {_fields(n_commas[i] + 1)}, but the header (line 1) "
                         f"has {ncol} columns", path=source)  # fmt: skip
    rec = np.flatnonzero(data_line)
    if rec.size == 0:
        return [], rec.astype(np.int64)
    comma_at = commas[first_comma[rec][:, None] + np.arange(ncol - 1)]  # (N, ncol-1)
    starts = np.concatenate([start[rec][:, None], comma_at + 1], axis=1)
    ends = np.concatenate([comma_at, end[rec][:, None]], axis=1)
    width = int((ends - starts).max())
    padded = np.concatenate([b, np.zeros(max(width, 1), dtype=np.uint8)])
    fields = [_gather(padded, starts[:, j], ends[:, j]) for j in range(ncol)]
    return fields, rec.astype(np.int64) + 1


def _fields(k) -> str:
    return f"{k} field" if k == 1 else f"{k} fields"


def _gather(buf: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """The byte strings ``buf[start[i]:end[i]]`` as an (N,) ``S<w>`` array (buf zero-padded)."""
    length = end - start
    w = max(int(length.max()), 1)
    windows = np.lib.stride_tricks.sliding_window_view(buf, w)[start]  # (N, w) copy
    windows *= np.arange(w) < length[:, None]  # zero the bytes past each field's end
    return windows.view(f"S{w}").reshape(-1)


def _split_quoted(text: str, source: str):
    """Header names, per-column unicode arrays and line numbers through the csv module."""
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        names = _header(next(reader), source)
        ncol = len(names)
        records, lines = [], []
        for rec in reader:
            if not rec:
                continue
            if len(rec) != ncol:
                raise InputError(f"line {reader.line_num}: {_fields(len(rec))}, but the header "
                                 f"(line 1) has {ncol} columns", path=source)  # fmt: skip
            records.append(rec)
            lines.append(reader.line_num)
    except csv.Error as exc:
        raise InputError(f"line {reader.line_num}: malformed CSV ({exc})", path=source) from None
    fields = [np.array(col) for col in zip(*records)] if records else []
    return names, fields, np.asarray(lines, dtype=np.int64)


def _columns_from_text(names, fields, lines):
    """Typed columns (defaults filled) from raw field arrays, and the parse errors.

    A numeric column that does not parse yields one problem, at its first bad field; its values
    before that field are kept and the rest set to 1.0 (a value every check accepts), so the
    validation that follows still finds any earlier problem.
    """
    n = lines.size
    raw = dict(zip(names, fields))
    cols, problems = {}, []
    for order, name in enumerate(COLUMNS):
        if name not in raw:
            cols[name] = _default_column(name, n)
            continue
        a = raw[name]
        if name in _FLOAT_COLUMNS:
            try:
                cols[name] = a.astype(np.float64)
            except ValueError:
                i = _first_unparsable(a)
                value = a[i].decode() if isinstance(a[i], bytes) else str(a[i])
                what = "empty value" if not value.strip() else f"{value.strip()!r} is not a number"
                problems.append((i, order, name, f"{what}; {name} must be a number", 1))
                cols[name] = np.ones(n)
                cols[name][:i] = a[:i].astype(np.float64)
        else:
            a = np.char.strip(a)
            if a.dtype.kind == "S":
                a = a.astype("U") if a.tobytes().isascii() else np.char.decode(a, "utf-8")
            cols[name] = a
    return cols, problems


def _default_column(name: str, n: int) -> np.ndarray:
    """An absent optional column: its default, ``n`` times."""
    default = _DEFAULTS[name]
    if name in _FLOAT_COLUMNS:
        return np.full(n, default, dtype=np.float64)
    return np.full(n, default, dtype=f"U{max(len(default), 1)}")


def _first_unparsable(a: np.ndarray) -> int:
    """Index of the first element of a string array that does not convert to float64."""
    step = 4096
    for lo in range(0, a.size, step):
        try:
            a[lo:lo + step].astype(np.float64)
        except ValueError:
            for i in range(lo, min(lo + step, a.size)):
                try:
                    a[i:i + 1].astype(np.float64)
                except ValueError:
                    return i
    raise AssertionError("no unparsable element")  # pragma: no cover


# -- GeoPackage -------------------------------------------------------------------------------
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


def _read_gpkg(path: Path, image_shape, layer) -> GcpTable:
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
    _validate(cols, where=where, path=source, image_shape=image_shape)
    return GcpTable._trusted(cols)


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
        allowed = _OGR_NUMBER if name in _FLOAT_COLUMNS else _OGR_TEXT
        if ogr_type not in allowed:
            what = "a number" if name in _FLOAT_COLUMNS else "text"
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
        allowed = ("'real', 'integer'" if name in _FLOAT_COLUMNS else
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
        ok = (storage in ("real", "integer") if name in _FLOAT_COLUMNS
              else storage in ("text", "integer") or (storage == "null" and name in ("band", "ccd")))
        if not ok:
            what = "NULL" if storage == "null" else f"{text!r} is not a " + (
                "number" if name in _FLOAT_COLUMNS else "text")  # fmt: skip
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
        if name in _FLOAT_COLUMNS:
            cols[name] = np.ascontiguousarray(column, dtype=np.float64)
        else:
            cols[name] = np.char.strip(_text_column(column))
    for name in COLUMNS:
        if name not in cols:
            cols[name] = _default_column(name, fids.size)
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
        found = _first(off)
        if found is not None:
            i, count = found
            raise InputError(f"{where(i)}: the point geometry's {'xyz'[k]} = {_fmt(xyz[i, k])} "
                             f"differs from the attribute {name} = {_fmt(v[i])} ({count} "
                             "features); the attributes define the GCPs: edit them, not the "
                             "geometry",
                             path=source, field=name)  # fmt: skip


# -- GeoTIFF ----------------------------------------------------------------------------------
def _read_geotiff(path: Path, image_shape) -> GcpTable:
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
            cols[name] = _default_column(name, n)
        _validate(cols, where=lambda i: f"GCP {i + 1}", path=source, image_shape=shape)
        return GcpTable._trusted(cols)
    table = _read_csv_bytes(stored.encode("utf-8"), f"{source} [metadata {_TIFF_DOMAIN}:"
                            f"{_TIFF_ITEM}]", shape)  # fmt: skip
    if len(table) != len(gcps):
        raise InputError(f"holds {len(gcps)} GDAL GCPs but its gcpcal table has {len(table)} "
                         "rows; the GCPs were edited by another tool", path=source)  # fmt: skip
    for name, values in gdal.items():
        found = _first(getattr(table, name) != values)
        if found is not None:
            i, count = found
            raise InputError(f"GCP {i + 1}: the GDAL GCP's {name} = {_fmt(values[i])} differs "
                             f"from the gcpcal table's {_fmt(getattr(table, name)[i])} ({count} "
                             "GCPs); the GCPs were edited by another tool", path=source,
                             field=name)  # fmt: skip
    return table


# ---------------------------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------------------------
def _check_output(table, path) -> Path:
    if not isinstance(table, GcpTable):
        raise InputError(f"expected a GcpTable, got {type(table).__name__}")
    path = Path(path)
    if len(table) == 0:
        raise InputError("the GCP table is empty; nothing to write", path=str(path))
    if not path.parent.is_dir():
        raise InputError(f"folder {str(path.parent)!r} does not exist", path=str(path))
    return path


def _csv_text_field(a: np.ndarray) -> np.ndarray:
    """Text column ready for CSV: fields holding , " CR or LF quoted per RFC 4180."""
    special = np.zeros(a.shape, dtype=bool)
    for ch in (",", '"', "\n", "\r"):
        special |= np.char.find(a, ch) >= 0
    if not special.any():
        return a
    out = a.astype(object)
    out[special] = ['"' + s.replace('"', '""') + '"' for s in a[special].tolist()]
    return out


def _csv_chunks(table: GcpTable):
    """The CSV text of ``table`` in pieces of :data:`_CHUNK_ROWS` rows (header first)."""
    yield ",".join(COLUMNS) + "\n"
    cols = [(_csv_text_field(a) if a.dtype.kind == "U" else a) for a in table.as_dict().values()]
    ncol = len(cols)
    row_fmt = ",".join("%r" if name in _FLOAT_COLUMNS else "%s" for name in COLUMNS) + "\n"
    for lo in range(0, len(table), _CHUNK_ROWS):
        m = min(_CHUNK_ROWS, len(table) - lo)
        flat = [None] * (m * ncol)
        for j, a in enumerate(cols):
            flat[j::ncol] = a[lo:lo + m].tolist()  # floats: repr() is shortest round-trip
        yield (row_fmt * m) % tuple(flat)


def write_gcps_csv(table: GcpTable, path) -> Path:
    """Write ``table`` as CSV, every column, floats repr-exact; atomically.

    Parameters
    ----------
    table : GcpTable
        At least one point.
    path : str or Path
        Destination; its folder must exist. Written to a temporary file beside it, then
        renamed: on any error nothing is left and an existing file is untouched.

    Returns
    -------
    Path
        ``path``.
    """
    path = _check_output(table, path)
    tmp = temporary_beside(path, ".csv")
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            for piece in _csv_chunks(table):
                fh.write(piece)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


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
    path = _check_output(table, path)
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


def write_gcps_geotiff(table: GcpTable, path, *, image_shape, source_raster=None, source_band=None) -> Path:
    """Write ``table`` as GDAL GCPs (EPSG:4326) inside a GeoTIFF; atomically.

    GDAL GCP ``line = row`` and ``pixel = col`` (both corner based, see the module notes),
    ``x = lon``, ``y = lat``, ``z = h``; the full table is also stored as CSV text in the
    metadata item ``GCP_TABLE_CSV`` of domain ``gcpcal``, since GeoTIFF tie points keep neither
    ids nor the other fields.

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
    path = _check_output(table, path)
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
    image_shape = _check_image_shape(image_shape)
    if image_shape is None:
        raise InputError("image_shape (n_rows, n_cols) is required", path=str(path))
    if len(table) > GEOTIFF_MAX_GCPS:
        raise InputError(f"{len(table)} points; a GeoTIFF holds at most {GEOTIFF_MAX_GCPS} GCPs "
                         "(GDAL's tie-point tag limit): write CSV or GeoPackage, or thin the "
                         "table", path=str(path))  # fmt: skip
    _validate(table.as_dict(), where=lambda i: f"point {i} (id {str(table.id[i])!r})",
              path=str(path), image_shape=image_shape)  # fmt: skip
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
        if n_written != len(table):  # never leave a file with GCPs silently dropped
            raise InputError(f"GDAL kept {n_written} of {len(table)} GCPs in the GeoTIFF",
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
    gcps = [GroundControlPoint(row=r, col=c, x=x, y=y, z=z, id=i, info=k)
            for r, c, x, y, z, i, k in zip(table.row.tolist(), table.col.tolist(),
                                           table.lon.tolist(), table.lat.tolist(),
                                           table.h.tolist(), table.id.tolist(),
                                           table.kind.tolist())]  # fmt: skip
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
        dst.update_tags(ns=_TIFF_DOMAIN, **{_TIFF_ITEM: "".join(_csv_chunks(table))})


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
