"""HTML and figure helpers shared by the calibration reports (:mod:`calibrate.report`,
:mod:`calibrate.report.star_report`): page style, escaping, number formatting, tables, Agg figures
embedded as PNG files (a report is written through :func:`sensor_models.files.atomic.atomic_folder`).
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np

#: resolution of every report figure
FIGURE_DPI = 100


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1250px;color:#222;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right}th{background:#f2f4f7}
td.l,th.l{text-align:left}tr.total td{font-weight:600;background:#fafafa}
.ok{color:#17733a;font-weight:600}.fail{color:#b3261e;font-weight:600}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.88em;color:#444}
.meta{color:#666;font-size:.85em}details{margin:.6em 0}summary{cursor:pointer}pre{margin:0;white-space:pre-wrap}
nav a{margin-right:1em}.count-note{font-size:.88em;color:#444;margin:.2em 0}
"""


def new_figure(width_in, height_in, *, left=0.8, right=0.25, bottom=0.6, top=0.45, wspace=0.8, hspace=0.75):
    """A Figure on an Agg canvas with fixed margins in inches.

    Fixed margins rather than a layout engine: constrained layout measures every text and
    doubles the drawing time of figures with many CCD labels.

    Parameters
    ----------
    width_in, height_in : float
        Figure size, inches.
    left, right, bottom, top : float
        Margins, inches.
    wspace, hspace : float
        Spacing between subplots, inches.

    Returns
    -------
    matplotlib.figure.Figure
        A figure with an Agg canvas.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=FIGURE_DPI)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=left / width_in, right=1.0 - right / width_in, bottom=bottom / height_in,
                        top=1.0 - top / height_in, wspace=wspace, hspace=hspace)
    return fig


def save_figure(fig, fig_dir: Path, name: str) -> str:
    """Save ``fig`` as a PNG in ``fig_dir``; its path relative to the report.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Figure to save.
    fig_dir : Path
        The report's ``figures/`` folder.
    name : str
        File name.

    Returns
    -------
    str
        ``"figures/<name>"``.
    """
    fig.savefig(fig_dir / name, dpi=FIGURE_DPI, format="png")
    return f"figures/{name}"


def escape(text) -> str:
    """HTML-escaped text (quotes included).

    Parameters
    ----------
    text : object
        Converted with ``str``.

    Returns
    -------
    str
        Escaped text.
    """
    return html.escape(str(text), quote=True)


def count_note(n, total, what: str, why: str) -> str:
    """One short paragraph saying why a count is smaller than another, or nothing when they agree.

    Every place a report shows two counts of the same points that differ says why beside them
    (``<p class="count-note">``), so that a reader never meets a bare discrepancy.

    Parameters
    ----------
    n, total : int or None
        The count shown and the one it differs from; None gives nothing.
    what : str
        The points counted (``"check points"``).
    why : str
        Short phrase: which ones the count holds or why the others are left out.

    Returns
    -------
    str
        ``<p class="count-note">n of total what: why.</p>``, or ``""`` when ``n == total``.
    """
    if n is None or total is None or int(n) == int(total):
        return ""
    return f'<p class="count-note">{int(n)} of {int(total)} {escape(what)}: {escape(why)}.</p>'


def fmt(value, digits: int = 4) -> str:
    """A number with ``digits`` significant digits; ``–`` for None and non-finite values.

    Parameters
    ----------
    value : float, int, bool or None
        Number to write (booleans become ``yes``/``no``).
    digits : int
        Significant digits.

    Returns
    -------
    str
        The text.
    """
    if value is None:
        return "–"
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return escape(value)
    if not math.isfinite(v):
        return "–"
    return f"{v:.{digits}g}"


def table(header, rows, *, left=1, row_classes=None) -> str:
    """HTML table; ``rows`` hold already-escaped cell strings; the first ``left`` columns align left.

    Parameters
    ----------
    header : sequence of str or None
        Column titles (escaped here); None for a table of key/value rows without a header row.
    rows : sequence of sequence of str
        Escaped cell HTML.
    left : int
        Leading columns aligned left.
    row_classes : sequence of str, optional
        CSS class of each row.

    Returns
    -------
    str
        HTML.
    """
    head = "" if header is None else "".join(
        f'<th class="l">{h}</th>' if j < left else f"<th>{h}</th>" for j, h in enumerate(header))
    body = []
    for i, row in enumerate(rows):
        cls = f' class="{row_classes[i]}"' if row_classes and row_classes[i] else ""
        cells = "".join(f'<td class="l">{c}</td>' if j < left else f"<td>{c}</td>" for j, c in enumerate(row))
        body.append(f"<tr{cls}>{cells}</tr>")
    thead = f"<thead><tr>{head}</tr></thead>" if head else ""
    return f"<table>{thead}<tbody>{''.join(body)}</tbody></table>"


def figure_html(fig) -> str:
    """The HTML of a figure record (image and caption); empty for None.

    Parameters
    ----------
    fig : dict or None
        ``{"src", "caption"}``.

    Returns
    -------
    str
        HTML.
    """
    if not fig:
        return ""
    return (
        f'<figure><img src="{escape(fig["src"])}" alt="{escape(fig["caption"])}">'
        f"<figcaption>{escape(fig['caption'])}</figcaption></figure>"
    )


def value_html(value, depth: int = 0) -> str:
    """A value of a report's free-form section as HTML: text, a number, a list, or a table of a
    mapping (nested to two levels, deeper values as compact text), never a raw JSON dump.

    Parameters
    ----------
    value : object
        JSON-like value (numbers, strings, mappings, sequences, numpy scalars/arrays).
    depth : int
        Nesting level of the call (tables nest to two levels).

    Returns
    -------
    str
        HTML.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, np.generic):
        value = value.item()
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)):
        return fmt(value, 6)
    if isinstance(value, str):
        return escape(value)
    if isinstance(value, dict):
        if depth >= 2:
            return escape(", ".join(f"{k}: {v}" for k, v in value.items()))
        return table(None, [[escape(k), value_html(v, depth + 1)] for k, v in value.items()], left=2)
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, dict) for v in value) and value and depth < 2:
            keys = list(dict.fromkeys(k for v in value for k in v))
            return table([escape(k) for k in keys], [[value_html(v.get(k), 2) for k in keys] for v in value],
                         left=len(keys))
        return escape(", ".join(str(fmt(v, 6) if isinstance(v, float) else v) for v in value))
    return escape(str(value))


