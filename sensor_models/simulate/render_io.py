"""Helpers shared by the push-broom simulator's profiles: footprints, coverage, block rendering, outputs.

(:mod:`sensor_models.simulate.pushbroom_sim` renders the ``ideal`` profile,
:mod:`sensor_models.simulate.realistic_sim` the others; both write through these helpers.)
"""

from __future__ import annotations

import json
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyproj

from sensor_models.errors import InputError
from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES
from sensor_models.files.threads import libraries_single_threaded, thread_count
from sensor_models.maps.grid import MapGrid

__all__ = ["PhaseClock", "SetupProgress", "check_covers", "footprint_lonlat", "render_scene", "step_progress", "utm_crs",
           "write_outputs"]

#: set-up steps counted by the progress callback before the blocks (models, reference)
SETUP_STEPS = 2


class PhaseClock:
    """Wall-clock seconds of the phases of a simulation, in order.

    Parameters
    ----------
    t_start : float, optional
        ``time.perf_counter()`` at the start of the command (default: now).

    Attributes
    ----------
    seconds : dict of str to float
        Seconds of each phase marked so far, rounded to the millisecond.
    """

    def __init__(self, t_start: float | None = None):
        self.t_start = time.perf_counter() if t_start is None else t_start
        self._last = self.t_start
        self.seconds: dict[str, float] = {}

    def mark(self, name: str) -> float:
        """End phase ``name`` now.

        Parameters
        ----------
        name : str
            Phase name (a later mark of the same name adds to it).

        Returns
        -------
        float
            Seconds since the start.
        """
        now = time.perf_counter()
        self.seconds[name] = round(self.seconds.get(name, 0.0) + now - self._last, 3)
        self._last = now
        return now - self.t_start


class SetupProgress:
    """The set-up steps' progress: ``setup(k)`` reports step ``k`` (1-based) done.

    :meth:`part` counts parts of the step under way (e.g. strips of a procedural source radiance
    or of a procedural reference) before it ends: the total grows by the parts announced, so a
    long step shows a count rather than nothing (``progress(done, parts + SETUP_STEPS + blocks)``).
    """

    def __init__(self, progress, n_blocks: int):
        self._progress, self._n_blocks, self._parts = progress, int(n_blocks), 0
        self._steps_done = 0

    def _total(self) -> int:
        return self._parts + SETUP_STEPS + self._n_blocks

    def __call__(self, k: int) -> None:
        self._steps_done = int(k)
        self._progress(self._parts + int(k), self._total())

    def part(self, done: int, parts: int) -> None:
        """``done`` of the step under way's ``parts`` done (``parts`` the same at every call)."""
        self._parts = int(parts)
        self._progress(self._steps_done + int(done), self._total())

    def blocks(self, done: int, _total=None) -> None:
        """``done`` blocks of lines rendered (the callback :func:`render_scene` takes)."""
        self._progress(self._parts + SETUP_STEPS + int(done), self._total())


