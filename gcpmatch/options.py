"""The matcher's settings: one frozen dataclass, the single home of its defaults.

:class:`MatchOptions` configures :func:`gcpmatch.extract.extract_gcps`; the ``gcpcal match``
command takes its option defaults from here. Every field is checked by
:meth:`MatchOptions.validate`, and a bad value raises an
:class:`~sensor_models.errors.InputError` naming the field.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

from sensor_models.errors import InputError
from sensor_models.files.threads import thread_count

__all__ = ["BACKENDS", "COARSE_SEARCHES", "SIGMA_MODELS", "MatchOptions", "require_cuda"]

BACKENDS = ("cpu", "gpu", "torch")  # numpy/scipy; torch on CUDA; torch on the CPU
SIGMA_MODELS = ("window", "ccd")  # the first is the default
#: the coarse stage's feature searches (gcpmatch.coarse.coarse_match); the first is the default
COARSE_SEARCHES = ("adaptive", "fast", "exhaustive")


def require_cuda() -> None:
    """Raise unless torch is installed and sees a CUDA device (the ``gpu`` backend's need).

    Raises
    ------
    InputError
        Without torch, or with a torch that has no CUDA device (checked before any work).
    """
    try:
        import torch
    except ImportError:
        raise InputError("--backend gpu needs torch with CUDA (pip install -e '.[gpu]'); use --backend cpu") from None
    if not torch.cuda.is_available():
        raise InputError("--backend gpu needs a CUDA device; this torch has none (use --backend cpu)")


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


@dataclass(frozen=True)
class MatchOptions:
    """Settings of :func:`gcpmatch.extract.extract_gcps` (all have working defaults).

    Parameters
    ----------
    window_px : int
        Side of the square phase-correlation windows, pixels; even, >= 16.
    spacing_px : int
        Step of the window grid along rows and columns, pixels; >= 1.
    max_offset_px : float
        Largest offset, pixels, that the coarse SIFT stage searches for; > 0.
    check_fraction : float
        Share of the GCPs set aside as independent check points, in [0, 1).
    backend : str
        ``"cpu"`` (numpy / scipy / OpenCV), ``"gpu"`` (torch on CUDA) or ``"torch"`` (torch on
        the CPU).
    cloud_window_fraction : float
        A window whose share of cloudy pixels exceeds this is skipped, in [0, 1].
    texture_fraction : float
        Windows whose reference standard deviation is below this fraction of the CCD's typical
        one are featureless (water) and skipped, in [0, 1].
    psf_sigma_px : float
        Standard deviation, pixels, of the Gaussian point-spread function applied to the
        reference chips; >= 0.
    seed : int
        Seed of the random draws (RANSAC, check-point split); >= 0.
    batch : int
        Windows one thread gathers, screens and phase-correlates at once; >= 1 (default 512:
        256 to 1024 ran at the same speed, 2048 at 0.6 of it, on one and two threads; the host
        holds about ``threads x batch`` windows' scratch). With ``backend="gpu"`` the least:
        the device's batches are sized up from the free GPU and host memory
        (:func:`gcpmatch.extract.window_task_size`, :func:`gcpmatch.phase_batch.match_batch`).
    radiometry : str
        Preparation of each window pair before correlation (:mod:`gcpmatch.radiometry`):
        ``"none"``, ``"rank"`` (rank transform: invariant to any monotonic grey-level change) or
        ``"gradient"`` (gradient magnitude).
    sigma_model : str
        How each GCP's ``sigma_px`` is set (docs/matching.md, "sigma_px"): ``"window"`` (default;
        per window: the matching noise predicted from its correlation score, combined with the
        reference DOM's geolocation accuracy) or ``"ccd"`` (one value per CCD: the robust spread
        of the residuals about a smooth correction).
    phase_eps : float
        Floor of the cross-power normalization of :func:`gcpmatch.phase.phase_correlate`
        (``eps``), relative to each pair's mean cross-power magnitude; >= 0.
    lowpass_cycles_px : float or None
        Standard deviation, cycles/px, of a Gaussian weight on the cross-power spectrum
        (``lowpass`` of :func:`gcpmatch.phase.phase_correlate`); None for none; > 0.
    reference_sigma_m : float, (float, float) or None
        Geolocation accuracy of the reference DOM (and its DEM's effect), metres (1 sigma): one
        value for both axes or ``(east, north)``, as its producer states it; >= 0. None (default): what the DOM states
        (:func:`sensor_models.maps.dom_inputs.reference_accuracy`: its GDAL tags or a Landsat MTL),
        else an assumed value that the summary names. Used by ``sigma_model="window"``.
    min_gradient_snr : float
        Absolute texture gate: a window whose scene gradient snr (rms forward difference over the
        band's noise, :func:`gcpmatch.texture.gradient_snr`) is below this on either axis is
        featureless (``no_texture``); >= 0, 0 (default) for no gate.
    texture_sigma_px : float
        ``sigma_model="window"``: extra matching noise per axis, pixels, of a window of gradient
        snr 1, added in quadrature as ``texture_sigma_px / snr`` (:func:`gcpmatch.texture.texture_sigma_px`);
        >= 0, 0 (default) for none.
    mismatch_sigma_scale : float
        ``sigma_model="window"``: factor on each pair's Cramer-Rao-shaped sigma with the pair's own
        mismatch as its noise (:func:`gcpmatch.texture.mismatch_cr_sigma_px`), added in
        quadrature; >= 0, 0 (default) for none.
    spectral_spread_sigma : bool
        ``sigma_model="window"``: add in quadrature each pair's spectral spread, how far the shift
        moves when the cross-power is weighted otherwise (pure phase, low-pass:
        :func:`gcpmatch.window_match.spectral_spread_px`), which grows where the reference
        shows the ground differently (another band, season or sensor); default False
        (docs/matching.md, "Matching under real change").
    max_spectral_spread : float
        Reject a window (``spectral_spread``) whose spectral spread exceeds this many times the
        matching noise its score predicts (:func:`gcpmatch.uncertainty.score_sigma_px`): a pair
        that disagrees with itself beyond its noise shows the ground differently in the two
        images; > 0, or 0 (default) for no test. 1 keeps the pairs consistent within their
        predicted noise (docs/matching.md, "Matching under real change").
    detect_change : bool
        Let the scene decide: every window's spectral spread is measured, and when the median
        over the scene's matched windows of the spread over the noise its score predicts exceeds
        1 (most pairs disagree with themselves beyond their noise: a reference of another band,
        season or sensor; :func:`gcpmatch.window_match.reference_disagrees`), the scene is
        matched as with ``spectral_spread_sigma=True`` and ``max_spectral_spread`` 1 (or the
        value given), else as the other options say. The summary's ``change`` reports the median
        and the decision. Costs two more phase correlations per window; default False
        (docs/matching.md, "What limits matching across the bands").
    coarse_search : {"adaptive", "fast", "exhaustive"}
        Feature search of the coarse stage (:func:`gcpmatch.coarse.coarse_match`): ``"adaptive"``
        (default; full-resolution SIFT, FLANN, 4 000 scene keypoints first), ``"fast"`` (SIFT
        on the images averaged down 1.5 times, matches measured at full resolution, where
        trusted; :mod:`gcpmatch.coarse_fast`) or ``"exhaustive"`` (brute force, 12 000 keypoints
        per image); docs/matching.md, "Coarse stage searches".
    coarse_skip : bool
        Skip the coarse SIFT stage when a cheap check finds the model already within the fine
        search radius (``window_px / 4``); ``gcpcal validate`` sets it (default False).
    threads : int
        Threads of the reference chips (blocks of lines), the phase correlation (batches of
        windows) and OpenCV (SIFT); 0 (default): ``GCPCAL_THREADS`` when set, else every core this
        process may run on. The GCPs do not depend on it (the work is split
        into the same blocks and batches whatever the count, and no sum runs across threads).
    """

    window_px: int = 64
    spacing_px: int = 32
    max_offset_px: float = 1000.0
    check_fraction: float = 0.2
    backend: str = "cpu"
    cloud_window_fraction: float = 0.1
    texture_fraction: float = 0.2
    psf_sigma_px: float = 0.45
    seed: int = 0
    batch: int = 512
    radiometry: str = "none"
    sigma_model: str = "window"
    phase_eps: float = 0.5
    lowpass_cycles_px: float | None = None
    reference_sigma_m: float | tuple[float, float] | None = None
    coarse_skip: bool = False
    coarse_search: str = "adaptive"
    min_gradient_snr: float = 0.0
    texture_sigma_px: float = 0.0
    mismatch_sigma_scale: float = 1.0
    spectral_spread_sigma: bool = False
    max_spectral_spread: float = 0.0
    detect_change: bool = False
    threads: int = 0

    def thread_count(self) -> int:
        """Threads to use: ``threads``, or when it is 0 ``GCPCAL_THREADS`` or every core this process
        may run on (:func:`sensor_models.files.threads.thread_count`)."""
        return thread_count(self.threads)

    def validate(self) -> MatchOptions:
        """Check every field; return ``self`` unchanged.

        Returns
        -------
        MatchOptions
            ``self``.

        Raises
        ------
        InputError
            On the first bad field, naming it.
        """
        if not _is_int(self.window_px) or self.window_px < 16 or self.window_px % 2:
            raise InputError(f"window must be an even number of pixels >= 16, got {self.window_px}", field="window_px")
        if not _is_int(self.spacing_px) or self.spacing_px < 1:
            raise InputError(f"spacing must be an integer >= 1 pixel, got {self.spacing_px!r}", field="spacing_px")
        if not _is_real(self.max_offset_px) or not self.max_offset_px > 0:
            raise InputError(f"maximum offset must be > 0 pixels, got {self.max_offset_px!r}", field="max_offset_px")
        if not _is_real(self.check_fraction) or not 0.0 <= self.check_fraction < 1.0:
            raise InputError(f"check fraction must lie in [0, 1), got {self.check_fraction}", field="check_fraction")
        if self.backend not in BACKENDS:
            raise InputError(f"backend must be cpu or gpu, got {self.backend!r}", field="backend")
        if self.backend == "gpu":
            require_cuda()
        for name in ("cloud_window_fraction", "texture_fraction"):
            value = getattr(self, name)
            if not _is_real(value) or not 0.0 <= value <= 1.0:
                raise InputError(f"must lie in [0, 1], got {value!r}", field=name)
        if not _is_real(self.psf_sigma_px) or not self.psf_sigma_px >= 0:
            raise InputError(f"PSF sigma must be >= 0 pixels, got {self.psf_sigma_px!r}", field="psf_sigma_px")
        if not _is_int(self.seed) or self.seed < 0:
            raise InputError(f"seed must be an integer >= 0, got {self.seed!r}", field="seed")
        if not _is_int(self.batch) or self.batch < 1:
            raise InputError(f"batch must be an integer >= 1 window, got {self.batch!r}", field="batch")
        from gcpmatch.radiometry import METHODS

        if self.radiometry not in METHODS:
            raise InputError(f"radiometry must be one of {', '.join(METHODS)}, got {self.radiometry!r}",
                             field="radiometry")
        if self.sigma_model not in SIGMA_MODELS:
            raise InputError(f"sigma model must be one of {', '.join(SIGMA_MODELS)}, got {self.sigma_model!r}",
                             field="sigma_model")
        if not _is_real(self.phase_eps) or not self.phase_eps >= 0:
            raise InputError(f"phase eps must be >= 0, got {self.phase_eps!r}", field="phase_eps")
        if self.lowpass_cycles_px is not None and (not _is_real(self.lowpass_cycles_px)
                                                   or not self.lowpass_cycles_px > 0):
            raise InputError(f"low-pass must be > 0 cycles/px or None, got {self.lowpass_cycles_px!r}",
                             field="lowpass_cycles_px")
        if self.reference_sigma_m is not None:
            values = (self.reference_sigma_m if isinstance(self.reference_sigma_m, (tuple, list))
                      else (self.reference_sigma_m,))
            if len(values) not in (1, 2) or not all(_is_real(v) and v >= 0 for v in values):
                raise InputError(f"reference sigma must be one or two (east, north) values >= 0 metres, got "
                                 f"{self.reference_sigma_m!r}", field="reference_sigma_m")
        for name in ("min_gradient_snr", "texture_sigma_px", "mismatch_sigma_scale", "max_spectral_spread"):
            value = getattr(self, name)
            if not _is_real(value) or not value >= 0.0 or value == float("inf"):
                raise InputError(f"must be a finite number >= 0, got {value!r}", field=name)
        if not _is_int(self.threads) or self.threads < 0:
            raise InputError(f"threads must be an integer >= 0 (0: every core), got {self.threads!r}", field="threads")
        if self.coarse_search not in COARSE_SEARCHES:
            raise InputError(f"coarse search must be one of {', '.join(COARSE_SEARCHES)}, got {self.coarse_search!r}",
                             field="coarse_search")
        for name in ("coarse_skip", "spectral_spread_sigma", "detect_change"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be true or false, got {getattr(self, name)!r}", field=name)
        return self
