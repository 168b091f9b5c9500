"""Stage action of ``gcpcal rpc``: RPCs fitted to a model over its image and height range.

What ``--out PATH`` gets (docs/calibration_outputs.md, "RPC output"):

* a FILE when one RPC is asked for (an RPC or staring-camera model, a push-broom band with one
  CCD, or ``--ccd``): ``*_RPC.TXT`` or ``*.RPB`` (text), or ``*.tif``: a georeferenced level-1A,
  a copy of the scene raster's band (the CCD's columns for ``--ccd``) with the RPC as GeoTIFF
  RPC tags and its fit errors in the metadata (:mod:`calibrate.actions._l1a`). PATH is written
  exactly; its summary is ``PATH.summary.json``. One RPC is written even when it misses
  ``max_error_px`` (the summary's ``warnings`` say so).
* a FOLDER otherwise (a push-broom band with several CCDs), and whenever PATH is an existing
  folder or a name without a suffix (any other suffix is a usage error). An RPC describes one
  smooth image: the stitched raster jumps where CCDs meet, so each CCD gets its own RPCs; and
  where one RPC cannot follow the model within ``max_error_px`` on its check grid (attitude or
  orbit varying faster than a cubic over the scene, look directions beyond a cubic), the CCD's
  image is split into tiles, each with its own RPC (:func:`sensor_models.models.rpc_fit.fit_rpc_tiles`).
  Per RPC: ``<ccd>_RPC.TXT`` (one tile) or ``<ccd>_r<row>_c<col>_RPC.TXT`` (tiles; row and
  column of the tile's first pixel in the CCD's image) and, when the scene's raster is known
  (manifest ``rasters`` or ``--image``), the same name with ``.tif`` (those pixels with that
  RPC); plus ``rpc.summary.json``.

A file PATH for a band with several CCDs is a usage error (:class:`RpcOutputUsageError`, exit 2).
"""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyproj

from calibrate.actions._guard import InputSet
from calibrate.actions._io import (check_output_files, check_output_folder, open_dem, staged_files, staged_folder,
                                   write_summary)
from calibrate.actions._l1a import scene_raster, write_l1a_with_rpc
from calibrate.actions._status import require_usable, status_fields
from calibrate.actions._provenance import geotiff_tags
from calibrate.actions.calibrate import rpc_error_estimates
from sensor_models.errors import InputError
from sensor_models.files.documents import load_json
from sensor_models.models.rpc import RpcModel
from sensor_models.terrain.footprint import check_dem_footprint, footprint_sample_lonlat
from sensor_models.readers.rpc_files import write_rpc

__all__ = ["DEFAULT_HEIGHT_RANGE_M", "DEFAULT_MAX_ERROR_PX", "RpcOutputUsageError", "calibration_errors", "fit_rpcs",
           "height_hint_tags", "out_is_folder"]

GEOD = pyproj.Geod(ellps="WGS84")

#: Ellipsoidal heights (m) spanned by the fit when neither a DEM nor a range is given.
DEFAULT_HEIGHT_RANGE_M = (-100.0, 3000.0)
#: Check-grid maximum error an RPC must reach before a folder output splits the image into
#: tiles (pixels): the accuracy at which an RPC stands in for a rigorous model (Tao & Hu 2001).
DEFAULT_MAX_ERROR_PX = 0.01
#: Smallest tile side (pixels) a split may produce.
MIN_TILE_PX = 32

_FILE_SUFFIXES = ("_rpc.txt", ".rpb", ".tif", ".tiff")


class RpcOutputUsageError(InputError):
    """``--out`` names one file but the band has several CCDs (the CLI maps it to exit 2)."""


