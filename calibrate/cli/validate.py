"""``gcpcal validate``: check a calibration on validation scenes, one Dask task per scene.

Shows progress (stderr) and the result table (stdout). Exit status: 0 when every scene was
validated, 4 when some failed and 3 when all failed (their rows say why; the outputs are written
all the same), 1 on a user error (one line: bad sites file, calibration, unreachable scheduler).
"""

from __future__ import annotations

import click

from calibrate.actions.validate import validate_calibration
from calibrate.cli._progress import scene_lines, stage_progress
from calibrate.cli.options import echo_json, echo_warnings, exit_for_failed_scenes, json_option, out_dir_option

__all__ = ["command"]


@click.command("validate")
@click.argument("sites_path", metavar="SITES", type=click.Path(dir_okay=False))
@click.option("--calibration", "calibration", required=True, type=click.Path(),
              help="Calibrated manifest.json, or the folder of gcpcal calibrate / gcpcal demo holding it.")
@out_dir_option()
@click.option("--scheduler", help="Dask scheduler address (tcp://host:8786); default: a local cluster.")
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True,
              help="Worker processes of the local cluster (ignored with --scheduler).")
@click.option("--spacing", type=click.IntRange(min=4), default=32, show_default=True, help="Matching window spacing, pixels.")
@click.option("--timeout", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Seconds allowed to connect to --scheduler.")
@json_option
@click.pass_context
def command(ctx, sites_path, calibration, out_dir, scheduler, workers, spacing, timeout, as_json):
    """Validate a calibration on the scenes of SITES (YAML or CSV: name, scene, dom, dem)."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    with stage_progress(ctx, "gcpcal validate", as_json) as bar:
        summary = validate_calibration(sites_path, calibration, out_dir, scheduler=scheduler, workers=workers,
                                       spacing_px=spacing, timeout_s=timeout, progress=scene_lines(bar, _ok_text))
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
    else:
        _print_table(Console(), Table, escape, summary["rows"], summary, out_dir)
    exit_for_failed_scenes(ctx, summary)


def _ok_text(row) -> str:
    return f"planar {row['rmse_planar_px']:.3f} px on {row['points']} points"


def _print_table(out, table_cls, escape, rows, summary, out_dir) -> None:
    def f(v, d=3):
        return "-" if v is None else f"{v:.{d}f}"

    table = table_cls(title="Validation scenes: accuracy of the calibrated model, px (seed 003 table 5)")
    for col in ("ID", "scene", "date", "along", "across", "planar", "planar m", "points", "LAB planar"):
        table.add_column(col, justify="left" if col in ("scene", "date") else "right", overflow="fold")  # never "..."
    for k, r in enumerate(rows, start=1):
        if r["status"] != "ok":
            table.add_row(str(k), escape(r["name"]), r.get("date") or "", "[red]failed[/red]", "", "", "", "", "")
            continue
        table.add_row(str(k), escape(r["name"]), r["date"] or "", f(r["rmse_along_px"]), f(r["rmse_across_px"]),
                      f(r["rmse_planar_px"]), f(r["rmse_planar_m"], 1), str(r["points"]), f(r["lab_rmse_planar_px"], 1))
    m = summary["mean"]
    table.add_row("", f"mean of {summary['ok']}", "", f(m["rmse_along_px"]), f(m["rmse_across_px"]),
                  f(m["rmse_planar_px"]), f(m["rmse_planar_m"], 1), f(m["points"], 0), f(m["lab_rmse_planar_px"], 1),
                  style="bold")
    out.print(table)
    for name, reason in summary["failures"].items():
        out.print(f"[red]failed[/red] {escape(name)}: {escape(reason or '')}", highlight=False)
    out.print(f"{summary['ok']}/{summary['scenes']} scenes in {summary['seconds']:.1f} s on {summary['workers']} "
              f"worker(s); wrote {out_dir}/validation.html, validation.csv, validation.json", highlight=False)
