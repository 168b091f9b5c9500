"""Fast first pass of the coarse stage: SIFT on coarser images, positions measured at full resolution.

OpenCV's SIFT doubles its input for its first octave (Lowe 2004, section 3.3), so most of its
time goes into the finest scales; averaged down ``FAST_REDUCTION`` (1.5) times, the warped scene
and the DOM cost about ``1 / 1.5^2`` (0.44) as much to build and fewer keypoints to describe.
Those keypoints are located less precisely and only find the correspondence; what the
pre-correction fits is measured at full (reduced-scene) resolution:

1. SIFT on both images averaged down ``FAST_REDUCTION`` times (the strongest
   ``FAST_FEATURE_BUDGET`` keypoints of the warped scene, the same density over the DOM's larger
   search window), ratio-test matches (FLANN, or exact on a torch device:
   :func:`gcpmatch.coarse_sift.ratio_pairs`) and a seeded affine RANSAC (threshold twice the
   stage's, in full-resolution pixels).
2. Around each ratio-test match, a ``REFINE_PATCH_PX`` square patch of the warped scene is
   resampled onto the DOM's pixels by the local map (the RANSAC map's linear part, translated to
   the match) and phase correlated with the DOM's patch (:func:`gcpmatch.phase.phase_correlate`,
   :func:`refine_at_full_resolution`): the match becomes the DOM patch's centre moved by the
   measured sub-pixel offset, and the scene point the local map sends there. These matches go
   through the stage's RANSAC again (its own threshold).
3. The pass is trusted (:func:`trusted`) when its consistent matches number 50 or more,
   outnumber what wrong matches give by chance, and pin the map at the corners of
   the part of the scene the DOM covers to a quarter of the fine stage's capture radius (3
   sigma); otherwise the caller runs the full-resolution search. The caller also asks that the
   pre-correction's kept matches reach every detector array with matches
   (:func:`spread_over_arrays`).

References
----------
Lowe, D. G. (2004). Distinctive image features from scale-invariant keypoints. IJCV 60(2).
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry, 2nd ed., section 5.2 (covariance of
a least-squares estimate).
Kuglin, C. D. & Hines, D. C. (1975). The phase correlation image alignment method. Proc. IEEE
Conference on Cybernetics and Society, 163-165.
"""

from __future__ import annotations

import cv2
import numpy as np

from gcpmatch.coarse_sift import MIN_FIRST_INLIERS, ratio_pairs, sift_features

__all__ = ["AFFINE_PARAMS", "FAST_FEATURE_BUDGET", "REFINE_PATCH_PX", "TRUST_FRACTION", "chance_inliers",
           "corner_sigma_px", "covered_corners", "fast_pass", "refine_at_full_resolution", "spread_over_arrays",
           "trusted"]

#: strongest keypoints of the warped scene in the half-resolution pass (the DOM gets the same
#: density over its search window)
FAST_FEATURE_BUDGET = 2500
#: the pass's images are the reduced ones averaged down this many times more
FAST_REDUCTION = 1.5
#: side of the full-resolution patches whose phase correlation measures each match, pixels
REFINE_PATCH_PX = 32
#: parameters of the affine map RANSAC fits
AFFINE_PARAMS = 6
#: the pass is trusted when the affine fit's 3-sigma error at the covered scene's corners is
#: below this fraction of the fine stage's capture radius
TRUST_FRACTION = 0.25


def _reduced(img: np.ndarray, mask: np.ndarray, k: float):
    """``img`` and ``mask`` averaged down ``k`` times (a pixel is usable when all it averages are)."""
    size = (max(1, int(round(img.shape[1] / k))), max(1, int(round(img.shape[0] / k))))
    small = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    small_mask = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.99
    return small, small_mask, (img.shape[1] / size[0], img.shape[0] / size[1])


def _half_features(img, mask, n_features):
    """SIFT of ``img`` averaged down ``FAST_REDUCTION`` times: keypoint (x, y) in ``img``'s pixels
    and descriptors."""
    small, small_mask, (kx, ky) = _reduced(img, mask, FAST_REDUCTION)
    kps, des = sift_features(small, small_mask, n_features)
    xy = np.float32([p.pt for p in kps]).reshape(-1, 2)
    # OpenCV pixel centres: x = k (x_small + 0.5) - 0.5
    return np.c_[kx * (xy[:, 0] + 0.5) - 0.5, ky * (xy[:, 1] + 0.5) - 0.5].astype(np.float32), des


