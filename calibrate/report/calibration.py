"""HTML calibration report with PNG figures.

:func:`write_report` turns a :class:`~calibrate.absolute.CalibrationResult` and the check-point
accuracy before and after calibration (:class:`~calibrate.accuracy.AccuracyReport`) into
``out_dir/report.html``, one self-contained HTML file (inline CSS, no script) that references
PNG figures in ``out_dir/figures/`` by relative paths.

Figures
-------
``residual_vectors.png``
    Check-point residual vectors over the image, before and after calibration, in two panels,
    each with its own arrow scale (a key arrow in pixels): before calibration the residuals
    are hundreds of pixels, after it tenths.
``distortion_<band>.png``
    Per-CCD distortion curves of each calibrated push-broom band (seed 003 fig. 6): the
    along-track and across-track look of the calibrated interior minus the initial one,
    ``(tan psi(s)_calibrated - tan psi(s)_initial) / IFOV`` in pixels against the detector
    (``first_col + s``), with the IFOV of each CCD taken as ``|c1|`` of its initial
    ``tan psi_y`` polynomial. With a truth model, the truth's interior minus the initial one
    is drawn dashed, and a second row shows the calibrated model minus the truth in image
    space (below).
``residual_histograms.png``
    Row and column check residuals after calibration with the fitted normal density and
    its 2-sigma bounds (seed 000 fig. 7 and table 4).
``error_vs_gcp_count.png``
    Check RMSE against the number of GCPs in the fit, log x axis (seed 000 fig. 8).

The calibrated-minus-truth curves are image-space differences, not interior differences: the
installation angles and the mean look of every CCD are nearly dependent (a camera rotation
shifts every detector's look), and the exterior absorbs the truth's attitude biases, so the
interior alone differs from the truth's by a gauge offset that never reaches the image. Each
detector ``s`` is localized with the truth (rows at 10, 50 and 90 % of the image, at the
median GCP height) and projected back with the calibrated model; the curve is the mean
``(row, col)_calibrated - (row, col)_truth`` over those rows, in pixels.

Tables: summary (status, scheme, counts, check RMSE before and after in pixels and metres,
relative RMSE of seed 003 eq. 4-6), parameters (exterior visible, interior in a collapsible
``<details>``; angles also in arcseconds), per-CCD accuracy before and after in the layout of
seed 003 table 4, the normal fits (seed 000 table 4), the convergence log and any ``extra``
key/value pairs. Numbers are printed with 4 significant digits (parameter values 6).

Output is atomic: everything is built in a temporary folder inside ``out_dir`` and moved into
place at the end, so a failure leaves the previous report (or nothing) and no temporary
folder. Figures are drawn with :class:`matplotlib.figure.Figure` on an Agg canvas, never
through ``pyplot``, so the caller's backend and global figure state are untouched.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import shutil
import tempfile
import warnings
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from calibrate.absolute import CalibrationResult, parameter_unit
from calibrate.report._html import CSS as _CSS, FIGURE_DPI, escape as _e, figure_html as _figure_html, fmt as _fmt
from calibrate.report._html import move_into_place as _move_into_place, new_figure as _new_figure, save_figure as _save, table as _table
from calibrate.accuracy import AccuracyReport
from sensor_models.errors import GcpcalError, InputError
from sensor_models.pushbroom import PushbroomModel

__all__ = ["write_report", "MAX_ARROWS", "FIGURE_DPI"]

#: most arrows drawn per vector panel (a seeded random subset beyond)
MAX_ARROWS = 1500
#: most GCP positions drawn as background dots
MAX_DOTS = 4000
#: detectors sampled per CCD for the distortion curves
CURVE_SAMPLES = 96
#: detectors per CCD and rows localized for the calibrated-minus-truth curves
TRUTH_SAMPLES = 48
TRUTH_ROW_FRACTIONS = (0.1, 0.5, 0.9)
_ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


# --------------------------------------------------------------------------- entry point
def write_report(
    out_dir,
    *,
    result,
    accuracy_before: AccuracyReport,
    accuracy_after: AccuracyReport,
    initial_model,
    gcps: Mapping,
    checks: Mapping,
    error_vs_count=None,
    truth_model=None,
    title: str = "gcpcal calibration report",
    extra: dict | None = None,
) -> Path:
    """Write ``out_dir/report.html`` and its PNG figures in ``out_dir/figures/``.

    Parameters
    ----------
    out_dir : path
        Created if needed. A previous ``report.html`` and ``figures/`` are replaced.
    result : CalibrationResult
        Of :func:`calibrate.absolute.calibrate_model` (an object with a ``calibration``
        attribute holding one, such as :class:`calibrate.rpc_bias.RpcBiasResult`, is
        unwrapped). Its per-point arrays (``residuals_before``, ``residuals_after``,
        ``weights``, ``inlier``, ``band``, ``ccd``) have one entry per GCP of ``gcps``.
    accuracy_before, accuracy_after : AccuracyReport
        :func:`calibrate.accuracy.check_point_accuracy` of the initial and calibrated models
        on ``checks`` (``residuals_px`` has one row per check point).
    initial_model : SensorModel
        The model before calibration (``result.model`` is the calibrated one).
    gcps, checks : mapping of str to array_like
        ``row``, ``col`` (pixels, shape (N,)) and optionally ``lon, lat, h, band, ccd``; ``ccd``
        holds CCD names or indices (``None`` or a missing key: unknown), ``band`` band names.
    error_vs_count : list of dict, optional
        Of :func:`calibrate.accuracy.error_versus_gcp_count`.
    truth_model : SensorModel, optional
        The true model of a simulation: adds truth curves to the distortion figures.
    title : str
    extra : dict, optional
        Shown as a key/value table (values that are not text are printed as JSON).

    Returns
    -------
    Path
        ``out_dir/report.html``.

    Raises
    ------
    InputError
        Inconsistent inputs (array lengths, types); nothing is written then.
    """
    result = _unwrap(result)
    for name, acc in (("accuracy_before", accuracy_before), ("accuracy_after", accuracy_after)):
        if not isinstance(acc, AccuracyReport):
            raise InputError(f"must be an AccuracyReport, got {type(acc).__name__}", field=name)
    g = _points(gcps, "gcps")
    c = _points(checks, "checks")
    _check_result(result, g["row"].size)
    for name, acc in (("accuracy_before", accuracy_before), ("accuracy_after", accuracy_after)):
        res = np.asarray(acc.residuals_px, dtype=np.float64) if acc.residuals_px is not None else None
        if res is None or res.shape != (c["row"].size, 2):
            shape = None if res is None else res.shape
            raise InputError(f"residuals_px has shape {shape} for {c['row'].size} check points", field=name)
    if extra is not None and not isinstance(extra, Mapping):
        raise InputError(f"must be a dict, got {type(extra).__name__}", field="extra")
    if error_vs_count is not None:
        if isinstance(error_vs_count, (str, bytes, Mapping)) or not all(
            isinstance(r, Mapping) and "n_gcps" in r for r in error_vs_count
        ):
            raise InputError("must be a list of dicts with 'n_gcps' (error_versus_gcp_count)", field="error_vs_count")
        error_vs_count = list(error_vs_count)

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".report-", dir=out_dir))
    try:
        fig_dir = tmp / "figures"
        fig_dir.mkdir()
        ctx = _Context(result, accuracy_before, accuracy_after, initial_model, g, c, truth_model)
        figures = {"vectors": _figure_vectors(ctx, fig_dir)}
        figures["distortion"] = [_figure_distortion(ctx, band, fig_dir) for band in ctx.bands]
        figures["histograms"] = _figure_histograms(ctx, fig_dir)
        figures["count"] = _figure_error_vs_count(error_vs_count, fig_dir) if error_vs_count else None
        text = _html(ctx, figures, error_vs_count, str(title), extra)
        (tmp / "report.html").write_text(text, encoding="utf-8")
        _move_into_place(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out_dir / "report.html"


# --------------------------------------------------------------------------- inputs
def _unwrap(result) -> CalibrationResult:
    """The CalibrationResult itself, or the one a wrapper holds (with the wrapper's message)."""
    if isinstance(result, CalibrationResult):
        return result
    inner = getattr(result, "calibration", None)
    if isinstance(inner, CalibrationResult):
        message = getattr(result, "message", None)
        return dataclasses.replace(inner, message=message) if isinstance(message, str) and message else inner
    raise InputError(f"must be a CalibrationResult, got {type(result).__name__}", field="result")


def _points(points, name) -> dict:
    """``row, col`` (float arrays), ``h`` (or None) and per-point ``band``/``ccd`` (or None)."""
    if not isinstance(points, Mapping):
        raise InputError(f"must be a mapping of arrays, got {type(points).__name__}", field=name)
    out = {}
    for key in ("row", "col"):
        if points.get(key) is None:
            raise InputError(f"needs '{key}'", field=name)
        out[key] = np.asarray(points[key], dtype=np.float64).reshape(-1)
    n = out["row"].size
    if out["col"].size != n:
        raise InputError(f"has {out['col'].size} values for {n} points", field=f"{name}.col")
    for key in ("h", "band", "ccd"):
        value = points.get(key)
        if value is None:
            out[key] = None
            continue
        if isinstance(value, (str, bytes)) or np.ndim(value) == 0:
            value = np.full(n, value, dtype=object)
        arr = np.asarray(value, dtype=np.float64 if key == "h" else object).reshape(-1)
        if arr.size != n:
            raise InputError(f"has {arr.size} values for {n} points", field=f"{name}.{key}")
        out[key] = arr
    return out


def _check_result(result: CalibrationResult, n_gcps: int) -> None:
    p = len(result.names)
    for attr in ("values", "initial_values"):
        if np.asarray(getattr(result, attr)).shape != (p,):
            raise InputError(f"{attr} has shape {np.shape(getattr(result, attr))} for {p} parameters", field="result")
    if result.covariance is not None and np.shape(result.covariance) != (p, p):
        raise InputError(f"covariance has shape {np.shape(result.covariance)} for {p} parameters", field="result")
    for attr in ("residuals_before", "residuals_after"):
        shape = np.shape(getattr(result, attr))
        if shape != (n_gcps, 2):
            raise InputError(f"{attr} has shape {shape} for {n_gcps} GCPs", field="result")
    for attr in ("weights", "inlier", "band", "ccd"):
        size = np.size(getattr(result, attr))
        if size != n_gcps:
            raise InputError(f"{attr} has {size} values for {n_gcps} GCPs", field="result")


class _Context:
    """Inputs shared by the figures and tables."""

    def __init__(self, result, before, after, initial, gcps, checks, truth):
        self.result = result
        self.before = before
        self.after = after
        self.initial = initial
        self.calibrated = result.model
        self.gcps = gcps
        self.checks = checks
        self.truth = truth
        self.pushbroom = isinstance(initial, PushbroomModel) and isinstance(result.model, PushbroomModel)
        self.bands = _calibrated_bands(result, initial) if self.pushbroom else []
        self.notes: list[str] = []
        shape = getattr(initial, "image_shape", None)
        if shape is not None:
            self.n_rows, self.n_cols = float(shape[0]), float(shape[1])
        else:
            allr = np.concatenate([gcps["row"], checks["row"]])
            allc = np.concatenate([gcps["col"], checks["col"]])
            self.n_rows, self.n_cols = float(np.nanmax(allr)), float(np.nanmax(allc))


def _calibrated_bands(result, model) -> list:
    """Bands whose interior was estimated, else the bands of the GCPs."""
    names = [n for n in result.names if ".tan_psi_" in n]
    bands = [b for b in model.bands if any(n.startswith(f"{b}.") for n in names)]
    if not bands:
        seen = {str(b) for b in result.band if b is not None}
        bands = [b for b in model.bands if b in seen]
    return bands


# --------------------------------------------------------------------------- figures
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


def _figure_vectors(ctx: _Context, fig_dir: Path) -> dict:
    """Check residual vectors before and after calibration (arrows in image coordinates)."""
    n_rows, n_cols = ctx.n_rows, ctx.n_cols
    extent = max(n_rows, n_cols)
    ratio = n_rows / max(n_cols, 1.0)
    panel_h = float(np.clip(5.2 * ratio, 3.0, 7.0))
    fig = _new_figure(12.0, panel_h + 0.9, wspace=0.08)
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
        ax.quiverkey(q, X=0.72, Y=1.035, U=key, label=f"{key:g} px", labelpos="E", coordinates="axes")
        summary = acc.absolute
        count = f"n={summary.n}" if summary.n == row.size else f"n={summary.n} of {row.size} projected"
        ax.set_title(f"{label}: RMSE {summary.rmse_px:.4g} px ({count})", loc="left", fontsize=10)
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


def _image_difference_px(model, truth, band, height_m: float = 0.0) -> dict:
    """Image position predicted by ``model`` minus the truth's, per detector, in pixels.

    Each sampled detector ``s`` of each CCD is localized with ``truth`` at rows 10, 50 and
    90 % of the image (``TRUTH_ROW_FRACTIONS``) on the ellipsoid at ``height_m``, projected back
    with ``model`` on the same CCD, and ``(row, col)_model - (row, col)_truth`` is averaged over
    the rows. CCDs are matched by name.

    Returns
    -------
    dict of int to (detector, d_row_px, d_col_px)
        Keyed by the CCD's index in ``model.band_ccds(band)``; ``detector = first_col + s``, each
        of shape (M,), M = min(n_detectors, TRUTH_SAMPLES). Empty when ``truth`` lacks the band.
    """
    if not isinstance(truth, PushbroomModel) or band not in truth.bands:
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
    lon, lat, h = truth.image_to_ground(row, col, height=height_m, band=band, ccd=np.concatenate(t_idx))
    owner, det = np.concatenate(m_idx), np.concatenate(det)
    r_mod, c_mod = model.ground_to_image(lon, lat, h, band=band, ccd=owner)
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


def _look_difference_px(initial, other, band) -> dict:
    """Interior look of ``other`` minus ``initial`` per detector, in pixels (seed 003 fig. 6).

    ``(tan psi_other(s) - tan psi_initial(s)) / IFOV`` along track (x) and across track (y),
    with the IFOV of each CCD ``|c1|`` of its initial ``tan psi_y`` (the median over the band
    where that is zero). CCDs are matched by name.

    Returns
    -------
    dict of int to (detector, d_along_px, d_across_px)
        Keyed by the CCD's index in ``initial.band_ccds(band)``; ``detector = first_col + s``,
        each of shape (M,), M = min(n_detectors, CURVE_SAMPLES).
    """
    if not isinstance(other, PushbroomModel) or band not in other.bands:
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


def _figure_distortion(ctx: _Context, band, fig_dir: Path) -> dict:
    """Per-CCD look differences of one band (seed 003 fig. 6)."""
    ccds_init = ctx.initial.band_ccds(band)
    truth_interior = _look_difference_px(ctx.initial, ctx.truth, band)
    truth_image = {}
    if ctx.truth is not None:
        h = ctx.gcps["h"]
        h_m = float(np.nanmedian(h)) if h is not None and np.any(np.isfinite(h)) else 0.0
        try:
            truth_image = _image_difference_px(ctx.calibrated, ctx.truth, band, h_m)
        except GcpcalError as err:  # a truth that cannot localize these detectors: say so
            ctx.notes.append(f"band {band}: calibrated-minus-truth curves not drawn ({err})")
    n_panel_rows = 2 if truth_image else 1
    fig = _new_figure(12.0, 3.6 * n_panel_rows + 0.6, wspace=0.2, hspace=0.22)
    axes = np.atleast_2d(fig.subplots(n_panel_rows, 2, sharex=True, squeeze=False))
    colors = _ccd_colors(len(ccds_init))
    calibrated = _look_difference_px(ctx.initial, ctx.calibrated, band)
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
                            fontsize=6 if small else 8, rotation=90 if small else 0)
    if truth_interior:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], color="0.2", lw=1.4), Line2D([], [], color="0.2", lw=1.2, ls="--")]
        axes[0, 1].legend(handles, ["calibrated − initial", "truth − initial"], fontsize=8, loc="upper right")
    caption = (
        f"Band {band}: look of each detector from the calibrated interior minus the initial one, "
        f"in pixels (difference of tan ψ divided by the CCD's IFOV, |c1| of its initial tan ψy)"
    )
    if truth_interior:
        caption += "; dashed: the truth's interior minus the initial one"
    if truth_image:
        caption += (
            ". Bottom: image position predicted by the calibrated model minus the truth's, per "
            "detector (mean over rows at 10, 50 and 90 % of the image; interior, installation "
            "and attitude together)"
        )
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", str(band))
    return {"src": _save(fig, fig_dir, f"distortion_{safe}.png"), "caption": caption + ".", "band": band}


