"""The first crossing of lines of sight with a DEM surface: the work of ``Dem.intersect``.

:func:`intersect_rays` (which :meth:`sensor_models.terrain.dem.Dem.intersect` calls) and the
private functions it calls take the :class:`~sensor_models.terrain.dem.Dem` as their first
argument and read its grid and the bounds it precomputes at load (its cell maxima and its
:class:`~sensor_models.terrain.height_bounds.RangePyramid`).

Method
------
A ray ``p(t) = o + t d`` (ITRF, ``|d| = 1``) is bracketed between its intersections with the
heights ``h_max + 1 m`` and ``h_min - 1 m`` of the DEM
(:func:`~sensor_models.terrain.ellipsoid.intersect_ellipsoid`, solved on the ``(a + h, b + h)``
ellipsoid whose distance to the true geodetic-height surface is below 1.3 cm up to 9 km). On
that bracket the geodetic height ``h(t)`` and the node index ``(col(t), row(t))`` of the ray
are smooth; each is replaced by its cubic interpolant through
four exactly computed points (error far below 1e-6 m for brackets of a few km). The ray is
then marched in steps of at most 0.45 node spacing in both ``col`` and ``row``; a step
``[t_k, t_k+1]`` is skipped only when the ray stays above the highest DEM node that the step can
reach (a 4 x 4-node maximum precomputed at load), which cannot miss a crossing. A step that may
hold one is split where it crosses grid lines; inside each DEM cell the bilinear surface along
the ray is a quadratic in ``t``, so the first root of ``f(t) = h(t) - z(col(t), row(t))`` is
found in closed form, then made exact on the model by two Newton steps. That root is finally
checked with exact evaluations (:func:`~sensor_models.geometry.geodesy.ecef_to_geodetic`, the DEM's
own CRS transform, bilinear interpolation); where ``|f| >= 1e-4 m`` (not seen in practice:
model roots are within 1e-8 m on SRTM and 2e-6 m at 70 degrees over 8 km of relief) it is
polished by bracketed Illinois (regula falsi) steps. The point returned is ``o + t d``:
exactly on the ray, so an image -> ground -> image round trip is exact.

Before marching, the bracket is narrowed with a min/max pyramid of the DEM (extrema over
blocks of 2**l cells): the ray cannot meet the surface while above the highest node under
its track, and has met it once below the lowest. A "crossing" includes touching: a ray
tangent to the surface (to ~1e-8 m) stops there. Auxiliary bounds are kept in float32
rounded outwards: a Dem takes about 2.8 times the memory of its float64 height grid.

References
----------
.. [1] J. Amanatides and A. Woo, "A fast voxel traversal algorithm for ray tracing",
   Eurographics 1987 (grid traversal; here replaced by bounded uniform steps plus exact
   per-cell roots).
.. [2] M. Dowell and P. Jarratt, "A modified regula falsi method for computing the root of an
   equation", BIT 11, 168-174 (1971) (the Illinois algorithm).
"""

from __future__ import annotations

import math

import numpy as np

from sensor_models.errors import DemError, InputError
from sensor_models.geometry.geodesy import ecef_to_geodetic
from sensor_models.terrain.ellipsoid import as_rays, ellipsoid_quadratic, first_ray_root, newton_on_height

__all__ = ["intersect_rays"]

#: Tolerance on ``h_ray - h_dem`` of :func:`intersect_rays`, metres.
_SURFACE_TOL_M = 1e-4
#: Margin added above the DEM maximum and below its minimum for the ray bracket, metres.
_BRACKET_PAD_M = 1.0
#: Longest march step, in node spacings (both along columns and along rows).
_MAX_STEP_NODES = 0.45
#: Rays processed together: bounds memory to a few tens of MB whatever the number of rays.
_CHUNK_RAYS = 1 << 15
#: Rounds of bracket narrowing with the min/max pyramid before marching.
_NARROWING_ROUNDS = 1
#: March steps evaluated together for each ray still marching.
_BLOCK_STEPS = 8
#: Cubic interpolation nodes along the bracket and the inverse of their Vandermonde matrix.
_MODEL_S = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])
_MODEL_VINV = np.linalg.inv(np.vander(_MODEL_S, 4, increasing=True))

