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

References
----------
Seed 000: on-orbit geometric calibration of a geostationary camera from the relative motion of
stars (equations 1-19, tables 3-4, figure 8).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.spatial import cKDTree

from calibrate.config import STAR_SCHEMES, StarOptions
from calibrate.lsq import solve
from calibrate.lsq_inputs import Chunk, Prior
from sensor_models.errors import InputError
from sensor_models.files.documents import load_json
from sensor_models.models.geo_staring import GeoStaringModel, vectors_to_radec

__all__ = [
    "StarCalibrationResult",
    "StarObservations",
    "calibrate_tracks",
    "check_frames_camera",
    "detect_frames",
    "error_versus_track_points",
    "identify",
    "load_frame",
    "predict_catalog",
    "process_frames",
    "radec_accuracy",
    "radec_errors_px",
    "read_frame_list",
]

_EXTERIOR = ("installation.roll", "installation.pitch", "installation.yaw")
ARCSEC = np.pi / (180.0 * 3600.0)


# --------------------------------------------------------------------------- inputs
def read_frame_list(path):
    """Read a frame list (``frames.json``, written by ``gcpcal simulate geo-stars``).

    Format (JSON, ``format_version`` 1, ``kind: "geo_star_frames"``)::

        {"format_version": 1, "kind": "geo_star_frames", "epoch_utc": "...",
         "manifest": "manifest.json",
         "frames": [{"path": "frames/frame_0000.tif", "seconds": 0.0}, ...]}

    Paths are relative to the list's folder; seconds count from the manifest's epoch and must
    increase strictly. ``path`` may also be the folder holding ``frames.json``.

    Parameters
    ----------
    path : path
        ``frames.json`` or the folder holding it.

    Returns
    -------
    frames : list of Path
    seconds : ndarray, shape (F,)
    manifest : Path or None
    """
    path = Path(path)
    if path.is_dir():
        path = path / "frames.json"
    if not path.is_file():
        raise InputError("frame list not found", path=str(path))
    doc = load_json(path)
    if not isinstance(doc, dict) or doc.get("kind") != "geo_star_frames":
        raise InputError("not a star frame list (kind must be 'geo_star_frames')", path=str(path), field="kind")
    unknown = set(doc) - {"format_version", "kind", "epoch_utc", "manifest", "frames"}
    if unknown:
        raise InputError(f"unknown keys {sorted(unknown)}", path=str(path))
    if doc.get("format_version") != 1:
        raise InputError(f"unsupported version {doc.get('format_version')!r}", path=str(path), field="format_version")
    entries = doc.get("frames")
    if not isinstance(entries, list) or not entries:
        raise InputError("must be a non-empty list", path=str(path), field="frames")
    frames, seconds = [], []
    for k, e in enumerate(entries):
        if not isinstance(e, dict) or set(e) != {"path", "seconds"}:
            raise InputError("each frame needs exactly 'path' and 'seconds'", path=str(path), field=f"frames[{k}]")
        frames.append(path.parent / e["path"])
        seconds.append(float(e["seconds"]))
    manifest = path.parent / doc["manifest"] if doc.get("manifest") else None
    try:
        checked = _check_seconds(seconds, len(frames))
    except InputError as exc:  # name the frame list: the times are its fields
        raise InputError(exc.reason, path=str(path),
                         field="frames[].seconds") from None
    return frames, checked, manifest


#: Largest relative difference of the pixel angle (IFOV) between the camera of a star sequence
#: and the camera it calibrates (a LAB focal length is off by far less; another camera by more).
IFOV_TOLERANCE = 0.02


def _frame_shape(frame) -> tuple[int, int]:
    """``(n_rows, n_cols)`` of a frame raster (FITS through astropy, anything else through GDAL)."""
    if Path(frame).suffix.lower() in (".fits", ".fit", ".fts"):
        return tuple(int(n) for n in load_frame(frame).shape)
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    with warnings.catch_warnings():  # star frames have no map geometry: no warning line
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            with rasterio.open(frame) as ds:
                return int(ds.height), int(ds.width)
        except RasterioError as exc:
            raise InputError(f"cannot read the star frame ({exc})", path=str(frame)) from None


