"""Torch backend of the coarse stage's descriptor matching: exact two nearest neighbours, Lowe's ratio test.

Private adapter of :mod:`gcpmatch.coarse` (imported only when ``backend`` is ``"torch"`` or
``"gpu"``). The keypoints and descriptors stay OpenCV's SIFT (the same as the CPU path's), and so
does the affine RANSAC after the matching: only the brute-force search for each scene
descriptor's two nearest DOM descriptors runs on the device, as matrix products::

    d^2(i, j) = |a_i|^2 + |b_j|^2 - 2 a_i . b_j

OpenCV's SIFT descriptors hold integers in 0..255 (stored as float32), so every product and sum
above is an integer below ``128 x 255^2 < 2^24``: exact in float32 in any summation order, hence
the same squared distances as ``cv2.BFMatcher(cv2.NORM_L2)`` and the same ratio-test matches
(a tie for the nearest fails the test whichever index comes first). On CUDA the products run in
float64 (exact too, whatever the TF32 setting of float32 products); descriptors that are not
integers are matched in float64 on every device.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ratio_test_pairs"]

#: Scene descriptors per block of the distance matrix (a 4096 x 12000 block of float64 is 393 MB).
QUERY_BLOCK = 4096


def _torch():
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        from sensor_models.errors import InputError

        raise InputError(f"the torch backends need torch (pip install -e '.[gpu]'): {exc}") from None
    return torch


def ratio_test_pairs(des_a: np.ndarray, des_b: np.ndarray, *, ratio: float = 0.8, device=None):
    """Exact two nearest neighbours of each ``des_a`` row among ``des_b``'s, and Lowe's ratio test.

    Parameters
    ----------
    des_a, des_b : ndarray of float32, shape (n_a, 128) and (n_b, 128)
        SIFT descriptors (OpenCV's: integers in 0..255); ``n_b >= 2``.
    ratio : float
        A match is kept when ``d1 < ratio * d2`` (Euclidean distances to the nearest and the
        second nearest), i.e. ``d1^2 < ratio^2 d2^2``.
    device : str or torch.device, optional
        Torch device; None or ``"auto"``: CUDA when available, else the CPU.

    Returns
    -------
    query, train : ndarray of intp, shape (m,)
        Indices into ``des_a`` and ``des_b`` of the kept matches, in ``des_a`` order.
    """
    torch = _torch()
    if device in (None, "auto"):
        device = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(device)
    if device.type == "cuda" and not torch.cuda.is_available():
        from gcpmatch.options import require_cuda

        require_cuda()
    integral = bool(np.all(des_a == np.round(des_a)) and np.all(des_b == np.round(des_b)))
    dtype = torch.float32 if integral and device.type == "cpu" else torch.float64
    b = torch.as_tensor(np.ascontiguousarray(des_b), device=device).to(dtype)
    b_sq = (b * b).sum(dim=1)
    best, second, index = [], [], []
    with torch.inference_mode():
        for start in range(0, des_a.shape[0], QUERY_BLOCK):
            a = torch.as_tensor(np.ascontiguousarray(des_a[start:start + QUERY_BLOCK]), device=device).to(dtype)
            d2 = (a * a).sum(dim=1)[:, None] + b_sq[None, :] - 2.0 * (a @ b.T)
            values, idx = torch.topk(d2, 2, dim=1, largest=False, sorted=True)
            best.append(values[:, 0].cpu())
            second.append(values[:, 1].cpu())
            index.append(idx[:, 0].cpu())
    d1 = torch.cat(best).to(torch.float64).clamp_min(0.0).numpy()
    d2nd = torch.cat(second).to(torch.float64).clamp_min(0.0).numpy()
    nearest = torch.cat(index).numpy().astype(np.intp)
    keep = np.flatnonzero(d1 < (ratio * ratio) * d2nd)
    return keep.astype(np.intp), nearest[keep]