# Outcome of each ray inside Dem.intersect.
_PENDING, _HIT, _LEFT_DEM, _MISSED, _UNDERGROUND = 0, 1, 2, 3, 4


def _residual_exact(dem, o, d, t):
    """``h_ray - h_dem`` at ``o + t d`` with exact geodetic and CRS conversions."""
    xyz = o + t[:, None] * d
    lon, lat, h = ecef_to_geodetic(xyz)
    col, row = dem._lonlat_to_index(lon, lat)
    return h - dem._bilinear(col, row), lon, lat, h, xyz


def intersect_rays(dem, origin_m, direction, *, outside="nan"):
    """First crossing of ITRF rays with ``dem``'s surface: the body of ``Dem.intersect``.

    See :meth:`sensor_models.terrain.dem.Dem.intersect` for the parameters, outputs and method.
    """
    fallback_h = None
    if isinstance(outside, str):
        if outside not in ("nan", "raise"):
            raise InputError(f"outside must be 'nan', 'raise' or a height in metres, "
                             f"got {outside!r}")
    else:
        try:
            fallback_h = float(outside)
        except (TypeError, ValueError) as err:
            raise InputError(f"outside must be 'nan', 'raise' or a height in metres, "
                             f"got {outside!r}") from err
        if not math.isfinite(fallback_h):
            raise InputError("outside must be a finite height in metres")
    o, d, shape = as_rays(origin_m, direction)
    n = o.shape[0]
    t = np.full(n, np.nan)
    status = np.zeros(n, dtype=np.int8)
    geo = np.full((n, 3), np.nan)
    for start in range(0, n, _CHUNK_RAYS):
        sl = slice(start, min(start + _CHUNK_RAYS, n))
        t[sl], status[sl], geo[sl] = _intersect_chunk(dem, o[sl], d[sl])
    failed = status != _HIT
    if failed.any():
        if outside == "raise":
            counts = {k: int(np.count_nonzero(status == k))
                      for k in (_LEFT_DEM, _MISSED, _UNDERGROUND)}
            lon0, lat0, lon1, lat1 = dem.bounds_lonlat
            raise DemError(
                f"{int(failed.sum())} of {n} rays have no ground point on the DEM "
                f"{dem.source or ''} (lon {lon0:.6f}..{lon1:.6f}, lat {lat0:.6f}..{lat1:.6f} "
                f"deg): {counts[_LEFT_DEM]} leave it or meet nodata before reaching the "
                f"surface, {counts[_MISSED]} miss its height range, {counts[_UNDERGROUND]} "
                "start under it; read a larger DEM or pass outside='nan' or a fallback height"
            )
        if fallback_h is not None:
            idx = np.nonzero(failed)[0]
            a_, b_, c_, disc = ellipsoid_quadratic(o[idx], d[idx], fallback_h)
            h_fb = np.full(idx.size, fallback_h)
            t[idx] = newton_on_height(o[idx], d[idx], h_fb, first_ray_root(a_, b_, c_, disc),
                                       max_iter=10)
            geo[idx] = np.stack(ecef_to_geodetic(o[idx] + t[idx, None] * d[idx]), axis=1)
        else:
            t[failed] = np.nan
    xyz = o + t[:, None] * d
    return (geo[:, 0].reshape(shape), geo[:, 1].reshape(shape), geo[:, 2].reshape(shape),
            xyz.reshape(shape + (3,)))