def corner_sigma_px(ps: np.ndarray, pd: np.ndarray, corners_xy: np.ndarray) -> float:
    """Largest standard error of a least-squares affine map's prediction at ``corners_xy``.

    With the design matrix ``X`` (rows ``[x, y, 1]`` of the matches' scene positions) and the
    residual variance per axis ``s^2 = sum |r|^2 / (2 n - 6)``, the prediction at ``c = [x, y,
    1]`` has the standard error ``s sqrt(c^T (X^T X)^-1 c)`` on each axis (Hartley & Zisserman
    2004, 5.2): small when many matches surround the corner, large when they are few or bunched.

    Parameters
    ----------
    ps, pd : ndarray, shape (n, 2)
        Matches' (x, y) in the scene and the DOM, pixels.
    corners_xy : ndarray, shape (k, 2)
        Points where the map is predicted, pixels.

    Returns
    -------
    float
        Largest 1-sigma error over the points, pixels (inf when n <= 3 or the fit is degenerate).
    """
    n = len(ps)
    if n <= 3:
        return float("inf")
    x = np.c_[ps.astype(np.float64), np.ones(n)]
    coef, *_ = np.linalg.lstsq(x, pd.astype(np.float64), rcond=None)
    resid = pd - x @ coef
    s2 = float((resid ** 2).sum() / max(2 * n - 6, 1))
    try:
        cov = np.linalg.inv(x.T @ x)
    except np.linalg.LinAlgError:
        return float("inf")
    c = np.c_[corners_xy.astype(np.float64), np.ones(len(corners_xy))]
    lev = np.einsum("ij,jk,ik->i", c, cov, c)
    return float(np.sqrt(s2 * max(float(lev.max()), 0.0)))


def chance_inliers(n_matches: int, dom_area_px: float, ransac_px: float) -> float:
    """Inliers that wrong matches give by chance: each lands within ``ransac_px`` of the map with
    probability ``pi ransac_px^2 / dom_area_px`` (uniform over the searched DOM); the expected
    count plus five Poisson standard deviations."""
    lam = n_matches * np.pi * ransac_px ** 2 / max(dom_area_px, 1.0)
    return float(lam + 5.0 * np.sqrt(lam))


def trusted(ps, pd, n_matches: int, corners_xy, *, dom_area_px: float, ransac_px: float, capture_px: float) -> bool:
    """Whether a pass's consistent matches ``ps, pd`` can pre-correct without the full search.

    All three must hold: they number ``MIN_FIRST_INLIERS`` (50) or more, what the adaptive search
    asks of its first pass (:mod:`gcpmatch.coarse_sift`; on a 1536-line Sentinel-2 scene a pass
    with 17 was 1.8 px from the reference pre-correction); they exceed what ``n_matches`` wrong
    matches give by chance (:func:`chance_inliers`, plus RANSAC's
    sample of 3); and the least-squares affine map's 3-sigma error at ``corners_xy``
    (:func:`corner_sigma_px`) is below ``TRUST_FRACTION`` of ``capture_px``.

    Parameters
    ----------
    ps, pd : ndarray, shape (n, 2)
        Consistent matches in the warped scene and the DOM, pixels.
    n_matches : int
        Ratio-test matches RANSAC chose them from.
    corners_xy : ndarray, shape (4, 2)
        Corners of the part of the warped scene the DOM covers (:func:`covered_corners`), pixels.
    dom_area_px : float
        Valid area of the searched DOM, pixels^2.
    ransac_px : float
        RANSAC threshold of the ratio-test matches, pixels.
    capture_px : float
        The fine stage's capture radius in these pixels.
    """
    n_in = len(ps)
    if n_in < max(2 * AFFINE_PARAMS, MIN_FIRST_INLIERS):
        return False
    if n_in < 3 + chance_inliers(n_matches, dom_area_px, ransac_px):
        return False
    return 3.0 * corner_sigma_px(ps, pd, corners_xy) <= TRUST_FRACTION * capture_px


