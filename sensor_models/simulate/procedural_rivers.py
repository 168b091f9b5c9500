"""River network of the procedural reference: drainage, channels, meanders, polyline drawing.

:func:`draw_rivers` drains the terrain shape by Priority-Flood [9]_ to the sea, the lakes or the
border, picks channel heads by drainage area, and turns each channel into a smoothed,
meandering [3]_ centre line with widths and a bed that never rises downstream;
:func:`draw_segments` rasterises such polylines (the river beds carved into the DEM, the rivers
and riparian strips drawn on the DOM).

References
----------
.. [3] W. B. Langbein and L. B. Leopold, "River meanders: theory of minimum variance", USGS
   Professional Paper 422-H, 1966 (the sine-generated curve).
.. [9] R. Barnes, C. Lehman and D. Mulla, "Priority-flood: an optimal depression-filling and
   watershed-labeling algorithm for digital elevation models", Computers & Geosciences 62,
   117-127, 2014.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sensor_models.simulate.procedural_terrain import MARGIN_NODES


@dataclass
class _River:
    xy_m: np.ndarray       # (n, 2) eastings and northings of the centre line
    width_m: np.ndarray    # (n,)
    bed: np.ndarray        # (n,) monotone bed level in shape units


def draw_rivers(args, ext, terrain, lakes, rng, area_km2):
    """A dendritic river network draining the terrain to the sea, lakes or the border.

    On cells of about 120 m (coarser for large areas, at most ~60 000 cells), the smoothed
    terrain shape is drained by Priority-Flood [9]_ from the outlets (sea, lakes and the border
    ring): each cell flows to the cell it was reached from, so every closed basin spills over
    its lowest pass. Drainage areas accumulate down these links; channels are the cells whose
    area exceeds the threshold giving ``n_rivers`` channel heads (about one per 250 km^2 by
    default, and at least 5 km^2). Each channel, from its head down to an outlet or a
    confluence, is smoothed (Chaikin corner cutting) and given irregular meanders (a lateral
    offset of about 2 widths with a wavelength of about 12 widths, see :func:`_meander` and
    [3]_), the width being ``w = clip(8 sqrt(A / km^2), 15, 100) m``. The bed is the running
    minimum of the terrain along the channel, so it never rises downstream.
    """
    n_heads = args["n_rivers"]
    if n_heads is None:
        n_heads = int(round(area_km2 / 250.0))
    res = ext.res_m
    cell_m = max(120.0, math.sqrt(area_km2 * 1e6 / 60_000.0), res)
    f = max(1, int(round(cell_m / res)))
    cell_m = f * res
    nr, nc = ext.n_rows // f, ext.n_cols // f
    if n_heads == 0 or min(nr, nc) < 8:
        return []

    def blocks(a, how):
        a = a[: nr * f, : nc * f].reshape(nr, f, nc, f)
        return a.mean(axis=(1, 3), dtype=np.float64) if how == "mean" else a.any(axis=(1, 3))

    height = ndimage.gaussian_filter(blocks(lakes.shape, "mean"), 1.0, mode="nearest")
    outlet = blocks(~terrain.land | lakes.mask, "any")
    ring = max(1, int(math.ceil(MARGIN_NODES / f)))
    outlet[:ring], outlet[-ring:], outlet[:, :ring], outlet[:, -ring:] = True, True, True, True
    parent, order = _priority_flood(height, outlet)
    area = np.ones(nr * nc, dtype=np.float64)
    for i in order[::-1]:
        if parent[i] >= 0:
            area[parent[i]] += area[i]
    area *= cell_m * cell_m / 1e6  # km^2
    heads = _channel_heads(area, parent, outlet.ravel(), n_heads, min_km2=5.0)
    if heads.size == 0:
        return []

    owner = np.full(nr * nc, -1, dtype=np.intp)
    rivers, paths = [], []
    for head in heads:
        cells = [head]
        while parent[cells[-1]] >= 0 and owner[cells[-1]] < 0 and not outlet.flat[cells[-1]]:
            cells.append(parent[cells[-1]])
        cells = np.asarray(cells)
        join = owner[cells[-1]]
        own = cells if join < 0 else cells[:-1]
        owner[own] = len(paths)
        r, c = np.divmod(cells, nc)
        node_r = r * f + 0.5 * (f - 1)
        node_c = c * f + 0.5 * (f - 1)
        xy = np.stack([ext.x0_m + (node_c + 0.5) * res, ext.y0_m - (node_r + 0.5) * res], axis=1)
        width = np.clip(8.0 * np.sqrt(area[cells]), 15.0, 100.0)
        xy, width = _chaikin(xy, width, 3)
        xy, width = _meander(xy, width, rng, fixed_end=join >= 0)
        if join >= 0:
            # End on the (meandering) centre line of the river joined.
            other = paths[join]
            k = int(np.argmin(np.sum((other - xy[-1]) ** 2, axis=1)))
            xy = np.concatenate([xy, other[k:k + 1]])
            width = np.concatenate([width, width[-1:]])
        paths.append(xy)
        col, row = ext.node_index(xy[:, 0], xy[:, 1])
        bed = ndimage.map_coordinates(lakes.shape, [row, col], order=1, mode="nearest")
        rivers.append(_River(xy, width, np.minimum.accumulate(bed.astype(np.float64))))
    return rivers


def _priority_flood(height, outlet):
    """Drainage links of a grid by Priority-Flood from outlet cells (Barnes et al. 2014).

    Cells are taken from a priority queue in order of their filled height (ties first in,
    first out, so flats drain towards their spill point); each unvisited 8-neighbour is
    linked to the cell it was reached from and queued at ``max(own height, that height)``.

    Returns
    -------
    parent : ndarray, shape (rows * cols,), intp
        Flat index of the cell each cell drains to; -1 for outlets.
    order : ndarray, shape (rows * cols,), intp
        Cells in the order they left the queue (every cell after the one it drains to).
    """
    import heapq

    nr, nc = height.shape
    h = height.ravel().tolist()
    parent = np.full(nr * nc, -1, dtype=np.intp)
    parent_list = parent.tolist()
    closed = bytearray(outlet.ravel().astype(np.uint8).tobytes())
    queue = [(h[i], i, i) for i in np.flatnonzero(outlet.ravel()).tolist()]
    heapq.heapify(queue)
    counter = nr * nc
    order = []
    steps = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
    while queue:
        level, _, i = heapq.heappop(queue)
        order.append(i)
        r, c = divmod(i, nc)
        for dr, dc in steps:
            rr, cc = r + dr, c + dc
            if 0 <= rr < nr and 0 <= cc < nc:
                j = rr * nc + cc
                if not closed[j]:
                    closed[j] = 1
                    parent_list[j] = i
                    heapq.heappush(queue, (max(h[j], level), counter, j))
                    counter += 1
    return np.asarray(parent_list, dtype=np.intp), np.asarray(order, dtype=np.intp)


def _channel_heads(area_km2, parent, outlet, n_heads, *, min_km2):
    """Channel heads for the drainage-area threshold giving about ``n_heads`` of them.

    A head is a land cell whose area reaches the threshold while none of its upstream
    neighbours does. Returned in decreasing order of drainage area (largest rivers first).
    """
    land = ~outlet

    def heads_for(threshold):
        big = (area_km2 >= threshold) & land
        fed = np.zeros(area_km2.size, dtype=bool)
        up = np.flatnonzero(big & (parent >= 0))
        fed[parent[up]] = True
        return np.flatnonzero(big & ~fed)

    candidates = np.unique(area_km2[land & (area_km2 >= min_km2)])
    if candidates.size == 0:
        return np.zeros(0, dtype=np.intp)
    lo, hi = 0, candidates.size - 1  # more heads at lower thresholds
    while lo < hi:
        mid = (lo + hi) // 2
        if heads_for(candidates[mid]).size > n_heads:
            lo = mid + 1
        else:
            hi = mid
    heads = heads_for(candidates[lo])
    return heads[np.argsort(-area_km2[heads], kind="stable")]


def _chaikin(xy, width, iterations):
    """Chaikin corner cutting of a polyline (end points kept) and of its per-vertex widths."""
    for _ in range(iterations):
        if xy.shape[0] < 3:
            break
        q = 0.75 * xy[:-1] + 0.25 * xy[1:]
        r = 0.25 * xy[:-1] + 0.75 * xy[1:]
        wq = 0.75 * width[:-1] + 0.25 * width[1:]
        wr = 0.25 * width[:-1] + 0.75 * width[1:]
        inner = np.stack([q, r], axis=1).reshape(-1, 2)[1:-1]
        inner_w = np.stack([wq, wr], axis=1).reshape(-1)[1:-1]
        xy = np.concatenate([xy[:1], inner, xy[-1:]])
        width = np.concatenate([width[:1], inner_w, width[-1:]])
    return xy, width


def _meander(xy, width, rng, *, fixed_end):
    """Resample a centre line every ~w/2 and offset it laterally into meanders.

    Returns the new vertices ``(m, 2)`` and their widths ``(m,)``.

    The offset is ``a(s) sin(phi(s))`` with ``phi' = 2 pi / lambda(s)``, a wavelength
    ``lambda = 12 w (1 + 0.3 sin(...))`` and an amplitude ``a = w (1.8 + 1.2 sin(...))``, both
    slowly modulated with random phases so that the bends are irregular; it fades in over the
    first wavelength and, when the river ends on another one (``fixed_end``), out over the last.
    """
    phases = rng.uniform(0.0, 2.0 * math.pi, 3)
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0.0:
        return xy, width
    step = max(0.5 * float(width.min()), 5.0)
    s_new = np.linspace(0.0, s[-1], max(2, int(s[-1] / step) + 1))
    xy = np.stack([np.interp(s_new, s, xy[:, 0]), np.interp(s_new, s, xy[:, 1])], axis=1)
    w = np.interp(s_new, s, width)
    base = 12.0 * w
    wavelength = base * (1.0 + 0.3 * np.sin(2.0 * math.pi * s_new / (4.1 * base) + phases[1]))
    amplitude = w * (1.8 + 1.2 * np.sin(2.0 * math.pi * s_new / (7.3 * base) + phases[2]))
    ds = np.diff(s_new, prepend=0.0)
    phi = phases[0] + np.cumsum(2.0 * math.pi * ds / wavelength)
    fade = np.clip(s_new / base, 0.0, 1.0)
    if fixed_end:
        fade = np.minimum(fade, np.clip((s_new[-1] - s_new) / base, 0.0, 1.0))
    tangent = np.gradient(xy, axis=0)
    tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-12)[:, None]
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    return xy + (amplitude * np.sin(phi) * fade)[:, None] * normal, w


def draw_segments(canvas, pts_px, values, thickness, *, antialias=False):
    """Draw consecutive segments of a polyline (pixel-centre coordinates) with OpenCV.

    ``values[i]`` and ``thickness[i]`` apply to segment ``i`` (points i, i+1); points are in
    continuous pixel coordinates (first pixel centre at 0.5, 0.5), columns then rows.
    """
    import cv2

    fixed = np.round((pts_px - 0.5) * 16.0).astype(np.int32)
    line = cv2.LINE_AA if antialias else cv2.LINE_8
    for i in range(fixed.shape[0] - 1):
        cv2.line(canvas, (int(fixed[i, 0]), int(fixed[i, 1])),
                 (int(fixed[i + 1, 0]), int(fixed[i + 1, 1])), float(values[i]),
                 thickness=int(thickness[i]), lineType=line, shift=4)
