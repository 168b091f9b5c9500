"""Stage action of ``gcpcal oalr``: camera changes from autocollimation cross marks (seed 004).

``MARKS.csv`` has exactly the header columns ``time,ccd1_x_px,ccd1_y_px,ccd2_x_px,ccd2_y_px``
(any order): the time of each epoch (seconds, strictly increasing) and the cross-mark positions on
the two SMCCDs (x = column, y = row, pixels, first pixel centre at 0.5). Data row ``reference``
(0-based, default 0) holds the nominal positions. Writes ``OUT/oalr.json`` (:func:`oalr_from_csv`).

``MARKS.csv`` may instead list SMCCD frames, header ``time,ccd1_frame,ccd2_frame`` (TIFF paths
relative to the CSV): the marks are then located in the frames first (:func:`marks_from_frames`).
"""

from __future__ import annotations

import csv
import io
import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from calibrate.actions._io import check_output_folder, staged_folder
from calibrate.actions._provenance import with_provenance
from sensor_models.errors import InputError
from sensor_models.files.documents import csv_error, read_text

__all__ = ["FRAME_COLUMNS", "MARK_COLUMNS", "marks_from_frames", "oalr_from_csv", "read_marks_csv"]

MARK_COLUMNS = ("time", "ccd1_x_px", "ccd1_y_px", "ccd2_x_px", "ccd2_y_px")
FRAME_COLUMNS = ("time", "ccd1_frame", "ccd2_frame")


@contextmanager
def _csv_file(path: Path):
    """The CSV decoded strictly (:func:`~sensor_models.files.documents.read_text`) as a text
    stream; a ``csv.Error`` inside the block (bad quoting, an over-long field) becomes an
    InputError naming the file and the line."""
    fh = io.StringIO(read_text(path), newline="")
    try:
        yield fh
    except csv.Error as exc:
        raise csv_error(exc, path, fh.getvalue().count("\n", 0, fh.tell()) + 1) from None


def _header(path: Path) -> list[str]:
    with _csv_file(path) as fh:
        return [h.strip() for h in next(csv.reader(fh), [])]


