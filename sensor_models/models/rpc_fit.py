"""Fitting an RPC00B model to any sensor model (terrain-independent, Tao & Hu 2001).

The fit
-------
The sensor model is sampled on three grids of image points ``(row, col)`` localized at height
layers ``h`` spanning ``height_range_m``: ``model.image_to_ground(row, col, height=h)``.

* the *fit* grid, ``grid_shape = (n_r, n_c, n_h)`` nodes with both ends of every axis (pixel
  centres ``0.5`` and ``n - 0.5``, both ends of the height range);
* the *validation* grid: the centres of the fit grid's cells (``n - 1`` per axis), which chooses
  the regularization;
* the *check* grid: ``check_grid_shape`` cell centres (default ``2 (n - 1)`` per axis, the
  quarter points of the fit cells) plus the first and last pixel centres on the row and column
  axes (the largest errors sit on the image's borders), all at the cell-centre heights: no
  point of it is a fit or validation point, and it covers the whole image and height range.
  Its errors are the ones reported.

Offsets and scales are the RPC00B normalization (centre and half-span of the ground and image
extents, :func:`normalization`). With ``T`` the 20 RPC00B monomials of the normalized ground
coordinates and ``y`` a normalized image coordinate, each of line and sample is

.. math:: y = \\frac{T a}{T b}, \\qquad b_0 = 1,

fitted by the iteratively reweighted linearized least squares of Tao & Hu [1]_ (sec.
"Iterative least-squares solution"): pass ``k`` solves

.. math:: \\min_x \\; \\| W_k (A x - y) \\|^2 + \\lambda \\| S x \\|^2,
          \\quad A = [T, \\; -\\mathrm{diag}(y) T_{1:}], \\quad x = (a, b_{1:}),

with ``W_k = diag(1 / (T b_{k-1}))`` (weights ``1 / B^2`` on the squared residuals, so that the
linearized residual ``T a - y T b`` divided by ``B = T b`` is the image error), ``S`` the column
norms of ``A`` (so ``lambda`` is relative) and the Tikhonov (ridge) term ``lambda`` of [1]_ and
[2]_. The passes stop when the fit-grid RMS stops falling by 0.1 %; a Gauss-Newton polish on the
true residual ``T a / T b - y`` (same ridge) follows. ``lambda`` is chosen on the data: every
value of a logarithmic ladder is fitted and the one with the smallest maximum error on the
validation grid wins, among those whose denominator is certified free of zeros over the whole
normalized cube ``[-1, 1]^3`` (:func:`denominator_lower_bound`). The polynomial form
(``form="polynomial"``: ``b = (1, 0, ..., 0)``) is fitted the same way without reweighting.

References
----------
.. [1] C. V. Tao and Y. Hu, "A comprehensive study of the rational function model for
   photogrammetric processing", Photogrammetric Engineering & Remote Sensing 67(12),
   1347-1357 (2001).
.. [2] A. N. Tikhonov and V. Y. Arsenin, "Solutions of Ill-Posed Problems", Winston (1977).
.. [3] R. T. Farouki, "The Bernstein polynomial basis: a centennial retrospective", Computer
   Aided Geometric Design 29(6), 379-419 (2012) (bounds from Bernstein coefficients, de
   Casteljau subdivision).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from math import comb

import numpy as np

from sensor_models.errors import InputError, RpcError
from sensor_models.models.rpc import RpcModel
from sensor_models.models.rpc_dem import rpc00b_monomials

__all__ = ["FORMS", "RpcTile", "denominator_lower_bound", "fit_rpc", "fit_rpc_tiles", "normalization"]

#: The forms :func:`fit_rpc` fits: ratios of cubics, or cubics (denominators 1).
FORMS = ("rational", "polynomial")

#: Ridge weights tried (relative to unit-norm design columns); 0 is tried too.
_LAMBDA_LADDER = tuple(10.0 ** -k for k in range(16, 3, -1))
#: A reweighting pass that lowers the fit-grid RMS by less than this fraction ends the passes.
_RMS_STALL = 1e-3
#: Gauss-Newton passes on the true residual after the reweighted passes.
_GN_PASSES = 5
#: Subdivision depth of the Bernstein bound (cells per axis up to 2**depth).
_BERNSTEIN_DEPTH = 5

# powers (L, P, H) of the RPC00B terms, in coefficient order
_POWERS = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (2, 0, 0),
           (0, 2, 0), (0, 0, 2), (1, 1, 1), (3, 0, 0), (1, 2, 0), (1, 0, 2), (2, 1, 0), (0, 3, 0),
           (0, 1, 2), (2, 0, 1), (0, 2, 1), (0, 0, 3))  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Denominator: a certified lower bound over the normalized cube
# ---------------------------------------------------------------------------------------------
def _bernstein_matrix():
    """``M`` with ``bernstein = M @ power`` along one axis: power basis in ``x`` on [-1, 1] ->
    Bernstein basis of degree 3 in ``u = (x + 1) / 2`` on [0, 1]."""
    to_u = np.zeros((4, 4))  # x^p = (2u - 1)^p = sum_q C(p, q) 2^q (-1)^(p-q) u^q
    for p in range(4):
        for q in range(p + 1):
            to_u[q, p] = comb(p, q) * 2.0**q * (-1.0) ** (p - q)
    to_b = np.zeros((4, 4))  # b_m = sum_{q <= m} C(m, q) / C(3, q) c_q
    for m in range(4):
        for q in range(m + 1):
            to_b[m, q] = comb(m, q) / comb(3, q)
    return to_b @ to_u


_TO_BERNSTEIN = _bernstein_matrix()


def _split(b, axis):
    """de Casteljau halves of a degree-3 Bernstein tensor along ``axis``."""
    b = np.moveaxis(b, axis, 0)
    b0, b1, b2, b3 = b
    b01, b12, b23 = (b0 + b1) / 2, (b1 + b2) / 2, (b2 + b3) / 2
    b012, b123 = (b01 + b12) / 2, (b12 + b23) / 2
    mid = (b012 + b123) / 2
    left, right = np.stack([b0, b01, b012, mid]), np.stack([mid, b123, b23, b3])
    return np.moveaxis(left, 0, axis), np.moveaxis(right, 0, axis)


def denominator_lower_bound(den, *, depth=_BERNSTEIN_DEPTH) -> float:
    """A certified lower bound of an RPC00B cubic over the normalized cube ``[-1, 1]^3``.

    The cubic ``D(L, P, H) = sum_k den[k] T_k`` is written in the tensor Bernstein basis of
    degree 3 on the cube; ``D`` is a convex combination of its 64 Bernstein coefficients, so
    their minimum is a lower bound of ``D`` [3]_. Cells whose bound is not positive are halved
    by de Casteljau subdivision (up to ``depth`` times per axis), which tightens the bound
    towards the true minimum. A corner coefficient is the value of ``D`` at that corner, so a
    non-positive one proves a zero (or a sign change) inside the cube.

    Parameters
    ----------
    den : array_like, shape (20,)
        Coefficients in RPC00B term order (:data:`sensor_models.models.rpc.RPC00B_TERMS`).
    depth : int
        Subdivisions per axis at most.

    Returns
    -------
    float
        A lower bound of ``D`` over the cube. Positive: ``D`` has no zero there (proved). Not
        positive: a value of ``D`` at most this bound was found (a cell corner), or the
        subdivision did not separate ``D`` from zero.
    """
    c = np.zeros((4, 4, 4))
    for coef, (i, j, k) in zip(np.asarray(den, dtype=np.float64).reshape(20), _POWERS):
        c[i, j, k] = coef
    b = np.einsum("ai,bj,ck,ijk->abc", _TO_BERNSTEIN, _TO_BERNSTEIN, _TO_BERNSTEIN, c)
    cells, bound = [(b, 0)], math.inf
    while cells:
        cell, level = cells.pop()
        low = float(cell.min())
        corner = float(cell[::3, ::3, ::3].min())  # exact values of D at the cell's corners
        if low > 0.0:
            bound = min(bound, low)
        elif corner <= 0.0 or level >= 3 * depth:
            return min(low, corner)
        else:
            cells.extend((half, level + 1) for half in _split(cell, level % 3))
    return bound


# ---------------------------------------------------------------------------------------------
# Grids and normalization
# ---------------------------------------------------------------------------------------------
def _axis(lo, hi, n, *, centres, ends=False):
    """``n`` nodes spanning [lo, hi]: the ends included, or the centres of ``n`` equal cells
    (and, with ``ends``, both ends too: ``n + 2`` nodes)."""
    if centres:
        mid = lo + (np.arange(n) + 0.5) * (hi - lo) / n
        return np.concatenate([[lo], mid, [hi]]) if ends else mid
    if n == 1:
        return np.array([(lo + hi) / 2.0])
    return np.linspace(lo, hi, n)


def _localize(model, band, shape_px, heights, grid, *, centres, edges=False):
    """Localize a ``grid = (rows, cols, heights)`` grid; ``(row, col, lon, lat, h)`` and drops.

    ``centres``: cell centres on every axis; ``edges`` adds the first and last pixel centres to
    the row and column axes (not to the heights), so the grid reaches the image's borders.
    """
    n_rows, n_cols = shape_px
    nr, nc, nh = grid
    axes = (_axis(0.5, n_rows - 0.5, nr, centres=centres, ends=edges),
            _axis(0.5, n_cols - 0.5, nc, centres=centres, ends=edges),
            _axis(heights[0], heights[1], nh, centres=centres))
    R, C, Hh = (a.reshape(-1) for a in np.meshgrid(*axes, indexing="ij"))
    kwargs = {} if band is None else {"band": band}
    lon, lat, h = (np.asarray(a, dtype=np.float64).reshape(-1)
                   for a in model.image_to_ground(R, C, height=Hh, **kwargs))  # fmt: skip
    ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
    return (R[ok], C[ok], lon[ok], lat[ok], h[ok]), int(np.count_nonzero(~ok))


def normalization(lon, lat, height_range_m, image_shape) -> dict:
    """RPC00B offsets and scales: centres and half-spans of the ground and image extents.

    Parameters
    ----------
    lon, lat : ndarray, shape (N,)
        Ground points of the fit grid, degrees.
    height_range_m : (float, float)
        Ellipsoidal heights spanned, metres.
    image_shape : (int, int)
        ``(n_rows, n_cols)``.

    Returns
    -------
    dict
        The ten ``RpcModel`` normalization keywords; image offsets in RPC space (first pixel
        centre at 0): ``line_off = n_rows / 2 - 0.5``, ``line_scale = n_rows / 2``, likewise for
        samples; a zero height span gets a 1 m scale.
    """
    out = {}
    for name, v, floor in (("lon", lon, 1e-9), ("lat", lat, 1e-9)):
        lo, hi = float(np.min(v)), float(np.max(v))
        out[f"{name}_off"], out[f"{name}_scale"] = (lo + hi) / 2.0, max((hi - lo) / 2.0, floor)
    h_lo, h_hi = height_range_m
    n_rows, n_cols = image_shape
    out.update(height_off=(h_lo + h_hi) / 2.0, height_scale=max((h_hi - h_lo) / 2.0, 1.0),
               line_off=n_rows / 2.0 - 0.5, samp_off=n_cols / 2.0 - 0.5,
               line_scale=n_rows / 2.0, samp_scale=n_cols / 2.0)  # fmt: skip
    return out


class _Samples:
    """Grid points in normalized form: terms ``T`` (N, 20), targets ``y`` (N, 2), pixels."""

    def __init__(self, pts, norm):
        R, C, lon, lat, h = pts
        self.points = pts
        self.T = rpc00b_monomials((lon - norm["lon_off"]) / norm["lon_scale"], (lat - norm["lat_off"]) / norm["lat_scale"],
                        (h - norm["height_off"]) / norm["height_scale"]).T  # fmt: skip
        self.y = np.stack([(R - 0.5 - norm["line_off"]) / norm["line_scale"],
                           (C - 0.5 - norm["samp_off"]) / norm["samp_scale"]], axis=1)  # fmt: skip
        self.scale_px = np.array([norm["line_scale"], norm["samp_scale"]])


# ---------------------------------------------------------------------------------------------
# One ratio
# ---------------------------------------------------------------------------------------------
def _ridge_solve(A, b, col_norm, lam, x0=None):
    """``argmin |A x - b|^2 + lam |diag(col_norm) (x + x0)|^2`` (``x0`` default 0).

    Solved on the normal equations of the column-scaled problem (39 unknowns at most, so a
    39 x 39 system; the ridge keeps it well conditioned, and ``lam = 0`` falls back to a
    least-squares solve of the normal equations).
    """
    As = A / col_norm
    # einsum: small products without BLAS threads (which only contend on a loaded machine)
    N = np.einsum("ni,nj->ij", As, As)
    rhs = np.einsum("ni,n->i", As, b)
    if x0 is not None and lam > 0.0:
        rhs = rhs - lam * (col_norm * x0)
    if lam > 0.0:
        N[np.diag_indices_from(N)] += lam
        try:
            return np.linalg.solve(N, rhs) / col_norm
        except np.linalg.LinAlgError:
            pass
    return np.linalg.lstsq(N, rhs, rcond=None)[0] / col_norm


def _rms(T, num, den, y):
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return float(np.sqrt(np.mean(((T @ num) / (T @ den) - y) ** 2)))


def _fit_ratio(T, y, lam, max_iterations, rational):
    """Numerator and denominator (each (20,), ``den[0] = 1``) of one image coordinate.

    Rational: reweighted linearized passes (weights ``1 / B``, Tao & Hu) until the fit-grid RMS
    stalls, then Gauss-Newton on ``T a / T b - y`` for the same penalized objective; the pass
    with the smallest fit-grid RMS is kept. Polynomial: one ridge solve of ``T a = y``.
    Returns ``num, den, passes``, or None when no pass gave finite values.
    """
    den = np.zeros(20)
    den[0] = 1.0
    if not rational:
        return _ridge_solve(T, y, np.linalg.norm(T, axis=0), lam), den, 1
    A0 = np.hstack([T, -y[:, None] * T[:, 1:]])
    col_norm = np.linalg.norm(A0, axis=0)
    col_norm[col_norm == 0.0] = 1.0
    best, rms_prev, passes = None, math.inf, 0
    for _ in range(max_iterations):  # Tao & Hu reweighted passes
        w = 1.0 / (T @ den)
        x = _ridge_solve(A0 * w[:, None], y * w, col_norm, lam)
        num, den = x[:20], np.concatenate([[1.0], x[20:]])
        passes += 1
        rms = _rms(T, num, den, y)
        if not math.isfinite(rms):
            break
        if best is None or rms < best[0]:
            best = (rms, num, den)
        if rms > (1.0 - _RMS_STALL) * rms_prev:
            break
        rms_prev = rms
    if best is None:
        return None
    rms, num, den = best
    x = np.concatenate([num, den[1:]])
    for _ in range(_GN_PASSES):  # Gauss-Newton: (J'J + lam S^2) dx = J'(y - pred) - lam S^2 x
        B = T @ den
        pred = (T @ num) / B
        J = np.hstack([T, -pred[:, None] * T[:, 1:]]) / B[:, None]
        x_new = x + _ridge_solve(J, y - pred, col_norm, lam, x0=x)
        num_new, den_new = x_new[:20], np.concatenate([[1.0], x_new[20:]])
        rms_new = _rms(T, num_new, den_new, y)
        passes += 1
        if not (rms_new < rms):
            break
        x, num, den, rms = x_new, num_new, den_new, rms_new
    return num, den, passes


# ---------------------------------------------------------------------------------------------
# The fit
# ---------------------------------------------------------------------------------------------
def _max_err_px(num, den, samples, k):
    """Max |error| (pixels) of coordinate ``k`` (0 line, 1 sample) on ``samples``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        e = (samples.T @ num) / (samples.T @ den) - samples.y[:, k]
    e = np.abs(e) * samples.scale_px[k]
    return float(np.max(e)) if np.all(np.isfinite(e)) else math.inf


