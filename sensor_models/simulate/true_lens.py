"""The TRUE push-broom lens beyond the cubic in detector index (``realistic`` profile).

Terms added to the TRUE camera of :mod:`sensor_models.simulate.scene` (the LAB model never
knows them; the estimator fits a cubic in the detector index per CCD):

* radial ``k2 r^4`` and ``k3 r^6`` (displacements ``k2 r^5``, ``k3 r^7``), given as their
  displacement in pixels at the end of the array (``radial_k2_px``, ``radial_k3_px``);
* focal-plane curvature: an along-track displacement ``c (y / Y)^2`` of every detector, with
  ``y`` its across-track position and ``Y`` half the array (``focal_plane_curvature_px`` = ``c``);
* CCD bending: an along-track clamped-beam bow of each CCD, ``b 16 u^2 (1 - u)^2`` with
  ``u = s / (n - 1)`` (a quartic: the deflection of a beam clamped at both ends under uniform
  load, Timoshenko & Gere, Mechanics of Materials); ``ccd_bending_px`` = ``b``;
* per-detector irregularity: white offsets of every detector's line of sight, ``sigma`` px rms
  along and across track, drawn per band and CCD from the camera ``seed``.

The smooth terms enter the TRUE directional-angle polynomials (degree 7: they are represented to
< 1e-4 px). The irregularity cannot be a polynomial: the radiometric kernel
(:mod:`sensor_models.simulate.kernel`) shifts each detector's footprint by it, and ``truth.json``
records it; ``gcpcal truth error`` compares with the polynomial truth and so does not include it
(its rms adds in quadrature).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as P

__all__ = ["LensExtras", "cubic_residual_px", "lens_extras"]


@dataclass(frozen=True)
class LensExtras:
    """Magnitudes of the TRUE lens terms beyond the cubic (pixels) and the camera seed.

    Attributes
    ----------
    k2_px, k3_px : float
        Radial displacement at the array end from ``k2`` and ``k3``, px.
    curvature_px : float
        Along-track focal-plane sag at the array ends, px.
    bending_px : float
        Peak along-track bow of each CCD, px.
    irregularity_px : float
        Per-detector line-of-sight offset, px rms per axis.
    seed : int
        The camera seed (irregularities are the sensor's, shared by its scenes).
    """

    k2_px: float = 0.0
    k3_px: float = 0.0
    curvature_px: float = 0.0
    bending_px: float = 0.0
    irregularity_px: float = 0.0
    seed: int = 0

    def smooth_tan(self, y_px, s, n_detectors: int, half_px: float, ifov: float):
        """Along-track ``tan psi_x`` added by curvature and bending (radial terms are in the camera).

        Parameters
        ----------
        y_px : ndarray, shape (N,)
            Across-track focal-plane position of the detectors from the array centre, px.
        s : ndarray, shape (N,)
            Detector indices in their CCD.
        n_detectors : int
            Detectors of the CCD.
        half_px : float
            Half the array width, px.
        ifov : float
            ``tan`` of one pixel (pixel pitch over focal length).

        Returns
        -------
        ndarray, shape (N,)
            ``d tan psi_x``.
        """
        u = np.asarray(s, dtype=np.float64) / max(1, n_detectors - 1)
        sag = self.curvature_px * (np.asarray(y_px) / half_px) ** 2 + self.bending_px * 16.0 * u**2 * (1.0 - u) ** 2
        return sag * ifov

    def irregularity(self, band_index: int, ccd_index: int, n_detectors: int):
        """Per-detector line-of-sight offsets of one band and CCD.

        Parameters
        ----------
        band_index, ccd_index : int
            Position of the band in the camera's bands and of the CCD in the band's CCDs.
        n_detectors : int
            Detectors of the CCD.

        Returns
        -------
        d_row_px, d_col_px : ndarray of float64, shape (n_detectors,)
            Along-track and across-track offsets, px (zeros when ``irregularity_px`` is 0).
        """
        if self.irregularity_px <= 0:
            z = np.zeros(n_detectors)
            return z, z.copy()
        rng = np.random.default_rng([int(self.seed), 20, int(band_index), int(ccd_index)])
        d = rng.normal(0.0, self.irregularity_px, (2, n_detectors))
        return d[0], d[1]


def lens_extras(profile, seed: int) -> LensExtras:
    """The :class:`LensExtras` of a profile.

    Parameters
    ----------
    profile : PushbroomProfile
        Its ``radial_k2_px``, ``radial_k3_px``, ``focal_plane_curvature_px``, ``ccd_bending_px``
        and ``detector_irregularity_px``.
    seed : int
        The camera seed.

    Returns
    -------
    LensExtras
    """
    v = profile.value
    return LensExtras(v("radial_k2_px"), v("radial_k3_px"), v("focal_plane_curvature_px"), v("ccd_bending_px"),
                      v("detector_irregularity_px"), int(seed))


def cubic_residual_px(models, lens: LensExtras, *, band: str | None = None) -> dict:
    """Residual of the TRUE lens after a per-CCD cubic fit in detector index (outside the family?).

    The true directional angles (polynomial truth plus the per-detector irregularity) are
    fitted, per CCD, with the cubic the calibration estimates; what is left is what no
    calibration of that model can remove.

    Parameters
    ----------
    models : SceneModels
        From :func:`sensor_models.simulate.scene.build_models` with ``lens``.
    lens : LensExtras
        The lens terms (for the irregularity).
    band : str, optional
        Band (default: the reference band).

    Returns
    -------
    dict
        ``rms_px``, ``max_px`` over both axes and all CCDs; ``smooth_rms_px``: the same without
        the irregularity.
    """
    model = models.true_model
    band = band or model.reference_band
    b = list(model.bands).index(band)
    ifov = models.true_camera.pixel_size_mm / models.true_camera.focal_length_mm
    all_r, smooth_r = [], []
    for k, look in enumerate(model.band_ccds(band)):
        s = np.arange(look.n_detectors, dtype=np.float64)
        d_row, d_col = lens.irregularity(b, k, look.n_detectors)
        for coef, irr in ((look.tan_psi_x, d_row), (look.tan_psi_y, d_col)):
            t = P.polyval(s, coef)
            for target, out in ((t, smooth_r), (t + irr * ifov, all_r)):
                fit = P.polyval(s, P.polyfit(s, target, 3))
                out.append((target - fit) / ifov)
    a, sm = np.concatenate(all_r), np.concatenate(smooth_r)
    return {"rms_px": float(np.sqrt(np.mean(a**2))), "max_px": float(np.abs(a).max()),
            "smooth_rms_px": float(np.sqrt(np.mean(sm**2)))}
