"""The plan of :func:`gcpmatch.phase.phase_correlate`: the algorithm's constants for one window shape.

:func:`make_plan` computes, once per window shape and options, everything the batch kernels
(:class:`gcpmatch.phase_numpy.NumpyKernel` and the torch backend) read and never change: the
fixed apodization window (step 1 of the :mod:`gcpmatch.phase` docstring), the spectral weight
``w(k)`` and the Hermitian multiplicity of the half-spectrum columns (step 2), the exclusion box
of the secondary peak (step 3), the half-resolution first pass's own plan (step 3), and the
DFT-upsampling stages of an integer ``upsample`` (step 5, :class:`UpsampleStage`). The
apodization profiles (:func:`window_profile`) and their translated copies for the
window-following passes (:func:`following_windows`, step 4) live here too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError

__all__ = ["HALF_FIRST_PASS_MIN_PX", "HALF_PASS_OFFSET_PX", "PhasePlan", "UpsampleStage", "following_windows",
           "make_plan", "window_profile"]

_WINDOWS = ("hann", "tukey", "none")
#: Half-width of a refinement stage after the first, in steps of the previous stage's grid. The
#: quadratic vertex fitted on a 0.1 px grid is within 0.002 px of the true maximum (measured:
#: U = 10 and U = 100 give the same RMS error, 0.0008 px), so 0.3 steps is ample.
_NEXT_STAGE_HALF_STEPS = 0.3
#: Smallest window side whose first pass runs at half resolution (a 16 x 16 px binned window);
#: smaller windows, sides not divisible by 4, user array windows and ``follow=0`` keep the
#: full-resolution first pass.
HALF_FIRST_PASS_MIN_PX = 32
#: Added to the doubled half-resolution estimate, px per axis: a 2 x 2 bin ``j`` holds the moving
#: content at full-resolution position ``2 j + 0.5`` while the reference's low-frequency quarter
#: samples it at ``2 j``, so the binned content appears 0.5 px early. Measured: the doubled
#: estimate is 0.498 / 0.502 px short on average over 512 benchmark pairs.
HALF_PASS_OFFSET_PX = 0.5


@dataclass(frozen=True)
class UpsampleStage:
    """One DFT-upsampling stage: sample offsets and pair-independent kernel factors."""

    factor: int
    offsets_px: np.ndarray  # (n,) float64: offsets of the samples from the stage's centre
    kernel_row: np.ndarray  # (n, H) complex: exp(2 pi i k1 d_a / H)
    kernel_col: np.ndarray  # (Wh, n) complex: m(k2) exp(2 pi i k2 d_b / W)


@dataclass(frozen=True)
class PhasePlan:
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
    stages: tuple[UpsampleStage, ...]  # DFT-upsampling stages; empty for the Newton refinement
    exclusion_px: int
    eps: float
    coarse: PhasePlan | None = None  # the half-resolution first pass (step 3); None: full resolution
    coarse_offset_px: float = HALF_PASS_OFFSET_PX  # added to its doubled estimate, px per axis

    @property
    def complex_dtype(self) -> np.dtype:
        return np.dtype(np.complex64 if self.dtype == np.float32 else np.complex128)


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
) -> PhasePlan:
    """Constants of the algorithm for windows of ``shape`` = (H, W) (see :func:`gcpmatch.phase.phase_correlate`).

    Parameters
    ----------
    shape : (int, int)
        Window size ``(H, W)``, pixels (rows, columns).
    upsample, window, tukey_alpha, lowpass, eps, follow, exclusion_px, stage1_upsample, first_pass
        As in :func:`gcpmatch.phase.phase_correlate` (an array ``window`` has shape (H, W)).
    dtype : numpy dtype
        Working precision, float32 or float64.

    Returns
    -------
    PhasePlan
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
    return PhasePlan(
        shape=(height, width), dtype=dtype,
        window_name=None if isinstance(window, np.ndarray) else _window_name(window),
        tukey_alpha=float(tukey_alpha), follow=int(follow), apodization=apod,
        weight=weight.astype(dtype), multiplicity=multiplicity.astype(dtype), freq_row=freq_row,
        freq_col=freq_col, stages=stages, exclusion_px=int(exclusion_px), eps=float(eps), coarse=coarse,
    )


def _dft_stages(upsample: int, stage1_upsample, freq_row, freq_col, multiplicity, height: int, width: int,
                dtype) -> tuple[UpsampleStage, ...]:
    """The DFT-upsampling stages of an integer ``upsample`` (:mod:`gcpmatch.phase` docstring, step 5)."""
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
        stages.append(UpsampleStage(factor, offsets, k_row, k_col))
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


def following_windows(plan: PhasePlan, shift_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apodization profiles of the moving windows, translated by the estimated shift.

    The reference keeps the fixed window ``w(t)``; the moving window gets ``w(t - s)`` along
    each axis (``s`` clipped to ``|s| <= n / 2``), so both weight the same ground content and
    nothing slides under a fixed taper (the stationary window's bias toward zero shift
    disappears). The part of the translated taper that leaves the window is lost: for a Hann
    window a fraction of about ``(8 pi^4 / 15) (|s| / n)^5`` of its energy, 0.16 % at
    ``|s| = n / 8``.

    Parameters
    ----------
    plan : PhasePlan
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
