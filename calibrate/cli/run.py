"""``gcpcal run``: calibrate from GCPs, or from star frames when clouds leave too few."""

from __future__ import annotations

import click

from calibrate.pipelines.run import MIN_COVERAGE, MIN_GCPS, run_scene
from calibrate.cli._errors import EXIT_FAILED
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import (accept_product_disagreement_option, add_options, allow_implausible_option,
                                   dom_options, echo_json, echo_warnings, exit_with_status, json_option,
                                   out_dir_option, required_dem_options)

__all__ = ["command"]


@click.command("run")
@allow_implausible_option
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@dom_options
@add_options(required_dem_options)
@click.option("--star-frames", type=click.Path(), help="Star sequence (frames.json or its folder) for the fallback.")
@out_dir_option()
@click.option("--min-gcps", type=click.IntRange(min=1), default=MIN_GCPS, show_default=True,
              help="GCPs needed to calibrate from the ground.")
@click.option("--min-coverage", type=click.FloatRange(0.0, 1.0), default=MIN_COVERAGE, show_default=True,
              help="Share of a 4 x 4 partition of the image the GCPs must cover.")
@click.option("--relative", is_flag=True,
              help="After a calibration from the GCPs, calibrate the other bands against the reference band "
                   "(gcpcal relative, into OUT/relative).")
@accept_product_disagreement_option
@json_option
@click.pass_context
def command(ctx, scene_path, dom_path, dem_path, dem_datum, geoid, star_frames, out_dir, min_gcps, min_coverage,
            relative, as_json, self_check):
    """Calibrate SCENE from GCPs, or from star frames when clouds leave too few (says which and why).

    SCENE is a gcpcal manifest, a model file (.geom, .RPB, _RPC.TXT, .DIM, .XML) with its raster
    beside it or named in it, or a raster carrying an RPC (GeoTIFF tags, or a .RPB, _RPC.TXT or
    .geom beside it); a crop with a pixel geotransform crops the model (docs/inputs.md).
    """
    with stage_progress(ctx, "gcpcal run", as_json) as progress:
        summary = run_scene(scene_path, dom_path=dom_path, dem_path=dem_path, out_dir=out_dir, star_frames=star_frames,
                            dem_datum=dem_datum, geoid=geoid, min_gcps=min_gcps, min_coverage=min_coverage,
                            relative=relative, progress=progress.message, self_check=self_check)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
    else:
        taken = f"path {summary['path']}" if summary["path"] else "no path"
        click.echo(f"{out_dir}: {taken} ({summary['reason']}); "
                   f"{'converged' if summary['success'] else 'FAILED'}: {summary['message']}")
    if not summary["success"]:
        exit_with_status(ctx, EXIT_FAILED, f"path {summary['path']}: {summary['message']}" if summary["path"]
                         else summary["message"])
