"""Stage action of ``gcpcal localize``: points through a model, image -> ground or ground -> image.

Image coordinates put the first pixel's centre at ``(0.5, 0.5)``; ground points are WGS84
longitude and latitude in degrees and heights in metres above the ellipsoid.

Points stream as rio and gdaltransform do: ``-`` reads them from standard input (CSV with a
header, or JSON lines: one object per line with ``row``/``col`` or ``lon``/``lat``/``h``, other
keys passed through) and writes the results on standard output (CSV, or JSON lines when the
points came as JSON lines); a file output ending in ``.jsonl`` or ``.ndjson`` is JSON lines.

Inputs are checked before anything is computed: image points outside the image
(``0 <= row <= n_rows``, ``0 <= col <= n_cols``) and ground coordinates outside
:data:`GROUND_RANGES` are refused with one line naming the field (no NaN, no per-point flag), and
a model written by a failed calibration is refused (:mod:`calibrate.actions._status`).
"""

from __future__ import annotations

import csv
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

from calibrate.actions._guard import InputSet, is_stdout
from calibrate.actions._io import check_output_files, open_dem, staged_files, write_summary
from calibrate.actions._status import require_usable, status_fields
from sensor_models.errors import InputError
from sensor_models.files.documents import csv_error, decode_text, read_text

__all__ = ["GROUND_RANGES", "JSON_LINES_SUFFIXES", "STDIN_NAME", "check_ground_points", "check_image_points",
           "csv_lines", "json_lines", "localize_points", "read_points_csv", "read_points_json_lines"]

#: File suffixes of JSON lines outputs.
JSON_LINES_SUFFIXES = (".jsonl", ".ndjson")
#: How standard input is named in messages.
STDIN_NAME = "<stdin>"
#: Decimals written per column (CSV and JSON lines): 1e-6 px, 1e-10 degree (~1e-5 m), 0.1 mm.
_DECIMALS = {"row": 6, "col": 6, "lon": 10, "lat": 10, "h": 4}


def _points_text(path) -> tuple[str, str]:
    """``(text, name for messages)`` of a points file, or of standard input for ``-``."""
    if str(path) == "-":
        return decode_text(sys.stdin.buffer.read(), STDIN_NAME), STDIN_NAME
    return read_text(Path(path)), str(path)

#: Accepted ranges of ground coordinates: ``[low, high)`` for ``lon`` (degrees; 0..360 east is
#: accepted too), ``[low, high]`` for ``lat`` (degrees) and ``h`` (metres above the ellipsoid).
GROUND_RANGES = {"lon": (-180.0, 360.0), "lat": (-90.0, 90.0), "h": (-500.0, 9000.0)}


