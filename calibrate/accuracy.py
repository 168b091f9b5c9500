"""Accuracy of a calibrated model on independent check points.

Check points are GCPs never used in the fit. For each, the residual is
``e = observed - model.ground_to_image(ground)`` in pixels: ``e_row`` along track (image
lines), ``e_col`` across track (samples), planar ``|e|``. Metres come from the ground
sampling distance: either given per point, or measured on the model as the ground distance
of a one-pixel step in row and in column at the point (on the ellipsoid at its height), so
that the planar error in metres is ``|e_row g_row + e_col g_col|`` with ``g_row, g_col`` the
horizontal ground vectors of a one-pixel step.

Statistics
----------
* absolute RMSE in row, column and plane (pixels and metres) and its mean (bias);
* relative to a reference point ``o`` (seed 003 eq. 4-6): the residuals of the other
  ``n - 1`` points minus that of ``o``, ``dE_oi = e_i - e_o``, and
  ``RMSE = sqrt(sum_i dE_oi^2 / (n - 1))``; this removes a common offset;
* per-CCD and per-band tables (seed 003 table 4);
* histogram with a fitted normal distribution (seed 000 table 4): mean and standard deviation
  with their confidence intervals (Student t and chi-square), the 2-sigma bounds and the
  fraction of residuals inside them;
* error versus the number of GCPs (seed 000 fig. 8): calibrations with random subsets of
  increasing size, scored on the check points.

Everything is returned as plain dataclasses and dicts (``to_dict`` is JSON-safe); plotting is
left to the report module.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats

from calibrate._json import json_safe
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.geometry.geodesy import geodetic_to_ecef

__all__ = [
    "AccuracyReport",
    "AccuracySummary",
    "NormalFit",
    "check_point_accuracy",
    "check_residuals",
    "error_versus_gcp_count",
    "fit_normal",
    "ground_steps",
    "summarize_residuals",
]


# --------------------------------------------------------------------------- result types
@dataclass
class AccuracySummary:
    """RMSE and bias of a set of check-point residuals.

    Attributes
    ----------
    n : int
        Check points with a finite residual.
    rmse_row_px, rmse_col_px, rmse_px : float
        Along track, across track, planar.
    mean_row_px, mean_col_px : float
        Biases.
    max_px : float
        Largest planar residual.
    rmse_row_m, rmse_col_m, rmse_m : float or None
        The same in metres (None without ground sampling distances).
    """

    n: int
    rmse_row_px: float
    rmse_col_px: float
    rmse_px: float
    mean_row_px: float
    mean_col_px: float
    max_px: float
    rmse_row_m: float | None = None
    rmse_col_m: float | None = None
    rmse_m: float | None = None

    def to_dict(self) -> dict:
        """JSON-safe mapping of the fields.

        Returns
        -------
        dict
            JSON-ready mapping of the fields (NaN becomes None).
        """
        return json_safe(asdict(self))


@dataclass
class NormalFit:
    """A normal distribution fitted to residuals, with a histogram (seed 000 table 4).

    Attributes
    ----------
    n : int
    mean, std : float
        Sample mean and standard deviation (``ddof=1``), pixels.
    mean_ci, std_ci : (float, float)
        ``confidence`` intervals: Student t for the mean, chi-square for the deviation.
    confidence : float
    two_sigma : (float, float)
        ``mean -+ 2 std``.
    fraction_within_two_sigma : float
        Observed fraction inside ``two_sigma`` (0.9545 for a normal distribution).
    bin_edges : ndarray, shape (B+1,)
    counts : ndarray, shape (B,)
    normal_counts : ndarray, shape (B,)
        Counts the fitted normal predicts per bin.
    """

    n: int
    mean: float
    std: float
    mean_ci: tuple
    std_ci: tuple
    confidence: float
    two_sigma: tuple
    fraction_within_two_sigma: float
    bin_edges: np.ndarray
    counts: np.ndarray
    normal_counts: np.ndarray

    def to_dict(self) -> dict:
        """JSON-safe mapping of the fields.

        Returns
        -------
        dict
            JSON-ready mapping of the fields (NaN becomes None).
        """
        return json_safe(asdict(self))


@dataclass
class AccuracyReport:
    """Accuracy of a model on check points (see the module docstring).

    Attributes
    ----------
    absolute : AccuracySummary
    relative : AccuracySummary
        Relative to the reference point ``reference_index`` (seed 003 eq. 4-6).
    reference_index : int
    groups : dict of str to AccuracySummary
        Per band and CCD (``"B2.ccd1"``), per band (``"B2"``), for push-broom models.
    histograms : dict of str to NormalFit
        ``"row"`` and ``"col"`` residual distributions.
    residuals_px : ndarray, shape (N, 2)
        Row and column residuals, input order (NaN where the model gives no projection).
    residuals_m : ndarray, shape (N, 3) or None
        Along-track, across-track and planar errors in metres.
    """

    absolute: AccuracySummary
    relative: AccuracySummary
    reference_index: int
    groups: dict = field(default_factory=dict)
    histograms: dict = field(default_factory=dict)
    residuals_px: np.ndarray | None = None
    residuals_m: np.ndarray | None = None

    def to_dict(self, *, points: bool = False) -> dict:
        """JSON-safe summary.

        Parameters
        ----------
        points : bool
            Include the per-point residuals (pixels and metres).

        Returns
        -------
        dict
            JSON-ready mapping: absolute and relative summaries, groups, normal fits.
        """
        out = {
            "absolute": self.absolute.to_dict(),
            "relative": self.relative.to_dict(),
            "reference_index": int(self.reference_index),
            "groups": {k: v.to_dict() for k, v in self.groups.items()},
            "histograms": {k: v.to_dict() for k, v in self.histograms.items()},
        }
        if points:
            out["residuals_px"] = json_safe(self.residuals_px)
            out["residuals_m"] = json_safe(self.residuals_m)
        return out




# --------------------------------------------------------------------------- core statistics
def summarize_residuals(residuals_px, residuals_m=None) -> AccuracySummary:
    """RMSE, bias and maximum of residuals.

    Parameters
    ----------
    residuals_px : array_like, shape (N, 2)
        Row and column residuals in pixels (non-finite rows are ignored).
    residuals_m : array_like, shape (N, 3), optional
        Along-track, across-track and planar errors in metres.

    Returns
    -------
    AccuracySummary
        Counts, RMSE, bias and maximum in pixels (and metres when ``residuals_m`` is given).
    """
    e = np.asarray(residuals_px, dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(e), axis=1)
    e = e[ok]
    n = int(e.shape[0])

    def rms(a):
        return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")

    planar = np.hypot(e[:, 0], e[:, 1])
    out = AccuracySummary(
        n=n,
        rmse_row_px=rms(e[:, 0]),
        rmse_col_px=rms(e[:, 1]),
        rmse_px=rms(planar),
        mean_row_px=float(np.mean(e[:, 0])) if n else float("nan"),
        mean_col_px=float(np.mean(e[:, 1])) if n else float("nan"),
        max_px=float(planar.max()) if n else float("nan"),
    )
    if residuals_m is not None:
        m = np.asarray(residuals_m, dtype=np.float64).reshape(-1, 3)[ok]
        good = np.all(np.isfinite(m), axis=1)
        m = m[good]
        out.rmse_row_m, out.rmse_col_m, out.rmse_m = rms(m[:, 0]), rms(m[:, 1]), rms(m[:, 2])
    return out


def _summary_of(residuals_px, residuals_m, sel):
    return summarize_residuals(residuals_px[sel], None if residuals_m is None else residuals_m[sel])


def _relative(residuals_px, residuals_m, vectors_m, reference):
    """Residuals relative to the reference point (seed 003 eq. 4-5), the reference removed."""
    e = np.asarray(residuals_px, dtype=np.float64)
    keep = np.ones(e.shape[0], dtype=bool)
    keep[reference] = False
    rel_px = (e - e[reference])[keep]
    rel_m = None
    if residuals_m is not None:
        along = residuals_m[:, 0] - residuals_m[reference, 0]
        across = residuals_m[:, 1] - residuals_m[reference, 1]
        if vectors_m is not None:
            planar = np.linalg.norm(vectors_m - vectors_m[reference], axis=1)
        else:
            planar = np.hypot(along, across)
        rel_m = np.stack([along, across, planar], axis=-1)[keep]
    return rel_px, rel_m


def fit_normal(
    residuals, *, confidence: float = 0.95, bins: int | Sequence[float] | str = "auto"
) -> NormalFit:
    """Fit a normal distribution to residuals; confidence intervals and 2-sigma bounds.

    The mean's interval is ``mean -+ t_{(1+c)/2, n-1} std / sqrt(n)``; the standard
    deviation's is ``std sqrt((n-1) / chi2_{(1+c)/2, n-1})`` to
    ``std sqrt((n-1) / chi2_{(1-c)/2, n-1})`` (seed 000 table 4 reports both at 95 %).

    Parameters
    ----------
    residuals : array_like, shape (N,)
        Non-finite values are ignored; at least two are needed.
    confidence : float
        In (0, 1).
    bins : int, sequence or str
        Passed to :func:`numpy.histogram`.

    Returns
    -------
    NormalFit
        Mean, standard deviation, their intervals, 2-sigma bounds and the histogram.
    """
    x = np.asarray(residuals, dtype=np.float64).reshape(-1)
    x = x[np.isfinite(x)]
    n = x.size
    if n < 2:
        raise InputError(f"needs at least 2 finite residuals, got {n}")
    if not 0.0 < confidence < 1.0:
        raise InputError("must be in (0, 1)", field="confidence")
    mean = float(np.mean(x))
    std = float(np.std(x, ddof=1))
    t = stats.t.ppf(0.5 * (1.0 + confidence), n - 1)
    half = t * std / np.sqrt(n)
    chi_hi = stats.chi2.ppf(0.5 * (1.0 + confidence), n - 1)
    chi_lo = stats.chi2.ppf(0.5 * (1.0 - confidence), n - 1)
    std_ci = (std * np.sqrt((n - 1) / chi_hi), std * np.sqrt((n - 1) / chi_lo))
    counts, edges = np.histogram(x, bins=bins)
    if std > 0.0:
        cdf = stats.norm.cdf(edges, loc=mean, scale=std)
        normal_counts = n * np.diff(cdf)
    else:
        normal_counts = np.zeros(counts.size)
    lo, hi = mean - 2.0 * std, mean + 2.0 * std
    return NormalFit(
        n=int(n),
        mean=mean,
        std=std,
        mean_ci=(mean - half, mean + half),
        std_ci=(float(std_ci[0]), float(std_ci[1])),
        confidence=float(confidence),
        two_sigma=(lo, hi),
        fraction_within_two_sigma=float(np.mean((x >= lo) & (x <= hi))),
        bin_edges=edges,
        counts=counts,
        normal_counts=normal_counts,
    )


# --------------------------------------------------------------------------- model-based pieces
def _has_named_arrays(model, band=None) -> bool:
    """Whether the model splits its image into named detector arrays (CCDs): SensorModel protocol."""
    return any(a.name for a in model.detector_arrays(band))


def _model_kwargs(model, band, ccd):
    if _has_named_arrays(model, band):
        return {"band": band, "array": ccd}
    if ccd is not None:
        raise InputError("ccd applies to push-broom models only", field="ccd")
    return {"band": band}


def _band_groups(model, n, band):
    """Point indices per band (one group with band None for single-band models)."""
    if isinstance(band, str) or band is None:
        return {band: np.arange(n)}
    labels = np.asarray(band, dtype=object).reshape(-1)
    if labels.size != n:
        raise InputError(f"has {labels.size} values for {n} check points", field="band")
    return {b: np.nonzero(labels == b)[0] for b in dict.fromkeys(labels)}


def _ccd_of(model, col, band, ccd, sel):
    if not _has_named_arrays(model, band):
        return None
    if ccd is None:
        return model.detector_index(col[sel], band=band).reshape(-1)
    if isinstance(ccd, str) or np.ndim(ccd) == 0:
        return model.detector_index(col[sel], band=band, array=ccd).reshape(-1)
    return np.asarray(ccd).reshape(-1)[sel]


def check_residuals(model, row, col, lon, lat, h, *, band=None, ccd=None):
    """Observed minus modelled image coordinates at check points.

    Parameters
    ----------
    model : SensorModel
    row, col : array_like, shape (N,)
        Observed image coordinates, pixels.
    lon, lat, h : array_like, shape (N,)
        Ground coordinates (WGS84 degrees, metres above the ellipsoid).
    band : str or array_like of str, optional
    ccd : int, str or array_like, optional
        Push-broom CCD per point (default: the CCD whose columns hold ``col``).

    Returns
    -------
    residuals : ndarray, shape (N, 2)
        Row and column residuals in pixels (NaN where the model gives no projection).
    ccd_index : ndarray of int, shape (N,)
        CCD index per point (-1 for models without CCDs).
    """
    row, col, lon, lat, h = _arrays(row, col, lon, lat, h)
    n = row.size
    out = np.full((n, 2), np.nan)
    ccd_index = np.full(n, -1, dtype=np.intp)
    for b, sel in _band_groups(model, n, band).items():
        c_idx = _ccd_of(model, col, b, ccd, sel)
        kw = _model_kwargs(model, b, c_idx)
        r, c = model.ground_to_image(lon[sel], lat[sel], h[sel], **kw)
        out[sel, 0] = row[sel] - r
        out[sel, 1] = col[sel] - c
        if c_idx is not None:
            ccd_index[sel] = c_idx
    return out, ccd_index


def ground_steps(model, row, col, h, *, band=None, ccd=None):
    """Horizontal ground vectors (m) of a one-pixel step in row and in column.

    Central differences of ``model.image_to_ground`` at height ``h``, projected on the local
    east-north plane.

    Parameters
    ----------
    model : SensorModel
        Model whose ``image_to_ground`` is differenced.
    row, col : array_like, shape (N,)
        Image positions, pixels.
    h : array_like, shape (N,)
        Heights above the ellipsoid, metres.
    band : str, optional
        Band of the points (push-broom models).
    ccd : array_like of int, shape (N,), optional
        CCD index of each point (push-broom models).

    Returns
    -------
    g_row, g_col : ndarray, shape (N, 2)
        East and north components, metres per pixel.
    """
    row, col, h = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (row, col, h))
    n = row.size
    g_row = np.full((n, 2), np.nan)
    g_col = np.full((n, 2), np.nan)
    for b, sel in _band_groups(model, n, band).items():
        c_idx = _ccd_of(model, col, b, ccd, sel)
        kw = _model_kwargs(model, b, c_idx)
        r, c, hh = row[sel], col[sel], h[sel]
        pts = [
            model.image_to_ground(r + dr, c + dc, height=hh, **kw)
            for dr, dc in ((-0.5, 0.0), (0.5, 0.0), (0.0, -0.5), (0.0, 0.5))
        ]
        xyz = [geodetic_to_ecef(*p) for p in pts]
        lon0 = np.radians(0.5 * (pts[0][0] + pts[1][0]))
        lat0 = np.radians(0.5 * (pts[0][1] + pts[1][1]))
        east = np.stack([-np.sin(lon0), np.cos(lon0), np.zeros_like(lon0)], axis=-1)
        north = np.stack([-np.sin(lat0) * np.cos(lon0), -np.sin(lat0) * np.sin(lon0), np.cos(lat0)], axis=-1)
        d_row = xyz[1] - xyz[0]
        d_col = xyz[3] - xyz[2]
        g_row[sel] = np.stack([np.sum(d_row * east, 1), np.sum(d_row * north, 1)], axis=-1)
        g_col[sel] = np.stack([np.sum(d_col * east, 1), np.sum(d_col * north, 1)], axis=-1)
    return g_row, g_col


def _arrays(*arrays):
    out = [np.asarray(a, dtype=np.float64).reshape(-1) for a in arrays]
    n = out[0].size
    if n == 0:
        raise InputError("no check points given")
    for name, a in zip(("row", "col", "lon", "lat", "h"), out):
        if a.size != n:
            raise InputError(f"has {a.size} values for {n} check points", field=name)
        if not np.all(np.isfinite(a)):
            raise InputError("holds NaN or infinite values", field=name)
    return out


def check_point_accuracy(
    model,
    row,
    col,
    lon,
    lat,
    h,
    *,
    band=None,
    ccd=None,
    gsd_m=None,
    metres: bool = True,
    reference_index: int | None = None,
    confidence: float = 0.95,
    bins="auto",
) -> AccuracyReport:
    """Accuracy statistics of ``model`` on check points (module docstring).

    Parameters
    ----------
    model : SensorModel
        The (calibrated) model.
    row, col, lon, lat, h : array_like, shape (N,)
        Observed image coordinates (px) and ground coordinates of the check points.
    band, ccd : optional
        As in :func:`check_residuals`.
    gsd_m : float or array_like, shape (N,) or (N, 2), optional
        Ground sampling distance (row, col) in metres per pixel; default: measured on the
        model (:func:`ground_steps`), unless ``metres=False``.
    metres : bool
        Compute metre statistics.
    reference_index : int, optional
        Reference point of the relative accuracy; default: the check point nearest the
        centroid of the check points' image positions.
    confidence : float
        Of the normal fits' intervals.
    bins
        Histogram bins (:func:`numpy.histogram`).

    Returns
    -------
    AccuracyReport
    """
    row, col, lon, lat, h = _arrays(row, col, lon, lat, h)
    residuals, ccd_index = check_residuals(model, row, col, lon, lat, h, band=band, ccd=ccd)
    residuals_m = vectors_m = None
    if gsd_m is not None:
        residuals_m = _metres_from_gsd(residuals, gsd_m)
    elif metres:
        residuals_m, vectors_m = _metres_from_model(model, residuals, row, col, h, band, ccd_index)
    finite = np.all(np.isfinite(residuals), axis=1)
    if not np.any(finite):
        raise InputError("the model projects none of the check points")
    reference_index = _reference_point(row, col, finite, reference_index)
    rel_px, rel_m = _relative(residuals, residuals_m, vectors_m, reference_index)
    histograms = {}
    if int(finite.sum()) >= 2:
        histograms = {
            "row": fit_normal(residuals[finite, 0], confidence=confidence, bins=bins),
            "col": fit_normal(residuals[finite, 1], confidence=confidence, bins=bins),
        }
    return AccuracyReport(
        absolute=summarize_residuals(residuals, residuals_m),
        relative=summarize_residuals(rel_px, rel_m),
        reference_index=reference_index,
        groups=_group_summaries(model, residuals, residuals_m, band, ccd_index),
        histograms=histograms,
        residuals_px=residuals,
        residuals_m=residuals_m,
    )


def _metres_from_gsd(residuals, gsd_m):
    """Residuals in metres (along, across, planar), shape (N, 3), from given sampling distances."""
    n = residuals.shape[0]
    g = np.asarray(gsd_m, dtype=np.float64)
    if g.ndim == 0:
        g = np.full((n, 2), float(g))
    elif g.shape == (n,):
        g = np.repeat(g[:, None], 2, axis=1)
    elif g.shape != (n, 2):
        raise InputError(f"needs a scalar, ({n},) or ({n}, 2) values, got shape {g.shape}", field="gsd_m")
    if not np.all(np.isfinite(g)) or np.any(g <= 0.0):
        raise InputError("must be positive and finite", field="gsd_m")
    along = residuals[:, 0] * g[:, 0]
    across = residuals[:, 1] * g[:, 1]
    return np.stack([along, across, np.hypot(along, across)], axis=-1)


def _metres_from_model(model, residuals, row, col, h, band, ccd_index):
    """Residuals in metres, shape (N, 3), and as ground vectors, from the model's ground steps."""
    per_point_ccd = ccd_index if _has_named_arrays(model) else None
    g_row, g_col = ground_steps(model, row, col, h, band=band, ccd=per_point_ccd)
    vectors_m = residuals[:, 0:1] * g_row + residuals[:, 1:2] * g_col
    residuals_m = np.stack(
        [
            residuals[:, 0] * np.linalg.norm(g_row, axis=1),
            residuals[:, 1] * np.linalg.norm(g_col, axis=1),
            np.linalg.norm(vectors_m, axis=1),
        ],
        axis=-1,
    )
    return residuals_m, vectors_m


