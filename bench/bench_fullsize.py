"""Benchmark: the full-size seed-003 scene end to end: time, memory and accuracy at full size.

Seed 003's acquisition (HY-1C CZI): 2 cameras x 2 CCDs of about 5 450 detectors (21 800 in all) over
a +-31 degree view, 4 bands, about 60 s. The geometry is ``bench/fullsize_seed003.json`` (a
``gcpcal simulate --config`` document): 4 x 5 450 detectors (12 overlapping), 8192 lines at 45 m
nadir GSD, i.e. +-32.0 degrees on the flat focal plane of the simulator and 8192 lines of 6.6 ms
(about 55 s). ``--scale F`` multiplies the detectors per CCD and the lines by ``F`` (same GSD, so
the footprint area and the pixel count scale as ``F**2``) for a quick check or an extrapolation.

Each stage runs as the command a user types (``gcpcal ...``, ``PYTHONPATH`` = this checkout), as a
child process; its wall time, CPU time (user + sys of the child and what it waited for, from
``os.wait4``) and peak RSS (``ru_maxrss``) are recorded, with ``/proc/loadavg`` before and after:

1. ``gcpcal simulate pushbroom --config CFG --workers 2`` (cached in ``--cache``: skipped when its
   ``summary.json`` is there), under ``--profile``:

   * ``realistic``: ``--profile realistic`` (procedural source radiance, the profile's kernel,
     degraded DOM and DEM as references). Its source grid is the footprint's bounding box: at full
     size over the procedural generator's pixel cap, with a TRUE DEM held whole (docs/speed.md), so
     it runs at reduced ``--scale`` or ``--lines`` only;
   * ``ideal-dom``: ``--dom DOM --dem DEM`` (ideal kernel, bounded memory) from a synthetic DOM
     (30 m value noise) and DEM (6 arc-seconds) written by strips under ``<cache>/inputs_scale<F>``
     (not timed), with the realistic profile's attitude and orbit magnitudes in the TRUE model
     (``--orbit-noise-m`` overrides the orbit's white noise). The references are what rendered
     the scene;
2. ``gcpcal match`` of the reference band against the user's DOM and DEM;
3. ``gcpcal calibrate`` (default ``--attitude auto``) and ``gcpcal calibrate --attitude static``
   (``--no-report``);
4. ``gcpcal relative`` for each of the two calibrations;
5. ``gcpcal truth error`` of the LAB and each calibrated model against ``truth_manifest.json`` over
   the TRUE DEM, every ``--truth-step`` lines and samples, reference band and every band.

The machine is shared: CPU time / 2 is reported beside the wall time as the estimate for a quiet
2-core machine. Not run in CI (minutes to an hour); ``tests/test_bench_fullsize.py`` runs a tiny scale.

Usage::

    python bench/bench_fullsize.py [--scale 1.0] [--cache /tmp/fullsize] [--profile realistic|ideal-dom]
        [--bands B1,B2,B3,B4] [--stages ...,truth] [--truth-step 16] [--out bench/results/fullsize.json]

    # the full-size run of docs/speed.md
    python bench/bench_fullsize.py --scale 1 --profile ideal-dom --bands B2,B4 --truth-step 64

    # the seed's full width (+-32 deg) under realistic errors over a strip of 512 lines, then the
    # same render matched and calibrated with the TRUE DEM as the user's DEM (docs/experiments.md)
    python bench/bench_fullsize.py --scale 1 --lines 512 --dom-resolution-m 45 --bands B2,B4 --cache /tmp/fw
    python bench/bench_fullsize.py --scale 1 --lines 512 --dom-resolution-m 45 --bands B2,B4 --cache /tmp/fw \
        --user-dem true

``--lines N`` sets the image lines after scaling (the cache folder and the default ``--out`` name
them); ``--user-dem true`` writes match, calibrate, relative and truth under
``<cache>/userdem_true``, the render reused. After ``match``, the GCP truth error (matched
``(row, col)`` minus the TRUE projection of each GCP's ground point) is recorded pooled and by
off-nadir angle (``bench/gcp_truth.py``).

Writes ``--out`` (default ``bench/results/fullsize.json``, or ``fullsize_scale<F>.json`` when
``--scale`` is not 1, ``fullsize_scale<F>_lines<N>.json`` with ``--lines``, ``_userdem_true``
appended with ``--user-dem true``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "bench" / "fullsize_seed003.json"
STAGES = ("simulate", "match", "calibrate_auto", "calibrate_static", "relative_auto", "relative_static")


# ---------------------------------------------------------------- configuration
def scaled_config(scale: float, bands: list[str] | None = None, lines: int | None = None) -> dict:
    """The simulation configuration at ``scale`` (detectors per CCD and lines times ``scale``).

    Parameters
    ----------
    scale : float
        In (0, 1]; 1 is seed 003's size.
    bands : list of str, optional
        Subset of the default bands (B1-B4) to render; the reference band B2 must be in it.
    lines : int, optional
        Number of image lines (after scaling), at least 64; default: the scaled 8192. A strip of
        lines at ``scale`` 1 has the seed's full width (+-32 deg) in a fraction of its area.

    Returns
    -------
    dict
        A ``gcpcal simulate pushbroom --config`` document.
    """
    if not 0.0 < scale <= 1.0:
        raise SystemExit(f"--scale must be in (0, 1], got {scale}")
    cfg = json.loads(CONFIG.read_text())
    cam, scene = cfg["camera"], cfg["scene"]
    cam["detectors_per_ccd"] = max(64, int(round(cam["detectors_per_ccd"] * scale)))
    scene["n_rows"] = max(256, int(round(scene["n_rows"] * scale)))
    if lines is not None:
        if lines < 64:
            raise SystemExit(f"--lines must be at least 64, got {lines}")
        scene["n_rows"] = int(lines)
    if bands is not None and list(bands) != ["B1", "B2", "B3", "B4"]:
        if "B2" not in bands:
            raise SystemExit("--bands must hold the reference band B2")
        every = {"B1": -6.0, "B2": -2.0, "B3": 2.0, "B4": 6.0}
        cam["bands"], cam["band_offsets_px"] = list(bands), [every[b] for b in bands]
        gains = {"B1": (0.85, 60.0, 1.1), "B2": (1.0, 40.0, 1.0), "B3": (0.9, 50.0, 0.95), "B4": (1.1, 30.0, 0.85)}
        cfg["radiometry"] = {"band_gain": [gains[b][0] for b in bands],
                             "band_offset_dn": [gains[b][1] for b in bands],
                             "band_gamma": [gains[b][2] for b in bands]}
    return cfg


# ---------------------------------------------------------------- streamed inputs (ideal-dom)
#: the realistic profile's attitude and orbit magnitudes (sensor_models/simulate/profiles.py,
#: ``_realistic``), written into the configuration's TRUE-model errors for the ideal kernel
REALISTIC_ATTITUDE = {"jitter_amplitude_urad": [5.0, 5.0, 2.0], "jitter_frequency_hz": 0.3,
                      "attitude_drift_arcsec_s": [0.05, -0.04, 0.02], "attitude_noise_urad": 3.0,
                      "orbit_noise_m": 1.0, "orbit_noise_period_s": 600.0}
#: value-noise octaves of the synthetic DOM: (cell in DOM pixels, amplitude)
DOM_OCTAVES = ((6, 0.6), (24, 0.7), (96, 0.6), (384, 0.5))
DOM_WHITE = 0.4  # white-noise amplitude (relative to the octaves' unit amplitude)
DOM_RESOLUTION_M = 30.0  # Landsat-like
DEM_STEP_ARCSEC = 6.0  # the simulator and the matcher hold the whole DEM: ~100 bytes per node


def noise_strip(r0: int, r1: int, n_cols: int, cell: int, seed: int, octave: int) -> np.ndarray:
    """Rows ``r0:r1`` of a seamless value-noise layer (unit normal nodes every ``cell`` pixels).

    Each node row is drawn from its own seeded generator, so strips of any height join without
    seams and no whole-raster array is held. Interpolation is separable, smoothstep-weighted.

    Parameters
    ----------
    r0, r1 : int
        First and past-the-end rows.
    n_cols : int
        Raster width, pixels.
    cell : int
        Node spacing, pixels.
    seed, octave : int
        Seed the node rows.

    Returns
    -------
    ndarray, shape (r1 - r0, n_cols), float32
    """
    j0, j1 = r0 // cell, (r1 - 1) // cell + 1
    n_nodes = n_cols // cell + 2
    nodes = np.stack([np.random.default_rng([seed, octave, j]).standard_normal(n_nodes, dtype=np.float32)
                      for j in range(j0, j1 + 1)])
    x = np.arange(n_cols)
    fx = ((x % cell) / cell).astype(np.float32)
    fx = fx * fx * (3.0 - 2.0 * fx)
    ix = x // cell
    across = nodes[:, ix] * (1.0 - fx) + nodes[:, ix + 1] * fx
    y = np.arange(r0, r1)
    fy = ((y % cell) / cell).astype(np.float32)[:, None]
    fy = fy * fy * (3.0 - 2.0 * fy)
    iy = y // cell - j0
    return across[iy] * (1.0 - fy) + across[iy + 1] * fy


def write_dom(path: Path, bounds_m, crs_wkt: str, *, resolution_m: float = DOM_RESOLUTION_M, seed: int = 7,
              strip_rows: int = 512) -> list[int]:
    """A tiled uint16 DOM of multi-octave value noise over ``bounds_m`` (x0, y0, x1, y1), written by strips.

    Returns
    -------
    list of int
        ``[rows, cols]`` of the raster.
    """
    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    from sensor_models.files.gdal_cache import GDAL_BLOCK_CACHE_BYTES

    x0, y0, x1, y1 = bounds_m
    n_cols, n_rows = int(np.ceil((x1 - x0) / resolution_m)), int(np.ceil((y1 - y0) / resolution_m))
    profile = dict(driver="GTiff", width=n_cols, height=n_rows, count=1, dtype="uint16", crs=crs_wkt, tiled=True,
                   blockxsize=512, blockysize=512, BIGTIFF="YES",
                   transform=Affine(resolution_m, 0.0, x0, 0.0, -resolution_m, y1))
    norm = float(np.sqrt(sum(a * a for _, a in DOM_OCTAVES) + DOM_WHITE**2))
    with rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES), rasterio.open(path, "w", **profile) as dst:
        for r0 in range(0, n_rows, strip_rows):
            r1 = min(n_rows, r0 + strip_rows)
            layer = np.random.default_rng([seed, 99, r0]).standard_normal((r1 - r0, n_cols), dtype=np.float32)
            layer *= DOM_WHITE
            for k, (cell, amp) in enumerate(DOM_OCTAVES):
                layer += amp * noise_strip(r0, r1, n_cols, cell, seed, k)
            dn = np.clip(1800.0 + 600.0 * layer / norm, 100.0, 4000.0).astype(np.uint16)
            dst.write(dn, 1, window=Window(0, r0, n_cols, r1 - r0))
    return [n_rows, n_cols]


def write_dem(path: Path, lon_range, lat_range, *, step_arcsec: float = DEM_STEP_ARCSEC, seed: int = 11) -> list[int]:
    """A geographic float32 DEM (ellipsoidal heights, ~0-1900 m of value-noise relief) over the ranges."""
    import rasterio
    from rasterio.transform import from_origin

    step = step_arcsec / 3600.0
    n_rows = int(np.ceil((lat_range[1] - lat_range[0]) / step))
    n_cols = int(np.ceil((lon_range[1] - lon_range[0]) / step))
    relief = 0.7 * noise_strip(0, n_rows, n_cols, 40, seed, 0) + 0.3 * noise_strip(0, n_rows, n_cols, 10, seed, 1)
    heights = np.clip(900.0 + 450.0 * relief, 0.0, None).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=n_cols, height=n_rows, count=1, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(lon_range[0], lat_range[1], step, step), tiled=True) as dst:
        dst.write(heights, 1)
        dst.update_tags(VERTICAL_DATUM="ellipsoid")
    return [n_rows, n_cols]


def prepare_streamed_inputs(cache: Path, cfg: dict) -> dict:
    """DOM (UTM, 30 m) and DEM (6", ellipsoid) over the TRUE footprint plus 3 km, for ``--profile ideal-dom``.

    Returns
    -------
    dict
        Paths, sizes and the seconds it took (not part of any timed stage).
    """
    import pyproj

    from sensor_models.simulate.config import config_from_dict
    from sensor_models.simulate.render_io import footprint_lonlat, utm_crs
    from sensor_models.simulate.scene import build_models

    dom, dem = inputs_dir(cache) / "dom.tif", inputs_dir(cache) / "dem.tif"
    facts_path = inputs_dir(cache) / "inputs.json"
    if facts_path.exists():
        return json.loads(facts_path.read_text())
    dom.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    model = build_models(config_from_dict(cfg)).true_model
    lon, lat = footprint_lonlat(model, (-200.0, 2300.0))
    crs = utm_crs(float(np.nanmean(lon)), float(np.nanmean(lat)))
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    pad = 3000.0
    dom_shape = write_dom(dom, (np.nanmin(x) - pad, np.nanmin(y) - pad, np.nanmax(x) + pad, np.nanmax(y) + pad),
                          crs.to_wkt())
    dem_shape = write_dem(dem, (np.nanmin(lon) - 0.05, np.nanmax(lon) + 0.05), (np.nanmin(lat) - 0.05, np.nanmax(lat) + 0.05))
    facts = {"dom": str(dom), "dem": str(dem), "dom_px": dom_shape, "dom_resolution_m": DOM_RESOLUTION_M,
             "dem_nodes": dem_shape, "dem_step_arcsec": DEM_STEP_ARCSEC, "seconds": round(time.perf_counter() - t0, 1)}
    facts_path.write_text(json.dumps(facts, indent=1))
    print(f"inputs: DOM {dom_shape[0]} x {dom_shape[1]} px, DEM {dem_shape[0]} x {dem_shape[1]} nodes "
          f"in {facts['seconds']} s", flush=True)
    return facts


# ---------------------------------------------------------------- measurement
def loadavg() -> list[float]:
    """The 1, 5 and 15 minute load averages of the machine."""
    return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]


def run_measured(name: str, cmd: list[str], log_dir: Path, timeout_s: float) -> dict:
    """Run ``cmd`` as a child; its exit status, wall time, CPU time and peak RSS.

    Parameters
    ----------
    name : str
        Stage name (the log files are ``log_dir/<name>.out`` and ``.err``).
    cmd : list of str
        The command (``gcpcal ...``).
    log_dir : Path
    timeout_s : float
        The child is killed after this many seconds.

    Returns
    -------
    dict
        ``rc``, ``wall_s``, ``cpu_s`` (user + sys of the child and its waited-for descendants),
        ``cpu_s_half`` (the 2-core estimate), ``peak_rss_mib`` (``ru_maxrss``), ``loadavg_start``,
        ``loadavg_end``, ``stderr_tail``, ``command``.
    """
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    load0, t0 = loadavg(), time.perf_counter()
    with open(log_dir / f"{name}.out", "w") as out, open(log_dir / f"{name}.err", "w") as err:
        child = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=out, stderr=err)
        deadline, status, usage = t0 + timeout_s, None, None
        while status is None:
            pid, st, ru = os.wait4(child.pid, os.WNOHANG)
            if pid == child.pid:
                status, usage = st, ru
            elif time.perf_counter() > deadline:
                child.kill()
            else:
                time.sleep(0.2)
        child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    cpu = usage.ru_utime + usage.ru_stime
    tail = (log_dir / f"{name}.err").read_text().strip().splitlines()[-3:]
    rec = {"command": " ".join(str(c) for c in cmd), "rc": child.returncode, "wall_s": round(wall, 2),
           "cpu_s": round(cpu, 2), "cpu_s_half": round(cpu / 2.0, 2), "peak_rss_mib": round(usage.ru_maxrss / 1024.0, 1),
           "loadavg_start": load0, "loadavg_end": loadavg(), "stderr_tail": tail}
    print(f"{name:17s} rc={rec['rc']:<3d} wall {wall:8.1f} s  cpu {cpu:8.1f} s (/2: {cpu / 2:7.1f} s)  "
          f"peak RSS {rec['peak_rss_mib']:7.0f} MiB  load {load0[0]:.1f}->{rec['loadavg_end'][0]:.1f}", flush=True)
    return rec


# ---------------------------------------------------------------- the chain
def gcpcal_command() -> str:
    """The ``gcpcal`` console script of this interpreter's environment (it imports from ``PYTHONPATH``)."""
    script = Path(sys.executable).parent / "gcpcal"
    if not script.exists():
        raise SystemExit(f"no gcpcal script beside {sys.executable}: install the project (pip install -e .)")
    return str(script)


def reference_paths(cache: Path, profile: str, user_dem: str = "given") -> dict:
    """The user's DOM and DEM given to match/relative, and the TRUE DEM of the truth error.

    ``realistic``: the simulator's degraded ``reference/dom.tif`` and ``dem.tif`` (not what rendered
    the scene) and ``reference/truth/dem_true.tif``. ``ideal-dom``: the streamed inputs, which
    rendered the scene (the ideal profile's reference is the rendering DOM and DEM itself).
    ``user_dem="true"`` (realistic): the TRUE DEM is given as the user's DEM, so the DEM error's
    share of the results shows against the ``given`` run of the same scene.
    """
    if profile == "realistic":
        ref = cache / "scene" / "reference"
        true_dem = ref / "truth" / "dem_true.tif"
        return {"dom": ref / "dom.tif", "dem": true_dem if user_dem == "true" else ref / "dem.tif",
                "true_dem": true_dem}
    inputs = inputs_dir(cache)
    return {"dom": inputs / "dom.tif", "dem": inputs / "dem.tif", "true_dem": inputs / "dem.tif"}


def inputs_dir(cache: Path) -> Path:
    """The streamed DOM and DEM of a size, shared by the runs of that size.

    ``<cache root>/inputs_scale<F>``, or ``inputs_scale<F>_lines<N>`` for a ``--lines`` run (its
    footprint differs from the scale's).
    """
    parts = cache.name.split("_")
    size = parts[:2] if len(parts) > 1 and parts[1].startswith("lines") else parts[:1]
    return cache.parent / ("inputs_" + "_".join(size))


def work_dir(cache: Path, user_dem: str = "given") -> Path:
    """Where match, calibrate, relative and truth write: the cache, or ``<cache>/userdem_true``."""
    return cache if user_dem == "given" else cache / f"userdem_{user_dem}"


def stage_commands(cache: Path, profile: str, workers: int, user_dem: str = "given") -> dict:
    """Every timed stage's command line (the ``gcpcal`` script; ``PYTHONPATH`` picks this checkout).

    The scene is ``<cache>/scene``; the other stages write under :func:`work_dir`.
    """
    g = [gcpcal_command()]
    scene, ref = cache / "scene", reference_paths(cache, profile, user_dem)
    work = work_dir(cache, user_dem)
    sim = g + ["simulate", "pushbroom", "--config", str(cache / "config.json"), "--out", str(scene), "--workers",
               str(workers), "-q"]
    sim += ["--profile", "realistic"] if profile == "realistic" else ["--dom", str(ref["dom"]), "--dem", str(ref["dem"])]
    cmds = {"simulate": sim,
            "match": g + ["match", str(scene / "manifest.json"), "--dom", str(ref["dom"]), "--dem",
                          str(ref["dem"]), "--out", str(work / "gcps.csv"), "-q"]}
    for att in ("auto", "static"):
        cmds[f"calibrate_{att}"] = g + ["calibrate", str(scene / "manifest.json"), "--gcps", str(work / "gcps.csv"),
                                       "--out", str(work / f"cal_{att}"), "--attitude", att, "--no-report", "-q"]
        cmds[f"relative_{att}"] = g + ["relative", str(scene / "manifest.json"), "--calibration",
                                      str(work / f"cal_{att}"), "--dem", str(ref["dem"]), "--out",
                                      str(work / f"rel_{att}"), "-q"]
    return cmds


def truth_error_of(cache: Path, profile: str, name: str, step_px: float, log_dir: Path, timeout_s: float,
                   work: Path | None = None):
    """``gcpcal truth error`` of one model (``lab``, ``cal_auto``, ``rel_static``...) over the TRUE DEM.

    Returns
    -------
    dict or None
        The reference band's and every band's RMS and max (px; :func:`summarize_truth`) and the
        command's wall time; None when that model was not written. ``work`` (default ``cache``)
        holds the calibrations and receives ``truth_<name>.json``.
    """
    scene, work = cache / "scene", work or cache
    manifest = scene / "manifest.json" if name == "lab" else work / name / "manifest.json"
    if not manifest.exists():
        return None
    ref_band = json.loads((scene / "summary.json").read_text()).get("image", {}).get("reference_band", "B2")
    res = work / f"truth_{name}.json"
    cmd = [gcpcal_command(), "truth", "error", str(manifest), "--truth", str(scene / "truth_manifest.json"),
           "--dem", str(reference_paths(cache, profile)["true_dem"]), "--step", str(step_px), "--out", str(res), "-q"]
    rec = run_measured(f"truth_{name}", cmd, log_dir, timeout_s)
    out = summarize_truth(json.loads(res.read_text()), ref_band) if rec["rc"] == 0 else {"rc": rec["rc"]}
    out["wall_s"], out["cpu_s"] = rec["wall_s"], rec["cpu_s"]
    return out


def summarize_truth(result: dict, ref_band: str) -> dict:
    """Reference-band and all-band RMS / max of a ``gcpcal truth error`` result (per-CCD rows)."""
    rows = [r for r in result.get("per_ccd", []) if r.get("n_points")]

    def pooled(sel):
        if not sel:
            return {"rms_px": None, "max_px": None, "n_points": 0}
        n = np.array([r["n_points"] for r in sel], dtype=np.float64)
        rms = np.array([r["rms_px"] for r in sel], dtype=np.float64)
        return {"rms_px": round(float(np.sqrt(np.sum(n * rms**2) / n.sum())), 4),
                "max_px": round(float(max(r["max_px"] for r in sel)), 4), "n_points": int(n.sum())}

    per_band = {b: pooled([r for r in rows if r.get("band") == b]) for b in sorted({r.get("band") for r in rows})}
    per_ccd = {r["ccd"]: {"rms_px": round(float(r["rms_px"]), 4), "max_px": round(float(r["max_px"]), 4),
                          "mean_row_px": round(float(r["mean_row_px"]), 4), "mean_col_px": round(float(r["mean_col_px"]), 4)}
               for r in rows if r.get("band") == ref_band and "ccd" in r}
    return {"reference_band": pooled([r for r in rows if r.get("band") == ref_band]), "all_bands": pooled(rows),
            "per_band": per_band, "reference_band_per_ccd": per_ccd}


def check_figures(cache: Path) -> dict:
    """GCP counts and the check-point RMSE before/after of each calibration."""
    out = {}
    summ = cache / "gcps.summary.json"
    if summ.exists():
        s = json.loads(summ.read_text())
        out["match"] = {k: s.get(k) for k in ("gcps", "check_points", "timings") if k in s}
    for att in ("auto", "static"):
        cal = cache / f"cal_{att}" / "calibration.json"
        if cal.exists():
            c = json.loads(cal.read_text())
            acc = c.get("check_accuracy") or {}
            out[f"calibrate_{att}"] = {
                "check_rmse_px": {w: ((acc.get(w) or {}).get("absolute") or {}).get("rmse_px") for w in ("before", "after")},
                "status": (c.get("status") or {}).get("status"), "attitude": _attitude_choice(c)}
    return out


def _attitude_choice(cal: dict):
    """The attitude correction a calibration chose (kind and number of terms), from ``calibration.json``."""
    att = cal.get("attitude")
    if not isinstance(att, dict):
        return att
    chosen = [c for c in att.get("candidates", []) if c.get("chosen")]
    return {"mode": att.get("mode"), "chosen": {k: chosen[0].get(k) for k in ("kind", "n_terms")} if chosen else None}


def default_out_name(scale: float, lines: int | None, user_dem: str = "given") -> str:
    """``fullsize.json``, ``fullsize_scale<F>.json``; ``fullsize_scale<F>_lines<N>.json`` with ``--lines``;
    ``_userdem_true`` appended with ``--user-dem true``."""
    tag = "" if user_dem == "given" else f"_userdem_{user_dem}"
    if lines is None:
        return ("fullsize" if scale == 1.0 else f"fullsize_scale{scale:g}") + tag + ".json"
    return f"fullsize_scale{scale:g}_lines{lines}{tag}.json"


def _parse(argv) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0, help="detectors and lines times F (default 1: full size)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fullsize"), help="scene and outputs (default /tmp/fullsize)")
    ap.add_argument("--profile", default="realistic", choices=["realistic", "ideal-dom"],
                    help="realistic: the simulator's realistic profile (procedural source, whole in memory); "
                         "ideal-dom: the ideal kernel from a streamed synthetic DOM and DEM, with the realistic "
                         "profile's attitude and orbit magnitudes in the TRUE model")
    ap.add_argument("--lines", type=int, default=None,
                    help="image lines after scaling (default: the scaled 8192); with --scale 1, the seed's full "
                         "width over a strip of N lines")
    ap.add_argument("--dom-resolution-m", type=float, default=None,
                    help="realistic: the procedural source/DOM pixel, m (default: the configuration's 22.5; the "
                         "simulator caps the DOM at 150 M pixels, which the full width's north-up box exceeds)")
    ap.add_argument("--user-dem", default="given", choices=["given", "true"],
                    help="realistic: the DEM given to match and relative: the simulator's degraded reference DEM "
                         "(given) or the TRUE DEM (true: outputs under <cache>/userdem_true, the render reused)")
    ap.add_argument("--bands", default="B1,B2,B3,B4", help="bands to render (B2, the reference, included)")
    ap.add_argument("--orbit-noise-m", type=float, default=None,
                    help="ideal-dom: white noise of the measured orbit per sample, m (default: the realistic 1 m)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--stages", default=",".join(STAGES + ("truth",)),
                    help="stages to run, comma-separated (simulate is skipped when cached; truth: the truth errors)")
    ap.add_argument("--truth-step", type=float, default=16.0, help="truth-error grid spacing, px")
    ap.add_argument("--timeout", type=float, default=3600.0, help="per command, s")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.orbit_noise_m is not None and args.profile != "ideal-dom":
        raise SystemExit("--orbit-noise-m applies to --profile ideal-dom")
    if args.user_dem != "given" and args.profile != "realistic":
        raise SystemExit("--user-dem applies to --profile realistic")
    return args


