"""``gcpcal calibrate``: calibrate a scene's model from a GCP table."""

from __future__ import annotations

import click

from calibrate.actions.calibrate import calibrate_scene
from calibrate.cli._errors import EXIT_FAILED
from calibrate.cli.options import echo_json, json_option, out_dir_option, progress_printer
from calibrate.config import CALIBRATION_SCHEMES, ROBUST_LOSSES, CalibrationOptions

__all__ = ["command"]


@click.command("calibrate")
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--gcps", "gcps_path", required=True, type=click.Path(dir_okay=False), help="GCP table (CSV, GeoPackage or GeoTIFF).")
@out_dir_option()
@click.option("--scheme", type=click.Choice(CALIBRATION_SCHEMES), default=CalibrationOptions.scheme, show_default=True,
              help="Which parameters, in which order (seed 002's schemes).")
@click.option("--robust", type=click.Choice(ROBUST_LOSSES), default=CalibrationOptions.robust, show_default=True,
              help="Robust loss.")
@click.option("--band", help="Band of GCPs that name none (default: the reference band).")
@click.option("--image", type=click.Path(dir_okay=False), help="Raster the GCPs were measured in, when it is a crop of SCENE.")
@click.option("--no-report", is_flag=True, help="Skip report.html and its figures.")
@json_option
@click.pass_context
def command(ctx, scene_path, gcps_path, out_dir, scheme, robust, band, image, no_report, as_json):
    """Calibrate SCENE's model from GCPs; write calibration.json, the calibrated model and report.html."""
    options = CalibrationOptions(scheme=scheme, robust=robust)
    summary = calibrate_scene(scene_path, gcps_path, out_dir, options=options, band=band, image=image,
                              report=not no_report, progress=progress_printer(ctx, as_json))
    if as_json:
        echo_json(summary)
    else:
        before, after = summary["check_rmse_px"]["before"], summary["check_rmse_px"]["after"]
        checks = (f"check RMSE {before:.3f} -> {after:.3f} px on {summary['check_points']} check points"
                  if before is not None else "no check points")
        click.echo(f"{out_dir}: {'converged' if summary['success'] else 'FAILED'} ({summary['message']}); {checks}")
    if not summary["success"]:
        ctx.exit(EXIT_FAILED)