def check_frames_camera(frames, listed_model, model, *, frames_source, model_source) -> None:
    """Refuse star frames taken by another camera than the one ``model`` describes.

    The frames must have the model's image size (``n_rows x n_cols``, read from the first
    frame's header), and the camera the frame list names (its manifest) must have the model's
    image size and pixel angle (IFOV, within :data:`IFOV_TOLERANCE`).

    Parameters
    ----------
    frames : list of Path
        The frame rasters (:func:`read_frame_list`).
    listed_model : SensorModel or None
        Model of the manifest the frame list names (None when it names none).
    model : SensorModel
        The camera to calibrate (the scene's or ``--manifest``'s model).
    frames_source, model_source : str or Path
        The frame list and the model's file (named in the message).

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming both files, both sizes or both pixel angles (microradians).
    """
    want = tuple(int(x) for x in model.image_shape)
    shapes = [("frames", _frame_shape(frames[0]))]
    if listed_model is not None:
        shapes.append(("its manifest", tuple(int(x) for x in listed_model.image_shape)))
    for what, shape in shapes:
        if shape != want:
            raise InputError(f"the star frames belong to another camera: {what} {shape[0]} x {shape[1]} px, "
                             f"{model_source} {want[0]} x {want[1]} px", path=str(frames_source))
    ifov_a, ifov_b = getattr(listed_model, "ifov_rad", None), getattr(model, "ifov_rad", None)
    if ifov_a is not None and ifov_b is not None and abs(ifov_a / ifov_b - 1.0) > IFOV_TOLERANCE:
        raise InputError(f"the star frames belong to another camera: pixel angle {1e6 * ifov_a:.3f} urad, "
                         f"{model_source} {1e6 * ifov_b:.3f} urad", path=str(frames_source))


def _check_seconds(seconds, n_frames: int) -> np.ndarray:
    t = np.asarray(seconds, dtype=np.float64).reshape(-1)
    if t.size != n_frames:
        raise InputError(f"{t.size} times for {n_frames} frames", field="seconds")
    if not np.all(np.isfinite(t)):
        raise InputError("frame times must be finite", field="seconds")
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(f"frames out of time order: frame {k} at {t[k]:g} s does not follow {t[k - 1]:g} s",
                         field="seconds")
    return t


def load_frame(frame) -> np.ndarray:
    """A frame as a float32 array (H, W): an array, a FITS file or any raster rasterio reads.

    Parameters
    ----------
    frame : ndarray (H, W) or path
        An image already in memory, a FITS file or a raster file.

    Returns
    -------
    ndarray of float32, shape (H, W)
        Pixel values (counts).
    """
    if isinstance(frame, np.ndarray):
        if frame.ndim != 2:
            raise InputError(f"a frame must be 2-D, got shape {frame.shape}")
        return frame.astype(np.float32, copy=False)
    path = Path(frame)
    if not path.is_file():
        raise InputError("frame not found", path=str(path))
    if path.suffix.lower() in (".fits", ".fit", ".fts"):
        from gcpmatch.star_tracks import read_fits_image

        return read_fits_image(path)[0].astype(np.float32)
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            with rasterio.open(path) as src:
                return src.read(1, out_dtype=np.float32)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"cannot read the frame: {exc}", path=str(path)) from None


