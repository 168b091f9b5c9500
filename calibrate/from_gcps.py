"""Calibrating a model from a GCP table: the table's arrays, and the fit on its ``gcp`` points."""

from __future__ import annotations

import numpy as np

from calibrate.config import CalibrationOptions
from sensor_models.errors import InputError

__all__ = ["apply_calibration", "points_of"]


def points_of(table, model=None) -> dict:
    """Arrays ``row, col, lon, lat, h, sigma_px, score, band, ccd`` of a GcpTable.

    Parameters
    ----------
    table : gcpmatch.gcps.GcpTable
        The points (any kind).
    model : SensorModel, optional
        With a model of named detector arrays (push-broom CCDs), array names become indices
        into ``model.detector_arrays(band)`` (what the accuracy functions take).

    Returns
    -------
    dict
        ``row, col`` (pixels), ``lon, lat`` (degrees), ``h`` (m), ``sigma_px``, ``score``: float64
        arrays of shape (N,); ``band`` and ``ccd``: arrays of shape (N,), or None when blank.
    """
    out = {k: np.asarray(getattr(table, k), dtype=np.float64) for k in ("row", "col", "lon", "lat", "h", "sigma_px", "score")}
    for k in ("band", "ccd"):
        v = np.asarray(getattr(table, k)).astype(str)
        out[k] = None if (v.size == 0 or np.all(v == "")) else v
    if model is not None and out["ccd"] is not None and any(a.name for a in model.detector_arrays()):
        idx = np.empty(out["ccd"].size, dtype=np.intp)
        bands = out["band"] if out["band"] is not None else np.full(idx.size, model.reference_band)
        for b in np.unique(bands):
            s = bands == b
            idx[s] = model.detector_index(out["col"][s], band=str(b), array=out["ccd"][s])
        out["ccd"] = idx
    return out


def apply_calibration(model, table, *, options: CalibrationOptions = CalibrationOptions(), band=None):
    """Calibrate ``model`` on the ``gcp`` points of ``table``.

    Rigorous models (push-broom, staring camera) use the stepwise schemes of
    :func:`calibrate.absolute.calibrate_model`; an RPC gets an image-space bias compensation
    (:func:`calibrate.rpc_bias.compensate_rpc_bias`, Grodecki and Dial 2003).

    Parameters
    ----------
    model : SensorModel
        The model to calibrate.
    table : gcpmatch.gcps.GcpTable
        GCPs and check points; only the points of kind ``gcp`` are fitted.
    options : CalibrationOptions
        Scheme, robust loss and solver settings of a rigorous model.
    band : str, optional
        Band of the points that name none.

    Returns
    -------
    result : CalibrationResult or RpcBiasResult
        The fit (``result.model`` is the calibrated model).
    gcps : dict
        The fitted points, as :func:`points_of` returns them.
    """
    from calibrate.absolute import calibrate_model
    from gcpmatch.gcps import GcpTable

    g = points_of(table.gcps())
    if g["row"].size == 0:
        raise InputError("the GCP table holds no point of kind 'gcp'")
    if band is not None:
        g["band"] = np.full(g["row"].size, band) if g["band"] is None else g["band"]
    if model.is_rigorous:  # push-broom or staring camera
        gcps = table.gcps()
        if band is not None and np.all(gcps.band == ""):
            gcps = GcpTable.from_arrays(**{**gcps.as_dict(), "band": band})
        result = calibrate_model(model, gcps, options=options)
    else:
        from calibrate.rpc_bias import compensate_rpc_bias

        result = compensate_rpc_bias(model, g["row"], g["col"], g["lon"], g["lat"], g["h"], sigma_px=g["sigma_px"])
    return result, g
