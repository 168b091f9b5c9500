"""Conservative height bounds of a DEM grid for ray marching: a min/max pyramid, float32 bounds.

:class:`RangePyramid` holds the extrema of the node heights over blocks of ``2**l`` cells, all
levels ``l``; :func:`float32_bound` stores bounds in float32 rounded outwards, so that they
still bound the float64 heights with half the memory.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RangePyramid", "float32_bound", "node_bounds"]


class RangePyramid:
    """Minima and maxima of a node grid over square blocks of 2**l x 2**l cells, all levels l.

    Block ``(J, I)`` of level ``l`` spans the nodes ``J 2^l .. (J + 1) 2^l`` by
    ``I 2^l .. (I + 1) 2^l`` (inclusive: neighbouring blocks share their edge nodes), so its
    range bounds the bilinear surface over its cells. Nodes without data count as ``+inf`` in
    the maxima and ``-inf`` in the minima (no bound there).
    """

    def __init__(self, z, *, bounds=None):
        n_rows, n_cols = z.shape
        self._n_cells = (n_rows - 1, n_cols - 1)
        if bounds is None:
            bounds = node_bounds(z)
        flats, offsets, widths = [], None, None
        for upper, nodes in zip((True, False), bounds):
            flat, offsets, widths = _pyramid(nodes, np.maximum if upper else np.minimum,
                                             np.float32(-np.inf if upper else np.inf))
            flats.append(flat)
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


def node_bounds(z):
    """Node heights as float32 bounds: ``(upper, lower)`` (H, W), rounded outwards, ``+inf`` /
    ``-inf`` at nodes without data.

    Rounding outwards to float32 is monotone, so a maximum (minimum) over these bounds equals
    the bound of the maximum (minimum) of the float64 heights, bit for bit: the pyramid and the
    DEM's cell maxima are built on them at 4 bytes a node instead of 8.
    """
    invalid = ~np.isfinite(z)
    bounds = []
    for upper, fill in ((True, np.inf), (False, -np.inf)):
        b = float32_bound(z, upper=upper)
        b[invalid] = fill
        bounds.append(b)
    return tuple(bounds)


def _level_shapes(n_rows: int, n_cols: int):
    """(rows, cols) of every level of a pyramid over ``n_rows x n_cols`` cells, level 0 first."""
    shapes = [(n_rows, n_cols)]
    while max(shapes[-1]) > 1:
        rows, cols = shapes[-1]
        shapes.append(((rows + 1) // 2, (cols + 1) // 2))
    return shapes


def _pyramid(nodes, reduce, pad):
    """Every level of a min or max pyramid over the cells of a (H, W) node grid, in one flat float32 array.

    Level 0 reduces each cell's four corner nodes; level ``l + 1`` reduces 2 x 2 blocks of level
    ``l``, padded with ``pad`` (the reduction's identity) to even sides. Returns ``(flat, offsets,
    widths)``: the levels one after the other, each level's first index and its width.
    """
    shapes = _level_shapes(nodes.shape[0] - 1, nodes.shape[1] - 1)
    sizes = [r * c for r, c in shapes]
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).tolist()
    flat = np.empty(sum(sizes), dtype=np.float32)
    rows, cols = shapes[0]
    level = flat[:sizes[0]].reshape(rows, cols)
    reduce(nodes[:-1, :-1], nodes[:-1, 1:], out=level)
    step = max(1, (1 << 22) // max(1, cols))  # the second pair by strips of rows: a small temporary
    for r0 in range(0, rows, step):
        r1 = min(rows, r0 + step)
        part = level[r0:r1]
        reduce(part, reduce(nodes[r0 + 1:r1 + 1, :-1], nodes[r0 + 1:r1 + 1, 1:]), out=part)
    for k in range(1, len(shapes)):
        rows, cols = shapes[k - 1]
        if rows % 2 or cols % 2:
            padded = np.full((rows + rows % 2, cols + cols % 2), pad, dtype=np.float32)
            padded[:rows, :cols] = level
        else:
            padded = level
        nxt = flat[offsets[k]:offsets[k] + sizes[k]].reshape(shapes[k])
        reduce(padded[0::2, 0::2], padded[0::2, 1::2], out=nxt)
        reduce(nxt, reduce(padded[1::2, 0::2], padded[1::2, 1::2]), out=nxt)
        level = nxt
    return flat, offsets, [c for _, c in shapes]
