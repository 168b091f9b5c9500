"""``gcpcal ortho``: orthoimage of a scene band as a Cloud-Optimized GeoTIFF."""

from __future__ import annotations

import click

from calibrate.actions.ortho import ortho_scene
from calibrate.cli._progress import stage_progress
from calibrate.cli.options import (accept_product_disagreement_option, add_options, allow_implausible_option,
                                   echo_json, echo_warnings, json_option, required_dem_options, threads_option)
from calibrate.config import ORTHO_RESAMPLING, OrthoOptions

__all__ = ["command"]


@click.command("ortho")
@allow_implausible_option
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--calibration", type=click.Path(),
              help="Calibrated model (manifest.json or RPC), or the folder of 'gcpcal calibrate': the geometry. "
                   "Default: SCENE's own model.")
@add_options(required_dem_options)
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Orthoimage (Cloud-Optimized GeoTIFF); OUT.summary.json goes beside it.")
@click.option("--band", help="Band (default: the reference band).")
@click.option("--crs", help="Output CRS, e.g. EPSG:32631 (default: the UTM zone of the scene centre).")
@click.option("--resolution", type=click.FloatRange(min=0.0, min_open=True),
              help="Pixel size in CRS units, m (default: the scene's ground sampling distance).")
@click.option("--resampling", type=click.Choice(ORTHO_RESAMPLING), default=OrthoOptions.resampling, show_default=True,
              help="Interpolation of the scene pixels.")
@click.option("--image", type=click.Path(dir_okay=False), help="Scene raster (default: the raster SCENE lists, names or has beside it).")
@click.option("--block", type=click.IntRange(min=64), default=OrthoOptions.block, show_default=True,
              help="Output pixels per block side (memory grows with its square times --threads, not with the output).")
@threads_option("the output blocks (each with one OpenCV thread)")
@accept_product_disagreement_option
@json_option
@click.pass_context
def command(ctx, scene_path, calibration, dem_path, dem_datum, geoid, out_path, band, crs, resolution, resampling,
            image, block, threads, as_json, self_check):
    """Orthorectify a band of SCENE on the DEM into a Cloud-Optimized GeoTIFF.

    The geometry comes from --calibration (the calibrated model) when given, the pixels from
    SCENE's rasters (or --image). The output grid is the scene footprint's bounding box in the
    CRS at the resolution; pixels off the image or the DEM are no-data (0).

    SCENE is a gcpcal manifest, a model file (.geom, .RPB, _RPC.TXT, .DIM, .XML) with its raster
    beside it or named in it, or a raster carrying an RPC (GeoTIFF tags, or a .RPB, _RPC.TXT or
    .geom beside it); a crop with a pixel geotransform crops the model (docs/inputs.md).
    """
    options = OrthoOptions(crs=crs, resolution_m=resolution, resampling=resampling, block=block, threads=threads)
    with stage_progress(ctx, "gcpcal ortho: blocks", as_json) as progress:
        summary = ortho_scene(scene_path, out_path, dem_path=dem_path, calibration=calibration, dem_datum=dem_datum,
                              geoid=geoid, band=band, image=image, options=options, progress=progress.count,
                              self_check=self_check)
    echo_warnings(summary)
    if as_json:
        echo_json(summary)
        return
    rows, cols = summary["shape"]
    check = summary["geometry_check_max_px"]
    click.echo(f"wrote {summary['output']}: {cols} x {rows} px at {summary['resolution_m']:g} m in {summary['crs']}, "
               f"{100 * summary['valid_fraction']:.0f} % valid, geometry check max "
               f"{check:.4f} px, {summary['seconds']:.1f} s" if check is not None else
               f"wrote {summary['output']}: {cols} x {rows} px in {summary['seconds']:.1f} s")
