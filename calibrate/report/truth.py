"""TRUE-model section of the calibration report: a simulation graded against its truth.

A simulated scene is rendered with a TRUE model and delivered with the LAB model an analyst
would have (``fixtures/hy1c_czi``). :func:`section_truth` tabulates
:func:`sensor_models.models.compare.model_difference` of the calibrated model (and of the LAB model)
against the truth: the image-space error ``(row, col)_model - (row, col)_truth`` of a dense grid
of every band and CCD localized by the truth on the DEM, as RMS and maximum in pixels, per band
and CCD, per band and over everything (the numbers ``gcpcal demo`` writes to ``summary.json``:
``truth_error_px``, ``truth_error_before_px``, ``truth_error_per_ccd``).

:func:`figure_truth_error` draws that error against the detector for every band: each sampled
detector is localized with the truth at rows 10, 50 and 90 % of the image and projected back
with the calibrated model (:func:`calibrate.report.calibration_figures.image_difference_px`),
the curve being the mean over those rows, along and across track.
"""

from __future__ import annotations

import math
from pathlib import Path

from calibrate.report._html import count_note, escape as _e, figure_html as _figure_html, fmt as _fmt
from calibrate.report._html import new_figure as _new_figure, save_figure as _save, table as _table
from calibrate.report.calibration_figures import image_difference_px
from sensor_models.errors import GcpcalError

__all__ = ["band_totals", "figure_truth_error", "section_truth"]

_BAND_COLORS = ("#1f5fa8", "#c0392b", "#2e8b57", "#8e44ad", "#d35400", "#16a085", "#7f8c8d", "#b7950b")


def band_totals(per_ccd) -> dict:
    """RMS and maximum error per band from the per-CCD rows of ``model_difference``.

    The band RMS is exact: ``sqrt(sum n_i rms_i^2 / sum n_i)`` over its CCDs (each CCD's RMS is
    over its ``n_points`` grid points).

    Parameters
    ----------
    per_ccd : list of dict
        ``band, ccd, rms_px, max_px, n_points`` (px).

    Returns
    -------
    dict of str to dict
        Per band ``{"rms_px", "max_px", "n_points"}`` (None for a band without a point).
    """
    out: dict[str, dict] = {}
    for r in per_ccd:
        acc = out.setdefault(r["band"], {"sq": 0.0, "n": 0, "max": None})
        n = int(r.get("n_points") or 0)
        if n == 0 or r.get("rms_px") is None:
            continue
        acc["sq"] += n * float(r["rms_px"]) ** 2
        acc["n"] += n
        acc["max"] = float(r["max_px"]) if acc["max"] is None else max(acc["max"], float(r["max_px"]))
    return {b: {"rms_px": math.sqrt(a["sq"] / a["n"]) if a["n"] else None, "max_px": a["max"], "n_points": a["n"]}
            for b, a in out.items()}


def figure_truth_error(model, truth, bands, fig_dir: Path, *, height_m: float = 0.0, notes=None) -> dict | None:
    """Calibrated-minus-truth image position against the detector, every band (two panels).

    Parameters
    ----------
    model, truth : PushbroomModel
        The calibrated model and the TRUE model (directional-angle interiors per CCD).
    bands : sequence of str
        Bands drawn, one colour each.
    fig_dir : Path
        Folder of the PNG.
    height_m : float
        Height above the ellipsoid at which the detectors are localized, metres.
    notes : list of str, optional
        Receives a line for a band whose curves cannot be computed.

    Returns
    -------
    dict or None
        ``{"src", "caption"}``; None when no band could be drawn.
    """
    if getattr(model, "interior_layout", None) != "per_array":
        return None
    curves = {}
    for band in bands:
        try:
            curves[band] = image_difference_px(model, truth, band, height_m)
        except GcpcalError as err:
            if notes is not None:
                notes.append(f"band {band}: truth-error curve not drawn ({err})")
    curves = {b: c for b, c in curves.items() if c}
    if not curves:
        return None
    fig = _new_figure(12.0, 4.2, wspace=0.25, top=0.45)
    axes = fig.subplots(1, 2, sharex=True)
    for i, (band, per_ccd) in enumerate(curves.items()):
        color = _BAND_COLORS[i % len(_BAND_COLORS)]
        for k, (det, d_row, d_col) in sorted(per_ccd.items()):
            label = band if k == min(per_ccd) else None
            axes[0].plot(det, d_row, color=color, lw=1.3, label=label)
            axes[1].plot(det, d_col, color=color, lw=1.3, label=label)
    first = next(iter(curves))
    junctions = [c.first_col for c in model.band_ccds(first)[1:]]
    for ax, axis in zip(axes, ("along track (row)", "across track (column)")):
        ax.set_title(f"calibrated − truth, image position, {axis}", loc="left", fontsize=10)
        ax.axhline(0.0, color="0.5", lw=0.6)
        for x in junctions:
            ax.axvline(x, color="0.7", lw=0.6, ls=":")
        ax.set_xlabel("detector (first column of the CCD + detector index s)")
        ax.set_ylabel("error (px)")
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[1].legend(fontsize=8, loc="best", title="band", title_fontsize=8)
    caption = ("Error of the calibrated model against the TRUE model per detector, every band: image position "
               "predicted by the calibrated model minus the truth's, in pixels (mean over rows at 10, 50 and "
               f"90 % of the image, on the ellipsoid at {height_m:.0f} m); dotted lines: CCD junctions.")
    return {"src": _save(fig, fig_dir, "truth_error_vs_detector.png"), "caption": caption}


