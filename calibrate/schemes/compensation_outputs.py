"""Outputs of seed 002's compensation study: table (JSON, CSV), Markdown summary and figures.

:func:`write_study` writes ``table.json``, ``table.csv``, ``summary.md`` (:func:`summary_markdown`:
ours beside seed 002 table 3, with the reason for each scheme's result) and the pointing-angle
maps of :data:`FIGURES` (seed 002 figures 4-10) of a
:class:`calibrate.schemes.compensation_study.CompensationStudy`, all at once: a failure leaves
the previous outputs and no partial folder.
"""

from __future__ import annotations

import math
import time

import numpy as np

from calibrate.schemes.compensation_study import CompensationStudy
from sensor_models.errors import InputError

__all__ = ["CSV_COLUMNS", "FIGURES", "summary_markdown", "write_study"]

#: figure cases: key of CompensationStudy.pointing -> (file name, title; seed 002 figure)
FIGURES = {
    "distortion": ("fig04_distortion.png", "Distortion alone, no installation error (seed 002 fig. 4)"),
    "interior_no_installation": ("fig05_interior_fit.png", "After interior compensation, no installation error (fig. 5)"),
    "before": ("before.png", "Before compensation: LAB model"),
    "ICO": ("fig07_ico.png", "ICO: interior only (seed 002 fig. 7)"),
    "ECO": ("fig08_eco.png", "ECO: exterior only (seed 002 fig. 8)"),
    "ICBEC": ("fig09_icbec.png", "ICBEC: interior, then exterior (seed 002 fig. 9)"),
    "ECBIC": ("fig10_ecbic.png", "ECBIC: exterior, then interior (seed 002 fig. 10)"),
    "joint": ("joint.png", "joint: exterior + interior, gauge held"),
    "ICO-g": ("ico_gauge.png", "ICO-g: gauge-held interior only"),
}


CSV_COLUMNS = ("scheme", "success", "mean_x_px", "mean_y_px", "rms_x_px", "rms_y_px", "total_px", "max_px",
               "seed_x_px", "seed_y_px", "seed_total_px", "roll_arcsec", "pitch_arcsec", "yaw_arcsec", "seconds")


