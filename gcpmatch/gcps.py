"""Ground control point (GCP) tables: the :class:`GcpTable` type and the checks of its columns.

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

Files
-----
A table is read from CSV, GeoPackage or GeoTIFF by :func:`gcpmatch.gcp_files.read_gcps` and
written by :func:`gcpmatch.gcp_csv.write_gcps_csv`, :func:`gcpmatch.geopackage.write_gcps_gpkg`
and :func:`gcpmatch.gcp_geotiff.write_gcps_geotiff` (each module documents its format). The
readers share the checks here (:func:`validate_columns`): reading is strict, the first problem
in the file (in file order) is raised as a one-line :class:`~sensor_models.errors.InputError`
naming the file, the place (CSV line number with the header on line 1, GeoPackage feature id,
GeoTIFF GCP number), the column and how many rows share the problem. Validation is vectorized.
The writers share :func:`check_output`; writing is atomic: a temporary file beside the
destination, renamed onto it at the end, so an error leaves no partial output (an existing
destination is left untouched).

References
----------
.. [1] D. Hilbert, "Ueber die stetige Abbildung einer Linie auf ein Flaechenstueck",
   Mathematische Annalen 38, 459-460 (1891): the space-filling curve whose order
   :meth:`GcpTable.split_check` samples along (computed bit by bit, quadrant by quadrant, with
   the rotation that keeps each sub-curve's ends on its quadrant's corners).
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import itemgetter
from pathlib import Path

import numpy as np

from sensor_models.errors import InputError

__all__ = ["COLUMNS", "FLOAT_COLUMNS", "KINDS", "OPTIONAL_COLUMNS", "REQUIRED_COLUMNS", "GcpTable",
           "check_image_shape", "check_output", "default_column", "first_flagged", "format_float",
           "validate_columns"]

REQUIRED_COLUMNS = ("id", "row", "col", "lon", "lat", "h")
OPTIONAL_COLUMNS = ("sigma_px", "band", "ccd", "score", "kind")
COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
#: The numeric columns (float64); the others hold text.
FLOAT_COLUMNS = frozenset(("row", "col", "lon", "lat", "h", "sigma_px", "score"))
_DEFAULTS = {"sigma_px": 1.0, "band": "", "ccd": "", "score": 1.0, "kind": "gcp"}
KINDS = ("gcp", "check")


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
        validate_columns(cols, where=lambda i: f"point {i} (id {str(cols['id'][i])!r})")
        for name, arr in cols.items():
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def from_validated_columns(cls, cols: dict) -> GcpTable:
        """Build from columns already coerced to owned arrays and validated (no copy, no check).

        For the readers, which parse a file into typed columns and run
        :func:`validate_columns` on them with the file's own place names (line numbers,
        feature ids); anything else should call the constructor or :meth:`from_arrays`.

        Parameters
        ----------
        cols : dict of str to ndarray, each shape (N,)
            Every column of :data:`COLUMNS`: float64 for :data:`FLOAT_COLUMNS`, numpy unicode
            for the others; the arrays become the table's own (made read-only).

        Returns
        -------
        GcpTable
        """
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
                value = np.full(n, value, dtype=np.float64 if name in FLOAT_COLUMNS else object)
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
            return GcpTable.from_validated_columns({k: v[which] for k, v in self.as_dict().items()})
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
        return GcpTable.from_validated_columns(cols)


def _coerce(name: str, values) -> np.ndarray:
    """An owned 1-D array of the column's dtype (float64, or numpy unicode for text)."""
    try:
        if name in FLOAT_COLUMNS:
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
        kind = "float64" if name in FLOAT_COLUMNS else "text"
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
def first_flagged(mask: np.ndarray):
    """(first index, count) of the True entries of ``mask``, or None.

    Parameters
    ----------
    mask : ndarray of bool, shape (N,)
        The points that have a problem.

    Returns
    -------
    (int, int) or None
        Index of the first flagged point and the number of flagged points; None if none is.
    """
    bad = np.flatnonzero(mask)
    return None if bad.size == 0 else (int(bad[0]), int(bad.size))


def format_float(x) -> str:
    """A number as error messages show it: ``repr(float(x))``, the shortest exact form.

    Parameters
    ----------
    x : float or numpy scalar

    Returns
    -------
    str
    """
    return repr(float(x))


