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
   ``sigma_px`` is the CCD's robust residual spread; a stratified fraction becomes check points.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from gcpmatch.clouds import cloud_pixels, low_texture
from gcpmatch.coarse import coarse_match
from gcpmatch.gcps import GcpTable
from gcpmatch.outliers import local_consistency, smooth_residuals
from gcpmatch.phase import Reject, phase_correlate
from gcpmatch.reference import reference_for_ccd, reference_for_image
from sensor_models.errors import InputError

__all__ = ["MatchOptions", "extract_gcps", "read_band"]

REASONS = ("no_reference", "no_data", "cloud", "no_texture", "flat", "not_finite", "out_of_range",
           "low_score", "low_peak_ratio", "inconsistent", "model_residual")
_PHASE_REASON = {Reject.FLAT: "flat", Reject.NOT_FINITE: "not_finite", Reject.OUT_OF_RANGE: "out_of_range",
                 Reject.LOW_SCORE: "low_score", Reject.LOW_PEAK_RATIO: "low_peak_ratio"}


@dataclass(frozen=True)
class MatchOptions:
    """Settings of :func:`extract_gcps` (all have working defaults)."""

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

    def validate(self) -> "MatchOptions":
        if self.window_px < 16 or self.window_px % 2:
            raise InputError(f"window must be an even number of pixels >= 16, got {self.window_px}", field="window_px")
        if self.spacing_px < 1:
            raise InputError("spacing must be >= 1 pixel", field="spacing_px")
        if not 0.0 <= self.check_fraction < 1.0:
            raise InputError(f"check fraction must lie in [0, 1), got {self.check_fraction}", field="check_fraction")
        if self.backend not in ("cpu", "gpu", "torch"):
            raise InputError(f"backend must be cpu or gpu, got {self.backend!r}", field="backend")
        return self


@dataclass(frozen=True)
class _WholeImage:
    """The whole image as one detector array (models without CCDs, e.g. RPC products)."""

    n_detectors: int
    first_col: int = 0
    name: str = ""


def _grid_starts(n: int, window: int, spacing: int) -> np.ndarray:
    if n < window:
        return np.zeros(0, dtype=np.intp)
    last = n - window
    starts = np.arange(0, last + 1, spacing)
    return starts if starts[-1] == last else np.append(starts, last)


