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
``H x 2 (W // 2 + 1)`` real view of ``Q`` and a few ``3 x (W // 2 + 1)`` products, for the whole
batch at once (``numpy.matmul``). Near the peak Newton's method converges quadratically (Ortega
and Rheinboldt 1970, ch. 10 and 12); from the 3-point parabolic estimate of the integer grid
(within about 0.2 px) two steps reach the maximum to better than 1e-4 px (measured:
``tests/test_phase.py``, ``docs/speed.md`` section 6). This replaces evaluating the surface
on upsampled DFT grids (Guizar-Sicairos, Thurman and Fienup 2008), which the integer
``upsample`` option of :func:`gcpmatch.phase.phase_correlate` still selects.

Safeguards: a pair whose Hessian is not negative definite (a start outside the peak's concave
region) keeps its position for that step; a step is clipped to +/- 0.5 px per axis.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_STEP_PX", "NEWTON_MAX_ITERATIONS", "NEWTON_TOLERANCE_PX", "newton_refine", "newton_step"]

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


def _phasors(centre_px: np.ndarray, freq_row: np.ndarray, freq_col: np.ndarray, width: int, dtype):
    """``exp(2 pi i k1 x / H)`` (B, H) and ``exp(2 pi i k2 y / W)`` (B, Wh) as (cos, sin) pairs.

    The phases are reduced to one turn in float64 and their cosines and sines taken in
    ``dtype`` (float32: the vectorized single-precision ``cos``/``sin``), in one call each for
    both axes.
    """
    height = freq_row.size
    turns = np.concatenate([centre_px[:, :1] * (freq_row / height), centre_px[:, 1:] * (freq_col / width)], axis=1)
    turns -= np.round(turns)
    phase = (_TWO_PI * turns).astype(dtype)
    cos, sin = np.cos(phase), np.sin(phase)
    return cos[:, :height], sin[:, :height], cos[:, height:], sin[:, height:]


def newton_step(cross: np.ndarray, centre_px: np.ndarray, freq_row: np.ndarray, freq_col: np.ndarray,
                multiplicity: np.ndarray, width: int):
    """One Newton step towards the maximum of the continuous correlation surface, per pair.

    Parameters
    ----------
    cross : ndarray of complex64 or complex128, shape (B, H, W // 2 + 1), C-contiguous
        Half cross-power spectra ``Q``.
    centre_px : ndarray of float64, shape (B, 2)
        Current (row, col) positions on the surface, pixels (a shift of ``(x, y)`` px).
    freq_row : ndarray of float64, shape (H,)
        Signed integer row frequencies ``k1`` (``numpy.fft.fftfreq(H, 1 / H)``).
    freq_col : ndarray of float64, shape (W // 2 + 1,)
        Column frequencies ``k2 = 0 .. W // 2``.
    multiplicity : ndarray, shape (W // 2 + 1,)
        Hermitian multiplicity ``m(k2)`` (1 or 2).
    width : int
        ``W``, the window's column count (the half spectrum does not tell an odd ``W``).

    Returns
    -------
    step : ndarray of float64, shape (B, 2)
        Newton step (row, col), px, clipped to +/- 0.5 px; 0 where the Hessian is not negative
        definite.
    value : ndarray of float64, shape (B,)
        ``H W`` times the surface value at the new position from the second-order model:
        ``c + grad . d + d^T Hess d / 2 = c + grad . d / 2``.
    """
    n, height, _ = cross.shape
    real = cross.real.dtype
    k1 = freq_row.astype(real)
    k2 = freq_col.astype(real)
    ar, ai, br, bi = _phasors(centre_px, freq_row, freq_col, width, real)  # (B, H) and (B, Wh)
    br *= multiplicity
    bi *= multiplicity
    rows = np.empty((n, 6, height), dtype=real)  # a, k1 a, k1^2 a: real parts, then imaginary parts
    rows[:, 0] = ar
    rows[:, 3] = ai
    np.multiply(ar, k1, out=rows[:, 1])
    np.multiply(ai, k1, out=rows[:, 4])
    np.multiply(rows[:, 1], k1, out=rows[:, 2])
    np.multiply(rows[:, 4], k1, out=rows[:, 5])
    prod = np.matmul(rows, cross.view(real))  # (B, 6, 2 Wh): columns alternate Re Q, Im Q
    t_re = prod[:, :3, 0::2] - prod[:, 3:, 1::2]  # Re(k1^i a^T Q), i = 0, 1, 2
    t_im = prod[:, :3, 1::2] + prod[:, 3:, 0::2]
    cols_re = np.stack([br, br * k2, br * (k2 * k2)], axis=2)  # (B, Wh, 3): b, k2 b, k2^2 b
    cols_im = np.stack([bi, bi * k2, bi * (k2 * k2)], axis=2)
    s_re = (np.matmul(t_re, cols_re) - np.matmul(t_im, cols_im)).astype(np.float64)  # (B, 3, 3): S_ij
    s_im = (np.matmul(t_re, cols_im) + np.matmul(t_im, cols_re)).astype(np.float64)
    return _solve(s_re, s_im, height, width)