def out_is_folder(out_path) -> bool:
    """Whether ``--out`` names a folder: an existing folder, or a name without a suffix.

    Parameters
    ----------
    out_path : str or Path

    Returns
    -------
    bool
        True for a folder, False for an RPC file (``*_RPC.TXT``, ``*.RPB``, ``*.tif``, ``*.tiff``).

    Raises
    ------
    RpcOutputUsageError
        A file name with another suffix.
    """
    out = Path(out_path)
    if out.is_dir() or not out.suffix:
        return True
    if not out.name.lower().endswith(_FILE_SUFFIXES):
        raise RpcOutputUsageError("--out must be *_RPC.TXT, *.RPB, *.tif or a folder", path=str(out))
    return False


def _height_range(model, dem_path, dem_datum, geoid, height_range):
    """``(height range, DEM footprint figures)``; the DEM must cover the model's footprint."""
    if dem_path is not None:
        dem = open_dem(dem_path, dem_datum, geoid, model=model)  # tiles: only under the scene
        h_lo, h_hi = dem.height_range_m
        lon, lat = footprint_sample_lonlat(model, 0.5 * (h_lo + h_hi))
        coverage = check_dem_footprint(dem, lon, lat)
        # the heights under the scene, not the whole file's: the footprint at the file's extremes
        ends = [footprint_sample_lonlat(model, h) for h in (h_lo, h_hi)]
        under = dem.height_range_over_m(np.concatenate([e[0] for e in ends]), np.concatenate([e[1] for e in ends]))
        if under is not None:
            h_lo, h_hi = under
        pad = max(50.0, 0.05 * (h_hi - h_lo))
        return (h_lo - pad, h_hi + pad), coverage
    return (DEFAULT_HEIGHT_RANGE_M if height_range is None else height_range), {"warnings": []}


def _targets(model, band, ccd):
    """``(model to fit, CCD name or None, first scene column)`` of each RPC to fit."""
    arrays = model.detector_arrays(band)
    if model.detector_view(band, 0) is model:  # one smooth image (area array, RPC): one RPC
        if ccd is not None:
            raise InputError(f"--ccd applies to push-broom models, not to a {model.kind} model")
        return [(model, None, 0)]
    if ccd is not None:
        i = int(model.detector_index([0.0], band=band, array=ccd)[0])
        return [(model.detector_view(band, i), arrays[i].name, arrays[i].first_col)]
    return [(model.detector_view(band, i), a.name, a.first_col) for i, a in enumerate(arrays)]


def _open_inputs(model_path, band, image, self_check):
    """The scene (its model cropped to its raster when that is a crop of the scene), its band and raster."""
    from sensor_models.readers import open_scene

    scene = open_scene(model_path, image=image, band=band, self_check=self_check)  # a raster with its RPC, too
    band = band or scene.model.reference_band
    try:
        raster = scene_raster(scene, band)
    except InputError:
        raster = None
    return scene, band, raster


