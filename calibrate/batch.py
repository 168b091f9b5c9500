"""Batch validation of a calibration over many scenes and sites, one Dask task per scene.

A sensor is calibrated once (``gcpcal calibrate`` or ``gcpcal demo`` writes the calibrated
manifest). Validation scenes are other acquisitions of the same sensor: same camera interior
and installation, another date, orbit, attitude bias, site and cloud cover (seed 003 section
3.4). Validating a scene with the calibration (:func:`validate_scene`):

1. the scene's own model (its orbit, attitude and line timing, from its manifest) gets the
   calibrated camera: ``scene.with_parameters(calibrated.parameters().values)``, installation
   angles and directional-angle coefficients, when both describe the same CCDs and
   parameters (else the row fails with "calibration does not fit this sensor");
2. the reference band is matched against the scene's DOM and DEM
   (:func:`gcpmatch.extract.extract_gcps`, starting from the calibrated model, no check
   fraction): every match is a check point, nothing is refitted;
3. the accuracy of the calibrated model on those points (:func:`calibrate.accuracy.check_point_accuracy`):
   RMSE along track (rows), across track (columns) and planar, in pixels and metres; and, for
   comparison, that of the scene's LAB model.

:func:`validate_sites` runs the scenes of a sites file (:func:`read_sites`) on Dask distributed
(a :class:`~distributed.LocalCluster` of single-threaded worker processes by default, or the
scheduler at a given address), reports progress as tasks finish, and writes into ``out_dir``:
``validation.csv``, ``validation.json`` (rows and summary), ``validation.html`` (the table in
the layout of seed 003 table 5 with a mean row, and a bar plot of the planar RMSE per scene,
``validation_planar.png``) and ``points/<name>.csv`` (each scene's check points). A scene that
fails (unreadable raster, missing DOM, no GCP, foreign sensor) is a row with
``status = "failed"`` and the reason; it never stops the others.

Models travel to the workers as file paths (manifests), never as pickled objects; the paths
must therefore be readable from the workers (shared filesystem on a cluster).
"""

from __future__ import annotations

import contextlib
import csv
import html
import importlib
import io
import json
import logging
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibrate._json import json_safe
from sensor_models.errors import GcpcalError, InputError

__all__ = ["COLUMNS", "Site", "calibration_manifest", "read_sites", "summarize_rows", "validate_scene",
           "validate_sites", "write_outputs"]

_REQUIRED = ("name", "scene", "dom", "dem")
_OPTIONAL = ("dem_datum", "geoid", "site", "band")
_PATHS = ("scene", "dom", "dem", "geoid")

#: Columns of a result row, in table order (``*_px`` pixels, ``*_m`` metres; ``lab_*``: the
#: scene's LAB model, the rest: the calibrated model).
COLUMNS = (
    "name", "site", "date", "center_lon_deg", "center_lat_deg", "status", "reason", "points", "cloud_fraction",
    "rmse_along_px", "rmse_across_px", "rmse_planar_px", "rmse_along_m", "rmse_across_m", "rmse_planar_m",
    "mean_along_px", "mean_across_px", "max_planar_px",
    "lab_rmse_along_px", "lab_rmse_across_px", "lab_rmse_planar_px", "lab_rmse_planar_m",
    "seconds", "cpu_seconds", "worker",
)
_MEAN_COLUMNS = ("rmse_along_px", "rmse_across_px", "rmse_planar_px", "rmse_along_m", "rmse_across_m",
                 "rmse_planar_m", "lab_rmse_along_px", "lab_rmse_across_px", "lab_rmse_planar_px",
                 "lab_rmse_planar_m", "cloud_fraction", "points")


# --------------------------------------------------------------------------- sites file
@dataclass(frozen=True)
class Site:
    """One validation scene of a sites file.

    Attributes
    ----------
    name : str
        Unique label (the row name; also names ``points/<name>.csv``).
    scene : Path
        The scene's manifest (its LAB model and rasters).
    dom, dem : Path
        Reference orthoimage and DEM covering the scene.
    dem_datum : str or None
        ``"ellipsoid"`` or ``"egm96"`` when the DEM file does not declare it.
    geoid : Path or None
        EGM96 grid for an orthometric DEM.
    site : str
        Free label of the place (table column "site"); default empty.
    band : str or None
        Band to match (default: the scene's reference band).
    """

    name: str
    scene: Path
    dom: Path
    dem: Path
    dem_datum: str | None = None
    geoid: Path | None = None
    site: str = ""
    band: str | None = None


