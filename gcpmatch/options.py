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

__all__ = ["BACKENDS", "MatchOptions", "require_cuda"]

BACKENDS = ("cpu", "gpu", "torch")  # numpy/scipy; torch on CUDA; torch on the CPU


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
        Windows phase-correlated per batch (bounds memory); >= 1.
    coarse_skip : bool
        Skip the coarse SIFT stage when a cheap check finds the model already within the fine
        search radius (``window_px / 4``); ``gcpcal validate`` sets it (default False).
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
    batch: int = 2048
    coarse_skip: bool = False

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
        if not isinstance(self.coarse_skip, bool):
            raise InputError(f"coarse_skip must be true or false, got {self.coarse_skip!r}", field="coarse_skip")
        return self