def validate_columns(cols: dict, *, where, path=None, image_shape=None, problems=()) -> None:
    """Raise the first (in point order) problem of the coerced columns as an InputError.

    ``where(i)`` names point ``i`` in the message (e.g. ``"line 7"``). ``problems`` holds the
    parse errors already found, as ``(index, column order, column, message, count)`` tuples;
    at the same point and column they win over the checks here.

    Parameters
    ----------
    cols : dict of str to ndarray, each shape (N,)
        Every column of :data:`COLUMNS`, coerced (float64 or numpy unicode).
    where : callable
        ``where(i) -> str``: the place of point ``i`` in messages.
    path : str, optional
        The file named in the error.
    image_shape : (int, int), optional
        ``(n_rows, n_cols)``: points outside ``[0, n_rows] x [0, n_cols]`` are errors.
    problems : sequence of tuple
        Parse errors already found (see above).

    Raises
    ------
    InputError
        The first problem, with the number of points that share it.
    """
    problems = list(problems)

    def add(name, found, message):
        if found is not None:
            i, count = found
            problems.append((i, COLUMNS.index(name), name, message(i), count))

    ids = cols["id"]
    add("id", first_flagged(np.char.str_len(ids) == 0), lambda i: "empty id")
    for name in ("id", "band", "ccd"):
        a = cols[name]
        add(name, first_flagged(np.char.strip(a) != a),
            lambda i, a=a, name=name: f"{name} {str(a[i])!r} has leading or trailing spaces")
    for name in ("row", "col", "lon", "lat", "h", "sigma_px", "score"):
        a = cols[name]
        add(name, first_flagged(~np.isfinite(a)),
            lambda i, a=a, name=name: f"{name} = {format_float(a[i])}: NaN and infinity are not "
            "allowed")
    lat, lon, sigma = cols["lat"], cols["lon"], cols["sigma_px"]
    add("lat", first_flagged((lat < -90.0) | (lat > 90.0)),
        lambda i: f"lat = {format_float(lat[i])} is outside [-90, 90] degrees")
    add("lon", first_flagged((lon < -180.0) | (lon >= 360.0)),
        lambda i: f"lon = {format_float(lon[i])} is outside [-180, 360) degrees")
    add("sigma_px", first_flagged(sigma <= 0.0),
        lambda i: f"sigma_px = {format_float(sigma[i])} must be > 0 pixels")
    kind = cols["kind"]
    add("kind", first_flagged(~np.isin(kind, KINDS)),
        lambda i: f"kind {str(kind[i])!r} must be 'gcp' or 'check'")
    if image_shape is not None:
        for name, size in (("row", image_shape[0]), ("col", image_shape[1])):
            a = cols[name]
            add(name, first_flagged((a < 0.0) | (a > size)),
                lambda i, a=a, name=name, size=size: f"{name} = {format_float(a[i])} is outside "
                f"the image [0, {size}] (image_shape {tuple(image_shape)})")
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


def check_image_shape(image_shape):
    """The ``image_shape`` argument of a reader or writer, checked.

    Parameters
    ----------
    image_shape : (int, int) or None
        ``(n_rows, n_cols)`` of the image the points refer to.

    Returns
    -------
    (int, int) or None
        ``(n_rows, n_cols)`` as Python ints; None when not given.

    Raises
    ------
    InputError
        Not two positive integers.
    """
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


def default_column(name: str, n: int) -> np.ndarray:
    """An absent optional column: its default, ``n`` times.

    Parameters
    ----------
    name : str
        One of :data:`OPTIONAL_COLUMNS`.
    n : int
        Number of points.

    Returns
    -------
    ndarray, shape (n,)
        float64 for a numeric column, numpy unicode for text.
    """
    default = _DEFAULTS[name]
    if name in FLOAT_COLUMNS:
        return np.full(n, default, dtype=np.float64)
    return np.full(n, default, dtype=f"U{max(len(default), 1)}")


# ---------------------------------------------------------------------------------------------
# Writing (shared by the writers)
# ---------------------------------------------------------------------------------------------
def check_output(table, path) -> Path:
    """Check a writer's arguments: a non-empty :class:`GcpTable` and a path in an existing folder.

    Parameters
    ----------
    table : GcpTable
        The table to write.
    path : str or Path
        Destination file.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        Not a GcpTable, an empty table, or the destination's folder does not exist.
    """
    if not isinstance(table, GcpTable):
        raise InputError(f"expected a GcpTable, got {type(table).__name__}")
    path = Path(path)
    if len(table) == 0:
        raise InputError("the GCP table is empty; nothing to write", path=str(path))
    if not path.parent.is_dir():
        raise InputError(f"folder {str(path.parent)!r} does not exist", path=str(path))
    return path