def _figure(study: CompensationStudy, key: str, path) -> None:
    """Two colour maps (X, Y pointing-angle difference in pixels) over the check grid."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dx, dy = study.pointing[key]
    k = study.check.grid_shape[0]
    n_rows, n_cols = study.truth.image_shape
    fig = Figure(figsize=(12.0, 4.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    fig.subplots_adjust(left=0.06, right=0.97, wspace=0.35)
    extent = (study.check.col.min(), study.check.col.max(), study.check.row.max(), study.check.row.min())
    for ax, values, label in zip(axes, (dx, dy), ("X (column)", "Y (row)")):
        grid = values.reshape(k, k) if values.size == k * k else values
        lim = float(np.nanmax(np.abs(values))) if np.any(np.isfinite(values)) else 1.0
        lim = lim if lim > 0.0 else 1.0
        im = ax.imshow(np.atleast_2d(grid), extent=extent, cmap="RdBu_r", aspect="equal",
                       interpolation="nearest", vmin=-lim, vmax=lim)
        ax.set_title(f"pointing-angle difference {label}")
        ax.set_xlabel("column (px)")
        ax.set_ylabel("row (px)")
        ax.set_xlim(0, n_cols)
        ax.set_ylim(n_rows, 0)
        fig.colorbar(im, ax=ax, label="pixels (x IFOV = angle)")
    fig.suptitle(FIGURES[key][1])
    fig.savefig(path, format="png")


def _fmt(v, digits=4):
    if v is None:
        return ""
    if isinstance(v, float):
        if not math.isfinite(v):
            return "nan"
        return f"{v:.{digits}g}" if abs(v) >= 1e-3 or v == 0.0 else f"{v:.2e}"
    return str(v)


def _csv_rows(rows):
    out = [",".join(CSV_COLUMNS)]
    for r in rows:
        inst = r["installation_arcsec"]
        vals = {**r, "roll_arcsec": inst[0], "pitch_arcsec": inst[1], "yaw_arcsec": inst[2]}
        out.append(",".join("" if vals.get(c) is None else repr(vals[c]) if isinstance(vals[c], float)
                            else str(vals[c]) for c in CSV_COLUMNS))
    return "\n".join(out) + "\n"


def summary_markdown(study: CompensationStudy) -> str:
    """Markdown table (ours beside seed 002 table 3) with the reason for each scheme's result.

    Parameters
    ----------
    study : CompensationStudy
        Of :func:`run_seed002`.

    Returns
    -------
    str
        Markdown text.
    """
    s = study.settings
    lines = [
        "# Seed 002 compensation schemes on a GF-4-like staring camera",
        "",
        f"Array {s['image_shape'][0]} x {s['image_shape'][1]} px (IFOV {s['ifov_arcsec']:.3f} arcsec), "
        f"{s['n_vcp']} virtual control points every {s['step_px']:g} px from {s['start_px']:g} to "
        f"{s['stop_px']:g}, noise {s['noise_px']:g} px; {s['n_check']} check points offset by half a step. "
        f"Installation error {s['installation_error_arcsec']} arcsec (table 2), distortion of table 1.",
        "",
        "| scheme | X mean px | Y mean px | RMS X px | RMS Y px | total px | max px | seed X | seed Y | "
        "seed total | roll, pitch, yaw (arcsec) | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in study.rows:
        inst = ", ".join(f"{a:.2f}" for a in r["installation_arcsec"])
        lines.append("| " + " | ".join([
            r["scheme"], _fmt(r["mean_x_px"]), _fmt(r["mean_y_px"]), _fmt(r["rms_x_px"]), _fmt(r["rms_y_px"]),
            _fmt(r["total_px"]), _fmt(r["max_px"]), _fmt(r["seed_x_px"]), _fmt(r["seed_y_px"]),
            _fmt(r["seed_total_px"]), inst, f"{r['seconds']:.2f}"]) + " |")
    lines += ["", f"Best scheme: **{study.best}**.", "", "## Why the schemes rank as they do", ""]
    for r in study.rows:
        lines.append(f"- **{r['scheme']}**: {r['explanation']}")
    lines += ["", "## Figures (pointing-angle differences, compensated minus true, body frame)", ""]
    for key, (name, title) in FIGURES.items():
        if key in study.pointing:
            lines.append(f"- [{title}](figures/{name})")
    return "\n".join(lines) + "\n"


def write_study(study: CompensationStudy, out_dir, *, figures: bool = True) -> dict:
    """Write ``table.json``, ``table.csv``, ``summary.md`` and ``figures/*.png`` atomically.

    Everything is built in a temporary folder beside ``out_dir`` and moved into place with
    :func:`os.replace` (an existing ``out_dir`` is replaced as a whole), so a failure leaves
    the previous outputs and no partial folder.

    Parameters
    ----------
    study : CompensationStudy
        Of :func:`run_seed002`.
    out_dir : path
        Output folder (replaced as a whole).
    figures : bool
        Also draw the PNG figures.

    Returns
    -------
    dict
        The ``table.json`` document.
    """
    import json
    from pathlib import Path

    from sensor_models.files.atomic import atomic_folder

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a folder", path=str(out_dir))
    with atomic_folder(out_dir, mode="replace") as tmp:  # the study's folder is replaced whole
        t0 = time.perf_counter()
        doc = study.to_dict()
        names = {}
        if figures:
            (tmp / "figures").mkdir()
            for key, (name, _title) in FIGURES.items():
                if key in study.pointing:
                    _figure(study, key, tmp / "figures" / name)
                    names[key] = f"figures/{name}"
        doc["figures"] = names
        doc["timings"]["figures_s"] = time.perf_counter() - t0
        (tmp / "table.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        (tmp / "table.csv").write_text(_csv_rows(study.rows), encoding="utf-8")
        (tmp / "summary.md").write_text(summary_markdown(study), encoding="utf-8")
    return doc