def _choose(fit, val, k, rational, lams, max_iterations):
    """The ridge weight of coordinate ``k``: the smallest validation max error among the
    weights whose denominator is certified zero-free over the cube. Returns a dict."""
    trials = []
    for lam in lams:
        out = _fit_ratio(fit.T, fit.y[:, k], lam, max_iterations, rational)
        if out is None:
            continue
        num, den, passes = out
        bound = denominator_lower_bound(den) if rational else 1.0
        trials.append({"lambda": lam, "num": num, "den": den, "passes": passes, "den_bound": bound,
                       "val_max_px": _max_err_px(num, den, val, k)})  # fmt: skip
    ok = [t for t in trials if t["den_bound"] > 0.0 and math.isfinite(t["val_max_px"])]
    if not ok:
        raise RpcError("no regularization gave an RPC denominator free of zeros over the normalized cube; "
                       "check the height range, or fit form='polynomial'")  # fmt: skip
    best = min(ok, key=lambda t: t["val_max_px"])
    best["ladder"] = [[t["lambda"], t["val_max_px"], t["den_bound"]] for t in trials]
    return best


def _check_options(height_range_m, grid_shape, check_grid_shape, form, regularization, max_iterations):
    try:
        h_lo, h_hi = (float(x) for x in height_range_m)
    except (TypeError, ValueError):
        raise InputError(f"height_range_m must be (min, max), got {height_range_m!r}") from None
    if not (math.isfinite(h_lo) and math.isfinite(h_hi) and h_lo <= h_hi):
        raise InputError(f"height_range_m must be finite with min <= max, got {height_range_m!r}")
    grid_shape = tuple(int(n) for n in grid_shape)
    if len(grid_shape) != 3 or min(grid_shape[:2]) < 4 or grid_shape[2] < 1:
        raise InputError(f"grid_shape must be (rows >= 4, cols >= 4, heights >= 1), got {grid_shape!r}")
    if h_hi > h_lo and grid_shape[2] < 4:
        raise InputError("grid_shape needs >= 4 heights to determine cubic height terms")
    if check_grid_shape is None:
        check_grid_shape = tuple(max(1, 2 * (n - 1)) for n in grid_shape)
    check_grid_shape = tuple(int(n) for n in check_grid_shape)
    if len(check_grid_shape) != 3 or min(check_grid_shape) < 1:
        raise InputError(f"check_grid_shape must be 3 positive integers, got {check_grid_shape!r}")
    if form not in FORMS:
        raise InputError(f"form must be one of {FORMS}, got {form!r}")
    if regularization is not None and not (math.isfinite(regularization) and regularization >= 0.0):
        raise InputError(f"regularization must be finite and >= 0 (or None: chosen on the data), "
                         f"got {regularization!r}")
    if int(max_iterations) < 1:
        raise InputError(f"max_iterations must be >= 1, got {max_iterations!r}")
    return (h_lo, h_hi), grid_shape, check_grid_shape


