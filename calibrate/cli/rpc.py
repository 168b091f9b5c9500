"""``gcpcal rpc``: fit an RPC to a model and write it (a text RPC or a level-1A GeoTIFF)."""

from __future__ import annotations

import click

from calibrate.actions.rpc import DEFAULT_MAX_ERROR_PX, MIN_TILE_PX, RpcOutputUsageError, fit_rpcs
from calibrate.cli.options import (accept_product_disagreement_option, add_options, allow_implausible_option, dem_options, echo_json, echo_warnings, height_range_option, json_option,
                                   one_height_source)

__all__ = ["command"]


@click.command("rpc")
@allow_implausible_option
@click.argument("model_path", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--out", "out_path", required=True, type=click.Path(),
              help="One RPC: this exact file, *_RPC.TXT, *.RPB, or *.tif (a copy of the scene raster with RPC tags). "
                   "Several CCDs, or tiles: a folder (<ccd>_RPC.TXT and <ccd>.tif per CCD or tile).")
@click.option("--image", type=click.Path(dir_okay=False),
              help="Scene raster copied into a *.tif output (default: the manifest's raster of the band); a crop "
                   "with a pixel geotransform crops the model.")
@add_options(dem_options)
@height_range_option
@click.option("--band", help="Band (multi-band models; default: the reference band).")
@click.option("--ccd", help="CCD name: one RPC for that CCD's columns (then --out may be a file).")
@click.option("--form", type=click.Choice(["rational", "polynomial"]), default="rational", show_default=True,
              help="RPC00B with free denominators, or cubic polynomials (denominators 1).")
@click.option("--max-error-px", type=click.FloatRange(min=0.0, min_open=True), default=DEFAULT_MAX_ERROR_PX,
              show_default=True,
              help="Check-grid maximum error each RPC must reach; a folder --out splits an image into tiles "
                   f"(down to {MIN_TILE_PX} px) until it does, a file --out warns.")
@accept_product_disagreement_option
@json_option
def command(model_path, out_path, image, dem_path, dem_datum, geoid, height_range, band, ccd, form, max_error_px,
            as_json, self_check):
    """Fit an RPC to MODEL over its image and height range and write it.

    --out is written exactly. One RPC (an RPC or staring-camera model, a one-CCD band, or --ccd)
    goes to a file: *_RPC.TXT, *.RPB, or *.tif, a georeferenced level-1A: a copy of the scene
    raster's band (the CCD's columns with --ccd) with the RPC as GeoTIFF RPC tags and its fit
    error in the metadata. A push-broom band with several CCDs needs --out to be a folder: the
    stitched raster jumps where CCDs meet, so each CCD gets its own RPC (<ccd>_RPC.TXT, columns
    counted from the CCD's first detector) and raster (<ccd>.tif); a file name there is a usage
    error (exit 2).

    Where one RPC misses --max-error-px (default 0.01 px) on its check grid because the model
    varies faster than an RPC can follow (attitude or orbit changing faster than a cubic over the
    scene, look directions beyond a cubic), a folder --out splits the CCD's image into tiles, each
    with its own RPC and raster (<ccd>_r<row>_c<col>_RPC.TXT and .tif, first pixel of the tile in
    the CCD's image); a file --out keeps one RPC and warns.

    The height range comes from --dem (its minimum and maximum over the scene, with a margin) or
    --height-range. The fit is terrain-independent (Tao & Hu's reweighted least squares with a
    ridge term chosen on a validation grid; denominators proved free of zeros over the normalized
    cube); its errors on an independent check grid are reported in the summary (OUT.summary.json,
    or rpc.summary.json in the folder).

    When MODEL is a manifest written by gcpcal calibrate (or gcpcal relative), each RPC gets
    ERR_BIAS and ERR_RAND (metres per horizontal axis) from the check points after calibration
    (calibration.json and residuals.gpkg beside it) and the reference's stated accuracy, with the
    RPC's own check-grid RMS added to ERR_RAND; otherwise they stay -1 (unknown).

    MODEL is a gcpcal manifest, a model file (.geom, .RPB, _RPC.TXT, .DIM, .XML) with its raster
    beside it or named in it, or a raster carrying an RPC (GeoTIFF tags, or a .RPB, _RPC.TXT or
    .geom beside it); a crop with a pixel geotransform crops the model (docs/inputs.md).
    """
    one_height_source(height_range=height_range, dem=dem_path)
    try:
        summary = fit_rpcs(model_path, out_path, dem_path=dem_path, dem_datum=dem_datum, geoid=geoid,
                           height_range=height_range, band=band, ccd=ccd, image=image, self_check=self_check,
                           form=form, max_error_px=max_error_px)
    except RpcOutputUsageError as exc:
        raise click.UsageError(str(exc)) from None
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
        return
    tiled = len(summary["rpcs"]) > len({f["ccd"] for f in summary["rpcs"]})
    for f in summary["rpcs"]:
        rep = f["fit"]
        label = f" (CCD {f['ccd']})" if f["ccd"] else ""
        if tiled:
            label += f" rows {f['first_row']}+{f['shape'][0]}, cols {f['first_col']}+{f['shape'][1]}"
        also = f" and {f['raster']}" if f["raster"] and f["raster"] != f["output"] else ""
        click.echo(f"wrote {f['output']}{also}{label}: {rep['form']} RPC, check-grid max {rep['check_max_px']:.2e} px, "
                   f"rms {rep['check_rms_px']:.2e} px")
    errors = summary["rpc_errors"]
    if errors["err_bias_m"] is None:
        click.echo(f"ERR_BIAS, ERR_RAND: {errors['source']}")
    else:
        rand = sorted({round(f["err_rand_m"], 3) for f in summary["rpcs"]})
        rand_text = f"{rand[0]:.3f}" if len(rand) == 1 else f"{rand[0]:.3f} to {rand[-1]:.3f}"
        click.echo(f"ERR_BIAS {errors['err_bias_m']:.3f} m, ERR_RAND {rand_text} m per axis, from "
                   f"{errors['check_points']} check points after calibration ({errors['source']})")