def step_progress(progress, n_rows: int, block_lines: int):
    """Progress over the set-up steps and the blocks: ``(setup, blocks)`` callbacks.

    Parameters
    ----------
    progress : callable(done, total) or None
        The caller's callback; it sees ``total = SETUP_STEPS + blocks`` (plus the parts of a
        set-up step announced through ``setup.part``) and ``done`` advancing once per
        part, per set-up step (models, reference) and per block of lines.
    n_rows : int
        Image lines.
    block_lines : int
        Lines per block.

    Returns
    -------
    setup : SetupProgress
        ``setup(k)`` reports set-up step ``k`` (1-based) done; ``setup.part(done, parts)`` the
        parts of the step under way.
    blocks : callable(done_blocks, total_blocks) or None
        The callback :func:`render_scene` takes.
    """
    if progress is None:
        return SetupProgress(lambda done, total: None, 0), None
    n_blocks = -(-int(n_rows) // max(1, int(block_lines)))
    setup = SetupProgress(progress, n_blocks)
    return setup, setup.blocks


def footprint_lonlat(model, heights_m, *, step_px: int = 32):
    """Lon/lat of the image border of every band at each height.

    Parameters
    ----------
    model : PushbroomModel
        The scene model (its ``bands`` and ``image_shape``).
    heights_m : iterable of float
        Ellipsoidal heights of the localization, metres.
    step_px : int
        Spacing of the border points, pixels (pixel centres, corners included).

    Returns
    -------
    lon_deg, lat_deg : ndarray, shape (N,)
        WGS84 degrees, every band and height concatenated (NaN where localization fails).
    """
    n_rows, n_cols = model.image_shape
    rows = np.linspace(0.5, n_rows - 0.5, max(2, n_rows // step_px + 1))
    cols = np.linspace(0.5, n_cols - 0.5, max(2, n_cols // step_px + 1))
    r = np.concatenate([rows, rows, np.full(cols.size, 0.5), np.full(cols.size, n_rows - 0.5)])
    c = np.concatenate([np.full(rows.size, 0.5), np.full(rows.size, n_cols - 0.5), cols, cols])
    lons, lats = [], []
    for band in model.bands:
        for h in heights_m:
            lon, lat, _ = model.image_to_ground(r, c, height=float(h), band=band)
            lons.append(lon)
            lats.append(lat)
    return np.concatenate(lons), np.concatenate(lats)


def utm_crs(lon: float, lat: float) -> pyproj.CRS:
    zone = int(np.floor((lon + 180.0) / 6.0)) % 60 + 1
    return pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


def check_covers(grid: MapGrid, lon, lat, *, what: str, path: str | None, margin_px: float = 2.0):
    tr = pyproj.Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True)
    x, y = tr.transform(lon, lat)
    a = grid.index_affine()
    u = a.a * np.asarray(x) + a.b * np.asarray(y) + a.c
    v = a.d * np.asarray(x) + a.e * np.asarray(y) + a.f
    n_rows, n_cols = grid.shape
    inside = (u >= margin_px) & (u <= n_cols - 1 - margin_px) & (v >= margin_px) & (v <= n_rows - 1 - margin_px)
    if not inside.all():
        frac = 1.0 - inside.mean()
        raise InputError(
            f"the {what} does not cover the scene footprint ({100 * frac:.0f} % of the border points "
            f"outside, footprint lon {lon.min():.4f}..{lon.max():.4f}, lat {lat.min():.4f}..{lat.max():.4f})",
            path=path or what,
        )


def _open_writer(path: Path, n_rows: int, n_cols: int, dtype: str):
    import rasterio

    return rasterio.open(
        path, "w", driver="GTiff", width=n_cols, height=n_rows, count=1, dtype=dtype,
        compress="deflate", predictor=2, zlevel=6, tiled=False, blockysize=16,
    )


def render_scene(renderer, model, tmp: Path, bands, ref_band, n_ccd, block_lines, workers, progress):
    """Render every block of lines into ``tmp/<band>.tif`` (and ``cloud_mask.tif`` with clouds).

    Returns ``(cloud pixels in the reference band, whether a cloud mask was written)``.
    GDAL's block cache is capped at
    :data:`sensor_models.files.gdal_cache.GDAL_BLOCK_CACHE_BYTES` meanwhile.
    """
    import rasterio

    workers = thread_count(workers)
    # GDAL keeps written blocks in its cache until the file closes (by default 5 % of the RAM):
    # without a cap the whole compressed scene would sit in memory
    with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES):
        return _render_blocks(renderer, model, tmp, bands, ref_band, n_ccd, block_lines, workers, progress)


def _render_blocks(renderer, model, tmp: Path, bands, ref_band, n_ccd, block_lines, workers, progress):
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.windows import Window

    n_rows, n_cols = model.image_shape
    blocks = [(r, min(n_rows, r + block_lines)) for r in range(0, n_rows, block_lines)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # raw sensor geometry
        writers = {b: _open_writer(tmp / f"{b}.tif", n_rows, n_cols, "uint16") for b in bands}
        mask_writer = (_open_writer(tmp / "cloud_mask.tif", n_rows, n_cols, "uint8")
                       if renderer.clouds is not None else None)
        # cloud shadows on the ground (realistic profile's clouds with height)
        shadow_writer = (_open_writer(tmp / "shadow_mask.tif", n_rows, n_cols, "uint8")
                         if getattr(renderer, "shadows", None) is not None else None)
    cloud_pixels = 0
    try:
        # one OpenCV and one BLAS thread per task: the tasks fill the cores
        with libraries_single_threaded(), ThreadPoolExecutor(max_workers=workers) as pool:

            for k, (r0, r1) in enumerate(blocks):
                jobs = {(b, c): pool.submit(renderer.task, b, c, r0, r1) for b in bands for c in range(n_ccd)}
                for b in bands:
                    block = np.zeros((r1 - r0, n_cols), dtype=np.uint16)
                    mask = np.zeros((r1 - r0, n_cols), dtype=np.uint8) if b == ref_band else None
                    shadow = np.zeros((r1 - r0, n_cols), dtype=np.uint8) if b == ref_band else None
                    for c, look in enumerate(model.band_ccds(b)):
                        dn, alpha, *rest = jobs[(b, c)].result()
                        cols = slice(look.first_col, look.first_col + look.n_detectors)
                        block[:, cols] = dn
                        if mask is not None and alpha is not None:
                            mask[:, cols] = alpha > 0.5
                        if shadow is not None and rest and rest[0] is not None:
                            shadow[:, cols] = rest[0]
                    writers[b].write(block, 1, window=Window(0, r0, n_cols, r1 - r0))
                    if mask is not None and mask_writer is not None:
                        mask_writer.write(mask, 1, window=Window(0, r0, n_cols, r1 - r0))
                        cloud_pixels += int(mask.sum())
                    if shadow is not None and shadow_writer is not None:
                        shadow_writer.write(shadow, 1, window=Window(0, r0, n_cols, r1 - r0))
                if progress is not None:
                    progress(k + 1, len(blocks))
    finally:
        for w in writers.values():
            w.close()
        if mask_writer is not None:
            mask_writer.close()
        if shadow_writer is not None:
            shadow_writer.close()
    return cloud_pixels, mask_writer is not None


def write_outputs(cfg, models, tmp: Path, initial, reference_files, dem_figures, clouds, render_seconds, workers,
                   t_start, record_timings, *, extra_truth=None, extra_summary=None, phases=None) -> dict:
    """Write the manifests, ``truth.json`` and ``summary.json`` of a rendered scene; return the summary.

    Parameters
    ----------
    cfg : SimConfig
        The effective configuration.
    models : SceneModels
        TRUE and LAB models.
    tmp : Path
        Output folder.
    initial : dict
        :func:`sensor_models.simulate.truth.truth_error` of the LAB model.
    reference_files : dict
        Reference file names (written into both documents).
    dem_figures : dict
        :func:`sensor_models.terrain.footprint.check_dem_footprint` of the user's DEM.
    clouds : (int, bool)
        Cloud pixels of the reference band, whether a mask was written.
    render_seconds : float
        Rendering time: from the start of the command to the last block written (models,
        reference and blocks).
    workers : int
        Rendering threads (the count used).
    t_start : float
        ``time.perf_counter()`` at the start.
    record_timings : bool
        Keep the timings in ``summary.json``.
    extra_truth, extra_summary : dict, optional
        Appended to ``truth.json`` and ``summary.json``.
    phases : PhaseClock, optional
        Phase times so far; ``outputs`` is marked here and ``phase_seconds`` added to the summary
        (with the other timings, only when ``record_timings``).

    Returns
    -------
    dict
        The summary.
    """
    from sensor_models.readers.manifest import write_manifest

    model = models.true_model
    n_rows, n_cols = model.image_shape
    bands = list(cfg.camera.bands)
    n_ccd = len(model.band_ccds(cfg.camera.reference_band))
    cloud_pixels, has_mask = clouds
    rasters = {b: str(tmp / f"{b}.tif") for b in bands}
    write_manifest(models.lab_model, tmp / "manifest.json", rasters=rasters)
    write_manifest(models.true_model, tmp / "truth_manifest.json", rasters=rasters)
    truth = {
        "format_version": 1,
        "kind": "gcpcal.simulate.pushbroom",
        "seed": cfg.seed,
        "true_model": "truth_manifest.json",
        "lab_model": "manifest.json",
        "reference": reference_files,
        "clouds": {"cover_requested": cfg.clouds.cover, "mask": "cloud_mask.tif" if has_mask else None},
        **models.truth,
        "config": _truth_config(cfg),
        **(extra_truth or {}),
    }
    pixels = n_rows * n_cols * len(bands)
    summary = {
        "kind": "gcpcal.simulate.pushbroom",
        "seed": cfg.seed,
        "image": {"n_rows": n_rows, "n_cols": n_cols, "bands": bands, "ccds": n_ccd},
        "files": {**{b: f"{b}.tif" for b in bands}, "manifest": "manifest.json",
                  "truth": "truth.json", "truth_manifest": "truth_manifest.json",
                  **({"cloud_mask": "cloud_mask.tif"} if has_mask else {})},
        "reference": reference_files,
        "cloud_fraction": cloud_pixels / float(n_rows * n_cols),
        "dem_coverage": dem_figures["dem_coverage"],
        "dem_void_fraction": dem_figures["dem_void_fraction"],
        "warnings": dem_figures["warnings"],
        "lab_truth_error_px": {"rms": initial["rms_px"], "max": initial["max_px"],
                               "mean_row": initial["mean_row_px"], "mean_col": initial["mean_col_px"]},
        **(extra_summary or {}),
        "render_seconds": render_seconds,
        "pixels_per_second": pixels / render_seconds,
        "workers": workers,
    }
    _write_json(tmp / "truth.json", truth)
    if phases is not None:
        phases.mark("outputs")
        summary["phase_seconds"] = dict(phases.seconds)
    summary["seconds"] = time.perf_counter() - t_start
    if not record_timings:
        timings = ("render_seconds", "pixels_per_second", "seconds", "phase_seconds")
        summary = {k: v for k, v in summary.items() if k not in timings}
    _write_json(tmp / "summary.json", summary)
    return summary


def _write_json(path: Path, doc: dict) -> None:
    path.write_text(json.dumps(doc, indent=1, sort_keys=False) + "\n", encoding="utf-8")


def _truth_config(cfg) -> dict:
    """The configuration recorded in ``truth.json``; a white orbit error (``orbit_noise_period_s``
    0, the ideal profile's) is left out, so that files written before that setting existed stay
    byte-identical (reading them back gives the same default)."""
    out = cfg.to_dict()
    if out["errors"].get("orbit_noise_period_s") == 0.0:
        del out["errors"]["orbit_noise_period_s"]
    return out