def covered_corners(warped_valid: np.ndarray, dom_valid: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """(4, 2) corners (x, y) of the bounding box of the warped scene's pixels that ``affine``
    (warped scene -> DOM) sends onto valid DOM pixels: where the fine stage can measure."""
    on_dom = cv2.warpAffine(dom_valid.astype(np.uint8), affine, (warped_valid.shape[1], warped_valid.shape[0]),
                            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
    rows, cols = np.nonzero((warped_valid > 0) & (on_dom > 0))
    if rows.size == 0:
        return np.zeros((4, 2))
    x0, x1, y0, y1 = cols.min(), cols.max(), rows.min(), rows.max()
    return np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]], dtype=np.float64)


def refine_at_full_resolution(warped, warped_valid, dom_u8, dom_valid, linear, ps, pd, *,
                              patch_px: int = REFINE_PATCH_PX):
    """Matches measured by phase correlation of full-resolution patches around matches ``ps, pd``.

    Each match's patch of the warped scene is resampled onto the DOM's pixels by the local map
    ``x -> linear (x - ps) + pd`` and phase correlated with the DOM's patch (same pixels, centred
    on the DOM pixel corner nearest ``pd``): the measured offset moves the DOM point.

    Parameters
    ----------
    warped, warped_valid : ndarray, shape (H, W)
        The warped scene (uint8) and its usable pixels.
    dom_u8, dom_valid : ndarray, shape (Hd, Wd)
        The reduced DOM (uint8) and its usable pixels.
    linear : ndarray, shape (2, 2)
        Linear part of the map warped scene (x, y) -> DOM (x, y).
    ps, pd : ndarray, shape (m, 2)
        Matches' (x, y) in the warped scene and the DOM (e.g. half-resolution keypoints).
    patch_px : int
        Patch side, pixels.

    Returns
    -------
    ps, pd : ndarray of float32, shape (k, 2)
        Warped-scene and DOM (x, y) of the matches with full data in both patches and a valid
        phase-correlation peak.
    """
    from gcpmatch.phase import phase_correlate

    hd, wd = dom_u8.shape
    half = patch_px // 2
    centres = np.round(pd).astype(np.int64)  # (x, y): the patch is rows [y - half, y + half)
    inside = ((centres[:, 0] >= half) & (centres[:, 0] <= wd - half)
              & (centres[:, 1] >= half) & (centres[:, 1] <= hd - half))
    refs, movs, scene_xy, centre_xy = [], [], [], []
    valid_u8 = warped_valid.astype(np.uint8)
    inverse = np.linalg.inv(linear)
    for k in np.flatnonzero(inside):
        x, y = centres[k]
        rows, cols = slice(y - half, y + half), slice(x - half, x + half)
        if not dom_valid[rows, cols].all():
            continue
        # scene -> patch pixels: the patch's pixel (0, 0) is DOM (x - half, y - half)
        m = np.c_[linear, pd[k] - linear @ ps[k] - np.array([x - half, y - half])]
        mov = cv2.warpAffine(warped, m, (patch_px, patch_px), flags=cv2.INTER_LINEAR)
        if not cv2.warpAffine(valid_u8, m, (patch_px, patch_px), flags=cv2.INTER_NEAREST).all():
            continue
        refs.append(dom_u8[rows, cols])
        movs.append(mov)
        centre = np.array([x - 0.5, y - 0.5])  # OpenCV coordinates of the patch centre
        scene_xy.append(inverse @ (centre - pd[k]) + ps[k])
        centre_xy.append(centre)
    if not refs:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    res = phase_correlate(np.stack(refs).astype(np.float32), np.stack(movs).astype(np.float32))
    valid = np.asarray(res.valid)
    shift = np.asarray(res.shift_px, dtype=np.float64)[valid]  # (d_row, d_col): the scene's content lies at DOM + shift
    dom_xy = np.asarray(centre_xy)[valid] - shift[:, ::-1]
    return np.asarray(scene_xy)[valid].astype(np.float32), dom_xy.astype(np.float32)