def fit_rpcs(model_path, out_path, *, dem_path=None, dem_datum=None, geoid=None, height_range=None, band=None,
             ccd=None, image=None, self_check: str = "refuse", form="rational",
             max_error_px=DEFAULT_MAX_ERROR_PX) -> dict:
    """Fit and write the RPC(s) of a model (see the module docstring for what ``out_path`` gets).

    Parameters
    ----------
    model_path : str or Path
        Anything :func:`sensor_models.readers.open_scene` reads.
    out_path : str or Path
        A file (``*_RPC.TXT``, ``*.RPB``, ``*.tif``) for one RPC, else a folder.
    dem_path, dem_datum, geoid : optional
        DEM whose height range (with a margin) the fit spans, its vertical datum and geoid grid.
    height_range : (float, float), optional
        Min and max ellipsoidal heights, m, when no DEM is given; default
        :data:`DEFAULT_HEIGHT_RANGE_M`.
    band : str, optional
        Band of a multi-band model; default: the reference band.
    ccd : str, optional
        One CCD only; default: one RPC per CCD (then ``out_path`` must be a folder).
    image : str or Path, optional
        The scene raster (default: the manifest's raster of the band); a crop with a pixel
        geotransform crops the model, as ``gcpcal match --image`` does.
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in the summary.
    form : {"rational", "polynomial"}
        RPC00B with free denominators (default), or cubic polynomials (denominators 1).
    max_error_px : float
        Check-grid maximum error each RPC must reach (pixels); a folder output splits an image
        into tiles until it does, a file output warns when it does not.

    Returns
    -------
    dict
        The summary (``rpcs``: per RPC its ``ccd``, ``first_row``, ``first_col`` (scene pixel
        of its first pixel), ``shape``, ``output``, ``raster`` (the level-1A GeoTIFF or None)
        and ``fit`` report; ``check_max_px`` (the largest); ``max_error_px``; ``warnings``).

    Raises
    ------
    RpcOutputUsageError
        ``out_path`` names a file and several RPCs are to be written.
    InputError
        Unreadable model, DEM or raster, or a ``*.tif`` output without a known scene raster.
    """
    t0 = time.perf_counter()
    out = Path(out_path)
    folder = out_is_folder(out)
    summary_path = out / "rpc.summary.json" if folder else out.with_name(out.name + ".summary.json")
    inputs = InputSet([model_path, image, dem_path, geoid])
    if folder:  # before any work
        check_output_folder(out, inputs=inputs)
    else:
        check_output_files(out, summary_path, inputs=inputs)
    scene, band, raster = _open_inputs(model_path, band, image, self_check)
    model = scene.model
    warning = require_usable(model, model_path, command="rpc")
    height_range, coverage = _height_range(model, dem_path, dem_datum, geoid, height_range)
    targets = _targets(model, band, ccd)
    if not folder and len(targets) > 1:
        names = ", ".join(name for _, name, _ in targets)
        raise RpcOutputUsageError(f"band {band} has {len(targets)} CCDs ({names}): give --out a folder (one RPC "
                                  f"and raster per CCD) or choose one with --ccd", path=str(out))
    if not folder and out.suffix.lower() in (".tif", ".tiff") and raster is None:
        raise InputError(f"a *.tif output is a copy of the scene raster, and the scene lists no raster for band "
                         f"{band!r}: give --image, or write *_RPC.TXT / *.RPB", path=str(out))
    errors = calibration_errors(model_path)
    context = dict(band=band, raster=raster, height_range=height_range, model_path=model_path,
                   n_rows_cols=tuple(model.image_shape), form=form, max_error_px=float(max_error_px),
                   errors=errors)
    if folder:
        with staged_folder(out, ".rpc-", inputs=inputs) as tmp:
            fits = [entry for t in targets for entry in _fit_tiles(t, tmp, out, model, context)]
            summary = _summary(scene, model_path, height_range, warning, coverage, fits, t0, max_error_px, errors)
            if raster is None:
                summary["warnings"].append(f"the scene lists no raster for band {band!r}: wrote the RPCs only "
                                           "(give --image for georeferenced level-1A copies)")
            write_summary(tmp / summary_path.name, summary)
        return summary
    with staged_files(out, summary_path, inputs=inputs) as (staged, staged_summary):
        fits = [_fit_one(targets[0], [(staged, out)], context)]
        summary = _summary(scene, model_path, height_range, warning, coverage, fits, t0, max_error_px, errors)
        write_summary(staged_summary, summary)
    return summary


def _fit_kwargs(ccd_name, context) -> dict:
    band = context["band"]
    kwargs = {"band": band} if (ccd_name is None and band is not None) else {}
    return dict(kwargs, height_range_m=tuple(context["height_range"]), form=context["form"])


def _fit_tiles(target, tmp: Path, out: Path, model, context) -> list[dict]:
    """Fit the RPC tiles of one CCD (or image) and write them into the staged folder."""
    from sensor_models.models.rpc_fit import fit_rpc_tiles

    view, ccd_name, first_col = target
    tiles = fit_rpc_tiles(view, max_error_px=context["max_error_px"], min_tile_px=MIN_TILE_PX,
                          **_fit_kwargs(ccd_name, context))
    stem = ccd_name or Path(str(getattr(model, "source", "") or "scene")).stem or "scene"
    entries = []
    for tile in tiles:
        name = stem if len(tiles) == 1 else f"{stem}_r{tile.first_row}_c{tile.first_col}"
        pairs = [(tmp / f"{name}_RPC.TXT", out / f"{name}_RPC.TXT")]
        if context["raster"] is not None:
            pairs.append((tmp / f"{name}.tif", out / f"{name}.tif"))
        entries.append(_write(tile.rpc, tile.report, ccd_name, tile.first_row, first_col + tile.first_col, pairs,
                              context))
    return entries