def newton_refine(cross: np.ndarray, centre_px: np.ndarray, freq_row: np.ndarray, freq_col: np.ndarray,
                  multiplicity: np.ndarray, *, width: int, max_iterations: int = NEWTON_MAX_ITERATIONS,
                  tolerance_px: float = NEWTON_TOLERANCE_PX):
    """Newton iterations to the surface maximum near ``centre_px``, batched (module docstring).

    Parameters
    ----------
    cross : ndarray of complex, shape (B, H, W // 2 + 1)
        Half cross-power spectra ``Q``.
    centre_px : ndarray of float64, shape (B, 2)
        Start (row, col), px (within the peak's concave region: about +/- 0.5 px).
    freq_row, freq_col, multiplicity : ndarray
        As in :func:`newton_step`.
    width : int
        ``W``, the window's column count (the half spectrum does not tell an odd ``W``).
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
    height = cross.shape[1]
    centre = np.asarray(centre_px, dtype=np.float64)
    value = np.zeros(centre.shape[0])
    active = np.ones(centre.shape[0], dtype=bool)  # a pair stops once its step is below the tolerance
    for _ in range(max_iterations):
        step, new_value = newton_step(cross, centre, freq_row, freq_col, multiplicity, width)
        centre = np.where(active[:, None], centre + step, centre)
        value = np.where(active, new_value, value)
        active &= np.abs(step).max(axis=1) >= tolerance_px
        if not active.any():
            break
    return centre, value / (height * width)


def _solve(s_re, s_im, height, width):
    """Newton step and model value from the sums ``S_ij`` (B, 3, 3) (module docstring)."""
    ur, uc = _TWO_PI / height, _TWO_PI / width
    grad_r, grad_c = -ur * s_im[:, 1, 0], -uc * s_im[:, 0, 1]
    h_rr, h_cc, h_rc = -ur * ur * s_re[:, 2, 0], -uc * uc * s_re[:, 0, 2], -ur * uc * s_re[:, 1, 1]
    det = h_rr * h_cc - h_rc * h_rc
    ok = (h_rr < 0) & (det > 0)
    det = np.where(ok, det, 1.0)
    step_r = np.where(ok, (h_rc * grad_c - h_cc * grad_r) / det, 0.0)
    step_c = np.where(ok, (h_rc * grad_r - h_rr * grad_c) / det, 0.0)
    step = np.clip(np.stack([step_r, step_c], axis=1), -MAX_STEP_PX, MAX_STEP_PX)
    value = s_re[:, 0, 0] + 0.5 * (grad_r * step[:, 0] + grad_c * step[:, 1])
    return step, value