def fast_pass(warped, warped_valid, dom_u8, dom_valid, *, n_features, ransac_px, seed, capture_px, device=None):
    """The half-resolution pass (module docstring): its matches when trusted, else None.

    Parameters
    ----------
    warped, warped_valid : ndarray, shape (H, W)
        The reduced scene warped into the DOM's frame (uint8) and its usable pixels.
    dom_u8, dom_valid : ndarray, shape (Hd, Wd)
        The reduced DOM (uint8) and its usable pixels.
    n_features : int
        The stage's full feature budget (caps the pass's budgets).
    ransac_px : float
        The stage's RANSAC threshold, reduced pixels.
    seed : int
        Seed of FLANN's trees and RANSAC.
    capture_px : float
        The fine stage's capture radius in reduced pixels.
    device : str or None
        None: FLANN on the CPU; else the torch device of the exact matcher.

    Returns
    -------
    tuple or None
        ``(ps, pd, n_kp_s, n_kp_d, ransac_in)`` as :func:`gcpmatch.coarse_sift.sift_ransac`, or
        None when the pass is not trusted.
    """
    warped_valid = warped_valid > 0
    area_s, area_d = float(warped_valid.sum()), float(dom_valid.sum())
    budget = min(n_features, FAST_FEATURE_BUDGET)
    budget_dom = int(min(n_features, np.ceil(budget * area_d / max(area_s, 1.0))))
    xy_s, des_s = _half_features(warped, warped_valid, budget)
    xy_d, des_d = _half_features(dom_u8, dom_valid, budget_dom)
    if des_s is None or des_d is None or len(xy_s) < 8 or len(xy_d) < 8:
        return None
    query, train = ratio_pairs(des_s, des_d, seed=seed, device=device)
    if query.size < 8:
        return None
    cv2.setRNGSeed(seed)
    affine, mask = cv2.estimateAffine2D(xy_s[query], xy_d[train], method=cv2.RANSAC,
                                        ransacReprojThreshold=2.0 * ransac_px, maxIters=10000, confidence=0.999)
    if mask is None or mask.sum() < 2 * AFFINE_PARAMS:
        return None
    ps, pd = refine_at_full_resolution(warped, warped_valid, dom_u8, dom_valid, affine[:, :2], xy_s[query],
                                       xy_d[train])
    if len(ps) < 2 * AFFINE_PARAMS:
        return None
    cv2.setRNGSeed(seed)
    affine, mask = cv2.estimateAffine2D(ps, pd, method=cv2.RANSAC, ransacReprojThreshold=ransac_px,
                                        maxIters=10000, confidence=0.999)
    if mask is None:
        return None
    ransac_in = mask.ravel().astype(bool)
    corners = covered_corners(warped_valid, dom_valid, affine)
    if not trusted(ps[ransac_in], pd[ransac_in], int(query.size), corners, dom_area_px=area_d,
                   ransac_px=2.0 * ransac_px, capture_px=capture_px):
        return None
    return ps, pd, len(xy_s), len(xy_d), ransac_in


#: matches an array needs before :func:`gcpmatch.precorrect.fit_ccd_offsets` fits its offset and
#: scale (4 times its ``min_points``, 5)
SPREAD_MIN_POINTS = 20


def spread_over_arrays(model, band, kept_cols: np.ndarray, match_cols: np.ndarray) -> bool:
    """Whether a fast pass's matches let the pre-correction fit every detector array it could.

    :func:`gcpmatch.precorrect.fit_ccd_offsets` fits a CCD's offset and scale from
    ``SPREAD_MIN_POINTS`` matches spread over more than half of it; an array the kept matches
    miss keeps what the exterior fit extrapolates to it. Every array that holds that many
    ratio-test matches must keep that many, so spread. Models without detector arrays pass.

    Parameters
    ----------
    model : SensorModel
        The scene's model.
    band : str or None
        Its band.
    kept_cols, match_cols : ndarray, shape (n,) and (m,)
        Scene columns (continuous pixels) of the consistent matches and of all ratio-test
        matches inside the scene.

    Returns
    -------
    bool
        False when an array with matches is missed or covered over half its width or less.
    """
    if not any(g.startswith("interior.") for g in model.parameter_groups()):
        return True
    kept_ccd = model.detector_index(kept_cols, band=band)
    match_ccd = model.detector_index(match_cols, band=band)
    for i, look in enumerate(model.detector_arrays(band)):
        if (match_ccd == i).sum() < SPREAD_MIN_POINTS:
            continue
        on = kept_ccd == i
        if on.sum() < SPREAD_MIN_POINTS or np.ptp(kept_cols[on]) / max(look.n_detectors, 1) <= 0.5:
            return False
    return True
