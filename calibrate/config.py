"""Every stage's options as frozen, validated values: the one home of gcpcal's defaults.

The command line takes its defaults from these classes (``calibrate/cli/``), the stage actions
pass them down (``calibrate/actions/``), and the library functions take one options value
instead of long keyword lists. An option that is out of range raises
:class:`~sensor_models.errors.InputError` naming the field when the value is built, so a bad
setting fails before any computation.

=====================  ======================================  =================================
class                  used by                                  defined in
=====================  ======================================  =================================
``MatchOptions``       dense GCP extraction (``gcpcal match``)  :mod:`gcpmatch.options` (matching
                                                                is below ``calibrate`` in the
                                                                layers; re-exported here)
``CalibrationOptions`` :func:`calibrate.absolute.calibrate_model`  here
``StarOptions``        star-track calibration (``gcpcal stars``) here
``OrthoOptions``       orthorectification (``gcpcal ortho``)    here
=====================  ======================================  =================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from gcpmatch.options import MatchOptions
from sensor_models.errors import InputError
from sensor_models.files.threads import parse_threads

__all__ = [
    "ATTITUDE_MODES",
    "CALIBRATION_SCHEMES",
    "CalibrationOptions",
    "MatchOptions",
    "ORTHO_RESAMPLING",
    "OrthoOptions",
    "ROBUST_LOSSES",
    "STAR_CENTROIDS",
    "STAR_SCHEMES",
    "StarOptions",
]

#: Parameter groups and their order (seed 002's schemes: ECO, ICO, ECBIC, ICBEC, joint).
CALIBRATION_SCHEMES = ("exterior", "interior", "exterior-interior", "interior-exterior", "joint")
#: Time-varying attitude of a push-broom calibration (:mod:`calibrate.attitude`).
ATTITUDE_MODES = ("static", "drift", "spline", "auto")
#: Robust losses of the least-squares solver (:mod:`calibrate.lsq`).
ROBUST_LOSSES = ("cauchy", "huber", "none")
#: Star-track calibration schemes (seed 000).
STAR_SCHEMES = ("exterior-interior", "exterior", "joint")
#: Star centroid estimators (seed 000 eq. 1, Gaussian fit, windowed).
STAR_CENTROIDS = ("iwc", "gaussian", "windowed")
#: Orthoimage resampling kernels.
ORTHO_RESAMPLING = ("nearest", "bilinear", "cubic")


def _choice(value, allowed, name):
    if value not in allowed:
        raise InputError(f"{name} must be one of {', '.join(allowed)}, got {value!r}", field=name)


def _positive(value, name, *, allow_zero=False, allow_inf=False):
    ok = (value >= 0 if allow_zero else value > 0) and (allow_inf or math.isfinite(value))
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"{name} must be {bound}, got {value!r}", field=name)


def _east_north_m(value, name: str = "reference_sigma_m") -> tuple[float, float]:
    """A pair of metres >= 0 (``(east, north)``) from one number or a pair."""
    try:
        v = [float(x) for x in (value if isinstance(value, (tuple, list)) else (value, value))]
    except (TypeError, ValueError):
        v = []
    if len(v) != 2 or not all(math.isfinite(x) and x >= 0.0 for x in v):
        raise InputError(f"{name} must be one or two finite numbers of metres >= 0, got {value!r}", field=name)
    return v[0], v[1]


class _Options:
    """Shared behaviour: ``replace`` with validation and a plain ``dict`` for JSON summaries."""

    def replace(self, **changes):
        """A copy with ``changes`` applied (validated like a new value)."""
        unknown = sorted(set(changes) - {f.name for f in fields(self)})
        if unknown:
            raise InputError(f"unknown option {unknown[0]!r} of {type(self).__name__}", field=unknown[0])
        return replace(self, **changes)

    def as_dict(self) -> dict:
        """The options as a JSON-ready mapping (field name -> value)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class CalibrationOptions(_Options):
    """Options of :func:`calibrate.absolute.calibrate_model`.

    Attributes
    ----------
    scheme : {"exterior-interior", "interior-exterior", "exterior", "interior", "joint"}
        Which parameter groups are estimated, in which order (seed 002's ECBIC, ICBEC, ECO, ICO
        and the joint solve; seed 003 2.2.1 uses exterior then interior).
    robust : {"cauchy", "huber", "none"}
        Robust loss of the iteratively reweighted least squares.
    interior_terms : int or tuple of str
        Polynomial terms of the directional angles estimated per CCD (``3``: c0..c3 of both
        ``tan(psi_x)`` and ``tan(psi_y)``), or explicit coefficient names.
    parameters : tuple of str or None
        Estimate exactly these parameters (overrides ``scheme``'s groups); None: the scheme's.
    max_outer, outer_tol : int, float
        Exterior/interior alternations and their stop on the change of the planar RMS, px.
    max_iter, tol : int, float
        Gauss-Newton/Levenberg-Marquardt iterations per step and the stop on the largest
        parameter update, in units of its standard deviation.
    reference_ccd : (band, ccd) or None
        The CCD whose interior is held (gauge) in a joint solve; None: the first CCD.
    gauge_sigma_px, gauge : float, bool
        Pseudo-observation (pixels) that fixes the gauge freedom between exterior and interior
        in joint solves, and whether it is used.
    min_points_factor, min_span_fraction : float
        A group is estimable with at least ``min_points_factor`` points per parameter spread
        over ``min_span_fraction`` of its detector array.
    max_condition : float
        Largest accepted condition number of the scaled normal matrix.
    outlier_threshold : float
        Residuals above this many robust sigmas are flagged as outliers.
    max_extrapolation : float
        Largest fraction of an array's length a point may lie outside it and still be used.
    chunk_points : int
        Points per chunk when the normal equations are accumulated (bounds memory).
    attitude : {"static", "drift", "spline", "auto"}
        Time-varying attitude correction of a push-broom model, estimated with the exterior:
        none, a drift (rate, quadratic), a cubic B-spline in time, or the best of all of them
        by BIC (:mod:`calibrate.attitude`; ``"static"`` for other model kinds).
    attitude_yaw_sigma_urad : float or None
        Prior on the yaw of the time-varying correction: every yaw coefficient gets the
        pseudo-observation ``0 +- attitude_yaw_sigma_urad`` (e.g. the star tracker's noise
        level), because a narrow field of view observes yaw weakly (docs/attitude.md). None:
        the weak ridge of every axis (``calibrate.attitude.REGULARIZATION_SIGMA_RAD``).
    reference_sigma_m : (float, float) or None
        Geolocation accuracy of the reference the GCPs' ground coordinates come from, metres
        (1 sigma east, north; a single number is both): its common shift is propagated into
        the parameters' covariance (:mod:`calibrate.reference_covariance`). None: no such term.
    reference_field_m : (float, float) or None
        The part of that error that is a smooth field rather than one common shift: its rms per
        axis and correlation length ``l`` (``rho(r) = exp(-r^2 / (2 l^2))``), metres. The common
        part is then ``sqrt(reference_sigma_m^2 - rms^2)``, and the field adds
        ``sum_ij G_i K_ij G_j^T`` (:func:`calibrate.reference_covariance.field_covariance`).
        None: the whole stated accuracy is one common shift.
    reference_source : str or None
        Where ``reference_sigma_m`` comes from (e.g. the match summary's source), for
        ``calibration.json``; None: ``"option"``.
    covariance_floor : bool or None
        Scale each step's covariance by ``max(1, sigma0^2)`` (True) rather than ``sigma0^2``
        (False); None: True when the GCP table states ``sigma_px`` (any value other than the
        default 1, which means unit weights with the scale left to the variance factor).
    score_weight : bool
        Weight each GCP by ``score / sigma_px^2`` (True) or by ``1 / sigma_px^2`` (False: for
        ``sigma_px`` from the matcher's ``window`` model, which already holds the score); a
        score of 0 drops the point either way.
    """

    scheme: str = "exterior-interior"
    robust: str = "cauchy"
    interior_terms: int | tuple[str, ...] = 3
    parameters: tuple[str, ...] | None = None
    max_outer: int = 10
    outer_tol: float = 0.1
    max_iter: int = 20
    tol: float = 0.1
    reference_ccd: tuple[str, str] | None = None
    gauge_sigma_px: float = 1e-3
    gauge: bool = True
    min_points_factor: float = 3.0
    min_span_fraction: float = 0.5
    max_condition: float = 1e10
    outlier_threshold: float = 3.0
    max_extrapolation: float = 0.1
    chunk_points: int = 50_000
    attitude: str = "auto"
    attitude_yaw_sigma_urad: float | None = None
    reference_sigma_m: tuple[float, float] | None = None
    reference_field_m: tuple[float, float] | None = None
    reference_source: str | None = None
    covariance_floor: bool | None = None
    score_weight: bool = True

    def __post_init__(self):
        _choice(self.scheme, CALIBRATION_SCHEMES, "scheme")
        if self.attitude_yaw_sigma_urad is not None:
            _positive(self.attitude_yaw_sigma_urad, "attitude_yaw_sigma_urad")
        if self.reference_sigma_m is not None:
            object.__setattr__(self, "reference_sigma_m", _east_north_m(self.reference_sigma_m))
        if self.reference_field_m is not None:
            field = _east_north_m(self.reference_field_m, "reference_field_m")
            if field[1] <= 0.0:
                raise InputError("reference_field_m needs a correlation length > 0 m", field="reference_field_m")
            object.__setattr__(self, "reference_field_m", field)
        _choice(self.robust, ROBUST_LOSSES, "robust")
        _choice(self.attitude, ATTITUDE_MODES, "attitude")
        if not isinstance(self.interior_terms, int):
            object.__setattr__(self, "interior_terms", tuple(self.interior_terms))
        elif self.interior_terms < 0:
            raise InputError(f"interior_terms must be >= 0, got {self.interior_terms}", field="interior_terms")
        if self.parameters is not None:
            object.__setattr__(self, "parameters", tuple(self.parameters))
        if self.reference_ccd is not None:
            object.__setattr__(self, "reference_ccd", tuple(self.reference_ccd))
        for name in ("max_outer", "max_iter", "chunk_points"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be >= 1, got {getattr(self, name)}", field=name)
        for name in ("outer_tol", "tol", "gauge_sigma_px", "min_points_factor", "max_condition",
                     "outlier_threshold"):
            _positive(getattr(self, name), name)
        _positive(self.max_extrapolation, "max_extrapolation", allow_zero=True, allow_inf=True)
        if not 0.0 <= self.min_span_fraction <= 1.0:
            raise InputError(f"min_span_fraction must lie in [0, 1], got {self.min_span_fraction}",
                             field="min_span_fraction")


@dataclass(frozen=True)
class StarOptions(_Options):
    """Options of the star-track calibration (:func:`calibrate.star_calibration.process_frames`, seed 000).

    Attributes
    ----------
    catalog : str
        Star catalogue name (``"hipparcos"``).
    mag_limit : float or None
        Faintest catalogue magnitude loaded; None: the whole catalogue.
    threshold_sigma : float
        Detection threshold above the local background, in noise sigmas.
    centroid : {"iwc", "gaussian", "windowed"}
        Centroid estimator (seed 000 eq. 1 intensity-weighted centroid, Gaussian fit, windowed).
    search_px, tolerance_px : float
        Identification: search radius around the predicted position and match tolerance, px.
    min_track_points : int
        Shortest track (frames) kept.
    n_check : int
        Points of each track held out as check points (never fitted).
    smooth : bool
        Smooth each track with a smoothing spline before fitting (seed 000 2.2).
    reject_px, reject_sigma : float
        Track points farther than ``reject_px`` and ``reject_sigma`` robust sigmas from their
        spline are rejected.
    scheme : {"exterior-interior", "exterior", "joint"}
        Stepwise exterior then interior (seed 000 eq. 12-17), exterior only, or joint.
    compare_joint : bool
        Also run the joint solve and report it beside the chosen scheme.
    interior_degree : int
        Degree of the estimated interior polynomials (3: the 20 coefficients).
    interior_prior_px : float or None
        Prior (px at the frame edge) holding the interior coefficients at their initial values.
    robust : {"huber", "cauchy", "none"}
        Robust loss.
    seed : int
        Seed of the choice of held-out points.
    """

    catalog: str = "hipparcos"
    mag_limit: float | None = 10.5
    threshold_sigma: float = 5.0
    centroid: str = "iwc"
    search_px: float = 120.0
    tolerance_px: float = 4.0
    min_track_points: int = 12
    n_check: int = 5
    smooth: bool = True
    reject_px: float = 0.5
    reject_sigma: float = 4.0
    scheme: str = "exterior-interior"
    compare_joint: bool = True
    interior_degree: int = 3
    interior_prior_px: float | None = 20.0
    robust: str = "huber"
    seed: int = 0

    def __post_init__(self):
        _choice(self.centroid, STAR_CENTROIDS, "centroid")
        _choice(self.scheme, STAR_SCHEMES, "scheme")
        _choice(self.robust, ROBUST_LOSSES, "robust")
        for name in ("threshold_sigma", "search_px", "tolerance_px", "reject_px", "reject_sigma"):
            _positive(getattr(self, name), name)
        if self.interior_prior_px is not None:
            _positive(self.interior_prior_px, "interior_prior_px")
        for name in ("min_track_points", "interior_degree"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be >= 1, got {getattr(self, name)}", field=name)
        if self.n_check < 0:
            raise InputError(f"n_check must be >= 0, got {self.n_check}", field="n_check")


@dataclass(frozen=True)
class OrthoOptions(_Options):
    """Options of orthorectification (:func:`sensor_models.imaging.ortho.orthorectify_to_file`).

    Attributes
    ----------
    crs : str or None
        Output CRS (e.g. ``"EPSG:32631"``); None: the UTM zone of the scene centre.
    resolution_m : float or None
        Output pixel size in metres (CRS units); None: the scene's ground sample distance.
    resampling : {"nearest", "bilinear", "cubic"}
        Resampling kernel.
    block : int
        Output block size in pixels (windowed processing bounds memory).
    node_step_px : float
        Spacing of the node grid on which the exact model is evaluated, output pixels.
    check_points : int
        Random output pixels at which the node-grid geometry is checked against the exact model.
    seed : int
        Seed of those check points.
    threads : int
        Blocks computed at once; 0: ``GCPCAL_THREADS`` or every core
        (:func:`sensor_models.files.threads.thread_count`). The output does not depend on it.
    """

    crs: str | None = None
    resolution_m: float | None = None
    resampling: str = "bilinear"
    block: int = 1024
    node_step_px: float = 16.0
    check_points: int = 256
    seed: int = 0
    threads: int = 0

    def __post_init__(self):
        _choice(self.resampling, ORTHO_RESAMPLING, "resampling")
        if self.resolution_m is not None:
            _positive(self.resolution_m, "resolution_m")
        if self.block < 64:
            raise InputError(f"block must be >= 64 pixels, got {self.block}", field="block")
        _positive(self.node_step_px, "node_step_px")
        if self.check_points < 0:
            raise InputError(f"check_points must be >= 0, got {self.check_points}", field="check_points")
        parse_threads(self.threads)

    def to_kwargs(self) -> dict:
        """Keyword arguments of :func:`sensor_models.imaging.ortho.orthorectify_to_file`.

        Returns
        -------
        dict
            Field name -> value.
        """
        return self.as_dict()