def read_points_csv(path, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Read numeric columns from a CSV with a header; errors name the file, row and column.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    columns : tuple of str
        Columns to read (others are ignored).

    Returns
    -------
    dict
        Column name -> float64 array of shape (N,), N >= 1.
    """
    text, path = _points_text(path)
    reader = csv.DictReader(io.StringIO(text, newline=""))
    try:
        return _points(reader, path, columns)
    except csv.Error as exc:  # bad quoting, a field over the csv module's limit
        raise csv_error(exc, path, reader.line_num) from None


def read_points_json_lines(path, columns: tuple[str, ...]) -> tuple[dict[str, np.ndarray], list[dict]]:
    """Read points from JSON lines: one object per line holding ``columns`` (numbers).

    Parameters
    ----------
    path : str or Path
        The file, or ``-`` for standard input.
    columns : tuple of str
        Keys every object must hold (``row, col`` or ``lon, lat, h``).

    Returns
    -------
    points : dict
        Column name -> float64 array of shape (N,), N >= 1.
    records : list of dict
        The N objects as read (their other keys are passed through to the output).

    Raises
    ------
    InputError
        A line that is not a JSON object, a missing key, a value that is not a finite number, no
        point at all; the message names the file (or standard input), the line and the key.
    """
    text, name = _points_text(path)
    records, values = [], {c: [] for c in columns}
    for line_no, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except (json.JSONDecodeError, RecursionError) as exc:
            raise InputError(f"line {line_no}: not JSON ({getattr(exc, 'msg', 'nested too deep')})", path=name) from None
        if not isinstance(rec, dict):
            raise InputError(f"line {line_no}: a JSON object is needed, got {type(rec).__name__}", path=name)
        for c in columns:
            v = rec.get(c)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise InputError(f"line {line_no}: must be a finite number, got {v!r}", path=name, field=c)
            values[c].append(float(v))
        records.append(rec)
    if not records:
        raise InputError("holds no points", path=name)
    return {c: np.asarray(v) for c, v in values.items()}, records


def json_lines(table: dict, records: list[dict] | None = None) -> list[str]:
    """JSON lines of localized points: each input object (if any) with the five results set.

    Parameters
    ----------
    table : dict
        ``row, col, lon, lat, h``: float arrays of shape (N,).
    records : list of dict, optional
        The N input objects whose other keys are kept.

    Returns
    -------
    list of str
        N lines, without line ends; a point not localized has nulls.
    """
    out = []
    for i in range(table["row"].size):
        rec = dict(records[i]) if records is not None else {}
        for k, d in _DECIMALS.items():
            v = float(table[k][i])
            rec[k] = round(v, d) if np.isfinite(v) else None
        out.append(json.dumps(rec, ensure_ascii=False))
    return out


def _points(reader: csv.DictReader, path: str, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    header = reader.fieldnames or []
    missing = [c for c in columns if c not in header]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (header: {','.join(header)})", path=str(path))
    values = {c: [] for c in columns}
    for line, rec in enumerate(reader, start=2):
        for c in columns:
            try:
                v = float(rec[c])
            except (TypeError, ValueError):
                raise InputError(f"row {line}: column '{c}' is not a number: {rec[c]!r}", path=str(path)) from None
            if not np.isfinite(v):
                raise InputError(f"row {line}: column '{c}' is not finite", path=str(path))
            values[c].append(v)
    if not values[columns[0]]:
        raise InputError("holds no data rows", path=str(path))
    return {c: np.asarray(v) for c, v in values.items()}


def _first_outside(values, low, high, *, high_open=False):
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    bad = (values < low) | ((values >= high) if high_open else (values > high)) | ~np.isfinite(values)
    return None if not bad.any() else (int(np.flatnonzero(bad)[0]), float(values[bad][0]), int(bad.sum()))


def check_ground_points(points: dict, *, source=None) -> None:
    """Refuse ground coordinates outside :data:`GROUND_RANGES` (one line naming the field).

    Parameters
    ----------
    points : dict
        Any of ``lon``, ``lat`` (degrees) and ``h`` (metres): float arrays of shape (N,).
    source : str, optional
        The file the points came from (named in the message).

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the field, the first offending value and how many are out of range.
    """
    for name, (low, high) in GROUND_RANGES.items():
        if name not in points:
            continue
        found = _first_outside(points[name], low, high, high_open=(name == "lon"))
        if found is not None:
            i, value, n = found
            closing = ")" if name == "lon" else "]"
            unit = "m" if name == "h" else "degrees"
            raise InputError(f"{value:g} (point {i + 1}; {n} point(s) in all) is outside [{low:g}, {high:g}{closing} "
                             f"{unit}", path=source, field=name)


def check_image_points(points: dict, image_shape, *, source=None) -> None:
    """Refuse image coordinates outside the image (``0 <= row <= n_rows``, ``0 <= col <= n_cols``).

    Parameters
    ----------
    points : dict
        ``row`` and ``col``, pixels (first pixel's centre at 0.5): float arrays of shape (N,).
    image_shape : tuple of int
        ``(n_rows, n_cols)`` of the model's image.
    source : str, optional
        The file the points came from (named in the message).

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the field, the first offending value and the image size.
    """
    for name, size in zip(("row", "col"), image_shape):
        found = _first_outside(points[name], 0.0, float(size))
        if found is not None:
            i, value, n = found
            raise InputError(f"{value:g} (point {i + 1}; {n} point(s) in all) is outside the image "
                             f"[0, {size}] px ({image_shape[0]} x {image_shape[1]} px)", path=source, field=name)


def csv_lines(table: dict) -> list[str]:
    """The CSV ``row,col,lon,lat,h`` of localized points, header first.

    Parameters
    ----------
    table : dict
        ``row, col, lon, lat, h``: float arrays of shape (N,).

    Returns
    -------
    list of str
        N + 1 lines, without line ends.
    """
    lines = ["row,col,lon,lat,h"]
    lines += [",".join(point_fields(a, b, x, y, z)) for a, b, x, y, z in zip(*table.values())]
    return lines


#: Decimals printed for row, col (px), lon, lat (degrees, ~10 um) and h (m, 0.1 mm).
POINT_DECIMALS = (6, 6, 10, 10, 4)


def point_fields(*values) -> list[str]:
    """``row, col, lon, lat, h`` as fixed-point text (:data:`POINT_DECIMALS`), never ``-0.0000``.

    A value that rounds to zero prints as ``0``: a height of -1e-12 m (the last bits of the
    arithmetic, which differ between CPUs) is the same point as +1e-12 m.
    """
    return [f"{round(float(v), d) + 0.0:.{d}f}" for v, d in zip(values, POINT_DECIMALS)]


def _write_points(out_path: Path, table: dict, summary: dict, inputs, records) -> None:
    jsonl = out_path.suffix.lower() in JSON_LINES_SUFFIXES
    lines = json_lines(table, records) if jsonl else csv_lines(table)
    with staged_files(out_path, out_path.with_suffix(".summary.json"), inputs=inputs) as (csv_tmp, summary_tmp):
        csv_tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
        write_summary(summary_tmp, summary | {"output": str(out_path)})


def _check_dem_under_points(model, rows, cols, dem, kwargs) -> None:
    """Refuse a DEM that is not under every point to localize (its points would come back NaN)."""
    from sensor_models.errors import DemError

    lon, lat, _ = model.image_to_ground(rows, cols, height=float(np.mean(dem.height_range_m)), **kwargs)
    lon, lat = np.atleast_1d(lon), np.atleast_1d(lat)
    coverage = dem.coverage_fraction(lon, lat) if lon.size else 1.0
    if coverage < 1.0:
        b = dem.bounds_lonlat
        raise DemError(f"{dem.source or 'DEM'}: the DEM is under {100 * coverage:.1f} % of the {lon.size} points "
                       f"to localize (points lon {np.nanmin(lon):.4f}..{np.nanmax(lon):.4f}, lat "
                       f"{np.nanmin(lat):.4f}..{np.nanmax(lat):.4f}; the DEM spans lon {b[0]:.4f}..{b[2]:.4f}, "
                       f"lat {b[1]:.4f}..{b[3]:.4f}): give a DEM under the scene")


def _check_dem_heights(h_m, dem) -> None:
    """Refuse a localization on a DEM that left points without a height (voids)."""
    from sensor_models.errors import DemError

    h_m = np.atleast_1d(h_m)
    n_bad = int(np.count_nonzero(~np.isfinite(h_m)))
    if n_bad:
        raise DemError(f"{dem.source or 'DEM'}: {n_bad} of the {h_m.size} points fall in DEM voids (no height "
                       f"there): fill the voids or give --height")


def localize_points(model_path, points: dict, *, direction: str, height=None, dem_path=None, dem_datum=None,
                    geoid=None, band=None, out_path=None, self_check: str = "refuse") -> dict:
    """Localize points through a model and write them (with a summary) when ``out_path`` is given.

    Parameters
    ----------
    model_path : str or Path
        Anything :func:`sensor_models.open_model` reads.
    points : dict
        ``row, col`` (direct) or ``lon, lat, h`` (inverse): float64 arrays of shape (N,); or
        ``{"csv": path}`` / ``{"jsonl": path}`` to read them from a CSV or JSON lines file
        (``-``: standard input).
    direction : {"direct", "inverse"}
        Image -> ground, or ground -> image.
    height : float, optional
        Ellipsoidal height of the ground for direct localization, m (else ``dem_path``).
    dem_path, dem_datum, geoid : optional
        DEM for direct localization, its vertical datum and geoid grid.
    band : str, optional
        Band of a multi-band model; default: the reference band.
    out_path : str or Path, optional
        CSV ``row,col,lon,lat,h`` (JSON lines for a ``.jsonl``/``.ndjson`` name);
        ``.summary.json`` goes beside it. ``-``: nothing is written (the caller prints
        :func:`csv_lines` or :func:`json_lines` on standard output).
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in the summary.

    Returns
    -------
    dict
        The summary (``points``, ``not_localized``, ...) plus ``results``: ``row, col, lon, lat,
        h`` arrays of shape (N,), and ``records``: the input JSON objects (None for other inputs).
    """
    from sensor_models.readers import open_scene

    t0 = time.perf_counter()
    given = points.get("csv", points.get("jsonl"))
    inputs = InputSet([model_path, None if str(given) == "-" else given, dem_path, geoid])
    to_stdout = is_stdout(out_path)
    if out_path and not to_stdout:  # before any work
        check_output_files(Path(out_path), Path(out_path).with_suffix(".summary.json"), inputs=inputs)
    columns = ("row", "col") if direction == "direct" else ("lon", "lat", "h")
    source, records = None, None
    if "csv" in points:
        source = STDIN_NAME if str(points["csv"]) == "-" else str(points["csv"])
        points = read_points_csv(points["csv"], columns)
    elif "jsonl" in points:
        source = STDIN_NAME if str(points["jsonl"]) == "-" else str(points["jsonl"])
        points, records = read_points_json_lines(points["jsonl"], columns)
    scene = open_scene(model_path, self_check=self_check)  # a raster with its RPC, or a crop, or a model file
    model = scene.model
    warning = require_usable(model, model_path, command="localize")
    kwargs = {} if band is None else {"band": band}
    if direction == "direct":
        check_image_points(points, model.image_shape, source=source)
        if height is not None:
            check_ground_points({"h": np.asarray([height])})
    else:
        check_ground_points(points, source=source)
    if direction == "direct":
        r, c = points["row"], points["col"]
        if dem_path is not None:
            dem = open_dem(dem_path, dem_datum, geoid, model=model)  # tiles: only under the scene
            _check_dem_under_points(model, r, c, dem, kwargs)
            lo, la, hh = model.image_to_ground(r, c, dem=dem, **kwargs)
            _check_dem_heights(hh, dem)
        else:
            lo, la, hh = model.image_to_ground(r, c, height=height, **kwargs)
    else:
        lo, la, hh = points["lon"], points["lat"], points["h"]
        r, c = model.ground_to_image(lo, la, hh, **kwargs)
    table = {"row": np.atleast_1d(r), "col": np.atleast_1d(c), "lon": np.atleast_1d(lo), "lat": np.atleast_1d(la),
             "h": np.atleast_1d(hh)}
    summary = {
        "command": "localize",
        "model": str(model_path),
        "model_kind": model.kind,
        "direction": direction,
        "points": int(table["row"].size),
        "not_localized": int(np.count_nonzero(~np.isfinite(table["row"] + table["lon"]))),
        **status_fields(model, warning, product_check=scene.product_check),
        "seconds": round(time.perf_counter() - t0, 4),
    }
    if out_path and not to_stdout:
        _write_points(Path(out_path), table, summary, inputs, records)
    return summary | {"results": table, "records": records}
