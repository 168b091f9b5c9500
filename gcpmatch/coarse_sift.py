"""SIFT features of the coarse stage (:mod:`gcpmatch.coarse`, step 3).

Detection (OpenCV SIFT), ratio-test matching (FLANN's randomized k-d trees on the CPU; the exact
two nearest neighbours on a torch device, :mod:`gcpmatch._features_torch`) and the seeded affine
RANSAC, with the adaptive feature budget: the strongest ``FIRST_FEATURE_BUDGET`` keypoints of the
scene first, the full budget where RANSAC keeps fewer than ``MIN_FIRST_INLIERS``.
"""

from __future__ import annotations

import cv2
import numpy as np

from sensor_models.errors import GcpcalError

__all__ = ["FIRST_FEATURE_BUDGET", "FLANN_CHECKS", "FLANN_TREES", "MIN_FIRST_INLIERS", "CoarseMatchError",
           "ratio_pairs", "sift_features", "sift_ransac", "to_uint8"]


class CoarseMatchError(GcpcalError, RuntimeError):
    """The coarse stage found no consistent set of matches."""


def to_uint8(img: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Stretch the 1-99 % range of the valid pixels to 0..255 (invalid -> 0).

    Parameters
    ----------
    img : ndarray, shape (H, W)
        Image, any real dtype.
    valid : ndarray of bool, shape (H, W), optional
        Pixels to use and keep; default: the finite ones.

    Returns
    -------
    ndarray of uint8, shape (H, W)
        The stretched image, 0 where not valid (all 0 when nothing is valid).
    """
    valid = np.isfinite(img) if valid is None else valid
    if not valid.any():
        return np.zeros(img.shape, np.uint8)
    lo, hi = np.percentile(img[valid], [1.0, 99.0])
    out = (np.clip((img - lo) / max(hi - lo, 1e-6), 0.0, 1.0) * 255.0)
    return np.where(valid, out, 0.0).astype(np.uint8)


#: Scene keypoints of the first SIFT pass (the DOM keeps the full budget: its search window is
#: larger than the scene, and where clouds or bare ground leave the scene few features, the DOM's
#: strongest ones would lie elsewhere). Measured, one thread, CPU time of the coarse stage with
#: the brute-force matcher and 12 000 features against FLANN and this budget: realistic demo 2.72
#: -> 0.93 s (pre-correction against the TRUE model 2.37 px rms both), Pleiades tutorial pair
#: 1.42 -> 0.48 s (the two pre-corrections 0.69 px apart), a 60 %-cloud scene 0.23 -> 0.22 px
#: against the TRUE model.
FIRST_FEATURE_BUDGET = 4000


#: RANSAC inliers below which the first pass is not trusted and the full budget runs: an affine
#: map has 6 parameters, and the pre-correction then fits the exterior to the inliers in ground
#: space; 50 leaves it determined several times over where a few outliers survive RANSAC.
MIN_FIRST_INLIERS = 50


#: FLANN randomized k-d trees and leaves checked per query (OpenCV's FlannBasedMatcher).
FLANN_TREES = 4


FLANN_CHECKS = 64


def sift_features(img, mask, n_features):
    """OpenCV SIFT keypoints and descriptors of a uint8 image, the ``n_features`` strongest
    (``mask`` True where usable)."""
    return cv2.SIFT_create(nfeatures=n_features, contrastThreshold=0.01).detectAndCompute(
        img, mask.astype(np.uint8) * 255)


def _flann_ratio_pairs(des_a, des_b, *, seed: int = 0):
    """FLANN k-d tree two nearest neighbours with Lowe's ratio test (0.8): (query, train) indices.

    The trees are randomized by OpenCV's generator of the calling thread, seeded here, so the
    matches do not depend on what ran before in the process.
    """
    cv2.setRNGSeed(seed)
    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": FLANN_TREES}, {"checks": FLANN_CHECKS})
    return _lowe_pairs(matcher.knnMatch(des_a, des_b, k=2))


def _lowe_pairs(knn_pairs):
    """``(query, train)`` indices of OpenCV two-nearest-neighbour matches that pass Lowe's ratio test (0.8)."""
    good = [p[0] for p in knn_pairs if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
    return (np.array([m.queryIdx for m in good], dtype=np.intp), np.array([m.trainIdx for m in good], dtype=np.intp))


def ratio_pairs(des_a, des_b, *, seed: int = 0, device=None):
    """Ratio-test (0.8) pairs ``(query, train)`` of two descriptor sets: FLANN on the CPU (``device``
    None), exhaustive ``cv2.BFMatcher`` (L2; ``device`` ``"brute"``), else the exact two nearest
    neighbours on the torch ``device``."""
    if device is None:
        return _flann_ratio_pairs(des_a, des_b, seed=seed)
    if device == "brute":
        return _lowe_pairs(cv2.BFMatcher(cv2.NORM_L2).knnMatch(des_a, des_b, k=2))
    from gcpmatch._features_torch import ratio_test_pairs

    return ratio_test_pairs(des_a, des_b, ratio=0.8, device=device)


def _sift_matches_opencv(scene_features, dom_features, *, seed: int = 0, device=None):
    """Ratio-test matches of two images' SIFT features, the pairs of :func:`ratio_pairs` (FLANN on
    the CPU for ``device`` None, brute force for ``"brute"``, else exact on the torch ``device``).

    Returns
    -------
    pa, pb : ndarray of float32, shape (m, 2)
        Matched keypoint positions (x, y) in each image (OpenCV pixels).
    n_a, n_b : int
        Keypoints of each image.
    """
    (kp_a, des_a), (kp_b, des_b) = scene_features, dom_features
    if des_a is None or des_b is None or len(kp_a) < 2 or len(kp_b) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32), len(kp_a), len(kp_b)
    query, train = ratio_pairs(des_a, des_b, seed=seed, device=device)
    pa = np.float32([kp_a[i].pt for i in query]).reshape(-1, 2)
    pb = np.float32([kp_b[j].pt for j in train]).reshape(-1, 2)
    return pa, pb, len(kp_a), len(kp_b)


def sift_ransac(warped, warped_valid, dom_small, *, n_features, ransac_px, seed, backend, device,
                exhaustive: bool = False):
    """SIFT matches (ratio test) between the warped scene and the DOM, and their RANSAC inliers.

    Both backends adapt the feature budget (module docstring, step 3); ``backend`` other than
    ``"cpu"`` matches the descriptors on the torch ``device`` (None: CUDA if available).
    ``exhaustive``: the full budget in both images at once and brute-force matching
    (``cv2.BFMatcher``), whatever the backend: the reference search the faster ones are measured
    against (bench/bench_coarse.py).

    Returns
    -------
    ps, pd : ndarray of float32, shape (m, 2)
        Matched (x, y) positions in the warped scene and in the reduced DOM (OpenCV pixels).
    n_kp_s, n_kp_d : int
        Keypoints found in each image.
    ransac_in : ndarray of bool, shape (m,)
        Matches consistent with one affine map.
    """
    dom_valid = np.isfinite(dom_small)
    dom_u8 = to_uint8(dom_small, dom_valid)
    device = (device or "auto") if backend != "cpu" else None  # None: FLANN on the CPU
    dom_features = sift_features(dom_u8, dom_valid, n_features)  # the full budget in both passes
    if exhaustive:
        return _sift_ransac_opencv(sift_features(warped, warped_valid > 0, n_features), dom_features, ransac_px,
                                   seed, "brute")
    first = min(n_features, FIRST_FEATURE_BUDGET)
    if first < n_features:  # the full budget in the scene only where the first is not enough
        try:
            found = _sift_ransac_opencv(sift_features(warped, warped_valid > 0, first), dom_features,
                                        ransac_px, seed, device)
            if int(found[-1].sum()) >= MIN_FIRST_INLIERS:
                return found
        except CoarseMatchError:
            pass
    return _sift_ransac_opencv(sift_features(warped, warped_valid > 0, n_features), dom_features, ransac_px, seed,
                               device)


def _sift_ransac_opencv(scene_features, dom_features, ransac_px, seed, device=None):
    """Ratio matches of the scene's and the DOM's SIFT features (FLANN, or exact on a torch
    ``device``), seeded affine RANSAC."""
    ps, pd, n_kp_s, n_kp_d = _sift_matches_opencv(scene_features, dom_features, seed=seed, device=device)
    _check_matches(ps, n_kp_s, n_kp_d)
    cv2.setRNGSeed(seed)
    _, mask = cv2.estimateAffine2D(ps, pd, method=cv2.RANSAC, ransacReprojThreshold=ransac_px,
                                   maxIters=10000, confidence=0.999)
    ransac_in = np.zeros(len(ps), bool) if mask is None else mask.ravel().astype(bool)
    return ps, pd, n_kp_s, n_kp_d, _enough(ransac_in)


def _check_matches(ps, n_kp_s, n_kp_d) -> None:
    if n_kp_s < 8 or n_kp_d < 8:
        raise CoarseMatchError(f"too few SIFT keypoints (scene {n_kp_s}, DOM {n_kp_d}): no texture?")
    if len(ps) < 8:
        raise CoarseMatchError(f"only {len(ps)} SIFT matches pass the ratio test")


def _enough(ransac_in: np.ndarray) -> np.ndarray:
    if ransac_in.sum() < 6:
        raise CoarseMatchError("RANSAC found no consistent set of SIFT matches")
    return ransac_in