def _read_frame(path: Path, *, listed_in: Path, line: int, column: str) -> np.ndarray:
    """First band of a TIFF (or any raster GDAL reads) as float64, errors naming the list row."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return ds.read(1).astype(np.float64)
    except RasterioIOError as exc:
        raise InputError(f"row {line}: cannot read frame {str(path)!r}: {exc}", path=str(listed_in),
                         field=column) from None


def marks_from_frames(path) -> dict[str, np.ndarray]:
    """Locate the cross marks in the SMCCD frames listed by a CSV ``time,ccd1_frame,ccd2_frame``.

    Frame paths are relative to the CSV's folder; each frame's mark is found by
    :func:`calibrate.schemes.autocollimation.locate_cross` (row = y, column = x).

    Parameters
    ----------
    path : str or Path
        The frame list (CSV).

    Returns
    -------
    dict
        The same columns as :func:`read_marks_csv`.
    """
    from calibrate.schemes.autocollimation import locate_cross

    path = Path(path)
    out = {c: [] for c in MARK_COLUMNS}
    with _csv_file(path) as fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        for c in header:
            if c not in FRAME_COLUMNS:
                raise InputError(f"unknown column (expected {','.join(FRAME_COLUMNS)})", path=str(path), field=c)
        for c in FRAME_COLUMNS:
            if c not in header:
                raise InputError("missing column", path=str(path), field=c)
        for line, rec in enumerate(reader, start=2):
            if any(rec.get(c) in (None, "") for c in FRAME_COLUMNS):
                missing = next(c for c in FRAME_COLUMNS if rec.get(c) in (None, ""))
                raise InputError(f"row {line}: empty value", path=str(path), field=missing)
            try:
                t = float(rec["time"])
            except ValueError:
                raise InputError(f"row {line}: not a number: {rec['time']!r}", path=str(path), field="time") from None
            if not np.isfinite(t):
                raise InputError(f"row {line}: value {rec['time']!r} is not finite", path=str(path), field="time")
            out["time"].append(t)
            for k in (1, 2):
                col = f"ccd{k}_frame"
                img = _read_frame(path.parent / rec[col].strip(), listed_in=path, line=line, column=col)
                try:
                    r, c = locate_cross(img)
                except InputError as exc:
                    raise InputError(f"row {line}: {rec[col].strip()}: {exc.reason}", path=str(path), field=col) from None
                out[f"ccd{k}_x_px"].append(c)
                out[f"ccd{k}_y_px"].append(r)
    marks = {c: np.asarray(v, dtype=np.float64) for c, v in out.items()}
    if marks["time"].size == 0:
        raise InputError("no data rows", path=str(path))
    bad = np.flatnonzero(np.diff(marks["time"]) <= 0.0)
    if bad.size:
        raise InputError(f"row {bad[0] + 3}: times must increase strictly", path=str(path), field="time")
    return marks


def read_marks_csv(path, *, ccd_size_px: float | None = None) -> dict[str, np.ndarray]:
    """Read a marks CSV strictly; every error names the file, the column and, for values, the row.

    Rows are numbered as lines of the file (the header is row 1). Refused: a missing, unknown or
    repeated column, a row with too few or too many fields, a value that is not a finite number,
    a position outside ``[0, ccd_size_px]`` when given, times not strictly increasing, and fewer
    than one data row.

    Parameters
    ----------
    path : str or Path
        The marks CSV.
    ccd_size_px : float, optional
        SMCCD size, pixels; positions beyond it are errors.

    Returns
    -------
    dict
        Column name -> float64 array of shape (N,).
    """
    path = Path(path)
    with _csv_file(path) as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if not header:
            raise InputError("empty file: expected header " + ",".join(MARK_COLUMNS), path=str(path))
        header = [h.strip() for h in header]
        for h in header:
            if h not in MARK_COLUMNS:
                raise InputError(f"unknown column (expected {','.join(MARK_COLUMNS)})", path=str(path), field=h)
            if header.count(h) > 1:
                raise InputError("repeated column", path=str(path), field=h)
        for c in MARK_COLUMNS:
            if c not in header:
                raise InputError("missing column", path=str(path), field=c)
        values = {c: [] for c in MARK_COLUMNS}
        for line, rec in enumerate(reader, start=2):
            if not rec or all(not v.strip() for v in rec):
                continue
            if len(rec) != len(header):
                raise InputError(f"row {line}: {len(rec)} fields, the header has {len(header)}", path=str(path),
                                 field=header[min(len(rec), len(header) - 1)])
            for name, text in zip(header, rec):
                try:
                    v = float(text)
                except ValueError:
                    raise InputError(f"row {line}: not a number: {text.strip()!r}", path=str(path), field=name) from None
                if not np.isfinite(v):
                    raise InputError(f"row {line}: value {text.strip()!r} is not finite", path=str(path), field=name)
                if name != "time" and (v < 0.0 or (ccd_size_px is not None and v > ccd_size_px)):
                    raise InputError(f"row {line}: position {v} px lies outside the SMCCD "
                                     f"[0, {ccd_size_px if ccd_size_px is not None else 'inf'}]",
                                     path=str(path), field=name)
                values[name].append(v)
    out = {c: np.asarray(v, dtype=np.float64) for c, v in values.items()}
    if out["time"].size == 0:
        raise InputError("no data rows", path=str(path))
    bad = np.flatnonzero(np.diff(out["time"]) <= 0.0)
    if bad.size:
        raise InputError(f"row {bad[0] + 3}: times must increase strictly", path=str(path), field="time")
    return out


def oalr_from_csv(path, out_dir, *, reference: int = 0, focal_mm: float = 6550.0, baseline_mm: float = 669.0,
                  pixel_um: float | None = None, sigma_k_px: float = 0.144, beta_deg: float = 0.0,
                  alpha_deg: float = 0.0, ccd_size_px: float | None = None, table3: bool = False) -> dict:
    """Stage action of ``gcpcal oalr``: read marks, apply seed 004 eq. 2-5, write ``oalr.json``.

    ``sigma_k_px`` is the error of each displacement coordinate (table 2's ``sigma_k``; for a
    displacement between two single locations, ``sqrt(2)`` times the location error).
    Angles in the output are arcseconds (``rot_x`` = Delta beta about X, ``rot_y`` = Delta alpha
    about Y, ``rot_z`` = Delta gamma about Z, camera frame); focal changes millimetres.

    Parameters
    ----------
    path : str or Path
        Marks CSV or frame-list CSV (see the module docstring).
    out_dir : str or Path
        Output folder (created when missing).
    reference : int
        Data row (0-based) of the nominal marks.
    focal_mm, baseline_mm : float
        Effective focal length f and distance L between the SMCCDs, mm.
    pixel_um : float, optional
        SMCCD pixel pitch, micrometres (default: the pitch subtending 1 arcsec at f).
    sigma_k_px : float
        Error of each displacement coordinate, pixels.
    beta_deg, alpha_deg : float
        SMCCD angles off axis in YOZ and XOZ, degrees.
    ccd_size_px : float, optional
        SMCCD size; positions beyond it are errors.
    table3 : bool
        Add seed 004 table 3, ours beside the paper's.

    Returns
    -------
    dict
        The document written to ``oalr.json``.
    """
    from calibrate._json import json_safe
    from calibrate.schemes.autocollimation import (ARCSEC, DEFAULT_PIXEL_UM, OalrGeometry, changes_from_displacements,
                                           reproduce_table3)
    from sensor_models.files.atomic import atomic_write_text

    path = Path(path)
    check_output_folder(out_dir, inputs=[path])  # before any work
    marks = _read_marks(path, ccd_size_px, reference)
    geometry = OalrGeometry(focal_mm, baseline_mm, DEFAULT_PIXEL_UM if pixel_um is None else pixel_um,
                            np.radians(beta_deg), np.radians(alpha_deg))
    d = {c: marks[c] - marks[c][reference] for c in MARK_COLUMNS[1:]}
    ch = changes_from_displacements(d["ccd1_x_px"], d["ccd1_y_px"], d["ccd2_x_px"], d["ccd2_y_px"], geometry,
                                    sigma_k_px=sigma_k_px)
    sig = {"sigma_f_mm": ch.sigma_f_mm, "sigma_rot_x_arcsec": ch.sigma_rot_x_rad / ARCSEC,
           "sigma_rot_y_arcsec": ch.sigma_rot_y_rad / ARCSEC, "sigma_rot_z_arcsec": ch.sigma_rot_z_rad / ARCSEC}
    epochs = _epochs(marks["time"], d, ch, sig, ARCSEC)
    doc = {
        "format_version": 1,
        "method": "seed 004 eq. 2-5 (OALR autocollimation), errors by table 2",
        "inputs": {"marks": str(path)},
        "geometry": {"focal_mm": geometry.focal_mm, "baseline_mm": geometry.baseline_mm,
                     "pixel_um": geometry.pixel_um, "beta_deg": beta_deg, "alpha_deg": alpha_deg},
        "sigma_k_px": sigma_k_px,
        "reference": {"index": int(reference), "time": marks["time"][reference],
                      **{c: marks[c][reference] for c in MARK_COLUMNS[1:]}},
        "sigmas": sig,
        "epochs": epochs,
    }
    if table3:
        doc["table3"] = reproduce_table3(geometry)
    with staged_folder(out_dir, ".oalr-", inputs=[path]) as stage:
        atomic_write_text(stage / "oalr.json", json.dumps(json_safe(with_provenance(doc)), indent=1, allow_nan=False) + "\n")
    return doc


def _read_marks(path: Path, ccd_size_px, reference) -> dict:
    """Marks of a marks CSV or a frame-list CSV, with ``reference`` checked against the rows."""
    if "ccd1_frame" in _header(path):
        marks = marks_from_frames(path)
    else:
        marks = read_marks_csv(path, ccd_size_px=ccd_size_px)
    n = marks["time"].size
    if not 0 <= int(reference) < n:
        raise InputError(f"reference row index {reference} is outside 0..{n - 1}", field="--reference")
    return marks


def _epochs(times, d: dict, ch, sig: dict, arcsec: float) -> list:
    """One entry per epoch of ``oalr.json``: displacements (px), changes (mm, arcsec) and sigmas."""
    return [
        {"time": times[i], "dx1_px": d["ccd1_x_px"][i], "dy1_px": d["ccd1_y_px"][i],
         "dx2_px": d["ccd2_x_px"][i], "dy2_px": d["ccd2_y_px"][i], "delta_f_mm": ch.delta_f_mm[i],
         "rot_x_arcsec": ch.rot_x_rad[i] / arcsec, "rot_y_arcsec": ch.rot_y_rad[i] / arcsec,
         "rot_z_arcsec": ch.rot_z_rad[i] / arcsec} | sig
        for i in range(times.size)
    ]
