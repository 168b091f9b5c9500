"""The residual layer: per-point image residuals as a GeoPackage layer a GIS opens.

One point feature per GCP or check point, at the point's ground position (EPSG:4326
``POINT Z``: lon, lat in degrees, h in metres above the WGS84 ellipsoid), with the fields of
:data:`RESIDUAL_FIELDS`. ``match``, ``calibrate``, ``validate`` and ``campaign`` write it through
:func:`write_residual_layer`; docs/calibration_outputs.md ("Residual layer") describes it.

Residuals are observed minus modelled image coordinates, in pixels: ``resid_along_px`` in the
row (line, along-track) direction, ``resid_across_px`` in the column (sample, across-track)
direction. Metres come from the model's local ground sampling distance at the point:
``gsd_along_m = |g_row|`` and ``gsd_across_m = |g_col|``, the horizontal ground lengths of a
one-pixel step in row and in column, found by localizing ``row +- 0.5`` and ``col +- 0.5`` at
the point's height (:func:`calibrate.accuracy.ground_steps`); then
``resid_along_m = resid_along_px * gsd_along_m`` and likewise across. ``resid_planar_m`` is the
length of the ground vector ``resid_along_px g_row + resid_across_px g_col`` (equal to the root
sum of squares of the two only when rows and columns are perpendicular on the ground).
``resid_east_m`` and ``resid_north_m`` are that ground vector's components in the local
east-north plane (the ground displacement from the modelled to the observed position), and
``resid_azimuth_deg`` its direction, clockwise from north in [0, 360): what a GIS arrow or
rotation symbol draws.

Each stage names its layer after itself (:data:`LAYER_NAMES`), so that two files loaded in one
GIS project stay apart.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sensor_models.errors import InputError

__all__ = ["KINDS", "LAYER_NAMES", "RESIDUAL_FIELDS", "concatenate_layers", "model_residual_layer", "read_residual_layer", "residual_layer",
           "write_residual_layer"]

#: Point kinds: fitted GCP, independent check point, GCP the fit rejected as an outlier.
KINDS = ("gcp", "check", "outlier")

#: Stage -> the name of its residual layer.
LAYER_NAMES = {"match": "match_residuals", "calibrate": "calibration_residuals", "validate": "validation_residuals",
               "campaign": "campaign_residuals"}

#: Field name -> (GeoPackage type, unit, meaning), in layer order (after ``fid`` and ``geom``).
RESIDUAL_FIELDS = {
    "id": ("TEXT", "", "point id of the GCP table"),
    "kind": ("TEXT", "", "gcp | check | outlier"),
    "site": ("TEXT", "", "validation scene name (validate) or campaign scene name (campaign); empty elsewhere"),
    "band": ("TEXT", "", "band the point was measured in"),
    "ccd": ("TEXT", "", "detector array (CCD) that imaged the point; empty for a single-array image"),
    "row": ("REAL", "px", "observed image row (first pixel centre at 0.5)"),
    "col": ("REAL", "px", "observed image column"),
    "lon": ("REAL", "deg", "WGS84 longitude"),
    "lat": ("REAL", "deg", "WGS84 latitude"),
    "h": ("REAL", "m", "height above the WGS84 ellipsoid"),
    "sigma_px": ("REAL", "px", "the point's measurement sigma (matcher's)"),
    "resid_along_px": ("REAL", "px", "observed minus modelled row"),
    "resid_across_px": ("REAL", "px", "observed minus modelled column"),
    "resid_planar_px": ("REAL", "px", "hypot of the two"),
    "resid_along_m": ("REAL", "m", "resid_along_px x gsd_along_m"),
    "resid_across_m": ("REAL", "m", "resid_across_px x gsd_across_m"),
    "resid_planar_m": ("REAL", "m", "length of the residual's ground vector"),
    "resid_east_m": ("REAL", "m", "east component of the residual's ground vector"),
    "resid_north_m": ("REAL", "m", "north component of the residual's ground vector"),
    "resid_azimuth_deg": ("REAL", "deg", "direction of the residual's ground vector, clockwise from north"),
    "gsd_along_m": ("REAL", "m/px", "ground length of a one-row step at the point (model's)"),
    "gsd_across_m": ("REAL", "m/px", "ground length of a one-column step at the point (model's)"),
}

_TEXT = [k for k, v in RESIDUAL_FIELDS.items() if v[0] == "TEXT"]
_DESCRIPTION = ("gcpcal residuals (observed minus modelled image coordinates; along = rows, across = "
                "columns; metres from the model's local GSD)")  # fmt: skip
_WKB_POINT_Z = np.dtype([("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8")])


def _ccd_names(model, col, band, ccd_names):
    """Per point: the table's CCD name, or the name of the array whose columns hold ``col``."""
    names = np.array([str(n) for n in np.asarray(ccd_names, dtype=object).ravel()], dtype=object)
    blank = names == ""  # object array: the names filled in below are not cut to the blanks' width
    for b in np.unique(band[blank]) if blank.any() else ():
        sel = blank & (band == b)
        arrays = model.detector_arrays(str(b) or None)
        idx = model.detector_index(col[sel], band=str(b) or None)
        names[sel] = np.array([a.name for a in arrays], dtype=object)[idx]
    return names


