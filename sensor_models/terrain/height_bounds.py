"""Conservative height bounds of a DEM grid for ray marching: a min/max pyramid, float32 bounds.

:class:`RangePyramid` holds the extrema of the node heights over blocks of ``2**l`` cells, all
levels ``l``; :func:`float32_bound` stores bounds in float32 rounded outwards, so that they
still bound the float64 heights with half the memory.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RangePyramid", "float32_bound"]


class RangePyramid:
    """Minima and maxima of a node grid over square blocks of 2**l x 2**l cells, all levels l.

    Block ``(J, I)`` of level ``l`` spans the nodes ``J 2^l .. (J + 1) 2^l`` by
    ``I 2^l .. (I + 1) 2^l`` (inclusive: neighbouring blocks share their edge nodes), so its
    range bounds the bilinear surface over its cells. Nodes without data count as ``+inf`` in
    the maxima and ``-inf`` in the minima (no bound there).
    """

    def __init__(self, z):
        valid = np.isfinite(z)
        self._n_cells = (z.shape[0] - 1, z.shape[1] - 1)
        flats = []
        for reduce, fill in ((np.maximum, np.inf), (np.minimum, -np.inf)):
            zz = np.where(valid, z, fill)
            level = reduce(reduce(zz[:-1, :-1], zz[:-1, 1:]), reduce(zz[1:, :-1], zz[1:, 1:]))
            blocks, offsets, widths, offset = [], [], [], 0
            while True:
                blocks.append(level.reshape(-1))
                offsets.append(offset)
                widths.append(level.shape[1])
                offset += level.size
                if max(level.shape) == 1:
                    break
                rows, cols = level.shape
                padded = np.full((rows + rows % 2, cols + cols % 2), -fill)
                padded[:rows, :cols] = level
                level = reduce(reduce(padded[0::2, 0::2], padded[0::2, 1::2]),
                               reduce(padded[1::2, 0::2], padded[1::2, 1::2]))
            flats.append(float32_bound(np.concatenate(blocks), upper=reduce is np.maximum))
        self._max_flat, self._min_flat = flats
        self._offsets = np.array(offsets, dtype=np.intp)
        self._widths = np.array(widths, dtype=np.intp)

    def range_over_box(self, col, row):
        """Lower and upper bounds of the surface over the bounding box of points, per ray.

        Parameters
        ----------
        col, row : ndarray, shape (m, k)
            Node indices of ``k`` points along each ray's (straight) track.

        Returns
        -------
        top_m, bottom_m : ndarray, shape (m,)
            ``+inf`` and ``-inf`` where the box leaves the grid or touches nodata.
        """
        n_rows, n_cols = self._n_cells
        c_lo, c_hi = col.min(axis=1), col.max(axis=1)
        r_lo, r_hi = row.min(axis=1), row.max(axis=1)
        inside = (c_lo >= 0.0) & (r_lo >= 0.0) & (c_hi <= n_cols) & (r_hi <= n_rows)
        # Cells under the box; a range of at most 2**l cells spans at most two blocks.
        i_lo, i_hi, j_lo, j_hi = (
            np.clip(np.floor(np.where(inside, v, 0.0)), 0, n - 1).astype(np.intp)
            for v, n in ((c_lo, n_cols), (c_hi, n_cols), (r_lo, n_rows), (r_hi, n_rows))
        )
        extent = np.maximum(i_hi - i_lo, j_hi - j_lo) + 1
        level = np.minimum(np.ceil(np.log2(extent)).astype(np.intp), self._offsets.size - 1)
        off, width = self._offsets[level], self._widths[level]
        i_lo, i_hi, j_lo, j_hi = (v >> level for v in (i_lo, i_hi, j_lo, j_hi))
        corners = [off + j * width + i for j in (j_lo, j_hi) for i in (i_lo, i_hi)]
        top = self._max_flat.take(corners[0])
        bottom = self._min_flat.take(corners[0])
        for k in corners[1:]:
            top = np.maximum(top, self._max_flat.take(k))
            bottom = np.minimum(bottom, self._min_flat.take(k))
        return np.where(inside, top, np.inf), np.where(inside, bottom, -np.inf)


def float32_bound(values, *, upper):
    """``values`` as float32 rounded outwards (up for upper bounds), halving their memory."""
    out = np.ascontiguousarray(values, dtype=np.float32)
    if upper:
        return np.where(out < values, np.nextafter(out, np.float32(np.inf)), out)
    return np.where(out > values, np.nextafter(out, np.float32(-np.inf)), out)