def read_sites(path) -> list[Site]:
    """Read a sites file, strictly.

    Two formats, told by the extension:

    * YAML (``.yaml``, ``.yml``): a list of mappings with keys ``name, scene, dom, dem`` and
      optionally ``dem_datum, geoid, site, band``;
    * CSV (``.csv``): a header ``name,scene,dom,dem`` with any of the optional columns, one
      scene per line; an empty optional cell means "not given".

    Relative paths are taken relative to the sites file's folder. Referenced files are not
    opened here: a missing DOM fails its scene's row, not the whole run.

    Parameters
    ----------
    path : path
        A ``.yaml``/``.yml`` or ``.csv`` sites file.

    Returns
    -------
    list of Site
        One per scene, paths resolved.

    Raises
    ------
    InputError
        One line naming the file, the entry and the field: unreadable file, not a list,
        missing or empty required field, unknown field, duplicate name, bad ``dem_datum``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".yaml", ".yml", ".csv"):
        raise InputError("a sites file must be .yaml, .yml or .csv", path=str(path))
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read the sites file ({exc.strerror or exc})", path=str(path)) from None
    entries = _yaml_entries(text, path) if suffix != ".csv" else _csv_entries(text, path)
    if not entries:
        raise InputError("lists no scene", path=str(path))
    base = path.resolve().parent
    out, seen = [], {}
    for label, entry in entries:
        unknown = [k for k in entry if k not in _REQUIRED + _OPTIONAL]
        if unknown:
            raise InputError(f"{label}: unknown field (known: {', '.join(_REQUIRED + _OPTIONAL)})", path=str(path),
                             field=str(unknown[0]))
        values = {}
        for key in _REQUIRED + _OPTIONAL:
            value = entry.get(key)
            if isinstance(value, bool) or (value is not None and not isinstance(value, (str, int, float))):
                raise InputError(f"{label}: must be a string, got {type(value).__name__}", path=str(path), field=key)
            value = None if value is None else str(value).strip()
            if key in _REQUIRED and not value:
                raise InputError(f"{label}: required field missing or empty", path=str(path), field=key)
            if value:
                values[key] = (base / value) if key in _PATHS else value
        if values.get("dem_datum") not in (None, "ellipsoid", "egm96"):
            raise InputError(f"{label}: must be ellipsoid or egm96, got {values['dem_datum']!r}", path=str(path),
                             field="dem_datum")
        if values["name"] in seen:
            raise InputError(f"{label}: name {values['name']!r} already used by {seen[values['name']]}",
                             path=str(path), field="name")
        seen[values["name"]] = label
        out.append(Site(**values))
    return out


def _yaml_entries(text: str, path: Path) -> list[tuple[str, dict]]:
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "syntax error"
        raise InputError(f"is not valid YAML{where}: {problem}", path=str(path)) from None
    if doc is None:
        return []
    if not isinstance(doc, list):
        raise InputError(f"must be a YAML list of scenes (mappings), got a {type(doc).__name__}", path=str(path))
    out = []
    for k, entry in enumerate(doc, start=1):
        if not isinstance(entry, dict):
            raise InputError(f"entry {k}: must be a mapping with name, scene, dom, dem", path=str(path))
        name = entry.get("name")
        out.append((f"entry {k}" + (f" ({name!r})" if isinstance(name, str) and name else ""),
                    {str(key): v for key, v in entry.items()}))
    return out


def _csv_entries(text: str, path: Path) -> list[tuple[str, dict]]:
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in _REQUIRED if c not in header]
    if missing:
        raise InputError(f"the header lacks column(s) {', '.join(missing)} (header: {','.join(header)})",
                         path=str(path), field=missing[0])
    unknown = [c for c in header if c not in _REQUIRED + _OPTIONAL]
    if unknown:
        raise InputError(f"unknown column (known: {', '.join(_REQUIRED + _OPTIONAL)})", path=str(path),
                         field=unknown[0])
    reader.fieldnames = header
    out = []
    for k, rec in enumerate(reader, start=1):
        if None in rec:
            raise InputError(f"entry {k} (line {reader.line_num}): more cells than header columns", path=str(path))
        if all((v or "").strip() == "" for v in rec.values()):
            continue
        name = (rec.get("name") or "").strip()
        label = f"entry {k} (line {reader.line_num}" + (f", {name!r})" if name else ")")
        out.append((label, {key: (v if (v or "").strip() else None) for key, v in rec.items()}))
    return out


def calibration_manifest(path) -> Path:
    """The calibrated manifest: ``path`` itself, or ``path/manifest.json`` for a folder.

    Parameters
    ----------
    path : path
        A manifest file or a folder holding ``manifest.json``.

    Returns
    -------
    Path
        The manifest file.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "manifest.json"
        if not path.is_file():
            raise InputError("the calibration folder holds no manifest.json", path=str(path.parent))
    elif not path.is_file():
        raise InputError("no such calibration file", path=str(path))
    return path


