"""``gcpcal demo``: the main job on an embedded fixture, with a before/after table.

Exit codes follow the run's status (:mod:`calibrate.coverage`): 0 ``calibrated``, 4 ``partial``
(a CCD or a band not calibrated or not verified, named on stderr), 3 ``failed``.
"""

from __future__ import annotations

from pathlib import Path

import click

from calibrate.pipelines.demo import DEFAULT_FIXTURE, FIXTURES, run_demo
from calibrate.cli._errors import EXIT_FAILED, EXIT_OK, EXIT_PARTIAL
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import echo_json, exit_with_status, json_option, out_dir_option

__all__ = ["command"]

_EXIT_OF_STATUS = {"calibrated": EXIT_OK, "partial": EXIT_PARTIAL, "failed": EXIT_FAILED}

_ROWS = (("check_rmse_row_px", "check RMSE along track, px"), ("check_rmse_col_px", "check RMSE across track, px"),
         ("check_rmse_px", "check RMSE planar, px"), ("check_rmse_m", "check RMSE planar, m"))


def _fmt(value, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _table(summary: dict):
    """The before/after table: check points overall and per CCD, then the error against the TRUE model."""
    from rich.table import Table

    table = Table(title=f"HY-1C-like scene, profile {summary['profile']}: LAB model -> calibrated "
                        "(check points never used in the fit)")
    for col in ("", "before", "after"):
        table.add_column(col, justify="right", overflow="fold")  # wrap, never cut with "..."
    for key, label in _ROWS:
        table.add_row(label, _fmt(summary[key]["before"], 2), _fmt(summary[key]["after"], 3))
    for name, rmse in summary["check_rmse_per_ccd_px"].items():
        table.add_row(f"check RMSE planar {name}, px", _fmt(rmse["before"], 2), _fmt(rmse["after"], 3))
    for stat in ("rms", "max"):
        table.add_row(f"error against the TRUE model ({stat}), px", _fmt(summary["truth_error_before_px"][stat], 2),
                      _fmt(summary["truth_error_px"][stat], 3))
    return table


def _print_table(summary: dict, out_dir) -> None:
    from rich.console import Console

    out = Console()
    out.print(_table(summary))
    dem = summary["truth_dem"]
    whose = ("the user's DEM is the TRUE DEM under the ideal profile" if dem == "reference/dem.tif"
             else "not the user's DEM")
    out.print(f"error against the TRUE model: every CCD and band, both models on the TRUE DEM ({dem}: {whose})")
    selected = summary["attitude"]["selected"]
    edf = "" if selected.get("edf") is None else f", {selected['edf']:.1f} effective parameters"
    out.print(f"attitude correction from the GCPs ({summary['attitude']['mode']}): {selected['kind']}, "
              f"{selected['n_terms']} terms{edf}")
    parallax = summary.get("parallax") or {}
    if parallax.get("used"):
        joint = parallax["selected"]
        out.print(f"band parallax: {parallax['ties']} tie points with {parallax['gcps']} GCPs -> final correction "
                  f"{joint['kind']}, {joint['n_terms']} terms")
    elif parallax:
        out.print(f"band parallax not used: {parallax.get('reason') or parallax.get('message')}")
    out.print(f"status: {summary['status']} ({summary['status_message']}); "
              f"variance factor {summary.get('variance_factor', float('nan')):.3g}")
    out.print(f"{summary['gcps']} GCPs, {summary['check_points']} check points; "
              f"wrote {out_dir}/summary.json, {out_dir}/report.html in {summary['seconds']:.1f} s")


@click.command("demo")
@out_dir_option(required=False, default="gcpcal-demo")
@click.option("--fixture", "fixture", type=click.Choice(sorted(FIXTURES)), default=DEFAULT_FIXTURE,
              show_default=True,
              help="Embedded scene: 'realistic' (the realistic error profile: the reference is another date and "
                   "sensor, the DEM SRTM-like) or 'ideal' (the unit-test scene: the reference is what rendered it).")
@json_option
@click.pass_context
def command(ctx, out_dir, fixture, as_json):
    """Run the main job on an embedded fixture and write OUT/summary.json.

    Exit 0: calibrated; 4: partial (CCDs or bands not calibrated or not verified, named); 3: failed.
    """
    with stage_progress(ctx, "gcpcal demo", as_json) as progress:
        summary = run_demo(Path(out_dir), fixture_dir=FIXTURES[fixture], progress=progress.message)
    if as_json:
        echo_json(summary)
    else:
        _print_table(summary, out_dir)
    code = _EXIT_OF_STATUS[summary["status"]]
    if code != EXIT_OK:
        exit_with_status(ctx, code, summary["status_message"])
