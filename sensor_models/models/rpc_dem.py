"""RPC00B polynomial kernel and Newton's intersection of an RPC's lines of sight with a DEM.

:func:`rpc00b_monomials` builds the 20 RPC00B monomials; :func:`derivative_coefficients` turns
the (20, 4) coefficient matrix of an RPC into the (20, 16) matrix whose product with those same
monomials gives the four cubics *and* their derivatives with respect to the normalized
longitude, latitude and height (a derivative of a cubic is a quadratic, itself a combination of
the 20 monomials), so one matrix product yields a projection and its Jacobian.

:func:`intersect_dem_newton` solves, for each image point, the three equations
``row(L, P, H) = row0``, ``col(L, P, H) = col0`` and ``dem(lon, lat) = h`` for the normalized
ground point ``(L, P, H)`` by Newton's method in the three unknowns, with the DEM's bilinear
slope as the third row of the Jacobian. Each iteration costs one evaluation of the RPC with its
derivatives and one DEM lookup; points stop when they reproject within ``tol_px`` (max norm) and
lie within ``tol_m`` of the DEM at the same evaluation, so every returned point meets both
bounds. The iteration starts from the fixed point ``h <- dem(inverse(row, col, h))`` of a
quadratic approximate inverse of the RPC (fitted once per model, :func:`fit_approximate_inverse`).
Points that do not converge within ``max_iter`` iterations (steep slopes seen at grazing angles,
where Newton may cycle between DEM cells; lines of sight that cross a void or the DEM's edge
during the iteration) are reported, and :class:`~sensor_models.models.rpc.RpcModel` localizes
them by its bracketed search instead.
"""

from __future__ import annotations

import numpy as np

__all__ = ["derivative_coefficients", "fit_approximate_inverse", "intersect_dem_newton", "rpc00b_monomials"]

