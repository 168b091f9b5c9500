"""Stage action of ``gcpcal match``: scene, DOM and DEM in; GCP table and its summary out."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calibrate.actions._guard import InputSet
from calibrate.actions._io import check_output_files, open_dem, staged_files
from calibrate.actions._l1a import scene_raster
from calibrate.actions._status import record_product_check
from calibrate.actions._provenance import note, with_provenance
from calibrate.plausibility import check_dom_resolution, check_scene_raster
from gcpmatch.extract import extract_gcps, read_band, window_count
from gcpmatch.options import MatchOptions
from sensor_models.maps.dom_inputs import dom_description, masked_fraction, open_dom, reference_accuracy
from sensor_models.errors import InputError

__all__ = ["GCP_TABLE_SUFFIXES", "gcp_table_format", "match_scene", "residual_layer_path"]

#: What ``match --out`` writes, by the name's suffix: the format the name promises.
GCP_TABLE_SUFFIXES = {".csv": "csv", ".txt": "csv", ".gpkg": "gpkg"}


def gcp_table_format(out_path) -> str:
    """The format of the GCP table ``out_path`` names: ``"csv"`` (``.csv``, ``.txt``) or ``"gpkg"`` (``.gpkg``).

    Parameters
    ----------
    out_path : str or Path

    Returns
    -------
    str

    Raises
    ------
    InputError
        Any other suffix (a name must not promise a format the file does not have).
    """
    suffix = Path(str(out_path)).suffix.lower()
    if suffix not in GCP_TABLE_SUFFIXES:
        raise InputError("the GCP table is written as CSV (.csv, .txt) or as a GeoPackage (.gpkg), chosen by the "
                         "name's suffix; for GDAL GCPs in a GeoTIFF give --geotiff", path=str(out_path))
    return GCP_TABLE_SUFFIXES[suffix]


def match_side_paths(gcps_path, out_format: str) -> dict[str, Path | None]:
    """The files ``match`` writes beside its GCP table: the QC figure, and for a CSV table the
    ``.csvt`` and ``.prj`` that make GDAL and QGIS read it typed and as WGS84 points.

    Parameters
    ----------
    gcps_path : str or Path
        The GCP table (``--out``).
    out_format : {"csv", "gpkg"}

    Returns
    -------
    dict
        ``qc`` (``<stem>_qc.png``), ``.csvt`` and ``.prj`` (None for a GeoPackage table).
    """
    gcps_path = Path(gcps_path)
    csv = out_format == "csv"
    return {"qc": gcps_path.with_name(f"{gcps_path.stem}_qc.png"),
            ".csvt": gcps_path.with_suffix(".csvt") if csv else None,
            ".prj": gcps_path.with_suffix(".prj") if csv else None}


def residual_layer_path(gcps_path) -> Path:
    """The residual layer ``match`` writes beside its GCP table: ``<stem>_residuals.gpkg``.

    Parameters
    ----------
    gcps_path : str or Path
        The GCP table (``--out``).

    Returns
    -------
    Path
    """
    gcps_path = Path(gcps_path)
    return gcps_path.with_name(f"{gcps_path.stem}_residuals.gpkg")


def match_scene(scene_path, *, dom_path, dem_path, out_path, geoid=None, dem_datum=None, band=None, image=None,
                mask_path=None, gpkg_path=None, geotiff_path=None, options: MatchOptions = MatchOptions(),
                progress=None, self_check: str = "refuse", progress_count=None) -> dict:
    """Read the inputs, extract GCPs, write the CSV (+ GeoPackage/GeoTIFF) and the summary.

    Parameters
    ----------
    scene_path : str or Path
        SCENE in any form :func:`sensor_models.readers.open_scene` reads (manifest, model file
        with its raster, raster with an RPC).
    dom_path : str, Path, sequence of them or sensor_models.maps.dom_inputs.DomSource
        Reference orthoimage (any CRS): a raster, tiles, a Landsat or Sentinel-2 band or product
        folder with its band, QA and radiometry (:func:`sensor_models.maps.dom_inputs.open_dom`).
    dem_path : str, Path or sequence of them
        DEM (any CRS), or tiles (:func:`calibrate.actions._io.open_dem`).
    out_path : str or Path
        GCP table: CSV (``.csv``, ``.txt``) or a GeoPackage (``.gpkg``), by its suffix
        (:func:`gcp_table_format`); ``out_path.with_suffix(".summary.json")`` goes beside it.
    geoid : str or Path, optional
        Geoid grid for an EGM96 DEM.
    dem_datum : {"ellipsoid", "egm96"}, optional
        Vertical datum of the DEM when the file does not declare it.
    band : str, optional
        Band to match; default: the model's reference band.
    image : str or Path, optional
        Scene raster (default: the manifest's raster of the band); a crop with a pixel
        geotransform crops the model.
    mask_path : str or Path, optional
        Invalid-pixel raster in scene geometry (nonzero = invalid).
    gpkg_path, geotiff_path : str or Path, optional
        Also write the GCPs as a GeoPackage layer / as GDAL GCPs in a GeoTIFF that holds a copy
        of the matched band's pixels. The residual layer of the GCPs against the (uncalibrated)
        input model always goes to :func:`residual_layer_path` beside ``out_path``.
    options : MatchOptions
        Matching settings.
    progress : callable(str), optional
        Receives progress messages.
    progress_count : callable(int, int), optional
        Receives ``(windows done, windows in all)`` as the windows are matched.
    self_check : {"refuse", "warn"}
        For a vendor product whose model disagrees with its own statements: refuse, or proceed
        and record the disagreement (``product_check``, ``warnings``) in the summary.

    Returns
    -------
    dict
        The summary of :func:`gcpmatch.extract.extract_gcps` with the input and output paths;
        ``product_check`` (:func:`calibrate.actions._status.product_check_fields`);
        ``reference_accuracy`` (east_m, north_m, source, assumed) and, when nothing stated it,
        ``reference_note``.

    Raises
    ------
    InputError
        When no GCP could be extracted (the summary is written all the same).
    """
    from sensor_models.readers import open_scene

    options.validate()  # before any work: e.g. --backend gpu without CUDA
    residuals_path = residual_layer_path(out_path)
    inputs = InputSet([scene_path, image, mask_path, dom_path, dem_path, geoid])
    out_format = gcp_table_format(out_path)
    side = match_side_paths(out_path, out_format)
    check_output_files(out_path, Path(out_path).with_suffix(".summary.json"), gpkg_path, geotiff_path, residuals_path,
                       *side.values(), inputs=inputs)
    opened = open_scene(scene_path, image=image, band=band, self_check=self_check)  # a crop's raster crops it
    model = opened.model
    band = band or getattr(model, "reference_band", None)
    implausible = check_scene_raster(opened, band, image)  # before any work: names and headers only
    scene = read_band(opened, band, image)
    if geotiff_path is not None:  # before any work: the GeoTIFF's size limit, from the window count
        _check_geotiff_capacity(model, band, options, geotiff_path)
    dem = open_dem(dem_path, dem_datum, geoid, model=model, band=band)
    dom, dom_found = open_dom(dom_path)
    implausible += check_dom_resolution(dom, model, band=band, source=_dom_name(dom_found, dom_path))
    mask = None
    if mask_path is not None:
        mask = read_band(opened, band, mask_path)
        mask = np.nan_to_num(mask) != 0
    accuracy = reference_accuracy(dom_found.files, given_m=options.reference_sigma_m)  # option, DOM's tags/MTL, assumed
    note("reference_accuracy", {"east_m": accuracy.east_m, "north_m": accuracy.north_m, "source": accuracy.source,
                                "assumed": accuracy.assumed})
    table, summary = extract_gcps(model, scene, dem, dom, band=band, mask=mask, options=options, progress=progress,
                                  accuracy=accuracy, progress_count=progress_count)
    out_path = Path(out_path)
    summary.update({"scene": str(scene_path), "dom": str(dom_path), "dem": str(dem_path), "gcp_file": str(out_path)})
    if table is not None and len(table) > 0:
        summary["residual_layer"] = str(residuals_path)
        summary["qc_figure"] = str(side["qc"])
    summary.update(_dom_summary(dom, dom_found, model, band, dem))
    record_product_check(summary, opened.product_check)
    if implausible:
        summary["implausible_accepted"] = implausible
    _write_outputs(table, summary, scene=opened, band=band, image=image, out_path=out_path, out_format=out_format,
                   gpkg_path=gpkg_path, geotiff_path=geotiff_path, residuals_path=residuals_path, side=side,
                   inputs=inputs)
    if table is None or len(table) == 0:
        raise InputError(f"no GCP could be extracted ({summary['message']}); see {out_path.with_suffix('.summary.json')}",
                         path=str(scene_path))
    return summary



def _write_outputs(table, summary, *, scene, band, image, out_path, out_format, gpkg_path, geotiff_path,
                   residuals_path, side, inputs) -> None:
    """Write the GCP table (CSV with its .csvt/.prj, or GeoPackage), the optional GeoPackage and
    GeoTIFF, the residual layer, the QC figure and the summary; every file moves in together at
    the end, and with no GCP only the summary (older outputs go)."""
    from calibrate.match_qc import write_match_qc
    from calibrate.residual_layer import LAYER_NAMES, model_residual_layer, write_residual_layer
    from gcpmatch.gcp_csv import csv_sidecar_texts, write_gcps_csv
    from gcpmatch.gcp_geotiff import write_gcps_geotiff
    from gcpmatch.geopackage import write_gcps_gpkg

    model = scene.model
    staged = staged_files(out_path, out_path.with_suffix(".summary.json"), gpkg_path, geotiff_path, residuals_path,
                          side["qc"], side[".csvt"], side[".prj"], inputs=inputs)
    with staged as (csv_tmp, summary_tmp, gpkg_tmp, geotiff_tmp, residuals_tmp, qc_tmp, csvt_tmp, prj_tmp):
        if table is not None and len(table) > 0:
            if geotiff_tmp is not None:  # first: the one writer with a size limit
                raster, index = scene_raster(scene, band, image)
                write_gcps_geotiff(table, geotiff_tmp, image_shape=model.image_shape, source_raster=raster,
                                   source_band=index)
            if out_format == "gpkg":
                write_gcps_gpkg(table, csv_tmp)
            else:
                write_gcps_csv(table, csv_tmp)
                texts = csv_sidecar_texts()
                csvt_tmp.write_text(texts[".csvt"], encoding="ascii")
                prj_tmp.write_text(texts[".prj"], encoding="ascii")
            if gpkg_tmp is not None:
                write_gcps_gpkg(table, gpkg_tmp)
            layer = model_residual_layer(model, table)
            write_residual_layer(layer, residuals_tmp, layer=LAYER_NAMES["match"])
            write_match_qc(layer, model.image_shape, qc_tmp)
        summary_tmp.write_text(json.dumps(with_provenance(summary), indent=1) + "\n", encoding="utf-8")


def _dom_name(dom_found, dom_path) -> str:
    """The DOM's file (the first one) for messages."""
    files = list(getattr(dom_found, "files", None) or ())
    return str(files[0]) if files else str(dom_path)


def _check_geotiff_capacity(model, band, options: MatchOptions, geotiff_path) -> None:
    """Refuse ``--geotiff`` when the windows could give more GCPs than a GeoTIFF holds."""
    from gcpmatch.gcp_geotiff import GEOTIFF_MAX_GCPS

    n_windows = window_count(model, band, options)
    if n_windows > GEOTIFF_MAX_GCPS:
        raise InputError(f"{geotiff_path}: up to {n_windows} GCPs ({n_windows} windows) and a GeoTIFF holds at most "
                         f"{GEOTIFF_MAX_GCPS}: raise --spacing or write --gpkg instead", path=str(geotiff_path))


def _dom_summary(dom, dom_found, model, band, dem) -> dict:
    """What the DOM was resolved to, and the share of it under the footprint that its QA masks."""
    from sensor_models.terrain.footprint import footprint_sample_lonlat

    fields = dom_description(dom_found)
    share = None
    if dom.has_mask:
        lon, lat = footprint_sample_lonlat(model, float(np.mean(dem.height_range_m)), band=band)
        share = masked_fraction(dom, lon, lat)
    fields["dom_masked_fraction"] = share
    if share is not None:
        what = []
        if dom_found.qa_files:
            flags = "cloud, shadow, fill" + (", cirrus" if dom_found.qa_cirrus else "")
            what.append(f"the DOM's QA ({dom_found.qa_layout}: {flags})")
        if dom_found.mask_files:
            what.append("the DOM mask")
        fields["dom_note"] = (f"{' and '.join(what)} mask {100 * share:.1f} % of the reference under the scene: "
                              "windows there have no reference")
    return fields