def _errors(rpc, pts):
    """``((max, rms, max row, max col), residual (N, 2))``: image errors (pixels) on grid points."""
    R, C, lon, lat, h = pts
    r, c = rpc.ground_to_image(lon, lat, h)
    dr, dc = r - R, c - C
    d = np.hypot(dr, dc)
    return (float(np.max(d)), float(np.sqrt(np.mean(d * d))), float(np.max(np.abs(dr))),
            float(np.max(np.abs(dc)))), np.stack([dr, dc], axis=1)  # fmt: skip


def fit_rpc(model, *, band=None, height_range_m, form="rational", grid_shape=(21, 21, 7), check_grid_shape=None,
            regularization=None, max_iterations=20):
    """Fit a terrain-independent RPC00B model to any sensor model (module docstring).

    Parameters
    ----------
    model : SensorModel
        Anything with ``image_shape`` and ``image_to_ground(row, col, height=, band=)``.
    band : str, optional
        Passed to ``model.image_to_ground``.
    height_range_m : (float, float)
        Ellipsoidal heights (metres) the RPC must cover.
    form : {"rational", "polynomial"}
        Ratios of cubics (RPC00B with free denominators), or cubics (denominators 1).
    grid_shape : (int, int, int)
        Fit grid ``(rows, cols, heights)``, ends included (>= 4 heights when the range is not
        a single height).
    check_grid_shape : (int, int, int), optional
        Independent check grid (cell centres, plus the image's border rows and columns), default
        ``2 (n - 1)`` cells per axis.
    regularization : float, optional
        Fixed ridge weight ``lambda`` (relative to unit-norm design columns); default None:
        chosen on the validation grid from 0 and 1e-16 ... 1e-4.
    max_iterations : int
        Reweighted passes at most.

    Returns
    -------
    rpc : RpcModel
        With ``image_shape`` of ``model`` and zero bias.
    report : dict
        ``form``; ``fit_max_px``, ``fit_rms_px``, ``check_max_px``, ``check_rms_px`` (image
        distances, pixels) and the per-axis maxima ``fit_max_row_px`` ... ``check_max_col_px``;
        ``validation_max_px``; point counts ``n_fit``, ``n_validation``, ``n_check`` and the
        localization failures ``n_fit_dropped`` ...; per coordinate (``_line``, ``_samp``):
        ``regularization_*`` (the ``lambda`` used), ``iterations_*`` (passes), and
        ``regularization_ladder_*`` (``[lambda, validation max px, denominator bound]`` per
        weight tried); ``denominator_lower_bound`` (certified over the normalized cube, > 0:
        no zero), ``min_abs_denominator`` (over the fit and check grids); the settings used.

    Raises
    ------
    RpcError
        Too few grid points could be localized, or no regularization gave a zero-free
        denominator.
    InputError
        Invalid options.
    """
    options = _check_options(height_range_m, grid_shape, check_grid_shape, form, regularization, max_iterations)
    rpc, report, _ = _fit(model, band, *options, form, regularization, int(max_iterations))
    return rpc, report


