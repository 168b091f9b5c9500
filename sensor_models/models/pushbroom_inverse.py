"""Inverse localization of the push-broom model and its analytic Jacobians.

Functions of a :class:`~sensor_models.models.pushbroom.PushbroomModel` (module docstring there):
for each ground point ``G`` the two collinearity conditions

.. math::

    F(row, s) = \\left(\\frac{v_x}{v_z} - \\tan\\psi_x(s),\\;
                       \\frac{v_y}{v_z} - \\tan\\psi_y(s)\\right) = 0,
    \\qquad \\mathbf{v} = (R^{itrf}_{body} R^{body}_{cam})^T (\\mathbf{G} - \\mathbf{P})

are solved by Newton's method, vectorized over points (:func:`collinearity`,
:func:`solve_ccd`, :func:`ground_to_image_chunk`), and the implicit-function theorem gives the
image-space Jacobian ``d(row, s)/dp = -J_{(row,s)}^{-1} \\partial F / \\partial p`` with respect
to the installation angles, the directional-angle coefficients and the attitude-correction
coefficients (:func:`parameter_jacobian`), or to body-frame attitude angles
(:func:`body_angle_jacobian`). ``PushbroomModel`` below is that class.
"""

from __future__ import annotations

import numpy as np

from sensor_models.base import as_float_arrays
from sensor_models.errors import InputError
from sensor_models.geometry.geodesy import geodetic_to_ecef
from sensor_models.models.pushbroom_types import CcdLook, Installation

__all__ = [
    "CHUNK",
    "body_angle_jacobian",
    "ccd_chunk",
    "collinearity",
    "ground_to_image_chunk",
    "parameter_jacobian",
    "solve_ccd",
]

#: points processed at once; bounds temporary memory to a few tens of MB
CHUNK = 1 << 16


def ccd_chunk(ccd, a, b):
    """The slice ``a:b`` of a per-point CCD selection (names and scalars pass through).

    Parameters
    ----------
    ccd : str or int or array_like or None
        A CCD for all points, or one per point.
    a, b : int
        The chunk's first and past-the-end points.

    Returns
    -------
    str or int or ndarray or None
    """
    if ccd is None or isinstance(ccd, str) or np.ndim(ccd) == 0:
        return ccd
    return np.asarray(ccd).reshape(-1)[a:b]


# ------------------------------------------------------------------ inverse localization
def collinearity(model, row, s, ground, ccd: CcdLook, r_inst):
    """``F(row, s)`` and its 2x2 Jacobian in ``(row, s)``; also the camera vector.

    Parameters
    ----------
    model : PushbroomModel
    row, s : ndarray, shape (N,)
        Rows and detector indices of the current solutions.
    ground : ndarray, shape (N, 3)
        ECEF points, metres.
    ccd : CcdLook
    r_inst : ndarray, shape (3, 3)
        The installation matrix.

    Returns
    -------
    f : ndarray, shape (N, 2)
    jac : ndarray, shape (N, 2, 2)
        ``dF/d(row, s)``.
    cam : ndarray, shape (N, 3)
        ``R_inst^T R^T (G - P)``.
    """
    p, r, dp, dr = model.exterior_at_rows(row, derivative=True)
    w = ground - p
    cam = r_inst.T @ np.einsum("nji,nj->ni", r, w)[..., None]  # R_inst^T R^T w
    cam = cam[..., 0]
    dcam = np.einsum("nji,nj->ni", dr, w) - np.einsum("nji,nj->ni", r, dp)
    dcam = dcam @ r_inst
    x, y, z = cam[:, 0], cam[:, 1], cam[:, 2]
    tx, ty, dtx, dty = ccd.look(s)
    f = np.stack([x / z - tx, y / z - ty], axis=-1)
    jac = np.empty((row.size, 2, 2))
    jac[:, 0, 0] = (dcam[:, 0] * z - x * dcam[:, 2]) / (z * z)
    jac[:, 1, 0] = (dcam[:, 1] * z - y * dcam[:, 2]) / (z * z)
    jac[:, 0, 1] = -dtx
    jac[:, 1, 1] = -dty
    return f, jac, cam