def _intersect_chunk(dem, o, d):
    """First crossing for a chunk of rays.

    Returns ``t`` (n,), ``status`` (n,) and ``lon, lat, h`` of the hits, shape (n, 3).
    """
    n = o.shape[0]
    status = np.zeros(n, dtype=np.int8)
    t_hit = np.full(n, np.nan)
    geo = np.full((n, 3), np.nan)

    # 1. Bracket between the DEM's top and bottom heights (padded).
    t_top, t_bot = _bracket(dem, o, d, status)
    idx = np.nonzero(status == _PENDING)[0]
    if idx.size == 0:
        return t_hit, status, geo
    o_a, d_a, t0, t1 = o[idx], d[idx], t_top[idx], t_bot[idx]

    # 2. Cubic model of (h, col, row) along the bracket from 4 exact points; an origin
    # inside the bracket may already be under the surface.
    coef, under = _ray_model(dem, o_a, d_a, t0, t1)
    status[idx[under]] = _UNDERGROUND

    # 3. Narrow the bracket to where the ray may meet the surface.
    s0, ds, n_steps = _narrow(dem, coef, under)

    # 4. March: skip steps that stay above the local DEM maximum; solve the others.
    s_hit = _march(dem, coef, s0, ds, n_steps, under, status, idx)

    # 5. Exact check and polish on the true geometry.
    hit = np.nonzero(status[idx] == _HIT)[0]
    t_root = t0[hit] + s_hit[hit] * (t1[hit] - t0[hit])
    t_root, geo_root = _polish(dem, o_a[hit], d_a[hit], t_root,
                                    (t1[hit] - t0[hit]) * ds[hit] / n_steps[hit])
    t_hit[idx[hit]] = t_root
    geo[idx[hit]] = geo_root
    lost = ~np.isfinite(t_root)
    status[idx[hit[lost]]] = _LEFT_DEM
    return t_hit, status, geo


def _bracket(dem, o, d, status):
    """Ray parameters ``(t_top, t_bot)`` (n,) at the padded highest and lowest DEM heights.

    Marks rays starting under the lowest height ``_UNDERGROUND`` and rays that never reach
    the height range ``_MISSED`` in ``status`` (n,), in place.
    """
    top = ellipsoid_quadratic(o, d, dem._h_max + _BRACKET_PAD_M)
    t_top = np.where(top[2] <= 0.0, 0.0, first_ray_root(*top))
    bot = ellipsoid_quadratic(o, d, dem._h_min - _BRACKET_PAD_M)
    t_bot = first_ray_root(*bot)
    with np.errstate(invalid="ignore", divide="ignore"):
        vertex = -bot[1] / bot[0]
    t_bot = np.where(np.isnan(t_bot) & (bot[3] < 0.0), vertex, t_bot)
    status[bot[2] <= 0.0] = _UNDERGROUND
    status[(status == _PENDING) & ~(np.isfinite(t_top) & (t_bot > t_top))] = _MISSED
    return t_top, t_bot


def _ray_model(dem, o_a, d_a, t0, t1):
    """Cubic model in ``s`` of (h, col, row) on ``[t0, t1]`` and the rays starting underground.

    Returns ``coef`` (m, 3, 4), monomial coefficients in ``s = (t - t0) / (t1 - t0)``, and
    ``under`` (m,) bool: the ray's first node lies on or under the surface.
    """
    t_nodes = t0[:, None] + _MODEL_S[None, :] * (t1 - t0)[:, None]
    p_nodes = o_a[:, None, :] + t_nodes[:, :, None] * d_a[:, None, :]
    lon, lat, h = ecef_to_geodetic(p_nodes)
    col, row = dem._lonlat_to_index(lon.reshape(-1), lat.reshape(-1))
    values = np.stack([h, col.reshape(h.shape), row.reshape(h.shape)], axis=1)  # (m, 3, 4)
    coef = values @ _MODEL_VINV.T  # monomial coefficients in s, (m, 3, 4)
    f_start = h[:, 0] - dem._bilinear(values[:, 1, 0], values[:, 2, 0])
    return coef, f_start <= 0.0


