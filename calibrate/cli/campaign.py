"""``gcpcal campaign``: ``gcpcal run`` on many scenes, one Dask task per scene (docs/campaign.md).

Shows progress (stderr) and the campaign table (stdout). Exit status: 0 when every scene was
calibrated, 4 when some failed and 3 when all failed (their rows say why; the outputs are written
all the same), 1 on a user error (one line: bad campaign file, unreachable scheduler, refused
output), 2 on a usage error.
"""

from __future__ import annotations

import click

from calibrate.cli._progress import scene_lines, stage_progress
from calibrate.cli.options import (add_options, dem_options, echo_json, exit_for_failed_scenes, json_option,
                                   optional_dom_options, out_dir_option)
from calibrate.pipelines.run import MIN_COVERAGE, MIN_GCPS

__all__ = ["command"]


@click.command("campaign")
@click.argument("campaign_path", metavar="CAMPAIGN", type=click.Path())
@out_dir_option(help="Campaign folder: OUT/<scene>/ per scene, campaign.csv, campaign.json, campaign_residuals.gpkg.")
@optional_dom_options
@add_options(dem_options)
@click.option("--scheduler", help="Dask scheduler address (tcp://host:8786); default: a local cluster.")
@click.option("--workers", type=click.IntRange(min=1),
              help="Workers of the local cluster (ignored with --scheduler)  [default: one per core, at most one per scene]")
@click.option("--threads", type=click.IntRange(min=0),
              help="Matching threads of each scene, 0: every core of its machine  "
                   "[default: the cores shared among the local workers; 0 with --scheduler]")
@click.option("--relative", is_flag=True, help="Also calibrate the other bands of each scene (gcpcal run --relative).")
@click.option("--spacing", type=click.IntRange(min=4), default=16, show_default=True, help="Matching window spacing, pixels.")
@click.option("--min-gcps", type=click.IntRange(min=1), default=MIN_GCPS, show_default=True,
              help="GCPs needed to calibrate a scene from the ground.")
@click.option("--min-coverage", type=click.FloatRange(0.0, 1.0), default=MIN_COVERAGE, show_default=True,
              help="Share of a 4 x 4 partition of the image the GCPs must cover.")
@click.option("--timeout", type=click.FloatRange(min=0.1), default=10.0, show_default=True,
              help="Seconds allowed to reach --scheduler and for its first worker.")
@click.option("--resume", is_flag=True,
              help="Keep the scene folders of OUT that a run completed from the same inputs and options; run the "
                   "other scenes (each folder moved into OUT as its scene ends, so that an interrupted run can "
                   "resume) and rebuild the campaign's table and layer over all.")
@json_option
@click.pass_context
def command(ctx, campaign_path, out_dir, dom_path, dem_path, dem_datum, geoid, scheduler, workers, threads, relative,
            spacing, min_gcps, min_coverage, timeout, resume, as_json):
    """Run gcpcal run on every scene of CAMPAIGN, one Dask task per scene; one table for all.

    CAMPAIGN is a campaign file (YAML, JSON or CSV: name, scene, dom, dem, and optionally out,
    dem_datum, geoid, dom_band, dom_qa, star_frames) or a folder with one scene per subfolder
    (docs/campaign.md). A scene that fails is a row with its reason; the others go on.

    The DOM and DEM options apply to a folder CAMPAIGN only: every scene's DOM and DEM (default:
    each scene's reference/dom.tif and reference/dem.tif).

    With --resume, a scene whose folder in OUT a run completed from the same inputs (files by
    size and modification time, content when only the time changed), the same campaign entry
    and the same options is kept, its row read from its run.summary.json; every other scene
    (new, changed, failed, or never finished) runs again, and stderr says why. Give --resume
    from the first run of a long campaign: without it OUT is written whole at the end, and an
    interrupted run leaves nothing to resume.
    """
    from calibrate.pipelines.campaign import read_campaign, run_campaign

    scenes = read_campaign(campaign_path, dom=dom_path, dem=dem_path, dem_datum=dem_datum, geoid=geoid)
    with stage_progress(ctx, "gcpcal campaign", as_json) as bar:
        summary = run_campaign(scenes, out_dir, source=campaign_path, scheduler=scheduler, workers=workers,
                               threads=threads, timeout_s=timeout, spacing_px=spacing, min_gcps=min_gcps,
                               min_coverage=min_coverage, relative=relative, resume=resume,
                               progress=scene_lines(bar, _ok_text), note=bar.note)
    if as_json:
        echo_json(summary)
    else:
        _print_table(summary, out_dir)
    exit_for_failed_scenes(ctx, summary)


def _ok_text(row) -> str:
    return f"{row['gcps']} GCPs, check RMSE {_f(row['check_rmse_after_px'])} px"


def _f(value, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _print_table(summary, out_dir) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table(title="Campaign: check-point RMSE before and after calibration, px")
    for col in ("scene", "status", "path", "GCPs", "before", "after", "s"):
        table.add_column(col, justify="left" if col in ("scene", "status", "path") else "right", overflow="fold")
    for r in summary["rows"]:
        status = "ok" if r["status"] == "ok" else "[red]failed[/red]"
        table.add_row(escape(r["name"]), status, r.get("path") or "-", "-" if r["gcps"] is None else str(r["gcps"]),
                      _f(r["check_rmse_before_px"], 1), _f(r["check_rmse_after_px"]), _f(r["seconds"], 1))
    out = Console()
    out.print(table)
    for name, reason in summary["failures"].items():
        out.print(f"[red]failed[/red] {escape(name)}: {escape(reason or '')}", highlight=False)
    kept = f" ({len(summary['kept'])} kept from the earlier run)" if summary.get("kept") else ""
    out.print(f"{summary['ok']}/{summary['scenes']} scenes{kept} in {summary['seconds']:.1f} s on {summary['workers']} "
              f"worker(s); wrote {out_dir}/campaign.csv, campaign.json, campaign_residuals.gpkg", highlight=False)
