"""Calibration of a geostationary staring camera from the relative motion of stars (seed 000).

With an Earth-fixed pointing from GEO the stars drift across consecutive frames at about
15 arcsec/s. Each star leaves a *track* of centroids; because the camera geometry is constant
over the sequence, every track point is an independent observation of the same camera, which
gives many object vectors even with a single star per frame (seed 000 section 2.3.1).

Pipeline (:func:`process_frames`)
---------------------------------
1. **Detection** in every frame (:func:`gcpmatch.star_tracks.detect_stars`; seed 000 eq. 1 is the
   intensity-weighted centroid, ``centroid="iwc"``).
2. **Prediction** of the catalogue stars in every frame with the approximate (LAB) model at the
   frame instant: apparent directions (:func:`sensor_models.geometry.star_catalogue.apparent_directions`, with
   the satellite's GCRF position and velocity), projected by ``star_to_image``.
3. **Identification**: a global offset vote over every (detection - prediction) pair closer
   than ``search_px`` in all frames (the LAB model's error is the same in every frame: tens of
   pixels), then mutual nearest neighbours within ``tolerance_px`` after that offset.
4. **Tracks**: the points of one catalogue star (HIP id) across frames. Per track, five points
   (``n_check``) are drawn at random and held out for the accuracy (seed 000 section 3.2); the
   others are smoothed by a smoothing spline of ``row(t)`` and ``col(t)`` (seed 000 eq. 2:
   :func:`scipy.interpolate.make_smoothing_spline`, the weight ``lambda = (1-p)/p`` chosen by
   generalized cross-validation), whose residuals also reject outliers.
5. **Object vectors** (seed 000 eq. 8-9): the apparent direction ``P_s`` of the star at the
   instant of its frame ``k`` is carried into the body frame with that frame's attitude and
   orbit, ``OV = R_body<-gcrf(t_k) P_s``. Mapping it back with the attitude of frame 0 gives a
   *virtual star* ``w' = R_gcrf<-body(t_0) OV`` that frame 0 would image at the same pixel
   (eq. 9: ``p'_1`` and ``p_2`` are images of two stars taken at the same time), so a single
   model, the one of frame 0, is calibrated from all points at once.
6. **Calibration** (seed 000 eq. 11-17): image-space residuals ``observed - star_to_image(w')``
   in pixels (eq. 11 multiplied by the interior's 2x2 derivative: the same zero set, weights
   in pixels) minimized by :func:`calibrate.lsq.solve` with the analytic Jacobian
   ``star_jacobian``: first the exterior (installation roll, pitch, yaw; eq. 12-14), then the
   interior (the 20 directional-angle coefficients; eq. 15-17) in the frame fixed by the
   exterior, repeated until the exterior stops moving. A ``joint`` scheme (all parameters with
   the gauge pseudo-observations of :meth:`GeoStaringModel.gauge_rows`) is run for comparison.
   The interior carries a weak prior towards the laboratory values (``interior_prior_px``):
   stars drift along the columns, so all points of one track share nearly one row and terms in
   the rows (``v^2``, ``v^3``...) are only constrained by the spread of the tracks' rows.
7. **Accuracy** on the held-out points (seed 000 eq. 18-19): the model maps the measured
   centroid to a right ascension and declination ``(sigma', delta')`` at the frame instant;
   ``RA_error = sigma' - sigma``, ``DE_error = delta' - delta`` against the catalogue's
   apparent position, converted to pixels by the angle of one pixel ``A / S`` (the LAB IFOV).
   As in the seed the RA error is a difference of right ascensions (not multiplied by
   ``cos delta``; ``ra_error_sky_px`` in the points gives the on-sky value). Means, mean
   absolute values, RMS and a normal fit with its 2-sigma bounds
   (:func:`calibrate.accuracy.fit_normal`, seed 000 table 4) are reported before and after.

Modules
-------
This module runs the pipeline and holds its result (:class:`StarCalibrationResult`); the steps
live in :mod:`calibrate.star_frames` (frame list, frames, detection), :mod:`calibrate.star_identification`
(prediction and identification), :mod:`calibrate.star_observations` (tracks and their smoothing),
:mod:`calibrate.star_solution` (the least squares) and :mod:`calibrate.star_accuracy` (the
held-out errors).

References
----------
Seed 000: on-orbit geometric calibration of a geostationary camera from the relative motion of
stars (equations 1-19, tables 3-4, figure 8).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from calibrate.config import StarOptions
from calibrate.star_accuracy import error_versus_track_points, radec_accuracy, radec_errors_px
from calibrate.star_frames import check_frame_seconds, detect_frames
from calibrate.star_identification import identify, predict_catalog
from calibrate.star_observations import StarObservations, smooth_tracks
from calibrate.star_solution import calibrate_tracks
from sensor_models.errors import InputError
from sensor_models.models.geo_staring import GeoStaringModel

__all__ = ["StarCalibrationResult", "process_frames", "resolve_catalog"]

ARCSEC = np.pi / (180.0 * 3600.0)


# --------------------------------------------------------------------------- result
@dataclass
class StarCalibrationResult:
    """Outcome of :func:`process_frames`; a failed estimation has ``success=False``.

    Attributes
    ----------
    success : bool
    message : str
    scheme : str
    parameter_names : tuple of str
    initial, parameters : ndarray, shape (23,)
        LAB and calibrated values over ``parameter_names``.
    sigma : ndarray or None
        Standard deviations of the last step's free parameters (``sigma_names``).
    accuracy : dict
        ``before`` and ``after`` (and ``joint_after`` when the joint scheme was compared):
        RA/DE mean, mean absolute, RMS, 2-sigma (normal fit) in pixels on the held-out points.
    tracks : list of dict
        Per track: HIP id, points, held out, rejected, spline RMS.
    frames : dict
        Counts: frames, detections, identified, frames without stars, voted offset.
    model : GeoStaringModel
        The calibrated model at frame 0.
    observations : StarObservations
    runs : list of dict
    versus_points : list of dict
        Figure 8: accuracy against the calibration points used per track (when computed).
    timings : dict
    frame_body_to_gcrf : ndarray, shape (F, 3, 3), or None
        The LAB model's body-to-GCRF rotation at each frame instant (the ``B_k`` of seed 000
        eq. 9), as the run computed them.
    frame_seconds : ndarray, shape (F,), or None
        The frame instants, seconds after the model's epoch.
    """

    success: bool
    message: str
    scheme: str
    parameter_names: tuple
    initial: np.ndarray
    parameters: np.ndarray
    sigma: np.ndarray | None
    sigma_names: tuple
    accuracy: dict
    tracks: list
    frames: dict
    model: GeoStaringModel | None = None
    observations: StarObservations | None = None
    runs: list = field(default_factory=list)
    versus_points: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    frame_body_to_gcrf: np.ndarray | None = None
    frame_seconds: np.ndarray | None = None

    def to_dict(self, *, points: bool = False) -> dict:
        """JSON-safe summary (the CLI's stars.json).

        Parameters
        ----------
        points : bool
            Include the per-point observations and held-out errors (pixels).

        Returns
        -------
        dict
            JSON-ready mapping (angles in radians and arcseconds, errors in pixels).
        """
        corr = (self.parameters - self.initial)
        d = {
            "success": self.success,
            "message": self.message,
            "scheme": self.scheme,
            "parameters": {n: float(v) for n, v in zip(self.parameter_names, self.parameters)},
            "initial_parameters": {n: float(v) for n, v in zip(self.parameter_names, self.initial)},
            "installation_correction_arcsec": {n.split(".")[1]: float(c / ARCSEC)
                                               for n, c in zip(self.parameter_names[:3], corr[:3])},
            "sigma": (None if self.sigma is None else
                      {n: float(s) for n, s in zip(self.sigma_names, self.sigma)}),
            "accuracy": self.accuracy,
            "tracks": self.tracks,
            "frames": self.frames,
            "runs": self.runs,
            "versus_points": self.versus_points,
            "timings": self.timings,
        }
        if points and self.observations is not None:
            o = self.observations
            d["points"] = {"hip": o.hip.tolist(), "frame": o.frame.tolist(), "seconds": o.seconds.tolist(),
                           "row": o.row.tolist(), "col": o.col.tolist(),
                           "row_smooth": np.where(np.isfinite(o.row_smooth), o.row_smooth, None).tolist(),
                           "col_smooth": np.where(np.isfinite(o.col_smooth), o.col_smooth, None).tolist(),
                           "check": o.check.tolist(), "rejected": o.rejected.tolist()}
        return d


# --------------------------------------------------------------------------- pipeline
def resolve_catalog(catalog, mag_limit):
    """A loaded star catalogue: ``catalog`` itself, or the one it names down to ``mag_limit``.

    Parameters
    ----------
    catalog : StarCatalog or str
        A loaded catalogue, or a catalogue name (:meth:`StarCatalog.load`'s ``source``).
    mag_limit : float
        Faintest magnitude loaded when ``catalog`` is a name.

    Returns
    -------
    StarCatalog

    Raises
    ------
    InputError
        ``catalog`` is neither (field ``catalog``).
    """
    from sensor_models.geometry.star_catalogue import StarCatalog

    if isinstance(catalog, StarCatalog):
        return catalog
    if isinstance(catalog, str):
        return StarCatalog.load(source=catalog, mag_limit=mag_limit)
    raise InputError(f"expected a StarCatalog or a catalogue name, got {type(catalog).__name__}", field="catalog")


def process_frames(frames, seconds, lab_model: GeoStaringModel, *, options: StarOptions = StarOptions(),
                   versus_points=None, detections=None) -> StarCalibrationResult:
    """Star-track calibration of a staring camera from a frame sequence (module docstring).

    Parameters
    ----------
    frames : sequence
        Frames: 2-D arrays or paths (FITS, or rasters rasterio reads), in time order.
    seconds : array_like, shape (F,)
        Exposure instants, seconds since ``lab_model``'s epoch; strictly increasing.
    lab_model : GeoStaringModel
        Approximate model (laboratory interior, nominal installation) whose orbit and attitude
        cover every frame; the model of frame ``k`` is ``lab_model.at_frame(seconds[k])``.
    options : StarOptions
        Catalogue (``catalog``, ``mag_limit``), detection (``threshold_sigma``, ``centroid``:
        :func:`gcpmatch.star_tracks.detect_stars`), identification (``search_px``,
        ``tolerance_px``: :func:`calibrate.star_identification.identify`), tracks
        (``min_track_points``, ``n_check`` points held out per track, seed 000: five;
        ``smooth``, ``reject_px``, ``reject_sigma``: the smoothing spline of eq. 2 and its
        outlier test, residual above ``max(reject_px, reject_sigma * robust sigma)``),
        calibration (``scheme``, ``interior_degree``, ``interior_prior_px``, ``robust``:
        :func:`calibrate.star_solution.calibrate_tracks`; ``compare_joint``: also run the joint
        scheme and report its accuracy in ``accuracy["joint_after"]``) and ``seed`` (of the
        held-out points).
    versus_points : sequence of int, optional
        Calibration points per track for the figure 8 study (e.g. ``(10, 15, 20, 25)``).
    detections : list of StarTable, optional
        Precomputed detections (skips step 1).

    Returns
    -------
    StarCalibrationResult

    Raises
    ------
    InputError
        Frames and times disagree, times out of order, an unknown catalogue, no star
        detected in any frame, or no star identified.
    """
    timings = {}
    t0 = time.perf_counter()
    if not isinstance(lab_model, GeoStaringModel):
        raise InputError(f"expected a GeoStaringModel, got {type(lab_model).__name__}", field="lab_model")
    if not isinstance(options, StarOptions):
        raise InputError(f"options must be a StarOptions, got {type(options).__name__}", field="options")
    frames = list(frames)
    t = check_frame_seconds(seconds, len(frames))
    cat = resolve_catalog(options.catalog, options.mag_limit)
    models = [lab_model.at_frame(float(s)) for s in t]
    b_all = np.stack([m.body_to_gcrf for m in models])  # B_k of every frame (seed 000 eq. 9)
    timings["models_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    detections, n_det, empty = _detect_all(frames, lab_model, detections, options)
    timings["detection_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    obs, offset = _identify_all(detections, n_det, models, b_all, cat, t, options)
    timings["identification_s"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    n = obs.hip.size
    rng = np.random.default_rng(options.seed)
    obs, tracks = smooth_tracks(obs, rng, n_check=options.n_check, min_points=options.min_track_points,
                                 reject_px=options.reject_px, reject_sigma=options.reject_sigma,
                                 smooth=options.smooth)  # fmt: skip
    timings["tracks_s"] = time.perf_counter() - t3
    frame_info = {"n_frames": len(frames), "n_detections": int(n_det.sum()), "n_identified": int(n),
                  "frames_without_stars": empty.tolist(), "offset_px": offset.tolist(),
                  "n_tracks": int(np.unique(obs.hip).size), "n_points": int(obs.hip.size),
                  "n_calibration_points": int(obs.calibration.sum()), "n_check_points": int(obs.check.sum())}
    model0 = models[0]
    base = dict(success=False, scheme=options.scheme, parameter_names=model0.parameter_names(),
                initial=model0.parameters().values, sigma=None, sigma_names=(), tracks=tracks, frames=frame_info,
                observations=obs, timings=timings, frame_body_to_gcrf=b_all,
                frame_seconds=t)
    if obs.calibration.sum() < 5:
        return StarCalibrationResult(message=f"only {int(obs.calibration.sum())} usable track points "
                                             f"(tracks of >= {options.min_track_points} points needed)",
                                     parameters=model0.parameters().values, accuracy={}, model=model0, **base)
    return _calibrate_and_score(obs, models, base, options, versus_points, t0)


def _detect_all(frames, lab_model, detections, options):
    """Step 1: detections of every frame (unless given), their counts and the empty frames."""
    if detections is None:
        detections, shapes = detect_frames(frames, threshold_sigma=options.threshold_sigma,
                                           centroid=options.centroid)
        bad = [k for k, s in enumerate(shapes) if tuple(s) != lab_model.image_shape]
        if bad:
            raise InputError(f"frame {bad[0]} has shape {shapes[bad[0]]}, the model {lab_model.image_shape}",
                             field="frames")
    n_det = np.array([len(d) for d in detections])
    empty = np.flatnonzero(n_det == 0)
    if empty.size == len(frames):
        raise InputError(f"no stars detected in any of the {len(frames)} frames")
    return detections, n_det, empty


def _identify_all(detections, n_det, models, b_all, cat, t, options):
    """Steps 2, 3 and 5: predicted stars matched to detections, with their virtual vectors."""
    pred = predict_catalog(models, cat, margin_px=options.search_px)
    pairs, offset = identify(detections, pred, search_px=options.search_px, tolerance_px=options.tolerance_px)
    if pairs.shape[0] == 0:
        raise InputError("no detected star matches a catalogue star; check the manifest's attitude and times")
    k, di, pi = pairs.T
    det_row = np.concatenate([d.row_px for d in detections])
    det_col = np.concatenate([d.col_px for d in detections])
    det_flux = np.concatenate([d.flux for d in detections])
    start = np.r_[0, np.cumsum(n_det)[:-1]]
    flat = start[k] + di
    b0 = models[0].body_to_gcrf
    vec = pred.vectors_gcrf[pi]
    virtual = np.einsum("ij,nkj,nk->ni", b0, b_all[k], vec)  # B0 B_k^T w  (seed 000 eq. 9)
    n = pairs.shape[0]
    obs = StarObservations(
        hip=cat.hip[pred.star[pi]].astype(np.int64), frame=k, seconds=t[k], row=det_row[flat], col=det_col[flat],
        row_smooth=np.full(n, np.nan), col_smooth=np.full(n, np.nan), vectors_gcrf=vec, virtual_gcrf=virtual,
        check=np.zeros(n, bool), rejected=np.zeros(n, bool), flux=det_flux[flat])
    return obs, offset


def _calibrate_and_score(obs, models, base, options, versus_points, t0):
    """Step 6 and the accuracy: calibrate frame 0's model, score it on the held-out points."""
    timings = base["timings"]
    model0 = models[0]
    b_all = base["frame_body_to_gcrf"]
    cal = obs.calibration
    kw = dict(interior_degree=options.interior_degree, interior_prior_px=options.interior_prior_px,
              robust=options.robust)
    t4 = time.perf_counter()
    theta, runs, last = calibrate_tracks(model0, obs.virtual_gcrf[cal], obs.row_smooth[cal], obs.col_smooth[cal],
                                         scheme=options.scheme, **kw)
    timings["calibration_s"] = time.perf_counter() - t4
    calibrated = model0.with_parameters(theta)
    chk = obs.check
    pixel = model0.ifov_rad
    b_chk = b_all[obs.frame[chk]]
    before = radec_errors_px(model0, b_chk, obs.row[chk], obs.col[chk], obs.vectors_gcrf[chk], pixel_rad=pixel)
    after = radec_errors_px(calibrated, b_chk, obs.row[chk], obs.col[chk], obs.vectors_gcrf[chk], pixel_rad=pixel)
    accuracy = {"before": radec_accuracy(before[0], before[1]), "after": radec_accuracy(after[0], after[1])}
    if options.compare_joint and options.scheme != "joint":
        t5 = time.perf_counter()
        theta_j, runs_j, last_j = calibrate_tracks(model0, obs.virtual_gcrf[cal], obs.row_smooth[cal],
                                                   obs.col_smooth[cal], scheme="joint", **kw)
        joint = radec_errors_px(model0.with_parameters(theta_j), b_chk, obs.row[chk], obs.col[chk],
                                obs.vectors_gcrf[chk], pixel_rad=pixel)
        accuracy["joint_after"] = radec_accuracy(joint[0], joint[1])
        accuracy["joint_after"]["success"] = bool(last_j.success)
        timings["joint_s"] = time.perf_counter() - t5
    versus = []
    if versus_points:
        versus = error_versus_track_points(model0, obs, b_all, versus_points, scheme=options.scheme,
                                           seed=options.seed, **kw)
    success = all(r["success"] for r in runs)
    msg = "calibrated" if success else f"a {runs[-1]['step']} step failed: {runs[-1]['message']}"
    base.update(success=success, sigma=last.sigma if last is not None else None,
                sigma_names=tuple(last.names) if last is not None else ())
    timings["total_s"] = time.perf_counter() - t0
    return StarCalibrationResult(message=msg, parameters=theta, accuracy=accuracy, model=calibrated, runs=runs,
                                 versus_points=versus, **base)


