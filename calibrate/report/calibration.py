"""HTML calibration report with PNG figures.

:func:`write_report` turns a :class:`~calibrate.calibration_result.CalibrationResult` and the check-point
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

import math
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from calibrate.calibration_result import CalibrationResult, parameter_unit
from calibrate.accuracy import AccuracyReport
from calibrate.report._html import CSS as _CSS, count_note, escape as _e, figure_html as _figure_html, fmt as _fmt
from calibrate.report._html import section_provenance, table as _table, value_html
from calibrate.report._inputs import ReportContext, check_result, point_columns, unwrap_result
from calibrate.report.attitude import figure_attitude, figure_parallax, section_attitude, section_parallax
from calibrate.report.band_to_band import figure_band_to_band, section_band_to_band
from calibrate.report.truth import figure_truth_error, section_truth
from calibrate.report.calibration_figures import (figure_distortion, figure_error_vs_count, figure_histograms,
                                                  figure_vectors)
from sensor_models.errors import InputError
from sensor_models.files.atomic import atomic_folder, replace_tree

__all__ = ["write_report"]

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
    coverage=None,
    status=None,
    relative=None,
    truth_error=None,
    provenance: dict | None = None,
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
    coverage : list of dict, optional
        Per band and CCD rows of the coverage gate (``band, ccd, gcps, check_points,
        spread_along, spread_across, calibrated, verified, reason``, optionally
        ``check_rmse_px {before, after}``; :mod:`calibrate.coverage`): a coverage table that
        names every uncalibrated or unverified CCD with its reason.
    status : CalibrationStatus, optional
        The run's status (calibrated, partial, failed), shown in the summary.
    relative : calibrate.relative.RelativeResult, optional
        The band-to-band calibration of the other bands against ``result``'s model: adds the
        band-to-band section (:mod:`calibrate.report.band_to_band`); its ``model`` is then the
        final model graded against ``truth_model``.
    truth_error : dict, optional
        ``{"after": model_difference(truth, final model), "before": model_difference(truth,
        initial model)}`` (:func:`sensor_models.models.compare.model_difference`; ``before``
        optional): adds the TRUE-model section (:mod:`calibrate.report.truth`), with a figure of
        the error against the detector when ``truth_model`` is given.

    provenance : dict, optional
        :func:`calibrate.actions._provenance.provenance_record`: shown first, under the title
        (version, command line, every input with its size and SHA-256, DEM datum and geoid,
        the reference's accuracy and its source).

    Returns
    -------
    Path
        ``out_dir/report.html``.

    Raises
    ------
    InputError
        Inconsistent inputs (array lengths, types); nothing is written then.
    """
    result = unwrap_result(result)
    g, c, error_vs_count = _checked_inputs(result, accuracy_before, accuracy_after, gcps, checks, error_vs_count,
                                           extra)  # fmt: skip
    _check_relative_truth(relative, truth_error)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_folder(out_dir, mode="merge", inside=True) as tmp:
        ctx = ReportContext(result, accuracy_before, accuracy_after, initial_model, g, c, truth_model)
        ctx.coverage, ctx.status = list(coverage or []), status
        ctx.relative, ctx.truth_error = relative, truth_error
        figures = _figures(ctx, error_vs_count, tmp / "figures")
        text = _html(ctx, figures, error_vs_count, str(title), extra, provenance)
        (tmp / "report.html").write_text(text, encoding="utf-8")
        replace_tree(tmp / "figures", out_dir / "figures")  # no figure of an earlier report survives
    return out_dir / "report.html"


def _figures(ctx, error_vs_count, fig_dir: Path) -> dict:
    """Draw every figure of the report into ``fig_dir`` (created); their paths by kind."""
    fig_dir.mkdir()
    figures = {"vectors": figure_vectors(ctx, fig_dir)}
    figures["distortion"] = [figure_distortion(ctx, band, fig_dir) for band in ctx.bands]
    figures["histograms"] = figure_histograms(ctx, fig_dir)
    figures["count"] = figure_error_vs_count(error_vs_count, fig_dir) if error_vs_count else None
    figures["attitude"] = figure_attitude(ctx.result, fig_dir)
    final = ctx.relative.model if ctx.relative is not None else ctx.calibrated
    if ctx.relative is not None:
        figures["band_to_band"] = [figure_band_to_band(b, final, fig_dir) for b in ctx.relative.bands.values()]
        figures["parallax"] = figure_parallax(ctx.relative, fig_dir)
    if ctx.truth_error is not None and ctx.truth is not None:
        figures["truth"] = figure_truth_error(final, ctx.truth, list(final.bands), fig_dir,
                                              height_m=_median_height(ctx), notes=ctx.notes)
    return figures


