"""The numpy + scipy.fft batch kernel of :func:`gcpmatch.phase.phase_correlate`.

:class:`NumpyKernel` runs steps 1 to 5 of the algorithm (the :mod:`gcpmatch.phase` docstring)
on one batch of window pairs with the constants of a :class:`~gcpmatch.phase_plan.PhasePlan`:
apodized spectra with the weighted mean removed in the frequency domain, the weighted
normalized cross-power, the coarse peak on the integer grid, the half-resolution first pass on
2 x 2 bins (:func:`bin_2x2`), the window-following passes and the sub-pixel refinement (Newton
steps, :mod:`gcpmatch.phase_newton`, or DFT-upsampled grids, :mod:`gcpmatch.phase_peak`). The
torch backend (``gcpmatch._phase_torch``) mirrors it call for call.
"""

from __future__ import annotations

import numpy as np
import scipy.fft

from gcpmatch.phase_newton import NEWTON_MAX_ITERATIONS, newton_refine, surface_grid
from gcpmatch.phase_peak import grid_peak, parabola_vertex
from gcpmatch.phase_plan import PhasePlan, following_windows, window_profile

__all__ = ["REVERSED_ORIGIN_PX", "NumpyKernel", "bin_2x2"]

#: The numpy kernel transforms the reference reversed: its correlation surface peaks at the shift
#: minus this many pixels per axis (``NumpyKernel.__call__``).
REVERSED_ORIGIN_PX = 1


