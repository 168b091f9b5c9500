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
   translated by the current estimate (:func:`~gcpmatch.phase_plan.following_windows`), so
   both windows weight the same ground content, and recomputes ``Q`` (the reference spectrum
   is reused).
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
import queue
from dataclasses import dataclass

import numpy as np

from gcpmatch.phase_batch import cpu_batch, device_batch
from gcpmatch.phase_numpy import NumpyKernel
from gcpmatch.phase_plan import make_plan
from gcpmatch.phase_pool import KERNEL_POOL
from sensor_models.errors import InputError
from sensor_models.files.threads import blas_threads, map_ordered, thread_count

__all__ = ["FIRST_PASSES", "MIN_PEAK_RATIO", "MIN_WINDOW_PX", "NULL_SIGMA_FACTOR", "PhaseMatches", "Reject",
           "phase_correlate"]

#: Smallest window side accepted, in pixels.
MIN_WINDOW_PX = 8

#: Default ``min_score`` in standard deviations of the score of unrelated windows. Measured on
#: 1000 unrelated pairs each of 32, 64 and 128 px (scene versus scene, scene versus white
#: noise): 99.9th percentile 8.6 to 9.5 sigma, maximum 10.8; true pairs at SNR 20 score at
#: least 12.8 (32 px), 23 (64 px) and 44 (128 px) sigma. ``tests/test_phase.py`` checks both
#: sides (with the peak-ratio test, which rejects most of the remaining false peaks).
NULL_SIGMA_FACTOR = 10.0