def _figure_histograms(ctx: _Context, fig_dir: Path) -> dict | None:
    """Row and column residual histograms after calibration with the fitted normal curve."""
    hists = ctx.after.histograms or {}
    keys = [k for k in ("row", "col") if k in hists]
    if not keys:
        return None
    fig = _new_figure(11.0, 3.8, wspace=0.2)
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
            f"{labels[key]}: μ = {fit.mean:.4g} px, σ = {fit.std:.4g} px, "
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


def _figure_error_vs_count(rows, fig_dir: Path) -> dict | None:
    """Check RMSE versus the number of GCPs (seed 000 fig. 8)."""
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


# --------------------------------------------------------------------------- HTML



def _html(ctx: _Context, figures, error_vs_count, title, extra) -> str:
    sections = [
        ("summary", "Summary", _section_summary(ctx) + _figure_html(figures["vectors"])),
        ("parameters", "Parameters", _section_parameters(ctx) + "".join(_figure_html(f) for f in figures["distortion"])),
        ("per-ccd", "Accuracy per CCD", _section_per_ccd(ctx)),
        ("distribution", "Residual distribution", _figure_html(figures["histograms"]) + _section_normal(ctx)),
    ]
    if error_vs_count:
        sections.append(("gcp-count", "Error versus number of GCPs", _figure_html(figures["count"]) + _section_count(error_vs_count)))
    sections.append(("convergence", "Convergence log", _section_convergence(ctx)))
    if extra:
        sections.append(("extra", "Additional information", _section_extra(extra)))
    if ctx.notes:
        sections.append(("notes", "Notes", "<ul>" + "".join(f"<li>{_e(n)}</li>" for n in ctx.notes) + "</ul>"))
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    nav = "".join(f'<a href="#{sid}">{_e(name)}</a>' for sid, name, _ in sections)
    body = "".join(f'<section id="{sid}"><h2>{_e(name)}</h2>{content}</section>' for sid, name, content in sections)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
        f"<h1>{_e(title)}</h1><p class=\"meta\">gcpcal calibration report, generated {stamp}</p>"
        f"<nav>{nav}</nav>{body}</body></html>\n"
    )


