"""Write an experiment's outputs: ``experiment.json``, ``sensitivity/*.json|png``, ``report.html``.

The HTML uses the report helpers of :mod:`calibrate.report._html` (style, escaping, number
format, tables, Agg figures). Files are written into the folder given (the stage action stages
it and moves it into place).
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

from calibrate._json import json_safe
from calibrate.experiments.results import ExperimentResult, PaperTable, SensitivityCurve
from calibrate.report._html import CSS, escape, figure_html, fmt, new_figure, save_figure, table

__all__ = ["write_experiment"]


def _curve_png(curve: SensitivityCurve, fig_dir: Path) -> str:
    fig = new_figure(6.0, 3.8, left=0.9, bottom=0.7)
    ax = fig.add_subplot(1, 1, 1)
    for label, ys in curve.series.items():
        ax.plot(curve.x, [float("nan") if y is None else y for y in ys], marker="o", label=label)
    ax.set_xlabel(curve.x_label)
    ax.set_ylabel(curve.y_label)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(curve.name.replace("_", " "), fontsize=10)
    return save_figure(fig, fig_dir, f"{curve.name}.png")


def _table_html(t: PaperTable) -> str:
    rows = [[escape(c) if isinstance(c, str) else fmt(c) for c in row] for row in t.rows]
    return (f"<h3>{escape(t.title)}</h3><p class=\"meta\">paper: {escape(t.source)}</p>"
            + table([escape(c) for c in t.columns], rows))


def _html(result: ExperimentResult, figures: list) -> str:
    doc = result.to_dict()
    head = [f"<h1>gcpcal experiment {escape(result.seed)}: profile {escape(result.profile)}</h1>",
            f"<p>{escape(result.title)}</p>",
            f"<p class=\"meta\">{'quick (reduced) run' if result.quick else 'full run'}; "
            f"{result.seconds:.1f} s; written {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC</p>"]
    scale = table(["scale", "value"], [[escape(k), escape(json.dumps(v))] for k, v in doc["scale"].items()])
    headline = table(["headline", "value"], [[escape(k), fmt(v)] for k, v in doc["headline"].items()])
    tables = "".join(_table_html(t) for t in result.tables)
    curves = "".join(f"{figure_html(f)}<p class=\"meta\">{escape(c.note)}</p>" for c, f in zip(result.curves, figures))
    notes = "".join(f"<li>{escape(n)}</li>" for n in result.notes)
    prof = table(["profile", "field", "value", "unit", "how injected", "source"],
                 [[escape(c) for c in row] for row in result.profile_rows], left=6)
    body = (f"{''.join(head)}<h2>Scale</h2>{scale}<h2>Headline</h2>{headline}<h2>Paper beside ours</h2>{tables}"
            f"<h2>Sensitivity</h2>{curves}<h2>Where ours differs from the paper</h2><ul>{notes}</ul>"
            f"<h2>Error profile</h2>{prof}")
    return (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>experiment {escape(result.seed)} "
            f"{escape(result.profile)}</title><style>{CSS}</style></head><body>{body}</body></html>\n")


def write_experiment(result: ExperimentResult, folder) -> dict:
    """Write the experiment's files into ``folder`` (created).

    Parameters
    ----------
    result : ExperimentResult
    folder : str or Path

    Returns
    -------
    dict
        The document written to ``experiment.json`` (with ``files``: paths relative to ``folder``).
    """
    folder = Path(folder)
    sens = folder / "sensitivity"
    sens.mkdir(parents=True, exist_ok=True)
    files, figures = ["experiment.json", "report.html"], []
    for curve in result.curves:
        data = json_safe({"name": curve.name, "profile": result.profile, "x_label": curve.x_label, "y_label": curve.y_label,
                "x": curve.x, "series": curve.series, "note": curve.note})
        (sens / f"{curve.name}.json").write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        src = _curve_png(curve, sens)
        figures.append({"src": "sensitivity/" + src.split("/", 1)[1], "caption": f"{curve.y_label} against {curve.x_label}"})
        files += [f"sensitivity/{curve.name}.json", f"sensitivity/{curve.name}.png"]
    doc = {**result.to_dict(), "files": files}
    (folder / "experiment.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    (folder / "report.html").write_text(_html(result, figures), encoding="utf-8")
    return doc