_BACKENDS = ("cpu", "numpy", "torch", "gpu")
#: First passes (``first_pass``): ``"half"`` correlates at half resolution (module docstring,
#: step 3), ``"full"`` on the full-resolution surface.
FIRST_PASSES = ("half", "full")
#: Default ``min_peak_ratio`` per first pass, set at equal false-acceptance of unrelated windows.
#: The half-resolution surface has a quarter of the samples and a lower main peak: on the
#: realistic demo's 920 window pairs of band B2, shuffled six times (5520 unrelated pairs), the
#: ratio reaches 2.0 in 1.39 % of them on the full surface and 1.8 in 1.25 % on the half one
#: (2.0 in 0.76 %); on the matched pairs the half ratio is 0.76 times the full one (median).
MIN_PEAK_RATIO = {"full": 2.0, "half": 1.8}


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
        Window-following passes after the first estimate (see :func:`~gcpmatch.phase_plan.following_windows`);
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
        float32, measured); ``None``: on the CPU backend 2**20 px worth of windows (256 pairs of
        64 x 64 px) per four threads (:func:`gcpmatch.phase_batch.cpu_batch`: 1 024 pairs at 16
        threads), on the torch backends what the device's free memory holds
        (:func:`gcpmatch.phase_batch.device_batch`). The results do not depend on it (to the
        last bits: :mod:`gcpmatch.phase_batch`).
    workers : int or None
        Threads over the batches (``None`` or -1: :func:`sensor_models.files.threads.thread_count`,
        ``GCPCAL_THREADS`` or every core; 1: one after the other); with fewer batches than
        threads, the rest go to each batch's ``scipy.fft`` calls. The default batch grows with
        the count (``batch``); the results are the same whatever the count (tested); the scratch
        memory is ``workers`` times a batch's. CPU backend only (torch uses
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
        Mismatched shapes, windows under 8 px, non-finite or non-numeric data, invalid options.
    """
    ref, mov = _validate_pairs(reference, moving)
    _, height, width = ref.shape
    options = _validate_options(upsample=upsample, min_score=min_score, min_peak_ratio=min_peak_ratio,
                                lowpass=lowpass, exclusion_px=exclusion_px, stage1_upsample=stage1_upsample,
                                follow=follow, eps=eps, dtype=dtype, backend=backend, device=device, batch=batch,
                                tukey_alpha=tukey_alpha, workers=workers, first_pass=first_pass)
    max_shift = _validate_max_shift(max_shift_px, height, width)
    plan_args = dict(upsample=upsample, window=window, tukey_alpha=tukey_alpha, lowpass=lowpass, eps=eps, follow=follow,
                     exclusion_px=exclusion_px, stage1_upsample=stage1_upsample, dtype=options["dtype"], first_pass=first_pass)
    plan = make_plan((height, width), **plan_args)
    if min_peak_ratio is None:
        min_peak_ratio = MIN_PEAK_RATIO["half" if plan.coarse is not None else "full"]
    if options["backend"] == "numpy":
        outputs = _run_numpy_batches(plan, ref, mov, batch, thread_count(None if workers == -1 else workers),
                                     _kernel_key((height, width), plan_args))
    else:
        outputs = _run_torch_batches(plan, ref, mov, batch, options["device"])
    return _assess(*outputs, min_score, min_peak_ratio, max_shift)


def _kernel_key(shape: tuple[int, int], plan_args: dict):
    """The key of a pooled kernel (:mod:`gcpmatch.phase_pool`): the window shape and the
    arguments of :func:`~gcpmatch.phase_plan.make_plan`; None for a user array window (not pooled)."""
    if isinstance(plan_args["window"], np.ndarray):
        return None
    named = {**plan_args, "window": str(plan_args["window"]).lower(), "dtype": np.dtype(plan_args["dtype"]).name}
    return tuple(shape), tuple(sorted(named.items()))


def _run_torch_batches(plan, ref, mov, batch, device):
    """The torch kernel over the pairs by batches (``None``: sized from the device's free memory,
    :func:`gcpmatch.phase_batch.device_batch`); the concatenated kernel outputs."""
    from gcpmatch import _phase_torch  # lazy: torch is an optional dependency

    with blas_threads(1):  # its product with ones would wake OpenBLAS's threads, which then spin
        _raise_non_finite(ref, mov)
    kernel = _phase_torch.TorchKernel(plan, device=device)
    if batch is None:
        batch = device_batch(ref.shape[1:], plan.dtype, kernel.device)
    return _concatenate([kernel(ref[a:b], mov[a:b]) for a, b in _batches(ref.shape, batch)])


def _batches(shape: tuple[int, int, int], batch, threads: int = 1) -> list[tuple[int, int]]:
    """``(first, end)`` pair indices of the batches of (N, H, W) pairs: ``batch`` pairs each
    (None: :func:`gcpmatch.phase_batch.cpu_batch` for ``threads``)."""
    n_pairs, height, width = shape
    if batch is None:
        batch = cpu_batch(height, width, threads)
    return [(a, min(n_pairs, a + batch)) for a in range(0, n_pairs, batch)]


def _run_numpy_batches(plan, ref: np.ndarray, mov: np.ndarray, batch, threads: int, key=None):
    """The numpy kernel over the batches of pairs on ``threads`` threads, results in pair order.

    Each running thread takes a kernel of its own (a kernel keeps scratch buffers between
    batches): one this call used already, else an idle one of ``key`` from
    :data:`gcpmatch.phase_pool.KERNEL_POOL`, else a new one; the call's kernels go back to the
    pool at its end (``key`` None: none is kept). With fewer batches than threads, each kernel's
    FFTs get ``threads // batches`` workers (``scipy.fft`` splits a batch over its transforms: the
    same numbers). BLAS runs one thread meanwhile.

    Returns
    -------
    tuple of ndarray
        The kernel's six outputs (shift, peak, quality mean and variance, secondary peak, first
        quality mean), each concatenated over the batches along the first axis (N).
    """
    spans = _batches(ref.shape, batch, threads)
    pool_threads = min(threads, len(spans))
    fft_workers = max(1, threads // pool_threads)
    idle = queue.SimpleQueue()  # this call's kernels not running a batch now
    pool_key = None if key is None else (key, fft_workers)

    def build():
        return NumpyKernel(plan, workers=fft_workers)

    def run(span):
        try:
            kernel = idle.get_nowait()
        except queue.Empty:
            kernel = build() if pool_key is None else KERNEL_POOL.take(pool_key, build)
        try:
            a, b = span
            _raise_non_finite(ref[a:b], mov[a:b], first_pair=a)  # while the batch is in the cache
            return kernel(ref[a:b], mov[a:b])
        finally:
            idle.put(kernel)

    with blas_threads(1):  # small products: BLAS threads would only wait (sensor_models.files.threads)
        outputs = _concatenate(list(map_ordered(run, spans, pool_threads)))
    while pool_key is not None and not idle.empty():
        KERNEL_POOL.give_back(pool_key, idle.get_nowait())
    return outputs


def _concatenate(parts) -> tuple:
    """Per-batch kernel outputs joined along the pair axis."""
    return tuple(np.concatenate(p) for p in zip(*parts))


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
    return ref, mov


def _raise_non_finite(ref: np.ndarray, mov: np.ndarray, first_pair: int = 0) -> None:
    """InputError naming the first of the (N, H, W) pairs ``first_pair``... whose reference, then
    moving, window holds a NaN or an infinity; nothing for finite or integer windows.

    The CPU backend checks each batch just before its kernel reads it (the batch is then in the
    cache: over the whole arrays first the check cost 6 % of the correlation, docs/speed.md), so
    pairs before the first bad one have been correlated when it raises.
    """
    for name, arr in (("reference", ref), ("moving", mov)):
        if not np.issubdtype(arr.dtype, np.floating):
            continue
        bad = _non_finite_windows(arr)
        if bad.any():
            raise InputError(
                f"{int(bad.sum())} window(s) of pairs {first_pair}-{first_pair + len(arr) - 1} hold NaN or inf "
                f"(first: pair {first_pair + int(np.argmax(bad))}); fill or drop them before matching",
                field=name,
            )


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
