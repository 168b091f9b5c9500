"""Torch backend of :mod:`gcpmatch.phase`: the same algorithm on ``torch.fft`` and ``torch.matmul``.

Imported lazily by :func:`gcpmatch.phase.phase_correlate` when ``backend="torch"`` or ``"gpu"``
is asked for; torch is an optional dependency (extra ``gpu``). Every constant (windows,
spectral weights, DFT kernels) comes from the :class:`gcpmatch.phase_plan.PhasePlan`, so
both backends share one definition of the algorithm; this module only translates the batch
operations (see the numpy ``NumpyKernel`` for the equations). Results match the CPU path to
well under 0.01 px (``tests/test_phase.py``).
"""

from __future__ import annotations

import math

import numpy as np

from gcpmatch.phase_newton import MAX_STEP_PX, NEWTON_MAX_ITERATIONS, NEWTON_TOLERANCE_PX
from sensor_models.errors import InputError

try:
    import torch
except ImportError as exc:  # pragma: no cover - depends on the environment
    raise InputError(
        f"backend='torch' needs the optional dependency torch ({exc}); install the 'gpu' extra or use backend='cpu'",
        field="backend",
    ) from exc


class TorchKernel:
    """Batch kernel on torch; same call and outputs as ``gcpmatch.phase_numpy.NumpyKernel``.

    Parameters
    ----------
    plan : gcpmatch.phase_plan.PhasePlan
    device : str
        Torch device ("cpu", "cuda", "cuda:1", ...).
    """

    def __init__(self, plan, *, device: str = "cpu"):
        try:
            self.device = torch.device(device)
        except (RuntimeError, TypeError) as exc:
            raise InputError(f"invalid torch device {device!r}: {exc}", field="device") from exc
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise InputError(f"device {device!r} asked for but torch finds no CUDA GPU; use device='cpu'", field="device")
        self.plan = plan
        self.real = torch.float32 if plan.dtype == np.float32 else torch.float64
        self.complex = torch.complex64 if plan.dtype == np.float32 else torch.complex128
        put = self._tensor
        if isinstance(plan.apodization, np.ndarray):
            self.apodization = put(plan.apodization)
        else:
            self.apodization = tuple(put(p) for p in plan.apodization)
        self.weight = put(plan.weight)
        self.multiplicity = put(plan.multiplicity)
        self.freq_row = torch.as_tensor(plan.freq_row, dtype=torch.float64, device=self.device)
        self.freq_col = torch.as_tensor(plan.freq_col, dtype=torch.float64, device=self.device)
        self.stages = [(put(s.kernel_row), put(s.kernel_col), s.offsets_px) for s in plan.stages]
        self.tiny = float(np.finfo(plan.dtype).tiny)
        self.coarse = None if plan.coarse is None else TorchKernel(plan.coarse, device=device)
        if self.coarse is not None:  # the reference's low-frequency quarter: |k1| < H/4, k2 <= W/4
            height, width = plan.shape
            self.quarter_rows = torch.as_tensor(np.r_[0:height // 4, height - height // 4:height], device=self.device)
            self.quarter_cols = width // 4 + 1

    def _tensor(self, array: np.ndarray):
        return torch.as_tensor(np.ascontiguousarray(array), device=self.device)

    @torch.inference_mode()
    def __call__(self, ref: np.ndarray, mov: np.ndarray):
        plan = self.plan
        ref_t = self._tensor(ref.astype(plan.dtype, copy=False))
        mov_t = self._tensor(mov.astype(plan.dtype, copy=False))
        spec_ref_conj = torch.conj(self.spectrum(ref_t, self.apodization))
        if self.coarse is not None:
            centre, second, first_q_mean = self.half_resolution_estimate(spec_ref_conj, mov_t)
        else:
            cross, q_mean, q_var = self.cross_power(spec_ref_conj, self.spectrum(mov_t, self.apodization))
            centre, second = self.coarse_peak(cross)
            first_q_mean = q_mean
        for k in range(plan.follow):
            win_mov = self.following_windows(centre)
            cross, q_mean, q_var = self.cross_power(spec_ref_conj, self.spectrum(mov_t, win_mov))
            if k < plan.follow - 1:
                centre, _ = self.refine(cross, centre, self.stages[:1], max_iterations=1)
        centre, peak = self.refine(cross, centre, self.stages)
        out = (centre, peak, q_mean, q_var, second, first_q_mean)
        return tuple(t.detach().to("cpu", torch.float64).numpy() for t in out)

    # ---------------------------------------------------------------- steps

    def half_resolution_estimate(self, spec_ref_conj, mov):
        """First pass at half resolution, as :meth:`gcpmatch.phase_numpy.NumpyKernel.half_resolution_estimate`.

        The doubled estimate is the shift minus ``plan.coarse_offset_px`` per axis (the 2 x 2 bins'
        half-pixel offset).

        Parameters
        ----------
        spec_ref_conj : tensor of complex, shape (B, H, W // 2 + 1)
            Conjugated half spectrum of the reference windows.
        mov : tensor, shape (B, H, W)
            Moving windows.

        Returns
        -------
        centre : tensor of float64, shape (B, 2)
            (row, col) shift estimate at full resolution, px.
        second, q_mean : tensor of float64, shape (B,)
            Secondary maximum and ideal peak height of the half-resolution surface.
        """
        coarse = self.coarse
        quarter = spec_ref_conj[:, self.quarter_rows, :self.quarter_cols]
        rows = mov[:, 0::2] + mov[:, 1::2]
        binned = rows[:, :, 0::2] + rows[:, :, 1::2]
        cross, q_mean, _ = coarse.cross_power(quarter, coarse.spectrum(binned, coarse.apodization))
        centre, second = coarse.coarse_peak(cross)
        centre, _ = coarse.refine(cross, centre, (), max_iterations=1)
        return 2.0 * centre + self.plan.coarse_offset_px, second, q_mean

    def spectrum(self, windows, window):
        """Half spectrum (B, H, Wh) of the apodized windows minus their weighted mean.

        Parameters
        ----------
        windows : tensor, shape (B, H, W)
            Windows in the plan's working precision, pixels indexed (row, col).
        window : tensor, shape (H, W), or (row, col) profiles of shapes (H,) and (W,) or (B, H) and (B, W)
            Apodization weights (the plan's, or the following windows of each pair).

        Returns
        -------
        tensor of complex, shape (B, H, W // 2 + 1)
            ``rfft2`` of ``window * (windows - weighted mean)``.
        """
        if isinstance(window, tuple):
            row, col = window
            if row.ndim == 1:
                row, col = row.expand(windows.shape[0], -1), col.expand(windows.shape[0], -1)
            weighted = torch.einsum("bij,bi,bj->b", windows, row, col)
            mean = weighted / (row.sum(dim=1) * col.sum(dim=1))
            prepared = (windows - mean[:, None, None]) * row[:, :, None] * col[:, None, :]
        else:
            mean = (windows * window).sum(dim=(1, 2)) / window.sum()
            prepared = (windows - mean[:, None, None]) * window
        return torch.fft.rfft2(prepared)

    def cross_power(self, spec_ref_conj, spec_mov):
        """Weighted normalized cross-power, as :meth:`gcpmatch.phase_numpy.NumpyKernel.cross_power`.

        Parameters
        ----------
        spec_ref_conj : tensor of complex, shape (B, H, W // 2 + 1)
            Conjugated half spectrum of the reference windows.
        spec_mov : tensor of complex, shape (B, H, W // 2 + 1)
            Half spectrum of the moving windows.

        Returns
        -------
        cross : tensor of complex, shape (B, H, W // 2 + 1)
            The weighted normalized cross-power ``Q``.
        q_mean : tensor of float64, shape (B,)
            ``sum|Q| / (H W)`` over the full spectrum: the ideal height of the surface peak.
        q_var : tensor of float64, shape (B,)
            ``sum|Q|^2 / (H W)^2``: the variance of the correlation surface.
        """
        height, width = self.plan.shape
        cross = spec_mov * spec_ref_conj
        mag = torch.abs(cross)
        floor = self.plan.eps * mag.mean(dim=(1, 2), keepdim=True) + self.tiny
        factor = self.weight / (mag + floor)
        cross = cross * factor
        mag = mag * factor
        n_px = height * width
        q_mean = (mag @ self.multiplicity).to(torch.float64).sum(dim=1) / n_px
        q_var = ((mag * mag) @ self.multiplicity).to(torch.float64).sum(dim=1) / n_px**2
        return cross, q_mean, q_var

    def coarse_peak(self, cross):
        """Integer-grid peak and secondary maximum, as :meth:`gcpmatch.phase_numpy.NumpyKernel.coarse_peak`.

        Parameters
        ----------
        cross : tensor of complex, shape (B, H, W // 2 + 1)
            Cross-power spectrum.

        Returns
        -------
        centre : tensor of float64, shape (B, 2)
            Signed (row, col) shift of the moving window, pixels, in [-H/2, H/2) x [-W/2, W/2).
        second : tensor of float64, shape (B,)
            Maximum of the integer-grid surface outside the exclusion box around the peak.
        """
        height, width = self.plan.shape
        n = cross.shape[0]
        surface = torch.fft.irfft2(cross, s=(height, width))
        idx = torch.argmax(surface.reshape(n, -1), dim=1)
        peak_row, peak_col = idx // width, idx % width
        pairs = torch.arange(n, device=self.device)
        centre_value = surface[pairs, peak_row, peak_col]
        offset_row = _parabola_vertex(surface[pairs, (peak_row - 1) % height, peak_col], centre_value,
                                      surface[pairs, (peak_row + 1) % height, peak_col])
        offset_col = _parabola_vertex(surface[pairs, peak_row, (peak_col - 1) % width], centre_value,
                                      surface[pairs, peak_row, (peak_col + 1) % width])
        span = torch.arange(-self.plan.exclusion_px, self.plan.exclusion_px + 1, device=self.device)
        rows = (peak_row[:, None] + span) % height
        cols = (peak_col[:, None] + span) % width
        surface[pairs[:, None, None], rows[:, :, None], cols[:, None, :]] = -math.inf
        second = surface.reshape(n, -1).max(dim=1).values.to(torch.float64)
        signed_row = torch.where(peak_row >= (height + 1) // 2, peak_row - height, peak_row)
        signed_col = torch.where(peak_col >= (width + 1) // 2, peak_col - width, peak_col)
        centre = torch.stack([signed_row + offset_row, signed_col + offset_col], dim=1)
        return centre, second

    def refine(self, cross, centre, stages, *, max_iterations: int = NEWTON_MAX_ITERATIONS):
        """Sub-pixel refinement around ``centre``, as :meth:`gcpmatch.phase_numpy.NumpyKernel.refine`:
        Newton steps when ``stages`` is empty, else the DFT grids.

        Parameters
        ----------
        cross : tensor of complex, shape (B, H, W // 2 + 1)
            Cross-power spectrum.
        centre : tensor of float64, shape (B, 2)
            Current (row, col) shift estimate, pixels.
        stages : sequence of stage plans
            Upsampling stages (DFT kernels along rows and columns, grid offsets in pixels); empty
            for the Newton refinement.
        max_iterations : int
            Newton steps at most.

        Returns
        -------
        centre : tensor of float64, shape (B, 2)
            Refined (row, col) shift, pixels.
        peak : tensor, shape (B,)
            Surface maximum at the refined shift, normalized by ``H W``.
        """
        height, width = self.plan.shape
        if not stages:
            return self.newton(cross, centre, max_iterations)
        peak = None
        for kernel_row, kernel_col, offsets_px in stages:
            ramp_row = _unit_phasor((2.0 * math.pi / height) * centre[:, :1] * self.freq_row, self.real)
            ramp_col = _unit_phasor((2.0 * math.pi / width) * centre[:, 1:] * self.freq_col, self.real)
            k_row = kernel_row[None] * ramp_row[:, None, :]
            k_col = ramp_col[:, :, None] * kernel_col[None]
            values = torch.matmul(torch.matmul(k_row, cross), k_col).real
            offset, peak = _grid_peak(values, offsets_px)
            centre = centre + offset
            peak = peak / (height * width)
        return centre, peak

    def newton(self, cross, centre, max_iterations: int):
        """Newton steps on the continuous surface, as :func:`gcpmatch.phase_newton.newton_refine`.

        Parameters
        ----------
        cross : tensor of complex, shape (B, H, W // 2 + 1)
            Cross-power spectrum.
        centre : tensor of float64, shape (B, 2)
            Start (row, col), pixels.
        max_iterations : int
            Steps at most (fewer when every step of the batch is below the tolerance).

        Returns
        -------
        centre : tensor of float64, shape (B, 2)
            Position of the surface maximum, pixels.
        peak : tensor of float64, shape (B,)
            Surface value there, normalized by ``H W``.
        """
        height, width = self.plan.shape
        k1 = self.freq_row.to(self.real)
        k2 = self.freq_col.to(self.real)
        value = torch.zeros(centre.shape[0], dtype=torch.float64, device=self.device)
        active = torch.ones(centre.shape[0], dtype=torch.bool, device=self.device)
        for _ in range(max_iterations):
            a = _unit_phasor((2.0 * math.pi / height) * centre[:, :1] * self.freq_row, self.real)  # (B, H)
            b = _unit_phasor((2.0 * math.pi / width) * centre[:, 1:] * self.freq_col, self.real) * self.multiplicity
            rows = torch.stack([a, a * k1, a * (k1 * k1)], dim=1)  # (B, 3, H)
            cols = torch.stack([b, b * k2, b * (k2 * k2)], dim=2)  # (B, Wh, 3)
            sums = torch.matmul(torch.matmul(rows, cross), cols).to(torch.complex128)  # S_ij
            step, new_value = _newton_solve(sums.real, sums.imag, height, width)
            centre = torch.where(active[:, None], centre + step, centre)
            value = torch.where(active, new_value, value)
            active &= step.abs().amax(dim=1) >= NEWTON_TOLERANCE_PX
            if not bool(active.any()):
                break
        return centre, value / (height * width)

    def following_windows(self, shift_px):
        """Torch version of :func:`gcpmatch.phase_plan.following_windows`.

        Parameters
        ----------
        shift_px : tensor of float64, shape (B, 2)
            Current (row, col) shift of each pair, pixels.

        Returns
        -------
        row, col : tensor, shapes (B, H) and (B, W)
            Window profiles centred on the shifted content, in the working precision.
        """
        profiles = []
        for axis, n in enumerate(self.plan.shape):
            s = torch.clamp(shift_px[:, axis], -n / 2.0, n / 2.0)[:, None]
            u = (torch.arange(n, device=self.device, dtype=torch.float64) + 0.5 - s) / n
            profiles.append(_window_profile(self.plan.window_name, u, self.plan.tukey_alpha).to(self.real))
        return profiles[0], profiles[1]


def _newton_solve(s_re, s_im, height: int, width: int):
    """Torch version of ``gcpmatch.phase_newton._solve``: step (B, 2) and model value (B,)."""
    ur, uc = 2.0 * math.pi / height, 2.0 * math.pi / width
    grad_r, grad_c = -ur * s_im[:, 1, 0], -uc * s_im[:, 0, 1]
    h_rr, h_cc, h_rc = -ur * ur * s_re[:, 2, 0], -uc * uc * s_re[:, 0, 2], -ur * uc * s_re[:, 1, 1]
    det = h_rr * h_cc - h_rc * h_rc
    ok = (h_rr < 0) & (det > 0)
    det = torch.where(ok, det, torch.ones_like(det))
    zero = torch.zeros_like(det)
    step_r = torch.where(ok, (h_rc * grad_c - h_cc * grad_r) / det, zero)
    step_c = torch.where(ok, (h_rc * grad_r - h_rr * grad_c) / det, zero)
    step = torch.clamp(torch.stack([step_r, step_c], dim=1), -MAX_STEP_PX, MAX_STEP_PX)
    value = s_re[:, 0, 0] + 0.5 * (grad_r * step[:, 0] + grad_c * step[:, 1])
    return step, value


def _unit_phasor(angle, real_dtype):
    """``exp(i angle)`` from a float64 angle, in the working complex precision."""
    return torch.polar(torch.ones_like(angle, dtype=real_dtype), angle.to(real_dtype))


def _window_profile(name: str, u, tukey_alpha: float):
    inside = (u >= 0.0) & (u <= 1.0)
    if name == "hann":
        out = torch.sin(math.pi * u) ** 2
    elif name == "tukey" and tukey_alpha > 0:
        edge = torch.minimum(u, 1.0 - u)
        out = torch.sin(0.5 * math.pi * torch.clamp(edge / (tukey_alpha / 2.0), 0.0, 1.0)) ** 2
    else:
        out = torch.ones_like(u)
    return torch.where(inside, out, torch.zeros_like(out))


def _parabola_vertex(left, centre, right):
    left, centre, right = (t.to(torch.float64) for t in (left, centre, right))
    curvature = left - 2.0 * centre + right
    safe = torch.where(curvature < 0, curvature, torch.full_like(curvature, -1.0))
    offset = torch.where(curvature < 0, 0.5 * (left - right) / safe, torch.zeros_like(curvature))
    return torch.clamp(offset, -0.5, 0.5)


def _grid_peak(values, offsets_px: np.ndarray):
    """Torch version of :func:`gcpmatch.phase_peak.grid_peak`."""
    n, m, _ = values.shape
    device = values.device
    idx = torch.argmax(values.reshape(n, -1), dim=1)
    a, b = idx // m, idx % m
    pairs = torch.arange(n, device=device)
    best = values[pairs, a, b].to(torch.float64)
    a = torch.clamp(a, 1, m - 2)
    b = torch.clamp(b, 1, m - 2)
    step = torch.arange(-1, 2, device=device)
    patch = values[pairs[:, None, None], (a[:, None] + step)[:, :, None], (b[:, None] + step)[:, None, :]].to(torch.float64)
    d_row, d_col = _quadratic_vertex(patch)
    offsets = torch.as_tensor(offsets_px, dtype=torch.float64, device=device)
    spacing = float(offsets_px[1] - offsets_px[0])
    offset = torch.stack([offsets[a] + d_row * spacing, offsets[b] + d_col * spacing], dim=1)
    return offset, best


def _quadratic_vertex(patch):
    """Torch version of :func:`gcpmatch.phase_peak.quadratic_vertex`."""
    x = torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64, device=patch.device)
    c1 = torch.einsum("bij,i->b", patch, x) / 6.0
    c2 = torch.einsum("bij,j->b", patch, x) / 6.0
    c3 = torch.einsum("bij,i->b", patch, x**2 - 2.0 / 3.0) / 2.0
    c4 = torch.einsum("bij,j->b", patch, x**2 - 2.0 / 3.0) / 2.0
    c5 = torch.einsum("bij,i,j->b", patch, x, x) / 4.0
    det = 4.0 * c3 * c4 - c5**2
    ok = (c3 < 0) & (det > 0)
    det = torch.where(ok, det, torch.ones_like(det))
    zero = torch.zeros_like(det)
    d_row = torch.where(ok, (c5 * c2 - 2.0 * c4 * c1) / det, zero)
    d_col = torch.where(ok, (c5 * c1 - 2.0 * c3 * c2) / det, zero)
    return torch.clamp(d_row, -1.0, 1.0), torch.clamp(d_col, -1.0, 1.0)
