"""Catalogue star patterns for lost-in-space identification: triangles hashed by side ratios.

:class:`StarPatternIndex` holds every triangle of the brightest catalogue stars whose sides fit
in a frame, keyed by its two scale-free side ratios, so that a triangle of detections finds its
catalogue candidates in a few hash bins (Liebe 1993 [1]_; the hashed-pattern lookup of tetra3
[2]_). :func:`gcpmatch.star_tracks.identify.identify_stars` turns each candidate into an attitude
hypothesis. Side lengths are angles between unit vectors (:func:`angle_between`).

References
----------
.. [1] C. C. Liebe, "Pattern recognition of star constellations for spacecraft applications",
   IEEE AES Magazine 8(1), 31-39 (1993) (angular-distance star patterns).
.. [2] G. Brown and ESA, tetra3 (lost-in-space solving by hashed star patterns, 2019).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sensor_models.errors import InputError

__all__ = ["StarPatternIndex", "angle_between"]


@dataclass(frozen=True, eq=False)
class StarPatternIndex:
    """Catalogue star triangles hashed by their side ratios.

    Each triangle of pattern stars whose sides are all below ``max_side_rad`` is stored with
    its vertices ordered ``(A, B, C)`` = opposite the (shortest, middle, longest) side, its
    ratios ``r1 = short / long`` and ``r2 = middle / long`` (scale free), its longest side and
    its handedness ``sign(det[A, B, C])``. Triangles are sorted by the hash
    ``floor(r1 / bin) * nbins + floor(r2 / bin)``; a query reads the 3 x 3 neighbouring bins.

    Attributes
    ----------
    catalog_index : ndarray of int, shape (P,)
        Row of each pattern star in the catalogue arrays given to :meth:`build`.
    vectors : ndarray, shape (P, 3)
        Their unit vectors.
    triangles : ndarray of int32, shape (T, 3)
        Pattern-star indices ``(A, B, C)``.
    ratios : ndarray of float32, shape (T, 2)
    long_side_rad : ndarray of float32, shape (T,)
    handedness : ndarray of int8, shape (T,)
    keys : ndarray of int64, shape (T,)
        Sorted hash keys.
    bin_width : float
    max_side_rad : float
    """

    catalog_index: np.ndarray
    vectors: np.ndarray
    triangles: np.ndarray
    ratios: np.ndarray
    long_side_rad: np.ndarray
    handedness: np.ndarray
    keys: np.ndarray
    bin_width: float
    max_side_rad: float

    @property
    def n_bins(self) -> int:
        """Hash bins per ratio axis (``ceil(1 / bin_width) + 2``)."""
        return int(np.ceil(1.0 / self.bin_width)) + 2

    @classmethod
    def build(cls, catalog_vectors, magnitudes, *, n_stars: int, max_side_deg: float,
              bin_width: float = 0.01) -> StarPatternIndex:
        """Index the triangles of the ``n_stars`` brightest catalogue stars.

        Parameters
        ----------
        catalog_vectors : array_like, shape (M, 3)
            Unit vectors (apparent directions at the date, or catalogue positions: a few
            arcseconds do not matter here).
        magnitudes : array_like, shape (M,)
            Brightness for the selection (smaller is brighter).
        n_stars : int
            Pattern stars: the brightest ``n_stars``.
        max_side_deg : float
            Longest triangle side kept (the frame's shorter angular side is a good choice).
        bin_width : float, optional
            Hash bin in ratio units; also the ratio tolerance of queries.

        Returns
        -------
        StarPatternIndex
        """
        vec = np.asarray(catalog_vectors, dtype=np.float64).reshape(-1, 3)
        mag = np.asarray(magnitudes, dtype=np.float64).reshape(-1)
        if mag.shape[0] != vec.shape[0]:
            raise InputError(f"{mag.shape[0]} magnitudes for {vec.shape[0]} vectors",
                             field="magnitudes")
        if not (0 < max_side_deg < 90):
            raise InputError("must lie in (0, 90) degrees", field="max_side_deg")
        if not (0 < bin_width < 0.2):
            raise InputError("must lie in (0, 0.2)", field="bin_width")
        order = np.argsort(mag, kind="stable")[:max(3, int(n_stars))]
        pv = vec[order]
        max_side = np.deg2rad(max_side_deg)
        chord = 2.0 * np.sin(max_side / 2.0)
        pairs = cKDTree(pv).query_pairs(chord, output_type="ndarray")  # i < j
        tri = _triangles_from_pairs(pairs, pv.shape[0])
        if tri.shape[0] == 0:
            raise InputError("no catalogue triangle fits: raise n_stars or max_side_deg")
        tri, ratios, long_side, hand = _triangle_shapes(pv, tri)
        keys = _hash_keys(ratios, bin_width)
        srt = np.argsort(keys, kind="stable")
        return cls(catalog_index=order, vectors=pv, triangles=tri[srt].astype(np.int32),
                   ratios=ratios[srt].astype(np.float32),
                   long_side_rad=long_side[srt].astype(np.float32),
                   handedness=hand[srt].astype(np.int8), keys=keys[srt],
                   bin_width=float(bin_width), max_side_rad=float(max_side))

    @classmethod
    def for_camera(cls, catalog_vectors, magnitudes, *, image_shape, focal_px: float,
                   stars_per_fov: float = 12.0, bin_width: float = 0.01) -> StarPatternIndex:
        """An index sized for a frame: ``stars_per_fov`` pattern stars per frame on average
        and triangles no longer than the frame's shorter angular side.

        Parameters
        ----------
        catalog_vectors : array_like, shape (M, 3)
            Catalogue unit vectors (GCRF).
        magnitudes : array_like, shape (M,)
            Brightness for the selection (smaller is brighter).
        image_shape : (int, int)
            ``(H, W)`` of the frame, pixels.
        focal_px : float
            Approximate focal length, pixels.
        stars_per_fov : float, optional
            Mean number of pattern stars in a frame.
        bin_width : float, optional
            See :meth:`build`.

        Returns
        -------
        StarPatternIndex
        """
        h, w = image_shape
        fov_h = 2 * np.arctan(h / (2 * focal_px))
        fov_w = 2 * np.arctan(w / (2 * focal_px))
        n_stars = int(round(stars_per_fov * 4 * np.pi / (fov_h * fov_w)))
        return cls.build(catalog_vectors, magnitudes, n_stars=n_stars,
                         max_side_deg=float(np.rad2deg(min(fov_h, fov_w))), bin_width=bin_width)

    def query(self, r1: float, r2: float, tolerance: float | None = None) -> np.ndarray:
        """Indices of triangles with both ratios within ``tolerance`` (default one bin).

        Parameters
        ----------
        r1, r2 : float
            Shortest / longest and middle / longest side ratios of the query triangle.
        tolerance : float, optional
            Largest difference of each ratio; default ``bin_width``.

        Returns
        -------
        ndarray of int, shape (K,)
            Rows of :attr:`triangles` (and of ``ratios``, ``long_side_rad``...).
        """
        tol = self.bin_width if tolerance is None else tolerance
        nb = self.n_bins
        i1, i2 = int(np.floor(r1 / self.bin_width)), int(np.floor(r2 / self.bin_width))
        k = ((i1 + np.array([-1, 0, 1]))[:, None] * nb + (i2 + np.array([-1, 0, 1]))).ravel()
        lo = np.searchsorted(self.keys, k, "left")
        hi = np.searchsorted(self.keys, k, "right")
        idx = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi) if b > a] or
                             [np.zeros(0, np.intp)])
        if idx.size:
            d = np.abs(self.ratios[idx] - np.array([r1, r2], np.float32))
            idx = idx[(d[:, 0] <= tol) & (d[:, 1] <= tol)]
        return idx


def _triangles_from_pairs(pairs: np.ndarray, n: int) -> np.ndarray:
    """All ``(i, j, k)``, ``i < j < k``, whose three pairs are in ``pairs`` (i < j rows)."""
    if pairs.shape[0] == 0:
        return np.zeros((0, 3), np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    edge_key = pairs[:, 0].astype(np.int64) * n + pairs[:, 1]
    start = np.searchsorted(pairs[:, 0], np.arange(n + 1))
    deg = np.diff(start)
    # wedges (i; j, k) with j < k both upper neighbours of i
    n_wedge = deg * (deg - 1) // 2
    owner = np.repeat(np.arange(n), n_wedge)
    if owner.size == 0:
        return np.zeros((0, 3), np.int64)
    first = np.repeat(np.cumsum(n_wedge) - n_wedge, n_wedge)
    local = np.arange(owner.size) - first
    d = deg[owner]
    # unrank local -> (a, b), a < b < d: row a holds d - 1 - a pairs
    a = (d - 0.5 - np.sqrt((d - 0.5) ** 2 - 2.0 * local)).astype(np.int64)
    a = np.clip(a, 0, None)
    before = a * (2 * d - a - 1) // 2
    fix = before > local
    while np.any(fix):
        a[fix] -= 1
        before = a * (2 * d - a - 1) // 2
        fix = before > local
    over = (before + (d - 1 - a)) <= local
    while np.any(over):
        a[over] += 1
        before = a * (2 * d - a - 1) // 2
        over = (before + (d - 1 - a)) <= local
    b = a + 1 + (local - before)
    j = pairs[start[owner] + a, 1]
    k = pairs[start[owner] + b, 1]
    closing = j.astype(np.int64) * n + k
    pos = np.searchsorted(edge_key, closing)
    pos = np.minimum(pos, edge_key.size - 1)
    hit = edge_key[pos] == closing
    return np.stack([owner[hit], j[hit], k[hit]], axis=1).astype(np.int64)


def _triangle_shapes(vectors: np.ndarray, tri: np.ndarray):
    """Reorder triangles (A, B, C) by opposite side and compute ratios, long side, handedness.

    ``vectors``: (P, 3) unit vectors; ``tri``: (T, 3) indices. Sides are angles.
    """
    v = vectors[tri]  # (T, 3, 3)
    # side opposite vertex m joins the two others
    opp = np.stack([angle_between(v[:, 1], v[:, 2]), angle_between(v[:, 0], v[:, 2]),
                    angle_between(v[:, 0], v[:, 1])], axis=1)
    order = np.argsort(opp, axis=1, kind="stable")
    tri = np.take_along_axis(tri, order, axis=1)
    sides = np.take_along_axis(opp, order, axis=1)
    v = vectors[tri]
    ratios = sides[:, :2] / sides[:, 2:3]
    hand = np.sign(np.einsum("ti,ti->t", v[:, 0], np.cross(v[:, 1], v[:, 2])))
    return tri, ratios, sides[:, 2], hand


def angle_between(a, b):
    """Angle between unit vectors along the last axis (stable for small angles).

    Parameters
    ----------
    a, b : ndarray, shape (..., 3)
        Unit vectors.

    Returns
    -------
    ndarray, shape (...)
        ``2 arcsin(|a - b| / 2)``, radians.
    """
    return 2.0 * np.arcsin(np.clip(np.linalg.norm(a - b, axis=-1) / 2.0, 0.0, 1.0))


def _hash_keys(ratios, bin_width):
    nb = int(np.ceil(1.0 / bin_width)) + 2
    i = np.floor(ratios / bin_width).astype(np.int64)
    return i[..., 0] * nb + i[..., 1]