def _section_summary(ctx: _Context) -> str:
    r = ctx.result
    status = '<span class="ok">success</span>' if r.success else '<span class="fail">failed</span>'
    model_name = getattr(ctx.initial, "name", "") or ""
    kind = getattr(ctx.initial, "kind", type(ctx.initial).__name__)
    n_in = int(np.sum(np.asarray(r.inlier, dtype=bool)))
    items = [
        ("Status", status),
        ("Message", _e(r.message)),
        ("Scheme", _e(r.scheme)),
        ("Robust loss", _e(r.robust)),
        ("Model", _e(f"{kind} {model_name}".strip())),
        ("GCPs", f"{ctx.gcps['row'].size} ({n_in} inliers)"),
        ("Check points", f"{ctx.checks['row'].size}"),
        ("σ0 / residual scale", f"{_fmt(r.sigma0)} / {_fmt(r.scale)} px"),
        ("Condition numbers", _e(", ".join(f"{k} {_fmt(v)}" for k, v in r.condition_numbers.items()) or "–")),
    ]
    if r.skipped:
        items.append(("CCDs keeping their interior", _e("; ".join(str(s.get("reason", s)) for s in r.skipped))))
    summary = _table(["", ""], [(k, v) for k, v in items], left=2)

    header = ["", "n", "along (px)", "across (px)", "planar (px)", "relative planar (px)", "max (px)",
              "along (m)", "across (m)", "planar (m)"]
    rows = []
    for label, acc in (("check points, before", ctx.before), ("check points, after", ctx.after)):
        a, rel = acc.absolute, acc.relative
        rows.append([_e(label), str(a.n), _fmt(a.rmse_row_px), _fmt(a.rmse_col_px), _fmt(a.rmse_px),
                     _fmt(rel.rmse_px), _fmt(a.max_px), _fmt(a.rmse_row_m), _fmt(a.rmse_col_m), _fmt(a.rmse_m)])
    for which in ("before", "after"):
        s = r.statistics(which)
        rows.append([_e(f"GCPs (inliers), {which}"), str(s["n_inliers"]), _fmt(s["rms_row_px"]), _fmt(s["rms_col_px"]),
                     _fmt(s["rms_px"]), "–", _fmt(s["max_px"]), "–", "–", "–"])
    rmse = "<p>Root mean square errors (relative: seed 003 eq. 4-6, about the check point nearest the centroid).</p>"
    return summary + rmse + _table(header, rows)


