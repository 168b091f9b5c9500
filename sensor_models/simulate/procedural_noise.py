"""Hashing, value noise and separable cubic resampling of the procedural reference.

The deterministic random primitives of :func:`sensor_models.simulate.procedural.generate_reference`:

* :func:`mix32`, :func:`hash32`, :func:`unit_float`: a 32-bit integer hash [5]_ of a key and
  integer lattice coordinates, and uniform floats drawn from it;
* :func:`resample`: separable Keys cubic convolution [6]_, cubic B-spline or linear resampling
  of node grids at the outer product of rows and columns;
* :func:`value_noise`: smooth noise of unit standard deviation (an i.i.d. uniform lattice
  blended by the cubic B-spline), a function of the key and the coordinates only;
* :func:`smoothstep`: the cubic Hermite step.

References
----------
.. [5] C. Wellons, "Prospecting for hash functions", 2018 (the ``lowbias32`` integer mixer).
.. [6] R. Keys, "Cubic convolution interpolation for digital image processing", IEEE Trans.
   ASSP 29(6), 1153-1160, 1981.
"""

from __future__ import annotations

import math

import numpy as np

#: Standard deviation of B-spline value noise made of uniform(-1, 1) nodes:
#: sqrt(1/3) * (integral of the sum of squared cubic B-spline weights = 151/315) per axis.
_VALUE_NOISE_STD = math.sqrt(1.0 / 3.0) * (151.0 / 315.0)


def mix32(h):
    """Wellons' lowbias32 integer mixer on a uint32 array (wrapping arithmetic), in place."""
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x7FEB352D)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x846CA68B)
    h ^= h >> np.uint32(16)
    return h


def hash32(key, *ints):
    """uint32 hash of a key and integer arrays (broadcast together); at least 1-D."""
    shape = np.broadcast_shapes(*(np.shape(a) for a in ints)) or (1,)
    h = np.full(shape, key & 0xFFFFFFFF, dtype=np.uint32)
    for a in ints:
        a = np.asarray(a)
        if a.dtype != np.uint32:
            a = (a.astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)
        h ^= a
        mix32(h)
        h += np.uint32(0x9E3779B9)
    return mix32(h)


def unit_float(h):
    """Uniform [0, 1) float32 from the top 24 bits of a uint32 hash."""
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(2.0**-24)


def _taps(t, kind):
    """Node offsets and weights at fraction ``t`` in [0, 1) of the interpolation kernels.

    ``"keys"``: Keys cubic convolution with ``a = -1/2`` [6]_ (interpolating, C1);
    ``"bspline"``: uniform cubic B-spline (smoothing, C2); ``"linear"``: two taps.
    """
    t = t.astype(np.float32)
    if kind == "linear":
        return (0, 1), (1.0 - t, t)
    t2 = t * t
    t3 = t2 * t
    if kind == "bspline":
        s = 1.0 - t
        return (-1, 0, 1, 2), (s * s * s / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
                               (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0)
    return (-1, 0, 1, 2), (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0,
                           -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)


def resample(grid, row_f, col_f, kind="keys"):
    """Separable resampling of node grids at the outer product of rows and columns.

    Parameters
    ----------
    grid : ndarray, shape (..., R, C), float32
        Values at integer node indices.
    row_f, col_f : ndarray, shape (m,) and (n,)
        Fractional node indices of the output rows and columns (nodes clamped at the edges).
    kind : {"keys", "bspline", "linear"}
        Kernel (see :func:`_taps`).

    Returns
    -------
    ndarray, shape (..., m, n), float32
    """
    n_r, n_c = grid.shape[-2:]
    r0 = np.floor(row_f).astype(np.intp)
    c0 = np.floor(col_f).astype(np.intp)
    lo = max(int(r0.min()) - 1, 0)
    hi = min(int(r0.max()) + 3, n_r)
    sub = grid[..., lo:hi, :]
    tmp = None
    for k, w in zip(*_taps(col_f - c0, kind)):
        term = np.take(sub, np.clip(c0 + k, 0, n_c - 1), axis=-1)
        term *= w
        tmp = term if tmp is None else np.add(tmp, term, out=tmp)
    out = None
    for k, w in zip(*_taps(row_f - r0, kind)):
        term = np.take(tmp, np.clip(r0 + k, 0, n_r - 1) - lo, axis=-2)
        term *= w[:, None]
        out = term if out is None else np.add(out, term, out=out)
    return out


def value_noise(key, x_m, y_m, spacing_m):
    """Smooth noise of unit standard deviation (on average) on a separable grid of points.

    Uniform(-1, 1) values at the nodes of a square lattice of ``spacing_m`` (offset by a
    key-dependent fraction of a cell), blended by the cubic B-spline. The value at a point
    depends only on ``key`` and its coordinates, whatever the grid it is evaluated on.

    Parameters
    ----------
    key : int
    x_m : ndarray, shape (n,)
        Eastings of the columns (any origin), metres.
    y_m : ndarray, shape (m,)
        Northings of the rows, metres.
    spacing_m : float

    Returns
    -------
    ndarray, shape (m, n), float32
    """
    off = (key % 997) / 997.0
    gx = np.asarray(x_m, dtype=np.float64) / spacing_m + off
    gy = np.asarray(y_m, dtype=np.float64) / spacing_m + off
    jx0 = int(np.floor(gx.min())) - 1
    jx1 = int(np.floor(gx.max())) + 2
    jy0 = int(np.floor(gy.min())) - 1
    jy1 = int(np.floor(gy.max())) + 2
    jx = np.arange(jx0, jx1 + 1)
    jy = np.arange(jy0, jy1 + 1)
    nodes = unit_float(hash32(key, jy[:, None], jx[None, :])) * np.float32(2.0) - np.float32(1.0)
    out = resample(nodes, gy - jy0, gx - jx0, "bspline")
    out *= np.float32(1.0 / _VALUE_NOISE_STD)
    return out


def smoothstep(a, b, x):
    """Cubic Hermite step ``3 t^2 - 2 t^3`` of ``t = clip((x - a) / (b - a), 0, 1)``."""
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
