"""Band and CCD parallax as attitude observations, fitted jointly with the GCPs (docs/attitude.md).

The bands of a push-broom focal plane sit at different along-track places, so band ``b`` sees
the ground that the reference band sees at line time ``t_ref`` a little later or earlier, at
``t_b = t_ref + dt`` (``dt`` = along-track offset / ground speed). A band-to-band tie point
(:func:`calibrate.tie_points.match_band`: window centre ``p`` in the reference band, measured
position ``q`` in band ``b``) is the observation

.. math::  q = T_b(p) = F_b(F_{ref}^{-1}(p; c); c)

of the transfer map through the ground ``G = F_ref^-1(p)``, where ``c`` are the coefficients of
the body-frame attitude correction ``delta(t)`` (:mod:`sensor_models.models.attitude_correction`). Its
derivative in a coefficient ``c_{a,j}`` of axis ``a``, basis function ``B_j``, is

.. math::  \\frac{\\partial q}{\\partial c_{a,j}} = J_b[:, a]\\, B_j(t_b)
           - A\\, J_{ref}[:, a]\\, B_j(t_{ref})

with ``J_b``, ``J_ref`` = ``d(row, col)/d(delta)`` (2 x 3) of band ``b`` and of the reference
band at ``G`` (:meth:`PushbroomModel.attitude_angle_jacobian`, analytic) and ``A = dT_b/dp``
(2 x 2) the transfer map's own Jacobian: moving the correction moves the reference band's ground
``G`` by ``-(dF_ref/dG)^-1 J_ref dc``, which band ``b`` sees ``A`` times that far. ``A`` is
close to the identity (bands of the same pixel size); it is taken by central differences of the
map at the ground's height (``TRANSFER_STEP_PX``), the terrain slope left out (the bands' view
directions differ by a few hundred micro-radians along track).

A tie therefore measures ``J (delta(t_b) - delta(t_ref))`` (plus a small ``(J_b - A J_ref)
delta``): jitter at frequencies the GCP rows cannot reach, with the gain ``|2 sin(pi f dt)|``
(blind where ``f dt`` is an integer, weak at low ``f``). The GCPs of the reference band (``r_i ~
J_i delta(t_i)``) hold the low frequencies. Both enter ONE weighted least squares for the
correction's coefficients, together with per (band, CCD) polynomials in the detector index for
the row and column of the ties (the linearized interior that the relative calibration solves;
:func:`joint_select`). The basis (static, drift, or the P-spline with knots as dense as the
observations' times and its smoothing chosen by blocked cross-validation, :mod:`calibrate.pspline`) is chosen on the
joint residuals (least GCV, kept when an F-test rejects the static model), as
:func:`calibrate.attitude.select_correction`
does on the GCPs alone. :func:`calibrate.relative.relative_calibration` alternates this step
with the interiors (``parallax=True``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import scipy.sparse as sp

from calibrate.attitude import (basis_columns, candidate_corrections, choose_candidate, held_out_masks, ridge_solution,
                                ridge_weights, spline_penalty)
from calibrate.pspline import smooth
from sensor_models.errors import InputError

__all__ = ["MAX_JOINT_SEGMENTS", "TRANSFER_STEP_PX", "AngleObservations", "ParallaxResult", "calibrate_with_parallax",
           "gcp_observations", "joint_select",
           "joint_candidates", "tie_observations", "tie_transfer"]

#: step of the central differences of the transfer map's 2x2 Jacobian ``A``, px
TRANSFER_STEP_PX = 0.5
#: most P-spline segments on joint data (dense ties resolve segments of tens of lines)
MAX_JOINT_SEGMENTS = 256
#: a GCP whose residual exceeds this many robust standard deviations is left out of the fit
GCP_REJECT_SIGMAS = 5.0


@dataclass(frozen=True)
class AngleObservations:
    """Image residuals linear in the attitude angles at one or two times per point.

    ``residual_px[i] ~ sum_k jac[k, i] delta(seconds[k, i])`` (+ a per-group polynomial in
    ``x`` when ``group[i] >= 0``). A GCP has one term; a tie two (band, and minus the
    reference band projected through the transfer map).

    Attributes
    ----------
    residual_px : ndarray, shape (N, 2)
        Observed minus computed (row, col), px.
    weight : ndarray, shape (N,)
        1/px^2 per axis (0: left out).
    jac : ndarray, shape (T, N, 2, 3)
        Pixels per radian of roll, pitch, yaw, per term.
    seconds : ndarray, shape (T, N)
        Time of each term, seconds since the model's epoch.
    group : ndarray of int, shape (N,)
        Nuisance group (a band's CCD) of each point; -1 for none (GCPs).
    x : ndarray, shape (N,)
        Detector index of the point normalized to [-1, 1] in its CCD (nuisance polynomials).
    label : str
        ``"gcp"`` or the band of the ties.
    """

    residual_px: np.ndarray
    weight: np.ndarray
    jac: np.ndarray
    seconds: np.ndarray
    group: np.ndarray
    x: np.ndarray
    label: str

    def __len__(self) -> int:
        return int(self.weight.size)

    def linear_effect(self, correction) -> np.ndarray:
        """``sum_k jac_k delta(t_k)`` (N, 2), px, of a correction (None: zeros).

        Parameters
        ----------
        correction : AttitudeCorrection or None

        Returns
        -------
        ndarray, shape (N, 2)
        """
        out = np.zeros_like(self.residual_px)
        if correction is None:
            return out
        for jac, t in zip(self.jac, self.seconds):
            out += np.einsum("nia,na->ni", jac, correction.angles(t))
        return out


# --------------------------------------------------------------------------- observations
def gcp_observations(model, gcps, *, band=None) -> AngleObservations:
    """Residuals and angle Jacobians of a band's GCPs under ``model`` (``r_i ~ J_i delta(t_i)``).

    Parameters
    ----------
    model : PushbroomModel
    gcps : GcpTable
        Points of kind ``"gcp"`` of ``band`` (an empty band column means the reference band)
        are used; weights ``score / sigma_px^2``; residuals beyond ``GCP_REJECT_SIGMAS`` robust
        standard deviations get weight 0.
    band : str, optional
        Default: the model's reference band.

    Returns
    -------
    AngleObservations
    """
    band = band or model.reference_band
    table = gcps.gcps()
    keep = (table.band == "") | (table.band == band)
    lon, lat, h = table.lon[keep], table.lat[keep], table.h[keep]
    row, col, jac = model.attitude_angle_jacobian(lon, lat, h, band=band, array=_ccd_column(model, band, table.ccd[keep]))
    residual = np.stack([table.row[keep] - row, table.col[keep] - col], axis=-1)
    weight = table.score[keep] / table.sigma_px[keep] ** 2
    ok = np.isfinite(residual).all(axis=1) & np.isfinite(jac).all(axis=(1, 2)) & (weight > 0)
    if ok.sum() >= 10:
        dist = np.hypot(*(residual - np.median(residual[ok], axis=0)).T)
        ok &= dist <= GCP_REJECT_SIGMAS * 1.4826 * np.median(dist[ok]) + 1e-6
    seconds = model.line_timing.seconds(np.where(np.isfinite(row), row, table.row[keep]))
    return _finite(AngleObservations(residual, np.where(ok, weight, 0.0), jac[None], seconds[None],
                                     np.full(row.size, -1), np.zeros(row.size), "gcp"))


def _ccd_column(model, band, ccd):
    """CCD indices of a GCP table's ``ccd`` column (names or indices); None when it is empty.

    Points in the overlap of two CCDs must be projected into the CCD that observed them.
    """
    text = np.asarray(ccd).astype(str)
    if text.size == 0 or np.all(text == ""):
        return None
    names = [c.name for c in model.band_ccds(band)]
    lookup = {name: i for i, name in enumerate(names)} | {str(i): i for i in range(len(names))}
    unknown = sorted(set(text[text != ""]) - set(lookup))
    if unknown or np.any(text == ""):
        raise InputError(f"GCP CCD(s) {', '.join(unknown) or '(empty)'} unknown in band {band} "
                         f"(CCDs {', '.join(names)})", field="ccd")
    return np.array([lookup[v] for v in text], dtype=np.intp)


def tie_transfer(model, ties, *, dem=None, height=None):
    """Predicted band positions of tie points and their derivatives in the attitude angles.

    Parameters
    ----------
    model : PushbroomModel
    ties : calibrate.tie_points.TiePoints
        Reference-band window centres ``row_ref, col_ref`` (CCD ``ccd_ref``) and the band's
        CCD ``ccd``.
    dem : Dem, optional
        Terrain localizing the reference band (or ``height``).
    height : float or ndarray, optional
        Ellipsoidal heights, m, instead of ``dem``.

    Returns
    -------
    predicted : ndarray, shape (N, 2)
        ``T_b(p) = F_b(F_ref^-1(p))`` (row, col), px.
    jac_band, jac_ref : ndarray, shape (N, 2, 3)
        ``J_b`` and ``A J_ref`` (module docstring), px/rad: ``dq = J_b ddelta(t_b) - A J_ref
        ddelta(t_ref)``.
    seconds_band, seconds_ref : ndarray, shape (N,)
        ``t_b`` (the predicted band line) and ``t_ref`` (the window centre's line).
    """
    ref = model.reference_band
    lon, lat, h = model.image_to_ground(ties.row_ref, ties.col_ref, dem=dem, height=height, band=ref,
                                        array=ties.ccd_ref)
    lon, lat, h = (np.asarray(v, dtype=float).reshape(-1) for v in (lon, lat, h))
    ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
    n = lon.size
    predicted = np.full((n, 2), np.nan)
    jac_b, jac_r = np.full((n, 2, 3), np.nan), np.full((n, 2, 3), np.nan)
    if ok.any():
        r, c, jac_b[ok] = model.attitude_angle_jacobian(lon[ok], lat[ok], h[ok], band=ties.band, array=ties.ccd[ok])
        predicted[ok] = np.stack([r, c], axis=-1)
        _, _, j_ref = model.attitude_angle_jacobian(lon[ok], lat[ok], h[ok], band=ref, array=ties.ccd_ref[ok])
        jac_r[ok] = np.einsum("nij,nja->nia", _transfer_jacobian(model, ties, h, ok), j_ref)
    t_band = model.line_timing.seconds(np.where(np.isfinite(predicted[:, 0]), predicted[:, 0], ties.row_ref))
    return predicted, jac_b, jac_r, t_band, model.line_timing.seconds(ties.row_ref)


def _transfer_jacobian(model, ties, h, ok):
    """``A = dT_b/dp`` (n_ok, 2, 2) by central differences at the ground's height."""
    step = TRANSFER_STEP_PX
    out = np.empty((int(ok.sum()), 2, 2))
    for k in range(2):
        q = []
        for sign in (1.0, -1.0):
            dr, dc = (sign * step, 0.0) if k == 0 else (0.0, sign * step)
            lon, lat, hh = model.image_to_ground(ties.row_ref[ok] + dr, ties.col_ref[ok] + dc, height=h[ok],
                                                 band=model.reference_band, array=ties.ccd_ref[ok])
            q.append(np.stack(model.ground_to_image(lon, lat, hh, band=ties.band, array=ties.ccd[ok]), axis=-1))
        out[:, :, k] = (q[0] - q[1]) / (2.0 * step)
    return out


def tie_observations(model, ties, *, dem=None, height=None, group_offset: int = 0) -> AngleObservations:
    """Tie points of one band as attitude observations (module docstring).

    Parameters
    ----------
    model : PushbroomModel
        Every band's interior as calibrated so far.
    ties : calibrate.tie_points.TiePoints
    dem : Dem, optional
    height : float or ndarray, optional
        As in :func:`tie_transfer`.
    group_offset : int
        Nuisance group of the band's first CCD (CCD ``j`` gets ``group_offset + j``).

    Returns
    -------
    AngleObservations
        Weights ``score / sigma_px^2``.
    """
    predicted, jac_b, jac_r, t_b, t_r = tie_transfer(model, ties, dem=dem, height=height)
    residual = np.stack([ties.row, ties.col], axis=-1) - predicted
    looks = model.band_ccds(ties.band)
    first = np.array([c.first_col for c in looks], dtype=float)[ties.ccd]
    width = np.array([c.n_detectors for c in looks], dtype=float)[ties.ccd]
    x = 2.0 * (ties.col - first) / width - 1.0
    weight = ties.score / np.asarray(ties.sigma_px, dtype=float) ** 2
    return _finite(AngleObservations(residual, weight, np.stack([jac_b, -jac_r]), np.stack([t_b, t_r]),
                                     group_offset + np.asarray(ties.ccd, dtype=np.intp), x, ties.band))


def _finite(obs: AngleObservations) -> AngleObservations:
    """Zero weight (and zeros instead of NaN) where a residual, Jacobian or time is not finite."""
    ok = (np.isfinite(obs.residual_px).all(axis=1) & np.isfinite(obs.jac).all(axis=(0, 2, 3))
          & np.isfinite(obs.seconds).all(axis=0) & np.isfinite(obs.weight))
    residual = np.where(ok[:, None], obs.residual_px, 0.0)
    jac = np.where(ok[None, :, None, None], obs.jac, 0.0)
    seconds = np.where(ok[None, :], obs.seconds, np.nanmedian(obs.seconds) if np.isfinite(obs.seconds).any() else 0.0)
    weight = np.where(ok, obs.weight, 0.0)
    return AngleObservations(residual, weight, jac, seconds, obs.group, np.where(ok, obs.x, 0.0), obs.label)


# --------------------------------------------------------------------------- the joint fit
def joint_candidates(mode, model, observations, *, min_span_fraction: float = 0.5,
                     max_segments: int = MAX_JOINT_SEGMENTS):
    """Candidate bases for the joint data (:func:`calibrate.attitude.candidate_corrections`).

    Every observation with weight counts at its first term's time (the GCP's line, the
    band's line of a tie): their distinct times set the P-spline's knots
    (:func:`calibrate.pspline.pspline_segments`). The spline spans the observations' times
    (every term) and holds its end values beyond.

    Parameters
    ----------
    mode : {"static", "drift", "spline", "auto"}
    model : PushbroomModel
    observations : list of AngleObservations
    min_span_fraction : float
    max_segments : int

    Returns
    -------
    list of AttitudeCorrection or None
    """
    t0, t1 = sorted(float(t) for t in model.line_timing.seconds(np.array(model.row_range)))
    t_img = sorted(float(t) for t in model.line_timing.seconds(np.array([0.0, float(model.n_rows)])))
    seconds = np.concatenate([o.seconds[0][o.weight > 0] for o in observations])
    every = np.concatenate([o.seconds[:, o.weight > 0].ravel() for o in observations])
    every = every[np.isfinite(every)]
    support = (float(every.min()), float(every.max())) if every.size else None
    return candidate_corrections(mode, t0, t1, n_points=int(seconds.size), n_lines=float(np.diff(model.row_range)[0]),
                                 seconds=seconds, image_span_s=t_img[1] - t_img[0],
                                 min_span_fraction=min_span_fraction, max_segments=max_segments, support_s=support)


def _design(observations, correction, n_groups: int, n_poly: int):
    """Sparse design (2 N, 3 K + 2 G n_poly), residuals (2 N,) and weights (2 N,) of a candidate."""
    rows, cols, vals, resid, weight = [], [], [], [], []
    offset = 0
    k = basis_columns(correction, np.zeros(1))[2]
    for obs in observations:
        n = len(obs)
        row_id = offset + 2 * np.arange(n)[:, None] + np.arange(2)[None, :]  # (N, 2)
        for jac, t in zip(obs.jac, obs.seconds):
            index, value, _ = basis_columns(correction, t)  # (N, M)
            for a in range(3):
                v = jac[:, :, a][:, :, None] * value[:, None, :]  # (N, 2, M)
                rows.append(np.broadcast_to(row_id[:, :, None], v.shape).ravel())
                cols.append(np.broadcast_to((a * k + index)[:, None, :], v.shape).ravel())
                vals.append(v.ravel())
        has = obs.group >= 0
        if n_poly and has.any():
            powers = obs.x[has, None] ** np.arange(n_poly)[None, :]  # (n, P)
            for axis in range(2):
                base = 3 * k + (2 * obs.group[has] + axis) * n_poly
                rows.append(np.repeat(row_id[has, axis], n_poly))
                cols.append((base[:, None] + np.arange(n_poly)[None, :]).ravel())
                vals.append(powers.ravel())
        resid.append(obs.residual_px.ravel())
        weight.append(np.repeat(obs.weight, 2))
        offset += 2 * n
    x = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(offset, 3 * k + 2 * n_groups * n_poly))
    return x, np.concatenate(resid), np.concatenate(weight), k


def _cholesky_ridge(normal, rhs, ridge, penalty=None):
    """As :func:`calibrate.attitude.ridge_solution`, by Cholesky (several times faster than eigh).

    Columns without data and without ridge (a CCD with no tie) get a unit ridge; every column a
    relative 1e-12 one. ``penalty`` (P, P) is a further quadratic penalty. The hat matrix's trace
    is ``P - trace(A^-1 D (R + S) D)`` of the scaled matrix
    ``A = D (N + R + S) D``.
    """
    from scipy.linalg import cho_factor, cho_solve, solve_triangular

    diag = np.diag(normal)
    ridge = ridge + np.where(diag > 0, diag * 1e-12, 1.0)
    penalty = np.diag(ridge) if penalty is None else penalty + np.diag(ridge)
    d = 1.0 / np.sqrt(diag + np.diag(penalty))
    a = d[:, None] * (normal + penalty) * d[None, :]
    try:
        factor = cho_factor(a, lower=True)
    except np.linalg.LinAlgError:
        return ridge_solution(normal + penalty - np.diag(ridge), rhs, ridge)
    coef = d * cho_solve(factor, d * rhs)
    l_inv = solve_triangular(np.tril(factor[0]), np.eye(a.shape[0]), lower=True)
    inv_scaled = l_inv.T @ l_inv
    dof = float(a.shape[0] - np.sum(inv_scaled * (d[:, None] * penalty * d[None, :])))
    return coef, d[:, None] * inv_scaled * d[None, :], dof


def joint_select(observations, candidates, *, base=None, interior_terms: int = 3, yaw_sigma_rad=None,
                 reweight: bool = True):
    """Choose the basis on GCPs and ties together (:func:`calibrate.attitude.choose_candidate`) and solve it.

    Parameters
    ----------
    observations : list of AngleObservations
        GCPs (:func:`gcp_observations`) and ties of each band (:func:`tie_observations`),
        residuals taken under a model carrying the correction ``base``.
    candidates : list of AttitudeCorrection or None
        :func:`joint_candidates`.
    base : AttitudeCorrection, optional
        The correction the residuals were taken with: its linear effect is added back, so every
        candidate is fitted to the same "static" residuals.
    interior_terms : int
        Degree of the per (band, CCD) nuisance polynomials of the ties' rows and columns.
    yaw_sigma_rad : float, optional
        Prior on the yaw coefficients (``CalibrationOptions.attitude_yaw_sigma_urad``).
    reweight : bool
        After a first selection, scale each block's weights (the GCPs, each band's ties) by the
        inverse of its weighted mean square residual under the chosen fit (one step of
        variance-component estimation: the stated ``sigma_px`` of matches and ties are
        estimates), then select again.

    Returns
    -------
    chosen : AttitudeCorrection or None
        The coefficients (radians; a drift's constant left out); None: static.
    covariance : ndarray, shape (3 K, 3 K) or None
        Of the chosen coefficients, scaled by the a-posteriori variance factor, rad^2.
    table : list of dict
        Per candidate ``kind``, ``n_terms``, ``n_parameters`` (effective), ``rss`` (weighted, px^2),
        ``bic``, ``gcv``, ``chosen`` (the P-spline's also ``smoothing``, its criterion curve); the
        chosen row also ``variance_factors`` per block label.
    """
    if not candidates:
        raise InputError("no candidate basis to fit", field="attitude")
    static_obs = [AngleObservations(o.residual_px + o.linear_effect(base), o.weight, o.jac, o.seconds, o.group,
                                    o.x, o.label) for o in observations]
    n_groups = 1 + max([int(o.group.max()) for o in static_obs if o.group.size] + [-1])
    fit = dict(n_groups=n_groups, n_poly=int(interior_terms) + 1, yaw_sigma_rad=yaw_sigma_rad)
    table, solutions, best = _select(static_obs, candidates, **fit)
    factors = None
    if reweight and len(static_obs) > 1:
        # one step of variance-component estimation: each block (GCPs, each band's ties) gets the
        # weight its residuals support under the chosen basis, then the selection runs again
        factors = _block_variance_factors(static_obs, candidates[best], solutions[best][3], **fit)
        static_obs = [replace(o, weight=o.weight / f) for o, f in zip(static_obs, factors)]
        table, solutions, best = _select(static_obs, candidates, **fit)
    table[best]["chosen"] = True
    if factors is not None:
        table[best]["variance_factors"] = {o.label: float(f) for o, f in zip(static_obs, factors)}
    cand = candidates[best]
    if cand is None:
        return None, None, table
    coef, cov, k, _ = solutions[best]
    keep = np.arange(3 * k).reshape(3, k)[:, 1:] if cand.kind == "drift" else np.arange(3 * k).reshape(3, k)
    keep = keep.reshape(-1)
    return cand.with_coefficients(coef[keep]), cov[np.ix_(keep, keep)], table


def _select(static_obs, candidates, *, n_groups, n_poly, yaw_sigma_rad):
    """Fit every candidate; the table, the solutions and the index of the chosen one."""
    table, solutions = [], []
    for cand in candidates:
        x, r, w, k = _design(static_obs, cand, n_groups, n_poly)
        xw = x.T.multiply(w[None, :]).tocsr()
        normal = (xw @ x).toarray()
        rhs = xw @ r
        m = int(np.count_nonzero(w))
        ridge = np.concatenate([ridge_weights(cand, k, yaw_sigma_rad=yaw_sigma_rad), np.zeros(normal.shape[0] - 3 * k)])
        penalty = spline_penalty(cand, k, normal.shape[0])
        smoothing = None
        if penalty is None:
            coef, inv, dof = _cholesky_ridge(normal, rhs, ridge)
            rss = max(float(w @ r**2) - 2.0 * coef @ rhs + coef @ normal @ coef, 1e-300)
        else:  # the P-spline: its smoothing chosen by blocked cross-validation (calibrate.pspline)
            times = np.concatenate([np.repeat(o.seconds[0], 2) for o in static_obs])
            folds = []
            for held in held_out_masks(cand, times):
                w_h = np.where(held, w, 0.0)
                xw_h = x.T.multiply(w_h[None, :]).tocsr()
                folds.append(((xw_h @ x).toarray(), xw_h @ r, float(w_h @ r**2)))
            coef, inv, dof, rss, smoothing = smooth(normal, rhs, float(w @ r**2), m, penalty, ridge, folds=folds)
        bic = m * np.log(rss / m) + dof * np.log(m)
        solutions.append((coef[: 3 * k], inv[: 3 * k, : 3 * k] * rss / max(m - dof, 1.0), k, coef))
        row = {"kind": "static" if cand is None else cand.kind, "n_terms": 0 if cand is None else cand.n_terms,
               "n_parameters": round(dof, 2), "rss": rss, "bic": float(bic), "chosen": False}
        if smoothing is not None:
            row["smoothing"] = smoothing.to_dict()
        table.append(row)
    return table, solutions, choose_candidate(table, m)


def _block_variance_factors(static_obs, cand, coef, *, n_groups, n_poly, yaw_sigma_rad):
    """Weighted mean square residual (floored at 1e-6) of each observation block under one fit."""
    del yaw_sigma_rad  # the fit is given
    x, r, w, _ = _design(static_obs, cand, n_groups, n_poly)
    e = r - x @ coef
    out, start = [], 0
    for o in static_obs:
        stop = start + 2 * len(o)
        used = np.count_nonzero(w[start:stop])
        out.append(max(float(w[start:stop] @ e[start:stop] ** 2) / max(used, 1), 1e-6))
        start = stop
    return out


# --------------------------------------------------------------------------- alternation
@dataclass
class ParallaxResult:
    """Outcome of :func:`calibrate_with_parallax`.

    Attributes
    ----------
    model : PushbroomModel
        The joint attitude correction, the reference band re-solved with it held, every band's
        interior re-solved from its ties.
    success : bool
    message : str
    correction, gcp_only : AttitudeCorrection or None
        The joint correction; the one the input model carried (the GCP-only estimate of
        ``gcpcal calibrate --attitude``).
    covariance : ndarray or None
        Of the joint coefficients, rad^2.
    candidates : list of dict
        Candidate table of the last round (:func:`joint_select`).
    n_gcps, n_ties : int
        Observations with weight in the last round (ties: every band).
    rounds : int
    reference : CalibrationResult or None
        Last re-solve of the reference band (exterior and its interior, correction held).
    bands : dict of str to CalibrationResult
        Last interior solve of each band.
    """

    model: object
    success: bool
    message: str
    correction: object
    gcp_only: object
    covariance: np.ndarray | None
    candidates: list
    n_gcps: int
    n_ties: int
    rounds: int
    reference: object = None
    bands: dict | None = None

    def to_dict(self) -> dict:
        """JSON-ready summary (``relative.json`` ``parallax``).

        Returns
        -------
        dict
            ``success``, ``message``, ``ties``, ``gcps``, ``rounds``, ``selected`` (``kind``,
            ``n_terms``, ``knot_spacing_s``), ``candidates`` and ``gcp_only`` (the input's basis).
        """
        def describe(c):
            return {"kind": "static", "n_terms": 0} if c is None else {
                "kind": c.kind, "n_terms": c.n_terms, "knot_spacing_s": c.knot_spacing_s}

        return {"success": self.success, "message": self.message, "ties": self.n_ties, "gcps": self.n_gcps,
                "rounds": self.rounds, "selected": describe(self.correction), "gcp_only": describe(self.gcp_only),
                "candidates": self.candidates,
                "coefficients_covariance_rad2": self.covariance}


def _with_ground(model, ties, dem, height):
    """Ties whose ground is what the reference band of ``model`` sees at their window centres.

    A tie whose centre no longer reaches the DEM through the updated model (a ray past the DEM's
    edge or into a void: measured, 2 of 9 996 ties on a full-width strip) is dropped, not passed
    on as a NaN ground point.
    """
    lon, lat, h = (np.asarray(a, float).reshape(-1) for a in model.image_to_ground(
        ties.row_ref, ties.col_ref, dem=dem, height=height, band=model.reference_band, array=ties.ccd_ref))
    keep = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
    ties = replace(ties, lon=lon, lat=lat, h=h)
    if keep.all():
        return ties
    return replace(ties, **{f.name: getattr(ties, f.name)[keep] for f in fields(ties)
                            if isinstance(getattr(ties, f.name), np.ndarray)})


def _observations(model, ties, gcps, dem, height):
    """GCP observations and the tie observations of every band (CCD groups numbered across bands)."""
    obs, offset = [gcp_observations(model, gcps)], 0
    for band, t in ties.items():
        obs.append(tie_observations(model, t, dem=dem, height=height, group_offset=offset))
        offset += len(model.band_ccds(band))
    return obs


def _attitude_step(model, obs, options, interior_terms, near=None):
    """Joint selection around ``model``'s correction; the chosen one with its GCP mean removed.

    ``near`` (the previous round's choice) limits the candidates to the static model and those
    of its family within a factor of two of its terms.
    """
    cands = joint_candidates(options.attitude, model, obs, min_span_fraction=options.min_span_fraction)
    if near is not None:
        cands = [c for c in cands if c is None or (c.kind == near.kind and near.n_terms / 2 <= c.n_terms <= 2 * near.n_terms)]
    yaw = None if options.attitude_yaw_sigma_urad is None else options.attitude_yaw_sigma_urad * 1e-6
    chosen, cov, table = joint_select(obs, cands, base=model.attitude_correction, interior_terms=interior_terms,
                                      yaw_sigma_rad=yaw)
    if chosen is not None and chosen.kind == "spline":  # the installation takes the mean (B-splines sum to one)
        g = obs[0]
        if np.any(g.weight > 0):
            mean = np.average(chosen.angles(g.seconds[0]), axis=0, weights=g.weight)
            chosen = chosen.with_coefficients(chosen.coefficients_rad - mean[:, None])
    return chosen, cov, table


def _change_urad(model, a, b):
    """RMS difference (µrad) of two corrections over the image lines (None is zero)."""
    t = model.line_timing.seconds(np.linspace(0.0, float(model.n_rows), 512))
    da = (0.0 if a is None else a.angles(t)) - (0.0 if b is None else b.angles(t))
    return float(np.sqrt(np.mean(np.square(da)))) * 1e6


def calibrate_with_parallax(model, ties, gcps, *, dem=None, height=None, options=None, rounds: int = 3,
                            tol_urad: float = 0.05, progress=None) -> ParallaxResult:
    """Attitude correction from GCPs and band parallax, alternated with the interiors.

    Each round: (1) the joint least squares of :func:`joint_select` on the reference band's
    GCPs and every band's ties under the current model chooses and solves the correction (its
    mean over the GCPs goes to the installation); (2) the reference band's exterior and
    interior are solved again from the GCPs with the correction held; (3) each band's interior
    is solved again from its ties (ground re-localized through the new reference band), the
    exterior held. Rounds stop when the correction moves by less than ``tol_urad`` (rms over
    the lines).

    Parameters
    ----------
    model : PushbroomModel
        Reference band calibrated, other bands' interiors calibrated from their ties.
    ties : dict of str to calibrate.tie_points.TiePoints
        Per band (not the reference band).
    gcps : GcpTable
        The reference band's GCPs (points of kind ``"gcp"``).
    dem : Dem, optional
    height : float, optional
        Localization of the ties' windows (exactly one).
    options : CalibrationOptions, optional
        ``attitude`` (the candidate family; ``"static"`` keeps the model), ``robust``,
        ``interior_terms``, ``min_span_fraction``; default ``CalibrationOptions()``.
    rounds : int
        Most rounds.
    tol_urad : float
        Convergence threshold.
    progress : callable(str), optional

    Returns
    -------
    ParallaxResult
        ``success=False`` (and the input model) when a re-solve fails.
    """
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions

    options = options or CalibrationOptions()
    say = progress or (lambda message: None)
    terms = options.interior_terms if isinstance(options.interior_terms, int) else 3
    ref_opts = options.replace(attitude="static")
    band_opts = CalibrationOptions(scheme="interior", robust=options.robust, interior_terms=options.interior_terms)
    gcp_only, current = model.attitude_correction, model
    out = ParallaxResult(model, False, "no round", gcp_only, gcp_only, None, [], 0, 0, 0, None, {})
    for k in range(int(rounds)):
        obs = _observations(current, ties, gcps, dem, height)
        say(f"parallax round {k + 1}: {int(np.sum(obs[0].weight > 0))} GCPs, "
            f"{sum(int(np.sum(o.weight > 0)) for o in obs[1:])} ties")
        chosen, cov, table = _attitude_step(current, obs, options, terms, near=out.correction if k else None)
        ref = calibrate_model(current.with_attitude_correction(chosen), gcps, options=ref_opts)
        if not ref.success:
            out.message = f"round {k + 1}: the reference band's re-solve failed ({ref.message}); the input model is kept"
            return out
        new, cals = ref.model, {}
        for band, t in ties.items():
            ties[band] = t = _with_ground(new, t, dem, height)
            cals[band] = cal = calibrate_model(new, t.as_gcp_table(), options=band_opts)
            if not cal.success:
                out.message = f"round {k + 1}: band {band}'s interior failed ({cal.message}); the input model is kept"
                return out
            new = cal.model
        moved = _change_urad(current, chosen, current.attitude_correction)
        out = ParallaxResult(new, True, f"{k + 1} round(s); last change {moved:.3f} µrad rms", chosen, gcp_only, cov,
                             table, int(np.sum(obs[0].weight > 0)), sum(int(np.sum(o.weight > 0)) for o in obs[1:]),
                             k + 1, ref, cals)
        current = new
        if moved < tol_urad:
            break
    return out
