"""One staring-camera calibration from star tracks of several sessions (seed 000 section 3.2).

Seed 000 observes the stars for 20 minutes at one time of day on 20 consecutive days and
verifies the model on the 437 tracks of all days together. :func:`calibrate.star_calibration.process_frames`
calibrates one session (one frame sequence) at a time; this module pools the tracks of several
sessions of one camera into one installation and interior, and scores every session's held-out
points with it. Whatever changed between the days (the thermal state of the installation at that
time of day) then shows in the held-out errors instead of being absorbed session by session.

Pooling (seed 000 eq. 9 applied across sessions). A session ``d`` carries its calibration points
as virtual stars ``w'_d = B0_d M l(row, col)`` of its frame 0, whose body-to-GCRF attitude is
``B0_d``; ``M`` is the installation and ``l`` the interior line of sight. Rotating them into the
frame 0 of the first session,

    w'' = B0_1 B0_d^T w'_d = B0_1 M l(row, col),

gives points that the first session's frame-0 model images at the same pixels, so
:func:`calibrate.star_solution.calibrate_tracks` solves one ``M`` and ``l`` from all of them. The GEO
orbit does not enter: the apparent directions of the catalogue stars already hold the aberration
of each frame's velocity.

Scoring. A held-out point of session ``d`` (frame ``k``, attitude ``B_k``) is mapped by the
pooled model to ``B_k M l(row, col)`` and compared with its catalogue direction
(:func:`calibrate.star_accuracy.radec_errors_px`, seed 000 eq. 18-19).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibrate.config import StarOptions
from calibrate.star_accuracy import radec_accuracy, radec_errors_px
from calibrate.star_calibration import StarCalibrationResult
from calibrate.star_observations import StarObservations
from calibrate.star_solution import calibrate_tracks
from sensor_models.errors import InputError
from sensor_models.models.geo_staring import GeoStaringModel

__all__ = ["StarSession", "calibrate_pooled"]


@dataclass
class StarSession:
    """The tracks of one session, ready to pool.

    Attributes
    ----------
    lab_model : GeoStaringModel
        The session's LAB model at its frame 0 (the model :func:`process_frames` started from).
    body_to_gcrf : ndarray, shape (F, 3, 3)
        Measured body-to-GCRF attitude of every frame of the session.
    observations : StarObservations
        Its smoothed tracks with the held-out points marked (``process_frames``'s).
    """

    lab_model: GeoStaringModel
    body_to_gcrf: np.ndarray
    observations: StarObservations

    @classmethod
    def from_result(cls, result: StarCalibrationResult, lab_model: GeoStaringModel, seconds) -> "StarSession":
        """The session of a :func:`calibrate.star_calibration.process_frames` run.

        Parameters
        ----------
        result : StarCalibrationResult
            The session's own calibration (its ``observations`` are used, not its parameters).
        lab_model : GeoStaringModel
            The LAB model given to ``process_frames``.
        seconds : array_like, shape (F,)
            The frame instants given to ``process_frames``, seconds after the model's epoch.

        Returns
        -------
        StarSession
        """
        if result.observations is None:
            raise InputError("the session has no track observations", field="observations")
        t = np.asarray(seconds, dtype=np.float64).reshape(-1)
        if result.frame_seconds is not None and np.array_equal(result.frame_seconds, t):
            # the run's own rotations (the same model at the same instants)
            return cls(lab_model.at_frame(float(t[0])), result.frame_body_to_gcrf, result.observations)
        frames = [lab_model.at_frame(float(s)) for s in t]
        return cls(frames[0], np.stack([m.body_to_gcrf for m in frames]), result.observations)


def _pooled_points(sessions: list) -> tuple:
    """Calibration points of every session carried into the first session's frame 0."""
    b0_ref = sessions[0].lab_model.body_to_gcrf
    virtual, row, col = [], [], []
    for s in sessions:
        o, cal = s.observations, s.observations.calibration
        rotation = b0_ref @ s.lab_model.body_to_gcrf.T  # B0_1 B0_d^T
        virtual.append(o.virtual_gcrf[cal] @ rotation.T)
        row.append(o.row_smooth[cal])
        col.append(o.col_smooth[cal])
    return np.concatenate(virtual), np.concatenate(row), np.concatenate(col)


def _held_out_errors(model: GeoStaringModel, session: StarSession) -> tuple:
    """RA and DE errors (pixels) of a session's held-out points under ``model``."""
    o = session.observations
    chk = o.check
    ra, de, _ = radec_errors_px(model, session.body_to_gcrf[o.frame[chk]], o.row[chk], o.col[chk],
                                o.vectors_gcrf[chk], pixel_rad=model.ifov_rad)
    return ra, de


def calibrate_pooled(sessions, *, options: StarOptions = StarOptions()) -> dict:
    """Calibrate one installation and interior from the tracks of several sessions; score each.

    Parameters
    ----------
    sessions : sequence of StarSession
        Sessions of one camera (same LAB installation and interior), any dates.
    options : StarOptions
        ``scheme``, ``interior_degree``, ``interior_prior_px`` and ``robust`` of
        :func:`calibrate.star_solution.calibrate_tracks`.

    Returns
    -------
    dict
        ``success``, ``message``, ``sessions``, ``calibration_points``, ``parameters``
        (name -> value over the first session's parameter names), ``runs`` (the least-squares
        steps), ``before`` and ``after`` (:func:`calibrate.star_calibration` accuracy dicts of every held-out
        point of every session: LAB and pooled model), ``per_session`` (mean absolute RA/DE
        error after, pixels, and the point count of each session).

    Raises
    ------
    InputError
        No session, or sessions of different cameras (image shape or LAB parameters differ).
    """
    sessions = list(sessions)
    if not sessions:
        raise InputError("no session to pool", field="sessions")
    ref = sessions[0].lab_model
    for k, s in enumerate(sessions[1:], start=1):
        same = (s.lab_model.image_shape == ref.image_shape
                and np.allclose(s.lab_model.parameters().values, ref.parameters().values, rtol=0.0, atol=1e-12))
        if not same:
            raise InputError(f"session {k} is not of the first session's camera (LAB model differs)",
                             field="sessions")
    virtual, row, col = _pooled_points(sessions)
    if virtual.shape[0] < 5:
        return {"success": False, "message": f"only {virtual.shape[0]} usable track points in all sessions",
                "sessions": len(sessions), "calibration_points": int(virtual.shape[0])}
    theta, runs, _ = calibrate_tracks(ref, virtual, row, col, scheme=options.scheme,
                                      interior_degree=options.interior_degree,
                                      interior_prior_px=options.interior_prior_px, robust=options.robust)
    pooled = ref.with_parameters(theta)
    before = [_held_out_errors(ref, s) for s in sessions]
    after = [_held_out_errors(pooled, s) for s in sessions]
    success = all(r["success"] for r in runs)
    return {
        "success": success,
        "message": "calibrated" if success else f"a {runs[-1]['step']} step failed: {runs[-1]['message']}",
        "sessions": len(sessions),
        "calibration_points": int(virtual.shape[0]),
        "parameters": {n: float(v) for n, v in zip(ref.parameter_names(), theta)},
        "runs": runs,
        "before": radec_accuracy(np.concatenate([b[0] for b in before]), np.concatenate([b[1] for b in before])),
        "after": radec_accuracy(np.concatenate([a[0] for a in after]), np.concatenate([a[1] for a in after])),
        "per_session": [{"n": int(ra.size), "ra_mean_abs_px": float(np.abs(ra).mean()) if ra.size else None,
                         "de_mean_abs_px": float(np.abs(de).mean()) if de.size else None} for ra, de in after],
    }