# --------------------------------------------------------------------------- one scene
def _calibrated_scene_model(scene, calibrated):
    """``scene`` with the camera parameters of ``calibrated`` (same sensor required)."""

    def layout(m):
        return [(b, c.name, c.first_col, c.n_detectors) for b, ccds in m.bands.items() for c in ccds]

    if getattr(scene, "kind", None) != "pushbroom":
        raise InputError(f"calibration does not fit this sensor (the scene is a {getattr(scene, 'kind', '?')} model, "
                         "the calibration a push-broom one)")
    if layout(scene) != layout(calibrated):
        raise InputError("calibration does not fit this sensor (its bands and CCDs differ from the scene's)")
    names_s, names_c = scene.parameter_names(), calibrated.parameter_names()
    if names_s != names_c:
        diff = next((a for a, b in zip(names_s, names_c) if a != b), None) or f"{len(names_s)} vs {len(names_c)} parameters"
        raise InputError(f"calibration does not fit this sensor (parameters differ: {diff})")
    return scene.with_parameters(calibrated.parameters().values)


def _empty_row(site: Site) -> dict:
    row = {c: None for c in COLUMNS}
    row.update(name=site.name, site=site.site, status="failed", reason="")
    return row


def _accuracy_columns(acc, prefix: str) -> dict:
    a = acc.absolute
    out = {f"{prefix}rmse_along_px": a.rmse_row_px, f"{prefix}rmse_across_px": a.rmse_col_px,
           f"{prefix}rmse_planar_px": a.rmse_px, f"{prefix}rmse_planar_m": a.rmse_m}
    if not prefix:
        out.update(rmse_along_m=a.rmse_row_m, rmse_across_m=a.rmse_col_m, mean_along_px=a.mean_row_px,
                   mean_across_px=a.mean_col_px, max_planar_px=a.max_px)
    return out


def validate_scene(site: Site, calibration, *, points_dir=None, spacing_px: int = 32, threads: int | None = None) -> dict:
    """Validate one scene with a calibration (module docstring, steps 1-3); never raises.

    Parameters
    ----------
    site : Site
    calibration : str or Path
        The calibrated manifest.
    points_dir : str or Path, optional
        Write the scene's check points to ``points_dir/<name>.csv``.
    spacing_px : int
        Matching window grid spacing, pixels.
    threads : int, optional
        OpenCV threads in this process (1 on single-threaded Dask workers).

    Returns
    -------
    dict
        A row with the keys of :data:`COLUMNS`: ``status`` is ``"ok"`` or ``"failed"`` (then
        ``reason`` says why and the accuracy columns are None).
    """
    t0, c0 = time.perf_counter(), time.process_time()
    row = _empty_row(site)
    row["worker"] = f"{os.uname().nodename}:{os.getpid()}"
    try:
        if threads is not None:
            import cv2

            cv2.setNumThreads(int(threads))
        _validate(site, Path(calibration), points_dir, spacing_px, row)
        row["status"], row["reason"] = "ok", ""
    except GcpcalError as exc:
        row["reason"] = str(exc)
    except MemoryError:
        row["reason"] = "out of memory"
    except Exception as exc:  # noqa: BLE001 - a failing scene is a row, never a stopped run
        row["reason"] = f"{type(exc).__name__}: {exc}".splitlines()[0]
    row["seconds"] = time.perf_counter() - t0
    row["cpu_seconds"] = time.process_time() - c0
    return json_safe(row)


