"""Windowed, batched, sub-pixel phase correlation: the fine matching kernel.

Given ``N`` pairs of equally sized windows (a reference chip resampled into scene geometry and
the scene window at the same place), :func:`phase_correlate` estimates for every pair the
translation of the moving content relative to the reference to a fraction of a pixel, with a
quality score, a peak ratio and a validity flag.

Sign convention
---------------
The returned shift is the displacement of the moving content relative to the reference::

    moving(r, c) ~ reference(r - shift_row_px, c - shift_col_px)

so a feature at position ``p`` in the reference window appears at ``p + shift`` in the moving
window (the opposite sign of ``skimage.registration.phase_cross_correlation``, which returns the
shift that registers the moving image onto the reference).

Algorithm (vectorized over a batch of pairs)
--------------------------------------------
1. Apodization: each window's weighted mean is removed (so the DC term carries nothing) and a
   separable Hann or Tukey window, evaluated at the pixel centres, is applied. Dividing by the
   standard deviation is not needed: the normalization in step 2 makes the estimate invariant
   to any positive gain, and its floor is relative to each pair's spectral level.
2. Normalized cross-power spectrum (Kuglin & Hines 1975), with half spectra from
   ``scipy.fft.rfft2``::

       X(k) = M(k) conj(F(k)),    Q(k) = w(k) X(k) / (|X(k)| + eps mean_k |X|)

   ``F``, ``M``: spectra of the prepared reference and moving windows. ``eps -> 0`` is pure
   phase correlation; the default ``eps = 0.5`` whitens the strong frequencies and weights
   those far below the mean level by their magnitude (a Wiener-like floor): the phase of bins
   without signal is noise, and pure phase correlation gives them full weight. Measured on
   64 x 64 px textures (``bench/bench_phase.py``, ablation), ``eps = 0.5`` divides the RMS
   error by 3.4 at SNR 20 and by 4.5 at SNR 50 compared with ``eps = 1e-6``, and by 10 on
   cubic-spline-resampled windows without noise (``tests/test_phase.py``).
   ``w(k)`` is zero at the DC term and at the Nyquist row/column (the only bins whose
   continuous interpolation is ambiguous), optionally times a Gaussian low-pass
   ``exp(-|f|^2 / (2 lowpass^2))``, ``f`` in cycles/px. Measured: with pure phase correlation
   a low-pass (0.15 cycles/px) divides the RMS error by 3 at SNR 20-50; with the default floor
   it gains at most 12 % at SNR 20 and loses up to 2x without noise, so it is off by default.
3. Coarse peak: argmax of the phase-correlation surface ``q = IDFT(Q)`` on the integer grid
   (periodic: shifts lie in ``[-H/2, H/2) x [-W/2, W/2)``), plus a 3-point parabolic offset
   per axis; the secondary peak (for ``peak_ratio``) is the surface maximum outside a periodic
   Chebyshev box of half-size ``exclusion_px`` around it. By default (``first_pass="half"``,
   windows whose sides are multiples of 4 and at least ``HALF_FIRST_PASS_MIN_PX``, with a
   following pass) this first pass runs at half resolution, because the following pass
   recomputes ``Q`` at full resolution anyway and only needs a start: the reference's spectrum
   (computed once for the last pass) is cut to its low-frequency quarter ``|k1| < H/4,
   k2 <= W/4`` (the reference low-passed and decimated by 2), the moving window is binned
   2 x 2 and apodized at half resolution, and steps 2-3 plus one Newton step (step 5) run on
   the (H/2, W/2) surface; the doubled estimate plus ``HALF_PASS_OFFSET_PX`` (the bins' centres
   sit half a pixel off the decimation's samples) starts the following pass (0.06 px rms from
   the final estimate on the benchmark's pairs). This replaces a full-resolution cross-power
   and inverse FFT by quarter-size ones (``bench/bench_phase.py --floor``; docs/speed.md);
   the peak ratio then comes from the half-resolution surface, whose default threshold is
   ``MIN_PEAK_RATIO["half"]`` (set at the full surface's false-acceptance rate).
4. Window following (``follow`` passes, default 1): a stationary window pulls the estimate
   toward zero shift (the moving content slides under the taper: 0.03 px RMS for +/- 8 px
   shifts in 64 px windows). A following pass re-apodizes the moving window with the taper
   translated by the current estimate (:func:`following_windows`), so both windows weight the
   same ground content, and recomputes ``Q`` (the reference spectrum is reused).
5. Sub-pixel refinement of the last ``Q``. Default (``upsample=None``): Newton steps on the
   continuous surface ``q(x, y)`` (its value, gradient and Hessian are separable sums over
   ``Q`` with powers of the frequencies: :mod:`gcpmatch.phase_newton`) from the coarse peak;
   a pair stops after a step below 0.01 px (two steps from the parabolic start; the maximum
   is then reached to about 1e-5 px). With an integer ``upsample = U``: the
   matrix-multiply DFT of Guizar-Sicairos,
   Thurman & Fienup, "Efficient subpixel image registration algorithms", Opt. Lett.
   33(2):156-158 (2008), eq. 3 and the text after it: ``q`` is evaluated exactly on an
   upsampled grid in a 1.5 x 1.5 px neighbourhood of the current estimate ``c``,
   ``q(c + d_a, c + d_b) = Re(K_r Q K_c) / (H W)`` with per-pair kernels
   ``K_r[a, k1] = exp(2 pi i k1 (c_r + d_a) / H)`` and
   ``K_c[k2, b] = m(k2) exp(2 pi i k2 (c_c + d_b) / W)`` (``m`` = 1 or 2: the Hermitian
   multiplicity of a half-spectrum column); one stacked matrix product for the whole batch.
   With ``U > 20`` two stages: factor ``u1 = round(sqrt(U))`` over the 1.5 px neighbourhood,
   then factor ``U`` over +/- ``0.3 / u1`` px. Each stage's grid maximum is refined by the
   vertex of a least-squares quadratic on its 3 x 3 neighbourhood, so the result is not
   quantized to ``1/U`` (no pixel-locking: the mean error versus the fractional shift stays
   below 0.001 px) and the two stages agree with the single 1.5 px stage at factor ``U`` to
   5e-5 px, at a twentieth of its cost.
6. Quality: ``score = q(peak) / mean(|Q|)`` (the fraction of the weighted cross-power coherent
   with the shift, 1 for a perfect translation; last pass). ``peak_ratio`` = score / (first
   pass's secondary peak / first pass's ``mean(|Q|)``; the first pass at half resolution by
   default, step 3). For unrelated windows ``q`` has zero
   mean and, by Parseval's theorem, variance ``sigma_q^2 = sum|Q|^2 / (H W)^2``; the default
   ``min_score`` is ``NULL_SIGMA_FACTOR`` times ``sigma_q / mean(|Q|)`` per pair (median
   0.31 for the benchmark's 64 x 64 px textures, 0.59 for 32 px, 0.16 for 128 px).

Precision: float32/complex64 by default (``dtype="float32"``): the estimates agree with float64
to 5e-5 px, at half the memory and two to three times the speed of float64 FFTs.

Rejection codes (``PhaseMatches.reason``, :class:`Reject`; the first failing test in this order):
``FLAT`` (a window without any texture: zero cross-power spectrum), ``NOT_FINITE`` (a non-finite
estimate), ``OUT_OF_RANGE`` (``|shift| > max_shift_px`` on either axis: a peak toward the window
border), ``LOW_SCORE`` (``score < min_score``), ``LOW_PEAK_RATIO``
(``peak_ratio < min_peak_ratio``).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from gcpmatch.phase_newton import NEWTON_MAX_ITERATIONS, newton_refine, surface_grid
from sensor_models.errors import InputError

__all__ = ["FIRST_PASSES", "HALF_FIRST_PASS_MIN_PX", "HALF_PASS_OFFSET_PX", "MIN_PEAK_RATIO", "MIN_WINDOW_PX",
           "NULL_SIGMA_FACTOR", "PhaseMatches", "Reject", "bin_2x2", "following_windows", "make_plan", "phase_correlate"]

#: Smallest window side accepted, in pixels.
MIN_WINDOW_PX = 8

#: Default ``min_score`` in standard deviations of the score of unrelated windows. Measured on
#: 1000 unrelated pairs each of 32, 64 and 128 px (scene versus scene, scene versus white
#: noise): 99.9th percentile 8.6 to 9.5 sigma, maximum 10.8; true pairs at SNR 20 score at
#: least 12.8 (32 px), 23 (64 px) and 44 (128 px) sigma. ``tests/test_phase.py`` checks both
#: sides (with the peak-ratio test, which rejects most of the remaining false peaks).
NULL_SIGMA_FACTOR = 10.0

_WINDOWS = ("hann", "tukey", "none")
_BACKENDS = ("cpu", "numpy", "torch", "gpu")
#: Half-width of a refinement stage after the first, in steps of the previous stage's grid. The
#: quadratic vertex fitted on a 0.1 px grid is within 0.002 px of the true maximum (measured:
#: U = 10 and U = 100 give the same RMS error, 0.0008 px), so 0.3 steps is ample.
_NEXT_STAGE_HALF_STEPS = 0.3
#: The numpy kernel transforms the reference reversed: its correlation surface peaks at the shift
#: minus this many pixels per axis (``NumpyKernel.__call__``).
REVERSED_ORIGIN_PX = 1
#: First passes (``first_pass``): ``"half"`` correlates at half resolution (module docstring,
#: step 3), ``"full"`` on the full-resolution surface.
FIRST_PASSES = ("half", "full")
#: Default ``min_peak_ratio`` per first pass, set at equal false-acceptance of unrelated windows.
#: The half-resolution surface has a quarter of the samples and a lower main peak: on the
#: realistic demo's 920 window pairs of band B2, shuffled six times (5520 unrelated pairs), the
#: ratio reaches 2.0 in 1.39 % of them on the full surface and 1.8 in 1.25 % on the half one
#: (2.0 in 0.76 %); on the matched pairs the half ratio is 0.76 times the full one (median).
MIN_PEAK_RATIO = {"full": 2.0, "half": 1.8}
#: Smallest window side whose first pass runs at half resolution (a 16 x 16 px binned window);
#: smaller windows, sides not divisible by 4, user array windows and ``follow=0`` keep the
#: full-resolution first pass.
HALF_FIRST_PASS_MIN_PX = 32
#: Added to the doubled half-resolution estimate, px per axis: a 2 x 2 bin ``j`` holds the moving
#: content at full-resolution position ``2 j + 0.5`` while the reference's low-frequency quarter
#: samples it at ``2 j``, so the binned content appears 0.5 px early. Measured: the doubled
#: estimate is 0.498 / 0.502 px short on average over 512 benchmark pairs.
HALF_PASS_OFFSET_PX = 0.5
#: Default batch: 256 windows of 64 x 64 px (~20 MB of scratch). Fewer Python calls per pair
#: than 128 (measured, ``first_pass="half"``, 1 thread: 72.0 % of the FFT floor against 66.4 %);
#: the floor itself is fastest at 32 pairs, where this kernel's per-call overhead dominates.
_BATCH_PIXELS = 1 << 20


class Reject(enum.IntEnum):
    """Why a match was rejected (``PhaseMatches.reason``); ``OK`` for accepted matches."""

    OK = 0
    FLAT = 1
    NOT_FINITE = 2
    OUT_OF_RANGE = 3
    LOW_SCORE = 4
    LOW_PEAK_RATIO = 5


@dataclass(frozen=True)
class PhaseMatches:
    """Result of :func:`phase_correlate` for ``N`` window pairs.

    Attributes
    ----------
    shift_row_px, shift_col_px : ndarray, shape (N,), float64
        Displacement of the moving content relative to the reference, in pixels
        (``moving(r, c) ~ reference(r - shift_row_px, c - shift_col_px)``); NaN for flat pairs.
    score : ndarray, shape (N,), float64
        Refined peak height of the phase-correlation surface over its ideal value, in [0, 1];
        higher is better.
    peak_ratio : ndarray, shape (N,), float64
        Main peak over the strongest secondary value outside the exclusion zone, both in units
        of their pass's ideal peak height (``inf`` when the rest of the surface is <= 0, 0 for
        flat pairs).
    valid : ndarray, shape (N,), bool
        Passed every quality test.
    reason : ndarray, shape (N,), int8
        :class:`Reject` code: 0 for valid matches, else the first test that failed.
    """

    shift_row_px: np.ndarray
    shift_col_px: np.ndarray
    score: np.ndarray
    peak_ratio: np.ndarray
    valid: np.ndarray
    reason: np.ndarray

    def __len__(self) -> int:
        return int(self.shift_row_px.shape[0])

    @property
    def shift_px(self) -> np.ndarray:
        """Shifts as one array: ``(row, col)`` in pixels, moving minus reference.

        Returns
        -------
        ndarray of float64, shape (N, 2)
            ``shift_row_px`` and ``shift_col_px`` side by side.
        """
        return np.stack([self.shift_row_px, self.shift_col_px], axis=-1)


@dataclass(frozen=True)
class _Stage:
    """One DFT-upsampling stage: sample offsets and pair-independent kernel factors."""

    factor: int
    offsets_px: np.ndarray  # (n,) float64: offsets of the samples from the stage's centre
    kernel_row: np.ndarray  # (n, H) complex: exp(2 pi i k1 d_a / H)
    kernel_col: np.ndarray  # (Wh, n) complex: m(k2) exp(2 pi i k2 d_b / W)


@dataclass(frozen=True)
class _Plan:
    """Constants of the algorithm for one window shape; the backends read only these."""

    shape: tuple[int, int]
    dtype: np.dtype  # float32 or float64
    window_name: str | None  # "hann", "tukey", "none"; None for a user array
    tukey_alpha: float
    follow: int  # window-following passes after the first
    apodization: np.ndarray | tuple[np.ndarray, np.ndarray]  # (H, W) array or ((H,), (W,)) profiles
    weight: np.ndarray  # (H, Wh) real spectral weight w(k)
    multiplicity: np.ndarray  # (Wh,) 1 or 2: Hermitian multiplicity of half-spectrum columns
    freq_row: np.ndarray  # (H,) float64 signed integer frequencies k1
    freq_col: np.ndarray  # (Wh,) float64 integer frequencies k2 >= 0
    stages: tuple[_Stage, ...]  # DFT-upsampling stages; empty for the Newton refinement
    exclusion_px: int
    eps: float
    coarse: _Plan | None = None  # the half-resolution first pass (step 3); None: full resolution
    coarse_offset_px: float = HALF_PASS_OFFSET_PX  # added to its doubled estimate, px per axis

    @property
    def complex_dtype(self) -> np.dtype:
        return np.dtype(np.complex64 if self.dtype == np.float32 else np.complex128)


def phase_correlate(reference, moving, *, upsample: int | None = None, window: str | np.ndarray | None = "hann",
                    tukey_alpha: float = 0.5, lowpass: float | None = None, eps: float = 0.5, follow: int = 1,
                    min_score: float | None = None, min_peak_ratio: float | None = None, max_shift_px=None,
                    exclusion_px: int | None = None, stage1_upsample: int | None = None, dtype: str = "float32",
                    backend: str = "cpu", device: str | None = None, batch: int | None = None,
                    workers: int | None = None, first_pass: str = "half") -> PhaseMatches:
    """Sub-pixel phase correlation of window pairs, batched (see the module docstring).

    Parameters
    ----------
    reference, moving : array_like, shape (N, H, W) or (H, W)
        Reference and moving windows: real numbers of any dtype, finite, ``H, W >= 8``.
        A single pair may be given as two (H, W) arrays (the result then has N = 1).
    upsample : int or None
        ``None``: Newton refinement on the continuous surface (module docstring, step 5). An
        integer ``U``: refinement on DFT-upsampled grids, the last of spacing ``1/U`` px (the
        quadratic vertex then refines within the grid).
    window : {"hann", "tukey", "none"} or ndarray (H, W)
        Apodization applied to both windows after the weighted mean is removed.
    tukey_alpha : float
        Taper fraction of the Tukey window (0 = box, 1 = Hann).
    lowpass : float or None
        Standard deviation, in cycles/px, of a Gaussian weight on the cross-power spectrum;
        ``None`` for none (its effect is measured in the module docstring).
    eps : float
        Floor of the normalization, relative to the pair's mean cross-power magnitude:
        ``~1e-6`` is pure phase correlation, larger values weight weak bins by magnitude.
    follow : int
        Window-following passes after the first estimate (see :func:`following_windows`);
        0 disables them (required with an array ``window``).
    min_score : float or None
        Reject matches whose ``score`` is lower; ``None``: ``NULL_SIGMA_FACTOR`` standard
        deviations of the score of unrelated windows, per pair.
    min_peak_ratio : float or None
        Reject matches whose ``peak_ratio`` is lower; ``None``: ``MIN_PEAK_RATIO`` of the first
        pass the plan runs (the two surfaces' ratios have different null distributions).
    max_shift_px : float or (float, float) or None
        Largest usable ``|shift|`` per axis (row, col), px; ``None`` = ``(H/4, W/4)``.
    exclusion_px : int or None
        Half-size (Chebyshev, px) of the main lobe excluded when looking for the secondary
        peak; ``None`` = 2, widened to ``ceil(3 sigma_x)`` with a low-pass of spatial
        standard deviation ``sigma_x = 1 / (2 pi lowpass)``.
    stage1_upsample : int or None
        With an integer ``upsample`` only: factor of the first of two refinement stages; ``None`` = ``round(sqrt(U))`` when
        ``U > 20``, else a single stage; 0 or 1 forces the single 1.5 px stage at factor U.
    dtype : {"float32", "float64"}
        Working precision.
    backend : {"cpu", "numpy", "torch", "gpu"}
        ``"cpu"`` (= ``"numpy"``): numpy + scipy.fft; ``"torch"``: the same algorithm in torch
        on ``device`` (default ``"cpu"``); ``"gpu"``: torch on ``device`` (default ``"cuda"``).
    device : str or None
        Torch device (``"cpu"``, ``"cuda"``, ``"cuda:1"``); only with the torch backends.
    batch : int or None
        Pairs processed at once (bounds the memory: about 20 bytes per pixel and pair in
        float32, measured); ``None``: 2**20 px worth of windows (256 pairs of 64 x 64 px).
    workers : int or None
        Threads of ``scipy.fft`` (``None`` or -1: all cores); CPU backend only (torch uses
        ``torch.set_num_threads``).
    first_pass : {"half", "full"}
        Where the first estimate and the peak ratio come from (module docstring, step 3):
        ``"half"`` at half resolution (windows with both sides divisible by 4 and at least
        ``HALF_FIRST_PASS_MIN_PX``, ``follow >= 1`` and a named window; otherwise the full
        resolution), ``"full"`` the full-resolution surface.

    Returns
    -------
    PhaseMatches
        Shifts, score, peak ratio, validity and rejection reason per pair.

    Raises
    ------
    sensor_models.errors.InputError
        Mismatched shapes, windows smaller than 8 px, non-finite values, non-numeric data or
        invalid options.
    """
    ref, mov = _validate_pairs(reference, moving)
    _, height, width = ref.shape
    options = _validate_options(upsample=upsample, min_score=min_score, min_peak_ratio=min_peak_ratio,
                                lowpass=lowpass, exclusion_px=exclusion_px, stage1_upsample=stage1_upsample,
                                follow=follow, eps=eps, dtype=dtype, backend=backend, device=device, batch=batch,
                                tukey_alpha=tukey_alpha, workers=workers, first_pass=first_pass)
    max_shift = _validate_max_shift(max_shift_px, height, width)
    plan = make_plan((height, width), upsample=upsample, window=window, tukey_alpha=tukey_alpha, lowpass=lowpass,
                     eps=eps, follow=follow, exclusion_px=exclusion_px, stage1_upsample=stage1_upsample,
                     dtype=options["dtype"], first_pass=first_pass)
    if min_peak_ratio is None:
        min_peak_ratio = MIN_PEAK_RATIO["half" if plan.coarse is not None else "full"]
    outputs = _run_batches(_make_kernel(plan, options, workers), ref, mov, batch)
    return _assess(*outputs, min_score, min_peak_ratio, max_shift)


def _make_kernel(plan, options: dict, workers):
    """The batch kernel of the validated backend: numpy + scipy.fft, or torch (lazy import)."""
    if options["backend"] == "numpy":
        return NumpyKernel(plan, workers=-1 if workers is None else workers)
    from gcpmatch import _phase_torch  # lazy: torch is an optional dependency

    return _phase_torch.TorchKernel(plan, device=options["device"])


def _run_batches(kernel, ref: np.ndarray, mov: np.ndarray, batch):
    """Run ``kernel`` over the (N, H, W) pairs ``batch`` at a time (None: 2**20 px worth).

    Returns
    -------
    tuple of ndarray
        The kernel's six outputs (shift, peak, quality mean and variance, secondary peak, first
        quality mean), each concatenated over the batches along the first axis (N).
    """
    n_pairs, height, width = ref.shape
    if batch is None:
        batch = max(1, _BATCH_PIXELS // (height * width))
    parts = [kernel(ref[i:i + batch], mov[i:i + batch]) for i in range(0, n_pairs, batch)]
    return tuple(np.concatenate(p) for p in zip(*parts))


# --------------------------------------------------------------------------- plan


def make_plan(
    shape: tuple[int, int],
    *,
    upsample: int | None = None,
    window: str | np.ndarray | None = "hann",
    tukey_alpha: float = 0.5,
    lowpass: float | None = None,
    eps: float = 0.5,
    follow: int = 1,
    exclusion_px: int | None = None,
    stage1_upsample: int | None = None,
    dtype=np.float32,
    first_pass: str = "half",
) -> _Plan:
    """Constants of the algorithm for windows of ``shape`` = (H, W) (see :func:`phase_correlate`).

    Parameters
    ----------
    shape : (int, int)
        Window size ``(H, W)``, pixels (rows, columns).
    upsample, window, tukey_alpha, lowpass, eps, follow, exclusion_px, stage1_upsample, first_pass
        As in :func:`phase_correlate` (an array ``window`` has shape (H, W)).
    dtype : numpy dtype
        Working precision, float32 or float64.

    Returns
    -------
    _Plan
        Apodization, spectral weights, bin multiplicities, refinement stages (none for the
        Newton refinement, ``upsample=None``) and exclusion box.
    """
    height, width = shape
    dtype = np.dtype(dtype)
    if follow and isinstance(window, np.ndarray):
        raise InputError("an array window cannot follow the shift; pass follow=0 with it", field="follow")
    apod = _apodization(height, width, window, tukey_alpha, dtype)
    freq_row = np.fft.fftfreq(height, 1.0 / height)  # signed integers, as float64
    freq_col = np.arange(width // 2 + 1, dtype=float)

    weight = np.ones((height, freq_col.size))
    if lowpass is not None:
        f2 = (freq_row[:, None] / height) ** 2 + (freq_col[None, :] / width) ** 2
        weight = np.exp(-0.5 * f2 / lowpass**2)
    weight[0, 0] = 0.0  # DC: no position information (and the weighted mean is removed)
    if height % 2 == 0:
        weight[height // 2, :] = 0.0  # Nyquist: its frequency's sign is ambiguous
    if width % 2 == 0:
        weight[:, width // 2] = 0.0
    multiplicity = np.where((freq_col == 0) | (2 * freq_col == width), 1.0, 2.0)

    if exclusion_px is None:
        exclusion_px = 2
        if lowpass is not None:
            exclusion_px = max(2, math.ceil(3.0 / (2.0 * math.pi * lowpass)))

    stages = () if upsample is None else _dft_stages(upsample, stage1_upsample, freq_row, freq_col, multiplicity, height,
                                                     width, dtype)
    coarse = None
    if (first_pass == "half" and follow >= 1 and not isinstance(window, np.ndarray) and height % 4 == 0
            and width % 4 == 0 and min(height, width) >= HALF_FIRST_PASS_MIN_PX):
        # the same algorithm on 2 x 2 bins: frequencies per binned pixel are twice as high, the
        # exclusion box half as wide
        coarse = make_plan((height // 2, width // 2), window=window, tukey_alpha=tukey_alpha,
                           lowpass=None if lowpass is None else 2.0 * lowpass, eps=eps, follow=0,
                           exclusion_px=max(1, math.ceil(exclusion_px / 2)), dtype=dtype)
    return _Plan(
        shape=(height, width), dtype=dtype,
        window_name=None if isinstance(window, np.ndarray) else _window_name(window),
        tukey_alpha=float(tukey_alpha), follow=int(follow), apodization=apod,
        weight=weight.astype(dtype), multiplicity=multiplicity.astype(dtype), freq_row=freq_row,
        freq_col=freq_col, stages=stages, exclusion_px=int(exclusion_px), eps=float(eps), coarse=coarse,
    )


def _dft_stages(upsample: int, stage1_upsample, freq_row, freq_col, multiplicity, height: int, width: int,
                dtype) -> tuple[_Stage, ...]:
    """The DFT-upsampling stages of an integer ``upsample`` (module docstring, step 5)."""
    if stage1_upsample is None:
        stage1_upsample = int(round(math.sqrt(upsample))) if upsample > 20 else 0
    two_stages = 1 < stage1_upsample < upsample
    factors = [stage1_upsample, upsample] if two_stages else [upsample]
    cdtype = np.complex64 if dtype == np.float32 else np.complex128
    stages = []
    half_width = 0.75  # the 1.5 x 1.5 px neighbourhood of the coarse peak
    for factor in factors:
        n_half = math.ceil(half_width * factor - 1e-9)
        offsets = np.arange(-n_half, n_half + 1) / factor
        k_row = np.exp(2j * np.pi * np.outer(offsets, freq_row) / height).astype(cdtype)
        k_col = (multiplicity[:, None] * np.exp(2j * np.pi * np.outer(freq_col, offsets) / width)).astype(cdtype)
        stages.append(_Stage(factor, offsets, k_row, k_col))
        half_width = _NEXT_STAGE_HALF_STEPS / factor  # around the vertex fitted on this grid
    return tuple(stages)


def _apodization(height: int, width: int, window, tukey_alpha: float, dtype):
    """The fixed apodization: an (H, W) array, or separable ``(row (H,), col (W,))`` profiles
    evaluated at pixel centres ``(i + 0.5) / n``."""
    if isinstance(window, np.ndarray):
        if window.shape != (height, width) or not np.all(np.isfinite(window)) or not np.any(window):
            raise InputError(f"an array window must be finite, not all zero, with shape {(height, width)}; got {window.shape}", field="window")
        return window.astype(dtype)
    name = _window_name(window)
    return (window_profile(name, (np.arange(height) + 0.5) / height, tukey_alpha).astype(dtype),
            window_profile(name, (np.arange(width) + 0.5) / width, tukey_alpha).astype(dtype))


def _window_name(window) -> str:
    name = "none" if window is None else str(window).lower()
    if name not in _WINDOWS:
        raise InputError(f"unknown window {window!r}; use one of {', '.join(_WINDOWS)} or an (H, W) array", field="window")
    return name


def window_profile(name: str, u, tukey_alpha: float = 0.5):
    """1-D apodization profile at normalized positions ``u`` (0 and 1: the support's ends).

    Hann: ``sin^2(pi u)``; Tukey: cosine tapers over ``alpha / 2`` of the support at both ends;
    none: a box. Zero outside ``[0, 1]``.

    Parameters
    ----------
    name : {"hann", "tukey", "none"}
        Profile shape.
    u : ndarray, any shape
        Positions in units of the support length (pixel centres of an ``n``-pixel window:
        ``(i + 0.5) / n``).
    tukey_alpha : float
        Taper fraction of the Tukey profile (0 = box, 1 = Hann).

    Returns
    -------
    ndarray of float64, shape of ``u``
        Weights in [0, 1].
    """
    inside = (u >= 0.0) & (u <= 1.0)
    if name == "hann":
        out = np.sin(np.pi * u) ** 2
    elif name == "tukey" and tukey_alpha > 0:
        edge = np.minimum(u, 1.0 - u)  # distance to the nearer end, in support lengths
        out = np.sin(0.5 * np.pi * np.clip(edge / (tukey_alpha / 2.0), 0.0, 1.0)) ** 2
    else:
        out = np.ones_like(u)
    return np.where(inside, out, 0.0)


def following_windows(plan: _Plan, shift_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apodization profiles of the moving windows, translated by the estimated shift.

    The reference keeps the fixed window ``w(t)``; the moving window gets ``w(t - s)`` along
    each axis (``s`` clipped to ``|s| <= n / 2``), so both weight the same ground content and
    nothing slides under a fixed taper (the stationary window's bias toward zero shift
    disappears). The part of the translated taper that leaves the window is lost: for a Hann
    window a fraction of about ``(8 pi^4 / 15) (|s| / n)^5`` of its energy, 0.16 % at
    ``|s| = n / 8``.

    Parameters
    ----------
    plan : _Plan
        Constants of :func:`make_plan` (window shape, profile name, working dtype).
    shift_px : ndarray, shape (B, 2)
        Current (row, col) estimates, px.

    Returns
    -------
    row, col : ndarray, shapes (B, H) and (B, W), plan dtype
        Separable profiles: the 2-D window of pair ``b`` is ``outer(row[b], col[b])``.
    """
    height, width = plan.shape
    # both axes in one (B, H + W) array: u = (i + 1/2 - s) / n per axis
    size = np.repeat([float(height), float(width)], [height, width])
    centres = np.concatenate([np.arange(height), np.arange(width)]) + 0.5
    s = np.clip(shift_px, -0.5 * np.array([height, width]), 0.5 * np.array([height, width]))
    u = ((centres - np.repeat(s, [height, width], axis=1)) / size).astype(plan.dtype)  # float32 sin: vectorized
    profiles = window_profile(plan.window_name, u, plan.tukey_alpha).astype(plan.dtype, copy=False)
    return profiles[:, :height], profiles[:, height:]


# --------------------------------------------------------------------------- numpy kernel


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

    def __init__(self, plan: _Plan, *, workers: int = -1):
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
        """First pass at half resolution (module docstring, step 3).

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
        offset = _parabola_vertex(values[:, :2], values[:, 2:3], values[:, 3:])  # (B, 2): row, col
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
            offset, peak = _grid_peak(values, stage.offsets_px)
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


def _window_2d_float64(plan: _Plan) -> np.ndarray:
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


#: Least-squares coefficients ``(c1, c2, c3, c4, c5)`` of the quadratic of
#: :func:`_quadratic_vertex` from the 9 samples of a 3 x 3 patch (row-major, x = row, y = col).
_X, _Y = (a.ravel() for a in np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij"))
_QUADRATIC_FIT = np.stack([_X / 6.0, _Y / 6.0, (_X**2 - 2.0 / 3.0) / 2.0, (_Y**2 - 2.0 / 3.0) / 2.0, _X * _Y / 4.0], axis=1)
_PATCH_STEPS = np.array([-1, 0, 1])


def _grid_peak(values: np.ndarray, offsets_px: np.ndarray):
    """Maximum of stage grids (B, m, m) refined by a quadratic fit on its 3 x 3 neighbourhood.

    Returns the (row, col) offset (B, 2), px, of the vertex from the grid centre (within one
    grid step of the best sample) and the best sample's value (B,).
    """
    n, m, _ = values.shape
    flat = values.reshape(n, m * m)
    best_index = np.argmax(flat, axis=1)
    best = np.take_along_axis(flat, best_index[:, None], axis=1)[:, 0].astype(float)
    a, b = np.divmod(best_index, m)
    a = np.minimum(np.maximum(a, 1), m - 2)  # neighbourhood inside the grid (only matters on its border)
    b = np.minimum(np.maximum(b, 1), m - 2)
    index = ((a * m + b)[:, None] + (_PATCH_STEPS[:, None] * m + _PATCH_STEPS[None, :]).ravel())
    d_row, d_col = _quadratic_vertex(np.take_along_axis(flat, index, axis=1).astype(float).reshape(n, 3, 3))
    spacing = offsets_px[1] - offsets_px[0]
    offset = np.stack([offsets_px[a] + d_row * spacing, offsets_px[b] + d_col * spacing], axis=1)
    return offset, best


def _quadratic_vertex(patch: np.ndarray):
    """Vertex (in grid steps, clipped to [-1, 1]) of the least-squares quadratic
    ``f = c0 + c1 x + c2 y + c3 x^2 + c4 y^2 + c5 x y`` on 3 x 3 samples (B, 3, 3) at
    ``x, y in {-1, 0, 1}`` (rows, columns); 0 where the fit has no maximum."""
    c1, c2, c3, c4, c5 = (patch.reshape(-1, 9) @ _QUADRATIC_FIT).T
    det = 4.0 * c3 * c4 - c5**2
    ok = (c3 < 0) & (det > 0)
    det = np.where(ok, det, 1.0)
    d_row = np.where(ok, (c5 * c2 - 2.0 * c4 * c1) / det, 0.0)
    d_col = np.where(ok, (c5 * c1 - 2.0 * c3 * c2) / det, 0.0)
    return np.minimum(np.maximum(d_row, -1.0), 1.0), np.minimum(np.maximum(d_col, -1.0), 1.0)


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


def _parabola_vertex(left, centre, right) -> np.ndarray:
    """Vertex offset in [-0.5, 0.5] of the parabola through (-1, left), (0, centre), (1, right)."""
    curvature = left - 2.0 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (left - right) / curvature, 0.0)
    return np.clip(offset, -0.5, 0.5).astype(float)


def _signed(index: np.ndarray, size: int) -> np.ndarray:
    """Periodic index in [0, size) -> signed shift in [-size/2, size/2)."""
    return np.where(index >= (size + 1) // 2, index - size, index)


# --------------------------------------------------------------------------- quality


def _assess(shift, peak, q_mean, q_var, second, first_q_mean, min_score, min_peak_ratio, max_shift) -> PhaseMatches:
    """Scores, peak ratios and the rejection tests, shared by every backend."""
    flat = ~(q_mean > 0)
    q_mean = np.where(flat, 1.0, q_mean)
    score = np.where(flat, 0.0, np.clip(peak / q_mean, 0.0, 1.0))
    if min_score is None:  # NULL_SIGMA_FACTOR standard deviations of the score of unrelated pairs
        min_score = np.minimum(NULL_SIGMA_FACTOR * np.sqrt(q_var) / q_mean, 1.0)
    # both peaks in units of their pass's ideal height: score / (second / first_q_mean)
    second_score = second / np.where(first_q_mean > 0, first_q_mean, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(second_score > 0, score / np.where(second_score > 0, second_score, 1.0), np.inf)
    ratio = np.where(flat | ~(score > 0), 0.0, ratio)
    shift = np.where(flat[:, None], np.nan, shift)

    reason = np.full(shift.shape[0], Reject.OK, dtype=np.int8)
    tests = [  # lowest priority first: a later test overwrites an earlier one
        (Reject.LOW_PEAK_RATIO, ratio < min_peak_ratio),
        (Reject.LOW_SCORE, score < min_score),
        (Reject.OUT_OF_RANGE, (np.abs(shift[:, 0]) > max_shift[0]) | (np.abs(shift[:, 1]) > max_shift[1])),
        (Reject.NOT_FINITE, ~np.all(np.isfinite(shift), axis=1) | ~np.isfinite(score)),
        (Reject.FLAT, flat),
    ]
    for code, failed in tests:
        reason[failed] = code
    return PhaseMatches(
        shift_row_px=np.ascontiguousarray(shift[:, 0], dtype=float),
        shift_col_px=np.ascontiguousarray(shift[:, 1], dtype=float),
        score=score.astype(float), peak_ratio=ratio.astype(float),
        valid=reason == Reject.OK, reason=reason,
    )


# --------------------------------------------------------------------------- validation


def _validate_pairs(reference, moving) -> tuple[np.ndarray, np.ndarray]:
    arrays = []
    for name, value in (("reference", reference), ("moving", moving)):
        arr = np.asarray(value)
        if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool) or np.iscomplexobj(arr):
            raise InputError(f"windows must hold real numbers, got dtype {arr.dtype}", field=name)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3:
            raise InputError(f"windows must have shape (N, H, W) or (H, W), got {arr.shape}", field=name)
        arrays.append(arr)
    ref, mov = arrays
    if ref.shape != mov.shape:
        raise InputError(f"reference and moving shapes differ: {ref.shape} vs {mov.shape}", field="moving")
    if min(ref.shape[1:]) < MIN_WINDOW_PX:
        raise InputError(f"windows must be at least {MIN_WINDOW_PX} x {MIN_WINDOW_PX} px, got {ref.shape[1]} x {ref.shape[2]}", field="reference")
    if ref.shape[0] == 0:
        raise InputError("no window pairs given (N = 0)", field="reference")
    for name, arr in (("reference", ref), ("moving", mov)):
        if not np.issubdtype(arr.dtype, np.floating):
            continue
        bad = _non_finite_windows(arr)
        if bad.any():
            raise InputError(
                f"{int(bad.sum())} window(s) hold NaN or inf (first: pair {int(np.argmax(bad))}); fill or drop them before matching",
                field=name,
            )
    return ref, mov


def _non_finite_windows(arr: np.ndarray) -> np.ndarray:
    """(N,) flags of the (N, H, W) floating windows holding a NaN or an infinity.

    One matrix-vector product with ones per window (a NaN or an infinity makes the sum
    non-finite; no boolean array is formed), then the exact test on the windows whose sum is not
    finite (finite values can also overflow the sum).
    """
    flat = arr.reshape(arr.shape[0], -1)
    with np.errstate(over="ignore", invalid="ignore"):
        suspect = ~np.isfinite(flat @ np.ones(flat.shape[1], dtype=arr.dtype))
    bad = np.zeros(arr.shape[0], dtype=bool)
    if suspect.any():
        bad[suspect] = ~np.isfinite(flat[suspect]).all(axis=1)
    return bad


def _is_int(value, minimum: int) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= minimum


def _validate_options(**o) -> dict:
    checks = [
        ("upsample", o["upsample"] is None or _is_int(o["upsample"], 1), "an integer >= 1 or None"),
        ("min_score", o["min_score"] is None or 0.0 <= o["min_score"] <= 1.0, "in [0, 1] or None"),
        ("min_peak_ratio", o["min_peak_ratio"] is None or o["min_peak_ratio"] >= 0.0, ">= 0 or None"),
        ("lowpass", o["lowpass"] is None or o["lowpass"] > 0.0, "a positive frequency in cycles/px or None"),
        ("eps", o["eps"] >= 0.0, ">= 0"),
        ("follow", _is_int(o["follow"], 0), "an integer >= 0"),
        ("exclusion_px", o["exclusion_px"] is None or _is_int(o["exclusion_px"], 0), "an integer >= 0 or None"),
        ("stage1_upsample", o["stage1_upsample"] is None or _is_int(o["stage1_upsample"], 0), "an integer >= 0 or None"),
        ("tukey_alpha", 0.0 <= o["tukey_alpha"] <= 1.0, "in [0, 1]"),
        ("batch", o["batch"] is None or _is_int(o["batch"], 1), "an integer >= 1 or None"),
        ("workers", o["workers"] is None or (_is_int(o["workers"], -1) and o["workers"] != 0), "a non-zero integer >= -1 or None"),
        ("first_pass", o["first_pass"] in FIRST_PASSES, "one of " + ", ".join(map(repr, FIRST_PASSES))),
    ]
    for field, ok, expected in checks:
        if not ok:
            raise InputError(f"{field} must be {expected}, got {o[field]!r}", field=field)
    dtypes = {"float32": np.float32, "float64": np.float64}
    key = str(np.dtype(o["dtype"])) if o["dtype"] in (np.float32, np.float64) else o["dtype"]
    if key not in dtypes:
        raise InputError(f"dtype must be 'float32' or 'float64', got {o['dtype']!r}", field="dtype")
    backend = str(o["backend"]).lower()
    if backend not in _BACKENDS:
        raise InputError(f"unknown backend {o['backend']!r}; use one of {', '.join(_BACKENDS)}", field="backend")
    device = o["device"]
    if backend in ("cpu", "numpy"):
        if device not in (None, "cpu"):
            raise InputError(f"device {device!r} needs backend='torch' or 'gpu'", field="device")
        backend = "numpy"
    else:
        if o["workers"] is not None:
            raise InputError("workers applies to backend='cpu'; set torch.set_num_threads() for torch", field="workers")
        device = device or ("cuda" if backend == "gpu" else "cpu")
        backend = "torch"
    return {"dtype": dtypes[key], "backend": backend, "device": device}


def _validate_max_shift(max_shift_px, height: int, width: int) -> tuple[float, float]:
    if max_shift_px is None:
        return height / 4.0, width / 4.0
    try:
        values = np.broadcast_to(np.asarray(max_shift_px, dtype=float), (2,))
    except (TypeError, ValueError):
        values = np.array([np.nan])
    if not np.all(values > 0):
        raise InputError(f"max_shift_px must be a positive number or a (row, col) pair, got {max_shift_px!r}", field="max_shift_px")
    return float(values[0]), float(values[1])