def _fit(model, band, heights, grid_shape, check_shape, form, regularization, max_iterations):
    """:func:`fit_rpc` on checked options; also returns the check points and their residuals."""
    image_shape = tuple(int(n) for n in model.image_shape)
    fit_pts, dropped = _localize(model, band, image_shape, heights, grid_shape, centres=False)
    if fit_pts[0].size < 2 * 39:
        raise RpcError(f"only {fit_pts[0].size} of {np.prod(grid_shape)} grid points could be localized; "
                       "need at least 78")  # fmt: skip
    val_shape = tuple(max(1, n - 1) for n in grid_shape)
    val_pts, dropped_v = _localize(model, band, image_shape, heights, val_shape, centres=True)
    check_pts, dropped_c = _localize(model, band, image_shape, heights, check_shape, centres=True, edges=True)
    if val_pts[0].size == 0 or check_pts[0].size == 0:
        raise RpcError("no validation or check-grid point could be localized")
    norm = normalization(fit_pts[2], fit_pts[3], heights, image_shape)
    fit, val = _Samples(fit_pts, norm), _Samples(val_pts, norm)
    rational = form == "rational"
    lams = (0.0, *_LAMBDA_LADDER) if regularization is None else (float(regularization),)
    line, samp = (_choose(fit, val, k, rational, lams, max_iterations) for k in (0, 1))
    rpc = RpcModel(line_num=line["num"], line_den=line["den"], samp_num=samp["num"], samp_den=samp["den"],
                   image_shape=image_shape, **norm)  # fmt: skip
    fit_e, val_e = _errors(rpc, fit_pts)[0], _errors(rpc, val_pts)[0]
    check_e, residual = _errors(rpc, check_pts)
    min_den = min(float(np.min(np.abs(s.T @ d))) for s in (fit, _Samples(check_pts, norm))
                  for d in (line["den"], samp["den"]))  # fmt: skip
    report = {
        "form": form,
        "fit_max_px": fit_e[0], "fit_rms_px": fit_e[1], "fit_max_row_px": fit_e[2], "fit_max_col_px": fit_e[3],
        "check_max_px": check_e[0], "check_rms_px": check_e[1], "check_max_row_px": check_e[2],
        "check_max_col_px": check_e[3],
        "validation_max_px": val_e[0],
        "n_fit": int(fit_pts[0].size), "n_validation": int(val_pts[0].size), "n_check": int(check_pts[0].size),
        "n_fit_dropped": dropped, "n_validation_dropped": dropped_v, "n_check_dropped": dropped_c,
        "regularization_line": line["lambda"], "regularization_samp": samp["lambda"],
        "iterations_line": line["passes"], "iterations_samp": samp["passes"],
        "regularization_ladder_line": line["ladder"], "regularization_ladder_samp": samp["ladder"],
        "denominator_lower_bound": min(line["den_bound"], samp["den_bound"]),
        "min_abs_denominator": min_den,
        "grid_shape": list(grid_shape), "validation_grid_shape": list(val_shape),
        "check_grid_shape": list(check_shape), "height_range_m": list(heights),
    }  # fmt: skip
    return rpc, report, (check_pts, residual)


