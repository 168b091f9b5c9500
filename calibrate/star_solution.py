"""Least squares of the frame-0 model of a staring camera from star tracks (seed 000 eq. 11-17).

:func:`calibrate_tracks` minimizes the image-space residuals ``observed - star_to_image(w')``
of the virtual star vectors ``w'`` (seed 000 eq. 9) with :func:`calibrate.lsq.solve` and the
analytic Jacobian ``star_jacobian``: first the exterior (installation roll, pitch, yaw; eq.
12-14), then the interior (the directional-angle coefficients; eq. 15-17) in the frame fixed by
the exterior, repeated until the exterior stops moving; or the exterior alone; or all
parameters at once with the gauge pseudo-observations of :meth:`GeoStaringModel.gauge_rows`.
The interior carries a weak prior towards the laboratory values (``interior_prior_px``).
"""

from __future__ import annotations

import numpy as np

from calibrate.config import STAR_SCHEMES, StarOptions
from calibrate.lsq import solve
from calibrate.lsq_inputs import Chunk, Prior
from sensor_models.errors import InputError
from sensor_models.models.geo_staring import GeoStaringModel

__all__ = ["calibrate_tracks"]

_EXTERIOR = ("installation.roll", "installation.pitch", "installation.yaw")


def _gauge_prior(model: GeoStaringModel, free, sigma_px: float):
    rows, scale = model.gauge_rows()
    names = list(model.parameter_names())
    idx = [names.index(n) for n in free]
    matrix = np.asarray(rows)[:, idx]
    keep = np.any(matrix != 0.0, axis=1)
    x0 = model.parameters().values[idx]
    return matrix[keep], matrix[keep] @ x0, sigma_px * np.asarray(scale)[keep]


def _prior(model: GeoStaringModel, free, *, interior_prior_px: float | None, gauge_sigma_px: float | None):
    """Weak interior prior towards ``model``'s values, plus the gauge for a joint solve."""
    names = list(model.parameter_names())
    values = model.parameters().values
    mats, vals, sigs = [], [], []
    interior = [k for k, n in enumerate(free) if n.startswith("interior.")]
    if interior and interior_prior_px:
        m = np.zeros((len(interior), len(free)))
        m[np.arange(len(interior)), interior] = 1.0
        mats.append(m)
        vals.append(values[[names.index(free[k]) for k in interior]])
        sigs.append(np.full(len(interior), interior_prior_px * model.ifov_rad))
    if gauge_sigma_px and interior and any(n in _EXTERIOR for n in free):
        m, v, s = _gauge_prior(model, free, gauge_sigma_px)
        mats.append(m), vals.append(v), sigs.append(s)
    if not mats:
        return None
    return Prior(np.vstack(mats), np.concatenate(vals), np.concatenate(sigs))


