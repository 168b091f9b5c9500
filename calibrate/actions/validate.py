"""Stage action of ``gcpcal validate``: a calibration checked on validation scenes, one Dask task each.

The work is :func:`calibrate.batch.validate_sites` (one Dask task per scene, rows and a
summary); this action reads the sites file, checks the scheduler address the user gave, hands
the sites over and writes the run folder: ``validation.csv``, ``validation.json`` (rows and
summary), ``validation.html`` (the table in the layout of seed 003 table 5 with a mean row, and
a bar plot of the planar RMSE per scene, ``validation_planar.png``), ``points/<name>.csv``
(each scene's check points, written by the tasks through :func:`write_scene_points`) and
``residuals.gpkg`` (every scene's check-point residuals against the calibrated model, one
layer with a ``site`` field holding the scene's name; :mod:`calibrate.residual_layer`).
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from functools import partial
from pathlib import Path

import numpy as np

from calibrate._json import json_safe
from calibrate.batch import COLUMNS
from calibrate.cluster import check_scheduler_address
from calibrate.actions._io import final_paths, staged_folder
from calibrate.actions._provenance import with_provenance
from sensor_models.files.atomic import atomic_folder

__all__ = ["check_scheduler_address", "merge_residual_layers", "run_validation", "validate_calibration",
           "write_outputs", "write_scene_points"]


def validate_calibration(sites_path, calibration, out_dir, *, scheduler=None, workers: int = 2, spacing_px: int = 32,
                         timeout_s: float = 10.0, progress=None) -> dict:
    """Validate ``calibration`` on every scene of the sites file.

    Parameters
    ----------
    sites_path : str or Path
        Sites file (YAML or CSV: name, scene, dom, dem; :func:`calibrate.batch.read_sites`).
    calibration : str or Path
        Calibrated ``manifest.json`` or the folder holding it.
    out_dir : str or Path
        Output folder.
    scheduler : str, optional
        Dask scheduler address; default: a local cluster of ``workers`` processes.
    workers : int
        Worker processes of the local cluster.
    spacing_px : int
        Matching window spacing, pixels.
    timeout_s : float
        Seconds allowed to connect to ``scheduler``.
    progress : callable(done, total, row), optional
        Called once with ``(0, n_sites, None)`` before the work starts, then as each scene
        finishes.

    Returns
    -------
    dict
        The summary of :func:`run_validation` with ``sites_file`` and ``rows``
        (one per scene; a failed scene says why).
    """
    from calibrate.actions._status import calibration_input, open_usable_calibration
    from calibrate.batch import read_sites

    if scheduler is not None:
        check_scheduler_address(scheduler)
    warning = open_usable_calibration(calibration, command="validate")[2]  # a failed calibration is refused
    sites = read_sites(sites_path)
    inputs = [sites_path, calibration_input(calibration)]  # and every scene, DOM and DEM the sites name
    inputs += [[getattr(s, k, None) for k in ("scene", "dom", "dem", "geoid", "dom_qa")] for s in sites]
    with staged_folder(out_dir, ".validate-", inputs=inputs) as stage:
        if progress is not None:
            progress(0, len(sites), None)
        rows, summary = run_validation(sites, calibration, stage, scheduler=scheduler, workers=workers,
                                       progress=progress, spacing_px=spacing_px, timeout_s=timeout_s)
    rows, summary = final_paths(rows, stage, out_dir), final_paths(summary, stage, out_dir)
    summary["sites_file"] = str(sites_path)
    return {**summary, "warnings": [warning] if warning else [], "rows": rows}


def run_validation(sites, calibration, out_dir, *, scheduler=None, workers: int = 2, progress=None,
                   spacing_px: int = 32, timeout_s: float = 10.0, title: str | None = None):
    """Validate ``calibration`` on ``sites`` (:func:`calibrate.batch.validate_sites`) and write the run folder.

    Parameters
    ----------
    sites : list of calibrate.batch.Site
        From :func:`calibrate.batch.read_sites`.
    calibration : str or Path
        The calibrated manifest, or a folder holding ``manifest.json``.
    out_dir : str or Path
        Output folder (module docstring); created if needed.
    scheduler : str, optional
        Dask scheduler address; default: a LocalCluster of ``workers`` processes.
    workers : int
        Worker processes of the LocalCluster.
    progress : callable(done, total, row), optional
        Called each time a scene finishes (in completion order).
    spacing_px : int
        Matching window spacing, pixels.
    timeout_s : float
        Seconds allowed to connect to ``scheduler``.
    title : str, optional
        Title of the HTML page.

    Returns
    -------
    rows : list of dict
        One row per site, in the sites' order (keys :data:`calibrate.batch.COLUMNS`).
    summary : dict
        Means over the scenes that succeeded, counts, timings and the output ``files``.

    Raises
    ------
    InputError
        Unreadable or non-push-broom calibration, no site, unreachable scheduler.
    """
    from calibrate.batch import validate_sites

    out_dir = Path(out_dir)
    points_dir = (out_dir / "points").resolve()
    rows, summary = validate_sites(sites, calibration, scheduler=scheduler, workers=workers, progress=progress,
                                   spacing_px=spacing_px, timeout_s=timeout_s,
                                   write_points=partial(write_scene_points, str(points_dir)))
    summary["residual_layer"] = merge_residual_layers(out_dir, rows)
    summary["files"] = write_outputs(out_dir, rows, summary, title=title)
    summary["files"]["residuals"] = summary["residual_layer"]
    return rows, summary


def write_scene_points(points_dir, table, name: str, residuals: dict | None = None) -> Path:
    """Write one scene's check points to ``points_dir/<name>.csv`` (run on the Dask worker).

    Parameters
    ----------
    points_dir : str or Path
        Folder of the per-scene point files (created if needed).
    table : gcpmatch.gcps.GcpTable
        The scene's check points (pixels, WGS84 degrees, metres).
    name : str
        The scene's name; characters other than letters, digits and ``-_.`` become ``_``.
    residuals : dict, optional
        Their residual layer (:func:`calibrate.residual_layer.residual_layer`), written to
        ``points_dir/<name>_residuals.gpkg`` for :func:`merge_residual_layers` to gather.

    Returns
    -------
    Path
        The CSV file written.
    """
    from calibrate.residual_layer import write_residual_layer
    from gcpmatch.gcp_csv import write_gcps_csv

    Path(points_dir).mkdir(parents=True, exist_ok=True)
    path = Path(points_dir) / f"{_safe_name(name)}.csv"
    write_gcps_csv(table, path)
    if residuals is not None:
        write_residual_layer(residuals, Path(points_dir) / f"{_safe_name(name)}_residuals.gpkg",
                             layer=f"{_safe_name(name)}_residuals")
    return path


def merge_residual_layers(out_dir, rows) -> str:
    """Gather the scenes' residual layers into ``out_dir/residuals.gpkg`` (one layer, ``site`` field).

    The per-scene files ``points/<name>_residuals.gpkg`` the tasks wrote are read in the sites'
    order and removed; a scene that failed contributes no point.

    Parameters
    ----------
    out_dir : str or Path
        The run folder (holding ``points/``).
    rows : sequence of dict
        Per-scene rows (``name``), in the sites' order.

    Returns
    -------
    str
        ``"residuals.gpkg"``, the layer's name relative to ``out_dir``.
    """
    from calibrate.residual_layer import LAYER_NAMES, concatenate_layers, read_residual_layer, write_residual_layer

    points_dir = Path(out_dir) / "points"
    parts = [points_dir / f"{_safe_name(r['name'])}_residuals.gpkg" for r in rows]
    parts = [p for p in dict.fromkeys(parts) if p.is_file()]
    write_residual_layer(concatenate_layers(read_residual_layer(p) for p in parts), Path(out_dir) / "residuals.gpkg",
                         layer=LAYER_NAMES["validate"])
    for p in parts:
        p.unlink()
    return "residuals.gpkg"


def _safe_name(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "scene"


# --------------------------------------------------------------------------- the run folder
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
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({c: _csv_cell(r.get(c)) for c in COLUMNS})
        (tmp / files["csv"]).write_text(buf.getvalue(), encoding="utf-8")
        doc = json_safe({**summary, "files": files, "columns": list(COLUMNS), "rows": rows})
        (tmp / files["json"]).write_text(json.dumps(with_provenance(doc), indent=1, allow_nan=False) + "\n", encoding="utf-8")
        _bar_plot(rows, summary, tmp / files["plot"])
        (tmp / files["html"]).write_text(_html_page(rows, summary, files, title), encoding="utf-8")
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

