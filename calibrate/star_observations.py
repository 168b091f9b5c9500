"""Star tracks: identified points per catalogue star, held-out points and smoothing (seed 000 step 4).

:class:`StarObservations` holds one row per identified point (catalogue id, frame, measured
centroid, smoothed centroid, apparent and virtual directions, held-out and rejected flags).
:func:`smooth_tracks` draws ``n_check`` points per track for the accuracy (seed 000 section
3.2) and smooths the others by a smoothing spline of ``row(t)`` and ``col(t)``
(:func:`smooth_track`, seed 000 eq. 2: :func:`scipy.interpolate.make_smoothing_spline`, the
weight chosen by generalized cross-validation in :mod:`calibrate.spline_gcv`), whose residuals
also reject outliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline

from calibrate.spline_gcv import gcv_weights

__all__ = ["StarObservations", "smooth_track", "smooth_tracks"]


@dataclass
class StarObservations:
    """Identified track points, one row per point (all arrays shape (N,) unless said).

    Attributes
    ----------
    hip : ndarray of int
        Catalogue identifier of the track.
    frame : ndarray of int
    seconds : ndarray
    row, col : ndarray
        Measured centroids.
    row_smooth, col_smooth : ndarray
        Smoothing-spline values (seed 000 eq. 2; NaN for held-out and rejected points).
    vectors_gcrf : ndarray, shape (N, 3)
        Apparent star directions at the frame instants.
    virtual_gcrf : ndarray, shape (N, 3)
        The same carried to frame 0's attitude (seed 000 eq. 9).
    check : ndarray of bool
        Held out for the accuracy.
    rejected : ndarray of bool
        Rejected by the spline residual test.
    """

    hip: np.ndarray
    frame: np.ndarray
    seconds: np.ndarray
    row: np.ndarray
    col: np.ndarray
    row_smooth: np.ndarray
    col_smooth: np.ndarray
    vectors_gcrf: np.ndarray
    virtual_gcrf: np.ndarray
    check: np.ndarray
    rejected: np.ndarray
    flux: np.ndarray

    @property
    def calibration(self) -> np.ndarray:
        """Points used in the fit: not held out, not rejected, smoothed.

        Returns
        -------
        ndarray of bool, shape (N,)
            True for the points the calibration uses.
        """
        return ~self.check & ~self.rejected & np.isfinite(self.row_smooth)

    def select(self, index) -> "StarObservations":
        """The observations picked by index.

        Parameters
        ----------
        index : array_like of int or bool
            Points to keep.

        Returns
        -------
        StarObservations
            Those points, every array indexed alike.
        """
        return StarObservations(**{k: getattr(self, k)[index] for k in self.__dataclass_fields__})


def smooth_track(t, y, good, smooth: bool) -> np.ndarray:
    """Smoothed ``y`` (n, 2) of one track at times ``t`` fitted on the ``good`` points.

    A straight line in time is removed first (the drift at the sidereal rate), then each
    coordinate's remainder is fitted by a cubic smoothing spline on normalized time with the
    weight chosen by generalized cross-validation (seed 000 eq. 2; the weight from
    :func:`calibrate.spline_gcv.gcv_weights`); fewer than 5 points, or ``smooth=False``, keep
    the straight line.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Times of the track's points, seconds.
    y : ndarray, shape (n, 2)
        Their ``(row, col)`` centroids, pixels.
    good : ndarray of bool, shape (n,)
        Points the fit uses.
    smooth : bool
        Add the smoothing spline to the straight line.

    Returns
    -------
    ndarray, shape (n, 2)
        Smoothed ``(row, col)`` at every time ``t``, pixels.
    """
    tg = t[good]
    coef = np.polyfit(tg, y[good], 1)
    line = t[:, None] * coef[0] + coef[1]
    if not smooth or tg.size < 5:
        return line
    span = max(float(tg.max() - tg.min()), 1e-9)
    x = (t - tg.min()) / span
    out = line.copy()
    rest = (y - line)[good]
    lam = gcv_weights(x[good], rest)  # the GCV weight make_smoothing_spline(lam=None) would pick
    for j in range(y.shape[1]):
        spl = make_smoothing_spline(x[good], rest[:, j], lam=lam[j])
        out[:, j] += spl(x)
    return out


def smooth_tracks(obs: StarObservations, rng, *, n_check: int, min_points: int, reject_px: float,
                   reject_sigma: float, smooth: bool):
    """Hold out ``n_check`` points per track, smooth the rest (eq. 2), reject outliers.

    Parameters
    ----------
    obs : StarObservations
        Identified points of every track; its ``check``, ``rejected``, ``row_smooth`` and
        ``col_smooth`` are filled in place.
    rng : numpy.random.Generator
        Draws the held-out points.
    n_check : int
        Points held out per track (seed 000: five).
    min_points : int
        Tracks with fewer points are skipped.
    reject_px, reject_sigma : float
        A point is rejected when its spline residual exceeds
        ``max(reject_px, reject_sigma * robust sigma)``, pixels.
    smooth : bool
        Smoothing spline (True) or straight line (False), :func:`smooth_track`.

    Returns
    -------
    obs : StarObservations
        The points of the kept tracks.
    records : list of dict
        Per track: HIP id, points, held out, rejected, spline RMS (or why it was skipped).
    """
    keep_rows, records = [], []
    for hip in np.unique(obs.hip):
        idx = np.flatnonzero(obs.hip == hip)
        idx = idx[np.argsort(obs.seconds[idx])]
        rec = {"hip": int(hip), "n_points": int(idx.size)}
        if idx.size < min_points:
            rec["skipped"] = f"{idx.size} points < {min_points}"
            records.append(rec)
            continue
        check = rng.choice(idx.size, size=min(n_check, idx.size - 5), replace=False) if n_check else []
        obs.check[idx[check]] = True
        fit = idx[~obs.check[idx]]
        t = obs.seconds[fit]
        rejected = np.zeros(fit.size, bool)
        for _ in range(2):
            good = ~rejected
            y = np.stack([obs.row[fit], obs.col[fit]], -1)
            res = y - smooth_track(t, y, good, smooth)
            size = np.hypot(res[:, 0], res[:, 1])
            mad = 1.4826 * np.median(size[good]) if good.any() else 0.0
            new = size > max(reject_px, reject_sigma * mad)
            if np.array_equal(new, rejected):
                break
            rejected = new
        obs.rejected[fit] = rejected
        obs.row_smooth[fit] = (y - res)[:, 0]
        obs.col_smooth[fit] = (y - res)[:, 1]
        obs.row_smooth[fit[rejected]] = np.nan
        obs.col_smooth[fit[rejected]] = np.nan
        good = ~rejected
        rec.update(n_calibration=int(good.sum()), n_check=int(len(check)), n_rejected=int(rejected.sum()),
                   spline_rms_px=float(np.sqrt(np.mean(size[good] ** 2))) if good.any() else None,
                   row_mean_px=float(obs.row[idx].mean()),
                   col_span_px=[float(obs.col[idx].min()), float(obs.col[idx].max())])
        records.append(rec)
        keep_rows.append(idx)
    keep = np.concatenate(keep_rows) if keep_rows else np.zeros(0, dtype=np.intp)
    return obs.select(keep), records
