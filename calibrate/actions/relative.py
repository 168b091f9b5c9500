"""Stage action of ``gcpcal relative``: band-to-band relative calibration (seed 003 section 2.2.2).

Tie points between the reference band and each other band become control points through the
calibrated reference band and the DEM; each band's interior is then solved with the exterior
held. The reading, solving and staged writing (``manifest.json``, ``relative.json``,
``relative.summary.json``) are done by :func:`calibrate.relative.relative_scene`.
"""

from __future__ import annotations

from calibrate.actions._io import final_paths, staged_folder
from calibrate.config import CalibrationOptions

__all__ = ["relative_calibration_stage"]


def relative_calibration_stage(scene_path, calibration, dem_path, out_dir, *, reference_band=None, dem_datum=None,
                               geoid=None, window_px=64, spacing_px: int = 24, rows=None,
                               options: CalibrationOptions = CalibrationOptions(), progress=None) -> dict:
    """Calibrate every band of a scene against its calibrated reference band.

    Parameters
    ----------
    scene_path : str or Path
        The LAB scene manifest (its rasters give the pixels).
    calibration : str or Path
        Calibrated ``manifest.json`` of the reference band, or its folder.
    dem_path : str or Path
        DEM raster.
    out_dir : str or Path
        Output folder.
    reference_band : str, optional
        Default: the calibrated model's reference band.
    dem_datum : {"ellipsoid", "egm96"}, optional
        Vertical datum of the DEM when the file does not declare it.
    geoid : str or Path, optional
        Geoid grid for an EGM96 DEM.
    window_px : int or (int, int)
        Phase-correlation window, pixels (square, or rows x columns).
    spacing_px : int
        Window grid spacing, pixels.
    rows : (int, int), optional
        Reference-band lines holding the tie points; default: all.
    options : CalibrationOptions
        Only ``robust`` (the robust loss of the interior solve) is used.
    progress : callable(str), optional
        Receives progress messages.

    Returns
    -------
    dict
        The summary written to ``relative.summary.json`` (``success``, ``bands``, ``seconds``).
    """
    from calibrate.relative import relative_scene

    with staged_folder(out_dir, ".relative-", inputs=[scene_path, calibration, dem_path, geoid]) as stage:
        summary = relative_scene(scene_path, calibration, dem_path, stage, reference_band=reference_band,
                                 dem_datum=dem_datum, geoid=geoid, window_px=window_px, spacing_px=spacing_px,
                                 rows=rows, robust=options.robust, progress=progress)
    return final_paths(summary, stage, out_dir)