def _parameter_rows(r: CalibrationResult, names_idx) -> list:
    sigma = r.sigma
    rows = []
    for j in names_idx:
        name = r.names[j]
        unit = parameter_unit(name)
        init, val = float(r.initial_values[j]), float(r.values[j])
        sd = None if sigma is None else float(sigma[j])
        row = [_e(name), _e(unit), _fmt(init, 6), _fmt(val, 6), _fmt(val - init), _fmt(sd)]
        if unit == "rad":
            row += [_fmt(init * _ARCSEC_PER_RAD, 6), _fmt(val * _ARCSEC_PER_RAD, 6),
                    _fmt((val - init) * _ARCSEC_PER_RAD), _fmt(None if sd is None else sd * _ARCSEC_PER_RAD)]
        else:
            row += [""] * 4
        rows.append(row)
    return rows


def _section_parameters(ctx: _Context) -> str:
    r = ctx.result
    header = ["parameter", "unit", "initial", "calibrated", "change", "σ",
              "initial (″)", "calibrated (″)", "change (″)", "σ (″)"]
    interior = [j for j, n in enumerate(r.names) if ".tan_psi_" in n]
    exterior = [j for j in range(len(r.names)) if j not in set(interior)]
    parts = []
    if not r.names:
        return "<p>No parameter was estimated.</p>"
    if exterior:
        parts.append(_table(header, _parameter_rows(r, exterior), left=2))
    if interior:
        ccds = len({n.rsplit(".", 2)[0] for n in (r.names[j] for j in interior)})
        parts.append(
            f"<details><summary>Interior: {len(interior)} directional-angle coefficients of {ccds} "
            f"CCD polynomials (tan ψ = Σ c_k s^k)</summary>{_table(header[:6], [row[:6] for row in _parameter_rows(r, interior)], left=2)}</details>"
        )
    kind = "stepwise, each group conditional on the other" if r.covariance_kind == "conditional-blocks" else "joint"
    parts.append(f"<p>σ: standard deviations from the covariance ({_e(kind)}); ″: arcseconds.</p>")
    return "".join(parts)