def _fit_one(target, outputs, context) -> dict:
    """Fit one RPC and write it to each ``(staged, final)`` path; its summary entry."""
    from sensor_models.models.rpc_fit import fit_rpc

    view, ccd_name, first_col = target
    fitted, report = fit_rpc(view, **_fit_kwargs(ccd_name, context))
    return _write(fitted, report, ccd_name, 0, first_col, outputs, context)


def height_hint_tags(rpc) -> dict[str, str]:
    """Metadata items that tell a GIS the height to warp a level-1A at, and what height 0 costs.

    GDAL's RPC transformer (and so QGIS dropping the file on a map) warps at height 0 unless it
    is given ``RPC_HEIGHT`` or ``RPC_DEM``; there is no standard tag for a default height. The
    file says it: ``GCPCAL_RPC_HEIGHT_HINT_M`` is the RPC's ``HEIGHT_OFF`` (the middle of the
    terrain heights the fit spans), and ``GCPCAL_WARNING`` how far the image centre moves between
    that height and 0, with the options that avoid it.

    Parameters
    ----------
    rpc : RpcModel
        The fitted RPC.

    Returns
    -------
    dict of str to str
    """
    hint = float(rpc.height_off)
    rows, cols = rpc.image_shape
    lon, lat, _ = rpc.image_to_ground(np.array([0.5 * rows, 0.5 * rows]), np.array([0.5 * cols, 0.5 * cols]),
                                       height=np.array([hint, 0.0]))
    moved_m = float(GEOD.inv(lon[0], lat[0], lon[1], lat[1])[2])
    return {"GCPCAL_RPC_HEIGHT_HINT_M": f"{hint:.1f}",
            "GCPCAL_WARNING": (f"warped without terrain (GDAL, QGIS: height 0) this image lands {moved_m:.0f} m from "
                               f"where it lies at its terrain height {hint:.0f} m: warp with -to RPC_DEM=<DEM> or "
                               f"-to RPC_HEIGHT={hint:.0f}")}


def _write(fitted, report, ccd_name, first_row, first_col, outputs, context) -> dict:
    """Write one RPC (text or level-1A GeoTIFF) to each ``(staged, final)`` path; its summary entry."""
    band = context["band"]
    fitted = _with_errors(fitted, report, context["errors"])
    entry = {"ccd": ccd_name, "first_row": int(first_row), "first_col": int(first_col),
             "shape": list(fitted.image_shape), "output": None, "raster": None, "fit": report,
             "err_bias_m": fitted.err_bias, "err_rand_m": fitted.err_rand}
    for staged, final in outputs:
        if final.suffix.lower() in (".tif", ".tiff"):
            path, index = context["raster"]
            extra = {"GCPCAL_RPC_HEIGHT_RANGE_M": " ".join(repr(float(h)) for h in context["height_range"]),
                     "GCPCAL_MODEL": str(context["model_path"]), "GCPCAL_BAND": str(band or ""),
                     "GCPCAL_CCD": ccd_name or "", "GCPCAL_FIRST_ROW": str(int(first_row)),
                     "GCPCAL_FIRST_COL": str(int(first_col)), **height_hint_tags(fitted), **geotiff_tags()}
            write_l1a_with_rpc(path, index, staged, fitted, image_shape=context["n_rows_cols"], first_col=first_col,
                               first_row=first_row, fit_report=report, extra_tags=extra)
            entry["raster"] = str(final)
            entry["source_raster"] = path
        else:
            write_rpc(fitted, staged)
        entry["output"] = entry["output"] or str(final)
    return entry