def _median_height(ctx) -> float:
    """Median GCP height (m), 0 without heights."""
    h = ctx.gcps["h"]
    return float(np.nanmedian(h)) if h is not None and np.any(np.isfinite(h)) else 0.0


def _check_relative_truth(relative, truth_error) -> None:
    """Validate the band-to-band result and the truth errors of :func:`write_report`."""
    if relative is not None and not (isinstance(getattr(relative, "bands", None), Mapping)
                                     and getattr(relative, "model", None) is not None):
        raise InputError(f"must be a RelativeResult (bands and model), got {type(relative).__name__}",
                         field="relative")
    if truth_error is None:
        return
    if not isinstance(truth_error, Mapping) or not isinstance(truth_error.get("after"), Mapping):
        raise InputError("must map 'after' (and optionally 'before') to model_difference results",
                         field="truth_error")
    for which in ("after", "before"):
        value = truth_error.get(which)
        if value is not None and not (isinstance(value, Mapping) and "rms_px" in value and "max_px" in value):
            raise InputError("needs 'rms_px' and 'max_px' (model_difference)", field=f"truth_error.{which}")


def _checked_inputs(result, accuracy_before, accuracy_after, gcps, checks, error_vs_count, extra):
    """Validate the inputs of :func:`write_report`: GCP and check columns, error-versus-count rows."""
    for name, acc in (("accuracy_before", accuracy_before), ("accuracy_after", accuracy_after)):
        if not isinstance(acc, AccuracyReport):
            raise InputError(f"must be an AccuracyReport, got {type(acc).__name__}", field=name)
    g = point_columns(gcps, "gcps")
    c = point_columns(checks, "checks")
    check_result(result, g["row"].size)
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
    return g, c, error_vs_count


# --------------------------------------------------------------------------- HTML



def _html(ctx: ReportContext, figures, error_vs_count, title, extra, provenance=None) -> str:
    sections = [
        *([("provenance", "Inputs and provenance", section_provenance(provenance))] if provenance else []),
        ("summary", "Summary", _section_summary(ctx) + _figure_html(figures["vectors"])),
        *([("coverage", "Coverage per CCD", _section_coverage(ctx))] if ctx.coverage else []),
        ("parameters", "Parameters", _section_parameters(ctx) + "".join(_figure_html(f) for f in figures["distortion"])),
        ("per-ccd", "Accuracy per CCD", _section_per_ccd(ctx)),
    ]
    if ctx.result.attitude:
        sections.append(("attitude", "Time-varying attitude", section_attitude(ctx.result, figures.get("attitude"))))
    if ctx.relative is not None:
        sections.append(("band-to-band", "Band-to-band calibration",
                         section_band_to_band(ctx.relative, figures.get("band_to_band") or [])))
        if getattr(ctx.relative, "parallax", None):
            sections.append(("parallax", "Attitude from band parallax", section_parallax(ctx.relative, figures.get("parallax"), ctx.gcps["row"].size)))
    if ctx.truth_error is not None:
        sections.append(("truth", "Error against the TRUE model", section_truth(ctx.truth_error, figures.get("truth"))))
    sections.append(("distribution", "Residual distribution", _figure_html(figures["histograms"]) + _section_normal(ctx)))
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


