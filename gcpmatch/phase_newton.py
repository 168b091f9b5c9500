"""Newton refinement of the phase-correlation peak on the continuous correlation surface.

The surface of a half cross-power spectrum ``Q`` (shape ``(H, W // 2 + 1)``, from
``scipy.fft.rfft2``) is, at any real position ``(x, y)`` in pixels,

    c(x, y) = Re sum_{k1, k2} m(k2) Q(k1, k2) exp(2 pi i (k1 x / H + k2 y / W)) / (H W),

with ``k1`` the signed row frequencies, ``k2 = 0 .. W // 2`` and ``m(k2)`` the Hermitian
multiplicity of a half-spectrum column (1 for the first and, for even ``W``, the Nyquist column;
2 otherwise): the inverse DFT of the full spectrum, evaluated between the grid points. Its
gradient and Hessian come from the same separable sums with ``k1`` and ``k2`` powers:
``S_ij = a^T diag(k1)^i Q diag(k2)^j b`` with ``a = exp(2 pi i k1 x / H)`` and
``b = m exp(2 pi i k2 y / W)``:

    c = Re S_00 / (H W),        dc/dx = -(2 pi / H) Im S_10 / (H W),
    d2c/dx2 = -(2 pi / H)^2 Re S_20 / (H W),   d2c/dx dy = -(2 pi / H)(2 pi / W) Re S_11 / (H W),

and likewise for ``y``. One Newton step ``d = -Hess^-1 grad`` per pair costs one product of a
``6 x H`` real matrix (the rows ``a``, ``k1 a``, ``k1^2 a``, real and imaginary parts) with the
``H x 2 (W // 2 + 1)`` real view of ``Q`` and one ``6 x (W // 2 + 1)`` by ``(W // 2 + 1) x 6``
product, for the whole batch at once (``numpy.matmul``). Near the peak Newton's method converges quadratically (Ortega
and Rheinboldt 1970, ch. 10 and 12); from the 3-point parabolic estimate of the integer grid
(within about 0.3 px) two steps reach the maximum to better than 1e-4 px (measured:
``tests/test_phase.py``, ``docs/speed.md`` section 6). This replaces evaluating the surface
on upsampled DFT grids (Guizar-Sicairos, Thurman and Fienup 2008), which the integer
``upsample`` option of :func:`gcpmatch.phase.phase_correlate` still selects.

Safeguards: a pair whose Hessian is not negative definite (a start outside the peak's concave
region) keeps its position for that step; a step is clipped to +/- 0.5 px per axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_STEP_PX", "NEWTON_MAX_ITERATIONS", "NEWTON_TOLERANCE_PX", "SurfaceGrid", "newton_refine", "newton_step",
           "surface_grid"]

#: The iterations stop when every step of the batch is shorter than this, px. Newton's error
#: after a step of length ``d`` is about ``K d^2`` with ``K`` about 0.05 / px (measured on
#: the benchmark's 64 x 64 px textures: a 0.2 px step leaves 2e-3 px), so 0.01 px leaves
#: about 5e-6 px.
NEWTON_TOLERANCE_PX = 0.01
#: Upper bound on the iterations (two suffice from the parabolic start; measured).
NEWTON_MAX_ITERATIONS = 4
#: Largest Newton step per axis, px (a start outside the concave region cannot run away).
MAX_STEP_PX = 0.5
_TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class SurfaceGrid:
    """Frequency tables of the continuous surface of (H, W) windows, built once per plan."""

    height: int
    width: int
    turns_per_px: np.ndarray  # (H + Wh,) float64: k1 / H, then k2 / W
    axis: np.ndarray  # (H + Wh,) intp: 0 for the row frequencies, 1 for the column ones
    freq_row: np.ndarray  # (H,) k1 in the working precision
    col_powers: np.ndarray  # (Wh, 3) m k2^j, j = 0, 1, 2, in the working precision


def surface_grid(shape: tuple[int, int], dtype=np.float32) -> SurfaceGrid:
    """The frequency tables of :func:`newton_step` for windows of ``shape`` = (H, W).

    Parameters
    ----------
    shape : (int, int)
        Window size (H, W), pixels.
    dtype : numpy dtype
        Working precision (float32 or float64) of the spectra.

    Returns
    -------
    SurfaceGrid
        Signed row frequencies ``k1`` (``numpy.fft.fftfreq(H, 1 / H)``), column frequencies
        ``k2 = 0 .. W // 2`` with their Hermitian multiplicity ``m`` (1 for the first and, for
        even ``W``, the Nyquist column; 2 otherwise).
    """
    height, width = shape
    freq_row = np.fft.fftfreq(height, 1.0 / height)
    freq_col = np.arange(width // 2 + 1, dtype=float)
    multiplicity = np.where((freq_col == 0) | (2 * freq_col == width), 1.0, 2.0)
    return SurfaceGrid(
        height=height, width=width,
        turns_per_px=np.concatenate([freq_row / height, freq_col / width]),
        axis=np.repeat([0, 1], [height, freq_col.size]),
        freq_row=freq_row.astype(dtype),
        col_powers=(multiplicity * freq_col ** np.arange(3)[:, None]).T.astype(dtype),
    )


def newton_step(cross: np.ndarray, centre_px: np.ndarray, grid: SurfaceGrid):
    """One Newton step towards the maximum of the continuous correlation surface, per pair.

    Parameters
    ----------
    cross : ndarray of complex64 or complex128, shape (B, H, W // 2 + 1), C-contiguous
        Half cross-power spectra ``Q``.
    centre_px : ndarray of float64, shape (B, 2)
        Current (row, col) positions on the surface, pixels (a shift of ``(x, y)`` px).
    grid : SurfaceGrid
        Frequency tables of :func:`surface_grid` for (H, W) in the precision of ``cross``.

    Returns
    -------
    step : ndarray of float64, shape (B, 2)
        Newton step (row, col), px, clipped to +/- ``MAX_STEP_PX``; 0 where the Hessian is not
        negative definite.
    value : ndarray of float64, shape (B,)
        ``H W`` times the surface value at the new position from the second-order model:
        ``c + grad . d + d^T Hess d / 2 = c + grad . d / 2``.
    """
    n, height, half = cross.shape
    real = cross.real.dtype
    # exp(2 pi i k1 x / H) and exp(2 pi i k2 y / W): phases reduced to one turn in float64, then
    # cos and sin in the working precision (float32: vectorized), both axes in one array
    turns = centre_px[:, grid.axis] * grid.turns_per_px
    turns -= np.rint(turns)
    phase = (turns * _TWO_PI).astype(real)
    cos, sin = np.cos(phase), np.sin(phase)
    rows = np.empty((n, 6, height), dtype=real)  # a, k1 a, k1^2 a as rows 0-2 (Re) and 3-5 (Im)
    rows[:, 0] = cos[:, :height]
    rows[:, 3] = sin[:, :height]
    np.multiply(rows[:, 0::3], grid.freq_row, out=rows[:, 1::3])
    np.multiply(rows[:, 1::3], grid.freq_row, out=rows[:, 2::3])
    prod = np.matmul(rows, cross.view(real))  # (B, 6, 2 Wh): columns alternate Re Q, Im Q
    # T_i = k1^i a^T Q = (P_re[i] - P_im[3 + i]) + i (P_im[i] + P_re[3 + i]), as [Re; Im] rows
    t = np.concatenate([prod[:, :3, 0::2] - prod[:, 3:, 1::2], prod[:, :3, 1::2] + prod[:, 3:, 0::2]], axis=1)
    # k2^j b = m k2^j (cos + i sin) as [Re | Im] columns: S = T (k2^j b), one product
    cols = np.concatenate([cos[:, height:, None] * grid.col_powers, sin[:, height:, None] * grid.col_powers], axis=2)
    blocks = np.matmul(t, cols).astype(np.float64)  # (B, 6, 6): [Re T; Im T] x [Re B | Im B]
    s_re = blocks[:, :3, :3] - blocks[:, 3:, 3:]  # S_ij, i: k1 power, j: k2 power
    s_im = blocks[:, :3, 3:] + blocks[:, 3:, :3]
    return _solve(s_re, s_im, height, grid.width)


def newton_refine(cross: np.ndarray, centre_px: np.ndarray, grid: SurfaceGrid, *,
                  max_iterations: int = NEWTON_MAX_ITERATIONS, tolerance_px: float = NEWTON_TOLERANCE_PX):
    """Newton iterations to the surface maximum near ``centre_px``, batched (module docstring).

    Parameters
    ----------
    cross : ndarray of complex, shape (B, H, W // 2 + 1)
        Half cross-power spectra ``Q``.
    centre_px : ndarray of float64, shape (B, 2)
        Start (row, col), px (within the peak's concave region: about +/- 0.5 px).
    grid : SurfaceGrid
        Frequency tables of :func:`surface_grid`.
    max_iterations : int
        Upper bound on the steps.
    tolerance_px : float
        A pair stops after a step shorter than this, px (so its result does not depend on the
        other pairs of the batch); the iterations end when every pair has stopped.

    Returns
    -------
    centre : ndarray of float64, shape (B, 2)
        Position of the maximum (row, col), px.
    peak : ndarray of float64, shape (B,)
        Surface value there, ``c`` of the module docstring (normalized by ``H W``).
    """
    cross = np.ascontiguousarray(cross)
    centre = np.array(centre_px, dtype=np.float64)  # a copy: updated in place
    value = np.zeros(centre.shape[0])
    active = np.arange(centre.shape[0])  # a pair stops once its step is below the tolerance
    for _ in range(max_iterations):
        # after the first step only the pairs still moving are gathered (usually a few)
        sub = cross if active.size == cross.shape[0] else cross[active]
        step, value[active] = newton_step(sub, centre[active], grid)
        centre[active] += step
        active = active[np.abs(step).max(axis=1) >= tolerance_px]
        if active.size == 0:
            break
    return centre, value / (grid.height * grid.width)


def _solve(s_re, s_im, height, width):
    """Newton step and model value from the sums ``S_ij`` (B, 3, 3) (module docstring)."""
    ur, uc = _TWO_PI / height, _TWO_PI / width
    grad = s_im[:, (1, 0), (0, 1)] * np.array([-ur, -uc])  # (B, 2): d/drow, d/dcol
    hess = s_re[:, (2, 0, 1), (0, 2, 1)] * np.array([-ur * ur, -uc * uc, -ur * uc])  # rr, cc, rc
    det = hess[:, 0] * hess[:, 1] - hess[:, 2] ** 2
    ok = (hess[:, 0] < 0) & (det > 0)
    # -Hess^-1 grad = (h_rc g_c - h_cc g_r, h_rc g_r - h_rr g_c) / det
    step = (hess[:, 2:] * grad[:, ::-1] - hess[:, 1::-1] * grad) / np.where(ok, det, 1.0)[:, None]
    step = np.clip(np.where(ok[:, None], step, 0.0), -MAX_STEP_PX, MAX_STEP_PX)
    value = s_re[:, 0, 0] + 0.5 * (grad * step).sum(axis=1)
    return step, value
