"""HTML report with PNG figures for the star-track calibration (seed 000).

:func:`write_star_report` turns the document of :meth:`calibrate.star_calibration.StarCalibrationResult.to_dict`
(``points=True``; what ``gcpcal stars`` writes to ``stars.json``) into ``out_dir/report.html``, one
self-contained HTML file (inline CSS, no script) referencing PNG figures in ``out_dir/figures/``.

Figures
-------
``star_tracks.png``
    The observed centroids of every track over the frame, one colour per track (HIP id), the
    smoothing-spline curve (seed 000 eq. 2) as a thin line, held-out points as open circles and
    points rejected by the spline test as crosses.
``radec_errors.png``
    RA and DE errors (seed 000 eq. 18-19, pixels) of the held-out points before and after
    calibration, one scatter panel each with its own scale, the mean marked and the 2-sigma
    box drawn; seed 000 table 3's mean initial error is marked in the "before" panel.
``error_histograms.png``
    RA and DE errors after calibration: histogram, fitted normal density and its 2-sigma
    bounds (seed 000 figure 7 and table 4).
``error_vs_points.png``
    Mean absolute error and 2-sigma of the held-out points against the calibration points per
    track (seed 000 figure 8), when the document has ``versus_points``.

The per-point errors are not part of the document (only their statistics are); they are taken
from ``points`` when it has ``ra_before_px, de_before_px, ra_after_px, de_after_px`` (one
value per point, None where not held out), else recomputed from a
:class:`~calibrate.star_calibration.StarCalibrationResult` passed as ``result`` (:func:`held_out_errors`).
Without either, the two error figures show the fitted normal curves from the document's
statistics only and say so.

Output is atomic like :func:`calibrate.report.write_report`: built in a temporary folder inside
``out_dir`` and moved into place at the end; a failure leaves the previous report (or nothing)
and no temporary folder. Figures use :class:`matplotlib.figure.Figure` on an Agg canvas, never
``pyplot``.

References
----------
Seed 000: on-orbit geometric calibration of a geostationary camera from the relative motion of
stars (eq. 2, 18-19; tables 3-4; figures 7-8).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from calibrate.report._html import CSS as _CSS, escape as _e, figure_html as _figure_html, fmt as _fmt
from calibrate.report._html import new_figure as _new_figure, save_figure as _save, table as _table
from sensor_models.errors import InputError
from sensor_models.files.atomic import atomic_folder, replace_tree

__all__ = ["SEED_000", "held_out_errors", "star_census", "write_star_report"]

#: Published figures of seed 000 (real data, 20 days; table 3 means, table 4 normal fits).
SEED_000 = {
    "before": {"ra": {"mean_px": -6.795}, "de": {"mean_px": -21.004}},
    "after": {
        "ra": {"mean_px": -0.148, "mean_abs_px": 0.84175, "fit_mean_px": -0.0611,
               "mean_ci_px": (-0.1661, 0.0440), "std_px": 1.1187, "std_ci_px": (1.0492, 1.1982),
               "two_sigma_px": 2.24},
        "de": {"mean_px": 0.529, "mean_abs_px": 0.8534, "fit_mean_px": 0.0234,
               "mean_ci_px": (-0.0870, 0.1338), "std_px": 1.1754, "std_ci_px": (1.1024, 1.2589),
               "two_sigma_px": 2.35},
    },
    "fraction_within_two_sigma": 0.9544,
}
_ERROR_KEYS = ("ra_before_px", "de_before_px", "ra_after_px", "de_after_px")
_POINT_KEYS = ("hip", "frame", "row", "col", "check")


# --------------------------------------------------------------------------- per-point errors
def held_out_errors(result) -> dict:
    """RA/DE errors of every held-out point before and after calibration (seed 000 eq. 18-19).

    Recomputes what :func:`calibrate.star_calibration.process_frames` summarizes in ``accuracy``: the LAB
    model (``result.initial``) and the calibrated one (``result.model``) map the measured
    centroid, with the attitude of the point's frame, to ``(sigma', delta')``, compared with
    the catalogue's apparent direction (:func:`calibrate.star_accuracy.radec_errors_px`).

    Parameters
    ----------
    result : StarCalibrationResult
        With ``model`` and ``observations`` (N points).

    Returns
    -------
    dict of str to ndarray, shape (N,)
        ``ra_before_px, de_before_px, ra_after_px, de_after_px``: NaN where the point is not
        held out (pixels, one pixel = the LAB IFOV).
    """
    from calibrate.star_accuracy import radec_errors_px

    obs, model = getattr(result, "observations", None), getattr(result, "model", None)
    if obs is None or model is None:
        raise InputError("needs the calibrated model and the observations", field="result")
    n = obs.hip.size
    out = {k: np.full(n, np.nan) for k in _ERROR_KEYS}
    chk = np.flatnonzero(obs.check)
    if chk.size == 0:
        return out
    initial = model.with_parameters(np.asarray(result.initial, dtype=np.float64))
    frames, first, inv = np.unique(obs.frame[chk], return_index=True, return_inverse=True)
    # body_to_gcrf depends on the attitude and time only, not on the calibrated parameters
    b = np.stack([model.at_frame(float(s)).body_to_gcrf for s in obs.seconds[chk][first]])[inv]
    args = (b, obs.row[chk], obs.col[chk], obs.vectors_gcrf[chk])
    for which, m in (("before", initial), ("after", model)):
        ra, de, _ = radec_errors_px(m, *args, pixel_rad=initial.ifov_rad)
        out[f"ra_{which}_px"][chk] = ra
        out[f"de_{which}_px"][chk] = de
    return out


# --------------------------------------------------------------------------- entry point
def write_star_report(out_dir, result_doc: Mapping, *, result=None,
                      title: str = "gcpcal star-track calibration report") -> Path:
    """Write ``out_dir/report.html`` and its figures ``out_dir/figures/*.png``.

    Parameters
    ----------
    out_dir : path
        Created if needed; a previous ``report.html`` and ``figures/`` are replaced.
    result_doc : mapping
        :meth:`StarCalibrationResult.to_dict` with ``points=True`` (``stars.json``): keys
        ``success, message, scheme, accuracy, frames`` are required; ``points`` (arrays of
        one length N: ``hip, frame, row, col, check`` and optionally ``rejected``,
        ``row_smooth``, ``col_smooth`` and the per-point errors of :func:`held_out_errors`),
        ``parameters``, ``initial_parameters``, ``installation_correction_arcsec``, ``sigma``,
        ``runs``, ``tracks``, ``versus_points``, ``timings``, ``inputs`` are used when present.
    result : StarCalibrationResult, optional
        The same run's result, to recompute the per-point errors when ``points`` lacks them.
    title : str

    Returns
    -------
    Path
        ``out_dir/report.html``.

    Raises
    ------
    InputError
        A malformed document (missing keys, wrong types, arrays of different lengths);
        nothing is written then.
    """
    doc = _check_doc(result_doc)
    points = _points(doc.get("points"))
    if points is not None and not all(k in points for k in _ERROR_KEYS) and result is not None:
        errors = held_out_errors(result)
        if errors["ra_before_px"].size != points["row"].size:
            raise InputError(f"{errors['ra_before_px'].size} result points for {points['row'].size} document points",
                             field="result")
        points.update(errors)
    shape = getattr(getattr(result, "model", None), "image_shape", None)

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        fig_dir = tmp / "figures"
        fig_dir.mkdir()
        figures = {
            "tracks": _figure_tracks(points, shape, fig_dir) if points is not None and points["hip"].size else None,
            "errors": _figure_errors(doc, points, fig_dir),
            "histograms": _figure_histograms(doc, points, fig_dir),
            "versus": _figure_versus(doc.get("versus_points") or [], fig_dir),
        }
        (tmp / "report.html").write_text(_html(doc, points, figures, str(title)), encoding="utf-8")
        replace_tree(tmp / "figures", out_dir / "figures")  # no figure of an earlier report survives
    return out_dir / "report.html"


# --------------------------------------------------------------------------- inputs
def _check_doc(doc) -> dict:
    if not isinstance(doc, Mapping):
        raise InputError(f"must be a mapping (stars.json), got {type(doc).__name__}", field="result_doc")
    types = {"success": bool, "message": str, "scheme": str, "accuracy": Mapping, "frames": Mapping}
    for key, kind in types.items():
        if key not in doc:
            raise InputError("missing", field=key)
        if not isinstance(doc[key], kind):
            raise InputError(f"must be {kind.__name__}, got {type(doc[key]).__name__}", field=key)
    for key in ("parameters", "initial_parameters", "installation_correction_arcsec", "sigma", "timings", "inputs"):
        if doc.get(key) is not None and not isinstance(doc[key], Mapping):
            raise InputError(f"must be a mapping, got {type(doc[key]).__name__}", field=key)
    for key in ("runs", "tracks", "versus_points"):
        value = doc.get(key)
        if value is not None and not (isinstance(value, list) and all(isinstance(v, Mapping) for v in value)):
            raise InputError("must be a list of mappings", field=key)
    for which, acc in doc["accuracy"].items():
        if which == "n" or not isinstance(acc, Mapping):
            raise InputError("must map before/after to statistics", field=f"accuracy.{which}")
    return dict(doc)


def _points(points) -> dict | None:
    """Per-point arrays (float, NaN for None; ``check``/``rejected`` bool), all of one length."""
    if points is None:
        return None
    if not isinstance(points, Mapping):
        raise InputError(f"must be a mapping of arrays, got {type(points).__name__}", field="points")
    missing = [k for k in _POINT_KEYS if k not in points]
    if missing:
        raise InputError(f"missing {missing}", field="points")
    out = {}
    for key, value in points.items():
        if key not in _POINT_KEYS + _ERROR_KEYS + ("rejected", "row_smooth", "col_smooth", "seconds"):
            continue
        try:
            if key in ("check", "rejected"):
                arr = np.asarray(value, dtype=bool).reshape(-1)
            else:
                arr = np.asarray([np.nan if v is None else v for v in value], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise InputError("must be a list of numbers", field=f"points.{key}") from None
        out[key] = arr
    n = out["hip"].size
    for key, arr in out.items():
        if arr.size != n:
            raise InputError(f"has {arr.size} values for {n} points", field=f"points.{key}")
    out.setdefault("rejected", np.zeros(n, bool))
    out["hip"] = out["hip"].astype(np.int64)
    return out


def _stat(doc, which, axis, key):
    acc = doc["accuracy"].get(which) or {}
    value = (acc.get(axis) or {}).get(key) if isinstance(acc.get(axis), Mapping) else None
    return value


# --------------------------------------------------------------------------- figures
def _track_colors(n):
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(k % cmap.N) for k in range(n)]


def _figure_tracks(p: dict, shape, fig_dir: Path) -> dict:
    """Observed centroids coloured by track; spline curves; held-out and rejected points."""
    row, col = p["row"], p["col"]
    if shape is not None:
        n_rows, n_cols = float(shape[0]), float(shape[1])
    else:
        n_rows = float(np.nanmax(row, initial=1.0)) * 1.05
        n_cols = float(np.nanmax(col, initial=1.0)) * 1.05
    ratio = n_rows / max(n_cols, 1.0)
    width, left, right, bottom, top = 9.0, 0.8, 1.7, 0.6, 0.3
    panel_h = float(np.clip((width - left - right) * ratio, 3.0, 9.0))
    fig = _new_figure(width, panel_h + bottom + top, left=left, right=right, bottom=bottom, top=top)
    ax = fig.subplots()
    hips, track = np.unique(p["hip"], return_inverse=True)
    colors = np.array(_track_colors(hips.size))
    plain = ~p["check"] & ~p["rejected"]
    ax.scatter(col[plain], row[plain], s=9, c=colors[track[plain]], lw=0)
    if "row_smooth" in p and "col_smooth" in p:
        for k in range(hips.size):  # one curve per track (tens of tracks, not a per-point loop)
            sel = np.flatnonzero((track == k) & np.isfinite(p["row_smooth"]))
            sel = sel[np.argsort(col[sel])]
            ax.plot(p["col_smooth"][sel], p["row_smooth"][sel], color=colors[k], lw=0.7, alpha=0.8)
    chk = p["check"]
    ax.scatter(col[chk], row[chk], s=36, facecolors="none", edgecolors=colors[track[chk]], lw=1.2)
    rej = p["rejected"]
    ax.scatter(col[rej], row[rej], s=30, marker="x", c="#b3261e", lw=1.0)
    ax.set_xlim(0.0, n_cols)
    ax.set_ylim(n_rows, 0.0)
    ax.set_aspect("equal" if 0.25 < ratio < 4.0 else "auto")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.grid(True, lw=0.3, alpha=0.5)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], ls="", marker="o", ms=4, color="0.3"),
               Line2D([], [], ls="", marker="o", ms=7, mfc="none", mec="0.3"),
               Line2D([], [], ls="", marker="x", ms=6, color="#b3261e"), Line2D([], [], color="0.3", lw=0.7)]
    ax.legend(handles, ["calibration point", "held out", "rejected", "smoothing spline"], fontsize=8,
              loc="upper left", bbox_to_anchor=(1.01, 1.0))
    caption = (f"Star tracks: {row.size} identified centroids of {hips.size} catalogue stars over the frame, one "
               f"colour per track; open circles: the {int(chk.sum())} held-out points; crosses: {int(rej.sum())} "
               f"points rejected by the smoothing-spline test; lines: the smoothing splines (seed 000 eq. 2).")
    return {"src": _save(fig, fig_dir, "star_tracks.png"), "caption": caption}


def _errors_of(p, which):
    """Finite (ra, de, track) of the held-out points, or None without per-point errors."""
    if p is None or f"ra_{which}_px" not in p:
        return None
    ra, de = p[f"ra_{which}_px"], p[f"de_{which}_px"]
    ok = p["check"] & np.isfinite(ra) & np.isfinite(de)
    return ra[ok], de[ok], p["hip"][ok]


def _figure_errors(doc, p, fig_dir: Path) -> dict | None:
    """Held-out RA/DE errors before and after calibration (scatter, own scale per panel)."""
    data = {w: _errors_of(p, w) for w in ("before", "after")}
    if data["before"] is None or data["after"] is None or data["after"][0].size == 0:
        return None
    fig = _new_figure(11.0, 5.0, wspace=0.3)
    axes = fig.subplots(1, 2)
    hips = np.unique(p["hip"])
    colors = np.array(_track_colors(hips.size))
    for ax, which in zip(axes, ("before", "after")):
        ra, de, hip = data[which]
        ax.scatter(ra, de, s=14, c=colors[np.searchsorted(hips, hip)], lw=0)
        mr, md = float(np.mean(ra)), float(np.mean(de))
        sr, sd = (float(np.std(ra, ddof=1)), float(np.std(de, ddof=1))) if ra.size > 1 else (0.0, 0.0)
        ax.plot([mr], [md], marker="+", ms=14, color="k", mew=1.5, ls="", label="mean")
        ax.add_patch(_rectangle(mr - 2 * sr, md - 2 * sd, 4 * sr, 4 * sd))
        half = max(float(np.max(np.abs(np.r_[ra - mr, de - md]))), 2.0 * max(sr, sd), 1e-6) * 1.25
        cr, cd = mr, md
        if which == "before":
            seed = SEED_000["before"]
            ax.plot([seed["ra"]["mean_px"]], [seed["de"]["mean_px"]], marker="*", ms=12, color="#c0392b", ls="",
                    label="seed 000 table 3 mean")
            lo_r, hi_r = min(mr - half, seed["ra"]["mean_px"] - 1), max(mr + half, seed["ra"]["mean_px"] + 1)
            lo_d, hi_d = min(md - half, seed["de"]["mean_px"] - 1), max(md + half, seed["de"]["mean_px"] + 1)
            half = 0.5 * max(hi_r - lo_r, hi_d - lo_d)
            cr, cd = 0.5 * (lo_r + hi_r), 0.5 * (lo_d + hi_d)
        ax.set_xlim(cr - half, cr + half)
        ax.set_ylim(cd - half, cd + half)
        ax.set_aspect("equal")
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.axvline(0.0, color="0.6", lw=0.6)
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.set_xlabel("RA error (px)")
        ax.set_ylabel("DE error (px)")
        ax.set_title(f"{which} calibration: mean ({mr:.3g}, {md:.3g}) px, n={ra.size}", loc="left", fontsize=10)
        ax.legend(fontsize=8, loc="upper right")
    caption = ("RA and DE errors of the held-out points (seed 000 eq. 18-19, pixels of the LAB IFOV; RA as a "
               "difference of right ascensions) before and after calibration, one colour per track, each panel "
               "with its own scale; +: mean, box: mean ± 2σ; star: seed 000's mean initial error (table 3).")
    return {"src": _save(fig, fig_dir, "radec_errors.png"), "caption": caption}


def _rectangle(x, y, w, h):
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, fill=False, ec="0.25", ls="--", lw=0.9, label="mean ± 2σ")


def _figure_histograms(doc, p, fig_dir: Path) -> dict | None:
    """RA/DE errors after calibration: histogram, fitted normal and 2-sigma bounds (fig. 7)."""
    from calibrate.accuracy import fit_normal

    data = _errors_of(p, "after")
    fits = {}
    for j, axis in enumerate(("ra", "de")):
        if data is not None and data[j].size >= 2:
            fits[axis] = fit_normal(data[j])
        elif _stat(doc, "after", axis, "std_px") is not None and _stat(doc, "after", axis, "mean_px") is not None:
            fits[axis] = None  # curve from the document's statistics only
    if not fits:
        return None
    fig = _new_figure(11.0, 3.9, wspace=0.22)
    axes = np.atleast_1d(fig.subplots(1, len(fits), squeeze=False)[0])
    for ax, (axis, fit) in zip(axes, fits.items()):
        if fit is not None:
            mean, std, n = fit.mean, fit.std, fit.n
            edges = np.asarray(fit.bin_edges, dtype=np.float64)
            ax.bar(edges[:-1], fit.counts, width=np.diff(edges), align="edge", color="#9dbbd8", edgecolor="#4a7bab",
                   lw=0.4, label="held-out points")
            scale, ylabel = n * float(np.mean(np.diff(edges))), "held-out points"
            within = fit.fraction_within_two_sigma
        else:
            mean, std = float(_stat(doc, "after", axis, "mean_px")), float(_stat(doc, "after", axis, "std_px"))
            scale, ylabel = 1.0, "probability density (1/px)"
            within = _stat(doc, "after", axis, "fraction_within_two_sigma")
        if std > 0.0:
            x = np.linspace(mean - 4.0 * std, mean + 4.0 * std, 400)
            if fit is not None:
                x = np.linspace(min(x[0], edges[0]), max(x[-1], edges[-1]), 400)
            z = (x - mean) / std
            ax.plot(x, scale * np.exp(-0.5 * z * z) / (std * math.sqrt(2.0 * math.pi)), color="#c0392b", lw=1.5,
                    label="normal fit")
        for bound in (mean - 2.0 * std, mean + 2.0 * std):
            ax.axvline(bound, color="#c0392b", ls="--", lw=1.0)
        ax.axvline(mean, color="0.3", lw=0.8)
        share = "" if within is None else f", {100.0 * float(within):.1f} % within ±2σ"
        ax.set_title(f"{axis.upper()} error: μ = {mean:.3g} px, σ = {std:.3g} px{share}", loc="left", fontsize=9)
        ax.set_xlabel(f"{axis.upper()} error after calibration (px)")
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=8, loc="upper right")
    caption = ("RA and DE errors of the held-out points after calibration with the fitted normal density "
               "(scaled to counts) and its 2σ bounds, dashed (seed 000 figure 7, table 4).")
    if any(f is None for f in fits.values()):
        caption = ("Normal densities of the RA and DE errors after calibration from the document's statistics "
                   "(mean and standard deviation; the per-point errors are not in the document) with their 2σ "
                   "bounds, dashed (seed 000 figure 7, table 4).")
    return {"src": _save(fig, fig_dir, "error_histograms.png"), "caption": caption}


def _figure_versus(rows, fig_dir: Path) -> dict | None:
    """Mean absolute error and 2-sigma against calibration points per track (seed 000 fig. 8)."""
    rows = [r for r in rows if r.get("points_per_track") is not None]
    if not rows:
        return None
    n = np.array([float(r["points_per_track"]) for r in rows])

    def col(key):
        return np.array([np.nan if r.get(key) is None else float(r[key]) for r in rows])

    fig = _new_figure(7.5, 4.3)
    ax = fig.subplots()
    for key, label, style, color in (("ra_mean_abs_px", "RA mean |error|", "o-", "#1f5fa8"),
                                     ("de_mean_abs_px", "DE mean |error|", "s-", "#c0392b"),
                                     ("ra_two_sigma_px", "RA 2σ", "o--", "#1f5fa8"),
                                     ("de_two_sigma_px", "DE 2σ", "s--", "#c0392b")):
        y = col(key)
        if np.any(np.isfinite(y)):
            ax.plot(n, y, style, color=color, ms=5, lw=1.1, mfc="none" if "--" in style else color, label=label)
    ax.set_xlabel("calibration points per track")
    ax.set_ylabel("held-out error (px)")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=8)
    failed = [int(r["points_per_track"]) for r in rows if r.get("success") is False]
    caption = ("Accuracy on the same held-out points when each track gives only n calibration points "
               "(tracks with fewer keep all; seed 000 figure 8)")
    if failed:
        caption += f"; calibration failed with {', '.join(map(str, failed))} points per track"
    return {"src": _save(fig, fig_dir, "error_vs_points.png"), "caption": caption + "."}


# --------------------------------------------------------------------------- HTML
def _html(doc, points, figures, title) -> str:
    sections = [("summary", "Summary", _section_summary(doc, points) + _figure_html(figures["tracks"]))]
    sections.append(("accuracy", "Accuracy on the held-out points",
                     _section_accuracy(doc, points) + _figure_html(figures["errors"])
                     + _figure_html(figures["histograms"])))
    sections.append(("parameters", "Parameters", _section_parameters(doc)))
    if doc.get("versus_points"):
        sections.append(("versus-points", "Error versus number of track points",
                         _figure_html(figures["versus"]) + _section_versus(doc["versus_points"])))
    if doc.get("tracks"):
        sections.append(("tracks", "Tracks", _section_tracks(doc["tracks"])))
    sections.append(("convergence", "Convergence runs", _section_runs(doc.get("runs") or [])))
    if doc.get("timings"):
        sections.append(("timings", "Timings", _table(["stage", "seconds"], [
            [_e(k), _fmt(v)] for k, v in doc["timings"].items()], left=1)))
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    nav = "".join(f'<a href="#{sid}">{_e(name)}</a>' for sid, name, _ in sections)
    body = "".join(f'<section id="{sid}"><h2>{_e(name)}</h2>{content}</section>' for sid, name, content in sections)
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
            f'<h1>{_e(title)}</h1><p class="meta">gcpcal star-track calibration report (seed 000), generated {stamp}</p>'
            f"<nav>{nav}</nav>{body}</body></html>\n")


def star_census(doc, points) -> dict:
    """What the frames held: frames with a tracked star, detections on and off the star tracks.

    A detection counts as a star only when it lies on a track (a catalogue star followed from
    frame to frame, :func:`calibrate.star_calibration.process_frames`); identified detections that formed
    no track are chance matches of noise with the catalogue.

    Parameters
    ----------
    doc : mapping
        ``stars.json``: ``frames`` with ``n_frames``, ``n_detections``, ``n_identified``,
        ``n_tracks``, ``n_points``.
    points : dict or None
        Per-point arrays (:func:`_points`): the track points, with their ``frame``.

    Returns
    -------
    dict
        ``n_frames, n_detections, n_identified, n_tracks, n_track_points`` (int or None),
        ``frames_without_track`` (int or None: frames holding no track point) and ``starless``
        (bool: no star track in any frame).
    """
    f = doc["frames"]

    def count(key):
        value = f.get(key)
        return int(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    n_frames, n_points = count("n_frames"), count("n_points")
    if points is not None:
        n_points = int(points["hip"].size)
    with_track = None if points is None else int(np.unique(points["frame"][np.isfinite(points["frame"])]).size)
    n_tracks = count("n_tracks")
    return {"n_frames": n_frames, "n_detections": count("n_detections"), "n_identified": count("n_identified"),
            "n_tracks": n_tracks, "n_track_points": n_points,
            "frames_without_track": None if with_track is None or n_frames is None else n_frames - with_track,
            "starless": n_tracks == 0 or n_points == 0}


def _starless_note(c: dict) -> str:
    """The paragraph that says the frames hold no star (``c``: :func:`star_census`)."""
    chance = c["n_identified"] or 0
    matches = (f" ({chance} chance match{'es' if chance != 1 else ''} with catalogue stars formed no track)"
               if chance else "")
    frames = "any frame" if c["n_frames"] is None else f"any of the {c['n_frames']} frames"
    if c["n_detections"] is None:
        detections = "no detection lies on a star track"
    else:
        detections = f"none of the {c['n_detections']} detections lies on a star track"
    return (f'<p class="fail">No star identified in {_e(frames)}: {_e(detections)}{_e(matches)}; they are noise '
            "or hot pixels. Check that the frames look at the sky (the pointing mirror turned to deep space), "
            "their exposure, and the manifest's attitude and times.</p>")


def _census_rows(c: dict) -> list:
    """Summary rows for frames and detections (``c``: :func:`star_census`)."""
    dash = lambda v: "–" if v is None else str(v)  # noqa: E731
    if c["starless"]:
        frames = f"{dash(c['n_frames'])} (no star track in any)"
        detections = (f"{dash(c['n_detections'])}, none on a star track: noise or hot pixels "
                      f"({dash(c['n_identified'])} chance catalogue matches)")
    else:
        frames = f"{dash(c['n_frames'])} ({dash(c['frames_without_track'])} without a tracked star)"
        detections = (f"{dash(c['n_detections'])} detections, {dash(c['n_identified'])} matched to catalogue stars, "
                      f"{dash(c['n_track_points'])} on star tracks")
    return [("Frames", _e(frames)), ("Detections", _e(detections))]


def _section_summary(doc, points=None) -> str:
    f = doc["frames"]
    census = star_census(doc, points)
    status = '<span class="ok">success</span>' if doc["success"] else '<span class="fail">failed</span>'
    offset = f.get("offset_px")
    items = [
        ("Status", status), ("Message", _e(doc["message"])), ("Scheme", _e(doc["scheme"])),
        *_census_rows(census),
        ("Tracks", _e(f.get("n_tracks", "–"))),
        ("Track points", f"{_e(f.get('n_points', '–'))} ({_e(f.get('n_calibration_points', '–'))} calibration, "
                         f"{_e(f.get('n_check_points', '–'))} held out)"),
        ("Identification offset (row, col)",
         "–" if not offset or census["starless"] else f"({_fmt(offset[0])}, {_fmt(offset[1])}) px"),
    ]
    for key, value in (doc.get("inputs") or {}).items():
        items.append((_e(f"Input: {key}"), _e(value)))
    if doc.get("calibrated_manifest"):
        items.append(("Calibrated manifest", _e(doc["calibrated_manifest"])))
    note = _starless_note(census) if census["starless"] else ""
    return note + _table(None, items, left=2)


def _section_accuracy(doc, points=None) -> str:
    acc = doc["accuracy"]
    if not acc:
        if star_census(doc, points)["starless"]:
            return "<p>No accuracy: no star track to calibrate from.</p>"
        return "<p>No accuracy: the calibration did not run.</p>"
    header = ["model", "error", "n", "mean (px)", "mean |e| (px)", "RMS (px)", "max |e| (px)", "σ (px)",
              "2σ (px)", "2σ bounds (px)", "μ CI 95 % (px)", "σ CI 95 % (px)", "within 2σ"]
    labels = {"before": "LAB (before)", "after": "calibrated (after)", "joint_after": "joint scheme (after)"}
    rows = []
    for which, a in acc.items():
        for axis in ("ra", "de"):
            s = a.get(axis)
            if not isinstance(s, Mapping):
                continue
            pair = lambda key: "–" if not s.get(key) else f"({_fmt(s[key][0])}, {_fmt(s[key][1])})"  # noqa: E731
            within = s.get("fraction_within_two_sigma")
            rows.append([_e(labels.get(which, which)), axis.upper(), _e(a.get("n", "–")), _fmt(s.get("mean_px")),
                         _fmt(s.get("mean_abs_px")), _fmt(s.get("rms_px")), _fmt(s.get("max_abs_px")),
                         _fmt(s.get("std_px")), _fmt(s.get("two_sigma_px")), pair("two_sigma_bounds_px"),
                         pair("mean_ci_px"), pair("std_ci_px"), "–" if within is None else f"{100 * within:.1f} %"])
    intro = ("<p>RA and DE errors of the held-out track points (seed 000 eq. 18-19) in pixels of the LAB IFOV, "
             "before and after calibration; σ, intervals and 2σ from the normal fit (seed 000 table 4).</p>")
    seed = SEED_000

    def ours(which, axis, key):
        return _fmt(_stat(doc, which, axis, key))

    comp = [
        ["mean RA error before (table 3)", _fmt(seed["before"]["ra"]["mean_px"], 5), ours("before", "ra", "mean_px")],
        ["mean DE error before (table 3)", _fmt(seed["before"]["de"]["mean_px"], 5), ours("before", "de", "mean_px")],
        ["mean RA error after (table 3)", _fmt(seed["after"]["ra"]["mean_px"], 5), ours("after", "ra", "mean_px")],
        ["mean DE error after (table 3)", _fmt(seed["after"]["de"]["mean_px"], 5), ours("after", "de", "mean_px")],
        ["mean |RA error| after (table 3)", _fmt(seed["after"]["ra"]["mean_abs_px"], 5),
         ours("after", "ra", "mean_abs_px")],
        ["mean |DE error| after (table 3)", _fmt(seed["after"]["de"]["mean_abs_px"], 5),
         ours("after", "de", "mean_abs_px")],
        ["RA σ after (table 4)", _fmt(seed["after"]["ra"]["std_px"], 5), ours("after", "ra", "std_px")],
        ["DE σ after (table 4)", _fmt(seed["after"]["de"]["std_px"], 5), ours("after", "de", "std_px")],
        ["RA 2σ after (table 4, text)", f"±{_fmt(seed['after']['ra']['two_sigma_px'])}",
         ours("after", "ra", "two_sigma_px")],
        ["DE 2σ after (table 4, text)", f"±{_fmt(seed['after']['de']['two_sigma_px'])}",
         ours("after", "de", "two_sigma_px")],
    ]
    note = ("<p>Seed 000's published figures (real data: 20 days of one camera, 437 trajectories) beside this run. "
            "Only the initial errors are comparable in kind; the errors after calibration depend on the "
            "centroid noise and the data (a simulation is much cleaner than orbit data).</p>")
    return (intro + _table(header, rows, left=2) + "<h3>Seed 000 beside this run</h3>" + note
            + _table(["quantity (px)", "seed 000", "this run"], [[_e(r[0]), r[1], r[2]] for r in comp]))


def _section_parameters(doc) -> str:
    values, initial = doc.get("parameters") or {}, doc.get("initial_parameters") or {}
    sigma = doc.get("sigma") or {}
    arcsec = 180.0 * 3600.0 / math.pi
    parts = []
    corr = doc.get("installation_correction_arcsec") or {}
    if corr:
        rows = []
        for axis, c in corr.items():
            name = f"installation.{axis}"
            sd = sigma.get(name)
            rows.append([_e(axis), _fmt(None if name not in initial else initial[name] * arcsec, 6),
                         _fmt(None if name not in values else values[name] * arcsec, 6), _fmt(c),
                         _fmt(None if sd is None else sd * arcsec)])
        parts.append("<p>Installation angles (seed 000 eq. 12-14) in arcseconds.</p>"
                     + _table(["angle", "LAB (″)", "calibrated (″)", "correction (″)", "σ (″)"], rows))
    interior = [n for n in values if n.startswith("interior.")]
    if interior:
        rows = [[_e(n), _fmt(initial.get(n), 6), _fmt(values[n], 6),
                 _fmt(None if n not in initial else values[n] - initial[n]), _fmt(sigma.get(n))] for n in interior]
        parts.append(f"<details><summary>Interior: {len(interior)} directional-angle coefficients "
                     f"(tan ψ polynomials, seed 000 eq. 15-17)</summary>"
                     f"{_table(['coefficient', 'LAB', 'calibrated', 'change', 'σ'], rows)}</details>")
    if sigma:
        parts.append("<p>σ: standard deviations of the last least-squares step's free parameters.</p>")
    if parts and not doc["success"]:
        parts.insert(0, '<p class="fail">The calibration failed: the "calibrated" values are those of the model '
                        "kept for diagnosis, not to be used.</p>")
    return "".join(parts) or "<p>No parameter in the document.</p>"


def _section_versus(rows) -> str:
    header = ["points per track", "calibration points", "success", "RA mean |e| (px)", "DE mean |e| (px)",
              "RA 2σ (px)", "DE 2σ (px)"]
    body = [[_e(r.get("points_per_track", "–")), _e(r.get("n_points", "–")), _fmt(r.get("success")),
             _fmt(r.get("ra_mean_abs_px")), _fmt(r.get("de_mean_abs_px")), _fmt(r.get("ra_two_sigma_px")),
             _fmt(r.get("de_two_sigma_px"))] for r in rows]
    return _table(header, body, left=0)


def _section_tracks(tracks) -> str:
    header = ["HIP", "points", "calibration", "held out", "rejected", "spline RMS (px)", "mean row (px)",
              "column span (px)", "skipped"]
    body = []
    for t in tracks:
        span = t.get("col_span_px")
        body.append([_e(t.get("hip", "–")), _e(t.get("n_points", "–")), _e(t.get("n_calibration", "–")),
                     _e(t.get("n_check", "–")), _e(t.get("n_rejected", "–")), _fmt(t.get("spline_rms_px")),
                     _fmt(t.get("row_mean_px")), "–" if not span else f"{_fmt(span[0])} – {_fmt(span[1])}",
                     _e(t.get("skipped", ""))])
    used = sum(1 for t in tracks if not t.get("skipped"))
    return (f"<details><summary>{len(tracks)} catalogue stars matched by a detection, {used} of them tracked and used"
            f"</summary>{_table(header, body)}</details>")


def _section_runs(runs) -> str:
    if not runs:
        return "<p>No least-squares step ran.</p>"
    header = ["step", "round", "success", "iterations", "σ0", "condition number", "message"]
    body = [[_e(r.get("step", "")), _e(int(r.get("round", 0)) + 1), _fmt(bool(r.get("success"))),
             _e(r.get("iterations", "–")), _fmt(r.get("sigma0")), _fmt(r.get("condition_number")),
             _e(r.get("message", ""))] for r in runs]
    return _table(header, body, left=1)