def _section_summary(ctx: ReportContext) -> str:
    r = ctx.result
    status = '<span class="ok">success</span>' if r.success else '<span class="fail">failed</span>'
    if ctx.status is not None:
        css = {"calibrated": "ok", "partial": "fail", "failed": "fail"}[ctx.status.status]
        status = f'<span class="{css}">{_e(ctx.status.status)}</span>'
        if ctx.status.status != "calibrated":
            status += " " + _e(ctx.status.message)
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
        ("Variance factor σ0²", f"{_fmt(r.variance_factor)} (parameter σ scaled by it: C = σ0² (JᵀWJ)⁻¹)"),
        ("Condition numbers", _e(", ".join(f"{k} {_fmt(v)}" for k, v in r.condition_numbers.items()) or "–")),
    ]
    if ctx.truth_error is not None:
        t, lab = ctx.truth_error["after"], ctx.truth_error.get("before")
        text = f"RMS {_fmt(t.get('rms_px'))} px, max {_fmt(t.get('max_px'))} px over every band and CCD"
        if lab:
            text += f" (LAB model: RMS {_fmt(lab.get('rms_px'))} px, max {_fmt(lab.get('max_px'))} px)"
        items.append(('<a href="#truth">Error against the TRUE model</a>', text))
    if r.skipped:
        items.append(("CCDs keeping their interior", _e("; ".join(str(s.get("reason", s)) for s in r.skipped))))
    summary = _table(None, [(k, v) for k, v in items], left=2)

    header = ["", "n", "along (px)", "across (px)", "planar (px)", "relative planar (px)", "max (px)",
              "along (m)", "across (m)", "planar (m)"]
    rows = []
    for label, acc in (("check points, before", ctx.before), ("check points, after", ctx.after)):
        a, rel = acc.absolute, acc.relative
        rows.append([_e(label), str(a.n), _fmt(a.rmse_row_px), _fmt(a.rmse_col_px), _fmt(a.rmse_px),
                     _fmt(rel.rmse_px), _fmt(a.max_px), _fmt(a.rmse_row_m), _fmt(a.rmse_col_m), _fmt(a.rmse_m)])
    stats = {which: r.statistics(which) for which in ("before", "after")}
    for which, s in stats.items():
        rows.append([_e(f"GCPs (inliers), {which}"), str(s["n_inliers"]), _fmt(s["rms_row_px"]), _fmt(s["rms_col_px"]),
                     _fmt(s["rms_px"]), "–", _fmt(s["max_px"]), "–", "–", "–"])
    rmse = "<p>Root mean square errors (relative: seed 003 eq. 4-6, about the check point nearest the centroid).</p>"
    return summary + rmse + _table(header, rows) + _summary_count_notes(ctx, stats)


def _summary_count_notes(ctx: ReportContext, stats: dict) -> str:
    """Why the summary's counts of check points and GCPs differ, one phrase per difference."""
    n_checks, n_gcps = int(ctx.checks["row"].size), int(ctx.gcps["row"].size)
    return (count_note(ctx.before.absolute.n, n_checks, "check points before calibration",
                       "those the initial model projects into the image, over which the RMSE before is taken")
            + count_note(ctx.after.absolute.n, n_checks, "check points after calibration",
                         "those the calibrated model projects into the image")
            + count_note(stats["after"]["n_inliers"], n_gcps, "GCPs after calibration",
                         "the inliers of the robust fit (the statistics leave out its outliers)")
            + count_note(stats["before"]["n_inliers"], stats["after"]["n_inliers"], "inliers before calibration",
                         "those the initial model projects into the image"))


def _section_coverage(ctx) -> str:
    """Per band and CCD: points, spread, verdict and reason (every CCD, names in full)."""
    header = ["band", "CCD", "GCPs", "check points", "spread along", "spread across", "calibrated", "verified",
              "check RMSE before (px)", "check RMSE after (px)", "reason"]
    rows = []
    for c in ctx.coverage:
        rmse = c.get("check_rmse_px") or {}
        rows.append([_e(c["band"]), _e(c["ccd"]), str(c["gcps"]), str(c["check_points"]),
                     f"{100 * c['spread_along']:.0f} %", f"{100 * c['spread_across']:.0f} %",
                     "yes" if c["calibrated"] else '<span class="fail">no</span>',
                     "yes" if c["verified"] else '<span class="fail">no</span>',
                     _fmt(rmse.get("before")), _fmt(rmse.get("after")), _e(c["reason"]) or "–"])
    bad = [c for c in ctx.coverage if not (c["calibrated"] and c["verified"])]
    items = "".join(f"<li>{_e('.'.join(p for p in (c['band'], c['ccd']) if p))}: {_e(c['reason'])}</li>" for c in bad)
    note = f"<p>Not calibrated or not verified:</p><ul>{items}</ul>" if bad else "<p>Every CCD calibrated and verified.</p>"
    return note + _table(header, rows)


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


def _section_parameters(ctx: ReportContext) -> str:
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


def _gcp_counts(ctx: ReportContext) -> dict:
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


def _section_per_ccd(ctx: ReportContext) -> str:
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
    note = count_note(ctx.before.absolute.n, ctx.after.absolute.n, "check points before calibration",
                      "the \"before\" columns are over those the initial model projects into the image; "
                      "\"checks\" counts those after")
    return intro + _table(header, rows, row_classes=classes) + note


def _section_normal(ctx: ReportContext) -> str:
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


def _section_convergence(ctx: ReportContext) -> str:
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
    return _table(["key", "value"], [[_e(key), value_html(value)] for key, value in extra.items()], left=2)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
