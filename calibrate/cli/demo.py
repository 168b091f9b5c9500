"""``gcpcal demo``: the main job on the embedded fixtures, with a before/after table."""

from __future__ import annotations

from pathlib import Path

import click

from calibrate.actions.demo import run_demo
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import echo_json, json_option, out_dir_option

__all__ = ["command"]

_ROWS = (("check_rmse_row_px", "check RMSE along track, px"), ("check_rmse_col_px", "check RMSE across track, px"),
         ("check_rmse_px", "check RMSE planar, px"), ("check_rmse_m", "check RMSE planar, m"))


def _print_table(summary: dict, out_dir) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="HY-1C-like scene: LAB model -> calibrated (check points never used in the fit)")
    for col in ("", "before", "after"):
        table.add_column(col, justify="right", overflow="fold")  # wrap, never cut with "..."
    for key, label in _ROWS:
        b, a = summary[key]["before"], summary[key]["after"]
        table.add_row(label, f"{b:.2f}" if b is not None else "-", f"{a:.3f}" if a is not None else "-")
    table.add_row("error against the TRUE model (rms), px", f"{summary['truth_error_before_px']['rms']:.2f}",
                  f"{summary['truth_error_px']['rms']:.3f}")
    table.add_row("error against the TRUE model (max), px", f"{summary['truth_error_before_px']['max']:.2f}",
                  f"{summary['truth_error_px']['max']:.3f}")
    out = Console()
    out.print(table)
    out.print(f"status: {summary.get('status', '?')}; variance factor {summary.get('variance_factor', float('nan')):.3g}")
    out.print(f"{summary['gcps']} GCPs, {summary['check_points']} check points; "
              f"wrote {out_dir}/summary.json, {out_dir}/report.html in {summary['seconds']:.1f} s")


@click.command("demo")
@out_dir_option(required=False, default="gcpcal-demo")
@json_option
@click.pass_context
def command(ctx, out_dir, as_json):
    """Run the main job on the embedded fixtures and write OUT/summary.json."""
    with stage_progress(ctx, "gcpcal demo", as_json) as progress:
        summary = run_demo(Path(out_dir), progress=progress.message)
    if as_json:
        echo_json(summary)
        return
    _print_table(summary, out_dir)