def _narrow(dem, coef, under):
    """Narrow ``[0, 1]`` in ``s`` and cut it into march steps.

    The ray cannot meet the surface while it is above the highest node under its remaining
    path, and has met it once below the lowest one. Returns ``s0`` (m,), ``ds`` (m,) and
    ``n_steps`` (m,) int: steps under ``_MAX_STEP_NODES`` DEM nodes each.
    """
    s0 = np.zeros(coef.shape[0])
    s1 = np.ones(coef.shape[0])
    for _ in range(_NARROWING_ROUNDS):
        _, c01, r01 = _eval_model(coef, np.stack([s0, s1], axis=1))
        top_m, bottom_m = dem._pyramid.range_over_box(c01, r01)
        s0_new = _solve_model_height(coef, top_m + _BRACKET_PAD_M, s0, s1)
        s1_new = _solve_model_height(coef, bottom_m - _BRACKET_PAD_M, s0, s1)
        s0 = np.where(np.isfinite(s0_new), s0_new, s0)
        s1 = np.where(np.isfinite(s1_new), np.maximum(s1_new, s0), s1)
    s0 = np.where(under, 0.0, s0)
    _, c01, r01 = _eval_model(coef, np.stack([s0, s1], axis=1))
    variation = np.maximum(np.abs(c01[:, 1] - c01[:, 0]), np.abs(r01[:, 1] - r01[:, 0]))
    n_steps = np.maximum(1, np.ceil(variation / _MAX_STEP_NODES)).astype(np.int64)
    return s0, s1 - s0, n_steps


def _march(dem, coef, s0, ds, n_steps, under, status, idx):
    """March every ray not ``under`` along its steps, blocks of steps at once.

    Sets ``status[idx]`` to ``_HIT``, ``_LEFT_DEM`` or ``_MISSED`` in place and returns
    ``s_hit`` (m,): the root's ``s`` for hits, NaN otherwise.
    """
    s_hit = np.full(idx.size, np.nan)
    k_cur = np.zeros(idx.size, dtype=np.int64)
    active = np.nonzero(~under)[0]
    while active.size:
        # Steps evaluated together: a block, or fewer when every ray is nearly done.
        block = int(min(_BLOCK_STEPS, np.max(n_steps[active] - k_cur[active])))
        ks = k_cur[active, None] + np.arange(block + 1)
        ka = n_steps[active, None]
        maybe = _steps_that_may_cross(dem, coef[active],
                                      s0[active, None] + ds[active, None] * (np.minimum(ks, ka) / ka))
        maybe &= ks[:, :-1] < ka
        found_any = maybe.any(axis=1)
        first = maybe.argmax(axis=1)

        # Rays with nothing in this block move on (or, past their last step, missed).
        quiet = active[~found_any]
        k_cur[quiet] += block
        ended = quiet[k_cur[quiet] >= n_steps[quiet]]
        status[idx[ended]] = _MISSED

        cand = active[found_any]
        k = k_cur[cand] + first[found_any]
        ka_c = n_steps[cand]
        got, left, s_root = _first_root_in_step(dem, 
            coef[cand], s0[cand] + ds[cand] * (k / ka_c), s0[cand] + ds[cand] * ((k + 1) / ka_c)
        )
        s_hit[cand[got]] = s_root[got]
        status[idx[cand[got]]] = _HIT
        status[idx[cand[left]]] = _LEFT_DEM
        none = ~got & ~left
        k_cur[cand[none]] = k[none] + 1
        ended = cand[none][k_cur[cand[none]] >= ka_c[none]]
        status[idx[ended]] = _MISSED
        active = np.nonzero(status[idx] == _PENDING)[0]
        active = active[~under[active]]
    return s_hit


def _steps_that_may_cross(dem, coef, s):
    """For step ends ``s`` (m, k + 1): steps (m, k) whose lower end is not above the cell maximum."""
    n_rows, n_cols = dem.shape
    hs, cs, rs = _eval_model(coef, s)
    ci = np.floor(cs)
    ri = np.floor(rs)
    inside = (ci >= 0) & (ci <= n_cols - 2) & (ri >= 0) & (ri <= n_rows - 2)
    cell = np.where(inside, ri * (n_cols - 1) + ci, 0).astype(np.intp)
    bound = np.where(inside, dem._cell_max_flat.take(cell), np.inf)
    return np.minimum(hs[:, :-1], hs[:, 1:]) <= bound[:, :-1]