def _validate(site: Site, calibration: Path, points_dir, spacing_px: int, out: dict) -> None:
    """Fill ``out`` (a row) step by step, so a failure keeps what was learnt before it."""
    from calibrate.accuracy import check_point_accuracy
    from calibrate.from_gcps import points_of
    from gcpmatch.extract import extract_gcps, read_band
    from gcpmatch.options import MatchOptions
    from sensor_models.readers import open_model
    from sensor_models.raster import MapImage
    from sensor_models.terrain import Dem

    lab = open_model(site.scene)
    out["date"] = str(np.datetime_as_string(np.datetime64(lab.epoch, "s")))[:10] if hasattr(lab, "epoch") else None
    calibrated = open_model(calibration)
    model = _calibrated_scene_model(lab, calibrated)
    band = site.band or model.reference_band
    if band not in model.bands:
        raise InputError(f"the scene has no band {band!r}", path=str(site.scene), field="band")
    for what, p in (("DOM", site.dom), ("DEM", site.dem)):
        if not Path(p).is_file():
            raise InputError(f"no such {what} file", path=str(p))
    image = read_band(model, band)
    dem = Dem.open(site.dem, vertical_datum=site.dem_datum, geoid=site.geoid)
    dom = MapImage.open(site.dom)
    n_rows, n_cols = model.image_shape
    lon, lat, _ = model.image_to_ground([0.5 * n_rows], [0.5 * n_cols], dem=dem, band=band)
    out["center_lon_deg"], out["center_lat_deg"] = float(lon[0]), float(lat[0])
    table, summary = extract_gcps(model, image, dem, dom, band=band,
                                  options=MatchOptions(spacing_px=spacing_px, check_fraction=0.0))
    out["cloud_fraction"] = summary.get("cloud_fraction")
    if table is None or len(table) == 0:
        raise InputError(summary.get("message", "no GCP"), path=str(site.scene))
    if points_dir is not None:
        from gcpmatch.gcps import write_gcps_csv

        Path(points_dir).mkdir(parents=True, exist_ok=True)
        write_gcps_csv(table, Path(points_dir) / f"{_safe_name(site.name)}.csv")
    pts = points_of(table, model)
    kw = {"band": pts["band"], "ccd": pts["ccd"]}
    acc = check_point_accuracy(model, pts["row"], pts["col"], pts["lon"], pts["lat"], pts["h"], **kw)
    acc_lab = check_point_accuracy(lab, pts["row"], pts["col"], pts["lon"], pts["lat"], pts["h"], **kw)
    out["points"] = int(acc.absolute.n)
    out.update(_accuracy_columns(acc, ""))
    out.update(_accuracy_columns(acc_lab, "lab_"))


def _safe_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "scene"


# --------------------------------------------------------------------------- Dask orchestration
@contextlib.contextmanager
def _dask_log_level():
    """Keep Dask's INFO chatter (scheduler start, workers joining) out of a non-verbose run."""
    importlib.import_module("distributed")  # importing it configures its logger: do that first

    logger = logging.getLogger("distributed")
    old = logger.level
    if logging.getLogger().getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(old)


def _connect(scheduler, workers: int, timeout_s: float):
    """A Dask client: on a new LocalCluster (``scheduler`` None) or at the given address.

    The LocalCluster's HTTP server takes a free port (``:0``), so concurrent runs never
    compete for the dashboard's default port.
    """
    from distributed import Client, LocalCluster

    if scheduler is None:
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
        try:
            return Client(cluster), cluster
        except BaseException:
            cluster.close()
            raise
    try:
        return Client(str(scheduler), timeout=f"{float(timeout_s)}s"), None
    except (OSError, TimeoutError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot reach the Dask scheduler within {timeout_s:g} s ({why})", path=str(scheduler),
                         field="scheduler") from None


