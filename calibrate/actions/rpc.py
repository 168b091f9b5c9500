"""Stage action of ``gcpcal rpc``: an RPC fitted to a model over its image and height range.

A push-broom band with several CCDs gets one RPC per CCD image (columns counted from the CCD's
first detector), since the stitched raster is discontinuous where CCDs overlap. The fit's errors
on an independent check grid go to ``OUT.summary.json``.
"""

from __future__ import annotations

import time
from pathlib import Path

from calibrate.actions._io import check_output_files, open_dem, staged_files, write_summary
from calibrate.actions._status import require_usable, status_fields
from sensor_models.errors import InputError
from sensor_models.terrain import check_dem_footprint, footprint_sample_lonlat

__all__ = ["DEFAULT_HEIGHT_RANGE_M", "fit_rpcs"]

#: Ellipsoidal heights (m) spanned by the fit when neither a DEM nor a range is given.
DEFAULT_HEIGHT_RANGE_M = (-100.0, 3000.0)


def _with_ccd_suffix(path: Path, ccd: str) -> Path:
    """``scene_RPC.TXT`` -> ``scene_ccd1_RPC.TXT``; ``scene.RPB`` -> ``scene_ccd1.RPB``."""
    name = path.name
    if name.upper().endswith("_RPC.TXT"):
        return path.with_name(f"{name[:-8]}_{ccd}{name[-8:]}")
    return path.with_name(f"{path.stem}_{ccd}{path.suffix}")


def _height_range(model, dem_path, dem_datum, geoid, height_range):
    """``(height range, DEM footprint figures)``; the DEM must cover the model's footprint."""
    if dem_path is not None:
        dem = open_dem(dem_path, dem_datum, geoid)
        h_lo, h_hi = dem.height_range_m
        lon, lat = footprint_sample_lonlat(model, 0.5 * (h_lo + h_hi))
        coverage = check_dem_footprint(dem, lon, lat)
        pad = max(50.0, 0.05 * (h_hi - h_lo))
        return (h_lo - pad, h_hi + pad), coverage
    return (DEFAULT_HEIGHT_RANGE_M if height_range is None else height_range), {"warnings": []}


def _targets(model, out: Path, band, ccd):
    """``(model to fit, output path, CCD name)`` for each RPC to write."""
    arrays = model.detector_arrays(band)
    if model.detector_view(band, 0) is model:  # one smooth image (area array, RPC): one RPC
        if ccd is not None:
            raise InputError(f"--ccd applies to push-broom models, not to a {model.kind} model")
        return [(model, out, None)]
    # an RPC describes one smooth image: one per CCD (the stitched raster jumps at overlaps)
    if ccd is not None:
        return [(model.detector_view(band, ccd), out, ccd)]
    if len(arrays) == 1:
        return [(model.detector_view(band, 0), out, arrays[0].name)]
    return [(model.detector_view(band, i), _with_ccd_suffix(out, a.name), a.name) for i, a in enumerate(arrays)]


def fit_rpcs(model_path, out_path, *, dem_path=None, dem_datum=None, geoid=None, height_range=None, band=None,
             ccd=None) -> dict:
    """Fit and write the RPC(s) of a model, and ``OUT.summary.json``.

    Parameters
    ----------
    model_path : str or Path
        Anything :func:`sensor_models.open_model` reads.
    out_path : str or Path
        ``*_RPC.TXT``, ``*.RPB`` or ``*.tif`` (RPC tags); one file per CCD gets a ``_<ccd>`` suffix.
    dem_path, dem_datum, geoid : optional
        DEM whose height range (with a margin) the fit spans, its vertical datum and geoid grid.
    height_range : (float, float), optional
        Min and max ellipsoidal heights, m, when no DEM is given; default
        :data:`DEFAULT_HEIGHT_RANGE_M`.
    band : str, optional
        Band of a multi-band model; default: the reference band.
    ccd : str, optional
        One CCD only; default: one RPC per CCD.

    Returns
    -------
    dict
        The summary (``rpcs``: output, CCD and fit report of each RPC; ``check_max_px``).
    """
    from sensor_models.readers import open_scene
    from sensor_models.rpc import fit_rpc

    t0 = time.perf_counter()
    out = Path(out_path)
    summary_path = out.with_name(out.name + ".summary.json")
    check_output_files(out, summary_path)  # before any work
    model = open_scene(model_path)  # a raster with its RPC, or a crop, as well as a model file
    warning = require_usable(model, model_path, command="rpc")
    height_range, coverage = _height_range(model, dem_path, dem_datum, geoid, height_range)
    targets = _targets(model, out, band, ccd)
    fits = []
    with staged_files(*[path for _, path, _ in targets], summary_path) as staged:
        for (target, path, ccd_name), staged_path in zip(targets, staged):
            kwargs = {} if (band is None or ccd_name is not None) else {"band": band}
            fitted, report = fit_rpc(target, height_range_m=tuple(height_range), **kwargs)
            fitted.write(staged_path)
            fits.append({"ccd": ccd_name, "output": str(path), "fit": report})
        summary = {
            "command": "rpc",
            "model": str(model_path),
            "height_range_m": list(height_range),
            **status_fields(model, warning, *coverage.pop("warnings")),
            **coverage,
            "rpcs": fits,
            "check_max_px": max(f["fit"]["check_max_px"] for f in fits),
            "seconds": round(time.perf_counter() - t0, 3),
        }
        write_summary(staged[-1], summary)
    return summary
