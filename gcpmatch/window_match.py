"""One batch of window pairs matched as :func:`gcpmatch.extract.extract_gcps` does.

:func:`correlate_pairs` turns reference and scene windows into shifts, a rejection reason per
pair and the per-window quality figures that the outlier tests and the sigma model
(:mod:`gcpmatch.uncertainty`) read. The radiometric preparation of the windows
(:mod:`gcpmatch.radiometry`) and the phase-correlation settings come from
:class:`~gcpmatch.options.MatchOptions`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gcpmatch.options import MatchOptions
from gcpmatch.phase import Reject, phase_correlate
from gcpmatch.radiometry import prepare_windows
from gcpmatch.texture import mismatch_cr_sigma_px
from gcpmatch.uncertainty import score_sigma_px

__all__ = ["PairMatches", "SPREAD_WEIGHTINGS", "correlate_pairs", "reference_disagrees", "spectral_spread_px"]

#: the other weightings of the cross-power that :func:`spectral_spread_px` compares the shift with
#: (keywords of :func:`gcpmatch.phase.phase_correlate`): pure phase correlation (every frequency
#: whitened: the shift read from edges and fine detail) and a low-passed, barely whitened one (read
#: from the coarse pattern); the default ``eps = 0.5`` sits between them
SPREAD_WEIGHTINGS = ({"eps": 0.01, "lowpass": None}, {"eps": 1.0, "lowpass": 0.15})

_PHASE_REASON = {Reject.OK: "", Reject.FLAT: "flat", Reject.NOT_FINITE: "not_finite",
                 Reject.OUT_OF_RANGE: "out_of_range", Reject.LOW_SCORE: "low_score",
                 Reject.LOW_PEAK_RATIO: "low_peak_ratio"}


@dataclass(frozen=True)
class PairMatches:
    """Result of :func:`correlate_pairs` for ``n`` window pairs.

    Attributes
    ----------
    shift_px : ndarray of float64, shape (n, 2)
        Scene minus reference shift ``(row, col)``, pixels (the :mod:`gcpmatch.phase` sign).
    status : ndarray of object (str), shape (n,)
        ``""`` for a match, else the phase-correlation rejection (``flat``, ``not_finite``,
        ``out_of_range``, ``low_score``, ``low_peak_ratio``).
    quality : dict of str -> ndarray of float64, shape (n,)
        ``score`` (coherent share of the cross-power, in [0, 1]), ``peak_ratio`` and
        ``mismatch_cr_row_px``, ``mismatch_cr_col_px`` (the Cramer-Rao-shaped sigma per axis with
        the pair's own mismatch as its noise, pixels: :func:`gcpmatch.texture.mismatch_cr_sigma_px`
        of the raw windows at the measured shift; NaN where the shift is not finite or too large, for
        rejected pairs, and for all when ``options`` does not use it: ``sigma_model`` other than
        ``"window"`` or ``mismatch_sigma_scale`` 0); ``spectral_spread_px`` only with
        ``options.spectral_spread_sigma``, ``options.max_spectral_spread`` or ``options.detect_change``
        (:func:`spectral_spread_px`; NaN for rejected pairs).
    """

    shift_px: np.ndarray
    status: np.ndarray
    quality: dict


def correlate_pairs(reference: np.ndarray, scene: np.ndarray, options: MatchOptions = MatchOptions(), *,
                    phase_options: dict | None = None) -> PairMatches:
    """Phase-correlate window pairs after the options' radiometric preparation.

    Parameters
    ----------
    reference, scene : ndarray of float, shape (n, w, w)
        Reference windows (DOM resampled into scene geometry) and scene windows at the same
        place; finite.
    phase_options : dict, optional
        Further keywords of :func:`gcpmatch.phase.phase_correlate` (``eps``, ``lowpass``, ...),
        for experiments (``bench/bench_matcher_realism.py``).
    options : MatchOptions
        ``radiometry`` (window preparation), ``phase_eps``, ``lowpass_cycles_px``, ``backend``;
        the largest shift accepted is a quarter of the window.

    Returns
    -------
    PairMatches
        Shifts (pixels), statuses and quality figures.
    """
    n, w = reference.shape[0], reference.shape[-1]
    if n == 0:
        empty = {k: np.zeros(0) for k in ("score", "peak_ratio", "mismatch_cr_row_px", "mismatch_cr_col_px")}
        return PairMatches(np.zeros((0, 2)), np.zeros(0, dtype=object), empty)
    ref, mov = prepare_windows(reference, scene, method=options.radiometry)
    kwargs = {"eps": options.phase_eps, "lowpass": options.lowpass_cycles_px, **(phase_options or {})}
    if options.backend == "cpu":
        kwargs.setdefault("workers", options.thread_count())
    pm = phase_correlate(ref, mov, max_shift_px=w / 4.0,
                         backend="torch" if options.backend in ("gpu", "torch") else "cpu",
                         device="cuda" if options.backend == "gpu" else None, **kwargs)
    status = np.array([_PHASE_REASON[Reject(r)] for r in pm.reason], dtype=object)
    # the sigma model's texture term, for the matched pairs of a model that uses it
    cr = np.full((n, 2), np.nan)
    matched = status == ""
    if options.sigma_model == "window" and options.mismatch_sigma_scale > 0.0 and matched.any():
        cr[matched] = mismatch_cr_sigma_px(reference[matched], scene[matched], pm.shift_px[matched],
                                           threads=options.thread_count())
    quality = {"score": pm.score, "peak_ratio": pm.peak_ratio,
               "mismatch_cr_row_px": cr[:, 0], "mismatch_cr_col_px": cr[:, 1]}
    if options.spectral_spread_sigma or options.max_spectral_spread > 0.0 or options.detect_change:
        spread = np.full(n, np.nan)
        if matched.any():
            spread[matched] = spectral_spread_px(ref[matched], mov[matched], pm.shift_px[matched],
                                                 max_shift_px=w / 4.0, **{k: v for k, v in kwargs.items()
                                                                          if k not in ("eps", "lowpass")})
        quality["spectral_spread_px"] = spread
    return PairMatches(shift_px=pm.shift_px, status=status, quality=quality)


def spectral_spread_px(reference: np.ndarray, moving: np.ndarray, shift_px: np.ndarray, *, max_shift_px: float,
                       **phase_options) -> np.ndarray:
    """How far each pair's shift moves under the other weightings of :data:`SPREAD_WEIGHTINGS`, pixels.

    Where scene and reference show the same ground the same way, every weighting of the
    cross-power finds the same shift up to noise. Where the reference shows it otherwise
    (another band: contrast inverted over some fields; another date: fields changed, water
    moved), the fine detail and the coarse pattern disagree, and the shift depends on which
    frequencies are trusted: that disagreement is a lower bound of the pair's error, seen in the
    pair itself (no constant fitted to a scene).

    ``spread^2 = 1/2 sum_w |d_w|^2``, with ``d_w`` the (row, col) shift under weighting ``w``
    minus ``shift_px``: the rms over the two axes of the root sum of squares over the
    weightings. The other estimates are read whatever their score (a low score is what a
    changed pair gives); one that is not finite or beyond ``max_shift_px`` counts as a difference
    of ``max_shift_px``.

    Parameters
    ----------
    reference, moving : ndarray, shape (n, h, w)
        The prepared window pairs (as phase-correlated).
    shift_px : ndarray, shape (n, 2)
        Their shift under the matcher's own weighting, pixels.
    max_shift_px : float
        Largest shift accepted, pixels.
    **phase_options
        Further keywords of :func:`gcpmatch.phase.phase_correlate` (backend, device, workers).

    Returns
    -------
    ndarray of float64, shape (n,)
        The spread, pixels per axis.
    """
    total = np.zeros(reference.shape[0])
    for weighting in SPREAD_WEIGHTINGS:
        other = phase_correlate(reference, moving, max_shift_px=max_shift_px, **phase_options, **weighting)
        d2 = np.sum((other.shift_px - shift_px) ** 2, axis=1)
        found = np.isfinite(d2) & (np.abs(other.shift_px) <= max_shift_px).all(axis=1)
        total += np.where(found, d2, max_shift_px**2)
    return np.sqrt(0.5 * total)


def reference_disagrees(spread_px: np.ndarray, score: np.ndarray, *, window_px: int = 64) -> tuple[bool, float]:
    """Whether most window pairs of a scene disagree with themselves beyond their own noise.

    Each matched pair's spectral spread (:func:`spectral_spread_px`) is divided by the matching
    noise its score predicts (:func:`gcpmatch.uncertainty.score_sigma_px`), the quantity that
    ``MatchOptions.max_spectral_spread`` tests per pair. Against a faithful reference most pairs
    lie below 1; against a reference that shows the ground otherwise (another band, season or
    sensor) most lie above (docs/matching.md, "What limits matching across the bands": scene
    medians 0.46-0.58 against the scene's own Sentinel-2 band, 1.10-1.34 across red and
    near-infrared). The median over the whole scene decides; no constant is fitted: 1 is the
    pair's own predicted noise.

    Parameters
    ----------
    spread_px : ndarray of float, shape (n,)
        Spectral spread of the pairs, pixels (NaN: not matched, left out).
    score : ndarray of float, shape (n,)
        Their phase-correlation scores.
    window_px : int
        Window side, pixels.

    Returns
    -------
    disagrees : bool
        The median ratio exceeds 1 (False without a matched pair).
    median_ratio : float
        The median of spread over predicted noise (NaN without a matched pair).
    """
    spread_px, score = np.asarray(spread_px, dtype=float), np.asarray(score, dtype=float)
    ok = np.isfinite(spread_px) & np.isfinite(score)
    if not ok.any():
        return False, float("nan")
    median = float(np.median(spread_px[ok] / score_sigma_px(score[ok], window_px=window_px)))
    return median > 1.0, median
