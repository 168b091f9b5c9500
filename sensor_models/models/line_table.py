"""Exterior orientation tabulated along the image lines, interpolated by a Catmull-Rom cubic.

A push-broom model (:class:`~sensor_models.models.pushbroom.PushbroomModel`) tabulates the
satellite position ``P_itrf`` and the rotation ``R_body_to_itrf`` at uniformly spaced rows and
interpolates them with the uniform Catmull-Rom cubic (C1, exact for cubics' values at the
knots), which gives analytic derivatives in the row and keeps the frame computations out of the
hot path. :func:`catmull_rom_weights` is the interpolation kernel (also used by the block
localization of :mod:`sensor_models.imaging.locate`); :class:`LineTable` the table.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LineTable", "catmull_rom_weights"]


def catmull_rom_weights(t):
    """Weights of the uniform Catmull-Rom cubic and of its derivative.

    For four knots ``v[k-1], v[k], v[k+1], v[k+2]`` the interpolated value at ``k + t`` is
    ``sum(w[:, j] * v[k - 1 + j])`` and its derivative in ``t`` ``sum(dw[:, j] * v[k - 1 + j])``.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Positions within the interval ``[k, k + 1]``, in ``[0, 1]``.

    Returns
    -------
    w, dw : ndarray, shape (N, 4) each
    """
    t2 = t * t
    t3 = t2 * t
    w = np.stack(
        [
            0.5 * (-t3 + 2.0 * t2 - t),
            0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
            0.5 * (-3.0 * t3 + 4.0 * t2 + t),
            0.5 * (t3 - t2),
        ],
        axis=-1,
    )
    dw = np.stack(
        [
            0.5 * (-3.0 * t2 + 4.0 * t - 1.0),
            0.5 * (9.0 * t2 - 10.0 * t),
            0.5 * (-9.0 * t2 + 8.0 * t + 1.0),
            0.5 * (3.0 * t2 - 2.0 * t),
        ],
        axis=-1,
    )
    return w, dw


class LineTable:
    """``P_itrf`` (m) and ``R_body_to_itrf`` tabulated at uniformly spaced rows.

    Parameters
    ----------
    row_start, row_step : float
        Row of the first knot and the knot spacing (rows).
    values : ndarray, shape (K, 12)
        Per knot ``P`` (3) then ``R`` row-major (9); ``K >= 4``.

    Attributes
    ----------
    row_min, row_max : float
        The rows the table interpolates (one knot kept on each side).
    """

    def __init__(self, row_start: float, row_step: float, values: np.ndarray):
        self.row_start = float(row_start)
        self.row_step = float(row_step)
        self.values = np.ascontiguousarray(values)  # (K, 12): P (3) then R row-major (9)
        k = values.shape[0]
        # Catmull-Rom needs one knot on each side of the interval
        self.row_min = self.row_start + self.row_step
        self.row_max = self.row_start + (k - 2) * self.row_step

    def evaluate(self, row, *, derivative: bool = False):
        """Interpolated ``P (N,3)``, ``R (N,3,3)`` and, optionally, their row derivatives."""
        u = (np.asarray(row, dtype=np.float64) - self.row_start) / self.row_step
        k = np.clip(np.floor(u).astype(np.intp), 1, self.values.shape[0] - 3)
        w, dw = catmull_rom_weights(u - k)
        v = self.values
        out = w[:, 0:1] * v[k - 1]
        out += w[:, 1:2] * v[k]
        out += w[:, 2:3] * v[k + 1]
        out += w[:, 3:4] * v[k + 2]
        p, r = out[:, :3], out[:, 3:].reshape(-1, 3, 3)
        if not derivative:
            return p, r
        d = dw[:, 0:1] * v[k - 1]
        d += dw[:, 1:2] * v[k]
        d += dw[:, 2:3] * v[k + 1]
        d += dw[:, 3:4] * v[k + 2]
        d /= self.row_step
        return p, r, d[:, :3], d[:, 3:].reshape(-1, 3, 3)