# ---------------------------------------------------------------------------------------------
# Tiles: where one RPC cannot follow the model
# ---------------------------------------------------------------------------------------------
class _Window:
    """Pixels ``[row0, row0 + n_rows) x [col0, col0 + n_cols)`` of a model as an image of its own."""

    def __init__(self, model, row0, col0, shape):
        self.model, self.row0, self.col0 = model, int(row0), int(col0)
        self.image_shape = (int(shape[0]), int(shape[1]))

    def image_to_ground(self, row, col, *, height, **kwargs):
        return self.model.image_to_ground(np.asarray(row) + self.row0, np.asarray(col) + self.col0, height=height,
                                          **kwargs)


@dataclass(frozen=True)
class RpcTile:
    """One RPC of :func:`fit_rpc_tiles`: the pixels it covers, the RPC and its fit report.

    Attributes
    ----------
    first_row, first_col : int
        The tile's first pixel in the fitted model's image (its RPC's pixel (0.5, 0.5)).
    rpc : RpcModel
        The RPC of the tile's pixels (``rpc.image_shape`` = the tile's shape).
    report : dict
        Of :func:`fit_rpc`.
    """

    first_row: int
    first_col: int
    rpc: RpcModel
    report: dict


def _split_axis(check_pts, residual):
    """0 (rows) or 1 (columns): the axis along which the residual varies most.

    The share of the residual's sum of squares explained by its means per check-grid row,
    and per check-grid column (an analysis of variance); the larger share wins (rows on a tie:
    attitude and orbit act along rows).
    """
    shares = []
    for coord in check_pts[:2]:
        _, group = np.unique(coord, return_inverse=True)
        count = np.bincount(group).astype(np.float64)
        ss = 0.0
        for k in range(2):
            means = np.bincount(group, weights=residual[:, k]) / count
            ss += float(np.sum(count * means**2))
        shares.append(ss)
    return 0 if shares[0] >= shares[1] else 1