def _ccd_indices(model, col, band, names):
    """Per point: index of its CCD in ``model.detector_arrays(band)``; None without named CCDs."""
    idx, named = np.zeros(col.size, dtype=np.intp), False
    for b in np.unique(band):
        sel = band == b
        if any(a.name for a in model.detector_arrays(str(b) or None)):
            idx[sel], named = model.detector_index(col[sel], band=str(b) or None, array=names[sel]), True
    return idx if named else None


def residual_layer(model, table, residuals_px, kind, *, site: str = "") -> dict[str, np.ndarray]:
    """The residual layer's columns for the points of ``table``.

    Parameters
    ----------
    model : SensorModel
        The model the residuals were computed against; its local GSD converts pixels to metres.
    table : gcpmatch.gcps.GcpTable
        The N points (row, col, lon, lat, h, sigma_px, band, ccd, id).
    residuals_px : array_like, shape (N, 2)
        Observed minus modelled (row, col), pixels; NaN where the model gives no projection.
    kind : str or array_like of str, shape (N,)
        Each point's kind, one of :data:`KINDS`.
    site : str
        Validation site name (empty outside ``validate``).

    Returns
    -------
    dict of str to ndarray, shape (N,)
        The :data:`RESIDUAL_FIELDS` columns (text as object arrays).

    Raises
    ------
    InputError
        Mis-shaped residuals or an unknown kind.
    """
    from calibrate.accuracy import ground_steps

    n = len(table)
    res = np.asarray(residuals_px, dtype=np.float64)
    if res.shape != (n, 2):
        raise InputError(f"residuals have shape {res.shape}, expected ({n}, 2)", field="residuals_px")
    kinds = np.broadcast_to(np.asarray(kind, dtype=object).astype(str), (n,))
    if not np.isin(kinds, KINDS).all():
        raise InputError(f"kind must be one of {KINDS}", field="kind")
    band = np.where(table.band == "", model.reference_band or "", table.band).astype(str)
    names = _ccd_names(model, table.col, band, table.ccd)
    g_row, g_col = ground_steps(model, table.row, table.col, table.h, band=None if np.all(band == "") else band,
                                ccd=_ccd_indices(model, table.col, band, names))
    gsd_row, gsd_col = np.linalg.norm(g_row, axis=1), np.linalg.norm(g_col, axis=1)
    vec = res[:, 0:1] * g_row + res[:, 1:2] * g_col
    cols = {"id": table.id, "kind": kinds, "site": np.full(n, str(site)), "band": band, "ccd": names,
            "row": table.row, "col": table.col, "lon": table.lon, "lat": table.lat, "h": table.h,
            "sigma_px": table.sigma_px, "resid_along_px": res[:, 0], "resid_across_px": res[:, 1],
            "resid_planar_px": np.hypot(res[:, 0], res[:, 1]), "resid_along_m": res[:, 0] * gsd_row,
            "resid_across_m": res[:, 1] * gsd_col, "resid_planar_m": np.linalg.norm(vec, axis=1),
            "resid_east_m": vec[:, 0], "resid_north_m": vec[:, 1],
            "resid_azimuth_deg": np.mod(np.degrees(np.arctan2(vec[:, 0], vec[:, 1])), 360.0),
            "gsd_along_m": gsd_row, "gsd_across_m": gsd_col}
    return {k: _column(k, cols[k]) for k in RESIDUAL_FIELDS}


def model_residual_layer(model, table, *, kind=None, site: str = "") -> dict[str, np.ndarray]:
    """The residual layer of ``table``'s points against ``model`` (no fit involved).

    Parameters
    ----------
    model : SensorModel
        The model the points are scored against (e.g. the uncalibrated input model of ``match``).
    table : gcpmatch.gcps.GcpTable
        The points.
    kind : str or array_like of str, optional
        Each point's kind (:data:`KINDS`); default: the table's own ``kind`` column.
    site : str
        Validation site name.

    Returns
    -------
    dict of str to ndarray
        As :func:`residual_layer`; residuals from :func:`calibrate.accuracy.check_residuals`.
    """
    from calibrate.accuracy import check_residuals

    band = np.where(table.band == "", model.reference_band or "", table.band).astype(str)
    names = _ccd_names(model, table.col, band, table.ccd)
    res = np.zeros((0, 2))
    if len(table):
        res, _ = check_residuals(model, table.row, table.col, table.lon, table.lat, table.h,
                                 band=None if np.all(band == "") else band,
                                 ccd=_ccd_indices(model, table.col, band, names))
    return residual_layer(model, table, res, table.kind if kind is None else kind, site=site)