def validate_sites(sites, calibrated_model, out_dir, *, scheduler=None, workers: int = 2, progress=None,
                   spacing_px: int = 32, timeout_s: float = 10.0, title: str | None = None):
    """Validate a calibration on every scene of ``sites``, one Dask task per scene.

    Parameters
    ----------
    sites : list of Site
        From :func:`read_sites`.
    calibrated_model : str or Path
        The calibrated manifest, or a folder holding ``manifest.json`` (the output folder of
        ``gcpcal calibrate`` or ``gcpcal demo``).
    out_dir : str or Path
        Output folder (module docstring).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); default: a LocalCluster of
        ``workers`` single-threaded processes.
    workers : int
        Worker processes of the LocalCluster.
    progress : callable, optional
        ``progress(done, total, row)`` each time a scene finishes (in completion order).
    spacing_px : int
        Matching window spacing.
    timeout_s : float
        Time allowed to connect to ``scheduler``.
    title : str, optional
        Title of the HTML page.

    Returns
    -------
    rows : list of dict
        One row per site, in the sites' order (keys :data:`COLUMNS`).
    summary : dict
        Means over the scenes that succeeded, counts, timings and the output files.

    Raises
    ------
    InputError
        Unreadable or non-push-broom calibration, no site, unreachable scheduler.
    """
    from sensor_models.readers import open_model

    t0 = time.perf_counter()
    sites = list(sites)
    if not sites:
        raise InputError("no scene to validate", field="sites")
    if int(workers) < 1:
        raise InputError(f"must be >= 1, got {workers}", field="workers")
    calib = calibration_manifest(calibrated_model).resolve()
    model = open_model(calib)
    if getattr(model, "kind", None) != "pushbroom":
        raise InputError("the calibration must be a push-broom manifest (calibrated manifest.json)", path=str(calib))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    points_dir = (out_dir / "points").resolve()
    rows: list[dict | None] = [None] * len(sites)
    with _dask_log_level():
        n_workers = _run_tasks(sites, str(calib), str(points_dir), rows, scheduler=scheduler, workers=workers,
                               timeout_s=timeout_s, spacing_px=spacing_px, progress=progress)
    summary = summarize_rows(rows)
    summary.update({
        "kind": "gcpcal.validate",
        "calibration": str(calib),
        "scheduler": str(scheduler) if scheduler else "LocalCluster",
        "workers": n_workers,
        "seconds": time.perf_counter() - t0,
    })
    summary["files"] = write_outputs(out_dir, rows, summary, title=title)
    return rows, summary


def _run_tasks(sites, calib: str, points_dir: str, rows: list, *, scheduler, workers, timeout_s, spacing_px,
               progress) -> int:
    """Submit one :func:`validate_scene` per site, fill ``rows`` as they finish; return the worker count."""
    from distributed import as_completed

    client, cluster = _connect(scheduler, workers, timeout_s)
    try:
        if cluster is None:
            try:
                client.wait_for_workers(1, timeout=timeout_s)
            except TimeoutError:
                raise InputError(f"the Dask scheduler has no worker (none joined within {timeout_s:g} s)",
                                 path=str(scheduler), field="scheduler") from None
            n_workers = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        else:
            n_workers = int(workers)
        futures = {client.submit(validate_scene, site, calib, points_dir=points_dir, spacing_px=spacing_px,
                                 threads=1, pure=False): k for k, site in enumerate(sites)}
        for done, fut in enumerate(as_completed(futures), start=1):
            k = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker fails its scene only
                row = _empty_row(sites[k])
                row["reason"] = f"task error: {type(exc).__name__}: {exc}".splitlines()[0]
            rows[k] = row
            if progress is not None:
                progress(done, len(sites), row)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return n_workers


