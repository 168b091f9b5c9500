"""Band-to-band registration error of a push-broom model against a TRUE model (simulations).

For a grid of reference-band pixels on every CCD, :func:`registration_error` compares where
the model and the truth say each other band sees the same ground: the misregistration that
products made with the model would carry. The tie residuals of :mod:`calibrate.relative`
measure the same quantity without a truth.
"""

from __future__ import annotations

import numpy as np

from calibrate.window_grid import target_ccd
from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel

__all__ = ["registration_error"]


def _grid(n: int, step: float) -> np.ndarray:
    k = max(2, int(np.ceil((n - 1) / step)) + 1)
    return np.linspace(0.5, n - 0.5, k)


def registration_error(true_model: PushbroomModel, model: PushbroomModel, *, dem, bands=None, reference_band=None,
                       step_px: float = 16.0) -> dict:
    """Band-to-band registration error of ``model`` against a TRUE model, px.

    For a grid of reference-band pixels ``p`` on every CCD, the truth says where band ``b``
    sees the same ground, ``q_true = T_b(T_ref^-1(p))``; the model says
    ``q = F_b(F_ref^-1(p))`` (both localize on ``dem``). The error is ``q - q_true``: the
    misregistration of band ``b`` on the reference band that products made with the model
    would carry, whatever the reference band's own absolute error.

    Parameters
    ----------
    true_model, model : PushbroomModel
        Same bands, CCD layouts and line count.
    dem : Dem
    bands : sequence of str, optional
        Default: every band but the reference band.
    reference_band : str, optional
        Default ``model.reference_band``.
    step_px : float
        Grid spacing in the reference band, px.

    Returns
    -------
    dict
        ``{band: {"rms_px", "max_px", "rms_row_px", "rms_col_px", "mean_row_px", "mean_col_px",
        "n_points", "per_ccd": [{"ccd", ...same keys}]}}``; grid points either model cannot
        project are left out.
    """
    reference_band = reference_band or model.reference_band
    bands = [b for b in model.bands if b != reference_band] if bands is None else list(bands)
    if true_model.n_rows != model.n_rows:
        raise InputError(f"the models have different line counts ({true_model.n_rows} and {model.n_rows})")
    rows = _grid(model.n_rows, step_px)
    out = {}
    for band in bands:
        per_ccd, all_d = [], []
        for i, look in enumerate(model.band_ccds(reference_band)):
            cols = look.first_col + _grid(look.n_detectors, step_px)
            rr, cc = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
            j = target_ccd(model, band, reference_band, i)
            q = []
            for m in (true_model, model):
                lon, lat, h = m.image_to_ground(rr, cc, dem=dem, band=reference_band, array=i)
                r, c = np.full(rr.size, np.nan), np.full(rr.size, np.nan)
                ok = np.isfinite(lon)
                if ok.any():
                    r[ok], c[ok] = m.ground_to_image(lon[ok], lat[ok], h[ok], band=band, array=j)
                q.append(np.stack([r, c], axis=-1))
            d = q[1] - q[0]
            d = d[np.all(np.isfinite(d), axis=1)]
            per_ccd.append({"ccd": look.name, **_error_stats(d)})
            all_d.append(d)
        out[band] = {**_error_stats(np.concatenate(all_d)), "per_ccd": per_ccd}
    return out


def _error_stats(d: np.ndarray) -> dict:
    if d.size == 0:
        return {"rms_px": None, "max_px": None, "rms_row_px": None, "rms_col_px": None,
                "mean_row_px": None, "mean_col_px": None, "n_points": 0}
    planar = np.hypot(d[:, 0], d[:, 1])
    return {
        "rms_px": float(np.sqrt(np.mean(planar**2))),
        "max_px": float(planar.max()),
        "rms_row_px": float(np.sqrt(np.mean(d[:, 0] ** 2))),
        "rms_col_px": float(np.sqrt(np.mean(d[:, 1] ** 2))),
        "mean_row_px": float(d[:, 0].mean()),
        "mean_col_px": float(d[:, 1].mean()),
        "n_points": int(d.shape[0]),
    }