# --------------------------------------------------------------------------- detection
def detect_frames(frames, *, threshold_sigma: float = 5.0, centroid: str = "iwc", border_px: float = 4.0,
                  saturation: float | None = None, max_stars: int | None = 200):
    """Detect and centroid stars in every frame.

    Parameters
    ----------
    frames : sequence of ndarray (H, W) or path
        Frames in time order (:func:`load_frame`).
    threshold_sigma : float
        Detection threshold above the local background, noise sigmas.
    centroid : {"iwc", "gaussian", "windowed"}
        Centroid estimator (:func:`gcpmatch.star_tracks.detect_stars`).
    border_px : float
        Detections closer than this to the frame edge are dropped, pixels.
    saturation : float, optional
        Saturation level in counts (:func:`gcpmatch.star_tracks.detect_stars`); detections it
        flags as saturated are dropped.
    max_stars : int, optional
        Most detections per frame (:func:`gcpmatch.star_tracks.detect_stars`); None: all.

    Returns
    -------
    list of StarTable
        One per frame, detections closer than ``border_px`` to the edge removed (a cut PSF
        biases the centroid), as are saturated ones when ``saturation`` is given.
    shapes : list of (int, int)
    """
    from gcpmatch.star_tracks import FLAG_SATURATED, detect_stars

    tables, shapes = [], []
    for frame in frames:
        img = load_frame(frame)
        tab = detect_stars(img, threshold_sigma=threshold_sigma, centroid=centroid, saturation=saturation,
                           max_stars=max_stars)
        h, w = img.shape
        keep = ((tab.row_px > border_px) & (tab.row_px < h - border_px) & (tab.col_px > border_px)
                & (tab.col_px < w - border_px) & np.isfinite(tab.row_px) & np.isfinite(tab.col_px)
                & ((tab.flags & FLAG_SATURATED) == 0))
        tables.append(tab.select(keep))
        shapes.append((h, w))
    return tables, shapes


@dataclass
class _Predictions:
    """Catalogue stars predicted by the approximate model, all frames stacked (M,)."""

    frame: np.ndarray
    star: np.ndarray  # catalogue row
    vectors_gcrf: np.ndarray  # (M, 3) apparent directions at the frame instant
    row: np.ndarray
    col: np.ndarray


def predict_catalog(models, catalog, *, margin_px: float = 60.0) -> _Predictions:
    """Apparent catalogue stars inside (or within ``margin_px`` of) every frame's model.

    Parameters
    ----------
    models : sequence of GeoStaringModel
        The model of every frame (``lab_model.at_frame(t_k)``).
    catalog : StarCatalog
        Loaded catalogue.
    margin_px : float
        Stars projected up to this far outside a frame are kept, pixels.

    Returns
    -------
    _Predictions
        All frames stacked (M,): frame index, catalogue row, apparent GCRF direction (M, 3)
        at the frame instant and the projected ``row, col`` in pixels.
    """
    from sensor_models.geometry.star_catalogue import catalog_stars_in_frame

    unit = catalog.unit_vectors()
    parts = []
    for k, m in enumerate(models):
        idx, vec, row, col = catalog_stars_in_frame(m, catalog, unit, margin_px)
        parts.append((np.full(idx.size, k), idx, vec, row, col))
    cat = [np.concatenate([p[i] for p in parts]) if parts else np.zeros(0) for i in range(5)]
    return _Predictions(cat[0].astype(np.intp), cat[1].astype(np.intp), cat[2].reshape(-1, 3), cat[3], cat[4])