def section_provenance(record: dict) -> str:
    """The "Inputs and provenance" section of a report from a provenance record.

    Parameters
    ----------
    record : dict
        :func:`calibrate.actions._provenance.provenance_record`.

    Returns
    -------
    str
        HTML: the version, command line and time; the input files (path, size, SHA-256); the
        terrain (DEM, vertical datum, geoid); the reference's accuracy and its source.
    """
    head = [["gcpcal", escape(record.get("gcpcal_version", ""))],
            ["command", f"<code>{escape(record.get('command_line') or '(called from Python)')}</code>"],
            ["created", escape(record.get("created_utc", ""))],
            ["python / platform", escape(f"{record.get('python', '')} / {record.get('platform', '')}")]]
    terrain = record.get("terrain") or {}
    if terrain:
        head.append(["DEM", escape(f"{terrain.get('dem')} (heights {terrain.get('vertical_datum')}"
                                   + (f", geoid {terrain.get('geoid')}" if terrain.get("geoid") else "") + ")")])
    acc = record.get("reference_accuracy") or {}
    if acc:
        head.append(["reference accuracy",
                     escape(f"{fmt(acc.get('east_m'), 3)} m east, {fmt(acc.get('north_m'), 3)} m north (1 sigma), "
                            f"{'assumed' if acc.get('assumed') else 'from ' + str(acc.get('source'))}")])
    rows = [[escape(i.get("path")), "–" if i.get("bytes") is None else f"{i['bytes']:,}",
             f"<code>{escape(i.get('sha256') or i.get('sha256_note') or '–')}</code>"]
            for i in record.get("inputs", [])]
    upstream = record.get("gcps_from") or {}
    if upstream:
        head.append(["GCPs made by", f"<code>{escape(upstream.get('command_line') or '?')}</code> "
                                     f"({escape(upstream.get('created_utc') or '')})"])
        up_terrain = upstream.get("terrain") or {}
        if up_terrain:
            head.append(["GCPs' DEM", escape(f"{up_terrain.get('dem')} (heights {up_terrain.get('vertical_datum')}"
                                             + (f", geoid {up_terrain.get('geoid')}" if up_terrain.get("geoid")
                                                else "") + ")")])
        rows += [[escape(i.get("path")) + " (matching)", "–" if i.get("bytes") is None else f"{i['bytes']:,}",
                  f"<code>{escape(i.get('sha256') or i.get('sha256_note') or '–')}</code>"]
                 for i in upstream.get("inputs") or []]
    out = table(None, head, left=2)
    if rows:
        out += table(["input file", "bytes", "SHA-256"], rows, left=1)
    return out
