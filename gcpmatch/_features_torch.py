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
integers are matched in float64 on every device. The two nearest neighbours and the ratio test
on those distances are kornia's (``kornia.feature.match_snn``, given the distance matrix); its
test keeps a ratio equal to the threshold, OpenCV's does not, so the threshold given to it is
the largest float below ``ratio``. Where kornia is not installed (a GPU machine carrying only
the wheels that fit its transfer limit: ``bench/gpu_wheels.sh``) the same two steps run in torch
(``topk`` and the ratio of the square roots), with the same matches.
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
    match_snn = _kornia_match_snn()
    below = float(np.nextafter(ratio, 0.0))  # kornia keeps ratio <= th; OpenCV's test is d1 < ratio d2
    query, train = [np.zeros(0, np.intp)], [np.zeros(0, np.intp)]
    with torch.inference_mode():
        for start in range(0, des_a.shape[0], QUERY_BLOCK):
            a = torch.as_tensor(np.ascontiguousarray(des_a[start:start + QUERY_BLOCK]), device=device).to(dtype)
            d2 = (a * a).sum(dim=1)[:, None] + b_sq[None, :] - 2.0 * (a @ b.T)
            # float64 distances: the square roots of exact integers, ordered as the squares are
            _, pairs = match_snn(a, b, th=below, dm=d2.to(torch.float64).clamp_min(0.0).sqrt())
            pairs = pairs.cpu().numpy().astype(np.intp).reshape(-1, 2)
            query.append(pairs[:, 0] + start)
            train.append(pairs[:, 1])
    query, train = np.concatenate(query), np.concatenate(train)
    order = np.argsort(query, kind="stable")
    return query[order], train[order]


def _kornia_match_snn():
    """``kornia.feature.match_snn``, or :func:`_match_snn_torch` where kornia is not installed."""
    try:
        from kornia.feature import match_snn
    except ImportError:
        return _match_snn_torch
    return match_snn


def _match_snn_torch(desc1, desc2, th: float, dm):
    """The nearest of ``dm``'s columns for each row, kept where its distance is at most ``th``
    times the second nearest's: ``(ratios (m, 1), index pairs (m, 2))`` as kornia's ``match_snn``."""
    torch = _torch()
    values, idx = torch.topk(dm, 2, dim=1, largest=False)
    ratio = values[:, 0] / values[:, 1]
    keep = ratio <= th
    rows = torch.arange(dm.shape[0], device=dm.device)[keep]
    return ratio[keep].view(-1, 1), torch.stack([rows, idx[:, 0][keep]], dim=1)
