"""``gcpcal run``: calibrate from GCPs, or from star frames when clouds leave too few."""

from __future__ import annotations

import click

from calibrate.actions.run import MIN_COVERAGE, MIN_GCPS, run_scene
from calibrate.cli._errors import EXIT_FAILED
from calibrate.cli.options import (add_options, dem_options, dom_options, echo_json, echo_warnings, json_option,
                                   out_dir_option, progress_printer)
from sensor_models.errors import InputError

__all__ = ["command"]


@click.command("run")
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@dom_options
@add_options(dem_options)
@click.option("--star-frames", type=click.Path(), help="Star sequence (frames.json or its folder) for the fallback.")
@out_dir_option()
@click.option("--min-gcps", type=click.IntRange(min=1), default=MIN_GCPS, show_default=True,
              help="GCPs needed to calibrate from the ground.")
@click.option("--min-coverage", type=click.FloatRange(0.0, 1.0), default=MIN_COVERAGE, show_default=True,
              help="Share of a 4 x 4 partition of the image the GCPs must cover.")
@json_option
@click.pass_context
def command(ctx, scene_path, dom_path, dem_path, dem_datum, geoid, star_frames, out_dir, min_gcps, min_coverage,
            as_json):
    """Calibrate SCENE from GCPs, or from star frames when clouds leave too few (says which and why)."""
    if dem_path is None:
        raise InputError("--dem is required: GCPs need terrain heights")
    summary = run_scene(scene_path, dom_path=dom_path, dem_path=dem_path, out_dir=out_dir, star_frames=star_frames,
                        dem_datum=dem_datum, geoid=geoid, min_gcps=min_gcps, min_coverage=min_coverage,
                        progress=progress_printer(ctx, as_json))
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
    else:
        click.echo(f"{out_dir}: path {summary['path']} ({summary['reason']}); "
                   f"{'converged' if summary['success'] else 'FAILED'}: {summary['message']}")
    if not summary["success"]:
        ctx.exit(EXIT_FAILED)