def _gcp_counts(ctx: _Context) -> dict:
    """GCPs per ``"band.ccd"`` and per band, from the result's per-point band and CCD index."""
    counts: dict[str, int] = {}
    if not ctx.pushbroom:
        return counts
    bands = np.array([str(b) for b in ctx.result.band], dtype=object)
    ccd = np.asarray(ctx.result.ccd)
    for b in dict.fromkeys(bands):
        if b not in ctx.initial.bands:
            continue
        in_band = bands == b
        counts[b] = int(in_band.sum())
        names = [c.name for c in ctx.initial.band_ccds(b)]
        idx, n = np.unique(ccd[in_band], return_counts=True)
        for k, m in zip(idx, n):
            if 0 <= k < len(names):
                counts[f"{b}.{names[k]}"] = int(m)
    return counts


def _section_per_ccd(ctx: _Context) -> str:
    header = ["CCD", "GCPs", "checks", "along before", "along after", "across before", "across after",
              "planar before", "planar after", "planar after (m)"]
    keys = list(dict.fromkeys(list(ctx.before.groups) + list(ctx.after.groups)))
    bands = [k for k in keys if "." not in k or k in getattr(ctx.initial, "bands", {})]
    counts = _gcp_counts(ctx)
    rows, classes = [], []

    def row_of(label, key, b, a):
        n = a.n if a is not None else (b.n if b is not None else 0)
        return [_e(label), str(counts.get(key, "–")) if key else str(ctx.gcps["row"].size), str(n),
                _fmt(b.rmse_row_px if b else None), _fmt(a.rmse_row_px if a else None),
                _fmt(b.rmse_col_px if b else None), _fmt(a.rmse_col_px if a else None),
                _fmt(b.rmse_px if b else None), _fmt(a.rmse_px if a else None), _fmt(a.rmse_m if a else None)]

    for band in bands:
        for key in keys:
            if key.startswith(f"{band}.") and key not in bands:
                rows.append(row_of(key, key, ctx.before.groups.get(key), ctx.after.groups.get(key)))
                classes.append("")
        rows.append(row_of(f"{band} (all CCDs)", band, ctx.before.groups.get(band), ctx.after.groups.get(band)))
        classes.append("total")
    if len(bands) != 1:
        rows.append(row_of("all check points", None, ctx.before.absolute, ctx.after.absolute))
        classes.append("total")
    intro = ("<p>Check-point RMSE in pixels along track (row), across track (column) and planar, "
             "before and after calibration (layout of seed 003 table 4).</p>")
    return intro + _table(header, rows, row_classes=classes)