def _summary(scene, model_path, height_range, warning, coverage, fits, t0, max_error_px, errors) -> dict:
    misses = [f for f in fits if f["fit"]["check_max_px"] > max_error_px]
    extra = []
    if misses:
        worst = max(f["fit"]["check_max_px"] for f in misses)
        extra.append(f"{len(misses)} of {len(fits)} RPC(s) miss {max_error_px:g} px on their check grid (worst "
                     f"{worst:.3g} px): the model varies faster than one RPC can follow; a folder --out splits the "
                     f"image into tiles (down to {MIN_TILE_PX} px) until each RPC is within it")
    return {
        "command": "rpc",
        "model": str(model_path),
        "height_range_m": list(height_range),
        **status_fields(scene.model, warning, *coverage.pop("warnings"), *extra, product_check=scene.product_check),
        **coverage,
        "max_error_px": float(max_error_px),
        "rpcs": fits,
        "check_max_px": max(f["fit"]["check_max_px"] for f in fits),
        "rpc_errors": errors,
        "seconds": round(time.perf_counter() - t0, 3),
    }


def _calibration_doc(model_path):
    """``(calibration.json path, how it was found)`` of a calibrated manifest, or ``(None, why not)``.

    Beside the manifest for ``gcpcal calibrate``'s folder; for ``gcpcal relative``'s, beside the
    calibrated manifest its ``relative.json`` names (the reference band's absolute calibration).
    """
    given = Path(model_path)
    folder = given if given.is_dir() else given.parent
    if (folder / "calibration.json").is_file():
        return folder / "calibration.json", "gcpcal calibrate"
    if (folder / "relative.json").is_file():
        try:
            named = load_json(folder / "relative.json").get("calibration")
        except (InputError, AttributeError):
            named = None
        if named:
            cal = Path(named) if Path(named).is_absolute() else folder / named
            doc = (cal if cal.is_dir() else cal.parent) / "calibration.json"
            if doc.is_file():
                return doc, f"gcpcal relative (its calibration {cal})"
    return None, f"no calibration.json beside {given} (nor named by a relative.json there)"


def calibration_errors(model_path) -> dict:
    """The check-point accuracy after calibration of a calibrated manifest, as RPC error figures.

    Read from the ``calibration.json`` written by ``gcpcal calibrate`` beside ``model_path`` (or,
    for ``gcpcal relative``'s folder, beside the calibration its ``relative.json`` names): with its
    ``residuals.gpkg``, the check points' along- and across-track metres after calibration, else
    their mean and RMS per axis (:func:`_check_figures`); combined by :func:`calibrate.actions.calibrate.rpc_error_estimates` with the reference's
    stated accuracy (``reference_accuracy``), as ``gcpcal calibrate`` does for an RPC product.

    Parameters
    ----------
    model_path : str or Path
        The model given to ``gcpcal rpc``.

    Returns
    -------
    dict
        ``err_bias_m``, ``err_rand_m`` (None: unknown, the RPCs get -1), ``check_points``,
        ``reference_sigma_m`` and ``source`` (what the figures came from, or why there are none).
    """
    doc_path, how = _calibration_doc(model_path)
    unknown = {"err_bias_m": None, "err_rand_m": None, "check_points": 0, "reference_sigma_m": None}
    if doc_path is None:
        return {**unknown, "source": f"{how}: ERR_BIAS and ERR_RAND are -1 (unknown)"}
    try:
        doc = load_json(doc_path)
        ref = doc.get("reference_accuracy") or {}
        sigma = None if ref.get("east_m") is None else (float(ref["east_m"]), float(ref.get("north_m") or 0.0))
        figures = _check_figures(doc_path, doc, sigma)
    except (InputError, AttributeError, TypeError, ValueError) as exc:
        return {**unknown, "source": f"{doc_path} unreadable ({exc}): ERR_BIAS and ERR_RAND are -1 (unknown)"}
    if figures is None:
        return {**unknown, "source": f"{doc_path} holds fewer than 2 check points after calibration: "
                                     "ERR_BIAS and ERR_RAND are -1 (unknown)"}
    bias, rand, n, what = figures
    return {"err_bias_m": bias, "err_rand_m": rand, "check_points": n, "reference_sigma_m": sigma,
            "source": f"{how}: {what}, with the reference accuracy of {doc_path.name}, each RPC's check-grid "
                      "RMS (px x its GSD) added to ERR_RAND in quadrature"}