def _setup(args) -> tuple[Path, dict, Path, list[str]]:
    """The cache folder (named by size, profile, bands and options), its configuration, --out, the bands."""
    bands = [b.strip() for b in args.bands.split(",") if b.strip()]
    tag = "" if args.orbit_noise_m is None else f"_orbit{args.orbit_noise_m:g}m"
    tag += "" if args.dom_resolution_m is None else f"_dom{args.dom_resolution_m:g}m"
    size = f"scale{args.scale:g}" + ("" if args.lines is None else f"_lines{args.lines}")
    cache = args.cache / (f"{size}_{args.profile}_{''.join(bands)}{tag}")
    cfg = scaled_config(args.scale, bands, args.lines)
    if args.dom_resolution_m is not None:
        cfg["reference"]["dom_resolution_m"] = args.dom_resolution_m
    if args.profile == "ideal-dom":
        cfg["errors"] = dict(REALISTIC_ATTITUDE)
        if args.orbit_noise_m is not None:
            cfg["errors"]["orbit_noise_m"] = args.orbit_noise_m
    (work_dir(cache, args.user_dem) / "logs").mkdir(parents=True, exist_ok=True)
    (cache / "config.json").write_text(json.dumps(cfg, indent=1))
    out = args.out or ROOT / "bench" / "results" / default_out_name(args.scale, args.lines, args.user_dem)
    return cache, cfg, out, bands


