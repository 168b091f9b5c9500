"""Each GCP's ``sigma_px``: the standard deviation per axis of its matched position.

Two models (:data:`gcpmatch.options.SIGMA_MODELS`; docs/matching.md, section "sigma_px"):

* ``"ccd"``: one value per CCD, the robust (MAD) spread per axis of the matches' residuals about
  a smooth per-CCD correction (:func:`gcpmatch.outliers.smooth_residuals`). It measures the
  matching noise *plus* whatever the smooth correction cannot follow (attitude jitter, lens
  terms), and nothing of the errors that all matches share (the reference's geolocation error).
* ``"window"`` (default): per window, the matching noise predicted from its phase-correlation
  score ``s`` (the coherent share of the cross-power), a floor of the matching itself, and the
  reference's stated geolocation accuracy (:func:`sensor_models.maps.dom_inputs.reference_accuracy`)::

      sigma_px^2 = (SCORE_SIGMA_PX sqrt((1 - s) / s))^2 + MATCH_FLOOR_PX^2 + sigma_ref_px^2
                   + (k sigma_mm_px)^2

  with ``sigma_mm_px`` the pair's Cramer-Rao-shaped bound with its own mismatch as the noise
  (:func:`gcpmatch.texture.mismatch_cr_sigma_px`, rms of the two axes; ``k`` =
  ``MatchOptions.mismatch_sigma_scale``, 1 by default, 0 for the window model alone):
  the score is relative to each window, this term is not, and it carries what texture-poor ground
  loses (docs/matching.md, "Texture-poor ground");

  with :attr:`~gcpmatch.options.MatchOptions.spectral_spread_sigma`, a further term in quadrature:
  the pair's spectral spread (:func:`gcpmatch.window_match.spectral_spread_px`, how far the shift
  moves under other weightings of the cross-power), which the score does not see where the
  reference shows the ground otherwise (another band or date; docs/matching.md, "Matching under
  real change");
  and ``sigma_ref_px`` the DOM's east / north accuracy projected into the CCD's rows and
  columns through the model's local ground -> image Jacobian (:func:`reference_sigma_px`),
  taken as the rms of the two axes (a GCP carries one ``sigma_px`` for both axes).

  The phase noise of a cross-power bin grows as the coherent share falls (for a small phase
  noise of variance ``v``, ``s ~ 1 - v / 2``), and the shift's variance grows with it. The
  floor is what a window match misses whatever its score on imagery of another sensor and date
  (resampling of a coarser reference, the window averaging a shift that varies inside it).
  Both constants are measured (``bench/bench_matcher_realism.py``) on the realistic profile
  with the DOM's geolocation error switched off, where every remaining error is the matcher's.
"""

from __future__ import annotations

import numpy as np

from gcpmatch.texture import texture_sigma_px as texture_term

__all__ = ["FALLBACK_SIGMA_PX", "MATCH_FLOOR_PX", "MIN_SIGMA_PX", "SCORE_SIGMA_PX", "reference_sigma_px",
           "score_sigma_px", "window_sigma"]

#: ``sigma_px`` when a CCD has too few matches (< 10) for a residual spread, pixels
FALLBACK_SIGMA_PX = 0.1
#: smallest ``sigma_px``, pixels
MIN_SIGMA_PX = 0.01
#: matching noise per axis, pixels, of a 64 px window whose score is 0.5 (``sqrt((1 - s) / s) =
#: 1``): least-squares fit ``e^2 = a^2 (1 - s) / s + f^2`` of the squared per-axis truth errors
#: of the 231 kept GCPs of the realistic profile without DOM error, on Lanczos reference chips
#: (a = 0.071 px, f = 0.032 px; docs/matching.md, "sigma_px"); on the ideal scene the same fit
#: gives a = 0.100 px, f = 0.007 px (``bench/bench_matcher_realism.py``)
SCORE_SIGMA_PX = 0.071
#: matching floor per axis, pixels (64 px windows), from the same fit
MATCH_FLOOR_PX = 0.032


def score_sigma_px(score: np.ndarray, *, window_px: int = 64) -> np.ndarray:
    """Matching noise per axis predicted from the phase-correlation score, pixels.

    Parameters
    ----------
    score : ndarray of float, shape (n,)
        :attr:`gcpmatch.phase.PhaseMatches.score`, in (0, 1].
    window_px : int
        Window side, pixels; the noise scales as ``64 / window_px`` (the shift's variance falls
        as the number of pixels, the score's null spread as its square root).

    Returns
    -------
    ndarray of float64, shape (n,)
        ``hypot(SCORE_SIGMA_PX sqrt((1 - s) / s), MATCH_FLOOR_PX) * 64 / window_px``.
    """
    s = np.clip(np.asarray(score, dtype=float), 1e-3, 1.0)
    return np.hypot(SCORE_SIGMA_PX * np.sqrt((1.0 - s) / s), MATCH_FLOOR_PX) * (64.0 / window_px)