def identify(detections, pred: _Predictions, *, search_px: float = 120.0, tolerance_px: float = 4.0,
             bin_px: float = 2.0):
    """Match detections to predicted catalogue stars (global offset vote, then nearest neighbours).

    Parameters
    ----------
    detections : sequence of StarTable
        Detections per frame (``row_px, col_px``).
    pred : _Predictions
        Of :func:`predict_catalog`.
    search_px : float
        Largest detection-minus-prediction distance voted on, pixels.
    tolerance_px : float
        Largest distance of a match after the voted offset, pixels.
    bin_px : float
        Bin of the offset vote, pixels.

    Returns
    -------
    pairs : ndarray of int, shape (K, 3)
        ``(frame, detection index, prediction index)``.
    offset_px : ndarray, shape (2,)
        The voted (row, col) offset, detection minus prediction.
    """
    diffs = []
    for k, tab in enumerate(detections):
        sel = np.flatnonzero(pred.frame == k)
        if len(tab) == 0 or sel.size == 0:
            continue
        d = tab.rowcol[:, None, :] - np.stack([pred.row[sel], pred.col[sel]], -1)[None, :, :]
        d = d.reshape(-1, 2)
        diffs.append(d[np.all(np.abs(d) < search_px, axis=1)])
    diffs = np.concatenate(diffs) if diffs else np.zeros((0, 2))
    if diffs.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.intp), np.full(2, np.nan)
    edges = np.arange(-search_px, search_px + bin_px, bin_px)
    hist, _, _ = np.histogram2d(diffs[:, 0], diffs[:, 1], bins=(edges, edges))
    # 2x2 box sum: a peak split across bin edges still wins
    box = hist[:-1, :-1] + hist[1:, :-1] + hist[:-1, 1:] + hist[1:, 1:]
    i, j = np.unravel_index(np.argmax(box), box.shape)
    peak = np.array([edges[i + 1], edges[j + 1]])
    near = np.all(np.abs(diffs - peak) < 2.0 * bin_px, axis=1)
    offset = np.median(diffs[near], axis=0)
    pairs = []
    for k, tab in enumerate(detections):
        sel = np.flatnonzero(pred.frame == k)
        if len(tab) == 0 or sel.size == 0:
            continue
        p = np.stack([pred.row[sel], pred.col[sel]], -1) + offset
        det_tree, pred_tree = cKDTree(tab.rowcol), cKDTree(p)
        dist, di = det_tree.query(p, distance_upper_bound=tolerance_px)
        _, back = pred_tree.query(tab.rowcol)
        ok = np.flatnonzero(np.isfinite(dist))
        ok = ok[back[di[ok]] == ok]  # mutual nearest neighbours
        pairs.append(np.stack([np.full(ok.size, k), di[ok], sel[ok]], -1))
    pairs = np.concatenate(pairs) if pairs else np.zeros((0, 3), dtype=np.intp)
    return pairs.astype(np.intp), offset


# --------------------------------------------------------------------------- tracks
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


def _smooth_track(t, y, good, smooth: bool) -> np.ndarray:
    """Smoothed ``y`` (n, 2) of one track at times ``t`` fitted on the ``good`` points.

    A straight line in time is removed first (the drift at the sidereal rate), then each
    coordinate's remainder is fitted by a cubic smoothing spline on normalized time with the
    weight chosen by generalized cross-validation (seed 000 eq. 2); fewer than 5 points, or
    ``smooth=False``, keep the straight line.
    """
    tg = t[good]
    coef = np.polyfit(tg, y[good], 1)
    line = t[:, None] * coef[0] + coef[1]
    if not smooth or tg.size < 5:
        return line
    span = max(float(tg.max() - tg.min()), 1e-9)
    x = (t - tg.min()) / span
    out = line.copy()
    for j in range(y.shape[1]):
        spl = make_smoothing_spline(x[good], (y[:, j] - line[:, j])[good], lam=None)
        out[:, j] += spl(x)
    return out


def _smooth_tracks(obs: StarObservations, rng, *, n_check: int, min_points: int, reject_px: float,
                   reject_sigma: float, smooth: bool):
    """Hold out ``n_check`` points per track, smooth the rest (eq. 2), reject outliers.

    Returns the observations of the kept tracks and per-track records.
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
            res = y - _smooth_track(t, y, good, smooth)
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


# --------------------------------------------------------------------------- calibration
def _gauge_prior(model: GeoStaringModel, free, sigma_px: float):
    rows, scale = model.gauge_rows()
    names = list(model.parameter_names())
    idx = [names.index(n) for n in free]
    matrix = np.asarray(rows)[:, idx]
    keep = np.any(matrix != 0.0, axis=1)
    x0 = model.parameters().values[idx]
    return matrix[keep], matrix[keep] @ x0, sigma_px * np.asarray(scale)[keep]


def _prior(model: GeoStaringModel, free, *, interior_prior_px: float | None, gauge_sigma_px: float | None):
    """Weak interior prior towards ``model``'s values, plus the gauge for a joint solve."""
    names = list(model.parameter_names())
    values = model.parameters().values
    mats, vals, sigs = [], [], []
    interior = [k for k, n in enumerate(free) if n.startswith("interior.")]
    if interior and interior_prior_px:
        m = np.zeros((len(interior), len(free)))
        m[np.arange(len(interior)), interior] = 1.0
        mats.append(m)
        vals.append(values[[names.index(free[k]) for k in interior]])
        sigs.append(np.full(len(interior), interior_prior_px * model.ifov_rad))
    if gauge_sigma_px and interior and any(n in _EXTERIOR for n in free):
        m, v, s = _gauge_prior(model, free, gauge_sigma_px)
        mats.append(m), vals.append(v), sigs.append(s)
    if not mats:
        return None
    return Prior(np.vstack(mats), np.concatenate(vals), np.concatenate(sigs))


