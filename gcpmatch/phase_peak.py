"""Sub-pixel peaks of sampled correlation surfaces: the estimators of :mod:`gcpmatch.phase`.

Three closed-form estimators, vectorized over a batch of surfaces, all in units of the
sampling step (the callers scale and add the sample positions):

- :func:`parabola_vertex`: the vertex of the parabola through three samples along one axis
  (the coarse peak's offset on the integer grid, module :mod:`gcpmatch.phase` step 3);
- :func:`quadratic_vertex`: the vertex of the least-squares quadratic
  ``f = c0 + c1 x + c2 y + c3 x^2 + c4 y^2 + c5 x y`` on a 3 x 3 patch of samples;
- :func:`grid_peak`: the maximum of a DFT-upsampled grid refined by :func:`quadratic_vertex`
  on its 3 x 3 neighbourhood (step 5, integer ``upsample``), so that the estimate is not
  quantized to the grid's step.
"""

from __future__ import annotations

import numpy as np

__all__ = ["grid_peak", "parabola_vertex", "quadratic_vertex"]


#: Least-squares coefficients ``(c1, c2, c3, c4, c5)`` of the quadratic of
#: :func:`quadratic_vertex` from the 9 samples of a 3 x 3 patch (row-major, x = row, y = col).
_X, _Y = (a.ravel() for a in np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij"))
_QUADRATIC_FIT = np.stack([_X / 6.0, _Y / 6.0, (_X**2 - 2.0 / 3.0) / 2.0, (_Y**2 - 2.0 / 3.0) / 2.0, _X * _Y / 4.0], axis=1)
_PATCH_STEPS = np.array([-1, 0, 1])


def grid_peak(values: np.ndarray, offsets_px: np.ndarray):
    """Maximum of stage grids (B, m, m) refined by a quadratic fit on its 3 x 3 neighbourhood.

    Parameters
    ----------
    values : ndarray, shape (B, m, m), m >= 3
        Surface samples on a square grid per pair (rows, columns).
    offsets_px : ndarray of float64, shape (m,)
        Evenly spaced sample offsets from the grid centre along either axis, px.

    Returns
    -------
    offset : ndarray of float64, shape (B, 2)
        (row, col) offset of the vertex from the grid centre, px (within one grid step of the
        best sample).
    best : ndarray of float64, shape (B,)
        The best sample's value.
    """
    n, m, _ = values.shape
    flat = values.reshape(n, m * m)
    best_index = np.argmax(flat, axis=1)
    best = np.take_along_axis(flat, best_index[:, None], axis=1)[:, 0].astype(float)
    a, b = np.divmod(best_index, m)
    a = np.minimum(np.maximum(a, 1), m - 2)  # neighbourhood inside the grid (only matters on its border)
    b = np.minimum(np.maximum(b, 1), m - 2)
    index = ((a * m + b)[:, None] + (_PATCH_STEPS[:, None] * m + _PATCH_STEPS[None, :]).ravel())
    d_row, d_col = quadratic_vertex(np.take_along_axis(flat, index, axis=1).astype(float).reshape(n, 3, 3))
    spacing = offsets_px[1] - offsets_px[0]
    offset = np.stack([offsets_px[a] + d_row * spacing, offsets_px[b] + d_col * spacing], axis=1)
    return offset, best


def quadratic_vertex(patch: np.ndarray):
    """Vertex (in grid steps, clipped to [-1, 1]) of the least-squares quadratic
    ``f = c0 + c1 x + c2 y + c3 x^2 + c4 y^2 + c5 x y`` on 3 x 3 samples (B, 3, 3) at
    ``x, y in {-1, 0, 1}`` (rows, columns); 0 where the fit has no maximum.

    Parameters
    ----------
    patch : ndarray, shape (B, 3, 3)
        Samples around each grid maximum, row-major (x = row, y = col).

    Returns
    -------
    d_row, d_col : ndarray of float64, shape (B,)
        Vertex offsets from the patch centre, in grid steps, in [-1, 1].
    """
    c1, c2, c3, c4, c5 = (patch.reshape(-1, 9) @ _QUADRATIC_FIT).T
    det = 4.0 * c3 * c4 - c5**2
    ok = (c3 < 0) & (det > 0)
    det = np.where(ok, det, 1.0)
    d_row = np.where(ok, (c5 * c2 - 2.0 * c4 * c1) / det, 0.0)
    d_col = np.where(ok, (c5 * c1 - 2.0 * c3 * c2) / det, 0.0)
    return np.minimum(np.maximum(d_row, -1.0), 1.0), np.minimum(np.maximum(d_col, -1.0), 1.0)


def parabola_vertex(left, centre, right) -> np.ndarray:
    """Vertex offset in [-0.5, 0.5] of the parabola through (-1, left), (0, centre), (1, right).

    Parameters
    ----------
    left, centre, right : ndarray, broadcastable shapes
        Samples at -1, 0 and +1 step from the maximum.

    Returns
    -------
    ndarray of float64, the broadcast shape
        Vertex offset in steps, clipped to [-0.5, 0.5]; 0 where the parabola has no maximum.
    """
    curvature = left - 2.0 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (left - right) / curvature, 0.0)
    return np.clip(offset, -0.5, 0.5).astype(float)
