"""``gcpcal rpc``: fit an RPC to a model and write it."""

from __future__ import annotations

import click

from calibrate.actions.rpc import fit_rpcs
from calibrate.cli.options import (add_options, dem_options, echo_json, echo_warnings, height_range_option, json_option,
                                   one_height_source)

__all__ = ["command"]


@click.command("rpc")
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False), help="Output: *_RPC.TXT, *.RPB, or *.tif (RPC tags).")
@add_options(dem_options)
@height_range_option
@click.option("--band", help="Band (multi-band models; default: the reference band).")
@click.option("--ccd", help="CCD name; default: one RPC per CCD (suffix _<ccd> in the file name).")
@json_option
def command(model_path, out_path, dem_path, dem_datum, geoid, height_range, band, ccd, as_json):
    """Fit an RPC to MODEL over its image and height range and write it.

    A push-broom band with several CCDs gets one RPC per CCD image (columns counted from the
    CCD's first detector), since the stitched raster is discontinuous where CCDs overlap.

    The height range comes from --dem (its minimum and maximum over the scene, with a margin) or
    --height-range. The fit is terrain-independent; its errors on an independent check grid are
    reported in OUT.summary.json.
    """
    one_height_source(height_range=height_range, dem=dem_path)
    summary = fit_rpcs(model_path, out_path, dem_path=dem_path, dem_datum=dem_datum, geoid=geoid,
                       height_range=height_range, band=band, ccd=ccd)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
        return
    for f in summary["rpcs"]:
        rep = f["fit"]
        label = f" (CCD {f['ccd']})" if f["ccd"] else ""
        click.echo(f"wrote {f['output']}{label}: check-grid max {rep['check_max_px']:.2e} px, rms {rep['check_rms_px']:.2e} px")