def solve_ccd(model, ground, ccd: CcdLook, row0, s0, *, max_iter=30, tol=1e-10, noise_px=1e-7):
    """Newton solution of the collinearity equations for one CCD (vectorized).

    A point converges when its Newton step falls below ``tol`` pixels. Near the solution
    the step can settle into a limit cycle at the floating-point noise floor of the
    collinearity equations (about 1e-10 px on a 12 000-line SPOT 5 scene), never going
    below ``tol``; a point whose last step is below ``noise_px`` after ``max_iter``
    iterations is therefore converged too (its error is below that step). Only points
    whose steps stay larger than ``noise_px``, or whose ray misses, get NaN. A point that
    Newton sends past the line table's edge twice running is outside the rows the data cover
    and stops there (NaN, as it would be at the end: orthoimages of scenes cut from longer
    strips have many such nodes; on ``bench/bench_ortho.py``'s scene 1 385 Newton steps
    instead of 2 540, the same pixels).

    Parameters
    ----------
    model : PushbroomModel
    ground : ndarray, shape (N, 3)
        ECEF points, metres.
    ccd : CcdLook
    row0, s0 : ndarray, shape (N,)
        Starting rows and detector indices.
    max_iter, tol, noise_px
        Newton iterations and the step thresholds (pixels) above.

    Returns
    -------
    row, s : ndarray, shape (N,)
        NaN where not converged or at the line table's edge.
    """
    lo, hi = model.row_range
    r_inst = model.installation.matrix()
    row = row0.copy()
    s = s0.copy()
    ok = np.zeros(row.size, dtype=bool)
    active = np.arange(row.size)
    last_step = np.full(row.size, np.inf)
    pinned = np.zeros(row.size, dtype=bool)  # of the active points: at the table's edge after the last step
    for _ in range(max_iter):
        if active.size == 0:
            break
        f, jac, cam = collinearity(model, row[active], s[active], ground[active], ccd, r_inst)
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        d_row = -(jac[:, 1, 1] * f[:, 0] - jac[:, 0, 1] * f[:, 1]) / det
        d_s = -(-jac[:, 1, 0] * f[:, 0] + jac[:, 0, 0] * f[:, 1]) / det
        behind = ~(cam[:, 2] > 0.0) | ~np.isfinite(d_row) | ~np.isfinite(d_s)
        new_row = np.clip(row[active] + d_row, lo, hi)
        # the detector index is bounded to a generous range for robustness
        new_s = np.clip(s[active] + d_s, -10.0 * ccd.n_detectors, 11.0 * ccd.n_detectors)
        row[active] = new_row
        s[active] = new_s
        last_step[active] = np.where(behind, np.inf, np.maximum(np.abs(d_row), np.abs(d_s)))
        done = (np.abs(d_row) < tol) & (np.abs(d_s) < tol * max(1.0, ccd.n_detectors))
        ok[active[done & ~behind]] = True
        # a point Newton sends past the table's edge twice running lies outside the rows the
        # data cover: it would end at the edge, not imaged (below), after every remaining step
        at_edge = (new_row <= lo + 1e-9) | (new_row >= hi - 1e-9)
        keep = ~done & ~behind & ~(at_edge & pinned)
        active, pinned = active[keep], at_edge[keep]
    ok[active[last_step[active] < noise_px]] = True  # settled at the noise floor
    row[~ok] = np.nan
    s[~ok] = np.nan
    # a solution pinned at the table edge is outside the data: not imaged
    edge = (row <= lo + 1e-9) | (row >= hi - 1e-9)
    row[edge] = np.nan
    s[edge] = np.nan
    return row, s


def ground_to_image_chunk(model, ground, band, ccd):
    """Inverse localization of a chunk of ECEF points on the CCDs of one band.

    With ``ccd=None`` the points are solved on the band's middle CCD, then each is moved to the
    CCD whose across-track look range contains its look and solved there (the first CCD on an
    overlap, the nearest when none does); otherwise on the CCD(s) given.

    Parameters
    ----------
    model : PushbroomModel
    ground : ndarray, shape (N, 3)
        ECEF points, metres.
    band : str or None
        The band (None: the reference band).
    ccd : str or int or ndarray or None
        Forced CCD(s) (:meth:`PushbroomModel.ccd_index`).

    Returns
    -------
    row, col : ndarray, shape (N,)
        NaN where not imaged.
    idx : ndarray of int, shape (N,)
        The CCD of each point.
    """
    ccds = model.band_ccds(band)
    n = ground.shape[0]
    row0 = np.full(n, 0.5 * model.n_rows)
    mid = -1
    if ccd is not None:
        idx = model.ccd_index(np.zeros(n), band=band, array=ccd)
    else:
        # solve on the middle CCD, then move each point to the CCD that sees it
        mid = len(ccds) // 2
        c = ccds[mid]
        row_m, s_m = solve_ccd(model, ground, c, row0, np.full(n, 0.5 * (c.n_detectors - 1)))
        idx = np.full(n, mid, dtype=np.intp)
        if len(ccds) > 1:
            idx = _assign_ccd_by_look(model, ground, row_m, ccds, fallback=mid)
        row0 = np.where(np.isfinite(row_m), row_m, row0)
    row = np.full(n, np.nan)
    col = np.full(n, np.nan)
    for i, c in enumerate(ccds):
        sel = np.nonzero(idx == i)[0]
        if sel.size == 0:
            continue
        if ccd is None and i == mid:  # already solved on this CCD
            row[sel] = row_m[sel]
            col[sel] = s_m[sel] + c.first_col + 0.5
            continue
        r, s = solve_ccd(model, ground[sel], c, row0[sel], np.full(sel.size, 0.5 * (c.n_detectors - 1)))
        row[sel] = r
        col[sel] = s + c.first_col + 0.5
    return row, col, idx