def summarize_rows(rows) -> dict:
    """Counts and column means over the rows that succeeded (seed 003 table 5's mean row).

    Parameters
    ----------
    rows : sequence of dict
        Per-scene rows of the validation table (errors in pixels and metres).

    Returns
    -------
    dict
        ``scenes``, ``ok``, ``failed``, the ``mean`` of the error columns over the successful
        rows, summed task wall and CPU seconds, and the reason of every failure by scene.
    """
    ok = [r for r in rows if r["status"] == "ok"]

    def mean(key):
        v = np.array([r[key] for r in ok if r.get(key) is not None], dtype=np.float64)
        v = v[np.isfinite(v)]
        return float(v.mean()) if v.size else None

    return {
        "scenes": len(rows),
        "ok": len(ok),
        "failed": len(rows) - len(ok),
        "mean": {k: mean(k) for k in _MEAN_COLUMNS},
        "task_seconds": float(sum(r["seconds"] or 0.0 for r in rows)),
        "task_cpu_seconds": float(sum(r["cpu_seconds"] or 0.0 for r in rows)),
        "failures": {r["name"]: r["reason"] for r in rows if r["status"] != "ok"},
    }


# --------------------------------------------------------------------------- outputs
def write_outputs(out_dir, rows, summary, *, title: str | None = None) -> dict:
    """Write ``validation.csv``, ``validation.json``, ``validation.html`` and the bar plot.

    Everything is written into a temporary folder inside ``out_dir`` and renamed into place, so
    an interrupted run leaves the previous files (or none), never half of them.

    Parameters
    ----------
    out_dir : path
        Output folder (created if needed).
    rows : sequence of dict
        Per-scene rows.
    summary : dict
        Of :func:`summarize_rows`.
    title : str, optional
        Title of the HTML page.

    Returns
    -------
    dict
        File kinds to names relative to ``out_dir``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {"csv": "validation.csv", "json": "validation.json", "html": "validation.html",
             "plot": "validation_planar.png"}
    tmp = Path(tempfile.mkdtemp(prefix=".validate-", dir=out_dir))
    try:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({c: _csv_cell(r.get(c)) for c in COLUMNS})
        (tmp / files["csv"]).write_text(buf.getvalue(), encoding="utf-8")
        doc = json_safe({**summary, "files": files, "columns": list(COLUMNS), "rows": rows})
        (tmp / files["json"]).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        _bar_plot(rows, summary, tmp / files["plot"])
        (tmp / files["html"]).write_text(_html_page(rows, summary, files, title), encoding="utf-8")
        for name in files.values():
            os.replace(tmp / name, out_dir / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return files


def _csv_cell(v):
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return v


def _bar_plot(rows, summary, path: Path) -> None:
    """Planar RMSE of the calibrated model per scene, failed scenes marked, mean dashed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(rows)
    fig = Figure(figsize=(max(5.0, 0.42 * n + 1.8), 3.6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(n)
    vals = np.array([r["rmse_planar_px"] if r["status"] == "ok" and r["rmse_planar_px"] is not None else np.nan
                     for r in rows], dtype=np.float64)
    ax.bar(x, np.nan_to_num(vals), color="#3b6ea8", width=0.7, label="planar RMSE, calibrated")
    top = float(np.nanmax(vals)) if np.isfinite(vals).any() else 1.0
    for i in np.flatnonzero(~np.isfinite(vals)):
        ax.text(i, 0.03 * top, "failed", rotation=90, ha="center", va="bottom", color="#b3261e", fontsize=8)
    m = summary["mean"]["rmse_planar_px"]
    if m is not None:
        ax.axhline(m, color="#d9822b", ls="--", lw=1.2, label=f"mean {m:.3g} px")
    ax.set_xticks(x)
    ax.set_xticklabels([str(k + 1) for k in range(n)], fontsize=8)
    ax.set_xlabel("validation scene (ID of the table)")
    ax.set_ylabel("planar RMSE, px")
    ax.set_ylim(0, 1.15 * top)
    ax.legend(loc="upper right", fontsize=8, frameon=False)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, format="png")


_CSS = (
    "body{font-family:system-ui,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1200px;color:#222;padding:0 1em}"
    "table{border-collapse:collapse;margin:.6em 0;font-size:.9em}"
    "th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right}th{background:#f2f4f7}"
    "td.l{text-align:left}tr.mean td{font-weight:600;background:#fafafa}tr.failed td{color:#b3261e}"
    ".meta{color:#666;font-size:.85em}img{max-width:100%;border:1px solid #ddd}"
)


def _f(v, digits: int = 3) -> str:
    return "-" if v is None or not math.isfinite(float(v)) else f"{float(v):.{digits}f}"


def _html_page(rows, summary, files, title) -> str:
    e = html.escape
    title = title or "gcpcal validation: geolocation accuracy of validation scenes"
    head = ("<tr><th rowspan=2>ID</th><th rowspan=2>scene</th><th rowspan=2>site (centre lon, lat)</th>"
            "<th rowspan=2>date</th><th colspan=3>accuracy, calibrated (px)</th><th rowspan=2>planar (m)</th>"
            "<th rowspan=2>points</th><th rowspan=2>cloud</th><th rowspan=2>LAB planar (px)</th></tr>"
            "<tr><th>along track</th><th>across track</th><th>planar</th></tr>")
    body = []
    for k, r in enumerate(rows, start=1):
        where = e(r.get("site") or "")
        if r.get("center_lon_deg") is not None:
            where += f" ({r['center_lon_deg']:.3f}, {r['center_lat_deg']:.3f})"
        lead = f"<td>{k}</td><td class=l>{e(r['name'])}</td><td class=l>{where}</td><td class=l>{e(r.get('date') or '')}</td>"
        if r["status"] != "ok":
            body.append(f"<tr class=failed>{lead}<td class=l colspan=7>failed: {e(r.get('reason') or '')}</td></tr>")
            continue
        cloud = "-" if r.get("cloud_fraction") is None else f"{100 * r['cloud_fraction']:.0f} %"
        body.append(f"<tr>{lead}<td>{_f(r['rmse_along_px'])}</td><td>{_f(r['rmse_across_px'])}</td>"
                    f"<td>{_f(r['rmse_planar_px'])}</td><td>{_f(r['rmse_planar_m'], 1)}</td><td>{r['points']}</td>"
                    f"<td>{cloud}</td><td>{_f(r['lab_rmse_planar_px'], 1)}</td></tr>")
    m = summary["mean"]
    body.append(f"<tr class=mean><td class=l colspan=4>mean of {summary['ok']} scene(s)</td>"
                f"<td>{_f(m['rmse_along_px'])}</td><td>{_f(m['rmse_across_px'])}</td><td>{_f(m['rmse_planar_px'])}</td>"
                f"<td>{_f(m['rmse_planar_m'], 1)}</td><td>{_f(m['points'], 0)}</td><td></td>"
                f"<td>{_f(m['lab_rmse_planar_px'], 1)}</td></tr>")
    meta = (f"calibration {e(str(summary.get('calibration', '')))}; {summary['scenes']} scenes, {summary['ok']} ok, "
            f"{summary['failed']} failed; {e(str(summary.get('scheduler', '')))} with {summary.get('workers', '?')} "
            f"worker(s), {summary.get('seconds', 0.0):.1f} s")
    return (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        f"<title>{e(title)}</title><style>{_CSS}</style></head><body><h1>{e(title)}</h1>"
        f"<p class=meta>{meta}</p>"
        "<p>Root-mean-square geolocation error of each scene's own model with the calibrated camera (installation "
        "and directional angles), measured on every point matched against the scene's reference DOM and DEM; no "
        "point is used in a fit (layout of seed 003 table 5). Along track = image rows, across track = columns.</p>"
        f"<table>{head}{''.join(body)}</table>"
        f"<figure><img src=\"{e(files['plot'])}\" alt=\"planar RMSE per scene\"><figcaption>Planar RMSE per "
        "validation scene, calibrated model; dashed: mean.</figcaption></figure>"
        f"<p class=meta>Data: <a href=\"{e(files['csv'])}\">{e(files['csv'])}</a>, "
        f"<a href=\"{e(files['json'])}\">{e(files['json'])}</a>.</p></body></html>\n"
    )