def calibrate_tracks(model0: GeoStaringModel, virtual_gcrf, row, col, *, scheme: str = StarOptions.scheme,
                     interior_degree: int = StarOptions.interior_degree, robust: str = StarOptions.robust,
                     interior_prior_px: float | None = StarOptions.interior_prior_px,
                     gauge_sigma_px: float = 1e-3, max_outer: int = 5, outer_tol: float = 0.05,
                     max_iter: int = 20, tol: float = 0.01):
    """Stepwise (or joint) least squares of the frame-0 model from virtual star vectors.

    Parameters
    ----------
    model0 : GeoStaringModel
        Initial model at frame 0 (LAB).
    virtual_gcrf : array_like, shape (N, 3)
        Directions that frame 0 images at ``(row, col)`` (seed 000 eq. 9).
    row, col : array_like, shape (N,)
        Observed (smoothed) track points, pixels.
    scheme : {"exterior-interior", "exterior", "joint"}
        Seed 000's stepwise exterior-then-interior (eq. 12-17), the exterior alone, or all
        parameters at once with the gauge pseudo-observations.
    interior_degree : int
        Degree of the estimated interior polynomials (3: the 20 coefficients).
    robust : {"huber", "cauchy", "none"}
        Robust loss of :func:`calibrate.lsq.solve`.
    interior_prior_px : float or None
        Standard deviation (pixels at the frame edge) of a pseudo-observation holding every
        interior coefficient at its initial value; None: no prior.
    gauge_sigma_px : float
        Joint scheme: standard deviation of the gauge pseudo-observations, pixels.
    max_outer, outer_tol : int, float
        Stepwise scheme: rounds, and the stop when an exterior step moves every angle by less
        than ``outer_tol`` of its standard deviation.
    max_iter, tol : int, float
        Per step, passed to :func:`calibrate.lsq.solve`.

    Returns
    -------
    theta : ndarray, shape (23,)
        Parameters over ``model0.parameter_names()``.
    runs : list of dict
        One per least-squares step: ``step``, ``round``, ``success``, ``message``,
        ``iterations``, ``sigma0``, ``condition_number``.
    result : LsqResult
        Of the last step.
    """
    if scheme not in STAR_SCHEMES:
        raise InputError(f"must be one of {', '.join(STAR_SCHEMES)}, got {scheme!r}", field="scheme")
    w = np.asarray(virtual_gcrf, dtype=np.float64).reshape(-1, 3)
    obs = np.stack([np.asarray(row, dtype=np.float64), np.asarray(col, dtype=np.float64)], -1)
    if obs.shape[0] != w.shape[0] or obs.shape[0] == 0:
        raise InputError(f"{obs.shape[0]} points for {w.shape[0]} vectors", field="row")
    interior = list(model0.interior_parameter_names(interior_degree))
    stepper = _TrackStepper(model0, w, obs, robust=robust, max_iter=max_iter, tol=tol)
    no_prior = dict(interior_prior_px=None, gauge_sigma_px=None)
    if scheme == "exterior":
        stepper.step(list(_EXTERIOR), "exterior", 0, no_prior)
    elif scheme == "joint":
        stepper.step(list(_EXTERIOR) + interior, "joint", 0,
                     dict(interior_prior_px=interior_prior_px, gauge_sigma_px=gauge_sigma_px))
    else:
        for rnd in range(max(1, int(max_outer))):
            res, moved = stepper.step(list(_EXTERIOR), "exterior", rnd, no_prior)
            if not res.success or (rnd > 0 and moved < outer_tol):
                break
            res, _ = stepper.step(interior, "interior", rnd,
                                  dict(interior_prior_px=interior_prior_px, gauge_sigma_px=None))
            if not res.success:
                break
    return stepper.theta, stepper.runs, stepper.last