def _column(name: str, values) -> np.ndarray:
    if name in _TEXT:
        return np.asarray(values).astype(str).astype(object)
    return np.asarray(values, dtype=np.float64).copy()


def concatenate_layers(layers) -> dict[str, np.ndarray]:
    """Join residual layers (e.g. one per validation site) into one.

    Parameters
    ----------
    layers : iterable of dict
        Columns as :func:`residual_layer` returns them.

    Returns
    -------
    dict of str to ndarray
        The rows of every layer, in order.
    """
    layers = list(layers)
    if not layers:
        return {k: _column(k, []) for k in RESIDUAL_FIELDS}
    return {k: _column(k, np.concatenate([np.asarray(x[k], dtype=object if k in _TEXT else np.float64)
                                          for x in layers])) for k in RESIDUAL_FIELDS}


def write_residual_layer(columns: dict, path, *, layer: str) -> Path:
    """Write a residual layer as an OGC GeoPackage (EPSG:4326 POINT Z); atomically.

    Written by GDAL through :func:`pyogrio.raw.write`, as
    :func:`gcpmatch.geopackage.write_gcps_gpkg` writes GCPs: ``fid``, ``geom`` (lon, lat, h) and the
    :data:`RESIDUAL_FIELDS` in order. An empty layer (no point) is written with its schema. The
    layer's default QGIS style (arrows along the residuals) is stored in ``layer_styles``
    (:mod:`calibrate.residual_style`).

    Parameters
    ----------
    columns : dict of str to array_like, shape (N,)
        The :data:`RESIDUAL_FIELDS` columns (:func:`residual_layer`).
    path : str or Path
        Destination (``*.gpkg``); its folder must exist. Written to a temporary file beside it and
        renamed.
    layer : str
        Layer name (:data:`LAYER_NAMES` for the stages' files).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        A missing column or GDAL could not write the file.
    """
    from calibrate.residual_style import add_residual_style
    from gcpmatch.geopackage import write_point_layer
    from sensor_models.files.atomic import atomic_file

    missing = [k for k in RESIDUAL_FIELDS if k not in columns]
    if missing:
        raise InputError(f"residual layer lacks the columns {missing}", path=str(path))
    cols = {k: _column(k, columns[k]) for k in RESIDUAL_FIELDS}
    path = Path(path)
    with atomic_file(path, ".gpkg") as tmp:
        write_point_layer(tmp, cols["lon"], cols["lat"], cols["h"], cols, layer=layer, description=_DESCRIPTION,
                          what="the residual layer")
        add_residual_style(tmp, layer)  # QGIS draws arrows by default (calibrate/residual_style.py)
    return path


def read_residual_layer(path, *, layer: str | None = None) -> dict[str, np.ndarray]:
    """Read a residual layer written by :func:`write_residual_layer`.

    Parameters
    ----------
    path : str or Path
        The GeoPackage.
    layer : str, optional
        Layer name; default: the file's only point layer (``layer_styles``, the stored QGIS
        style, is a table without geometry).

    Returns
    -------
    dict of str to ndarray, shape (N,)
        The :data:`RESIDUAL_FIELDS` columns in feature order, plus ``geom_lon``, ``geom_lat``,
        ``geom_h`` from the point geometries.

    Raises
    ------
    InputError
        Unreadable file, missing layer or field.
    """
    import pyogrio.raw
    from pyogrio.errors import DataSourceError, DataLayerError

    try:
        if layer is None:
            layers = [str(name) for name, geometry in pyogrio.list_layers(path) if geometry is not None]
            if len(layers) != 1:
                raise InputError(f"holds {len(layers)} layers ({', '.join(layers)}): name the residual layer",
                                 path=str(path))
            layer = layers[0]
        meta, _, geometry, values = pyogrio.raw.read(path, layer=layer)
    except (DataSourceError, DataLayerError) as exc:
        raise InputError(f"cannot read the residual layer: {exc}", path=str(path)) from None
    names = list(meta["fields"])
    missing = [k for k in RESIDUAL_FIELDS if k not in names]
    if missing:
        raise InputError(f"residual layer lacks the fields {missing}", path=str(path))
    out = {k: _column(k, values[names.index(k)]) for k in RESIDUAL_FIELDS}
    xyz = np.array([np.frombuffer(bytes(g), dtype=_WKB_POINT_Z)[0].tolist()[2:] for g in geometry]).reshape(-1, 3)
    out["geom_lon"], out["geom_lat"], out["geom_h"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return out