def _reference_point(row, col, finite, reference_index) -> int:
    """The given reference point (checked), or the check point nearest the centroid."""
    if reference_index is None:
        centre = np.array([np.mean(row[finite]), np.mean(col[finite])])
        d = np.hypot(row - centre[0], col - centre[1])
        d[~finite] = np.inf
        return int(np.argmin(d))
    if not 0 <= int(reference_index) < row.size or not finite[int(reference_index)]:
        raise InputError("must index a check point with a finite residual", field="reference_index")
    return int(reference_index)


def _group_summaries(model, residuals, residuals_m, band, ccd_index) -> dict:
    """Per band and per CCD summaries of a push-broom model (empty for other models)."""
    groups = {}
    if not _has_named_arrays(model):
        return groups
    n = residuals.shape[0]
    if band is None or isinstance(band, str):
        bands = np.full(n, model.reference_band if band is None else band, dtype=object)
    else:
        bands = np.asarray(band, dtype=object).reshape(-1)
    for b in dict.fromkeys(bands):
        in_band = bands == b
        groups[str(b)] = _summary_of(residuals, residuals_m, in_band)
        names = [a.name for a in model.detector_arrays(b)]
        for k in np.unique(ccd_index[in_band]):
            groups[f"{b}.{names[k]}"] = _summary_of(residuals, residuals_m, in_band & (ccd_index == k))
    return groups