#: Exponents (of L, P, H) of the 20 RPC00B monomials, in coefficient order.
EXPONENTS = (
    (0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (2, 0, 0),
    (0, 2, 0), (0, 0, 2), (1, 1, 1), (3, 0, 0), (1, 2, 0), (1, 0, 2), (2, 1, 0), (0, 3, 0),
    (0, 1, 2), (2, 0, 1), (0, 2, 1), (0, 0, 3),
)  # fmt: skip

#: points per block of the Newton iteration (its temporaries stay in cache)
BLOCK = 1 << 13


def rpc00b_monomials(L, P, H):
    """RPC00B monomials, shape (20, N), for normalized coordinates of shape (N,)."""
    T = np.empty((20, L.shape[0]))
    T[0] = 1.0
    T[1], T[2], T[3] = L, P, H
    np.multiply(L, P, out=T[4])
    np.multiply(L, H, out=T[5])
    np.multiply(P, H, out=T[6])
    np.multiply(L, L, out=T[7])
    np.multiply(P, P, out=T[8])
    np.multiply(H, H, out=T[9])
    np.multiply(T[4], H, out=T[10])  # P*L*H
    np.multiply(T[7], L, out=T[11])  # L^3
    np.multiply(T[8], L, out=T[12])  # L*P^2
    np.multiply(T[9], L, out=T[13])  # L*H^2
    np.multiply(T[7], P, out=T[14])  # L^2*P
    np.multiply(T[8], P, out=T[15])  # P^3
    np.multiply(T[9], P, out=T[16])  # P*H^2
    np.multiply(T[7], H, out=T[17])  # L^2*H
    np.multiply(T[8], H, out=T[18])  # P^2*H
    np.multiply(T[9], H, out=T[19])  # H^3
    return T


def derivative_coefficients(coef):
    """Coefficients of the cubics and of their L, P, H derivatives on the RPC00B monomials.

    Parameters
    ----------
    coef : ndarray, shape (20, 4)
        The four cubics (line num, line den, samp num, samp den), RPC00B term order.

    Returns
    -------
    ndarray, shape (20, 16)
        Columns 0-3: ``coef``; 4-7: d/dL; 8-11: d/dP; 12-15: d/dH, so that
        ``derivative_coefficients(coef).T @ rpc00b_monomials(L, P, H)`` holds the values and
        derivatives of the four cubics.
    """
    index = {e: k for k, e in enumerate(EXPONENTS)}
    out = np.zeros((20, 16))
    out[:, 0:4] = coef
    for axis in range(3):
        for k, e in enumerate(EXPONENTS):
            if e[axis] == 0:
                continue
            lower = list(e)
            lower[axis] -= 1
            out[index[tuple(lower)], 4 * (axis + 1):4 * (axis + 2)] += e[axis] * coef[k]
    return out


def _quadratic_basis(u, v, w):
    return np.stack([np.ones_like(u), u, v, w, u * v, u * w, v * w, u * u, v * v, w * w])


def fit_approximate_inverse(project):
    """A quadratic approximation of an RPC's inverse, fitted on a grid over its normalized cube.

    Parameters
    ----------
    project : callable
        ``project(L, P, H) -> (line_n, samp_n)``: the RPC's normalized image coordinates.

    Returns
    -------
    ndarray, shape (10, 2)
        Coefficients of ``(L, P)`` on the quadratic monomials of ``(line_n, samp_n, H)``
        (:func:`approximate_inverse` evaluates them); only a starting point for Newton.
    """
    g = np.linspace(-1.0, 1.0, 9)
    L, P, H = (a.reshape(-1) for a in np.meshgrid(g, g, np.linspace(-1.0, 1.0, 5), indexing="ij"))
    u, v = project(L, P, H)
    ok = np.isfinite(u) & np.isfinite(v)
    basis = _quadratic_basis(u[ok], v[ok], H[ok]).T
    sol, *_ = np.linalg.lstsq(basis, np.stack([L[ok], P[ok]], axis=1), rcond=None)
    return sol


def approximate_inverse(inv, u, v, w):
    """``(L, P)`` of :func:`fit_approximate_inverse`'s coefficients ``inv`` at normalized
    image coordinates ``u, v`` (line, samp) and normalized heights ``w``."""
    b = _quadratic_basis(u, v, w)
    return inv[:, 0] @ b, inv[:, 1] @ b


def intersect_dem_newton(rpc, row_rpc, col_rpc, dem, h_range, *, tol_px, tol_m, max_iter=12):
    """Newton's method in ``(L, P, H)`` for the intersection of lines of sight with a DEM.

    Parameters
    ----------
    rpc : RpcModel
        The model (offsets, scales, :meth:`~RpcModel.rpc_kernel`).
    row_rpc, col_rpc : ndarray, shape (N,)
        Image points without the bias correction (first pixel centre at 0.5).
    dem : object
        With ``height_and_slope_m(lon, lat) -> (h, dh_dlon, dh_dlat)`` (metres, metres per
        degree; NaN outside the DEM and next to voids).
    h_range : (float, float)
        Heights the iterates are kept within (the DEM's range, widened a little).
    tol_px, tol_m : float
        Reprojection (max norm, pixels) and height (metres) tolerances met by every returned
        point at the same evaluation.
    max_iter : int
        Iterations before a point is given up.

    Returns
    -------
    lon, lat, h : ndarray, shape (N,)
        NaN where the iteration did not converge (``done`` False).
    done : ndarray of bool, shape (N,)
    """
    n = row_rpc.shape[0]
    out = [np.full(n, np.nan) for _ in range(3)]
    done = np.zeros(n, dtype=bool)
    for s in range(0, n, BLOCK):
        sl = slice(s, s + BLOCK)
        lon, lat, h, ok = _newton_block(rpc, row_rpc[sl], col_rpc[sl], dem, h_range, tol_px, tol_m, max_iter)
        out[0][sl], out[1][sl], out[2][sl], done[sl] = lon, lat, h, ok
    return out[0], out[1], out[2], done


def _newton_block(rpc, row_rpc, col_rpc, dem, h_range, tol_px, tol_m, max_iter):
    coef16, inv = rpc.rpc_kernel()
    ls, lo = rpc.line_scale, rpc.line_off + 0.5
    ss, so = rpc.samp_scale, rpc.samp_off + 0.5
    lon_s, lon_o, lat_s, lat_o = rpc.lon_scale, rpc.lon_off, rpc.lat_scale, rpc.lat_off
    hs, ho = rpc.height_scale, rpc.height_off
    h_lo, h_hi = h_range
    n = row_rpc.shape[0]
    u = (row_rpc - lo) / ls
    v = (col_rpc - so) / ss
    # start: two rounds of the fixed point h <- dem(approximate inverse at h), from mid-range
    h = np.full(n, 0.5 * (h_lo + h_hi))
    for _ in range(2):
        L, P = approximate_inverse(inv, u, v, (h - ho) / hs)
        with np.errstate(invalid="ignore"):
            z = dem.height_and_slope_m(L * lon_s + lon_o, P * lat_s + lat_o)[0]
        h = np.where(np.isfinite(z), np.clip(z, h_lo, h_hi), h)
    L, P = approximate_inverse(inv, u, v, (h - ho) / hs)
    out_lon, out_lat, out_h = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    done = np.zeros(n, dtype=bool)
    active = np.arange(n)
    row_t, col_t = row_rpc, col_rpc
    for _ in range(max_iter):
        if active.size == 0:
            break
        lon = L * lon_s + lon_o
        lat = P * lat_s + lat_o
        with np.errstate(invalid="ignore"):
            z, z_lon, z_lat = dem.height_and_slope_m(lon, lat)
        V = coef16.T @ rpc00b_monomials(L, P, (h - ho) / hs)  # (16, m)
        nl, dl, ns, ds = V[0], V[1], V[2], V[3]
        with np.errstate(divide="ignore", invalid="ignore"):
            ql, qs = ls / dl, ss / ds
            fr = nl * ql + lo - row_t
            fc = ns * qs + so - col_t
            dz = z - h
            conv = (np.abs(fr) <= tol_px) & (np.abs(fc) <= tol_px) & (np.abs(dz) <= tol_m)
        if conv.any():
            ids = active[conv]
            out_lon[ids], out_lat[ids], out_h[ids] = lon[conv], lat[conv], h[conv]
            done[ids] = True
            keep = ~conv
            active, L, P, h, row_t, col_t, z_lon, z_lat, fr, fc, dz, V, ql, qs = (
                x[..., keep] for x in (active, L, P, h, row_t, col_t, z_lon, z_lat, fr, fc, dz, V, ql, qs))
            nl, dl, ns, ds = V[0], V[1], V[2], V[3]
        # Jacobian of (row, col) in (L, P, H): d(N/D) = (dN - (N/D) dD) / D, scaled
        rl, rs = nl / dl, ns / ds
        j = [(V[4 * a + 4] - rl * V[4 * a + 5]) * ql for a in range(3)]
        k = [(V[4 * a + 6] - rs * V[4 * a + 7]) * qs for a in range(3)]
        with np.errstate(divide="ignore", invalid="ignore"):
            det = j[0] * k[1] - j[1] * k[0]
            # (dL, dP) = a + b * dh solve the two image equations; the DEM's gives dh
            aL = (k[1] * -fr + j[1] * fc) / det
            aP = (j[0] * -fc + k[0] * fr) / det
            bL = (-k[1] * j[2] + j[1] * k[2]) / (det * hs)
            bP = (-j[0] * k[2] + k[0] * j[2]) / (det * hs)
            gL, gP = z_lon * lon_s, z_lat * lat_s
            dh = (dz + gL * aL + gP * aP) / (1.0 - gL * bL - gP * bP)
            dh = np.clip(h + dh, h_lo, h_hi) - h
            dL, dP = aL + bL * dh, aP + bP * dh
            # limit steps to the size of the normalized domain, so a bad start cannot fly off
            step = np.maximum(np.abs(dL), np.abs(dP))
            damp = np.where(step > 0.5, 0.5 / step, 1.0)
            good = np.isfinite(dh) & np.isfinite(step)
        if not good.all():
            active, L, P, h, row_t, col_t, dL, dP, dh, damp = (
                x[good] for x in (active, L, P, h, row_t, col_t, dL, dP, dh, damp))
        L = L + damp * dL
        P = P + damp * dP
        h = h + damp * dh
    return out_lon, out_lat, out_h, done