def window_sigma(sigma_ccd_px: float, residual_px: np.ndarray, quality: dict, *, model: str = "ccd",
                 reference_sigma_px: float = 0.0, window_px: int = 64, texture_sigma_px: float = 0.0,
                 mismatch_scale: float = 0.0, spread_sigma: bool = False) -> np.ndarray:
    """Per-GCP standard deviation per axis, pixels, for the kept matches of one CCD.

    Parameters
    ----------
    sigma_ccd_px : float
        Robust spread per axis of the CCD's residuals about a smooth correction, pixels
        (:func:`gcpmatch.outliers.smooth_residuals`); NaN with too few matches.
    residual_px : ndarray of float64, shape (n, 2)
        The kept matches' residuals about that correction (row, col), pixels.
    quality : dict of str -> ndarray (n,)
        Per-window quality of the kept matches (``score``, needed by ``"window"``).
    model : {"ccd", "window"}
        See the module docstring.
    reference_sigma_px : float
        The reference's geolocation accuracy per axis in scene pixels (``"window"`` only).
    window_px : int
        Window side, pixels.
    texture_sigma_px : float
        ``"window"`` only: scale of an extra term for texture-poor windows added in quadrature,
        :func:`gcpmatch.texture.texture_sigma_px` of the quality's ``gradient_snr_row`` and
        ``gradient_snr_col`` (0, the default: none; :attr:`MatchOptions.texture_sigma_px`).
    mismatch_scale : float
        ``"window"`` only: factor on the rms over the two axes of the quality's
        ``mismatch_cr_row_px`` and ``mismatch_cr_col_px`` (:func:`gcpmatch.texture.mismatch_cr_sigma_px`),
        added in quadrature; NaN counts as 0 (0, the default: none; :attr:`MatchOptions.mismatch_sigma_scale`).
    spread_sigma : bool
        ``"window"`` only: add the quality's ``spectral_spread_px``
        (:func:`gcpmatch.window_match.spectral_spread_px`) in quadrature (False, the default: not;
        :attr:`MatchOptions.spectral_spread_sigma`).

    Returns
    -------
    ndarray of float64, shape (n,)
        ``sigma_px`` of each kept GCP (at least :data:`MIN_SIGMA_PX`).
    """
    n = residual_px.shape[0]
    if model == "window" and "score" in quality:
        match = np.hypot(score_sigma_px(quality["score"], window_px=window_px), reference_sigma_px)
        if texture_sigma_px > 0.0 and "gradient_snr_row" in quality:
            match = np.hypot(match, texture_term(quality["gradient_snr_row"], quality["gradient_snr_col"],
                                                 texture_sigma_px))
        if mismatch_scale > 0.0 and "mismatch_cr_row_px" in quality:
            cr = np.sqrt(0.5 * (quality["mismatch_cr_row_px"] ** 2 + quality["mismatch_cr_col_px"] ** 2))
            match = np.hypot(match, mismatch_scale * np.nan_to_num(cr, nan=0.0))
        if spread_sigma and "spectral_spread_px" in quality:  # MatchOptions.spectral_spread_sigma
            match = np.hypot(match, np.nan_to_num(quality["spectral_spread_px"], nan=0.0))
        return np.maximum(match, MIN_SIGMA_PX)
    base = max(sigma_ccd_px, MIN_SIGMA_PX) if np.isfinite(sigma_ccd_px) else FALLBACK_SIGMA_PX
    return np.full(n, base)


def reference_sigma_px(model, east_m: float, north_m: float, *, band, first_col: float, n_detectors: int,
                       height_m: float = 0.0, array=None) -> tuple:
    """A reference's east / north geolocation error projected into image rows and columns, pixels.

    The ground -> image Jacobian ``J = d(row, col) / d(east, north)`` (px per m,
    :func:`sensor_models.imaging.ground_shift.ground_shift_jacobian`) at the ground point under the
    detector array's centre (on the ellipsoid at ``height_m``); the image covariance is
    ``J diag(east^2, north^2) J^T``.

    Parameters
    ----------
    model : SensorModel
        The (pre-corrected) scene model.
    east_m, north_m : float
        The reference's 1-sigma error along east and north, metres.
    band : str
        Band of ``model``.
    first_col : float
        The detector array's first column in the whole scene.
    n_detectors : int
        Its width, pixels.
    height_m : float
        Ellipsoidal height of the localization, metres.
    array : int or str, optional
        The detector array whose geometry maps the points (:meth:`SensorModel.image_to_ground`).

    Returns
    -------
    sigma_row_px, sigma_col_px : float
        Standard deviations along rows and columns, pixels (NaN where the model cannot localize).
    """
    from sensor_models.imaging.ground_shift import ground_shift_jacobian

    r0, c0 = model.image_shape[0] / 2.0, first_col + n_detectors / 2.0
    kw = {} if array is None else {"array": array}
    lon, lat, h = model.image_to_ground(np.array([r0]), np.array([c0]), height=height_m, band=band, **kw)
    px_per_ground = ground_shift_jacobian(model, lon, lat, h, band=band, **kw)[0]
    if not np.all(np.isfinite(px_per_ground)):
        return float("nan"), float("nan")
    cov = px_per_ground @ np.diag([east_m**2, north_m**2]) @ px_per_ground.T
    return float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