# --------------------------------------------------------------------------- versus GCP count
_POINT_KEYS = ("row", "col", "lon", "lat", "h")


def _subset(points: Mapping, idx) -> dict:
    out = {}
    for key, value in points.items():
        if value is None or isinstance(value, str) or np.ndim(value) == 0:
            out[key] = value
        else:
            out[key] = np.asarray(value)[idx] if not isinstance(value, np.ndarray) else value[idx]
    return out


def error_versus_gcp_count(
    model,
    gcps: Mapping,
    checks: Mapping,
    counts: Sequence[int],
    *,
    repeats: int = 3,
    seed: int = 0,
    options: CalibrationOptions = CalibrationOptions(),
) -> list[dict]:
    """Check-point error of calibrations from random GCP subsets of increasing size.

    Reproduces seed 000 fig. 8 (error versus the number of control points).

    Parameters
    ----------
    model : SensorModel
        Initial model handed to :func:`calibrate.absolute.calibrate_model`.
    gcps, checks : mapping of str to array_like
        ``row, col, lon, lat, h`` and optionally ``band, ccd, sigma_px, score`` (GCPs) or
        ``band, ccd`` (check points), one value per point.
    counts : sequence of int
        Subset sizes (each at most the number of GCPs).
    repeats : int
        Random subsets per size.
    seed : int
        Of the subset draws.
    options : CalibrationOptions
        Of every :func:`~calibrate.absolute.calibrate_model` run (e.g. ``scheme``).

    Returns
    -------
    list of dict
        Per size: ``n_gcps``, ``repeats``, ``successes``, and over the successful repeats
        the mean and standard deviation of the check RMSE (``rmse_px_mean``,
        ``rmse_px_std``, ``rmse_row_px_mean``, ``rmse_col_px_mean``).
    """
    from calibrate.absolute import calibrate_model

    missing = [k for k in _POINT_KEYS if k not in gcps or k not in checks]
    if missing:
        raise InputError(f"gcps and checks need {', '.join(_POINT_KEYS)}; missing {', '.join(missing)}")
    n = np.asarray(gcps["row"]).size
    rng = np.random.default_rng(seed)
    rows = []
    check_kw = {k: checks.get(k) for k in ("band", "ccd")}
    for count in counts:
        count = int(count)
        if not 1 <= count <= n:
            raise InputError(f"subset size {count} outside 1..{n}", field="counts")
        rmse, rmse_row, rmse_col, ok = [], [], [], 0
        for _ in range(int(repeats)):
            idx = np.sort(rng.choice(n, size=count, replace=False))
            sub = _subset(gcps, idx)
            extra = {k: sub[k] for k in ("band", "ccd", "sigma_px", "score") if sub.get(k) is not None}
            table = GcpTable.from_arrays(*(sub[k] for k in _POINT_KEYS), **extra)
            result = calibrate_model(model, table, options=options)
            if not result.success:
                continue
            ok += 1
            res, _ = check_residuals(result.model, *(checks[k] for k in _POINT_KEYS), **check_kw)
            s = summarize_residuals(res)
            rmse.append(s.rmse_px)
            rmse_row.append(s.rmse_row_px)
            rmse_col.append(s.rmse_col_px)
        rows.append(
            {
                "n_gcps": count,
                "repeats": int(repeats),
                "successes": ok,
                "rmse_px_mean": float(np.mean(rmse)) if rmse else None,
                "rmse_px_std": float(np.std(rmse)) if rmse else None,
                "rmse_row_px_mean": float(np.mean(rmse_row)) if rmse else None,
                "rmse_col_px_mean": float(np.mean(rmse_col)) if rmse else None,
            }
        )
    return rows
