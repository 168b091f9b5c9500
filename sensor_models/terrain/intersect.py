"""Per-pixel DEM intersection of straight-ray layers: the fixed solver and the adaptive one.

Used by :func:`sensor_models.imaging.locate.locate_block`. :func:`dem_planes` holds the DEM's heights
and gradients for one-pass bilinear sampling. The fixed solver (:func:`intersect_dem_fixed`) runs
four steps (two of them sampling the
height and its gradient) on every pixel of a block, from one mid-height start. Most of that work
is wasted: the intersection height varies smoothly from pixel to pixel wherever the terrain does.
Here, for the same straight-ray layers ``u(h) = u_lo + (h - h_lo) du/dh`` (and ``v``):

1. **Coarse start.** The fixed solver runs on every ``coarse_step``-th pixel in both directions
   (1/25 of the pixels for a step of 5); its heights and the slopes ``f'(h)`` of
   ``f(h) = h - D(u(h), v(h))`` there are interpolated bilinearly to every pixel
   (``cv2.resize``: an odd step puts the coarse samples exactly on pixel centres).
2. **Chord steps everywhere** (two by default) with the interpolated slope: one
   single-channel DEM sample per pixel and step, in-place passes over reused buffers; the
   ray's position is advanced by ``d du`` with each step ``d``.
3. **Convergence mask.** Only the pixels whose step exceeded ``tolerance_m`` (breaks of slope,
   ridges, the DEM's edge, starts the coarse grid could not give) take further full Newton
   steps (height and gradient sampled), gathered into compact arrays, until their step is
   below ``tolerance_m`` or ``max_refine_steps`` is reached. A caller that needs positions
   rather than heights passes the height tolerance that bounds the horizontal error
   (:func:`sensor_models.imaging.locate.height_tolerance_for_position`).

Error bound: a chord or Newton step of size ``|d|`` leaves an error of at most
``|d| q / (1 - q)``, where ``q`` is the step's contraction factor (``|1 - f'/s|`` for a chord
step with slope ``s``; quadratic for Newton). Stopping at ``|d| <= tolerance_m`` with
``q <= 1/2`` leaves at most ``tolerance_m`` of height error. Heights map into positions through
``du/dh``, a few thousandths of a node per metre for near-nadir views: 1 mm of height is
~1e-5 DEM node. ``tests/test_locate.py`` checks the result against the exact per-pixel model
(2e-3 DOM px RMS), and ``tests/test_speed_paths.py`` against the fixed solver (< 1 cm).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["dem_planes", "height_planes", "intersect_dem_adaptive", "intersect_dem_fixed"]

#: pixels per row of the compact arrays the refinement steps sample (cv2.remap needs < 32767)
_COMPACT_WIDTH = 4096


def intersect_dem_adaptive(dem, u_lo, v_lo, du, dv, h_lo, *, tolerance_m: float = 1e-3, coarse_step: int = 5,
                           chord_steps: int = 2, max_refine_steps: int = 6):
    """Per-pixel solution of ``h = D(u_lo + (h - h_lo) du, v_lo + (h - h_lo) dv)``, adaptively.

    Parameters
    ----------
    dem : sensor_models.terrain.dem.Dem
        Terrain (ellipsoidal heights, metres), sampled bilinearly between nodes.
    u_lo, v_lo : ndarray of float32, shape (n_lines, n_cols)
        DEM node indices of each pixel's line of sight at height ``h_lo``.
    du, dv : ndarray of float32, shape (n_lines, n_cols)
        Their derivatives with height, nodes per metre.
    h_lo : float
        Height of the lower layer, metres.
    tolerance_m : float
        A pixel stops once its last height step is at most this, metres (> 0).
    coarse_step : int
        Spacing of the pixels solved by the fixed solver for the start (odd; 1 = every pixel).
    chord_steps : int
        Chord steps on every pixel (slope interpolated from the coarse grid) before the mask.
    max_refine_steps : int
        Newton steps at most on the pixels that have not converged after the chord steps.

    Returns
    -------
    h : ndarray of float32, shape (n_lines, n_cols)
        Ellipsoidal height of the intersection, metres (NaN outside the DEM).
    u, v : ndarray of float32, shape (n_lines, n_cols)
        DEM node indices of the intersection (NaN outside the DEM).
    """
    if not tolerance_m > 0:
        raise ValueError(f"tolerance_m must be > 0, got {tolerance_m}")
    h_lo = np.float32(h_lo)
    t, inv_slope = _coarse_start(dem, u_lo, v_lo, du, dv, h_lo, int(coarse_step), intersect_dem_fixed)
    heights = _dem_heights(dem)
    u = np.empty(u_lo.shape, dtype=np.float32)
    v = np.empty(v_lo.shape, dtype=np.float32)
    d = np.empty(u_lo.shape, dtype=np.float32)
    scratch = np.empty(u_lo.shape, dtype=np.float32)
    _ray_at(t, u_lo, v_lo, du, dv, u, v)
    n_steps = max(1, int(chord_steps))
    for k in range(n_steps):  # chord steps everywhere; t is the height above h_lo
        cv2.remap(heights, u, v, cv2.INTER_LINEAR, dst=d, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        d -= h_lo
        d -= t
        d *= inv_slope
        t += d
        if k == n_steps - 1:  # NaN steps (outside the DEM) are not refined: their height stays NaN
            todo = np.flatnonzero(np.abs(d, out=scratch) > np.float32(tolerance_m))
        _advance(u, v, d, du, dv, scratch)
    if todo.size:
        _refine(dem, t, u_lo, v_lo, du, dv, h_lo, todo, tolerance_m, max_refine_steps)
        idx = (todo // t.shape[1], todo % t.shape[1])
        tt = t[idx]
        u[idx] = u_lo[idx] + tt * du[idx]
        v[idx] = v_lo[idx] + tt * dv[idx]
    t += h_lo
    _mask_outside(dem.shape, t, u, v)
    return t, u, v


def _ray_at(t, u_lo, v_lo, du, dv, u, v) -> None:
    """``u = u_lo + t du`` and ``v = v_lo + t dv`` into the given arrays.

    Copy, then in-place products and sums: on the development machine an in-place operation
    on two arrays costs less than half of one writing a third array.
    """
    np.copyto(u, du)
    u *= t
    u += u_lo
    np.copyto(v, dv)
    v *= t
    v += v_lo


def _advance(u, v, d, du, dv, scratch) -> None:
    """``u += d du`` and ``v += d dv`` in place, after a height step ``d`` (consumed)."""
    np.copyto(scratch, d)
    scratch *= du
    u += scratch
    d *= dv
    v += d


def _mask_outside(dem_shape, h, u, v) -> None:
    """Set ``h, u, v`` to NaN (in place) where ``(u, v)`` leaves the DEM's nodes or ``h`` is NaN.

    Four reductions decide the usual case (every pixel inside: nothing to mask; a NaN height
    makes ``u`` NaN, which fails the test); the per-pixel mask runs only otherwise.
    """
    rows, cols = dem_shape
    if u.min() >= 0 and u.max() <= cols - 1 and v.min() >= 0 and v.max() <= rows - 1:
        return
    bad = ~((u >= 0) & (u <= cols - 1) & (v >= 0) & (v <= rows - 1) & np.isfinite(h))
    h[bad] = np.nan
    u[bad] = np.nan
    v[bad] = np.nan


def _coarse_start(dem, u_lo, v_lo, du, dv, h_lo, step, fixed_solver):
    """Start heights (above ``h_lo``) and inverse chord slopes of every pixel, from the coarse grid.

    The fixed solver runs on every ``step``-th pixel; its heights and the inverse slopes
    ``1 / f'(h)`` there are interpolated bilinearly (``cv2.resize``). Coarse samples whose
    solution is not finite (next to the DEM's edge) start at mid-height, and grazing rays
    (``f' <= 1/4``) take plain fixed-point steps (inverse slope 1), as in the fixed solver; both
    are settled on the coarse grid, so the interpolated starts and slopes are finite and the
    inverse slopes lie in ``(0, 4]``. Returns float32 arrays of the block's shape (views with
    C-contiguous rows).
    """
    n_lines, n_cols = u_lo.shape
    h_min, h_max = dem.height_range_m
    mid = np.float32(0.5 * (h_min + h_max) - h_lo)
    if step <= 1 or n_lines < 2 * step or n_cols < 2 * step:
        t = np.full(u_lo.shape, mid, dtype=np.float32)
        return t, np.ones_like(t)
    ri = np.minimum(np.arange(step // 2, n_lines + step - 1, step)[: -(-n_lines // step)], n_lines - 1)
    ci = np.minimum(np.arange(step // 2, n_cols + step - 1, step)[: -(-n_cols // step)], n_cols - 1)
    sub = np.ix_(ri, ci)
    cu, cv, cdu, cdv = (np.ascontiguousarray(a[sub]) for a in (u_lo, v_lo, du, dv))
    hc, uc, vc = fixed_solver(dem, cu, cv, cdu, cdv, h_lo, 4)
    s = cv2.remap(dem_planes(dem), uc, vc, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                  borderValue=(np.nan, np.nan, np.nan))
    slope_c = 1.0 - (s[..., 1] * cdu + s[..., 2] * cdv)
    with np.errstate(divide="ignore", invalid="ignore"):  # NaN and small slopes fail the test
        inv_c = np.where(slope_c > 0.25, 1.0 / slope_c, 1.0).astype(np.float32)
    tc = hc - h_lo
    tc[~np.isfinite(tc)] = mid
    size = (ci.size * step, ri.size * step)
    t = cv2.resize(tc, size, interpolation=cv2.INTER_LINEAR)[:n_lines, :n_cols]
    inv_slope = cv2.resize(inv_c, size, interpolation=cv2.INTER_LINEAR)[:n_lines, :n_cols]
    return t, inv_slope


def _refine(dem, t, u_lo, v_lo, du, dv, h_lo, todo, tolerance_m, max_steps):
    """Newton steps on the flat pixel indices ``todo`` of ``t`` (updated in place) until converged.

    The arrays may be views with C-contiguous rows (not one flat buffer): pixels are gathered
    and scattered by (row, column) pairs.
    """
    planes = dem_planes(dem)
    n_cols = t.shape[1]
    for _ in range(max_steps):
        idx = (todo // n_cols, todo % n_cols)
        tt = t[idx]
        a, b = du[idx], dv[idx]
        s = _sample_compact(planes, u_lo[idx] + tt * a, v_lo[idx] + tt * b)
        slope = 1.0 - (s[:, 1] * a + s[:, 2] * b)
        slope[~(slope > 0.25)] = 1.0
        step = (s[:, 0] - h_lo - tt) / slope
        t[idx] = tt + step
        keep = ~(np.abs(step) <= tolerance_m) & np.isfinite(step)
        todo = todo[keep]
        if not todo.size:
            return


def _sample_compact(planes, u, v):
    """Bilinear samples of the 3-channel ``planes`` at scattered node indices: (n, 3) float32."""
    n = u.size
    width = min(_COMPACT_WIDTH, max(1, n))
    rows = -(-n // width)
    pu = np.full(rows * width, np.nan, np.float32)
    pv = np.full(rows * width, np.nan, np.float32)
    pu[:n], pv[:n] = u, v
    s = cv2.remap(planes, pu.reshape(rows, width), pv.reshape(rows, width), cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan, np.nan))
    return s.reshape(-1, 3)[:n]


def dem_planes(dem) -> np.ndarray:
    """Heights of a DEM and their node gradients, stacked for one-pass bilinear sampling.

    Built on first use and cached on the DEM (derived data only); call it once before
    sharing a DEM between threads so that they do not all build it.

    Parameters
    ----------
    dem : Dem
        Terrain (ellipsoidal heights in metres, NaN for no data).

    Returns
    -------
    ndarray of float32, shape (n_rows, n_cols, 3), C-contiguous
        ``[..., 0]`` the height (m), ``[..., 1]`` and ``[..., 2]`` its central-difference
        derivatives along columns (``dh/du``) and rows (``dh/dv``), metres per node.
    """
    cached = getattr(dem, "_render_planes", None)
    if cached is None:
        cached = height_planes(np.asarray(dem.heights_m, dtype=np.float64))
        dem._render_planes = cached  # derived data only; the DEM itself is immutable
    return cached


#: nodes :func:`height_planes` differentiates at a time (whole rows)
PLANE_STRIP_NODES = 1 << 20


def height_planes(z: np.ndarray, strip_nodes: int = PLANE_STRIP_NODES) -> np.ndarray:
    """``[z, dz/du, dz/dv]`` (H, W, 3) float32 of a (H, W) height grid, by strips of rows.

    The derivatives are :func:`numpy.gradient`'s (central differences, one-sided on the grid's
    edges) of the heights with non-finite values as NaN. Each strip is differentiated with one
    row of its neighbours on either side, so its rows get the whole grid's differences, bit for
    bit, while the float64 temporaries stay the size of a strip.

    Parameters
    ----------
    z : ndarray of float64, shape (H, W)
        Heights, H, W >= 2.
    strip_nodes : int
        Nodes per strip (at least one row).

    Returns
    -------
    ndarray of float32, shape (H, W, 3), C-contiguous
    """
    n_rows, n_cols = z.shape
    out = np.empty((n_rows, n_cols, 3), dtype=np.float32)
    step = max(1, strip_nodes // n_cols)
    for r0 in range(0, n_rows, step):
        r1 = min(n_rows, r0 + step)
        a, b = max(0, r0 - 1), min(n_rows, r1 + 1)  # one row of context each side
        part = z[a:b]
        d_row, d_col = np.gradient(np.where(np.isfinite(part), part, np.nan))
        inner = slice(r0 - a, r1 - a)
        out[r0:r1, :, 0] = part[inner]
        out[r0:r1, :, 1] = d_col[inner]
        out[r0:r1, :, 2] = d_row[inner]
    return out


def intersect_dem_fixed(dem, u_lo, v_lo, du, dv, h_lo, iterations: int):
    """Per-pixel Newton solution of ``h = D(u_lo + (h - h_lo) du, v_lo + (h - h_lo) dv)``.

    The first two steps are full Newton steps (height and gradient sampled); the later ones
    reuse the last slope (chord method: linear convergence at the rate of the slope's change,
    one single-channel sample per step). Returns ``h`` and the DEM node indices ``u, v`` of
    the solution (float32; NaN outside the DEM).
    """
    planes = dem_planes(dem)
    heights = _dem_heights(dem)
    rows, cols = planes.shape[:2]
    h_min, h_max = dem.height_range_m
    h = np.full(u_lo.shape, 0.5 * (h_min + h_max) - h_lo, dtype=np.float32)  # h - h_lo
    u = np.empty_like(u_lo)
    v = np.empty_like(v_lo)
    slope = None
    for it in range(iterations):
        np.multiply(h, du, out=u)
        u += u_lo
        np.multiply(h, dv, out=v)
        v += v_lo
        if it < 2:
            s = cv2.remap(planes, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(np.nan, np.nan, np.nan))
            d_h = s[..., 0]
            slope = 1.0 - (s[..., 1] * du + s[..., 2] * dv)
            # safeguard: grazing rays (slope -> 0) fall back to a plain fixed-point step
            slope[~(slope > 0.25)] = 1.0
        else:
            d_h = cv2.remap(heights, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                            borderValue=np.nan)
        d_h = d_h - h_lo
        d_h -= h
        d_h /= slope
        h += d_h
    _ray_at(h, u_lo, v_lo, du, dv, u, v)
    h += h_lo
    _mask_outside((rows, cols), h, u, v)
    return h, u, v


def _dem_heights(dem):
    """The height plane of :func:`dem_planes` as its own contiguous float32 array (cached)."""
    cached = getattr(dem, "_render_heights", None)
    if cached is None:
        cached = np.ascontiguousarray(dem_planes(dem)[..., 0])
        dem._render_heights = cached
    return cached
