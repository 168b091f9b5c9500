"""``gcpcal ortho``: orthoimage of a scene band as a Cloud-Optimized GeoTIFF.

Registered on the ``gcpcal`` group by :mod:`calibrate.cli` (module attribute ``command``). This
module imports nothing from :mod:`calibrate.cli` at import time (that module imports this one
while it loads), so the DEM options are spelled out here, as in ``calibrate.cli.dem_options``.

The stage action :func:`ortho_scene` reads the inputs, takes the geometry from the calibrated
model (``--calibration``) and the pixels from the scene's rasters, and calls
:func:`sensor_models.ortho.orthorectify_to_file`; it writes ``OUT`` and ``OUT.summary.json``
(``OUT`` with the suffix ``.summary.json``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from sensor_models.errors import InputError

__all__ = ["command", "ortho_scene", "resolve_calibration"]


def resolve_calibration(path) -> Path:
    """The calibrated model file: ``path`` itself, or in a folder its ``manifest.json`` or its
    only ``*_RPC.TXT`` (the outputs of ``gcpcal calibrate``)."""
    path = Path(path)
    if path.is_dir():
        manifest = path / "manifest.json"
        if manifest.is_file():
            return manifest
        rpcs = sorted(p for p in path.iterdir() if p.name.upper().endswith("_RPC.TXT"))
        if len(rpcs) == 1:
            return rpcs[0]
        raise InputError("the calibration folder holds no manifest.json (nor a single *_RPC.TXT)", path=str(path))
    if not path.is_file():
        raise InputError("calibration not found", path=str(path))
    return path


def ortho_scene(scene_path, out_path, *, dem_path, calibration=None, dem_datum=None, geoid=None, band=None,
                image=None, crs=None, resolution_m=None, resampling="bilinear", block=1024, progress=None) -> dict:
    """``gcpcal ortho``: orthorectify one band of a scene; write the COG and its summary.

    Parameters
    ----------
    scene_path : path
        Scene manifest (its rasters give the pixels) or any model file.
    out_path : path
        The orthoimage (GeoTIFF, COG layout); ``out_path.with_suffix(".summary.json")`` beside it.
    dem_path : path
        DEM raster; ``dem_datum`` and ``geoid`` as in ``gcpcal localize``.
    calibration : path, optional
        Calibrated model (manifest, RPC file, or the folder of ``gcpcal calibrate``): the geometry.
        Default: the scene's own model.
    band, image, crs, resolution_m, resampling, block
        See :func:`sensor_models.ortho.orthorectify_to_file`; ``image`` replaces the scene's raster.

    Returns
    -------
    dict
        The summary written to ``OUT.summary.json``.
    """
    from calibrate.cli import open_dem, write_summary
    from sensor_models import open_model
    from sensor_models.ortho import orthorectify_to_file

    t0 = time.perf_counter()
    out_path = Path(out_path)
    if out_path.suffix.lower() not in (".tif", ".tiff"):
        raise InputError("the orthoimage is a GeoTIFF: give a .tif name", path=str(out_path))
    scene = open_model(scene_path)
    geometry = scene
    calib_file = None
    if calibration is not None:
        calib_file = resolve_calibration(calibration)
        geometry = open_model(calib_file)
        if tuple(geometry.image_shape) != tuple(scene.image_shape):
            raise InputError(f"the calibrated model describes a {geometry.image_shape[0]} x {geometry.image_shape[1]} "
                             f"px image, the scene {scene.image_shape[0]} x {scene.image_shape[1]}",
                             path=str(calib_file))
    if band is None:
        band = getattr(geometry, "reference_band", None)
    bands = getattr(geometry, "bands", None)
    if band is not None and bands is not None and band not in bands:
        raise InputError(f"unknown band {band!r}; the model has {', '.join(bands)}", field="band")
    if image is None:
        rasters = getattr(scene, "rasters", None) or {}
        key = band if band is not None else getattr(scene, "reference_band", None)
        if key not in rasters:
            raise InputError(f"the scene lists no raster for band {key!r}; give --image", path=str(scene_path))
        image = (rasters[key]["path"], int(rasters[key].get("index", 1)))
    dem = open_dem(dem_path, dem_datum, geoid)
    say = progress or (lambda done, total: None)
    result = orthorectify_to_file(geometry, image, dem, out_path, crs=crs, resolution_m=resolution_m, band=band,
                                  resampling=resampling, block=block, progress=say)
    summary = {
        "command": "ortho",
        "scene": str(scene_path),
        "calibration": None if calib_file is None else str(calib_file),
        "model_kind": geometry.kind,
        "image": str(image[0]) if isinstance(image, tuple) else str(image),
        "dem": str(dem_path),
        **result,
        "ortho_seconds": result["seconds"],
        "seconds": round(time.perf_counter() - t0, 3),
    }
    summary_path = out_path.with_suffix(".summary.json")
    summary["summary"] = str(summary_path)
    write_summary(summary_path, summary)
    return summary


@click.command("ortho")
@click.argument("scene_path", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("--calibration", type=click.Path(),
              help="Calibrated model (manifest.json or RPC), or the folder of 'gcpcal calibrate': the geometry. "
                   "Default: SCENE's own model.")
@click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM raster (any CRS rasterio reads).")
@click.option("--dem-datum", type=click.Choice(["ellipsoid", "egm96"]), default=None,
              help="Vertical datum of the DEM heights when the file does not declare it.")
@click.option("--geoid", type=click.Path(dir_okay=False), help="Geoid grid (e.g. egm96_15.gtx) for egm96 heights.")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Orthoimage (Cloud-Optimized GeoTIFF); OUT.summary.json goes beside it.")
@click.option("--band", help="Band (default: the reference band).")
@click.option("--crs", help="Output CRS, e.g. EPSG:32631 (default: the UTM zone of the scene centre).")
@click.option("--resolution", type=click.FloatRange(min=0.0, min_open=True),
              help="Pixel size in CRS units, m (default: the scene's ground sampling distance).")
@click.option("--resampling", type=click.Choice(["nearest", "bilinear", "cubic"]), default="bilinear", show_default=True,
              help="Interpolation of the scene pixels.")
@click.option("--image", type=click.Path(dir_okay=False), help="Scene raster (default: the manifest's raster of the band).")
@click.option("--block", type=click.IntRange(min=64), default=1024, show_default=True,
              help="Output pixels per block side (memory grows with its square, not with the output).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.pass_context
def command(ctx, scene_path, calibration, dem_path, dem_datum, geoid, out_path, band, crs, resolution, resampling,
            image, block, as_json):
    """Orthorectify a band of SCENE on the DEM into a Cloud-Optimized GeoTIFF.

    The geometry comes from --calibration (the calibrated model) when given, the pixels from
    SCENE's rasters (or --image). The output grid is the scene footprint's bounding box in the
    CRS at the resolution; pixels off the image or the DEM are no-data (0).
    """
    from calibrate.cli import _json_default

    if dem_path is None:
        raise InputError("--dem is required: orthorectification needs terrain heights")
    quiet = bool((ctx.obj or {}).get("quiet", False)) or as_json

    def progress(done, total):
        if not quiet and (done == total or done % max(1, total // 10) == 0):
            click.echo(f"ortho: {done}/{total} blocks", err=True)

    summary = ortho_scene(scene_path, out_path, dem_path=dem_path, calibration=calibration, dem_datum=dem_datum,
                          geoid=geoid, band=band, image=image, crs=crs, resolution_m=resolution,
                          resampling=resampling, block=block, progress=progress)
    if as_json:
        click.echo(json.dumps(summary, default=_json_default))
        return
    rows, cols = summary["shape"]
    check = summary["geometry_check_max_px"]
    click.echo(f"wrote {summary['output']}: {cols} x {rows} px at {summary['resolution_m']:g} m in {summary['crs']}, "
               f"{100 * summary['valid_fraction']:.0f} % valid, geometry check max "
               f"{check:.4f} px, {summary['seconds']:.1f} s" if check is not None else
               f"wrote {summary['output']}: {cols} x {rows} px in {summary['seconds']:.1f} s")
