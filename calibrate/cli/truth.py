"""``gcpcal truth error``: compare a model with the TRUE model of a simulated scene."""

from __future__ import annotations

import click

from calibrate.actions.simulate import truth_error_of
from calibrate.cli.options import (add_options, allow_implausible_option, constant_height_option, dem_options, echo_json, echo_warnings,
                                   height_range_option, json_option, one_height_source)

__all__ = ["command"]


@click.group("truth")
def command():
    """Compare models with the truth of a simulated scene."""


@command.command("error")
@allow_implausible_option
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--truth", "truth_path", required=True, type=click.Path(dir_okay=False), help="The TRUE model (truth_manifest.json of a simulation).")
@add_options(dem_options)
@constant_height_option
@height_range_option
@click.option("--step", type=click.FloatRange(min=1.0), default=16.0, show_default=True, help="Grid spacing in pixels.")
@click.option("--out", "out_path", type=click.Path(dir_okay=False), help="Write the result as JSON; - writes it on standard output.")
@json_option
def error_command(model_path, truth_path, dem_path, dem_datum, geoid, height, height_range, step, out_path, as_json):
    """Pixel error of MODEL against the TRUE model over a grid of every CCD and band.

    The ground is --dem, or the planes at --height, or at the lowest, middle and highest heights
    of --height-range; default: the planes at 0, 1000 and 2000 m above the ellipsoid.
    """
    result = truth_error_of(model_path, truth_path, dem_path=dem_path, dem_datum=dem_datum, geoid=geoid,
                            heights_m=_heights_m(height, height_range, dem_path), step_px=step,
                            out_path=out_path)
    echo_warnings(result)
    if as_json or out_path == "-":
        echo_json(result)
        return
    for r in result["per_ccd"]:
        if r["rms_px"] is None:  # the CCD's grid fell off the DEM
            click.echo(f"{r['band']:>6} {r['ccd']:>10}  no point on the DEM")
            continue
        click.echo(f"{r['band']:>6} {r['ccd']:>10}  rms {r['rms_px']:.4f} px  max {r['max_px']:.4f} px  "
                   f"mean (row, col) ({r['mean_row_px']:+.4f}, {r['mean_col_px']:+.4f})")
    if result["rms_px"] is None:
        click.echo(f"all: no grid point seen by both models ({result['n_missing']} left out)")
        return
    over = " (lines of sight: the frame sees no ground)" if result.get("compared") == "lines of sight" else ""
    click.echo(f"all: rms {result['rms_px']:.4f} px, max {result['max_px']:.4f} px over {result['n_points']} points{over}")


def _heights_m(height, height_range, dem_path):
    """Heights (m) of the comparison planes from the height family; None for the DEM or the default."""
    source = one_height_source(height=height, height_range=height_range, dem=dem_path)
    if source == "height":
        return [height]
    if source == "height_range":
        low, high = sorted(height_range)
        return [low, 0.5 * (low + high), high] if high > low else [low]
    return None
