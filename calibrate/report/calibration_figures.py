"""Figures of the calibration report (:func:`calibrate.report.write_report`).

Each ``figure_*`` function draws one PNG into ``fig_dir`` with :class:`matplotlib.figure.Figure`
on an Agg canvas (never ``pyplot``) and returns ``{"src": relative path, "caption": text}``
(``None`` when there is nothing to draw). The module docstring of
:mod:`calibrate.report.calibration` describes every figure.
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np

from calibrate.report._html import new_figure as _new_figure, save_figure as _save
from calibrate.report._inputs import ReportContext
from sensor_models.errors import GcpcalError

__all__ = ["MAX_ARROWS", "figure_distortion", "figure_error_vs_count", "figure_histograms", "figure_vectors",
           "image_difference_px", "look_difference_px"]

#: most arrows drawn per vector panel (a seeded random subset beyond)
MAX_ARROWS = 1500
#: most GCP positions drawn as background dots
MAX_DOTS = 4000
#: detectors sampled per CCD for the distortion curves
CURVE_SAMPLES = 96
#: detectors per CCD and rows localized for the calibrated-minus-truth curves
TRUTH_SAMPLES = 48
TRUTH_ROW_FRACTIONS = (0.1, 0.5, 0.9)


def _nice(value: float) -> float:
    """The 1-2-5 number nearest below ``value`` (arrow key lengths)."""
    if not (value > 0.0 and math.isfinite(value)):
        return 1.0
    exp = math.floor(math.log10(value))
    base = value / 10.0**exp
    step = 5.0 if base >= 5.0 else (2.0 if base >= 2.0 else 1.0)
    return step * 10.0**exp


def _subset(n: int, limit: int, seed: int = 0) -> np.ndarray:
    if n <= limit:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=limit, replace=False))


def figure_vectors(ctx: ReportContext, fig_dir: Path) -> dict:
    """Check residual vectors before and after calibration (arrows in image coordinates).

    Parameters
    ----------
    ctx : ReportContext
        Report inputs.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict
        ``{"src", "caption"}``.
    """
    n_rows, n_cols = ctx.n_rows, ctx.n_cols
    extent = max(n_rows, n_cols)
    ratio = n_rows / max(n_cols, 1.0)
    panel_h = float(np.clip(5.2 * ratio, 3.0, 7.0))
    fig = _new_figure(12.0, panel_h + 1.2, wspace=0.08, top=0.75)
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    row, col = ctx.checks["row"], ctx.checks["col"]
    g_idx = _subset(ctx.gcps["row"].size, MAX_DOTS, seed=1)
    boundaries = [c.first_col for c in ctx.initial.band_ccds(ctx.bands[0])[1:]] if ctx.bands else []
    sub = _subset(row.size, MAX_ARROWS)
    for ax, acc, label, color in zip(axes, (ctx.before, ctx.after), ("before calibration", "after calibration"), ("#c0392b", "#1f5fa8")):
        res = np.asarray(acc.residuals_px)[sub]
        ok = np.all(np.isfinite(res), axis=1)
        ax.scatter(ctx.gcps["col"][g_idx], ctx.gcps["row"][g_idx], s=2, c="0.75", lw=0, label="GCPs")
        for b in boundaries:
            ax.axvline(b, color="0.6", lw=0.6, ls=":")
        mags = np.hypot(res[ok, 0], res[ok, 1])
        ref = float(np.percentile(mags, 90)) if mags.size else 1.0
        key = _nice(ref)
        scale = max(ref, 1e-12) / (0.06 * extent)  # residual pixels per image pixel of arrow
        q = ax.quiver(col[sub][ok], row[sub][ok], res[ok, 1], res[ok, 0], color=color, angles="xy",
                      scale_units="xy", scale=scale, width=0.0025, headwidth=3.5, headlength=4.0)
        # the key arrow sits on its own line between the axes and the title (pad, points)
        ax.quiverkey(q, X=0.02, Y=1.03, U=key, label=f"key: {key:g} px", labelpos="E", coordinates="axes",
                     fontproperties={"size": 9})
        summary = acc.absolute
        count = f"n={summary.n}" if summary.n == row.size else f"n={summary.n} of {row.size} projected"
        ax.set_title(f"{label}: RMSE {summary.rmse_px:.4g} px ({count})", loc="left", fontsize=10, pad=20)
        ax.set_xlim(0.0, n_cols)
        ax.set_ylim(n_rows, 0.0)
        ax.set_xlabel("column (px)")
        ax.set_aspect("equal" if 0.25 < ratio < 4.0 else "auto")
    axes[0].set_ylabel("row (px)")
    shown = int(sub.size)
    caption = (
        f"Check-point residuals (observed minus modelled image position) before and after "
        f"calibration, {shown} of {row.size} check points; each panel has its own arrow scale "
        f"(key arrow above it). Grey dots: GCPs used in the fit; dotted lines: CCD junctions."
    )
    return {"src": _save(fig, fig_dir, "residual_vectors.png"), "caption": caption}


def _ifov(look) -> float:
    """Detector IFOV (rad) from the linear term of ``tan psi_y``."""
    return abs(float(look.tan_psi_y[1])) if look.tan_psi_y.size > 1 else 0.0


def _ccd_colors(n):
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(k % cmap.N) for k in range(n)]


def image_difference_px(model, truth, band, height_m: float = 0.0) -> dict:
    """Image position predicted by ``model`` minus the truth's, per detector, in pixels.

    Each sampled detector ``s`` of each CCD is localized with ``truth`` at rows 10, 50 and
    90 % of the image (``TRUTH_ROW_FRACTIONS``) on the ellipsoid at ``height_m``, projected back
    with ``model`` on the same CCD, and ``(row, col)_model - (row, col)_truth`` is averaged over
    the rows. CCDs are matched by name.

    Parameters
    ----------
    model, truth : PushbroomModel
        Compared models.
    band : str
        Band drawn.
    height_m : float
        Height of the localized points above the ellipsoid, metres.

    Returns
    -------
    dict of int to (detector, d_row_px, d_col_px)
        Keyed by the CCD's index in ``model.band_ccds(band)``; ``detector = first_col + s``, each
        of shape (M,), M = min(n_detectors, TRUTH_SAMPLES). Empty when ``truth`` lacks the band.
    """
    if truth is None or truth.interior_layout != "per_array" or band not in truth.bands:
        return {}
    t_ccds = {c.name: (k, c) for k, c in enumerate(truth.band_ccds(band))}
    rows_eval = np.asarray(TRUTH_ROW_FRACTIONS) * truth.n_rows
    rows, cols, t_idx, m_idx, det = [], [], [], [], []
    for k, look in enumerate(model.band_ccds(band)):
        if look.name not in t_ccds:
            continue
        kt, tl = t_ccds[look.name]
        s = np.unique(np.linspace(0.0, tl.n_detectors - 1.0, min(tl.n_detectors, TRUTH_SAMPLES)))
        r, ss = np.meshgrid(rows_eval, s, indexing="ij")
        rows.append(r.ravel())
        cols.append(tl.first_col + 0.5 + ss.ravel())
        t_idx.append(np.full(r.size, kt))
        m_idx.append(np.full(r.size, k))
        det.append(tl.first_col + ss.ravel())
    if not rows:
        return {}
    row, col = np.concatenate(rows), np.concatenate(cols)
    lon, lat, h = truth.image_to_ground(row, col, height=height_m, band=band, array=np.concatenate(t_idx))
    owner, det = np.concatenate(m_idx), np.concatenate(det)
    r_mod, c_mod = model.ground_to_image(lon, lat, h, band=band, array=owner)
    d_row, d_col = r_mod - row, c_mod - col
    n_r = rows_eval.size
    out = {}
    with warnings.catch_warnings():  # a detector no row sees gives NaN, not a warning
        warnings.simplefilter("ignore", RuntimeWarning)
        for k in np.unique(owner):
            sel = owner == k
            out[int(k)] = (
                det[sel].reshape(n_r, -1)[0],
                np.nanmean(d_row[sel].reshape(n_r, -1), axis=0),
                np.nanmean(d_col[sel].reshape(n_r, -1), axis=0),
            )
    return out


def look_difference_px(initial, other, band) -> dict:
    """Interior look of ``other`` minus ``initial`` per detector, in pixels (seed 003 fig. 6).

    ``(tan psi_other(s) - tan psi_initial(s)) / IFOV`` along track (x) and across track (y),
    with the IFOV of each CCD ``|c1|`` of its initial ``tan psi_y`` (the median over the band
    where that is zero). CCDs are matched by name.

    Parameters
    ----------
    initial, other : PushbroomModel
        Compared models.
    band : str
        Band drawn.

    Returns
    -------
    dict of int to (detector, d_along_px, d_across_px)
        Keyed by the CCD's index in ``initial.band_ccds(band)``; ``detector = first_col + s``,
        each of shape (M,), M = min(n_detectors, CURVE_SAMPLES).
    """
    if other is None or other.interior_layout != "per_array" or band not in other.bands:
        return {}
    ccds = initial.band_ccds(band)
    others = {c.name: c for c in other.band_ccds(band)}
    fallback = float(np.median([_ifov(c) for c in ccds if _ifov(c) > 0.0] or [1.0]))
    out = {}
    for k, look0 in enumerate(ccds):
        look1 = others.get(look0.name)
        if look1 is None:
            continue
        ifov = _ifov(look0) or fallback
        s = np.unique(np.linspace(0.0, look0.n_detectors - 1.0, min(look0.n_detectors, CURVE_SAMPLES)))
        t0, t1 = look0.look(s)[:2], look1.look(s)[:2]
        out[k] = (look0.first_col + s, (t1[0] - t0[0]) / ifov, (t1[1] - t0[1]) / ifov)
    return out


def figure_distortion(ctx: ReportContext, band, fig_dir: Path) -> dict:
    """Per-CCD look differences of one band (seed 003 fig. 6).

    Parameters
    ----------
    ctx : ReportContext
        Report inputs.
    band : str
        Band drawn.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict
        ``{"src", "caption", "band"}``.
    """
    ccds_init = ctx.initial.band_ccds(band)
    truth_interior = look_difference_px(ctx.initial, ctx.truth, band)
    truth_image = _truth_image_differences(ctx, band)
    n_panel_rows = 2 if truth_image else 1
    fig = _new_figure(12.0, 3.6 * n_panel_rows + 0.6, wspace=0.2, hspace=0.22)
    axes = np.atleast_2d(fig.subplots(n_panel_rows, 2, sharex=True, squeeze=False))
    colors = _ccd_colors(len(ccds_init))
    calibrated = look_difference_px(ctx.initial, ctx.calibrated, band)
    for k in range(len(ccds_init)):
        for curves, style in ((calibrated, "-"), (truth_interior, "--")):
            if k in curves:
                x, d_along, d_across = curves[k]
                axes[0, 0].plot(x, d_along, color=colors[k], lw=1.4 if style == "-" else 1.2, ls=style)
                axes[0, 1].plot(x, d_across, color=colors[k], lw=1.4 if style == "-" else 1.2, ls=style)
        if truth_image and k in truth_image:
            det, dr, dc = truth_image[k]
            axes[1, 0].plot(det, dr, color=colors[k], lw=1.4)
            axes[1, 1].plot(det, dc, color=colors[k], lw=1.4)
    for j, axis in enumerate(("along track (tan ψx)", "across track (tan ψy)")):
        axes[0, j].set_title(f"{band} interior, {axis}: calibrated − initial", loc="left", fontsize=10)
        axes[0, j].set_ylabel("look difference (px)")
    if truth_image:
        for j, axis in enumerate(("along track (row)", "across track (column)")):
            axes[1, j].set_title(f"{band} calibrated − truth, image position, {axis}", loc="left", fontsize=10)
            axes[1, j].set_ylabel("difference (px)")
            axes[1, j].axhline(0.0, color="0.5", lw=0.6)
    for ax in axes[-1]:
        ax.set_xlabel("detector (first column of the CCD + detector index s)")
    for ax in axes.ravel():
        for look in ccds_init[1:]:
            ax.axvline(look.first_col, color="0.7", lw=0.6, ls=":")
        ax.grid(True, lw=0.3, alpha=0.5)
    small = len(ccds_init) > 8
    for k, look in enumerate(ccds_init):
        for j in range(2):
            axes[0, j].text(look.first_col + 0.5 * look.n_detectors, 0.02, look.name, color=colors[k],
                            transform=axes[0, j].get_xaxis_transform(), ha="center", va="bottom",
                            fontsize=6 if small else 8, rotation=90 if small else 0,
                            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0, "pad": 1.0})
    if truth_interior:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], color="0.2", lw=1.4), Line2D([], [], color="0.2", lw=1.2, ls="--")]
        axes[0, 1].legend(handles, ["calibrated − initial", "truth − initial"], fontsize=8, loc="upper right")
    caption = _distortion_caption(band, bool(truth_interior), bool(truth_image))
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", str(band))
    return {"src": _save(fig, fig_dir, f"distortion_{safe}.png"), "caption": caption + ".", "band": band}


def _truth_image_differences(ctx: ReportContext, band) -> dict:
    """Per CCD, calibrated-minus-truth image positions (px) at the GCPs' median height; {} without a truth."""
    if ctx.truth is None:
        return {}
    h = ctx.gcps["h"]
    h_m = float(np.nanmedian(h)) if h is not None and np.any(np.isfinite(h)) else 0.0
    try:
        return image_difference_px(ctx.calibrated, ctx.truth, band, h_m)
    except GcpcalError as err:  # a truth that cannot localize these detectors: say so
        ctx.notes.append(f"band {band}: calibrated-minus-truth curves not drawn ({err})")
        return {}


