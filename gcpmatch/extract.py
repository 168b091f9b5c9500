"""The GCP extraction pipeline: coarse SIFT pre-correction, dense phase correlation, outliers.

``extract_gcps(model, scene, dem, dom)`` returns a :class:`~gcpmatch.gcps.GcpTable` and a JSON
summary:

1. :func:`gcpmatch.coarse.coarse_match` pre-corrects the model (within a few pixels);
2. per CCD, the DOM is resampled into scene geometry through the pre-corrected model
   (:func:`gcpmatch.reference.reference_for_ccd`);
3. windows of ``window_px`` on a grid every ``spacing_px`` are phase-correlated in batches
   (:func:`gcpmatch.phase.phase_correlate`); windows with reference no-data, scene no-data,
   clouds (mask or detector) or no texture (water) are skipped;
4. outliers: phase-correlation quality, local consistency on the window grid, robust residuals
   against a smooth per-CCD correction (:mod:`gcpmatch.outliers`);
5. each kept window gives a GCP: the ground point that the pre-corrected model sees at the
   window centre ``p`` (DEM intersection) observed at ``p + shift`` in the scene;
   ``sigma_px`` comes from the window's correlation score and the reference DOM's stated accuracy
   (:mod:`gcpmatch.uncertainty`; ``sigma_model="ccd"``: the CCD's robust residual spread); a
   stratified fraction becomes check points.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from gcpmatch.clouds import detect_clouds, low_texture
from gcpmatch.coarse import CoarseMatchError, coarse_match, scene_height_m
from gcpmatch.coverage import reference_coverage
from gcpmatch.gcps import GcpTable
from gcpmatch.options import MatchOptions
from gcpmatch.outliers import local_consistency, smooth_residuals
from gcpmatch.phase_batch import match_batch
from gcpmatch.reference import reference_for_ccd, reference_for_image, scene_gsd_m
from gcpmatch.texture import band_noise_dn, gradient_snr, weak_texture
from gcpmatch.uncertainty import reference_sigma_px, score_sigma_px, window_sigma
from sensor_models.maps.dom_inputs import ReferenceAccuracy, reference_accuracy
from gcpmatch.window_match import correlate_pairs, reference_disagrees
from sensor_models.errors import InputError
from gcpmatch.phase_pool import release_kernels
from sensor_models.files.memory import release_free_heap
from sensor_models.files.threads import blas_threads, map_ordered, opencv_threads

__all__ = ["MatchOptions", "coarse_stage", "correlate_pairs", "extract_gcps", "grid_starts", "read_band", "reject_outliers",
           "window_count"]

#: windows the CUDA backend's threads gather on the host at once, all together (about 100 kB of
#: scratch a window: ~1.6 GB)
GPU_HOST_WINDOWS = 16384
#: scratch of a window task on the CPU backends, bytes per window pixel (gathered windows, masks,
#: spectra, sigma model): about 100 kB a 64 px window, measured on the full seed-003 geometry
#: (0.75-1.0 GB for 16 tasks of 512 windows)
WINDOW_SCRATCH_BYTES_PER_PX = 25
#: the CPU backends' window tasks in flight together stay within this (20 tasks of 512 windows of
#: 64 px; more threads than it allows wait their turn: docs/memory.md)
CPU_HOST_WINDOW_BYTES = 1 << 30

REASONS = ("no_reference", "no_data", "cloud", "no_texture", "flat", "not_finite", "out_of_range",
           "low_score", "low_peak_ratio", "spectral_spread", "inconsistent", "model_residual")


def grid_starts(n: int, window: int, spacing: int) -> np.ndarray:
    """First pixels of the matching windows along one axis: every ``spacing`` px, plus the last
    window flush with the end.

    Parameters
    ----------
    n : int
        Pixels along the axis.
    window : int
        Window side, px.
    spacing : int
        Step between window starts, px.

    Returns
    -------
    ndarray of intp, shape (K,)
        Start indices in ``[0, n - window]``; empty when ``n < window``.
    """
    if n < window:
        return np.zeros(0, dtype=np.intp)
    last = n - window
    starts = np.arange(0, last + 1, spacing)
    return starts if starts[-1] == last else np.append(starts, last)


def window_count(model, band: str, options: MatchOptions) -> int:
    """Matching windows over every detector array of a band: an upper bound of the GCP count.

    Parameters
    ----------
    model : SensorModel
        The scene's model (``image_shape``, ``detector_arrays``).
    band : str
        Band to match.
    options : MatchOptions
        ``window_px`` and ``spacing_px`` (pixels) place the windows, as :func:`extract_gcps` does.

    Returns
    -------
    int
        Number of windows (each gives at most one GCP or check point).
    """
    n_rows = model.image_shape[0]
    rows = grid_starts(n_rows, options.window_px, options.spacing_px).size
    return int(sum(rows * grid_starts(look.n_detectors, options.window_px, options.spacing_px).size
                   for look in model.detector_arrays(band)))


def extract_gcps(model, scene: np.ndarray, dem, dom, *, band: str, mask: np.ndarray | None = None,
                 options: MatchOptions = MatchOptions(), progress=None, accuracy: ReferenceAccuracy | None = None,
                 progress_count=None):
    """Dense GCPs of one band of a scene (see the module docstring).

    Parameters
    ----------
    model : SensorModel
        Current model (e.g. the LAB model, hundreds of pixels off): a push-broom model with
        CCDs (``band_ccds``) or any model seen as one detector array (e.g. RPC).
    scene : ndarray, shape (n_rows, n_cols)
        The band's pixels, ``model.image_shape``; 0 or NaN = no data.
    dem : Dem
        Terrain heights (ellipsoidal after the DEM's datum conversion), for the reference
        chips and the GCP heights.
    dom : MapImage
        Reference orthoimage, resampled into scene geometry.
    band : str
        Band of ``model`` the scene belongs to.
    mask : ndarray of bool, shape (n_rows, n_cols), optional
        True where the scene is cloudy or invalid; default: the detector of
        :mod:`gcpmatch.clouds` (scene much brighter than the reference predicts).
    options : MatchOptions
        Window size and spacing, coarse search range, backend, check share, seed, ...
    progress : callable(str), optional
        Called with one line after the coarse stage and after each CCD.
    accuracy : ReferenceAccuracy, optional
        The DOM's geolocation accuracy (``sigma_model="window"``); ``options.reference_sigma_m``
        wins when set; default: what ``dom.path`` states, else assumed
        (:func:`sensor_models.maps.dom_inputs.reference_accuracy`).
    progress_count : callable(int, int), optional
        Called with ``(windows done, windows in all)`` after the coarse stage and after each
        batch of windows.

    Returns
    -------
    table : GcpTable or None
        The GCPs (``row, col`` in continuous pixel coordinates of the whole scene, first pixel's
        centre at (0.5, 0.5); ``lon, lat`` degrees, ``h`` metres above the ellipsoid; a
        stratified ``check_fraction`` of kind "check"); None when no window survived.
    summary : dict
        JSON-ready report: counts, rejection reasons, per-CCD figures, coarse stage, options,
        timings (seconds); ``message`` says why when there is no GCP.
    """
    opt = options.validate()
    with opencv_threads(opt.thread_count()):
        return _extract(model, scene, dem, dom, band=band, mask=mask, opt=opt, accuracy=accuracy, progress=progress,
                        progress_count=progress_count)


def _extract(model, scene, dem, dom, *, band, mask, opt: MatchOptions, accuracy, progress, progress_count=None):
    """:func:`extract_gcps` with validated options, inside the thread setting."""
    t0 = time.perf_counter()
    scene = _checked_scene(model, scene, mask)
    try:
        coarse = coarse_stage(scene, model, dem, dom, band, opt)
    except CoarseMatchError as exc:  # name the cloud figure: clouds are a common cause
        raise CoarseMatchError(f"{exc}; {_cloud_note(scene, mask)}") from exc
    timings = {"coarse_s": time.perf_counter() - t0}
    release_free_heap()  # the stages' scratch goes back between them (sensor_models.files.memory)
    model_pc = coarse.model
    if progress:
        searched = _searched(coarse, model_pc, band)
        progress(f"coarse stage: {coarse.n_inliers} SIFT matches, model pre-corrected{searched}")
    height_m = scene_height_m(model_pc, dem, band=band)
    tally = _Tally(height_m=height_m, mask_given=mask is not None, accuracy=_accuracy(dom, opt, accuracy),
                   count=progress_count, windows_total=window_count(model_pc, band, opt))
    tally.windows_done_by(0)
    # no DOM read session across CCDs (MapImage.reading): at full size it fills GDAL's block cache
    # (+1.27 GB peak, 2931 -> 4205 MiB) for no end-to-end gain (84.0 vs 86.3 s; docs/speed.md)
    pending = []  # with detect_change, every CCD is correlated before any is rejected
    for i, look in enumerate(model_pc.detector_arrays(band)):
        # an array that is a model of its own (a CCD) is rendered alone; a whole image at once
        split = model_pc.detector_view(band, i) is not model_pc
        ccd = _correlate_ccd(tally, model_pc, scene, mask, dem, dom, band=band, ccd=i if split else None,
                             look=look, opt=opt)
        if opt.detect_change:
            pending.append(ccd)
        else:
            _finish_ccd(tally, ccd, model_pc, dem, dom, band=band, opt=opt, progress=progress)
    if opt.detect_change:
        run_opt = _change_decision(tally, pending, opt)
        for ccd in pending:
            _finish_ccd(tally, ccd, model_pc, dem, dom, band=band, opt=run_opt, progress=progress)
    for i, report in coarse.ccd_search.items():  # the coarse stage's word on a CCD without SIFT matches
        if report["status"] != "pre-corrected" and tally.per_ccd[i].get("cause"):
            tally.per_ccd[i]["cause"] += f"; coarse stage: not pre-corrected ({report['reason']})"
    timings["reference_s"] = tally.t_ref
    timings["phase_s"] = tally.t_phase
    table = _gcp_table(tally.tables, opt)
    timings["total_s"] = time.perf_counter() - t0
    return table, _summary(band, table, tally, coarse, opt, timings, n_cols=scene.shape[1])


def _searched(coarse, model, band) -> str:
    """"; CCD x pre-corrected by its own search (offset ...)" / "not pre-corrected (why)", or ""."""
    arrays = model.detector_arrays(band)
    parts = []
    for i, report in coarse.ccd_search.items():
        name = arrays[i].name or str(i)
        if report["status"] == "pre-corrected":
            d_row, d_col = report["shift_px"]
            parts.append(f"CCD {name} pre-corrected by its own search (offset {d_row:+.1f}, {d_col:+.1f} px)")
        else:
            parts.append(f"CCD {name} not pre-corrected ({report['reason']})")
    return "".join(f"; {p}" for p in parts)


def _accuracy(dom, opt: MatchOptions, accuracy):
    """The reference's accuracy for ``sigma_model="window"`` (None for ``"ccd"``): option, given, stated, assumed."""
    if opt.sigma_model != "window":
        return None
    if opt.reference_sigma_m is not None or accuracy is None:
        path = getattr(dom, "path", None)
        return reference_accuracy([path] if isinstance(path, str) else [], given_m=opt.reference_sigma_m)
    return accuracy


@dataclass
class _Tally:
    """What the per-CCD passes add up: rejection counts, per-CCD reports, GCP columns, seconds."""

    reasons: dict = field(default_factory=lambda: {r: 0 for r in REASONS})
    per_ccd: list = field(default_factory=list)
    tables: list = field(default_factory=list)
    cloud_sum: float = 0.0
    cloud_cols: int = 0  # detector columns whose cloud fraction is known
    height_m: float = 0.0  # localization height of the coverage grids
    accuracy: ReferenceAccuracy | None = None  # the reference's, for sigma_model="window"
    mask_given: bool = False
    n_windows: int = 0
    t_ref: float = 0.0
    t_phase: float = 0.0
    count: object = None  # progress_count(done, total) of extract_gcps
    windows_total: int = 0
    windows_done: int = 0
    change: dict | None = None  # detect_change: the scene's median spread ratio and the decision

    def windows_done_by(self, k: int) -> None:
        """``k`` more windows done: tell the progress counter."""
        self.windows_done += int(k)
        if self.count is not None:
            self.count(self.windows_done, self.windows_total)


def _checked_scene(model, scene, mask) -> np.ndarray:
    """The scene as float32, after checking its shape (and the mask's) against the model."""
    scene = np.asarray(scene, dtype=np.float32)
    if scene.shape != model.image_shape:
        raise InputError(f"the scene raster is {scene.shape}, the model describes {model.image_shape}")
    if mask is not None and mask.shape != scene.shape:
        raise InputError(f"the mask is {mask.shape}, the scene {scene.shape}")
    return scene


def _cloud_note(scene: np.ndarray, mask) -> str:
    """The cloud figure known before the coarse stage: the mask's share, or "unknown"."""
    valid = np.isfinite(scene) & (scene != 0)
    if mask is not None and valid.any():
        return f"the mask marks {100 * np.count_nonzero(mask & valid) / np.count_nonzero(valid):.0f} % of the scene as cloud"
    return ("cloud fraction unknown (the cloud detector needs the pre-corrected model; give --mask to name the "
            "clouds)")


def coarse_stage(scene, model, dem, dom, band, opt: MatchOptions):
    """Coarse SIFT matching and model pre-correction, on the options' backend.

    Parameters
    ----------
    scene : ndarray, shape (H, W)
        The band's image.
    model : SensorModel
        The model to pre-correct.
    dem, dom
        The reference DEM and orthoimage.
    band : str
        The band matched.
    opt : MatchOptions
        ``max_offset_px``, ``seed``, ``backend``, ``window_px`` (the capture radius
        ``window_px / 4``), ``coarse_search`` and ``coarse_skip`` are used.

    Returns
    -------
    gcpmatch.coarse.CoarseResult
        What :func:`gcpmatch.coarse.coarse_match` returns (its ``model`` is pre-corrected).
    """
    torch_backend = opt.backend in ("gpu", "torch")
    device = "cuda" if opt.backend == "gpu" else ("cpu" if torch_backend else None)
    return coarse_match(scene, model, dem, dom, band=band, max_offset_px=opt.max_offset_px, seed=opt.seed,
                        backend="torch" if torch_backend else "cpu", device=device,
                        skip_within_px=opt.window_px / 4.0 if opt.coarse_skip else None,
                        capture_px=opt.window_px / 4.0, search=opt.coarse_search, threads=opt.thread_count())


@dataclass
class _CcdMatches:
    """One CCD's windows after correlation, before rejection (:func:`_correlate_ccd`)."""

    look: object
    ccd: int | None
    shape: tuple
    cloud_px: float | None
    cover: dict
    grid: tuple = (0, 0)
    rr: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    cc: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    status: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    std_r: np.ndarray = field(default_factory=lambda: np.zeros(0))
    shift: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    quality: dict = field(default_factory=dict)
    ref_rc_px: np.ndarray = field(default_factory=lambda: np.zeros(2))


def _correlate_ccd(tally: _Tally, model_pc, scene, mask, dem, dom, *, band, ccd, look,
                   opt: MatchOptions) -> _CcdMatches:
    """Render the reference of one CCD (``ccd`` None: the whole image), screen and correlate its windows."""
    t1 = time.perf_counter()
    if ccd is not None:
        ref = reference_for_ccd(model_pc, dem, dom, band=band, ccd=ccd, psf_sigma_px=opt.psf_sigma_px,
                                workers=opt.thread_count())
    else:
        ref = reference_for_image(model_pc, dem, dom, band=band, psf_sigma_px=opt.psf_sigma_px)
    release_free_heap()
    tally.t_ref += time.perf_counter() - t1
    cols = slice(look.first_col, look.first_col + look.n_detectors)
    img = scene[:, cols]
    if mask is None:  # detector: brighter than the reference predicts
        msk, cloud_px = detect_clouds(img, ref)
    else:
        msk = mask[:, cols]
        cloud_px = float(msk.mean())
    cover = reference_coverage(model_pc, dem, dom, band=band, array=ccd, height_m=tally.height_m)
    out = _CcdMatches(look=look, ccd=ccd, shape=img.shape, cloud_px=cloud_px, cover=cover)
    rs = grid_starts(img.shape[0], opt.window_px, opt.spacing_px)
    cs = grid_starts(img.shape[1], opt.window_px, opt.spacing_px)
    if rs.size == 0 or cs.size == 0:
        return out
    out.grid = (rs.size, cs.size)
    out.rr, out.cc = (a.ravel() for a in np.meshgrid(rs, cs, indexing="ij"))
    tally.n_windows += out.rr.size
    t1 = time.perf_counter()
    out.status, out.std_r, out.shift, out.quality = _correlate_windows(img, ref, msk, out.rr, out.cc, opt,
                                                                       on_batch=tally.windows_done_by)
    release_kernels()  # the phase kernels' scratch (gcpmatch.phase_pool), then the heap
    release_free_heap()
    tally.t_phase += time.perf_counter() - t1
    out.ref_rc_px = _reference_px(tally, model_pc, band, look, ccd)
    return out


def _change_decision(tally: _Tally, pending: list, opt: MatchOptions) -> MatchOptions:
    """``detect_change``: the options the scene's windows are rejected with, and ``tally.change``."""
    spread = np.concatenate([c.quality.get("spectral_spread_px", np.zeros(0)) for c in pending] or [np.zeros(0)])
    score = np.concatenate([c.quality.get("score", np.zeros(0)) for c in pending] or [np.zeros(0)])
    disagrees, median = reference_disagrees(spread, score, window_px=opt.window_px)
    tally.change = {"median_spread_ratio": None if not np.isfinite(median) else median, "detected": disagrees}
    if not disagrees:
        return opt
    return replace(opt, spectral_spread_sigma=True, max_spectral_spread=opt.max_spectral_spread or 1.0)


def _finish_ccd(tally: _Tally, m: _CcdMatches, model_pc, dem, dom, *, band, opt: MatchOptions, progress) -> None:
    """Reject the outliers of one correlated CCD, add its GCPs and its report to ``tally``."""
    look, n = m.look, m.rr.size
    if n == 0:
        tally.per_ccd.append(_ccd_report(look, 0, 0, m.cloud_px, m.cover, {}, float("nan"), (np.empty(0),) * 2,
                                         m.shape, dem, dom))
        return
    keep, r_c, c_c, sigma = reject_outliers(m.status, m.std_r, m.shift, m.rr, m.cc, m.grid, look.first_col, opt,
                                            quality=m.quality,
                                            reference_sigma_px=float(np.sqrt(np.mean(m.ref_rc_px**2))))
    status, shift = m.status, m.shift
    score = m.quality.get("score", np.full(n, np.nan))
    for r in REASONS:
        tally.reasons[r] += int(np.sum(status == r))
    if keep.size:
        kw = {"array": m.ccd} if m.ccd is not None else {}
        tally.tables.append(_ccd_gcps(model_pc, dem, band, look, r_c, c_c, shift[keep], score[keep], sigma, kw))
    cloud_px = m.cloud_px
    if cloud_px is not None:
        tally.cloud_sum += cloud_px * look.n_detectors
        tally.cloud_cols += look.n_detectors
    counts = {r: int(np.sum(status == r)) for r in REASONS}
    sigma_ccd = float(np.sqrt(np.mean(sigma**2))) if sigma.size else float("nan")
    tally.per_ccd.append(_ccd_report(look, n, keep.size, cloud_px, m.cover, counts, sigma_ccd,
                                     (r_c, c_c - look.first_col), m.shape, dem, dom))
    tally.per_ccd[-1]["reference_sigma_px"] = [float(v) for v in m.ref_rc_px]  # (row, col)
    if progress:
        line = f"CCD {look.name}: {keep.size} GCPs from {n} windows" if look.name else \
            f"image: {keep.size} GCPs from {n} windows"
        cause = tally.per_ccd[-1]["cause"]
        progress(line + (f" ({cause})" if cause else ""))


def _reference_px(tally: _Tally, model_pc, band, look, ccd) -> np.ndarray:
    """The reference's accuracy in this CCD's (row, col) pixels (zeros without one)."""
    acc = tally.accuracy
    if acc is None or (acc.east_m == 0 and acc.north_m == 0):
        return np.zeros(2)
    px = np.array(reference_sigma_px(model_pc, acc.east_m, acc.north_m, band=band, first_col=look.first_col,
                                     n_detectors=look.n_detectors, height_m=tally.height_m, array=ccd))
    if not np.all(np.isfinite(px)):  # the CCD centre does not localize: the scene's mean GSD
        px = np.full(2, acc.per_axis_m / scene_gsd_m(model_pc, band=band, height_m=tally.height_m))
    if not np.all(np.isfinite(px)):
        raise InputError(f"cannot convert the reference accuracy ({acc.per_axis_m:.1f} m) into pixels of "
                         f"{look.name or 'the image'}: its centre does not localize; give --sigma-model ccd")
    return px


#: a CCD with fewer usable windows than this fraction gets a ``cause``
THIN_FRACTION = 0.1


def _ccd_report(look, n, n_keep, cloud_px, cover, counts, sigma, centres, shape, dem, dom) -> dict:
    """The per-CCD entry of the summary, with the ``cause`` of an empty or thin CCD."""
    n_win = max(n, 1)
    report = {
        "ccd": look.name, "windows": int(n), "gcps": int(n_keep),
        "usable_fraction": float(n_keep / n_win),
        "cloud_fraction": cloud_px,
        "cloud_windows": int(counts.get("cloud", 0)),
        "no_texture_fraction": float(counts.get("no_texture", 0) / n_win),
        "dem_coverage": cover["dem"],
        "dom_coverage": cover["dom"],
        "sigma_px": None if not np.isfinite(sigma) else sigma,
        "coverage": _coverage(centres[0], centres[1], shape),
    }
    if cloud_px is None:
        report["cloud_note"] = "the cloud detector cannot estimate here (too little land matches the reference)"
    thin = n_keep == 0 or n_keep < THIN_FRACTION * n_win
    report["cause"] = _cause(report, counts, dem, dom) if thin else None
    return report


def _cause(report, counts, dem, dom) -> str:
    """Why a CCD gave no (or few) GCPs: the first of DEM, DOM, clouds, texture, else the rejections."""
    def name(obj, what):
        return getattr(obj, "source", None) or getattr(obj, "path", None) or what

    if report["dem_coverage"] < 0.5:
        return f"DEM covers {100 * report['dem_coverage']:.0f} % of the CCD ({name(dem, 'DEM')})"
    if report["dom_coverage"] is not None and report["dom_coverage"] < 0.5:
        return f"DOM covers {100 * report['dom_coverage']:.0f} % of the CCD ({name(dom, 'DOM')})"
    if report["cloud_fraction"] is not None and report["cloud_fraction"] >= 0.5:
        return f"clouds cover {100 * report['cloud_fraction']:.0f} % of the CCD"
    if report["windows"] and report["no_texture_fraction"] >= 0.5:
        return f"no texture (water, uniform ground) in {100 * report['no_texture_fraction']:.0f} % of the windows"
    if report["cloud_fraction"] is None and report["windows"]:
        return "cloud cover unknown; the scene does not match the reference (clouds, or another place)"
    top = sorted(((v, k) for k, v in counts.items() if v), reverse=True)[:3]
    return "windows rejected: " + (", ".join(f"{k} {v}" for v, k in top) or "no window fits the CCD")


def _correlate_windows(img, ref, msk, rr, cc, opt: MatchOptions, on_batch=None):
    """Screen and phase-correlate the windows at upper-left corners ``(rr, cc)``, in batches.

    ``on_batch(k)``, when given, is called after each batch with the number of windows it held.

    Returns
    -------
    status : ndarray of object (str), shape (n,)
        ``""`` for a match, else the rejection reason.
    std_r : ndarray of float64, shape (n,)
        Standard deviation of each reference window (NaN where it has no data).
    shift : ndarray of float64, shape (n, 2)
        Scene minus reference shift (row, col), pixels; NaN where not correlated.
    quality : dict of str -> ndarray of float64, shape (n,)
        Per-window quality figures of :func:`correlate_pairs` (``score``, ...) and the scene
        window's gradient snr per axis (``gradient_snr_row``, ``gradient_snr_col``,
        :func:`gcpmatch.texture.gradient_snr`, only when ``min_gradient_snr`` or, with the
        ``"window"`` sigma model, ``texture_sigma_px`` is set); NaN where not correlated.
    """
    w, n = opt.window_px, rr.size
    win_s = sliding_window_view(img, (w, w))
    win_r = sliding_window_view(ref, (w, w))
    win_m = sliding_window_view(msk, (w, w))
    # the absolute texture measure (gcpmatch.texture), for the options that use it: the noise
    # estimate convolves the whole CCD (4.5 CPU-s and ~1.5 GB of float64 scratch at 8192 x 5450)
    snr_used = opt.min_gradient_snr > 0.0 or (opt.sigma_model == "window" and opt.texture_sigma_px > 0.0)
    noise_dn = band_noise_dn(img) if snr_used else None
    threads = opt.thread_count()
    step = window_task_size(w, opt, threads)
    spans = [(a, min(n, a + step)) for a in range(0, n, step)]
    # one task per span on its own thread; inside a task, the phase correlation and the sigma
    # model get the threads the tasks at once leave (one each once as many run as there are threads)
    at_once = window_tasks_at_once(step, opt, threads, len(spans))
    task_opt = replace(opt, threads=max(1, threads // at_once))

    def task(span):
        a, b = span
        return _screen_and_correlate(win_s[rr[a:b], cc[a:b]], win_r[rr[a:b], cc[a:b]],
                                     win_m[rr[a:b], cc[a:b]], task_opt, noise_dn)

    status = np.full(n, "", dtype=object)
    std_r = np.full(n, np.nan)
    shift = np.full((n, 2), np.nan)
    quality = {}
    # BLAS on one thread: its idle workers spin beside the tasks' threads (measured on 2 cores:
    # 1 task thread kept 2 cores busy, and 2 threads ran no faster than 1; docs/speed.md)
    with blas_threads(1):
        for (a, b), (st, sd, sh, q) in zip(spans, map_ordered(task, spans, at_once)):
            status[a:b], std_r[a:b], shift[a:b] = st, sd, sh
            for k, v in q.items():
                quality.setdefault(k, np.full(n, np.nan))[a:b] = v
            if on_batch is not None:
                on_batch(b - a)
    return status, std_r, shift, quality


def window_task_size(window_px: int, opt: MatchOptions, threads: int) -> int:
    """Windows that one thread gathers, screens and correlates at once (:func:`_correlate_windows`).

    On the CPU and torch-on-CPU backends ``opt.batch``: the tasks, and so the GCPs, are the same
    whatever the thread count, and the host holds about ``threads x batch`` windows' scratch. On
    CUDA the device's batch (:func:`gcpmatch.phase_batch.match_batch`) shared among the threads,
    within ``GPU_HOST_WINDOWS`` gathered on the host at once, and at least ``opt.batch``.
    """
    batch = match_batch(window_px, opt.backend, opt.batch)
    if opt.backend != "gpu":
        return batch
    return int(max(opt.batch, min(batch, GPU_HOST_WINDOWS // max(1, threads))))


def window_tasks_at_once(step: int, opt: MatchOptions, threads: int, n_tasks: int) -> int:
    """Window tasks of ``step`` windows that run at once: one a thread, at most as many tasks as
    there are, and on the CPU backends at most as many as keep their scratch within
    ``CPU_HOST_WINDOW_BYTES`` (``WINDOW_SCRATCH_BYTES_PER_PX`` a window pixel: the scratch grows
    with the tasks in flight, not with the scene). The tasks, and so the GCPs, do not depend on it."""
    at_once = min(threads, n_tasks)
    if opt.backend != "gpu":
        task_bytes = WINDOW_SCRATCH_BYTES_PER_PX * opt.window_px**2 * max(1, step)
        at_once = min(at_once, CPU_HOST_WINDOW_BYTES // task_bytes)
    return max(1, at_once)


def _screen_and_correlate(ws, wr, wm, opt: MatchOptions, noise_dn):
    """One task of :func:`_correlate_windows`: its (k, w, w) scene, reference and mask windows.

    Returns the task's ``status``, ``std_r``, ``shift`` and ``quality`` (as the caller's).
    """
    k = ws.shape[0]
    status = np.full(k, "", dtype=object)
    shift = np.full((k, 2), np.nan)
    bad_ref = ~np.isfinite(wr).all(axis=(1, 2))
    bad_s = ~(np.isfinite(ws).all(axis=(1, 2)) & (ws > 0).all(axis=(1, 2)))
    status[bad_ref] = "no_reference"
    status[~bad_ref & bad_s] = "no_data"
    with np.errstate(invalid="ignore"):
        std_r = wr.std(axis=(1, 2))
    cloudy = wm.mean(axis=(1, 2)) > opt.cloud_window_fraction
    status[(status == "") & cloudy] = "cloud"
    go = np.flatnonzero(status == "")
    quality = {}
    if go.size == 0:
        return status, std_r, shift, quality
    pm = correlate_pairs(wr[go], ws[go], opt)
    shift[go] = pm.shift_px
    status[go] = pm.status
    batch_quality = dict(pm.quality)
    if noise_dn is not None:
        snr = gradient_snr(ws[go], noise_dn)
        batch_quality.update(gradient_snr_row=snr[:, 0], gradient_snr_col=snr[:, 1])
    for name, v in batch_quality.items():
        quality[name] = np.full(k, np.nan)
        quality[name][go] = v
    return status, std_r, shift, quality


def reject_outliers(status, std_r, shift, rr, cc, grid_shape, first_col: int, opt: MatchOptions, *,
                    quality: dict | None = None, reference_sigma_px: float = 0.0):
    """Mark featureless, locally inconsistent and model-residual outliers; the kept GCPs' sigma.

    Parameters
    ----------
    status : ndarray of object (str), shape (n,)
        ``""`` for a match so far, else a rejection reason; updated in place.
    std_r : ndarray of float64, shape (n,)
        Standard deviation of each reference window (the texture test).
    shift : ndarray of float64, shape (n, 2)
        Scene minus reference shift (row, col), pixels.
    rr, cc : ndarray of int, shape (n,)
        Upper-left corners of the windows in the CCD image, on a grid of ``grid_shape``
        (row-major).
    grid_shape : (int, int)
        Window-grid rows and columns.
    first_col : int
        The CCD's first column in the whole scene.
    opt : MatchOptions
        ``window_px``, ``texture_fraction``, ``sigma_model``.
    quality : dict of str -> ndarray (n,), optional
        Per-window quality of :func:`correlate_pairs` (``score``), for ``sigma_model="window"``.
    reference_sigma_px : float
        The reference's geolocation accuracy per axis in this CCD's pixels (``sigma_model="window"``).

    Returns
    -------
    keep : ndarray of intp
        Indices of the kept windows.
    r_c, c_c : ndarray, shape (len(keep),)
        Their centres in whole-scene continuous pixel coordinates.
    sigma_px : ndarray of float64, shape (len(keep),)
        Each kept GCP's standard deviation per axis, pixels (:func:`gcpmatch.uncertainty.window_sigma`).
    """
    half = opt.window_px // 2
    # water and other featureless ground, judged on the whole CCD
    texture_ok = np.isfinite(std_r)
    status[(status == "") & texture_ok & low_texture(std_r, texture_fraction=opt.texture_fraction)] = "no_texture"
    if opt.min_gradient_snr > 0.0 and quality and "gradient_snr_row" in quality:  # absolute texture gate
        weak = weak_texture(quality["gradient_snr_row"], quality["gradient_snr_col"], opt.min_gradient_snr)
        status[(status == "") & weak] = "no_texture"
    if opt.max_spectral_spread > 0.0 and quality and "spectral_spread_px" in quality:  # real change
        noise = score_sigma_px(quality["score"], window_px=opt.window_px)
        with np.errstate(invalid="ignore"):
            status[(status == "") & (quality["spectral_spread_px"] > opt.max_spectral_spread * noise)] = "spectral_spread"
    # local consistency on the window grid
    grid = np.where((status == "")[:, None], shift, np.nan).reshape(*grid_shape, 2)
    consistent = local_consistency(grid).reshape(-1)
    status[(status == "") & ~consistent] = "inconsistent"
    keep = np.flatnonzero(status == "")
    r_c = rr[keep] + half  # window centres (continuous coordinates)
    c_c = cc[keep] + half + first_col
    if not keep.size:
        return keep, r_c, c_c, np.zeros(0)
    inl, sigma, residual = smooth_residuals(r_c, c_c, shift[keep, 0], shift[keep, 1])
    status[keep[~inl]] = "model_residual"
    keep, r_c, c_c = keep[inl], r_c[inl], c_c[inl]
    kept_quality = {k: v[keep] for k, v in (quality or {}).items()}
    return keep, r_c, c_c, window_sigma(sigma, residual[inl], kept_quality, model=opt.sigma_model,
                                        reference_sigma_px=reference_sigma_px, window_px=opt.window_px,
                                        texture_sigma_px=opt.texture_sigma_px, mismatch_scale=opt.mismatch_sigma_scale,
                                        spread_sigma=opt.spectral_spread_sigma)


def _ccd_gcps(model_pc, dem, band, look, r_c, c_c, shift, score, sigma, ccd_kw) -> dict:
    """GCP columns of one CCD: the ground seen at each window centre, observed at centre + shift
    (``sigma``: per GCP, pixels)."""
    lon, lat, h = model_pc.image_to_ground(r_c.astype(np.float64), c_c.astype(np.float64), dem=dem,
                                           band=band, **ccd_kw)
    ok = np.isfinite(lon)
    sig = sigma[ok]
    return {
        "row": r_c[ok] + shift[ok, 0], "col": c_c[ok] + shift[ok, 1],
        "lon": lon[ok], "lat": lat[ok], "h": h[ok], "sigma_px": sig,
        "band": np.full(ok.sum(), band or "", dtype=object), "ccd": np.full(ok.sum(), look.name, dtype=object),
        "score": score[ok],
    }


def _gcp_table(tables: list, opt: MatchOptions):
    """One GcpTable from the per-CCD columns, a share marked as check points; None if empty."""
    if not tables:
        return None
    table = GcpTable.from_arrays(**{k: np.concatenate([t[k] for t in tables]) for k in tables[0]})
    if opt.check_fraction > 0 and len(table) > 1:
        table = table.split_check(opt.check_fraction, seed=opt.seed)
    return table


def _summary(band, table, tally: _Tally, coarse, opt: MatchOptions, timings: dict, *, n_cols: int) -> dict:
    """The JSON-ready report of :func:`extract_gcps`."""
    reasons, n_windows = tally.reasons, tally.n_windows
    n_gcp = 0 if table is None else len(table)
    summary = {
        "kind": "gcpcal.match",
        "band": band,
        "gcps": int(0 if table is None else np.sum(table.kind == "gcp")),
        "check_points": int(0 if table is None else np.sum(table.kind == "check")),
        "windows": n_windows,
        "usable_fraction": n_gcp / max(n_windows, 1),
        "cloud_fraction": tally.cloud_sum / tally.cloud_cols if tally.cloud_cols else None,
        "cloud_window_fraction": reasons["cloud"] / max(n_windows, 1),
        "rejected": reasons,
        "per_ccd": tally.per_ccd,
        "coarse": coarse.summary(),
        "options": asdict(opt),
        "timings": timings,
        "matches_per_second": (n_windows - reasons["no_reference"] - reasons["no_data"] - reasons["cloud"])
        / max(tally.t_phase, 1e-9),
    }
    if tally.cloud_cols < n_cols and not tally.mask_given:
        summary["cloud_note"] = ("cloud fraction unknown" if not tally.cloud_cols else
                                 f"cloud fraction over the {100 * tally.cloud_cols / n_cols:.0f} % of the columns "
                                 "where the detector could estimate it") + "; give --mask for a known cover"
    if tally.change is not None:
        summary["change"] = tally.change
    if tally.accuracy is not None:
        summary["reference_accuracy"] = tally.accuracy.to_dict()
        if tally.accuracy.note:
            summary["reference_note"] = tally.accuracy.note
    if coarse.note:
        summary["note"] = coarse.note
    if n_gcp == 0:
        causes = "; ".join(f"{c['ccd'] or 'image'}: {c['cause']}" for c in tally.per_ccd if c.get("cause"))
        summary["message"] = "no GCP: " + (causes or ", ".join(f"{k} {v}" for k, v in reasons.items() if v))
    return summary


def _coverage(row, col, shape, cells: int = 8) -> float:
    """Fraction of an 8 x 8 partition of the CCD image holding at least one GCP."""
    if row.size == 0:
        return 0.0
    i = np.clip((row / shape[0] * cells).astype(int), 0, cells - 1)
    j = np.clip((col / shape[1] * cells).astype(int), 0, cells - 1)
    return float(np.unique(i * cells + j).size / cells**2)


#: Raster types whose every value float32 holds exactly (read_band lets GDAL convert them).
_EXACT_IN_FLOAT32 = tuple(np.dtype(t) for t in ("uint8", "int8", "uint16", "int16", "float32"))


def read_band(scene, band: str, image=None) -> np.ndarray:
    """The pixels of ``band`` (float32): ``image`` if given, else the manifest's raster.

    Parameters
    ----------
    scene : Scene
        The scene opened (:func:`sensor_models.readers.open_scene`); its ``rasters`` map band ->
        ``{"path", "index"}``.
    band : str
        Band to read.
    image : str or Path, optional
        A raster to read instead (its first band).

    Returns
    -------
    ndarray of float32, shape (n_rows, n_cols)
        The pixels, NaN where the raster is masked (nodata).

    Raises
    ------
    InputError
        No raster for the band, or the raster cannot be read.
    """
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError
    import warnings

    if image is None:
        rasters = scene.rasters
        if band not in rasters:
            from sensor_models.readers.scene_input import missing_raster_message

            raise InputError(missing_raster_message(scene, band))
        path, index = rasters[band]["path"], int(rasters[band].get("index", 1))
    else:
        path, index = str(image), 1
    from rasterio.enums import MaskFlags

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                # float32 pixels without a masked array's copies (a full-size band is 714 MB as
                # float32): GDAL converts the types float32 holds exactly as it reads, others are
                # converted by numpy; GDAL's mask is read only where the band has one
                if np.dtype(ds.dtypes[index - 1]) in _EXACT_IN_FLOAT32:
                    data = ds.read(index, out_dtype="float32")
                else:
                    data = ds.read(index).astype(np.float32)
                if ds.mask_flag_enums[index - 1] != [MaskFlags.all_valid]:
                    data[ds.read_masks(index) == 0] = np.nan
    except (RasterioError, IndexError) as exc:
        raise InputError(f"cannot read the scene raster ({exc})", path=path) from None
    return data
