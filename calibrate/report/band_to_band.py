"""Band-to-band section of the calibration report (seed 003 section 2.2.2).

:func:`section_band_to_band` writes one table row per band calibrated against the reference
band by :func:`calibrate.relative.relative_calibration` (tie points, windows tried, the tie
residual RMS before and after the interior solve, planar, along and across track, in pixels),
a per-CCD table in a collapsible ``<details>``, and one figure per band
(:func:`figure_band_to_band`).

The tie residual of a band is its measured image position (phase correlation of its window
against the reference band's) minus the position its model predicts for the ground point the
reference band sees there, in pixels of the band (:class:`calibrate.relative.BandResult`):
"before" under the model given to the relative stage, "after" under the calibrated one. The
statistics are :func:`calibrate.calibration_result.residual_statistics` over the inliers of the solve, the
same numbers ``gcpcal demo`` writes to ``summary.json`` (``calibration.<band>.tie_rms_*_px``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from calibrate.report._html import count_note, escape as _e, figure_html as _figure_html, fmt as _fmt
from calibrate.report._html import new_figure as _new_figure, save_figure as _save, table as _table

__all__ = ["figure_band_to_band", "section_band_to_band"]


def _tie_residuals(band_result):
    """Band column (px), residuals before and after (N, 2: row, col, px) and inlier flags; None if absent."""
    cal = band_result.calibration
    if cal is None:
        return None
    col = np.asarray(band_result.ties.col, dtype=np.float64)
    # "before" is under the model given to the relative stage: the band's own first solve keeps it
    # when a joint (band parallax) solve followed, whose own start is already calibrated
    given = getattr(band_result, "residuals_before_px", None)
    before = np.asarray(cal.residuals_before if given is None else given)
    after = np.asarray(cal.residuals_after)
    inlier = np.asarray(cal.inlier, dtype=bool)
    if not (col.size == before.shape[0] == after.shape[0] == inlier.size) or col.size == 0:
        return None
    return col, before, after, inlier


def figure_band_to_band(band_result, model, fig_dir: Path) -> dict | None:
    """Tie residuals of one band against the image column, before and after its interior solve.

    Parameters
    ----------
    band_result : calibrate.relative.BandResult
        One band of :func:`calibrate.relative.relative_calibration`.
    model : PushbroomModel
        Model whose CCD junctions (``band_ccds(band)``) are drawn as dotted lines.
    fig_dir : Path
        Folder of the PNG.

    Returns
    -------
    dict or None
        ``{"src", "caption", "band"}``; None when the band has no tie point or no solve.
    """
    data = _tie_residuals(band_result)
    if data is None:
        return None
    col, before, after, inlier = data
    band = band_result.band
    fig = _new_figure(12.0, 3.9, wspace=0.25, top=0.55)
    axes = fig.subplots(1, 2, sharex=True)
    junctions = [c.first_col for c in model.band_ccds(band)[1:]] if band in model.bands else []
    for ax, res, stats, label in ((axes[0], before, band_result.before, "before"),
                                  (axes[1], after, band_result.after, "after")):
        ax.scatter(col[inlier], res[inlier, 0], s=4, lw=0, color="#c0392b", label="along track (row)")
        ax.scatter(col[inlier], res[inlier, 1], s=4, lw=0, color="#1f5fa8", label="across track (column)")
        ax.axhline(0.0, color="0.5", lw=0.6)
        for x in junctions:
            ax.axvline(x, color="0.6", lw=0.6, ls=":")
        ax.set_title(f"{band} tie residuals {label}: RMS {_fmt(stats.get('rms_px'))} px "
                     f"({int(inlier.sum())} inliers of {col.size})", loc="left", fontsize=10)
        ax.set_xlabel("column of the tie point (px)")
        ax.set_ylabel("residual (px)")
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[1].legend(fontsize=8, loc="upper right", markerscale=2.5)
    caption = (f"Band {band} against the reference band: tie-point residuals (measured minus modelled position "
               f"of {band}, px) along track (red) and across track (blue) against the image column, before "
               f"(left) and after (right) the band's interior calibration; each panel has its own scale; "
               f"dotted lines: CCD junctions; outliers of the solve are not drawn.")
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", str(band))
    return {"src": _save(fig, fig_dir, f"band_to_band_{safe}.png"), "caption": caption, "band": band}


def _band_row(b) -> list:
    before, after = b.before or {}, b.after or {}
    status = '<span class="ok">yes</span>' if b.success else '<span class="fail">no</span>'
    return [_e(b.band), status, str(len(b.ties)), str(after.get("n_inliers", "–")), str(b.windows),
            _fmt(before.get("rms_row_px")), _fmt(after.get("rms_row_px")),
            _fmt(before.get("rms_col_px")), _fmt(after.get("rms_col_px")),
            _fmt(before.get("rms_px")), _fmt(after.get("rms_px"))]


def _ccd_rows(b) -> list:
    rows = []
    for c in b.per_ccd:
        before, after = c.get("before") or {}, c.get("after") or {}
        rows.append([_e(b.band), _e(c["ccd"]), str(c.get("ties", "–")), _fmt(before.get("rms_px")),
                     _fmt(after.get("rms_px")), _fmt(after.get("max_px"))])
    return rows


def section_band_to_band(relative, figures) -> str:
    """HTML of the band-to-band section: table per band, per-CCD details, one figure per band.

    Parameters
    ----------
    relative : calibrate.relative.RelativeResult
        Of :func:`calibrate.relative.relative_calibration`.
    figures : list of dict or None
        Of :func:`figure_band_to_band`, in the order of ``relative.bands``.

    Returns
    -------
    str
        HTML.
    """
    bands = list(relative.bands.values())
    if not bands:
        return f"<p>No band other than the reference band {_e(relative.reference_band)}.</p>"
    intro = (f"<p>Every other band calibrated against the calibrated reference band {_e(relative.reference_band)} "
             "from dense band-to-band tie points (seed 003 section 2.2.2): its interior (directional angles of "
             "each CCD) is solved so that its image positions match the reference band's. Tie residual RMS "
             "over the inliers of the solve, in pixels.</p>")
    header = ["band", "calibrated", "tie points", "inliers", "windows", "along before", "along after",
              "across before", "across after", "planar before", "planar after"]
    table = _table(header, [_band_row(b) for b in bands])
    table += "".join(count_note((b.after or {}).get("n_inliers"), len(b.ties), f"tie points of {b.band}",
                                "the inliers of the robust solve, over which its RMS is taken") for b in bands)
    table += "<ul>" + "".join(f"<li>{_e(b.band)}: {_e(b.message)}</li>" for b in bands) + "</ul>"
    ccd_rows = [row for b in bands for row in _ccd_rows(b)]
    details = ""
    if ccd_rows:
        ccd_header = ["band", "CCD", "tie points", "planar before (px)", "planar after (px)", "max after (px)"]
        details = (f"<details><summary>Per CCD ({len(ccd_rows)} rows)</summary>"
                   f"{_table(ccd_header, ccd_rows, left=2)}</details>")
    return intro + table + details + "".join(_figure_html(f) for f in figures)
