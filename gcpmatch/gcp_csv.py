"""GCP tables as CSV text: the strict, vectorized reader and the repr-exact, atomic writer.

Format (``*.csv``)
------------------
UTF-8 (an optional byte-order mark is skipped), comma separated, header on line 1 naming the
columns in any order: ``id,row,col,lon,lat,h`` are required, ``sigma_px, band, ccd, score,
kind`` optional (their defaults, :mod:`gcpmatch.gcps`, apply to the whole column when it is
absent). Numbers as Python's ``float`` reads them; blank lines are skipped; fields may be quoted
(RFC 4180). Written with every column, floats in their shortest repr-exact form (reading them
back gives the same float64 bit for bit) and ``\\n`` line ends.

A file without quotes is split on byte positions with numpy (no per-row Python loop); a file
with quotes goes through the :mod:`csv` module. The same text is the ``GCP_TABLE_CSV`` metadata
item of gcpcal's GeoTIFFs (:mod:`gcpmatch.gcp_geotiff`), read by :func:`parse_gcps_csv` and
written by :func:`csv_chunks`.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from gcpmatch.gcps import (
    COLUMNS,
    FLOAT_COLUMNS,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    GcpTable,
    check_output,
    default_column,
    validate_columns,
)
from sensor_models.errors import InputError
from sensor_models.files.atomic import atomic_file

__all__ = ["CSVT_TYPES", "csv_chunks", "csv_sidecar_texts", "parse_gcps_csv", "read_gcps_csv", "write_gcps_csv"]

#: GDAL CSV driver column types (``.csvt``) of the GCP columns: ``CoordX``/``CoordY`` make GDAL and
#: QGIS read ``lon``/``lat`` as the point geometry (with the ``.prj`` beside: WGS84).
CSVT_TYPES = {"id": "String", "row": "Real", "col": "Real", "lon": "CoordX", "lat": "CoordY", "h": "Real",
              "sigma_px": "Real", "band": "String", "ccd": "String", "score": "Real", "kind": "String"}

_CHUNK_ROWS = 65536  # rows formatted at a time by the CSV writer


def read_gcps_csv(path: Path, image_shape) -> GcpTable:
    """Read and validate a CSV GCP table (:func:`gcpmatch.gcp_files.read_gcps` for ``*.csv``).

    Parameters
    ----------
    path : Path
        The file.
    image_shape : (int, int) or None
        ``(n_rows, n_cols)``, already checked (:func:`gcpmatch.gcps.check_image_shape`):
        points outside the image are errors.

    Returns
    -------
    GcpTable
    """
    return parse_gcps_csv(_read_bytes(path), str(path), image_shape)


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=str(path)) from None


def parse_gcps_csv(data: bytes, source: str, image_shape) -> GcpTable:
    """Parse and validate CSV bytes; ``source`` names the file in messages.

    Parameters
    ----------
    data : bytes
        The CSV text, UTF-8 (a byte-order mark is skipped).
    source : str
        The file (or the file and metadata item) named in error messages.
    image_shape : (int, int) or None
        ``(n_rows, n_cols)``, already checked: points outside the image are errors.

    Returns
    -------
    GcpTable

    Raises
    ------
    InputError
        The first problem, with its line number (header = line 1).
    """
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
    validate_columns(cols, where=lambda i: f"line {lines[i]}", path=source, image_shape=image_shape,
                     problems=problems)  # fmt: skip
    return GcpTable.from_validated_columns(cols)


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
            cols[name] = default_column(name, n)
            continue
        a = raw[name]
        if name in FLOAT_COLUMNS:
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


def csv_chunks(table: GcpTable):
    """The CSV text of ``table`` in pieces of ``_CHUNK_ROWS`` rows (header first).

    Parameters
    ----------
    table : GcpTable

    Yields
    ------
    str
        The header line, then the rows (every column, floats repr-exact, ``\\n`` line ends).
    """
    yield ",".join(COLUMNS) + "\n"
    cols = [(_csv_text_field(a) if a.dtype.kind == "U" else a) for a in table.as_dict().values()]
    ncol = len(cols)
    row_fmt = ",".join("%r" if name in FLOAT_COLUMNS else "%s" for name in COLUMNS) + "\n"
    for lo in range(0, len(table), _CHUNK_ROWS):
        m = min(_CHUNK_ROWS, len(table) - lo)
        flat = [None] * (m * ncol)
        for j, a in enumerate(cols):
            flat[j::ncol] = a[lo:lo + m].tolist()  # floats: repr() is shortest round-trip
        yield (row_fmt * m) % tuple(flat)


def csv_sidecar_texts() -> dict[str, str]:
    """The sidecars that make a GCP CSV open typed and as points in GDAL and QGIS.

    Returns
    -------
    dict of str to str
        ``".csvt"``: the column types in :data:`COLUMNS` order (:data:`CSVT_TYPES`, GDAL's CSV
        driver); ``".prj"``: the CRS of ``lon``/``lat`` (EPSG:4326, ESRI WKT as GDAL reads it).
    """
    import pyproj

    return {".csvt": ",".join(CSVT_TYPES[name] for name in COLUMNS) + "\n",
            ".prj": pyproj.CRS.from_epsg(4326).to_wkt("WKT1_ESRI")}


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
    path = check_output(table, path)
    with atomic_file(path, ".csv") as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        for piece in csv_chunks(table):
            fh.write(piece)
    return path