def _first_root_in_step(dem, coef, s_a, s_b):
    """First root of ``h - z`` on the model between ``s_a`` and ``s_b`` (one march step).

    The step is split where the ray's track crosses grid lines (at most one column and one
    row line: steps are under half a node spacing). Each piece lies in one cell, where
    ``f = h - z`` is close to a quadratic in the parameter: the quadratic through the
    piece's ends and middle locates the first root, and two Newton steps on the model
    ``f`` itself make it exact (to the model's accuracy, far below 1e-6 m).

    Returns
    -------
    found, left : ndarray of bool, shape (m,)
        A root was found; the step left the grid or met nodata before any root.
    s_root : ndarray, shape (m,)
    """
    n_rows, n_cols = dem.shape
    ends = np.stack([s_a, s_b], axis=1)
    _, c_ab, r_ab = _eval_model(coef, ends)
    u_col = _grid_line_crossing(coef, 1, s_a, s_b, c_ab[:, 0], c_ab[:, 1])
    u_row = _grid_line_crossing(coef, 2, s_a, s_b, r_ab[:, 0], r_ab[:, 1])
    breaks = [np.zeros_like(s_a), np.fmin(u_col, u_row), np.fmax(u_col, u_row),
              np.ones_like(s_a)]
    m = s_a.size
    found = np.zeros(m, dtype=bool)
    left = np.zeros(m, dtype=bool)
    s_root = np.full(m, np.nan)
    s_lo = np.full(m, np.nan)
    s_hi = np.full(m, np.nan)
    cell_i = np.zeros(m, dtype=np.intp)
    cell_j = np.zeros(m, dtype=np.intp)
    ds = s_b - s_a
    for p in range(3):
        ua, ub = breaks[p], breaks[p + 1]
        pending = ~found & ~left & (ub > ua)  # empty pieces: their point was just tested
        if not pending.any():
            continue
        sp = s_a[:, None] + np.stack([ua, 0.5 * (ua + ub), ub], axis=1) * ds[:, None]
        h, col, row = _eval_model(coef, sp)
        i = np.floor(col[:, 1])
        j = np.floor(row[:, 1])
        inside = (i >= 0) & (i <= n_cols - 2) & (j >= 0) & (j <= n_rows - 2)
        i = np.where(inside, i, 0).astype(np.intp)
        j = np.where(inside, j, 0).astype(np.intp)
        z = dem._cell_values(i[:, None], j[:, None], col - i[:, None], row - j[:, None])
        f = h - z
        bad = pending & ~(inside & np.isfinite(f).all(axis=1))
        left |= bad
        root = _first_quadratic_root(f[:, 0], f[:, 1], f[:, 2])
        new = pending & ~bad & np.isfinite(root)
        s_root[new] = (sp[:, 0] + root * (sp[:, 2] - sp[:, 0]))[new]
        s_lo[new] = sp[new, 0]
        s_hi[new] = sp[new, 2]
        cell_i[new] = i[new]
        cell_j[new] = j[new]
        found |= new
    hit = np.nonzero(found)[0]
    s_root[hit] = _newton_on_model(dem, coef[hit], s_root[hit], s_lo[hit], s_hi[hit],
                                        cell_i[hit], cell_j[hit])
    return found, left, s_root