class NumpyKernel:
    """The algorithm on numpy + scipy.fft for one batch.

    ``kernel(ref, mov)``, with ``ref``, ``mov`` of shape (B, H, W), returns six arrays:
    ``shift`` (B, 2) px; ``peak`` (B,) the refined surface maximum (last pass); ``q_mean``
    (B,) its ideal height ``sum|Q| / (H W)``; ``q_var`` (B,) the surface variance
    ``sum|Q|^2 / (H W)^2``; ``second`` (B,) the first pass's maximum outside the exclusion
    zone; ``first_q_mean`` (B,) the first pass's ``q_mean``.

    Every pass over a batch is a single vectorized operation, written where it can into
    buffers the kernel keeps between batches (fresh arrays of a few MB cost page faults);
    the fixed window's weighted mean is removed in the frequency domain (:meth:`spectrum`).
    """

    def __init__(self, plan: PhasePlan, *, workers: int = -1):
        self.plan = plan
        self.workers = workers
        apod = plan.apodization
        self.window_2d = apod if isinstance(apod, np.ndarray) else np.outer(apod[0], apod[1]).astype(plan.dtype)
        self.window_sum = float(self.window_2d.sum(dtype=np.float64))
        self.window_bins, self.window_spectrum = self._window_support(_window_2d_float64(plan))
        # the reference is transformed reversed (see __call__)
        self.window_2d_reversed = np.ascontiguousarray(self.window_2d[::-1, ::-1])
        self.reversed_bins, self.reversed_spectrum = self._window_support(_window_2d_float64(plan)[::-1, ::-1])
        self.weight_flat = plan.weight.reshape(-1)
        self.ones_flat = np.full(plan.weight.size, 1.0 / plan.weight.size, dtype=plan.dtype)
        self.neighbours, self.grid_shift = _grid_tables(plan.shape)
        self.surface_grid = surface_grid(plan.shape, plan.dtype)
        self.sum_mult_weight = float((plan.multiplicity.astype(np.float64) * plan.weight).sum())
        self._buffers = {}
        self.coarse = None if plan.coarse is None else NumpyKernel(plan.coarse, workers=workers)
        if self.coarse is not None:  # the reference's low-frequency quarter: |k1| < H/4, k2 <= W/4
            height, width = plan.shape
            self.quarter_rows = np.r_[0:height // 4, height - height // 4:height]
            self.quarter_cols = width // 4 + 1
            # the reversed reference's ramp is 1 full px = 0.5 bin per axis; the half-resolution
            # kernel expects REVERSED_ORIGIN_PX = 1 bin: complete it with another 0.5 bin
            k1 = plan.freq_row[self.quarter_rows] / height
            k2 = plan.freq_col[:self.quarter_cols] / width
            self.quarter_ramp = _unit_phasors(k1[:, None] + k2[None, :], plan.complex_dtype)

    def _window_support(self, window_2d: np.ndarray):
        """Bins (rows, cols) where ``rfft2(window_2d)`` is not negligible (6 for Hann: sin^2 at
        pixel centres) and its values there over ``sum(w)``, in the working complex dtype."""
        spec = np.fft.rfft2(window_2d)
        support = np.abs(spec) > 1e-11 * np.abs(spec).max()  # beyond: float64 rounding
        return np.nonzero(support), (spec[support] / self.window_sum).astype(self.plan.complex_dtype)

    def _buffer(self, name: str, shape, dtype) -> np.ndarray:
        """A scratch array of ``shape`` kept between batches (the last batch may be smaller)."""
        buf = self._buffers.get(name)
        size = int(np.prod(shape))
        if buf is None or buf.size < size or buf.dtype != dtype:
            buf = self._buffers[name] = np.empty(size, dtype=dtype)
        return buf[:size].reshape(shape)

    def __call__(self, ref: np.ndarray, mov: np.ndarray):
        plan = self.plan
        ref = ref.astype(plan.dtype, copy=False)  # a no-op for float32 chips
        mov = mov.astype(plan.dtype, copy=False)
        # the reference reversed, y(t) = x(n - 1 - t): its spectrum is conj(F) exp(2 pi i k / n) per
        # axis, so M conj(F) costs no conjugation and the surface of M Y peaks at the shift minus
        # one pixel per axis (REVERSED_ORIGIN_PX, added back by coarse_peak and refine)
        spec_ref = self.spectrum(ref, reverse=True)
        if self.coarse is not None:
            centre, second, first_q_mean = self.half_resolution_estimate(spec_ref, mov)
        else:
            cross, q_mean, q_var = self.cross_power(spec_ref, self.spectrum(mov), variance=plan.follow == 0)
            centre, second = self.coarse_peak(cross, keep=plan.follow == 0)
            first_q_mean = q_mean
        for k in range(plan.follow):
            last = k == plan.follow - 1
            cross, q_mean, q_var = self.cross_power(spec_ref, self.spectrum(mov, following_windows(plan, centre)),
                                                    variance=last)
            if not last:
                centre, _ = self.refine(cross, centre, plan.stages[:1], max_iterations=1)
        centre, peak = self.refine(cross, centre, plan.stages)
        return centre, peak, q_mean, q_var, second, first_q_mean

    def half_resolution_estimate(self, spec_ref, mov):
        """First pass at half resolution (:mod:`gcpmatch.phase` docstring, step 3).

        The reference's low-frequency quarter (``|k1| < H / 4``, ``k2 <= W / 4``: its spectrum
        low-passed and decimated by 2, already computed for the last pass) against the moving
        windows binned 2 x 2 and apodized at half resolution; integer peak, secondary peak and one
        Newton step on that (H/2, W/2) surface.

        Parameters
        ----------
        spec_ref : ndarray of complex, shape (B, H, W // 2 + 1)
            The reversed reference's half spectrum (:meth:`spectrum` with ``reverse=True``).
        mov : ndarray, shape (B, H, W)
            Moving windows in the plan's precision.

        Returns
        -------
        centre : ndarray of float64, shape (B, 2)
            (row, col) shift estimate at full resolution, px (about 0.06 px rms from the
            refined one on the benchmark's textures).
        second : ndarray of float64, shape (B,)
            Secondary maximum of the half-resolution surface.
        q_mean : ndarray of float64, shape (B,)
            Ideal peak height of that surface (``sum|Q| / (H W / 4)``).
        """
        coarse = self.coarse
        quarter = spec_ref[:, self.quarter_rows, :self.quarter_cols]  # a copy
        quarter *= self.quarter_ramp
        cross, q_mean, _ = coarse.cross_power(quarter, coarse.spectrum(bin_2x2(mov)), variance=False)
        centre, second = coarse.coarse_peak(cross, keep=True)
        centre, _ = coarse.refine(cross, centre, (), max_iterations=1)
        return 2.0 * centre + self.plan.coarse_offset_px, second, q_mean

    def spectrum(self, windows, window=None, *, reverse: bool = False):
        """Half spectrum (B, H, Wh) of the apodized, mean-removed windows.

        With the plan's fixed window the product ``w x`` is transformed and the weighted mean
        removed afterwards: ``rfft2(w (x - m)) = rfft2(w x) - m rfft2(w)`` with
        ``m = sum(w x) / sum(w)``, the DC bin of ``rfft2(w x)`` over ``sum(w)``; ``rfft2(w)``
        is non-negligible on a few bins only (6 for a Hann window). So apodization and the mean
        cost one multiplication.

        Parameters
        ----------
        windows : ndarray, shape (B, H, W)
            Windows in the plan's working precision, pixels indexed (row, col).
        window : None or (row, col) profiles of shapes (B, H) and (B, W)
            None: the plan's fixed apodization; else the following windows of each pair.
        reverse : bool
            With the fixed apodization only: transform the windows reversed along both axes,
            ``x(H - 1 - r, W - 1 - c)``, whose spectrum is the conjugate of the windows' times
            ``exp(2 pi i (k1 / H + k2 / W))``.

        Returns
        -------
        ndarray of complex, shape (B, H, W // 2 + 1)
            ``rfft2`` of ``window * (windows - weighted mean)`` (reversed if ``reverse``).
        """
        buf = self._buffer("apodized", windows.shape, self.plan.dtype)
        if window is None:
            if reverse:
                np.multiply(windows[:, ::-1, ::-1], self.window_2d_reversed, out=buf)
                (rows, cols), window_spectrum = self.reversed_bins, self.reversed_spectrum
            else:
                np.multiply(windows, self.window_2d, out=buf)
                (rows, cols), window_spectrum = self.window_bins, self.window_spectrum
            spec = scipy.fft.rfft2(buf, workers=self.workers, overwrite_x=True)
            mean_sum = spec[:, 0, 0].real.copy()  # sum(w x) = sum(w) m
            spec[:, rows, cols] -= mean_sum[:, None] * window_spectrum
            return spec
        row, col = window
        # sum_ij row_i col_j x_ij as two matrix products, without forming the 2-D window
        weighted = np.matmul(row[:, None, :], np.matmul(windows, col[:, :, None]))[:, 0, 0]
        mean = (weighted / (row.sum(axis=1) * col.sum(axis=1))).astype(self.plan.dtype)
        np.subtract(windows, mean[:, None, None], out=buf)
        buf *= row[:, :, None]
        buf *= col[:, None, :]
        return scipy.fft.rfft2(buf, workers=self.workers, overwrite_x=True)

    def cross_power(self, spec_ref_conj, spec_mov, *, variance: bool = True):
        """Weighted normalized cross-power ``Q`` (B, H, Wh), ``sum|Q|/(HW)``, ``sum|Q|^2/(HW)^2``.

        ``spec_mov`` is overwritten.

        Parameters
        ----------
        spec_ref_conj : ndarray of complex, shape (B, H, W // 2 + 1)
            Conjugated half spectrum of the reference windows, possibly times a phase ramp (the
            reversed reference of ``__call__``: the surface is then translated).
        spec_mov : ndarray of complex, shape (B, H, W // 2 + 1)
            Half spectrum of the moving windows.
        variance : bool
            Compute ``q_var`` (else it is None: only the last pass's is used).

        Returns
        -------
        cross : ndarray of complex, shape (B, H, W // 2 + 1)
            The weighted normalized cross-power ``Q``.
        q_mean : ndarray of float64, shape (B,)
            ``sum|Q| / (H W)`` over the full spectrum: the ideal height of the surface peak.
        q_var : ndarray of float64, shape (B,), or None
            ``sum|Q|^2 / (H W)^2``: the variance of the correlation surface.
        """
        plan = self.plan
        n, height, half = spec_mov.shape
        cross = spec_mov
        cross *= spec_ref_conj  # M conj(F): the surface peaks at +shift (minus the ramp's translation)
        factor = np.abs(cross, out=self._buffer("factor", cross.shape, plan.dtype))
        flat = factor.reshape(n, -1)
        signal = flat @ self.weight_flat  # sum w |X|: 0 only for a flat pair
        floor = plan.eps * (flat @ self.ones_flat) + np.finfo(plan.dtype).tiny  # eps mean|X|: a BLAS sum
        factor += floor[:, None, None]
        np.divide(plan.weight, factor, out=factor)  # g = w / (|X| + floor)
        cross *= factor
        # |Q| = w |X| / (|X| + floor) = w - floor g: no pass over |X| again
        n_px = height * plan.shape[1]
        with np.errstate(over="ignore", invalid="ignore"):  # g overflows only for flat pairs (floor = tiny)
            q_mean = np.where(signal > 0, (self.sum_mult_weight - floor * self._mult_sum(factor)) / n_px, 0.0)
        q_var = None
        if variance:
            factor *= floor[:, None, None]
            np.subtract(plan.weight, factor, out=factor)
            q_var = self._mult_sum(np.square(factor, out=factor)) / n_px**2
        return cross, q_mean, q_var

    def _mult_sum(self, values: np.ndarray) -> np.ndarray:
        """``sum_k m(k2) values(k)`` per pair (B,) in float64, from (B, H, Wh) half-spectrum
        values: float32 sums of one row each, then float64 over the rows."""
        n, height, half = values.shape
        return (values.reshape(-1, half) @ self.plan.multiplicity).reshape(n, height).sum(axis=1, dtype=np.float64)

    def coarse_peak(self, cross, *, keep: bool = True):
        """Peak of the integer-grid surface with a 3-point parabolic offset per axis (B, 2),
        as signed shifts, and the secondary maximum outside the exclusion box (B,).

        Parameters
        ----------
        cross : ndarray of complex, shape (B, H, W // 2 + 1)
            Cross-power spectrum with the reversed reference (its surface peaks at the shift
            minus ``REVERSED_ORIGIN_PX`` per axis).
        keep : bool
            False: ``cross`` may be overwritten (by the inverse FFT).

        Returns
        -------
        centre : ndarray of float64, shape (B, 2)
            Signed (row, col) shift of the moving window, pixels, in [-H/2, H/2) x [-W/2, W/2).
        second : ndarray of float64, shape (B,)
            Maximum of the integer-grid surface outside the exclusion box around the peak.
        """
        height, width = self.plan.shape
        n = cross.shape[0]
        surface = scipy.fft.irfft2(cross, s=(height, width), workers=self.workers, overwrite_x=not keep)
        flat = surface.reshape(n, -1)
        peak = np.argmax(flat, axis=1)
        # the peak and its 4 periodic neighbours (up, left, centre, down, right) in one gather
        values = np.take_along_axis(flat, self.neighbours[peak], axis=1).astype(float)
        offset = parabola_vertex(values[:, :2], values[:, 2:3], values[:, 3:])  # (B, 2): row, col
        # blank the periodic exclusion box around the peak, then take the maximum
        peak_row, peak_col = np.divmod(peak, width)
        span = np.arange(-self.plan.exclusion_px, self.plan.exclusion_px + 1)
        rows = (peak_row[:, None] + span) % height
        cols = (peak_col[:, None] + span) % width
        surface[np.arange(n)[:, None, None], rows[:, :, None], cols[:, None, :]] = -np.inf
        second = flat.max(axis=1).astype(float)
        return self.grid_shift[peak] + offset, second

    def refine(self, cross, centre, stages, *, max_iterations: int = NEWTON_MAX_ITERATIONS):
        """Sub-pixel refinement around ``centre`` (B, 2): new centre and peak value.

        Newton steps on the continuous surface (:func:`gcpmatch.phase_newton.newton_refine`)
        when ``stages`` is empty, else the matrix-multiply DFT on the stages' grids.

        Parameters
        ----------
        cross : ndarray of complex, shape (B, H, W // 2 + 1)
            Cross-power spectrum with the reversed reference (as in :meth:`coarse_peak`).
        centre : ndarray of float64, shape (B, 2)
            Current (row, col) shift estimate, pixels.
        stages : sequence of stage plans
            Upsampling stages (DFT kernels along rows and columns, grid offsets in pixels);
            empty for the Newton refinement.
        max_iterations : int
            Newton steps at most.

        Returns
        -------
        centre : ndarray of float64, shape (B, 2)
            Refined (row, col) shift, pixels.
        peak : ndarray, shape (B,)
            Surface maximum at the refined shift, normalized by ``H W``.
        """
        plan = self.plan
        height, width = plan.shape
        centre = centre - REVERSED_ORIGIN_PX  # position on the surface of M Y (__call__)
        if not stages:
            centre, peak = newton_refine(cross, centre, self.surface_grid, max_iterations=max_iterations)
            return centre + REVERSED_ORIGIN_PX, peak
        peak = None
        for stage in stages:
            # per-pair phase ramps exp(2 pi i k c / n), folded into the stage's kernels
            k_row = stage.kernel_row * _unit_phasors(centre[:, :1] * (plan.freq_row / height), plan.complex_dtype)[:, None, :]
            k_col = _unit_phasors(centre[:, 1:] * (plan.freq_col / width), plan.complex_dtype)[:, :, None] * stage.kernel_col
            values = np.matmul(np.matmul(k_row, cross), k_col).real  # (B, m, m)
            offset, peak = grid_peak(values, stage.offsets_px)
            centre = centre + offset
            peak = peak / (height * width)
        return centre + REVERSED_ORIGIN_PX, peak


def bin_2x2(windows: np.ndarray) -> np.ndarray:
    """Sums of 2 x 2 pixel blocks: (B, H, W) -> (B, H // 2, W // 2), same dtype.

    Bin ``(i, j)`` covers pixels ``2i, 2i + 1`` x ``2j, 2j + 1``: its centre lies at full-resolution
    position ``(2i + 0.5, 2j + 0.5)`` (see ``HALF_PASS_OFFSET_PX``). A sum, not a mean: the
    normalized cross-power ignores the gain.
    """
    rows = windows[:, 0::2] + windows[:, 1::2]
    return rows[:, :, 0::2] + rows[:, :, 1::2]


def _window_2d_float64(plan: PhasePlan) -> np.ndarray:
    """The plan's fixed apodization as an (H, W) float64 array, profiles evaluated in float64
    (their float32 rounding would spread a Hann window's 6-bin spectrum over every bin)."""
    if plan.window_name is None:
        return np.asarray(plan.apodization, dtype=np.float64)
    height, width = plan.shape
    return np.outer(window_profile(plan.window_name, (np.arange(height) + 0.5) / height, plan.tukey_alpha),
                    window_profile(plan.window_name, (np.arange(width) + 0.5) / width, plan.tukey_alpha))


def _unit_phasors(turns: np.ndarray, dtype) -> np.ndarray:
    """``exp(2 pi i turns)`` in ``dtype`` (complex64 or complex128), phases reduced to one turn first."""
    phase = (2.0 * np.pi) * (turns - np.round(turns))
    out = np.empty(phase.shape, dtype=dtype)
    out.real = np.cos(phase)
    out.imag = np.sin(phase)
    return out


def _grid_tables(shape: tuple[int, int]):
    """Per flat index of an (H, W) surface of the reversed reference (``NumpyKernel.__call__``):
    the flat indices of the point and its periodic neighbours, (H W, 5) in the order up, left,
    centre, down, right; and the signed (row, col) shift it stands for, (H W, 2) float64, in
    ``[-H/2, H/2) x [-W/2, W/2)`` (its index plus ``REVERSED_ORIGIN_PX``, wrapped)."""
    height, width = shape
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(height), np.arange(width), indexing="ij"))
    steps = [(-1, 0), (0, -1), (0, 0), (1, 0), (0, 1)]
    neighbours = np.stack([(rows + dr) % height * width + (cols + dc) % width for dr, dc in steps], axis=1)
    shift = np.stack([_signed((rows + REVERSED_ORIGIN_PX) % height, height),
                      _signed((cols + REVERSED_ORIGIN_PX) % width, width)], axis=1).astype(float)
    return neighbours, shift


def _signed(index: np.ndarray, size: int) -> np.ndarray:
    """Periodic index in [0, size) -> signed shift in [-size/2, size/2)."""
    return np.where(index >= (size + 1) // 2, index - size, index)
