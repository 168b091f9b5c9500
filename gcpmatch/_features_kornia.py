"""Kornia backend of the coarse stage: weight-free SIFT, ratio-test matching, RANSAC (torch).

Private adapter (imported only when ``backend`` is ``"torch"`` or ``"gpu"``): the same steps as
the OpenCV path of :mod:`gcpmatch.coarse` (SIFT keypoints and descriptors, Lowe's ratio test at
0.8, RANSAC), on a torch device. Coordinates follow OpenCV's pixel convention (the centre of
pixel ``[0, 0]`` at ``(0, 0)``, ``(x, y)`` = (column, row)), as ``kornia.feature.get_laf_center``
returns them. RANSAC fits a homography (kornia has no affine model), with a fixed seed.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ransac_inliers", "sift_matches"]


def _torch():
    try:
        import kornia.feature as KF
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        from sensor_models.errors import InputError

        raise InputError(f"the gpu backend needs torch and kornia (pip install -e '.[gpu]'): {exc}") from None
    return torch, KF


def _device(torch, device):
    if device in (None, "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(device)
    if device.type == "cuda" and not torch.cuda.is_available():
        from gcpmatch.options import require_cuda

        require_cuda()
    return device


def sift_matches(img_a: np.ndarray, mask_a: np.ndarray, img_b: np.ndarray, mask_b: np.ndarray, *,
                 n_features: int = 8000, ratio: float = 0.8, device=None):
    """SIFT keypoints of two uint8 images and their ratio-test matches.

    Parameters
    ----------
    img_a, img_b : ndarray of uint8, shape (H_a, W_a) and (H_b, W_b)
        The two images.
    mask_a, mask_b : ndarray of bool, same shapes
        True where keypoints may be detected.
    n_features : int
        Most keypoints kept per image.
    ratio : float
        Lowe's ratio-test threshold (distance to the best over the second-best descriptor).
    device : str or torch.device, optional
        Torch device; None or ``"auto"``: CUDA when available, else the CPU.

    Returns
    -------
    pts_a, pts_b : ndarray (M, 2) float32
        Matched keypoint centres ``(x, y)`` in each image.
    n_a, n_b : int
        Keypoints detected in each image.
    """
    torch, KF = _torch()
    dev = _device(torch, device)
    sift = KF.SIFTFeature(num_features=n_features, upright=False, device=dev)

    def detect(img, mask):
        t = torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32) / 255.0)[None, None].to(dev)
        m = torch.from_numpy(np.ascontiguousarray(mask, dtype=np.float32))[None, None].to(dev)
        with torch.inference_mode():
            lafs, responses, descs = sift(t, m)
        keep = responses[0] > 0
        centres = KF.get_laf_center(lafs)[0][keep]
        return centres, descs[0][keep]

    ca, da = detect(img_a, mask_a)
    cb, db = detect(img_b, mask_b)
    if da.shape[0] < 2 or db.shape[0] < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32), int(da.shape[0]), int(db.shape[0])
    with torch.inference_mode():
        _, idx = KF.match_snn(da, db, th=ratio)
    pa = ca[idx[:, 0]].cpu().numpy().astype(np.float32)
    pb = cb[idx[:, 1]].cpu().numpy().astype(np.float32)
    return pa, pb, int(da.shape[0]), int(db.shape[0])


def ransac_inliers(pts_a: np.ndarray, pts_b: np.ndarray, *, threshold_px: float, seed: int = 0, device=None) -> np.ndarray:
    """Inlier flags of a homography RANSAC between matched points.

    Parameters
    ----------
    pts_a, pts_b : ndarray of float32, shape (M, 2)
        Matched ``(x, y)`` positions, OpenCV pixel convention (centre of pixel [0, 0] at (0, 0)).
    threshold_px : float
        Inlier threshold, pixels.
    seed : int
        Seed of the random draws.
    device : str or torch.device, optional
        Torch device; None or ``"auto"``: CUDA when available, else the CPU.

    Returns
    -------
    ndarray of bool, shape (M,)
        True for inliers (all False with fewer than 8 matches).
    """
    torch, _ = _torch()
    from kornia.geometry.ransac import RANSAC

    if len(pts_a) < 8:
        return np.zeros(len(pts_a), bool)
    dev = _device(torch, device)
    torch.manual_seed(seed)
    ransac = RANSAC(model_type="homography", inl_th=threshold_px, max_iter=50, confidence=0.999, seed=seed)
    with torch.inference_mode():
        _, inliers = ransac(torch.from_numpy(pts_a).to(dev), torch.from_numpy(pts_b).to(dev))
    return inliers.cpu().numpy().astype(bool).reshape(-1)