def extract_gcps(model, scene: np.ndarray, dem, dom, *, band: str, mask: np.ndarray | None = None,
                 options: MatchOptions = MatchOptions(), progress=None):
    """Dense GCPs of one band of a scene (see the module docstring).

    Parameters
    ----------
    model : PushbroomModel
        Current model (e.g. the LAB model, hundreds of pixels off).
    scene : ndarray (n_rows, n_cols)
        The band's pixels (0 or NaN = no data).
    dem : Dem
    dom : MapImage
    band : str
    mask : ndarray (n_rows, n_cols) of bool, optional
        True where the scene is cloudy or invalid; default: the detector of :mod:`gcpmatch.clouds`.

    Returns
    -------
    table : GcpTable
    summary : dict
    """
    opt = options.validate()
    timings = {}
    t0 = time.perf_counter()
    scene = np.asarray(scene, dtype=np.float32)
    if scene.shape != model.image_shape:
        raise InputError(f"the scene raster is {scene.shape}, the model describes {model.image_shape}")
    if mask is not None and mask.shape != scene.shape:
        raise InputError(f"the mask is {mask.shape}, the scene {scene.shape}")
    torch_backend = opt.backend in ("gpu", "torch")
    device = "cuda" if opt.backend == "gpu" else ("cpu" if torch_backend else None)
    coarse = coarse_match(scene, model, dem, dom, band=band, max_offset_px=opt.max_offset_px, seed=opt.seed,
                          backend="torch" if torch_backend else "cpu", device=device)
    timings["coarse_s"] = time.perf_counter() - t0
    model_pc = coarse.model
    if progress:
        progress(f"coarse stage: {coarse.n_inliers} SIFT matches, model pre-corrected")
    w, half = opt.window_px, opt.window_px // 2
    reasons = {r: 0 for r in REASONS}
    per_ccd, tables, cloud_sum = [], [], 0.0
    t_ref = t_phase = 0.0
    n_windows = 0
    pushbroom = hasattr(model_pc, "band_ccds")
    looks = model_pc.band_ccds(band) if pushbroom else [_WholeImage(model_pc.image_shape[1])]
    for i, look in enumerate(looks):
        t1 = time.perf_counter()
        if pushbroom:
            ref = reference_for_ccd(model_pc, dem, dom, band=band, ccd=i, psf_sigma_px=opt.psf_sigma_px)
        else:
            ref = reference_for_image(model_pc, dem, dom, band=band, psf_sigma_px=opt.psf_sigma_px)
        t_ref += time.perf_counter() - t1
        img = scene[:, look.first_col : look.first_col + look.n_detectors]
        if mask is None:  # detector: much brighter than the reference predicts
            msk = cloud_pixels(img, ref)
        else:
            msk = mask[:, look.first_col : look.first_col + look.n_detectors]
        cloud_px = float(msk.mean())
        rs = _grid_starts(img.shape[0], w, opt.spacing_px)
        cs = _grid_starts(img.shape[1], w, opt.spacing_px)
        if rs.size == 0 or cs.size == 0:
            per_ccd.append({"ccd": look.name, "windows": 0, "gcps": 0})
            continue
        rr, cc = (a.ravel() for a in np.meshgrid(rs, cs, indexing="ij"))
        n = rr.size
        n_windows += n
        win_s = sliding_window_view(img, (w, w))
        win_r = sliding_window_view(ref, (w, w))
        status = np.full(n, "", dtype=object)
        std_r = np.full(n, np.nan)
        shift = np.full((n, 2), np.nan)
        score = np.full(n, np.nan)
        t1 = time.perf_counter()
        for a in range(0, n, opt.batch):
            b = min(n, a + opt.batch)
            ws = win_s[rr[a:b], cc[a:b]]
            wr = win_r[rr[a:b], cc[a:b]]
            bad_ref = ~np.isfinite(wr).all(axis=(1, 2))
            bad_s = ~(np.isfinite(ws).all(axis=(1, 2)) & (ws > 0).all(axis=(1, 2)))
            status[a:b][bad_ref] = "no_reference"
            status[a:b][~bad_ref & bad_s] = "no_data"
            with np.errstate(invalid="ignore"):
                std_r[a:b] = wr.std(axis=(1, 2))
            cloudy = sliding_window_view(msk, (w, w))[rr[a:b], cc[a:b]].mean(axis=(1, 2)) > opt.cloud_window_fraction
            status[a:b][(status[a:b] == "") & cloudy] = "cloud"
            go = np.flatnonzero(status[a:b] == "")
            if go.size == 0:
                continue
            pm = phase_correlate(wr[go], ws[go], max_shift_px=w / 4.0,
                                 backend="torch" if opt.backend in ("gpu", "torch") else "cpu",
                                 device="cuda" if opt.backend == "gpu" else None)
            shift[a + go, 0] = pm.shift_row_px
            shift[a + go, 1] = pm.shift_col_px
            score[a + go] = pm.score
            for code, name in _PHASE_REASON.items():
                status[a + go[pm.reason == code]] = name
        t_phase += time.perf_counter() - t1
        # water and other featureless ground, judged on the whole CCD
        texture_ok = np.isfinite(std_r)
        status[(status == "") & texture_ok & low_texture(std_r, texture_fraction=opt.texture_fraction)] = "no_texture"
        # local consistency on the window grid
        grid = np.where((status == "")[:, None], shift, np.nan).reshape(rs.size, cs.size, 2)
        consistent = local_consistency(grid).reshape(-1)
        status[(status == "") & ~consistent] = "inconsistent"
        keep = np.flatnonzero(status == "")
        r_c = rr[keep] + half  # window centres (continuous coordinates)
        c_c = cc[keep] + half + look.first_col
        sigma = float("nan")
        if keep.size:
            inl, sigma, _ = smooth_residuals(r_c, c_c, shift[keep, 0], shift[keep, 1])
            status[keep[~inl]] = "model_residual"
            keep, r_c, c_c = keep[inl], r_c[inl], c_c[inl]
        for r in REASONS:
            reasons[r] += int(np.sum(status == r))
        if keep.size:
            kw = {"ccd": i} if pushbroom else {}
            lon, lat, h = model_pc.image_to_ground(r_c.astype(np.float64), c_c.astype(np.float64), dem=dem,
                                                   band=band, **kw)
            ok = np.isfinite(lon)
            sig = np.full(ok.sum(), max(sigma, 0.01) if np.isfinite(sigma) else 0.1)
            tables.append({
                "row": r_c[ok] + shift[keep[ok], 0], "col": c_c[ok] + shift[keep[ok], 1],
                "lon": lon[ok], "lat": lat[ok], "h": h[ok], "sigma_px": sig,
                "band": np.full(ok.sum(), band or "", dtype=object), "ccd": np.full(ok.sum(), look.name, dtype=object),
                "score": score[keep[ok]],
            })
        cloud_sum += cloud_px * look.n_detectors
        per_ccd.append({
            "ccd": look.name, "windows": int(n), "gcps": int(keep.size),
            "usable_fraction": float(keep.size / n),
            "cloud_fraction": cloud_px,
            "cloud_windows": int(np.sum(status == "cloud")),
            "no_texture_fraction": float(np.mean(status == "no_texture")),
            "sigma_px": None if not np.isfinite(sigma) else sigma,
            "coverage": _coverage(r_c, c_c - look.first_col, img.shape),
        })
        if progress:
            progress(f"CCD {look.name}: {keep.size} GCPs from {n} windows")
    timings["reference_s"] = t_ref
    timings["phase_s"] = t_phase
    table = None
    if tables:
        table = GcpTable.from_arrays(**{k: np.concatenate([t[k] for t in tables]) for k in tables[0]})
        if opt.check_fraction > 0 and len(table) > 1:
            table = table.split_check(opt.check_fraction, seed=opt.seed)
    timings["total_s"] = time.perf_counter() - t0
    n_gcp = 0 if table is None else len(table)
    summary = {
        "kind": "gcpcal.match",
        "band": band,
        "gcps": int(0 if table is None else np.sum(table.kind == "gcp")),
        "check_points": int(0 if table is None else np.sum(table.kind == "check")),
        "windows": n_windows,
        "usable_fraction": n_gcp / max(n_windows, 1),
        "cloud_fraction": cloud_sum / scene.shape[1],
        "cloud_window_fraction": reasons["cloud"] / max(n_windows, 1),
        "rejected": reasons,
        "per_ccd": per_ccd,
        "coarse": coarse.summary(),
        "options": asdict(opt),
        "timings": timings,
        "matches_per_second": (n_windows - reasons["no_reference"] - reasons["no_data"] - reasons["cloud"])
        / max(t_phase, 1e-9),
    }
    if n_gcp == 0:
        summary["message"] = "no GCP: " + ", ".join(f"{k} {v}" for k, v in reasons.items() if v)
    return table, summary


def _coverage(row, col, shape, cells: int = 8) -> float:
    """Fraction of an 8 x 8 partition of the CCD image holding at least one GCP."""
    if row.size == 0:
        return 0.0
    i = np.clip((row / shape[0] * cells).astype(int), 0, cells - 1)
    j = np.clip((col / shape[1] * cells).astype(int), 0, cells - 1)
    return float(np.unique(i * cells + j).size / cells**2)


def read_band(model, band: str, image=None) -> np.ndarray:
    """The pixels of ``band`` (float32): ``image`` if given, else the manifest's raster."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError
    import warnings

    if image is None:
        rasters = getattr(model, "rasters", None) or {}
        if band not in rasters:
            raise InputError(f"the scene lists no raster for band {band!r}; give --image")
        path, index = rasters[band]["path"], int(rasters[band].get("index", 1))
    else:
        path, index = str(image), 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                data = ds.read(index, masked=True)
    except (RasterioError, IndexError) as exc:
        raise InputError(f"cannot read the scene raster ({exc})", path=path) from None
    return np.ma.filled(data.astype(np.float32), np.nan)
