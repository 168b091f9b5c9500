"""The least-squares problem of a GCP calibration: grouped points and their residual function.

:class:`CalibrationProblem` holds the GCPs grouped by band and CCD (:mod:`calibrate.gcp_groups`)
in the order the solver sees them (first a strided sample of every group, from which the solver
takes its provisional robust scale, then the rest in chunks), and builds for one step the
chunked residual and Jacobian function over the free parameters (:class:`~calibrate.lsq_inputs.Chunk`),
fitting only the groups the step selects. :data:`EXTERIOR` names the installation angles.
"""

from __future__ import annotations

import numpy as np

from calibrate.lsq_inputs import Chunk
from calibrate.normal_equations import PROBE_POINTS

__all__ = ["EXTERIOR", "CalibrationProblem"]

#: the exterior of a camera: its installation angles (camera -> body), radians
EXTERIOR = ("installation.roll", "installation.pitch", "installation.yaw")


class CalibrationProblem:
    """GCPs grouped by band and CCD, and the chunked residual/Jacobian function of a step.

    Parameters
    ----------
    model : SensorModel
        The model whose parameters are estimated (its values are the starting point).
    points : dict of str to ndarray
        ``row, col, lon, lat, h`` of the GCPs (:func:`calibrate.gcp_groups.as_points`).
    weight : ndarray, shape (N,)
        Prior weights, 1/px^2.
    groups : list
        Of :func:`calibrate.gcp_groups.group_points`.
    chunk_points : int
        Points per chunk handed to the solver.
    attitude_free : bool
        Count the attitude correction's coefficients with the exterior.
    """

    def __init__(self, model, points, weight, groups, chunk_points, *, attitude_free=False):
        self.model = model
        self.points = points
        self.weight = weight
        self.groups = groups
        self.chunk_points = int(chunk_points)
        self.all_names = tuple(model.parameters().names)
        self.exterior = EXTERIOR + (tuple(model.parameter_groups().get("attitude", ())) if attitude_free else ())
        self.lookup = {n: i for i, n in enumerate(self.all_names)}
        layout = model.interior_layout
        self.pushbroom = layout == "per_array"  # one interior per detector array (CCD)
        self.staged = layout != "none"  # exterior + interior groups
        # yield order: first a strided sample of every group (the solver takes its provisional
        # robust scale from the first points it sees), then the rest in chunks
        n = sum(g.idx.size for g in groups)
        stride = max(1, n // PROBE_POINTS)
        probes, rests = [], []
        for k, g in enumerate(groups):
            take = np.zeros(g.idx.size, dtype=bool)
            take[::stride] = True
            probes.append((k, g.idx[take]))
            rest = g.idx[~take]
            rests += [(k, rest[a : a + self.chunk_points]) for a in range(0, rest.size, self.chunk_points)]
        self.segments = [(k, idx) for k, idx in probes + rests if idx.size]
        self.order = np.concatenate([idx for _k, idx in self.segments])

    def chunks_for(self, theta, free, active, max_extrapolation=np.inf):
        """Residual function over the free names; ``active(group) -> bool`` selects the fit.

        Points whose projection, shifted by the chunk's median column residual, falls more
        than ``max_extrapolation`` (a fraction of the CCD's detectors) outside their CCD are
        left out of that evaluation: where the interior is estimated the cubic's Jacobian there
        gives them unbounded leverage, and a point observed on one CCD but projected far beyond
        it is a mismatch.
        """
        free = tuple(free)
        free_idx = np.array([self.lookup[n] for n in free], dtype=np.intp)
        position = {n: j for j, n in enumerate(free)}
        plan = []
        for g in self.groups:
            if not active(g):
                plan.append((g, (), np.zeros(0, dtype=np.intp), False))  # evaluated, not fitted
                continue
            names = [n for n in free if n in self.exterior] if self.staged else list(free)
            if self.staged and g.estimable:
                names += [n for n in g.interior if n in position]
            cols = np.array([position[n] for n in names], dtype=np.intp)
            bounds = None
            if self.pushbroom and np.isfinite(max_extrapolation):
                look = self.model.detector_arrays(g.band)[g.ccd]
                margin = max_extrapolation * look.n_detectors
                lo = look.first_col + 0.5 - margin
                bounds = (lo, lo + look.n_detectors - 1.0 + 2.0 * margin)
            plan.append((g, tuple(names), cols, bounds))
        p = self.points

        def chunks(x):
            values = theta.copy()
            values[free_idx] = x
            model = self.model.with_parameters(values)
            for k, sel in self.segments:
                g, names, cols, bounds = plan[k]
                kw = {"band": g.band, "array": g.ccd} if self.pushbroom else {"band": g.band}
                if names:
                    r, c, jac = model.image_jacobian(
                        p["lon"][sel], p["lat"][sel], p["h"][sel], names=names, **kw
                    )
                else:
                    r, c = model.ground_to_image(p["lon"][sel], p["lat"][sel], p["h"][sel], **kw)
                    jac = np.zeros((sel.size, 2, 0))
                res = np.stack([p["row"][sel] - r, p["col"][sel] - c], axis=-1)
                if bounds is False:
                    w = np.zeros(sel.size)
                elif bounds is None:
                    w = self.weight[sel]
                else:
                    # the chunk's median column residual removes a common offset (a model
                    # still hundreds of pixels off) before the extrapolation test
                    c_shifted = c + _median_or_zero(p["col"][sel] - c)
                    w = np.where((c_shifted >= bounds[0]) & (c_shifted <= bounds[1]), self.weight[sel], 0.0)
                yield Chunk(res, jac, w, cols)

        return chunks

    def to_input_order(self, grouped):
        """Per-point values in the solver's order (``self.order``) back in input order (NaN where unseen)."""
        out = np.full((self.order.size,) + grouped.shape[1:], np.nan)
        out[self.order] = grouped
        return out


def _median_or_zero(values):
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else 0.0