def _distortion_caption(band, with_truth_interior: bool, with_truth_image: bool) -> str:
    """Caption of :func:`figure_distortion` (without the final full stop)."""
    caption = (
        f"Band {band}: look of each detector from the calibrated interior minus the initial one, "
        f"in pixels (difference of tan ψ divided by the CCD's IFOV, |c1| of its initial tan ψy)"
    )
    if with_truth_interior:
        caption += "; dashed: the truth's interior minus the initial one"
    if with_truth_image:
        caption += (
            ". Bottom: image position predicted by the calibrated model minus the truth's, per "
            "detector (mean over rows at 10, 50 and 90 % of the image; interior, installation "
            "and attitude together)"
        )
    return caption


def figure_histograms(ctx: ReportContext, fig_dir: Path) -> dict | None:
    """Row and column residual histograms after calibration with the fitted normal curve.

    Parameters
    ----------
    ctx : ReportContext
        Report inputs.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict or None
        ``{"src", "caption"}``; None when the check points have no normal fit.
    """
    hists = ctx.after.histograms or {}
    keys = [k for k in ("row", "col") if k in hists]
    if not keys:
        return None
    fig = _new_figure(11.0, 4.1, wspace=0.2, top=0.75)
    axes = np.atleast_1d(fig.subplots(1, len(keys), squeeze=False)[0])
    labels = {"row": "along track (row)", "col": "across track (column)"}
    for ax, key in zip(axes, keys):
        fit = hists[key]
        edges = np.asarray(fit.bin_edges, dtype=np.float64)
        counts = np.asarray(fit.counts, dtype=np.float64)
        ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color="#9dbbd8", edgecolor="#4a7bab", lw=0.4)
        if fit.std > 0.0:
            lo = min(edges[0], fit.mean - 4.0 * fit.std)
            hi = max(edges[-1], fit.mean + 4.0 * fit.std)
            x = np.linspace(lo, hi, 400)
            z = (x - fit.mean) / fit.std
            density = np.exp(-0.5 * z * z) / (fit.std * math.sqrt(2.0 * math.pi))
            ax.plot(x, fit.n * float(np.mean(np.diff(edges))) * density, color="#c0392b", lw=1.5, label="normal fit")
        for bound in fit.two_sigma:
            ax.axvline(bound, color="#c0392b", ls="--", lw=1.0)
        ax.axvline(fit.mean, color="0.3", lw=0.8)
        ax.set_title(
            f"{labels[key]}\nμ = {fit.mean:.4g} px, σ = {fit.std:.4g} px, "
            f"{100.0 * fit.fraction_within_two_sigma:.1f} % within ±2σ",
            loc="left", fontsize=9,
        )
        ax.set_xlabel("residual after calibration (px)")
        ax.set_ylabel("check points")
    caption = (
        "Check residuals after calibration with the fitted normal density (scaled to counts) and "
        "its 2σ bounds (dashed); the table below gives the fit with its confidence intervals."
    )
    return {"src": _save(fig, fig_dir, "residual_histograms.png"), "caption": caption}