class _TrackStepper:
    """One least-squares step after another on the frame-0 model; keeps the values and log."""

    def __init__(self, model0, virtual_gcrf, observed, *, robust, max_iter, tol):
        self.model0 = model0
        self.w = virtual_gcrf
        self.obs = observed
        self.solve_kw = dict(robust=robust, max_iter=max_iter, tol=tol)
        self.names = list(model0.parameter_names())
        self.theta = model0.parameters().values.copy()
        self.runs, self.last = [], None

    def step(self, free, label, rnd, prior_kw):
        """Solve for ``free``; the result and how far it moved them, in standard deviations."""
        idx = np.array([self.names.index(n) for n in free])
        theta, model0, w, obs = self.theta, self.model0, self.w, self.obs

        def chunks(x):
            full = theta.copy()
            full[idx] = x
            r, c, jac = model0.with_parameters(full).star_jacobian(w, names=free)
            return [Chunk(obs - np.stack([r, c], -1), jac)]

        prior = _prior(model0.with_parameters(theta), free, **prior_kw)
        res = solve(chunks, theta[idx], names=free, prior=prior, warm_start=bool(self.runs), **self.solve_kw)
        self.runs.append({"step": label, "round": rnd, "success": bool(res.success), "message": res.message,
                          "iterations": int(res.iterations), "sigma0": float(res.sigma0),
                          "condition_number": float(res.condition_number)})
        self.last = res
        if not res.success:
            return res, np.inf
        moved = np.abs(res.x - theta[idx])
        sig = res.sigma
        self.theta = theta.copy()
        self.theta[idx] = res.x
        return res, (float(np.max(moved / sig)) if sig is not None and np.all(sig > 0) else np.inf)


# --------------------------------------------------------------------------- accuracy
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
def _resolve_catalog(catalog, mag_limit):
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
        ``tolerance_px``: :func:`identify`), tracks (``min_track_points``, ``n_check`` points
        held out per track, seed 000: five; ``smooth``, ``reject_px``, ``reject_sigma``: the
        smoothing spline of eq. 2 and its outlier test, residual above
        ``max(reject_px, reject_sigma * robust sigma)``), calibration (``scheme``,
        ``interior_degree``, ``interior_prior_px``, ``robust``: :func:`calibrate_tracks`;
        ``compare_joint``: also run the joint scheme and report its accuracy in
        ``accuracy["joint_after"]``) and ``seed`` (of the held-out points).
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
    t = _check_seconds(seconds, len(frames))
    cat = _resolve_catalog(options.catalog, options.mag_limit)
    models = [lab_model.at_frame(float(s)) for s in t]
    timings["models_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    detections, n_det, empty = _detect_all(frames, lab_model, detections, options)
    timings["detection_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    obs, offset = _identify_all(detections, n_det, models, cat, t, options)
    timings["identification_s"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    n = obs.hip.size
    rng = np.random.default_rng(options.seed)
    obs, tracks = _smooth_tracks(obs, rng, n_check=options.n_check, min_points=options.min_track_points,
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
                observations=obs, timings=timings)
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


def _identify_all(detections, n_det, models, cat, t, options):
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
    b_all = np.stack([m.body_to_gcrf for m in models])
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
    b_all = np.stack([m.body_to_gcrf for m in models])
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
        Of :func:`calibrate_tracks`.
    seed : int
        Seeds the draws (``seed + 1``).
    **kw
        Further keywords of :func:`calibrate_tracks`.

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