def _assign_ccd_by_look(model, ground, row, ccds, *, fallback):
    """Pick, per point, the CCD whose across-track look range contains the point's look."""
    n = ground.shape[0]
    good = np.isfinite(row)
    idx = np.full(n, fallback, dtype=np.intp)
    if not np.any(good):
        return idx
    p, r = model.exterior_at_rows(row[good])
    cam = np.einsum("nji,nj->ni", r, ground[good] - p) @ model.installation.matrix()
    ty = cam[:, 1] / cam[:, 2]
    best = np.full(ty.size, np.inf)
    choice = np.full(ty.size, fallback, dtype=np.intp)
    for i, c in enumerate(ccds):
        _, lo_y, _, _ = c.look(np.array([-0.5]))
        _, hi_y, _, _ = c.look(np.array([c.n_detectors - 0.5]))
        lo_y, hi_y = sorted((float(lo_y[0]), float(hi_y[0])))
        dist = np.maximum(np.maximum(lo_y - ty, ty - hi_y), 0.0)
        better = dist < best  # strict: the first CCD wins on overlaps
        choice[better] = i
        best[better] = dist[better]
    idx[good] = choice
    return idx


# ------------------------------------------------------------------ Jacobians
def parameter_jacobian(model, lon, lat, h, *, band, names, ccd):
    """Analytic ``d(row, col)/d(parameters)`` at the projections of ground points.

    The body of :meth:`PushbroomModel.image_jacobian` (see there), after its checks.

    Parameters
    ----------
    model : PushbroomModel
    lon, lat, h : array_like, shape (N,)
        Ground points: degrees, degrees, metres above the ellipsoid.
    band : str
        A band of the model.
    names : sequence of str or None
        Parameters (None: all, in :meth:`PushbroomModel.parameter_names` order).
    ccd : str or int or array_like or None
        Force the CCD.

    Returns
    -------
    row, col : ndarray, shape (N,)
    jac : ndarray, shape (N, 2, P)
    """
    all_names = model.parameter_names()
    names = all_names if names is None else tuple(names)
    lookup = {n: i for i, n in enumerate(all_names)}
    unknown = [n for n in names if n not in lookup]
    if unknown:
        raise InputError(f"unknown parameters: {', '.join(unknown)}")
    lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
    lon, lat, h = lon.reshape(-1), lat.reshape(-1), h.reshape(-1)
    ground = geodetic_to_ecef(lon, lat, h)
    n = ground.shape[0]
    row = np.full(n, np.nan)
    col = np.full(n, np.nan)
    jac = np.zeros((n, 2, len(names)))
    col_of = {name: j for j, name in enumerate(names)}
    ccds = model.band_ccds(band)
    for a in range(0, n, CHUNK):
        g = ground[a : a + CHUNK]
        r_c, c_c, idx = ground_to_image_chunk(model, g, band, ccd_chunk(ccd, a, a + CHUNK))
        row[a : a + CHUNK], col[a : a + CHUNK] = r_c, c_c
        for i, c in enumerate(ccds):
            sel = np.nonzero((idx == i) & np.isfinite(r_c))[0]
            if sel.size == 0:
                continue
            s = c_c[sel] - c.first_col - 0.5
            inv, dfdp = _collinearity_partials(model, r_c[sel], s, g[sel], band, c, col_of, len(names))
            # d(row, s)/dp = -J^-1 dF/dp ; col = s + const
            jac[a + sel] = -np.einsum("nij,njp->nip", inv, dfdp)
    return row, col, jac


def _ratio_derivative(cam, dcam):
    """``d(x/z, y/z)`` (N, 2) for camera vectors ``cam`` and their derivatives ``dcam``."""
    x, y, z = cam[:, 0], cam[:, 1], cam[:, 2]
    return np.stack([(dcam[:, 0] * z - x * dcam[:, 2]) / (z * z), (dcam[:, 1] * z - y * dcam[:, 2]) / (z * z)], axis=-1)


