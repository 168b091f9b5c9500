"""Accuracy of a star-calibrated staring camera on held-out track points (seed 000 eq. 18-19).

:func:`radec_errors_px` maps measured centroids to right ascension and declination through a
model with each point's frame attitude and compares them with the catalogue's apparent
positions, in pixels of the LAB IFOV; :func:`radec_accuracy` summarizes them (means, RMS and a
normal fit with its 2-sigma bounds, seed 000 tables 3-4); :func:`error_versus_track_points`
recalibrates with fewer points per track (seed 000 figure 8).
"""

from __future__ import annotations

import numpy as np

from calibrate.star_observations import StarObservations
from calibrate.star_solution import calibrate_tracks
from sensor_models.models.geo_staring import GeoStaringModel, vectors_to_radec

__all__ = ["error_versus_track_points", "radec_accuracy", "radec_errors_px"]


def radec_errors_px(model0: GeoStaringModel, body_to_gcrf, row, col, vectors_gcrf, *, pixel_rad: float):
    """RA and DE errors (seed 000 eq. 18-19) of points measured in frames with given attitude.

    Parameters
    ----------
    model0 : GeoStaringModel
        The model at frame 0 (its camera rotation is reused with each point's attitude).
    body_to_gcrf : ndarray, shape (N, 3, 3)
        Attitude of each point's frame.
    row, col : array_like, shape (N,)
        Measured image points.
    vectors_gcrf : ndarray, shape (N, 3)
        Catalogue apparent directions at the frame instants.
    pixel_rad : float
        Angle of one pixel, ``A / S`` of eq. 19.

    Returns
    -------
    ra_px, de_px, ra_sky_px : ndarray, shape (N,)
        ``(sigma' - sigma) / (A/S)``, ``(delta' - delta) / (A/S)``, and the RA error on the sky
        (multiplied by ``cos delta``).
    """
    v0 = model0.object_vector_gcrf(row, col)  # B0 M l
    cam = v0 @ model0.body_to_gcrf  # rows: (B0^T v0)^T = (M l)^T in the body frame
    v = np.einsum("nij,nj->ni", body_to_gcrf, cam)
    ra1, de1 = vectors_to_radec(v)
    ra0, de0 = vectors_to_radec(vectors_gcrf)
    pix_deg = np.degrees(pixel_rad)
    dra = (ra1 - ra0 + 180.0) % 360.0 - 180.0
    return dra / pix_deg, (de1 - de0) / pix_deg, dra * np.cos(np.radians(de0)) / pix_deg


def radec_accuracy(ra_px, de_px) -> dict:
    """Seed 000's accuracy figures of held-out RA/DE errors (tables 3-4).

    Parameters
    ----------
    ra_px, de_px : ndarray, shape (N,)
        RA and DE errors, pixels (non-finite values are left out).

    Returns
    -------
    dict
        ``n`` and, per ``ra``/``de``: ``mean_px``, ``mean_abs_px``, ``rms_px``, ``max_abs_px`` and,
        with two points or more, the normal fit (``std_px``, ``two_sigma_px``, bounds and
        confidence intervals, :func:`calibrate.accuracy.fit_normal`).
    """
    from calibrate.accuracy import fit_normal

    out = {"n": int(ra_px.size)}
    for name, e in (("ra", ra_px), ("de", de_px)):
        e = e[np.isfinite(e)]
        d = {"mean_px": float(e.mean()) if e.size else None,
             "mean_abs_px": float(np.abs(e).mean()) if e.size else None,
             "rms_px": float(np.sqrt(np.mean(e**2))) if e.size else None,
             "max_abs_px": float(np.abs(e).max()) if e.size else None}
        if e.size >= 2:
            nf = fit_normal(e)
            d.update(std_px=nf.std, two_sigma_px=2.0 * nf.std, two_sigma_bounds_px=list(nf.two_sigma),
                     mean_ci_px=list(nf.mean_ci), std_ci_px=list(nf.std_ci),
                     fraction_within_two_sigma=nf.fraction_within_two_sigma)
        out[name] = d
    return out


def error_versus_track_points(model0, obs: StarObservations, body_to_gcrf_frames, counts, *,
                              scheme="exterior-interior", seed: int = 0, **kw):
    """Seed 000 figure 8: held-out accuracy when each track gives only ``n`` calibration points.

    For each ``n`` in ``counts``, ``n`` of each track's calibration points are drawn at random
    (tracks with fewer keep all), the model is recalibrated and evaluated on the same held-out
    points. Returns a list of ``{"points_per_track", "n_points", "ra_mean_abs_px",
    "de_mean_abs_px", "ra_two_sigma_px", "de_two_sigma_px"}``.

    Parameters
    ----------
    model0 : GeoStaringModel
        Initial model at frame 0.
    obs : StarObservations
        Tracks after smoothing (held-out points marked in ``check``).
    body_to_gcrf_frames : ndarray, shape (F, 3, 3)
        Body-to-GCRF rotation of every frame.
    counts : sequence of int
        Calibration points per track.
    scheme : {"exterior-interior", "exterior", "joint"}
        Of :func:`calibrate.star_solution.calibrate_tracks`.
    seed : int
        Seeds the draws (``seed + 1``).
    **kw
        Further keywords of :func:`calibrate.star_solution.calibrate_tracks`.

    Returns
    -------
    list of dict
        One row per count (errors in pixels).
    """
    rng = np.random.default_rng(seed + 1)
    cal = np.flatnonzero(obs.calibration)
    chk = obs.check
    b_chk = body_to_gcrf_frames[obs.frame[chk]]
    out = []
    for n in counts:
        pick = []
        for hip in np.unique(obs.hip[cal]):
            idx = cal[obs.hip[cal] == hip]
            pick.append(rng.choice(idx, size=min(int(n), idx.size), replace=False))
        pick = np.sort(np.concatenate(pick))
        theta, runs, _ = calibrate_tracks(model0, obs.virtual_gcrf[pick], obs.row_smooth[pick],
                                          obs.col_smooth[pick], scheme=scheme, **kw)
        ra, de, _ = radec_errors_px(model0.with_parameters(theta), b_chk, obs.row[chk], obs.col[chk],
                                    obs.vectors_gcrf[chk], pixel_rad=model0.ifov_rad)
        acc = radec_accuracy(ra, de)
        out.append({"points_per_track": int(n), "n_points": int(pick.size),
                    "success": all(r["success"] for r in runs),
                    "ra_mean_abs_px": acc["ra"]["mean_abs_px"], "de_mean_abs_px": acc["de"]["mean_abs_px"],
                    "ra_two_sigma_px": acc["ra"].get("two_sigma_px"), "de_two_sigma_px": acc["de"].get("two_sigma_px")})
    return out
