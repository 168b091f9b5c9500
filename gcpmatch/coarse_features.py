"""Coarse stage's feature matching: SIFT, a nearest-neighbour matcher, affine RANSAC, a trust test.

The feature budget adapts to the scene. A first pass runs SIFT on both images (averaged down a
further ``FIRST_PASS_REDUCTION`` times, 1: not at all) and keeps the strongest
``FIRST_FEATURE_BUDGET`` keypoints of the warped scene and the same density in the DOM over its
larger search window (the budget times the ratio of the two images' valid areas). The first pass
is accepted when its RANSAC set passes :func:`trusted` (enough inliers, more than chance gives,
the affine fit's own uncertainty at the corners of the part of the scene the DOM covers well
inside the fine stage's capture radius) and the caller's own test of what it makes of them (the
coarse stage asks for kept matches spread over every detector array that holds matches);
otherwise :func:`full_pass` runs the full budget at full resolution in both images: the features
a fixed-budget stage would use.

Matching is Lowe's ratio test (0.8) on the two nearest neighbours, found by FLANN's randomized
k-d trees (Muja & Lowe 2009, ``"flann"``, the default) or exhaustively (``"brute"``).

References
----------
Lowe, D. G. (2004). Distinctive image features from scale-invariant keypoints. IJCV 60(2).
Muja, M. & Lowe, D. G. (2009). Fast approximate nearest neighbors with automatic algorithm
configuration. VISAPP.
Hartley, R. & Zisserman, A. (2004). Multiple View Geometry, 2nd ed., section 5.2 (covariance of
a least-squares estimate).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sensor_models.errors import GcpcalError

__all__ = ["FIRST_FEATURE_BUDGET", "MATCHERS", "CoarseMatchError", "FeatureMatches", "first_pass", "full_pass",
           "trusted"]

#: nearest-neighbour matchers of the coarse stage
MATCHERS = ("flann", "brute")
#: scene keypoints of the first pass (the DOM gets the same density over its search window)
FIRST_FEATURE_BUDGET = 2000
#: the first pass's images are the reduced ones averaged down this many times more. 2 makes the
#: pass's SIFT about 4 times cheaper (OpenCV's SIFT doubles its input for its first octave) but
#: its pre-correction less consistent on real stereo texture: on the Pleiades pair the 60-line bias
#: came back from the two runs' GCP medians as 59.49 lines against 60.12 with 1 (and 60.06 with
#: the full budget), and the tutorials' GCP counts moved by 1.4 and 1.8 % against 0.3 and 0.2 %
FIRST_PASS_REDUCTION = 1
#: FLANN randomized k-d trees and leaves checked per query (OpenCV's FlannBasedMatcher)
FLANN_TREES, FLANN_CHECKS = 4, 64
#: Lowe's ratio test threshold
RATIO = 0.8
#: parameters of the affine map RANSAC fits; a first pass needs its inliers to determine it
#: twice over before its corner uncertainty is taken as meaningful
AFFINE_PARAMS = 6
#: a first pass is trusted when the affine fit's 3-sigma error at the scene's corners is below
#: this fraction of the fine stage's capture radius
TRUST_FRACTION = 0.25


class CoarseMatchError(GcpcalError, RuntimeError):
    """The coarse stage found no consistent set of matches."""


@dataclass
class FeatureMatches:
    """Ratio-test matches of one pass and their RANSAC inliers.

    Attributes
    ----------
    ps, pd : ndarray of float32, shape (m, 2)
        Matched (x, y) positions in the warped scene and in the reduced DOM (OpenCV pixels).
    n_kp_s, n_kp_d : int
        Keypoints described in each image.
    inlier : ndarray of bool, shape (m,)
        Matches consistent with the RANSAC affine map.
    affine : ndarray, shape (2, 3)
        The RANSAC map, warped scene (x, y) -> DOM (x, y).
    passes : int
        1: the first pass was trusted; 2: the full budget ran after it.
    """

    ps: np.ndarray
    pd: np.ndarray
    n_kp_s: int
    n_kp_d: int
    inlier: np.ndarray
    affine: np.ndarray
    passes: int = 1


def sift_features(img: np.ndarray, mask: np.ndarray, n_features: int):
    """OpenCV SIFT keypoints and descriptors of a uint8 image, the ``n_features`` strongest.

    Parameters
    ----------
    img : ndarray of uint8, shape (H, W)
    mask : ndarray of bool, shape (H, W)
        True where usable.
    n_features : int
        Keypoints kept (by DoG response), >= 1.

    Returns
    -------
    keypoints : tuple of cv2.KeyPoint
    descriptors : ndarray of float32, shape (n, 128), or None
    """
    return cv2.SIFT_create(nfeatures=int(n_features), contrastThreshold=0.01).detectAndCompute(
        img, mask.astype(np.uint8) * 255)


def sift_features_reduced(img: np.ndarray, mask: np.ndarray, n_features: int, k: int):
    """:func:`sift_features` of ``img`` averaged down ``k`` times, keypoints in ``img``'s pixels.

    A pixel is usable when every pixel it averages is; positions map back as
    ``x = k (x_k + 0.5) - 0.5`` (OpenCV pixel centres), sizes scale by ``k``.
    """
    if k == 1:
        return sift_features(img, mask, n_features)
    h, w = img.shape[0] // k, img.shape[1] // k
    small = cv2.resize(img[:h * k, :w * k], (w, h), interpolation=cv2.INTER_AREA)
    small_mask = cv2.resize(mask[:h * k, :w * k].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0.99
    kps, des = sift_features(small, small_mask, n_features)
    kps = tuple(cv2.KeyPoint(k * (p.pt[0] + 0.5) - 0.5, k * (p.pt[1] + 0.5) - 0.5, p.size * k, p.angle, p.response,
                             p.octave, p.class_id) for p in kps)
    return kps, des


def ratio_matches(scene_features, dom_features, *, matcher: str = "flann", seed: int = 0):
    """Two nearest DOM descriptors of each scene descriptor and Lowe's ratio test.

    FLANN's trees are randomized by OpenCV's generator of the calling thread, seeded here, so the
    matches do not depend on what ran before in the process or on the thread count.

    Returns
    -------
    ps, pd : ndarray of float32, shape (m, 2)
        (x, y) of the matches in the scene and the DOM.
    """
    (kp_a, des_a), (kp_b, des_b) = scene_features, dom_features
    if des_a is None or des_b is None or len(kp_a) < 2 or len(kp_b) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    if matcher == "brute":
        knn = cv2.BFMatcher(cv2.NORM_L2)
    elif matcher == "flann":
        cv2.setRNGSeed(seed)
        knn = cv2.FlannBasedMatcher({"algorithm": 1, "trees": FLANN_TREES}, {"checks": FLANN_CHECKS})
    else:
        raise ValueError(f"matcher must be one of {', '.join(MATCHERS)}, got {matcher!r}")
    pairs = knn.knnMatch(des_a, des_b, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < RATIO * p[1].distance]
    pa = np.float32([kp_a[m.queryIdx].pt for m in good]).reshape(-1, 2)
    pb = np.float32([kp_b[m.trainIdx].pt for m in good]).reshape(-1, 2)
    return pa, pb


def _ransac(ps, pd, n_kp_s, n_kp_d, *, ransac_px, seed, passes) -> FeatureMatches:
    """Seeded affine RANSAC of the matches; errors when too few keypoints, matches or inliers."""
    if n_kp_s < 8 or n_kp_d < 8:
        raise CoarseMatchError(f"too few SIFT keypoints (scene {n_kp_s}, DOM {n_kp_d}): no texture?")
    if len(ps) < 8:
        raise CoarseMatchError(f"only {len(ps)} SIFT matches pass the ratio test")
    cv2.setRNGSeed(seed)
    affine, mask = cv2.estimateAffine2D(ps, pd, method=cv2.RANSAC, ransacReprojThreshold=ransac_px,
                                        maxIters=10000, confidence=0.999)
    inlier = np.zeros(len(ps), bool) if mask is None else mask.ravel().astype(bool)
    if inlier.sum() < 6:
        raise CoarseMatchError("RANSAC found no consistent set of SIFT matches")
    return FeatureMatches(ps, pd, n_kp_s, n_kp_d, inlier, affine, passes)


def corner_sigma_px(ps: np.ndarray, pd: np.ndarray, corners_xy: np.ndarray) -> float:
    """Largest standard error of a least-squares affine map's prediction at ``corners_xy``.

    With the design matrix ``X`` (rows ``[x, y, 1]`` of the inliers' scene positions) and the
    residual variance per axis ``s^2 = sum |r|^2 / (2 n - 6)``, the prediction at ``c = [x, y,
    1]`` has the standard error ``s sqrt(c^T (X^T X)^-1 c)`` on each axis (Hartley & Zisserman
    2004, 5.2): small when many inliers surround the corner, large when they are few or bunched.

    Parameters
    ----------
    ps, pd : ndarray, shape (n, 2)
        Inliers' (x, y) in the scene and the DOM, pixels; n > 3.
    corners_xy : ndarray, shape (k, 2)
        Points where the map is predicted (the scene's corners), pixels.

    Returns
    -------
    float
        Largest 1-sigma error over the corners, pixels (inf when the fit is degenerate).
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


def trusted(found: FeatureMatches, corners_xy: np.ndarray, *, dom_area_px: float, ransac_px: float,
            capture_px: float) -> bool:
    """Whether a pass's RANSAC set is good enough to pre-correct from without more features.

    All three must hold: the inliers determine the affine map at least twice over
    (``2 * AFFINE_PARAMS``); they exceed what wrong matches give by chance
    (:func:`chance_inliers` plus the 3 of RANSAC's sample); and the affine fit's 3-sigma error
    at the scene's corners (:func:`corner_sigma_px`) is below ``TRUST_FRACTION`` of
    ``capture_px``.

    Parameters
    ----------
    found : FeatureMatches
    corners_xy : ndarray, shape (4, 2)
        Corners of the part of the warped scene that the DOM covers (:func:`covered_corners`),
        pixels.
    dom_area_px : float
        Valid area of the searched DOM, pixels^2.
    ransac_px : float
        RANSAC threshold, pixels.
    capture_px : float
        Capture radius of the fine stage in these (reduced) pixels.
    """
    n_in = int(found.inlier.sum())
    if n_in < 2 * AFFINE_PARAMS or n_in < 3 + chance_inliers(len(found.ps), dom_area_px, ransac_px):
        return False
    sigma = corner_sigma_px(found.ps[found.inlier], found.pd[found.inlier], corners_xy)
    return 3.0 * sigma <= TRUST_FRACTION * capture_px


def covered_corners(warped_valid: np.ndarray, dom_valid: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """(4, 2) corners (x, y) of the bounding box of the warped scene's pixels that ``affine``
    (warped scene -> DOM) sends onto valid DOM pixels: where the fine stage can measure."""
    on_dom = cv2.warpAffine(dom_valid.astype(np.uint8), affine, (warped_valid.shape[1], warped_valid.shape[0]),
                            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
    rows, cols = np.nonzero(warped_valid & (on_dom > 0))
    if rows.size == 0:
        return np.zeros((4, 2))
    x0, x1, y0, y1 = cols.min(), cols.max(), rows.min(), rows.max()
    return np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]], dtype=np.float64)


def first_pass(warped, warped_valid, dom_u8, dom_valid, *, n_features, ransac_px, seed, capture_px,
               matcher: str = "flann") -> FeatureMatches | None:
    """The first pass (module docstring): its matches when :func:`trusted`, else None.

    Parameters are those of :func:`full_pass`, plus ``capture_px``, the fine stage's capture
    radius in reduced pixels.
    """
    k = FIRST_PASS_REDUCTION
    area_s, area_d = float(warped_valid.sum()), float(dom_valid.sum())
    first_dom = int(min(n_features, np.ceil(FIRST_FEATURE_BUDGET * area_d / max(area_s, 1.0))))
    scene_f = sift_features_reduced(warped, warped_valid, min(n_features, FIRST_FEATURE_BUDGET), k)
    dom_f = sift_features_reduced(dom_u8, dom_valid, first_dom, k)
    ps, pd = ratio_matches(scene_f, dom_f, matcher=matcher, seed=seed)
    try:  # keypoints found k times coarser: their positions k times noisier
        found = _ransac(ps, pd, len(scene_f[0]), len(dom_f[0]), ransac_px=k * ransac_px, seed=seed, passes=1)
    except CoarseMatchError:
        return None
    corners = covered_corners(warped_valid, dom_valid, found.affine)
    return found if trusted(found, corners, dom_area_px=area_d, ransac_px=k * ransac_px,
                            capture_px=capture_px) else None


def full_pass(warped: np.ndarray, warped_valid: np.ndarray, dom_u8: np.ndarray, dom_valid: np.ndarray, *,
              n_features: int, ransac_px: float, seed: int, matcher: str = "flann", passes: int = 1) -> FeatureMatches:
    """SIFT ratio matches at full resolution, ``n_features`` per image, and their RANSAC inliers.

    Parameters
    ----------
    warped, dom_u8 : ndarray of uint8, shape (H, W) and (Hd, Wd)
        The reduced scene warped into the DOM's frame, and the reduced DOM.
    warped_valid, dom_valid : ndarray of bool, same shapes
        Their usable pixels.
    n_features : int
        Most keypoints per image.
    ransac_px : float
        RANSAC threshold, reduced pixels.
    seed : int
        Seed of FLANN's trees and RANSAC.
    matcher : {"flann", "brute"}
        Nearest-neighbour search.
    passes : int
        Passes run with this one (stored in the result).

    Returns
    -------
    FeatureMatches

    Raises
    ------
    CoarseMatchError
        Too few keypoints, ratio matches or RANSAC inliers.
    """
    if matcher not in MATCHERS:
        raise ValueError(f"matcher must be one of {', '.join(MATCHERS)}, got {matcher!r}")
    scene_f = sift_features(warped, warped_valid, n_features)
    dom_f = sift_features(dom_u8, dom_valid, n_features)
    ps, pd = ratio_matches(scene_f, dom_f, matcher=matcher, seed=seed)
    return _ransac(ps, pd, len(scene_f[0]), len(dom_f[0]), ransac_px=ransac_px, seed=seed, passes=passes)
