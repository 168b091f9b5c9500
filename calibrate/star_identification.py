"""Catalogue stars predicted in every frame and matched to the detections (seed 000 steps 2-3).

:func:`predict_catalog` projects the catalogue stars' apparent directions at each frame instant
(:func:`sensor_models.geometry.star_catalogue.apparent_directions`, with the satellite's GCRF
position and velocity) through that frame's approximate (LAB) model;
:func:`identify` matches detections to predictions: a global offset vote over every
(detection - prediction) pair closer than ``search_px`` in all frames (the LAB model's error is
the same in every frame: tens of pixels), then mutual nearest neighbours within
``tolerance_px`` after that offset. The pipeline that uses them is
:func:`calibrate.star_calibration.process_frames`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["identify", "predict_catalog"]


@dataclass
class _Predictions:
    """Catalogue stars predicted by the approximate model, all frames stacked (M,)."""

    frame: np.ndarray
    star: np.ndarray  # catalogue row
    vectors_gcrf: np.ndarray  # (M, 3) apparent directions at the frame instant
    row: np.ndarray
    col: np.ndarray


def predict_catalog(models, catalog, *, margin_px: float = 60.0) -> _Predictions:
    """Apparent catalogue stars inside (or within ``margin_px`` of) every frame's model.

    Parameters
    ----------
    models : sequence of GeoStaringModel
        The model of every frame (``lab_model.at_frame(t_k)``).
    catalog : StarCatalog
        Loaded catalogue.
    margin_px : float
        Stars projected up to this far outside a frame are kept, pixels.

    Returns
    -------
    _Predictions
        All frames stacked (M,): frame index, catalogue row, apparent GCRF direction (M, 3)
        at the frame instant and the projected ``row, col`` in pixels.
    """
    from sensor_models.geometry.star_catalogue import catalog_stars_in_frame

    unit = catalog.unit_vectors()
    parts = []
    for k, m in enumerate(models):
        idx, vec, row, col = catalog_stars_in_frame(m, catalog, unit, margin_px)
        parts.append((np.full(idx.size, k), idx, vec, row, col))
    cat = [np.concatenate([p[i] for p in parts]) if parts else np.zeros(0) for i in range(5)]
    return _Predictions(cat[0].astype(np.intp), cat[1].astype(np.intp), cat[2].reshape(-1, 3), cat[3], cat[4])


def identify(detections, pred: _Predictions, *, search_px: float = 120.0, tolerance_px: float = 4.0,
             bin_px: float = 2.0):
    """Match detections to predicted catalogue stars (global offset vote, then nearest neighbours).

    Parameters
    ----------
    detections : sequence of StarTable
        Detections per frame (``row_px, col_px``).
    pred : _Predictions
        Of :func:`predict_catalog`.
    search_px : float
        Largest detection-minus-prediction distance voted on, pixels.
    tolerance_px : float
        Largest distance of a match after the voted offset, pixels.
    bin_px : float
        Bin of the offset vote, pixels.

    Returns
    -------
    pairs : ndarray of int, shape (K, 3)
        ``(frame, detection index, prediction index)``.
    offset_px : ndarray, shape (2,)
        The voted (row, col) offset, detection minus prediction.
    """
    diffs = []
    for k, tab in enumerate(detections):
        sel = np.flatnonzero(pred.frame == k)
        if len(tab) == 0 or sel.size == 0:
            continue
        d = tab.rowcol[:, None, :] - np.stack([pred.row[sel], pred.col[sel]], -1)[None, :, :]
        d = d.reshape(-1, 2)
        diffs.append(d[np.all(np.abs(d) < search_px, axis=1)])
    diffs = np.concatenate(diffs) if diffs else np.zeros((0, 2))
    if diffs.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.intp), np.full(2, np.nan)
    edges = np.arange(-search_px, search_px + bin_px, bin_px)
    hist, _, _ = np.histogram2d(diffs[:, 0], diffs[:, 1], bins=(edges, edges))
    # 2x2 box sum: a peak split across bin edges still wins
    box = hist[:-1, :-1] + hist[1:, :-1] + hist[:-1, 1:] + hist[1:, 1:]
    i, j = np.unravel_index(np.argmax(box), box.shape)
    peak = np.array([edges[i + 1], edges[j + 1]])
    near = np.all(np.abs(diffs - peak) < 2.0 * bin_px, axis=1)
    offset = np.median(diffs[near], axis=0)
    pairs = []
    for k, tab in enumerate(detections):
        sel = np.flatnonzero(pred.frame == k)
        if len(tab) == 0 or sel.size == 0:
            continue
        p = np.stack([pred.row[sel], pred.col[sel]], -1) + offset
        det_tree, pred_tree = cKDTree(tab.rowcol), cKDTree(p)
        dist, di = det_tree.query(p, distance_upper_bound=tolerance_px)
        _, back = pred_tree.query(tab.rowcol)
        ok = np.flatnonzero(np.isfinite(dist))
        ok = ok[back[di[ok]] == ok]  # mutual nearest neighbours
        pairs.append(np.stack([np.full(ok.size, k), di[ok], sel[ok]], -1))
    pairs = np.concatenate(pairs) if pairs else np.zeros((0, 3), dtype=np.intp)
    return pairs.astype(np.intp), offset