def fit_rpc_tiles(model, *, band=None, height_range_m, max_error_px, min_tile_px=64, form="rational",
                  grid_shape=(21, 21, 7), check_grid_shape=None, regularization=None, max_iterations=20):
    """RPCs over tiles of the image, each within ``max_error_px`` of the model on its check grid.

    One RPC is fitted to the whole image (:func:`fit_rpc`). Where its check-grid maximum error
    exceeds ``max_error_px``, the image is halved along the axis along which the check-grid
    residual varies most (:func:`_split_axis`: attitude and orbit changes faster than a cubic
    in time vary along rows, look directions beyond a cubic along columns), and each half is
    fitted again, recursively. A tile is not halved below ``min_tile_px`` pixels on that axis;
    such a tile is kept with its error (the caller reports it).

    Parameters
    ----------
    model : SensorModel
        As for :func:`fit_rpc`.
    band : str, optional
    height_range_m : (float, float)
    max_error_px : float
        The check-grid maximum error each tile must reach, pixels (> 0).
    min_tile_px : int
        Smallest tile side a split may produce, pixels (>= 8).
    form, grid_shape, check_grid_shape, regularization, max_iterations
        As for :func:`fit_rpc`.

    Returns
    -------
    list of RpcTile
        In row-major order of their first pixels; one tile (the whole image) when one RPC is
        within ``max_error_px``.

    Raises
    ------
    InputError
        Invalid options.
    RpcError
        As :func:`fit_rpc`.
    """
    options = _check_options(height_range_m, grid_shape, check_grid_shape, form, regularization, max_iterations)
    if not (math.isfinite(max_error_px) and max_error_px > 0.0):
        raise InputError(f"max_error_px must be > 0, got {max_error_px!r}")
    if int(min_tile_px) < 8:
        raise InputError(f"min_tile_px must be >= 8, got {min_tile_px!r}")
    tiles, todo = [], [(0, 0, tuple(int(n) for n in model.image_shape))]
    while todo:
        row0, col0, shape = todo.pop()
        view = model if (row0, col0, shape) == (0, 0, tuple(model.image_shape)) else _Window(model, row0, col0, shape)
        rpc, report, (check_pts, residual) = _fit(view, band, *options, form, regularization, int(max_iterations))
        axis = _split_axis(check_pts, residual)
        if report["check_max_px"] <= max_error_px or shape[axis] < 2 * int(min_tile_px):
            tiles.append(RpcTile(row0, col0, rpc, report))
            continue
        half = shape[axis] // 2
        if axis == 0:
            todo += [(row0, col0, (half, shape[1])), (row0 + half, col0, (shape[0] - half, shape[1]))]
        else:
            todo += [(row0, col0, (shape[0], half)), (row0, col0 + half, (shape[0], shape[1] - half))]
    return sorted(tiles, key=lambda t: (t.first_row, t.first_col))