def main(argv=None) -> int:
    args = _parse(argv)
    cache, cfg, out, bands = _setup(args)
    work = work_dir(cache, args.user_dem)
    cmds, wanted = stage_commands(cache, args.profile, args.workers, args.user_dem), set(args.stages.split(","))
    result = {"scale": args.scale, "lines": cfg["scene"]["n_rows"], "profile": args.profile, "bands": bands,
              "user_dem": args.user_dem, "config": cfg, "cache": str(cache), "work": str(work),
              "cpu_count": os.cpu_count(), "python": platform.python_version(), "loadavg_start": loadavg(),
              "stages": {}}
    if args.profile == "ideal-dom":
        result["inputs"] = prepare_streamed_inputs(cache, cfg)
    if (cache / "scene" / "summary.json").exists():
        print(f"simulate: cached in {cache / 'scene'}")
        wanted.discard("simulate")
    refs = reference_paths(cache, args.profile, args.user_dem)
    result["user_dem_path"] = str(refs["dem"])
    result["truth_error"] = {"dem": str(refs["true_dem"]), "step_px": args.truth_step}
    graded = {"calibrate_static": ("lab", "cal_auto", "cal_static"), "relative_auto": ("rel_auto",),
              "relative_static": ("rel_static",)}
    for name in STAGES:
        if name in wanted:
            result["stages"][name] = rec = run_measured(name, cmds[name], work / "logs", args.timeout)
            if name in ("simulate", "match") and rec["rc"] not in (0, 4):
                break
        if name == "match" and "truth" in wanted:
            result["gcp_truth_error"] = gcp_truth_of(cache, work)
        for model in graded.get(name, ()) if "truth" in wanted else ():
            result["truth_error"][model] = truth_error_of(cache, args.profile, model, args.truth_step,
                                                          work / "logs", args.timeout, work)
        _write(result, cache, out, work)
    _write(result, cache, out, work)
    print(json.dumps({k: result[k] for k in ("scene", "accuracy", "gcp_truth_error", "truth_error",
                                             "match_plus_calibrate") if k in result}, indent=1, default=str))
    print(f"wrote {out}")
    return 0