def _section_normal(ctx: _Context) -> str:
    hists = ctx.after.histograms or {}
    if not hists:
        return "<p>Too few check points for a normal fit.</p>"
    header = ["residual", "n", "CL", "μ (px)", "μ CI (px)", "σ (px)", "σ CI (px)", "2σ bounds (px)", "within 2σ"]
    labels = {"row": "along track (row)", "col": "across track (column)"}
    rows = []
    for key in ("row", "col"):
        fit = hists.get(key)
        if fit is None:
            continue
        rows.append([
            _e(labels[key]), str(fit.n), f"{100.0 * fit.confidence:.0f} %", _fmt(fit.mean),
            f"({_fmt(fit.mean_ci[0])}, {_fmt(fit.mean_ci[1])})", _fmt(fit.std),
            f"({_fmt(fit.std_ci[0])}, {_fmt(fit.std_ci[1])})",
            f"({_fmt(fit.two_sigma[0])}, {_fmt(fit.two_sigma[1])})",
            f"{100.0 * fit.fraction_within_two_sigma:.2f} %",
        ])
    note = ("<p>Normal fit of the check residuals after calibration (seed 000 table 4): Student t "
            "interval of the mean, chi-square interval of the standard deviation; a normal "
            "distribution holds 95.45 % within 2σ.</p>")
    return note + _table(header, rows)


