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
scheduler at a given address), reports progress as tasks finish, and returns one row per scene
and a summary (:func:`summarize_rows`). A scene that fails (unreadable raster, missing DOM, no
GCP, foreign sensor) is a row with ``status = "failed"`` and the reason; it never stops the
others. This module writes no file of its own: the run folder (tables, page, plot and each
scene's check points) is written by :mod:`calibrate.actions.validate`, whose point writer the
tasks are given.

Models travel to the workers as file paths (manifests), never as pickled objects; the paths
must therefore be readable from the workers (shared filesystem on a cluster).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibrate._json import json_safe
from calibrate.cluster import connect, dask_log_level, worker_count
from sensor_models.errors import GcpcalError, InputError

__all__ = ["COLUMNS", "Site", "calibration_manifest", "read_sites", "summarize_rows", "validate_scene",
           "validate_sites"]

_REQUIRED = ("name", "scene", "dom", "dem")
_OPTIONAL = ("dem_datum", "geoid", "site", "band", "dom_band", "dom_qa")
_PATHS = ("scene", "dom", "dem", "geoid", "dom_qa")

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
    dom_band : str or None
        Band of a DOM product folder (``B04``, ``B4``; :mod:`sensor_models.maps.dom_inputs`).
    dom_qa : Path or None
        QA raster masking the DOM (default: the one beside the band, when found).
    """

    name: str
    scene: Path
    dom: Path
    dem: Path
    dem_datum: str | None = None
    geoid: Path | None = None
    site: str = ""
    band: str | None = None
    dom_band: str | None = None
    dom_qa: Path | None = None


def read_sites(path) -> list[Site]:
    """Read a sites file, strictly.

    Two formats, told by the extension:

    * YAML (``.yaml``, ``.yml``): a list of mappings with keys ``name, scene, dom, dem`` and
      optionally ``dem_datum, geoid, site, band, dom_band, dom_qa``;
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
    from calibrate.scene_lists import read_entries

    out = []
    for values in read_entries(path, required=_REQUIRED, optional=_OPTIONAL, paths=_PATHS):
        label = values.pop("_label")
        if values.get("dem_datum") not in (None, "ellipsoid", "egm96"):
            raise InputError(f"{label}: must be ellipsoid or egm96, got {values['dem_datum']!r}", path=str(path),
                             field="dem_datum")
        out.append(Site(**values))
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
    if getattr(calibrated, "attitude_correction", None) is not None:
        calibrated = calibrated.with_attitude_correction(None)  # a function of that scene's time only
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


def validate_scene(site: Site, calibration, *, write_points=None, spacing_px: int = 32,
                   threads: int | None = None, coarse_skip: bool = True) -> dict:
    """Validate one scene with a calibration (module docstring, steps 1-3); never raises.

    Parameters
    ----------
    site : Site
    calibration : str or Path
        The calibrated manifest.
    write_points : callable(GcpTable, str, dict), optional
        Called with the scene's check points, ``site.name`` and their residual layer against the
        calibrated model (:func:`calibrate.residual_layer.residual_layer`, kind ``check``) once
        they are scored (e.g. :func:`calibrate.actions.validate.write_scene_points`).
    spacing_px : int
        Matching window grid spacing, pixels.
    threads : int, optional
        Threads of the match in this process: OpenCV, reference chips, phase correlation (1 on
        single-threaded Dask workers); None: ``GCPCAL_THREADS`` or every core.
    coarse_skip : bool
        Skip the coarse SIFT stage when a cheap check finds the calibrated model within the
        fine search radius (:func:`gcpmatch.coarse_skip.within_fine_radius`); False: always SIFT.

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
        _validate(site, Path(calibration), write_points, spacing_px, row, coarse_skip=coarse_skip,
                  threads=threads or 0)
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


def _validate(site: Site, calibration: Path, write_points, spacing_px: int, out: dict, *,
              coarse_skip: bool = True, threads: int = 0) -> None:
    """Fill ``out`` (a row) step by step, so a failure keeps what was learnt before it."""
    from calibrate.accuracy import check_point_accuracy
    from calibrate.plausibility import check_dem_heights, check_dom_resolution
    from calibrate.from_gcps import points_of
    from gcpmatch.extract import extract_gcps, read_band
    from gcpmatch.options import MatchOptions
    from sensor_models.maps.dom_inputs import DomSource, open_dom
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    scene = open_scene(site.scene)
    lab = scene.model
    out["date"] = str(np.datetime_as_string(np.datetime64(lab.epoch, "s")))[:10] if hasattr(lab, "epoch") else None
    calibrated = open_model(calibration)
    model = _calibrated_scene_model(lab, calibrated)
    band = site.band or model.reference_band
    if band not in model.bands:
        raise InputError(f"the scene has no band {band!r}", path=str(site.scene), field="band")
    for what, p in (("DOM", site.dom), ("DEM", site.dem)):
        if not (Path(p).exists() or set("*?[") & set(str(p))):  # a file, a folder of tiles or a glob
            raise InputError(f"no such {what} file", path=str(p))
    image = read_band(scene, band)
    dem = Dem.open(site.dem, vertical_datum=site.dem_datum, geoid=site.geoid)
    check_dem_heights(dem, model, band=band)
    dom, _ = open_dom(DomSource(items=(str(site.dom),), band=site.dom_band,
                                qa=() if site.dom_qa is None else (str(site.dom_qa),)))
    check_dom_resolution(dom, model, band=band, source=site.dom)
    n_rows, n_cols = model.image_shape
    lon, lat, _ = model.image_to_ground([0.5 * n_rows], [0.5 * n_cols], dem=dem, band=band)
    out["center_lon_deg"], out["center_lat_deg"] = float(lon[0]), float(lat[0])
    # a calibrated model is usually within the fine search radius: the coarse SIFT stage is
    # skipped when a few windows show it (and runs when they do not)
    table, summary = extract_gcps(model, image, dem, dom, band=band,
                                  options=MatchOptions(spacing_px=spacing_px, check_fraction=0.0,
                                                       coarse_skip=coarse_skip, threads=threads))
    out["coarse"] = _coarse_line(summary)
    out["cloud_fraction"] = summary.get("cloud_fraction")
    if table is None or len(table) == 0:
        raise InputError(summary.get("message", "no GCP"), path=str(site.scene))
    pts = points_of(table, model)
    kw = {"band": pts["band"], "ccd": pts["ccd"]}
    acc = check_point_accuracy(model, pts["row"], pts["col"], pts["lon"], pts["lat"], pts["h"], **kw)
    if write_points is not None:  # every point is a check point here: none was fitted
        from calibrate.residual_layer import residual_layer

        write_points(table, site.name, residual_layer(model, table, acc.residuals_px, "check", site=site.name))
    acc_lab = check_point_accuracy(lab, pts["row"], pts["col"], pts["lon"], pts["lat"], pts["h"], **kw)
    out["points"] = int(acc.absolute.n)
    out.update(_accuracy_columns(acc, ""))
    out.update(_accuracy_columns(acc_lab, "lab_"))


def _coarse_line(summary: dict) -> str:
    """What the coarse stage did, in one line: its skip note, or the SIFT inlier count."""
    coarse = summary.get("coarse") or {}
    note = str(coarse.get("note") or "")
    if note.startswith("coarse stage skipped"):
        return note
    return f"coarse stage: SIFT, {coarse.get('inliers', 0)} inliers"


# --------------------------------------------------------------------------- Dask orchestration
def validate_sites(sites, calibrated_model, *, scheduler=None, workers: int = 2, progress=None,
                   spacing_px: int = 32, timeout_s: float = 10.0, write_points=None):
    """Validate a calibration on every scene of ``sites``, one Dask task per scene.

    Parameters
    ----------
    sites : list of Site
        From :func:`read_sites`.
    calibrated_model : str or Path
        The calibrated manifest, or a folder holding ``manifest.json`` (the output folder of
        ``gcpcal calibrate`` or ``gcpcal demo``).
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
    write_points : callable(GcpTable, str, dict), optional
        Given to every task (:func:`validate_scene`): receives each scene's check points, name
        and residual layer, on the worker. Must be picklable (a module-level function or a partial of one).

    Returns
    -------
    rows : list of dict
        One row per site, in the sites' order (keys :data:`COLUMNS`).
    summary : dict
        Means over the scenes that succeeded, counts and timings.

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
    rows: list[dict | None] = [None] * len(sites)
    with dask_log_level():
        n_workers = _run_tasks(sites, str(calib), write_points, rows, scheduler=scheduler, workers=workers,
                               timeout_s=timeout_s, spacing_px=spacing_px, progress=progress)
    summary = summarize_rows(rows)
    summary.update({
        "kind": "gcpcal.validate",
        "calibration": str(calib),
        "scheduler": str(scheduler) if scheduler else "LocalCluster",
        "workers": n_workers,
        "seconds": time.perf_counter() - t0,
    })
    return rows, summary


def _run_tasks(sites, calib: str, write_points, rows: list, *, scheduler, workers, timeout_s, spacing_px,
               progress) -> int:
    """Submit one :func:`validate_scene` per site, fill ``rows`` as they finish; return the worker count."""
    from distributed import as_completed

    client, cluster = connect(scheduler, workers, timeout_s)
    try:
        n_workers = worker_count(client, cluster, scheduler, timeout_s)
        futures = {client.submit(validate_scene, site, calib, write_points=write_points, spacing_px=spacing_px,
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
        rows, summed task wall and CPU seconds, the reason of every failure by scene,
        ``coarse_skipped`` (scenes whose coarse SIFT stage was skipped) and ``coarse`` (by
        scene: "coarse stage skipped: model within N px ..." or "coarse stage: SIFT, K inliers").
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
        "coarse_skipped": sum(1 for r in rows if str(r.get("coarse") or "").startswith("coarse stage skipped")),
        "coarse": {r["name"]: r["coarse"] for r in rows if r.get("coarse")},
    }