def _check_figures(doc_path: Path, doc: dict, sigma):
    """``(ERR_BIAS, ERR_RAND, check points, what they came from)`` of a calibration, or None.

    With the calibration's ``residuals.gpkg``: :func:`rpc_error_estimates` of its check points'
    along- and across-track metres, exactly what ``gcpcal calibrate`` writes for an RPC product.
    Else the same formula on ``check_accuracy.after.absolute`` of ``calibration.json``: the mean
    per axis (px, at the metres per pixel of that axis's RMS) and the variance ``RMS^2 - mean^2``
    (sample-corrected).
    """
    layer = doc_path.parent / "residuals.gpkg"
    if layer.is_file():
        from calibrate.residual_layer import read_residual_layer

        pts = read_residual_layer(layer)
        check = np.asarray(pts["kind"]).astype(str) == "check"
        res = np.stack([np.asarray(pts[k], dtype=np.float64)[check]
                        for k in ("resid_along_m", "resid_across_m", "resid_planar_m")], axis=1)
        est = rpc_error_estimates(SimpleNamespace(residuals_m=res), sigma)
        if est is not None:
            return est[0], est[1], int(check.sum()), f"the check points' metres of {layer.name}"
    a = ((doc.get("check_accuracy") or {}).get("after") or {}).get("absolute") or {}
    n = int(a.get("n") or 0)
    values = [a.get(k) for k in ("mean_row_px", "mean_col_px", "rmse_row_px", "rmse_col_px", "rmse_row_m", "rmse_col_m")]
    if n < 2 or any(v is None or not np.isfinite(v) for v in values) or not (values[2] > 0 and values[3] > 0):
        return None
    mean_px, rms_px, rms_m = np.array(values[:2]), np.array(values[2:4]), np.array(values[4:])
    mean_m = mean_px * rms_m / rms_px
    var = np.maximum(rms_m**2 - mean_m**2, 0.0) * n / (n - 1)
    ref = 0.0 if sigma is None else float(np.mean(np.square(sigma)))
    return (float(np.sqrt(ref + 0.5 * np.sum(mean_m**2))), float(np.sqrt(0.5 * np.sum(var))), n,
            f"the check points' mean and RMS per axis of {doc_path.name} (check_accuracy.after)")


def _gsd_m(rpc) -> float:
    """Mean ground distance (m) of a one-pixel step along rows and columns at the RPC's centre and HEIGHT_OFF."""
    rows, cols = rpc.image_shape
    r, c = 0.5 * rows, 0.5 * cols
    lon, lat, _ = rpc.image_to_ground(np.array([r, r + 1.0, r]), np.array([c, c, c + 1.0]),
                                      height=np.full(3, float(rpc.height_off)))
    steps = [GEOD.inv(lon[0], lat[0], lon[k], lat[k])[2] for k in (1, 2)]
    return float(np.mean(steps))


def _with_errors(fitted, report, errors):
    """The RPC with ``ERR_BIAS``/``ERR_RAND`` from the calibration's accuracy and its own fit (unknown: as fitted)."""
    if errors is None or errors.get("err_bias_m") is None:
        return fitted
    fit_m = float(report["check_rms_px"]) * _gsd_m(fitted) / np.sqrt(2.0)  # per horizontal axis
    rand = float(np.hypot(errors["err_rand_m"], fit_m))
    return RpcModel(**{**fitted.init_kwargs(), "err_bias": float(errors["err_bias_m"]), "err_rand": rand})
