"""GCP truth error of a matched table, pooled and split by view angle (full-width runs).

Each matched GCP's image point ``(row, col)`` minus the TRUE model's projection of its ground
point ``(lon, lat, h)`` (:func:`calibrate.experiments.simulate_seed003.gcp_truth_error`), split by
the off-nadir angle of the TRUE line of sight at the GCP: the angle between the look direction and
the geocentric nadir (``-origin``) at the satellite. A height error ``dh`` of the user's DEM moves
the ground point a GCP carries by about ``dh * tan(angle)`` across track (plus the Earth's
curvature, a few per cent at 32 deg), so this split shows the DEM term growing off nadir.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: off-nadir angle classes, degrees: [lo, hi)
ANGLE_CLASSES_DEG = ((0.0, 10.0), (10.0, 20.0), (20.0, 35.0))


def off_nadir_deg(truth, table) -> np.ndarray:
    """Off-nadir angle of the TRUE line of sight at each GCP, degrees.

    Parameters
    ----------
    truth : PushbroomModel
        The TRUE model.
    table : GcpTable
        Matched GCPs (one band).

    Returns
    -------
    ndarray, shape (N,)
        Angle between the look direction and the geocentric nadir at the satellite, degrees.
    """
    band = str(table.band[0]) or None
    ccd = table.ccd if all(str(c) for c in table.ccd) else None
    origin, direction = truth.rays_itrf(table.row, table.col, band=band, array=ccd)
    nadir = -origin / np.linalg.norm(origin, axis=1, keepdims=True)
    cos = np.clip(np.sum(nadir * direction, axis=1), -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def _stats(err_px: np.ndarray) -> dict:
    """``n``, ``rms_px``, ``median_px``, ``max_px`` of 2-D errors (None when empty)."""
    err_px = err_px[np.isfinite(err_px)]
    if not err_px.size:
        return {"n": 0, "rms_px": None, "median_px": None, "max_px": None}
    return {"n": int(err_px.size), "rms_px": round(float(np.sqrt(np.mean(err_px**2))), 4),
            "median_px": round(float(np.median(err_px)), 4), "max_px": round(float(err_px.max()), 4)}


def gcp_truth_by_angle(truth_manifest: Path, gcps_csv: Path) -> dict:
    """GCP truth error (2-D, px) of a GCP table, pooled and per off-nadir class.

    Parameters
    ----------
    truth_manifest : Path
        The simulator's ``truth_manifest.json``.
    gcps_csv : Path
        ``gcpcal match`` output (GCPs and check points).

    Returns
    -------
    dict
        ``all`` (:func:`calibrate.experiments.simulate_seed003.gcp_truth_error`, rounded),
        ``by_off_nadir_deg`` (``"lo-hi"`` -> ``n``, ``rms_px``, ``median_px``, ``max_px``),
        ``off_nadir_max_deg`` and, per class, the mean signed ``(row, col)`` error in px
        (``mean_drow_px``, ``mean_dcol_px``).
    """
    from calibrate.experiments.simulate_seed003 import gcp_truth_error
    from gcpmatch.gcp_files import read_gcps
    from sensor_models.readers import open_model

    truth, table = open_model(truth_manifest), read_gcps(gcps_csv)
    pooled = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in gcp_truth_error(truth, table).items()}
    band = str(table.band[0]) or None
    ccd = table.ccd if all(str(c) for c in table.ccd) else None
    r_t, c_t = truth.ground_to_image(table.lon, table.lat, table.h, band=band, array=ccd)
    d_row, d_col = table.row - r_t, table.col - c_t
    err = np.hypot(d_row, d_col)
    angle = off_nadir_deg(truth, table)
    classes = {}
    for lo, hi in ANGLE_CLASSES_DEG:
        sel = (angle >= lo) & (angle < hi) & np.isfinite(err)
        classes[f"{lo:g}-{hi:g}"] = {**_stats(err[sel]),
                                     "mean_drow_px": round(float(np.mean(d_row[sel])), 4) if sel.any() else None,
                                     "mean_dcol_px": round(float(np.mean(d_col[sel])), 4) if sel.any() else None}
    return {"all": pooled, "by_off_nadir_deg": classes, "off_nadir_max_deg": round(float(np.nanmax(angle)), 2)}