def _collinearity_partials(model, row, s, ground, band, c, col_of, n_names):
    """``J_(row,s)^-1`` (N,2,2) and ``dF/dp`` (N,2,P) at solved points of one CCD."""
    r_inst = model.installation.matrix()
    _, jrs, cam = collinearity(model, row, s, ground, c, r_inst)
    inv = np.linalg.inv(jrs)
    body = cam @ r_inst.T  # R^T (G - P) = R_inst cam, already evaluated above
    dfdp = np.zeros((row.size, 2, n_names))
    d_inst = model.installation.matrix_derivatives()
    for k, ax in enumerate(Installation.NAMES):
        j = col_of.get(f"installation.{ax}")
        if j is not None:
            dfdp[:, :, j] = _ratio_derivative(cam, body @ d_inst[k])  # (dR_inst/da)^T body
    for axis, comp in (("tan_psi_x", 0), ("tan_psi_y", 1)):
        for k in range(getattr(c, axis).size):
            j = col_of.get(f"{band}.{c.name}.{axis}.c{k}")
            if j is not None:
                dfdp[:, comp, j] = -(s**k)
    corr = model.attitude_correction
    if corr is not None:
        cols = np.array([col_of.get(nm, -1) for nm in corr.names()]).reshape(3, -1)
        if np.any(cols >= 0):
            dfdd, basis = _angle_partials(model, row, cam, body)
            for ax in range(3):
                for k in np.nonzero(cols[ax] >= 0)[0]:
                    dfdp[:, :, cols[ax, k]] = dfdd[:, :, ax] * basis[:, k : k + 1]
    return inv, dfdp


def _angle_partials(model, row, cam, body):
    """``dF/ddelta`` (N,2,3) of the correction angles and the basis (N,K) at ``row``."""
    c, dc, _ = model.correction_at_rows(row)
    basis, _ = model.attitude_correction.basis(model.line_timing.seconds(row))
    body0 = np.einsum("nij,nj->ni", c, body)  # R^T (G - P) without the correction
    r_inst = model.installation.matrix()
    dfdd = np.empty((row.size, 2, 3))
    for ax in range(3):
        dcam = np.einsum("nji,nj->ni", dc[ax], body0) @ r_inst  # R_inst^T dC^T body0
        dfdd[:, :, ax] = _ratio_derivative(cam, dcam)
    return dfdd, basis


def body_angle_jacobian(model, lon, lat, h, *, band, ccd):
    """``d(row, col)/d(delta)`` of body-frame attitude angles at the projections of ground points.

    The body of :meth:`PushbroomModel.attitude_angle_jacobian` (see there), after its checks.

    Parameters
    ----------
    model : PushbroomModel
        A model with an attitude correction.
    lon, lat, h : array_like, shape (N,)
        Ground points: degrees, degrees, metres above the ellipsoid.
    band : str
        A band of the model.
    ccd : str or int or array_like or None
        Force the CCD.

    Returns
    -------
    row, col : ndarray, shape (N,)
    jac : ndarray, shape (N, 2, 3)
        Pixels per radian of roll, pitch, yaw.
    """
    lon, lat, h = as_float_arrays(lon, lat, h, names=("lon", "lat", "h"))
    ground = geodetic_to_ecef(lon.reshape(-1), lat.reshape(-1), h.reshape(-1))
    n = ground.shape[0]
    row, col = np.full(n, np.nan), np.full(n, np.nan)
    jac = np.full((n, 2, 3), np.nan)
    r_inst = model.installation.matrix()
    for a in range(0, n, CHUNK):
        g = ground[a : a + CHUNK]
        r_c, c_c, idx = ground_to_image_chunk(model, g, band, ccd_chunk(ccd, a, a + CHUNK))
        row[a : a + CHUNK], col[a : a + CHUNK] = r_c, c_c
        for i, c in enumerate(model.band_ccds(band)):
            sel = np.nonzero((idx == i) & np.isfinite(r_c))[0]
            if sel.size:
                s = c_c[sel] - c.first_col - 0.5
                _, jrs, cam = collinearity(model, r_c[sel], s, g[sel], c, r_inst)
                dfdd, _ = _angle_partials(model, r_c[sel], cam, cam @ r_inst.T)
                jac[a + sel] = -np.einsum("nij,njp->nip", np.linalg.inv(jrs), dfdd)
    return row, col, jac