def section_truth(truth_error, figure) -> str:
    """HTML of the TRUE-model section: totals, per band, per band and CCD, and the figure.

    Parameters
    ----------
    truth_error : dict
        ``{"after": model_difference(truth, calibrated), "before": model_difference(truth, lab)}``
        (``before`` optional); each with ``rms_px``, ``max_px``, ``n_points`` and ``per_ccd``.
    figure : dict or None
        Of :func:`figure_truth_error`.

    Returns
    -------
    str
        HTML.
    """
    after, before = truth_error["after"], truth_error.get("before")
    intro = ("<p>The scene was rendered with a TRUE model and delivered with the LAB model; the calibrated model "
             "is graded against the truth over a dense grid of every band and CCD localized on the DEM: "
             "image position of the model minus the truth's, in pixels. These errors include what check "
             "points cannot see (lens terms beyond the fitted polynomial, between the check points).</p>")
    totals = [["calibrated model, every band and CCD", str(after.get("n_points", "–")), _fmt(after.get("rms_px")),
               _fmt(after.get("max_px"))]]
    if before:
        totals.append(["LAB model (before calibration)", str(before.get("n_points", "–")),
                       _fmt(before.get("rms_px")), _fmt(before.get("max_px"))])
    header = ["model", "grid points", "RMS (px)", "max (px)"]
    notes = _grid_notes(after, before)
    per_band = band_totals(after.get("per_ccd") or [])
    band_rows = [[_e(b), str(t["n_points"]), _fmt(t["rms_px"]), _fmt(t["max_px"])] for b, t in per_band.items()]
    ccd_rows = [[_e(r["band"]), _e(r["ccd"]), str(r.get("n_points", "–")), _fmt(r.get("rms_px")),
                 _fmt(r.get("max_px")), _fmt(r.get("mean_row_px")), _fmt(r.get("mean_col_px"))]
                for r in after.get("per_ccd") or []]
    ccd_header = ["band", "CCD", "grid points", "RMS (px)", "max (px)", "mean along (px)", "mean across (px)"]
    return (intro + _table(header, totals) + notes
            + "<h3>Calibrated model per band</h3>" + _table(["band", "grid points", "RMS (px)", "max (px)"], band_rows)
            + "<h3>Calibrated model per band and CCD</h3>" + _table(ccd_header, ccd_rows, left=2)
            + _figure_html(figure))


def _grid_notes(after: dict, before) -> str:
    """Why the grid-point counts of the calibrated and the LAB model differ (spacing, points left out)."""
    notes = []
    for label, t in (("calibrated model", after), ("LAB model", before or {})):
        missing = int(t.get("n_missing") or 0)
        if missing:
            n = int(t.get("n_points") or 0)
            notes.append(count_note(n, n + missing, f"grid points of the {label}",
                                    "the others it does not see (off the DEM or outside its CCD) are left out"))
    if before and before.get("n_points") != after.get("n_points"):
        a_step, b_step = after.get("step_px"), before.get("step_px")
        why = (f"the LAB model is graded on a grid every {b_step:g} px, the calibrated model every {a_step:g} px"
               if a_step and b_step and a_step != b_step else "the grid points each leaves out are counted above")
        notes.append(f'<p class="count-note">{before.get("n_points")} grid points for the LAB model against '
                     f'{after.get("n_points")} for the calibrated model: {_e(why)}.</p>')
    return "".join(notes)