def calibrate_tracks(model0: GeoStaringModel, virtual_gcrf, row, col, *, scheme: str = StarOptions.scheme,
                     interior_degree: int = StarOptions.interior_degree, robust: str = StarOptions.robust,
                     interior_prior_px: float | None = StarOptions.interior_prior_px,
                     gauge_sigma_px: float = 1e-3, max_outer: int = 5, outer_tol: float = 0.05,
                     max_iter: int = 20, tol: float = 0.01):
    """Stepwise (or joint) least squares of the frame-0 model from virtual star vectors.

    Parameters
    ----------
    model0 : GeoStaringModel
        Initial model at frame 0 (LAB).
    virtual_gcrf : array_like, shape (N, 3)
        Directions that frame 0 images at ``(row, col)`` (seed 000 eq. 9).
    row, col : array_like, shape (N,)
        Observed (smoothed) track points, pixels.
    scheme : {"exterior-interior", "exterior", "joint"}
        Seed 000's stepwise exterior-then-interior (eq. 12-17), the exterior alone, or all
        parameters at once with the gauge pseudo-observations.
    interior_degree : int
        Degree of the estimated interior polynomials (3: the 20 coefficients).
    robust : {"huber", "cauchy", "none"}
        Robust loss of :func:`calibrate.lsq.solve`.
    interior_prior_px : float or None
        Standard deviation (pixels at the frame edge) of a pseudo-observation holding every
        interior coefficient at its initial value; None: no prior.
    gauge_sigma_px : float
        Joint scheme: standard deviation of the gauge pseudo-observations, pixels.
    max_outer, outer_tol : int, float
        Stepwise scheme: rounds, and the stop when an exterior step moves every angle by less
        than ``outer_tol`` of its standard deviation.
    max_iter, tol : int, float
        Per step, passed to :func:`calibrate.lsq.solve`.

    Returns
    -------
    theta : ndarray, shape (23,)
        Parameters over ``model0.parameter_names()``.
    runs : list of dict
        One per least-squares step: ``step``, ``round``, ``success``, ``message``,
        ``iterations``, ``sigma0``, ``condition_number``.
    result : LsqResult
        Of the last step.
    """
    if scheme not in STAR_SCHEMES:
        raise InputError(f"must be one of {', '.join(STAR_SCHEMES)}, got {scheme!r}", field="scheme")
    w = np.asarray(virtual_gcrf, dtype=np.float64).reshape(-1, 3)
    obs = np.stack([np.asarray(row, dtype=np.float64), np.asarray(col, dtype=np.float64)], -1)
    if obs.shape[0] != w.shape[0] or obs.shape[0] == 0:
        raise InputError(f"{obs.shape[0]} points for {w.shape[0]} vectors", field="row")
    interior = list(model0.interior_parameter_names(interior_degree))
    stepper = _TrackStepper(model0, w, obs, robust=robust, max_iter=max_iter, tol=tol)
    no_prior = dict(interior_prior_px=None, gauge_sigma_px=None)
    if scheme == "exterior":
        stepper.step(list(_EXTERIOR), "exterior", 0, no_prior)
    elif scheme == "joint":
        stepper.step(list(_EXTERIOR) + interior, "joint", 0,
                     dict(interior_prior_px=interior_prior_px, gauge_sigma_px=gauge_sigma_px))
    else:
        for rnd in range(max(1, int(max_outer))):
            res, moved = stepper.step(list(_EXTERIOR), "exterior", rnd, no_prior)
            if not res.success or (rnd > 0 and moved < outer_tol):
                break
            res, _ = stepper.step(interior, "interior", rnd,
                                  dict(interior_prior_px=interior_prior_px, gauge_sigma_px=None))
            if not res.success:
                break
    return stepper.theta, stepper.runs, stepper.last


class _TrackStepper:
    """One least-squares step after another on the frame-0 model; keeps the values and log."""

    def __init__(self, model0, virtual_gcrf, observed, *, robust, max_iter, tol):
        self.model0 = model0
        self.w = virtual_gcrf
        self.obs = observed
        self.solve_kw = dict(robust=robust, max_iter=max_iter, tol=tol)
        self.names = list(model0.parameter_names())
        self.theta = model0.parameters().values.copy()
        self.runs, self.last = [], None

    def step(self, free, label, rnd, prior_kw):
        """Solve for ``free``; the result and how far it moved them, in standard deviations."""
        idx = np.array([self.names.index(n) for n in free])
        theta, model0, w, obs = self.theta, self.model0, self.w, self.obs

        def chunks(x):
            full = theta.copy()
            full[idx] = x
            r, c, jac = model0.with_parameters(full).star_jacobian(w, names=free)
            return [Chunk(obs - np.stack([r, c], -1), jac)]

        prior = _prior(model0.with_parameters(theta), free, **prior_kw)
        res = solve(chunks, theta[idx], names=free, prior=prior, warm_start=bool(self.runs), **self.solve_kw)
        self.runs.append({"step": label, "round": rnd, "success": bool(res.success), "message": res.message,
                          "iterations": int(res.iterations), "sigma0": float(res.sigma0),
                          "condition_number": float(res.condition_number)})
        self.last = res
        if not res.success:
            return res, np.inf
        moved = np.abs(res.x - theta[idx])
        sig = res.sigma
        self.theta = theta.copy()
        self.theta[idx] = res.x
        return res, (float(np.max(moved / sig)) if sig is not None and np.all(sig > 0) else np.inf)