def _newton_on_model(dem, coef, s, s_lo, s_hi, i, j, n_iter=2):
    """Newton steps on ``f(s) = h(s) - z(col(s), row(s))`` in one cell, kept in [s_lo, s_hi]."""
    n_cols = dem.shape[1]
    k = j * n_cols + i
    zf = dem._z_flat
    z00, z01 = zf.take(k), zf.take(k + 1)
    z10, z11 = zf.take(k + n_cols), zf.take(k + n_cols + 1)
    d_col = z01 - z00
    d_row = z10 - z00
    twist = z11 - z10 - z01 + z00
    for _ in range(n_iter):
        (h, col, row), (dh, dcol, drow) = _eval_model_d(coef, s)
        fc = col - i
        fr = row - j
        f = h - (z00 + fc * d_col + fr * d_row + fc * fr * twist)
        df = dh - (d_col + fr * twist) * dcol - (d_row + fc * twist) * drow
        with np.errstate(invalid="ignore", divide="ignore"):
            s_new = s - f / df
        s = np.where(np.isfinite(s_new), np.clip(s_new, s_lo, s_hi), s)
    return s


def _polish(dem, o, d, t, step_t):
    """Exact check of model roots; bracketed Illinois where ``|h - z| >= 1e-4 m``.

    Returns
    -------
    t : ndarray, shape (m,)
        Ray parameters (NaN where no root could be confirmed).
    lon_lat_h : ndarray, shape (m, 3)
        Geodetic coordinates of ``o + t d``.
    """
    f, lon, lat, h, _ = _residual_exact(dem, o, d, t)
    geo = np.stack([lon, lat, h], axis=1)
    todo = np.nonzero(~(np.abs(f) < _SURFACE_TOL_M))[0]
    if todo.size == 0:
        return t, geo
    t = t.copy()
    o, d, tr, w = o[todo], d[todo], t[todo], np.minimum(0.05, 0.5 * step_t[todo])
    ta, tb = tr - w, tr + w
    fa, *_ = _residual_exact(dem, o, d, ta)
    fb, *_ = _residual_exact(dem, o, d, tb)
    fr = f[todo]
    # Keep the first sub-bracket holding a sign change.
    first_half = (fa > 0.0) & (fr <= 0.0)
    tb = np.where(first_half, tr, tb)
    fb = np.where(first_half, fr, fb)
    ta = np.where(first_half, ta, tr)
    fa = np.where(first_half, fa, fr)
    bracketed = (fa > 0.0) & (fb <= 0.0)
    best = tr.copy()
    side = np.zeros(todo.size, dtype=np.int8)
    active = bracketed.copy()
    for it in range(60):
        if not active.any():
            break
        with np.errstate(invalid="ignore", divide="ignore"):
            tn = (ta * fb - tb * fa) / (fb - fa)
        bisect = ~((tn > ta) & (tn < tb)) | (it % 4 == 3)
        tn = np.where(bisect, 0.5 * (ta + tb), tn)
        fn, *_ = _residual_exact(dem, o, d, tn)
        best = np.where(active, tn, best)
        done = active & (np.abs(fn) < _SURFACE_TOL_M)
        low = active & (fn > 0.0)
        high = active & ~(fn > 0.0)
        # Illinois: halve the retained end's value when the same end is kept twice.
        fb = np.where(low & (side == 1), 0.5 * fb, fb)
        fa = np.where(high & (side == -1), 0.5 * fa, fa)
        ta = np.where(low, tn, ta)
        fa = np.where(low, fn, fa)
        tb = np.where(high, tn, tb)
        fb = np.where(high, fn, fb)
        side = np.where(low, 1, np.where(high, -1, side)).astype(np.int8)
        active &= ~done & ((tb - ta) > 1e-9)
    # Unbracketed: a graze within the model error; keep the model root.
    f_best, lon, lat, h, _ = _residual_exact(dem, o, d, best)
    ok = np.abs(f_best) < max(100.0 * _SURFACE_TOL_M, 1e-2)
    t[todo] = np.where(ok, best, np.nan)
    geo[todo] = np.stack([lon, lat, h], axis=1)
    return t, geo


