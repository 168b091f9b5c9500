"""Stage action of ``gcpcal ortho``: orthoimage of a scene band as a Cloud-Optimized GeoTIFF.

:func:`ortho_scene` reads the inputs, takes the geometry from the calibrated model
(``calibration``) and the pixels from the scene's rasters, and calls
:func:`sensor_models.imaging.ortho.orthorectify_to_file`; it writes ``OUT`` and ``OUT.summary.json``
(``OUT`` with the suffix ``.summary.json``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from calibrate.actions._guard import InputSet
from calibrate.actions._io import check_output_files, open_dem, staged_files, write_summary
from calibrate.actions._status import calibration_input, open_usable_calibration, require_usable, status_fields
from calibrate.actions._provenance import geotiff_tags
from calibrate.plausibility import check_dem_heights, check_scene_raster
from calibrate.config import OrthoOptions
from sensor_models.errors import InputError
from sensor_models.readers.scene_input import missing_raster_message, open_scene

__all__ = ["ortho_scene"]


def ortho_scene(scene_path, out_path, *, dem_path, calibration=None, dem_datum=None, geoid=None, band=None,
                image=None, options: OrthoOptions = OrthoOptions(), progress=None, self_check: str = "refuse") -> dict:
    """Orthorectify one band of a scene; write the COG and its summary.

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
    band : str, optional
        Band (default: the reference band).
    image : path, optional
        Replaces the scene's raster of the band.
    options : OrthoOptions
        Output CRS, resolution, resampling and block size.
    progress : callable(done, total), optional
        Called as blocks are written.
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in the summary.

    Returns
    -------
    dict
        The summary written to ``OUT.summary.json``.
    """
    from sensor_models.imaging.ortho import orthorectify_to_file

    t0 = time.perf_counter()
    out_path = Path(out_path)
    if out_path.suffix.lower() not in (".tif", ".tiff"):
        raise InputError("the orthoimage is a GeoTIFF: give a .tif name", path=str(out_path))
    summary_path = out_path.with_suffix(".summary.json")
    inputs = InputSet([scene_path, calibration_input(calibration), image, dem_path, geoid])
    check_output_files(out_path, summary_path, inputs=inputs)  # before any work
    scene = open_scene(scene_path, image=image, band=band, self_check=self_check)  # a crop's raster crops it
    scene_warning = require_usable(scene.model, scene_path, command="ortho")
    geometry, calib_file, calib_warning = scene.model, None, None
    if calibration is not None:
        geometry, calib_file, calib_warning = open_usable_calibration(calibration, command="ortho")
        geometry = _crop_like_scene(geometry, scene)
        if tuple(geometry.image_shape) != tuple(scene.model.image_shape):
            raise InputError(f"the calibrated model describes a {geometry.image_shape[0]} x {geometry.image_shape[1]} "
                             f"px image, the scene {scene.model.image_shape[0]} x {scene.model.image_shape[1]}",
                             path=str(calib_file))
    band, image = _band_and_image(scene, geometry, band, image, scene_path)
    check_scene_raster(scene, band, image if isinstance(image, (str, Path)) else None)
    dem, dem_windows = _open_dem(dem_path, dem_datum, geoid, geometry, band)
    try:
        dem_figures = _dem_under_scene(geometry, dem, band)
        say = progress or (lambda done, total: None)
        with staged_files(out_path, summary_path, inputs=inputs) as (tif_tmp, summary_tmp):
            result = orthorectify_to_file(geometry, image, dem, tif_tmp, crs=options.crs,
                                          resolution_m=options.resolution_m, band=band,
                                          resampling=options.resampling, block=options.block, progress=say,
                                          dem_windows=dem_windows, tags=geotiff_tags(),
                                          threads=options.threads or None)
            summary = _summary(result, out_path, summary_path, scene_path, calib_file, geometry, image, dem_path,
                               status_fields(geometry, scene_warning, calib_warning,
                                             product_check=scene.product_check), dem_figures, t0)
            write_summary(summary_tmp, summary)
    finally:
        if dem_windows is not None:
            dem_windows.close()
    return summary


def _summary(result, out_path, summary_path, scene_path, calib_file, geometry, image, dem_path, status, dem_figures,
             t0) -> dict:
    """The JSON summary of ``gcpcal ortho``."""
    result["output"] = str(out_path)
    summary = {
        "command": "ortho",
        "scene": str(scene_path),
        "calibration": None if calib_file is None else str(calib_file),
        "model_kind": geometry.kind,
        "image": str(image[0]) if isinstance(image, tuple) else str(image),
        "dem": str(dem_path),
        **status,
        **dem_figures,
        **result,
        "ortho_seconds": result["seconds"],
        "seconds": round(time.perf_counter() - t0, 3),
    }
    summary["summary"] = str(summary_path)
    return summary


def _crop_like_scene(geometry, scene):
    """The calibrated full-scene model cropped as the scene's raster is (a crop with a pixel geotransform)."""
    crop = scene.crop
    shape = tuple(scene.model.image_shape)
    if crop is None or not hasattr(geometry, "cropped") or tuple(geometry.image_shape) == shape:
        return geometry
    status = getattr(geometry, "calibration", None)
    geometry = geometry.cropped(crop[0], crop[1], shape)
    geometry.calibration = status
    return geometry


def _band_and_image(scene, geometry, band, image, scene_path):
    """The band to orthorectify (default: the reference band) and its raster (default: the scene's)."""
    if band is None:
        band = geometry.reference_band
    if band is not None and band not in geometry.bands:
        named = [str(b) for b in geometry.bands if b is not None]
        raise InputError(f"unknown band {band!r}; the model has {', '.join(named) if named else 'no named band'}",
                         field="band")
    if image is None:
        rasters = scene.rasters
        key = band if band is not None else scene.model.reference_band
        if key not in rasters:
            raise InputError(missing_raster_message(scene, key), path=str(scene_path))
        image = (rasters[key]["path"], int(rasters[key].get("index", 1)))
    return band, image


def _dem_under_scene(geometry, dem, band) -> dict:
    """``dem_coverage`` and ``dem_void_fraction`` over the scene footprint; refuses a DEM away or mostly void.

    Part of an ortho outside the DEM is no-data, which the summary's valid share shows: no warning.
    """
    from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat

    kwargs = {} if band is None or getattr(geometry, "bands", None) is None else {"band": band}
    lon, lat = footprint_sample_lonlat(geometry, float(np.mean(dem.height_range_m)), **kwargs)
    figures = check_dem_footprint(dem, lon, lat)
    return {"dem_coverage": figures["dem_coverage"], "dem_void_fraction": figures["dem_void_fraction"]}


def _open_dem(dem_path, dem_datum, geoid, geometry, band):
    """``(Dem, DemWindows or None)``: tiles are read under the scene only (:func:`open_dem`); one large
    file is read by windows per output block (:func:`sensor_models.terrain.dem_windows.open_ortho_dem`)."""
    from sensor_models.maps.mosaic import raster_inputs
    from sensor_models.terrain.dem_windows import open_ortho_dem

    files = raster_inputs(dem_path, what="DEM")
    if len(files) > 1 or files[0].lower().endswith(".vrt"):
        return open_dem(dem_path, dem_datum, geoid, model=geometry, band=band), None
    dem, windows = open_ortho_dem(files[0], vertical_datum=dem_datum, geoid=geoid)
    try:
        check_dem_heights(dem, geometry, band=band)  # as open_dem does
    except BaseException:
        if windows is not None:
            windows.close()
        raise
    return dem, windows