def figure_error_vs_count(rows, fig_dir: Path) -> dict | None:
    """Check RMSE versus the number of GCPs (seed 000 fig. 8).

    Parameters
    ----------
    rows : list of dict
        Of :func:`calibrate.accuracy.error_versus_gcp_count`.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict or None
        ``{"src", "caption"}``; None when no row has a result.
    """
    ok = [r for r in rows if r.get("rmse_px_mean") is not None and r.get("n_gcps")]
    if not ok:
        return None
    n = np.array([float(r["n_gcps"]) for r in ok])
    mean = np.array([float(r["rmse_px_mean"]) for r in ok])
    std = np.array([float(r.get("rmse_px_std") or 0.0) for r in ok])
    fig = _new_figure(7.0, 4.2)
    ax = fig.subplots()
    ax.errorbar(n, mean, yerr=std, marker="o", color="#1f5fa8", capsize=3, label="planar")
    for key, label, style in (("rmse_row_px_mean", "along track (row)", "s--"), ("rmse_col_px_mean", "across track (col)", "^--")):
        vals = np.array([np.nan if r.get(key) is None else float(r[key]) for r in ok])
        if np.any(np.isfinite(vals)):
            ax.plot(n, vals, style, ms=4, lw=0.9, label=label)
    ax.set_xscale("log")
    positive = mean[mean > 0.0]
    if positive.size and positive.max() / positive.min() > 20.0:
        ax.set_yscale("log")
    ax.set_xlabel("GCPs in the fit")
    ax.set_ylabel("check RMSE (px)")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=8)
    failed = [int(r["n_gcps"]) for r in rows if r.get("rmse_px_mean") is None]
    caption = "Check-point RMSE of calibrations from random GCP subsets (mean and standard deviation over the repeats)"
    if failed:
        caption += f"; no successful fit with {', '.join(map(str, failed))} GCPs"
    return {"src": _save(fig, fig_dir, "error_vs_gcp_count.png"), "caption": caption + "."}