def _solve_model_height(coef, h_target, s_lo, s_hi):
    """Parameter in [s_lo, s_hi] where the model height equals ``h_target`` (h decreasing).

    A chord estimate then one Newton step on the cubic (the chord is off by the ray's
    curvature in height, under a metre for brackets of a few km; Newton removes that).
    Clipped to the interval; NaN where ``h_target`` is not finite.
    """
    c0, c1, c2, c3 = (coef[:, 0, k] for k in range(4))
    h_lo = ((c3 * s_lo + c2) * s_lo + c1) * s_lo + c0
    h_hi = ((c3 * s_hi + c2) * s_hi + c1) * s_hi + c0
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip(s_lo + (h_lo - h_target) / (h_lo - h_hi) * (s_hi - s_lo), s_lo, s_hi)
        h = ((c3 * s + c2) * s + c1) * s + c0
        dh = (3.0 * c3 * s + 2.0 * c2) * s + c1
        s = np.clip(s - (h - h_target) / dh, s_lo, s_hi)
    return np.where(np.isfinite(h_target), s, np.nan)


def _eval_model(coef, s):
    """Cubic model at ``s``: coef (m, 3, 4) monomial coefficients, s (m, k) -> 3 x (m, k)."""
    out = []
    for q in range(3):
        c0, c1, c2, c3 = (coef[:, q, k, None] for k in range(4))
        out.append(((c3 * s + c2) * s + c1) * s + c0)
    return out


def _eval_model_d(coef, s):
    """Cubic model and its derivative at ``s`` of shape (m,): two lists of 3 x (m,)."""
    values, slopes = [], []
    for q in range(3):
        c0, c1, c2, c3 = (coef[:, q, k] for k in range(4))
        values.append(((c3 * s + c2) * s + c1) * s + c0)
        slopes.append((3.0 * c3 * s + 2.0 * c2) * s + c1)
    return values, slopes


def _grid_line_crossing(coef, q, s_a, s_b, v_a, v_b):
    """Fraction ``u`` in [0, 1] of a step where model quantity ``q`` crosses an integer.

    ``v_a``, ``v_b`` are its values at the step's ends; at most one integer lies between
    them. The chord gives a first estimate, one Newton step on the cubic makes it exact.
    Returns 1 where no integer is crossed.
    """
    n = np.floor(np.maximum(v_a, v_b))
    crosses = (np.minimum(v_a, v_b) < n) & (v_b != v_a)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.clip((n - v_a) / (v_b - v_a), 0.0, 1.0)
        ds = s_b - s_a
        s = s_a + u * ds
        c0, c1, c2, c3 = (coef[:, q, k] for k in range(4))
        value = ((c3 * s + c2) * s + c1) * s + c0
        slope = ((3.0 * c3 * s + 2.0 * c2) * s + c1) * ds
        u_newton = u - (value - n) / slope
    u = np.where(np.isfinite(u_newton), np.clip(u_newton, 0.0, 1.0), u)
    return np.where(crosses, u, 1.0)


def _first_quadratic_root(f0, fm, f1):
    """Smallest ``u`` in [0, 1] where the quadratic through (0, f0), (1/2, fm), (1, f1) is 0.

    ``f(u) = f0 + b u + c u^2`` with ``c = 2 (f0 - 2 fm + f1)``, ``b = f1 - f0 - c``. Roots by
    the cancellation-free pair ``q / c`` and ``f0 / q`` with
    ``q = -(b + sign(b) sqrt(b^2 - 4 c f0)) / 2``, which also covers the linear case ``c = 0``.
    NaN where there is none.
    """
    c = 2.0 * (f0 - 2.0 * fm + f1)
    b = f1 - f0 - c
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = b * b - 4.0 * c * f0
        q = -0.5 * (b + np.copysign(np.sqrt(disc), b))
        r1 = q / c
        r2 = f0 / q
    eps = 1e-12
    r1 = np.where((r1 >= -eps) & (r1 <= 1.0 + eps), r1, np.nan)
    r2 = np.where((r2 >= -eps) & (r2 <= 1.0 + eps), r2, np.nan)
    root = np.clip(np.fmin(r1, r2), 0.0, 1.0)
    root = np.where(f0 <= 0.0, 0.0, root)
    # An end at zero or below that rounding hid from the formula still counts.
    root = np.where(np.isnan(root) & (f1 <= 0.0), 1.0, root)
    return root
