"""``gcpcal stars``: star-track calibration of a geostationary staring camera (seed 000)."""

from __future__ import annotations

import click

from calibrate.actions.stars import stars_sequence
from calibrate.cli._errors import EXIT_FAILED
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import echo_json, exit_with_status, json_option, out_dir_option
from calibrate.config import STAR_CENTROIDS, STAR_SCHEMES, StarOptions

__all__ = ["command"]


def _accuracy_line(out_dir, doc: dict) -> str:
    acc = doc["accuracy"]
    if not acc:
        return f"{out_dir}: {doc['message']}"
    b, a = acc["before"], acc["after"]
    return (f"{out_dir}: {doc['message']}; {doc['frames']['n_tracks']} tracks; held-out RA/DE mean "
            f"{b['ra']['mean_px']:.3f}/{b['de']['mean_px']:.3f} px -> mean |error| "
            f"{a['ra']['mean_abs_px']:.3f}/{a['de']['mean_abs_px']:.3f} px, 2-sigma "
            f"{a['ra'].get('two_sigma_px', float('nan')):.3f}/{a['de'].get('two_sigma_px', float('nan')):.3f} px")


@click.command("stars")
@click.argument("frames_path", metavar="FRAMES", type=click.Path())
@out_dir_option()
@click.option("--manifest", type=click.Path(dir_okay=False), help="LAB manifest (default: the one the frame list names).")
@click.option("--catalog", default=StarOptions.catalog, show_default=True, help="Star catalogue.")
@click.option("--mag-limit", type=float, default=StarOptions.mag_limit, show_default=True,
              help="Faintest catalogue magnitude.")
@click.option("--scheme", type=click.Choice(STAR_SCHEMES), default=StarOptions.scheme, show_default=True,
              help="Seed 000's stepwise scheme, the exterior alone, or joint.")
@click.option("--centroid", type=click.Choice(STAR_CENTROIDS), default=StarOptions.centroid, show_default=True,
              help="Star centroid estimator on the frames.")
@click.option("--seed", type=int, default=StarOptions.seed, show_default=True, help="Choice of the held-out points.")
@json_option
@click.pass_context
def command(ctx, frames_path, out_dir, manifest, catalog, mag_limit, scheme, centroid, seed, as_json):
    """Calibrate a staring camera from star tracks in FRAMES (a frames.json or its folder)."""
    options = StarOptions(catalog=catalog, mag_limit=mag_limit, scheme=scheme, centroid=centroid, seed=seed)
    with stage_progress(ctx, "gcpcal stars", as_json):
        doc = stars_sequence(frames_path, out_dir, manifest=manifest, options=options)
    if as_json:
        echo_json({"success": doc["success"], "message": doc["message"], "accuracy": doc["accuracy"]})
    else:
        click.echo(_accuracy_line(out_dir, doc))
    if not doc["success"]:
        exit_with_status(ctx, EXIT_FAILED, doc["message"])