def gcp_truth_of(cache: Path, work: Path):
    """GCP truth error of ``<work>/gcps.csv`` against the TRUE model, pooled and by off-nadir angle.

    Returns
    -------
    dict or None
        :func:`gcp_truth.gcp_truth_by_angle` (``bench/gcp_truth.py``) and its wall time; None when
        no GCP table was written.
    """
    gcps, truth = work / "gcps.csv", cache / "scene" / "truth_manifest.json"
    if not (gcps.exists() and truth.exists()):
        return None
    sys.path.insert(0, str(ROOT / "bench"))
    from gcp_truth import gcp_truth_by_angle

    t0 = time.perf_counter()
    res = gcp_truth_by_angle(truth, gcps)
    res["wall_s"] = round(time.perf_counter() - t0, 2)
    return res


def _write(result: dict, cache: Path, out: Path, work: Path | None = None) -> None:
    """Complete ``result`` with the scene facts and figures so far and write it (after every stage)."""
    result["scene"] = _scene_facts(cache)
    result["accuracy"] = check_figures(work or cache)
    result["loadavg_end"] = loadavg()
    mc = [result["stages"].get(k) for k in ("match", "calibrate_auto")]
    if all(mc):
        result["match_plus_calibrate"] = {k: round(sum(r[k] for r in mc), 2) for k in ("wall_s", "cpu_s", "cpu_s_half")}
        result["match_plus_calibrate"]["peak_rss_mib"] = max(r["peak_rss_mib"] for r in mc)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, default=str) + "\n")


def _scene_facts(cache: Path) -> dict:
    summ = cache / "scene" / "summary.json"
    if not summ.exists():
        return {}
    s = json.loads(summ.read_text())
    du = sum(f.stat().st_size for f in (cache / "scene").rglob("*") if f.is_file())
    return {"image": s.get("image"), "seconds": s.get("seconds"), "phase_seconds": s.get("phase_seconds"),
            "injected": s.get("injected"), "disk_mib": round(du / 2**20, 1)}


if __name__ == "__main__":
    sys.exit(main())
