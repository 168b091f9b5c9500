"""Clouds and water: which match windows cannot give a GCP.

* A mask raster in scene geometry (nonzero = cloud or invalid) is used when given.
* Otherwise a detector flags windows that are much brighter than the reference predicts:
  per CCD, the scene window means are regressed robustly on the reference window means
  (``m_s ~ a m_r + b``, IRLS), and windows whose residual exceeds ``4 * 1.4826 MAD`` on the bright
  side are clouds. Clouds are bright, opaque and absent from the reference.
* Water (and any featureless ground) is recognized in the reference: windows whose reference
  standard deviation is below ``texture_fraction`` of the median over the CCD have no texture.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bright_outliers", "low_texture"]


def bright_outliers(mean_scene: np.ndarray, mean_ref: np.ndarray, *, k: float = 4.0) -> np.ndarray:
    """Flags of windows far brighter than the linear prediction from the reference (clouds)."""
    ok = np.isfinite(mean_scene) & np.isfinite(mean_ref)
    out = np.zeros(mean_scene.shape, bool)
    if ok.sum() < 10:
        return out
    x, y = mean_ref[ok], mean_scene[ok]
    w = np.ones(x.size)
    for _ in range(6):
        a = np.stack([x, np.ones_like(x)], axis=-1) * np.sqrt(w)[:, None]
        coef = np.linalg.lstsq(a, y * np.sqrt(w), rcond=None)[0]
        res = y - (coef[0] * x + coef[1])
        s = 1.4826 * np.median(np.abs(res)) + 1e-9
        w = np.where(np.abs(res) <= 1.345 * s, 1.0, 1.345 * s / np.abs(res))
    out[ok] = res > k * s
    return out


def low_texture(std_ref: np.ndarray, *, texture_fraction: float = 0.2) -> np.ndarray:
    """Flags of windows whose reference has (almost) no texture (water, haze, uniform fields)."""
    ok = np.isfinite(std_ref)
    out = ~ok
    if ok.any():
        out |= std_ref < texture_fraction * np.median(std_ref[ok])
    return out
