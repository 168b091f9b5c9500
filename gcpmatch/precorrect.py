"""Pre-correction of a sensor model from a few hundred coarse matches.

After launch a model can be off by hundreds (or thousands) of pixels, so image-space residuals
may not even exist (the ground point projects outside the tabulated lines). The fit is therefore
done in ground space: each matched scene pixel is localized at the height of its ground point
and the horizontal distance to that point (east, north in metres, local tangent plane) is
minimized by robust Gauss-Newton (Huber weights, MAD scale) over a few exterior parameters:
installation roll, pitch, yaw for a push-broom model, the RPC image offsets for an RPC.
Jacobians are central differences (3 parameters), kept while the steps are small (chord method).

Then, for push-broom models, each CCD gets the along- and across-track offset (``tan psi``
``c0`` terms) of its median image-space residual, which absorbs camera-to-camera rotations and
CCD placement errors of a few pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sensor_models.geometry.geodesy import enu_basis, geodetic_to_ecef

__all__ = ["PULLED_FACTOR", "PrecorrectResult", "exterior_names", "fit_exterior_in_ground", "fit_ccd_offsets",
           "ground_distance_m", "precorrect_matches"]

HUBER_K = 1.345


@dataclass
class PrecorrectResult:
    model: object
    names: tuple
    delta: np.ndarray
    rms_m: float
    inlier: np.ndarray
    iterations: int


def exterior_names(model) -> tuple[str, ...]:
    """The exterior parameters the coarse stage fits for ``model``'s kind.

    Parameters
    ----------
    model : SensorModel
        A push-broom model (installation angles) or an RPC model with a bias (row, col offsets).

    Returns
    -------
    tuple of str
        ``installation.roll, .pitch, .yaw`` (radians) or ``bias.row.a0, bias.col.b0`` (pixels).

    Raises
    ------
    ValueError
        The model has neither.
    """
    names = model.parameters().names
    if "installation.roll" in names:
        return ("installation.roll", "installation.pitch", "installation.yaw")
    if "bias.row.a0" in names:
        return ("bias.row.a0", "bias.col.b0")
    raise ValueError(f"no exterior parameters known for {type(model).__name__}")


def _ground_residual(model, row, col, xyz, h, basis, band, ccd):
    kw = {"band": band}
    if ccd is not None:
        kw["array"] = ccd
    lon, lat, hh = model.image_to_ground(row, col, height=h, **kw)
    d = geodetic_to_ecef(lon, lat, hh) - xyz
    return np.stack([d @ basis[0], d @ basis[1]], axis=-1)  # (N, 2) east, north metres


def ground_distance_m(model, row, col, lon, lat, h, *, band=None, ccd=None) -> np.ndarray:
    """Horizontal distance, metres, between where ``model`` puts each pixel and its matched ground point.

    Parameters
    ----------
    model : SensorModel
        The model.
    row, col : ndarray (N,)
        Scene coordinates, continuous pixels.
    lon, lat, h : ndarray (N,)
        Matched ground points: WGS84 degrees, metres above the ellipsoid.
    band : str, optional
        Band of ``model``.
    ccd : ndarray (N,) of int, optional
        CCD of each point.

    Returns
    -------
    ndarray (N,)
        ``|(east, north)|`` of the pixel's ground point (at height ``h``) minus the matched one,
        metres; NaN where the model cannot localize the pixel.
    """
    xyz = geodetic_to_ecef(lon, lat, h)
    basis = enu_basis(float(np.mean(lon)), float(np.mean(lat)))
    r = _ground_residual(model, row, col, xyz, h, basis, band, ccd)
    return np.hypot(r[:, 0], r[:, 1])


#: the Gauss-Newton Jacobian (central differences, 2 residual evaluations per parameter) is
#: evaluated again only after a step larger than this many difference steps (1e-3 rad, about
#: 800 m from 780 km; 50 px for RPC offsets): the ground-space residuals are smooth in the
#: exterior, so the Jacobian kept from before (the chord method; Ortega & Rheinboldt 1970, ch. 7)
#: converges to the same robust fit. Measured on the realistic demo: 42 residual evaluations
#: instead of 109, the pre-corrected model's corners and centre 0.000 px from before (also on the
#: Pleiades tutorial pair)
CHORD_STEPS = 1000.0


def _central_jacobian(model, x, idx, steps, residual_args):
    """(2 N, p) central-difference Jacobian of the stacked ground residuals in parameters ``idx``
    of the parameter vector ``x`` (steps ``steps``)."""
    cols = []
    for j, dx in zip(idx, steps):
        xp, xm = x.copy(), x.copy()
        xp[j] += dx
        xm[j] -= dx
        rp = _ground_residual(model.with_parameters(xp), *residual_args).reshape(-1)
        rm = _ground_residual(model.with_parameters(xm), *residual_args).reshape(-1)
        cols.append((rp - rm) / (2 * dx))
    return np.stack(cols, axis=-1)


def _steps(names):
    return np.array([1e-6 if n.startswith("installation") else 0.05 for n in names])


def fit_exterior_in_ground(model, row, col, lon, lat, h, *, band=None, ccd=None, names=None,
                           max_iter: int = 12, min_scale_m: float = 1.0) -> PrecorrectResult:
    """Robustly fit exterior parameters so that pixels land on their matched ground points.

    Parameters
    ----------
    model : SensorModel
        The model to correct.
    row, col : ndarray (N,)
        Observed scene coordinates of the matches, continuous pixels (first pixel's centre at
        (0.5, 0.5)).
    lon, lat, h : ndarray (N,)
        Their ground points: WGS84 degrees, metres above the ellipsoid (DEM heights).
    band : str, optional
        Band of ``model`` (default: the model's reference band).
    ccd : ndarray (N,) of int, optional
        CCD of each match (push-broom); default: the model's choice.
    names : sequence of str, optional
        Parameters to fit (default :func:`exterior_names`).
    max_iter : int
        Most Gauss-Newton / IRLS iterations.
    min_scale_m : float
        Floor of the robust residual scale, metres.

    Returns
    -------
    PrecorrectResult
        The corrected model, the parameter change, the inlier flags (|r| < 3 scale) and the
        inliers' RMS in metres.
    """
    names = tuple(names or exterior_names(model))
    pv = model.parameters()
    idx = pv.index(names)
    x = pv.values.copy()
    xyz = geodetic_to_ecef(lon, lat, h)
    basis = enu_basis(float(np.mean(lon)), float(np.mean(lat)))
    steps = _steps(names)
    w = np.ones(row.size)
    cur = model
    scale = np.inf
    it = 0
    jac = None
    for it in range(1, max_iter + 1):
        r = _ground_residual(cur, row, col, xyz, h, basis, band, ccd).reshape(-1)
        if jac is None:  # chord method: the Jacobian is kept while the steps are small
            jac = _central_jacobian(model, x, idx, steps, (row, col, xyz, h, basis, band, ccd))
        dist = np.hypot(r[0::2], r[1::2])
        ok = np.isfinite(dist)
        scale = max(min_scale_m, 1.4826 * np.median(dist[ok]) if ok.any() else np.inf)
        u = dist / scale
        w = np.where(ok, np.where(u <= HUBER_K, 1.0, HUBER_K / np.maximum(u, 1e-12)), 0.0)
        ww = np.repeat(w, 2)
        good = np.isfinite(r) & np.all(np.isfinite(jac), axis=1)
        a = jac[good] * ww[good, None]
        delta = np.linalg.lstsq(a.T @ jac[good], a.T @ r[good], rcond=None)[0]
        x[idx] -= delta
        cur = model.with_parameters(x)
        if np.all(np.abs(delta) < steps * 1e-2):
            break
        if np.any(np.abs(delta) > steps * CHORD_STEPS):
            jac = None  # a large step: the Jacobian is evaluated again where it landed
    r = _ground_residual(cur, row, col, xyz, h, basis, band, ccd)
    dist = np.hypot(r[:, 0], r[:, 1])
    ok = np.isfinite(dist)
    scale = max(min_scale_m, 1.4826 * np.median(dist[ok]))
    inlier = ok & (dist < 3.0 * scale)
    rms = float(np.sqrt(np.mean(dist[inlier] ** 2))) if inlier.any() else float("nan")
    return PrecorrectResult(cur, names, x[idx] - pv.values[idx], rms, inlier, it)


def fit_ccd_offsets(model, row, col, lon, lat, h, ccd, *, band: str, min_points: int = 5):
    """Correct each CCD's ``tan psi`` offset (``c0``) and, with enough points, scale (``c1``).

    Per CCD, the image-space residuals of its matches are fitted by robust (Huber IRLS) least
    squares on the analytic Jacobian of ``tan_psi_x/y.c0`` (and ``.c1`` with >= 4 ``min_points``
    matches spread over the CCD), which absorbs camera-to-camera rotations, CCD placement and
    the linear part of the distortion. CCDs with fewer than ``min_points`` matches are left
    alone.

    Parameters
    ----------
    model : PushbroomModel
        The model to correct (directional-angle coefficients per band and CCD).
    row, col : ndarray, shape (N,)
        Observed scene coordinates of the matches, continuous pixels (first pixel's centre at
        (0.5, 0.5)).
    lon, lat, h : ndarray, shape (N,)
        Their ground points: WGS84 degrees, metres above the ellipsoid.
    ccd : ndarray of int, shape (N,)
        CCD index of each match, in ``model.detector_arrays(band)`` order.
    band : str
        The band whose coefficients are corrected.
    min_points : int
        Fewest matches a CCD needs to be corrected (4 x as many, spread over more than half
        the CCD, to fit the scale too).

    Returns
    -------
    model : PushbroomModel
        The corrected model.
    removed : dict of int to (float, float)
        CCD index -> median (d_row, d_col) residual before the correction, pixels.
    """
    pv = model.parameters()
    x = pv.values.copy()
    removed = {}
    for i, look in enumerate(model.detector_arrays(band)):
        sel = ccd == i
        if sel.sum() < min_points:
            continue
        names = [f"{band}.{look.name}.tan_psi_x.c0", f"{band}.{look.name}.tan_psi_y.c0"]
        s_span = np.ptp(col[sel]) / max(look.n_detectors, 1)
        if sel.sum() >= 4 * min_points and s_span > 0.5:
            names += [f"{band}.{look.name}.tan_psi_x.c1", f"{band}.{look.name}.tan_psi_y.c1"]
        rr, cc, jac = model.image_jacobian(lon[sel], lat[sel], h[sel], band=band, names=names, array=i)
        res = np.stack([row[sel] - rr, col[sel] - cc], axis=-1)
        ok = np.all(np.isfinite(res), axis=1)
        if ok.sum() < min_points:
            continue
        res, jac = res[ok], jac[ok]
        a = jac.reshape(-1, len(names))
        y = res.reshape(-1)
        scale = np.abs(a).max(axis=0)
        w = np.ones(y.size)
        for _ in range(6):
            sw = np.sqrt(w)
            delta = np.linalg.lstsq(a / scale * sw[:, None], y * sw, rcond=None)[0] / scale
            r = y - a @ delta
            s = 1.4826 * np.median(np.abs(r)) + 1e-9
            w = np.where(np.abs(r) <= HUBER_K * s, 1.0, HUBER_K * s / np.abs(r))
        x[pv.index(names)] += delta
        med = np.median(res, axis=0)
        removed[i] = (float(med[0]), float(med[1]))
    return model.with_parameters(x), removed


#: the re-screening refit on every ratio match is rejected when it moves the RANSAC consensus
#: (median distance) by more than this many times the consensus's own robust spread about the
#: first fit. Measured: 2.4-3.5 on same-band scenes (cloudy ideal scene of tests/test_match.py,
#: Sentinel-2 scenes of bench/change_pairs.py), 43-80 for Sentinel-2 red against
#: near-infrared, where about 20 % of the ratio matches are right
PULLED_FACTOR = 10.0


def precorrect_matches(model, band, row, col, glon, glat, gh, *, sel, inside, min_scale_m):
    """Fit the exterior to the RANSAC inliers, re-screen all matches, remove CCD offsets.

    Parameters
    ----------
    model : SensorModel
        The model to pre-correct.
    band : str or None
        Its band.
    row, col : ndarray, shape (m,)
        Scene pixels of the coarse matches (continuous, first pixel's centre at (0.5, 0.5)).
    glon, glat, gh : ndarray, shape (m,)
        Their ground points: degrees, metres above the ellipsoid.
    sel : ndarray of bool, shape (m,)
        The RANSAC inliers inside the scene and the DEM (the first fit).
    inside : ndarray of bool, shape (m,)
        Every match inside the scene and the DEM (the re-screening).
    min_scale_m : float
        Floor of the robust scale, metres (half a reduced pixel).

    Returns
    -------
    corrected : SensorModel
        The pre-corrected model.
    keep : ndarray of intp
        Indices of the matches kept by the re-screening.
    rms_m : float
        Ground-space RMS of the re-screened fit, metres.
    offsets : dict
        Per-CCD offsets removed, pixels (empty for models without CCDs).
    """
    # models whose detector arrays carry their own interior (push-broom CCDs) get CCD offsets
    per_array = any(g.startswith("interior.") for g in model.parameter_groups())
    ccd = model.detector_index(col, band=band) if per_array else None
    fit = fit_exterior_in_ground(model, row[sel], col[sel], glon[sel], glat[sel], gh[sel], band=band,
                                 ccd=None if ccd is None else ccd[sel], min_scale_m=min_scale_m)
    # re-screen every ratio-test match against the corrected model: a robust refit on all of them
    # picks up the matches the affine RANSAC left out (CCD offsets, parallax), unless most ratio
    # matches are wrong (bands whose contrast inverts): then it is pulled off the RANSAC
    # consensus (PULLED_FACTOR), and only the matches within 3 of the consensus's own spread
    # are refitted
    fit2 = fit_exterior_in_ground(fit.model, row[inside], col[inside], glon[inside], glat[inside], gh[inside],
                                  band=band, ccd=None if ccd is None else ccd[inside], min_scale_m=min_scale_m)
    consensus = np.flatnonzero(sel)[fit.inlier]
    kw = {"band": band}
    before = ground_distance_m(fit.model, row[consensus], col[consensus], glon[consensus], glat[consensus],
                               gh[consensus], ccd=None if ccd is None else ccd[consensus], **kw)
    after = ground_distance_m(fit2.model, row[consensus], col[consensus], glon[consensus], glat[consensus],
                              gh[consensus], ccd=None if ccd is None else ccd[consensus], **kw)
    scale = max(min_scale_m, 1.4826 * float(np.median(before)))
    near = inside
    if not np.median(after) < PULLED_FACTOR * scale:
        dist = np.full(row.size, np.inf)
        dist[inside] = ground_distance_m(fit.model, row[inside], col[inside], glon[inside], glat[inside],
                                         gh[inside], ccd=None if ccd is None else ccd[inside], **kw)
        near = inside & (dist < 3.0 * scale)
        fit2 = fit_exterior_in_ground(fit.model, row[near], col[near], glon[near], glat[near], gh[near],
                                      band=band, ccd=None if ccd is None else ccd[near], min_scale_m=min_scale_m)
    keep = np.flatnonzero(near)[fit2.inlier]
    corrected = fit2.model
    offsets = {}
    if ccd is not None:
        corrected, offsets = fit_ccd_offsets(corrected, row[keep], col[keep], glon[keep], glat[keep], gh[keep],
                                             ccd[keep], band=band or corrected.reference_band)
    return corrected, keep, fit2.rms_m, offsets