def _section_count(rows) -> str:
    header = ["GCPs", "repeats", "successes", "planar mean (px)", "planar std (px)", "along mean (px)", "across mean (px)"]
    body = [[str(r.get("n_gcps", "–")), str(r.get("repeats", "–")), str(r.get("successes", "–")),
             _fmt(r.get("rmse_px_mean")), _fmt(r.get("rmse_px_std")), _fmt(r.get("rmse_row_px_mean")),
             _fmt(r.get("rmse_col_px_mean"))] for r in rows]
    return _table(header, body, left=0)


def _section_convergence(ctx: _Context) -> str:
    steps = ctx.result.steps or []
    if not steps:
        return "<p>No estimation step ran.</p>"
    header = ["step", "round", "parameters", "iterations", "cost", "σ0", "rms row (px)", "rms col (px)",
              "rms (px)", "condition number", "converged", "message"]
    rows = []
    for s in steps:
        rows.append([
            _e(s.get("step", "")), str(int(s.get("outer", 0)) + 1), str(s.get("parameters", "–")),
            str(s.get("iterations", "–")), _fmt(s.get("cost")), _fmt(s.get("sigma0")),
            _fmt(s.get("rms_row_px")), _fmt(s.get("rms_col_px")), _fmt(s.get("rms_px")),
            _fmt(s.get("condition_number")), _fmt(bool(s.get("success"))), _e(s.get("message", "")),
        ])
    out = _table(header, rows)
    log_rows = []
    for s in steps:
        for entry in s.get("log") or []:
            log_rows.append([
                _e(s.get("step", "")), str(int(s.get("outer", 0)) + 1), str(entry.get("iteration", "–")),
                _fmt(entry.get("cost")), _fmt(entry.get("scale")), _fmt(entry.get("step_sigma")),
                _fmt(entry.get("damping")), _fmt(entry.get("accepted")), str(entry.get("n_valid", "–")),
                _e(entry.get("rule", "")),
            ])
    if log_rows:
        log_header = ["step", "round", "iteration", "cost", "scale", "step (σ)", "damping", "accepted", "valid", "loss"]
        out += f"<details><summary>Iterations ({len(log_rows)})</summary>{_table(log_header, log_rows, left=2)}</details>"
    return out


def _section_extra(extra: Mapping) -> str:
    rows = []
    for key, value in extra.items():
        if isinstance(value, str):
            text = _e(value)
        elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
            text = _fmt(value, 6)
        else:
            text = f"<pre>{_e(json.dumps(value, indent=1, default=_json_default))}</pre>"
        rows.append([_e(key), text])
    return _table(["key", "value"], rows, left=2)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
