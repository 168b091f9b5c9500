"""The GPU check of the matcher, in one run: CUDA against every CPU core of the same machine.

What it measures (one JSON, one table):

1. **Phase stage** (:func:`gcpmatch.phase.phase_correlate`) on rendered 64 x 64 px window pairs
   (``bench/bench_phase.py``'s texture, edges, noise and radiometric change): windows per second
   of the torch backend on the device at several batches and at the batch planned from the free
   memory (:mod:`gcpmatch.phase_batch`), of the CPU backend on every core, the device's peak
   memory per window against the planner's budget, and the agreement of the two backends: the
   largest shift difference over the pairs both accept, and how many each accepts.
2. **The whole match** of a small scene (the tests' 384 x 640 px, 4 CCDs) and of a large one
   (``bench/fullsize_seed003.json`` at ``--scale``, band B2, ``--profile ideal-dom``'s streamed
   30 m DOM and 6" DEM: ``bench/bench_fullsize.py``), each in a child process per backend:
   ``gcpmatch.extract.extract_gcps`` (what ``gcpcal match`` runs between reading its inputs and
   writing its files; the check does not write GCP files, so it needs no GeoPackage library) with
   ``--backend cpu`` on every core and ``--backend gpu``. Recorded: wall time of reading plus
   matching, the match's own stage times, the coarse stage's pre-correction difference at the
   scene's corners and mid-edges (pixels; the fine stage captures 16 px with 64 px windows), and
   the GCPs of both: windows that survive in both (the same ground point at the window centre,
   within a quarter pixel) and their largest position difference, pixels.

The inputs are generated here (``gcpcal simulate pushbroom``; the large scene's DOM and DEM by
``bench/bench_fullsize.py``'s writers) under ``--work``. Needs torch, numpy, scipy, OpenCV and
the packages of ``bench/gpu_wheels.sh`` (carried as wheels to a machine without them).

Usage::

    python bench/gpu_check.py                            # on a CUDA machine: the whole check
    python bench/gpu_check.py --device cpu --small       # a dry run without a GPU (torch on the CPU)

Writes ``--out`` (default ``$OUT/gpu_check.json`` when ``OUT`` is set, else
``bench/results/gpu_check.json``); prints one table naming the card, the CPU count and the load.
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
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

#: the fine stage's capture radius with the default 64 px windows (a quarter of the window), px
CAPTURE_RADIUS_PX = 16.0
#: the small scene: the tests' configuration (tests/test_match.py)
SMALL_SCENE = {"camera": {"detectors_per_ccd": 160, "bands": ["B2"], "reference_band": "B2",
                          "band_offsets_px": [0.0]},
               "scene": {"n_rows": 384},
               "radiometry": {"band_gain": [1.0], "band_offset_dn": [40.0], "band_gamma": [0.9]}}


def loadavg() -> list[float]:
    """The machine's 1, 5 and 15 minute load averages."""
    return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]


def cli(*args) -> list[str]:
    """A ``gcpcal`` command line run by this interpreter on this checkout."""
    return [sys.executable, "-c", "import sys; from calibrate.cli import main; sys.exit(main())", *map(str, args)]


def environment(device: str) -> dict:
    """The card, the CPU count, torch and the memory the planner sees."""
    import torch

    from gcpmatch.phase_batch import device_batch, free_memory_bytes

    facts = {"device": device, "torch": torch.__version__, "python": platform.python_version(),
             "cpu_count": os.cpu_count(), "cpu_affinity": len(os.sched_getaffinity(0)), "loadavg_start": loadavg(),
             "host_free_bytes": free_memory_bytes("cpu")}
    if device == "cuda":
        facts["card"] = torch.cuda.get_device_name(0)
        facts["device_free_bytes"] = free_memory_bytes("cuda")
        facts["device_total_bytes"] = int(torch.cuda.mem_get_info(0)[1])
    else:
        facts["card"] = f"none (torch on the CPU: {platform.processor() or platform.machine()})"
    facts["planned_batch_64px"] = device_batch((64, 64), np.float32, device)
    return facts


def timed(fn, repeat: int) -> tuple[float, object]:
    """Best wall time of ``repeat`` calls after one warm-up (plans, caches), and the last result."""
    out = fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def phase_stage(device: str, small: bool) -> dict:
    """Windows per second of both backends, the device's memory per window, their agreement."""
    import torch

    from bench_phase import render_pairs
    from gcpmatch.phase import phase_correlate
    from gcpmatch.phase_batch import device_batch, window_bytes

    n_render, tiles, repeat = (512, 2, 1) if small else (4096, 16, 3)
    ref, mov, _shifts = render_pairs(n_render, 64, seed=5)
    ref, mov = ref.astype(np.float32), mov.astype(np.float32)
    big_ref, big_mov = np.tile(ref, (tiles, 1, 1)), np.tile(mov, (tiles, 1, 1))
    backend = "gpu" if device == "cuda" else "torch"
    planned = device_batch((64, 64), np.float32, device)
    batches = sorted({256, 1024, 4096, 16384, min(planned, len(big_ref))} if not small else {64, min(planned, 1024)})
    out = {"pairs": len(big_ref), "window_px": 64, "planned_batch": planned, "device": {}, "repeat": repeat}
    for batch in batches:
        if device == "cuda":
            torch.cuda.reset_peak_memory_stats()
            base = torch.cuda.memory_allocated()
        seconds, _ = timed(lambda b=batch: phase_correlate(big_ref, big_mov, backend=backend, batch=b), repeat)
        rec = {"seconds": round(seconds, 4), "windows_per_s": round(len(big_ref) / seconds)}
        if device == "cuda":
            peak = (torch.cuda.max_memory_allocated() - base) / batch
            rec.update(peak_bytes_per_window=round(peak), budget_bytes_per_window=window_bytes(64, 64, 4))
        out["device"][str(batch)] = rec
        print(f"  phase {backend} batch {batch}: {rec['windows_per_s']} windows/s", flush=True)
    n_cpu = len(ref) * (1 if small else 4)
    cpu_ref, cpu_mov = big_ref[:n_cpu], big_mov[:n_cpu]
    seconds, _ = timed(lambda: phase_correlate(cpu_ref, cpu_mov, workers=os.cpu_count()), repeat)
    out["cpu"] = {"pairs": n_cpu, "threads": os.cpu_count(), "seconds": round(seconds, 4),
                  "windows_per_s": round(n_cpu / seconds)}
    print(f"  phase cpu ({os.cpu_count()} threads): {out['cpu']['windows_per_s']} windows/s", flush=True)
    cpu = phase_correlate(ref, mov, workers=os.cpu_count())
    dev = phase_correlate(ref, mov, backend=backend)
    both = cpu.valid & dev.valid
    out["agreement"] = {"pairs": len(ref), "valid_cpu": int(cpu.valid.sum()), "valid_device": int(dev.valid.sum()),
                        "valid_both": int(both.sum()), "same_reason": int((cpu.reason == dev.reason).sum()),
                        "max_abs_shift_diff_px": float(np.abs(cpu.shift_px[both] - dev.shift_px[both]).max())}
    return out


def small_scene(work: Path) -> dict:
    """The tests' small scene (simulated once under ``work``)."""
    folder = work / "small"
    if not (folder / "scene" / "summary.json").exists():
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "config.json").write_text(json.dumps(SMALL_SCENE))
        subprocess.run(cli("simulate", "pushbroom", "--config", folder / "config.json", "--out", folder / "scene",
                           "-q", "--overwrite"), check=True)
    ref = folder / "scene" / "reference"
    return {"scene": str(folder / "scene"), "dom": str(ref / "dom.tif"), "dem": str(ref / "dem.tif")}


def large_scene(work: Path, scale: float) -> dict:
    """Seed 003's geometry at ``scale``, band B2, over streamed DOM and DEM (``bench_fullsize``)."""
    import bench_fullsize as fs

    cache = work / f"scale{scale:g}_ideal-dom_B2"
    cache.mkdir(parents=True, exist_ok=True)
    cfg = fs.scaled_config(scale, ["B2"])
    cfg["errors"] = dict(fs.REALISTIC_ATTITUDE)
    (cache / "config.json").write_text(json.dumps(cfg, indent=1))
    t0 = time.perf_counter()
    inputs = fs.prepare_streamed_inputs(cache, cfg)
    if not (cache / "scene" / "summary.json").exists():
        subprocess.run(cli("simulate", "pushbroom", "--config", cache / "config.json", "--out", cache / "scene",
                           "--workers", os.cpu_count(), "--dom", inputs["dom"], "--dem", inputs["dem"], "-q",
                           "--overwrite"), check=True)
    return {"scene": str(cache / "scene"), "dom": inputs["dom"], "dem": inputs["dem"], "scale": scale,
            "prepare_s": round(time.perf_counter() - t0, 1)}


def match_child(scene: str, dom: str, dem: str, backend: str, out: str, given_model: str = "-") -> None:
    """Child process: read the inputs, run the match, save its GCPs, times and pre-correction.

    ``given_model``: a pickled pre-corrected model (another run's) to match from with the coarse
    stage skipped, so both runs render the same windows ("-": the scene's own model, coarse
    stage run). The run's pre-corrected model is pickled beside ``out``.
    """
    import pickle
    import resource

    t0 = time.perf_counter()
    from gcpmatch.coarse import scene_height_m
    from gcpmatch.extract import coarse_stage, extract_gcps, read_band
    from gcpmatch.options import MatchOptions
    from gcpmatch.phase_batch import match_batch
    from gcpmatch.reference import scene_gsd_m
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = open_model(Path(scene) / "manifest.json")
    if given_model != "-":
        model = pickle.loads(Path(given_model).read_bytes())
    band = model.reference_band
    img = read_band(open_scene(Path(scene) / "manifest.json"), band)
    dem_map, dom_map = Dem.open(dem), MapImage.open(dom)
    opt = MatchOptions(backend=backend, check_fraction=0.0, coarse_skip=given_model != "-")
    table, summary = extract_gcps(model, img, dem_map, dom_map, band=band, options=opt)
    wall = time.perf_counter() - t0
    info = {"backend": backend, "import_s": t_import, "read_and_match_s": wall, "timings": summary["timings"],
            "windows": summary["windows"], "gcps": 0 if table is None else len(table),
            "batch": match_batch(opt.window_px, backend, opt.batch), "threads": opt.thread_count()}
    info["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    info["coarse_note"] = summary.get("coarse", {}).get("note") or ""
    if backend == "gpu":
        import torch

        info["device_peak_bytes"] = int(torch.cuda.max_memory_allocated())
    # the pre-corrected model's corners and mid-edges (the coarse stage again: it is deterministic)
    corrected = coarse_stage(img, model, dem_map, dom_map, band, opt).model
    Path(out).with_suffix(".model.pkl").write_bytes(pickle.dumps(corrected))
    n_rows, n_cols = model.image_shape
    rows = np.array([0.5, 0.5, n_rows - 0.5, n_rows - 0.5, n_rows / 2, n_rows / 2, 0.5, n_rows - 0.5])
    cols = np.array([0.5, n_cols - 0.5, 0.5, n_cols - 0.5, 0.5, n_cols - 0.5, n_cols / 2, n_cols / 2])
    h = scene_height_m(corrected, dem_map, band=band)
    lon, lat, _ = corrected.image_to_ground(rows, cols, height=h, band=band)
    info["gsd_m"] = scene_gsd_m(corrected, band=band, height_m=h)
    arrays = {"corner_lon": lon, "corner_lat": lat}
    if table is not None:
        arrays.update(row=table.row, col=table.col, lon=table.lon, lat=table.lat, ccd=table.ccd.astype(str))
    np.savez(out, info=json.dumps(info), **arrays)


def run_match(inputs: dict, backend: str, work: Path, tag: str, given_model: str = "-") -> tuple[dict, dict]:
    """One match in a child process (``given_model``: :func:`match_child`); its record and arrays."""
    out = work / f"match_{tag}_{backend}{'_fine' if given_model != '-' else ''}.npz"
    load0 = loadavg()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, __file__, "--child-match", inputs["scene"], inputs["dom"], inputs["dem"],
                    backend, str(out), given_model], check=True)
    data = np.load(out)
    info = json.loads(str(data["info"]))
    info.update(process_s=round(time.perf_counter() - t0, 2), loadavg_before=load0, loadavg_after=loadavg())
    print(f"  match {tag} {backend}{' (fine stage from the CPU pre-correction)' if given_model != '-' else ''}: "
          f"{info['read_and_match_s']:.1f} s, {info['gcps']} GCPs, peak RSS {info['peak_rss_mib']:.0f} MiB", flush=True)
    return info, {k: data[k] for k in data.files if k != "info"}


def compare_matches(cpu: tuple[dict, dict], dev: tuple[dict, dict]) -> dict:
    """Pre-correction difference at the corners and GCP agreement of the same surviving windows.

    A GCP is a ground point and the image point that sees it. Where the two runs' pre-corrections
    differ, the same window's centre is a slightly different ground point (up to a quarter pixel
    is taken as the same window), so the image points are compared at the same ground point: the
    CPU run's image-point difference minus ``J (xy_cpu - xy_dev)``, with ``J`` the local
    ground-to-image Jacobian fitted to the CPU run's 9 nearest GCPs of that CCD (an affine
    map, by least squares). Where both runs share the pre-correction the ground points coincide
    and the correction vanishes.
    """
    from scipy.spatial import cKDTree

    (ci, ca), (di, da) = cpu, dev
    lat0 = np.deg2rad(float(np.mean(ca["corner_lat"])))
    metres = 6371008.8 * np.deg2rad(1.0)

    def xy(lon, lat):
        return np.stack([lon * metres * np.cos(lat0), lat * metres], axis=1)

    gsd = ci["gsd_m"]
    corner_px = np.linalg.norm(xy(ca["corner_lon"], ca["corner_lat"]) - xy(da["corner_lon"], da["corner_lat"]),
                               axis=1) / gsd
    out = {"precorrection_diff_px": [round(float(v), 4) for v in corner_px],
           "precorrection_max_px": float(corner_px.max()), "capture_radius_px": CAPTURE_RADIUS_PX,
           "gcps_cpu": ci["gcps"], "gcps_device": di["gcps"]}
    if "row" not in ca or "row" not in da:
        return out
    xy_c, xy_d = xy(ca["lon"], ca["lat"]), xy(da["lon"], da["lat"])
    dist, j = cKDTree(xy_d).query(xy_c, distance_upper_bound=0.25 * gsd)
    same = np.isfinite(dist)
    same[same] &= ca["ccd"][same] == da["ccd"][j[same]]
    i_c, i_d = np.flatnonzero(same), j[same]
    d_rc = np.stack([ca["row"][i_c] - da["row"][i_d], ca["col"][i_c] - da["col"][i_d]], axis=1)
    d_rc_ground = d_rc - np.einsum("nij,nj->ni", _local_jacobian(ca, xy_c, i_c), xy_c[i_c] - xy_d[i_d])
    for name, d in (("", np.hypot(*d_rc_ground.T)), ("_uncorrected", np.hypot(*d_rc.T))):
        out[f"max_gcp_diff_px{name}"] = float(d.max()) if d.size else None
        out[f"p99_gcp_diff_px{name}"] = float(np.percentile(d, 99)) if d.size else None
    out.update(same_windows=int(same.sum()),
               ground_diff_px_at_window_centres=float(dist[same].max() / gsd) if same.any() else None)
    out["speedup"] = round(ci["read_and_match_s"] / di["read_and_match_s"], 2)
    return out


def _local_jacobian(arrays: dict, xy_m: np.ndarray, index: np.ndarray, k: int = 9) -> np.ndarray:
    """(n, 2, 2) d(row, col) / d(x, y) at the GCPs ``index``: an affine map fitted to the ``k``
    nearest GCPs of the same CCD (least squares; x, y metres)."""
    from scipy.spatial import cKDTree

    jac = np.zeros((index.size, 2, 2))
    rc = np.stack([arrays["row"], arrays["col"]], axis=1)
    for ccd in np.unique(arrays["ccd"][index]):
        pts = np.flatnonzero(arrays["ccd"] == ccd)
        here = np.flatnonzero(arrays["ccd"][index] == ccd)
        kk = min(k, pts.size)
        if kk < 3:
            continue
        _, nb = cKDTree(xy_m[pts]).query(xy_m[index[here]], k=kk)
        nb = pts[nb.reshape(here.size, kk)]
        dx = xy_m[nb] - xy_m[nb].mean(axis=1, keepdims=True)  # (m, k, 2)
        drc = rc[nb] - rc[nb].mean(axis=1, keepdims=True)  # (m, k, 2)
        # J^T = (dx^T dx)^-1 dx^T drc, per point
        jac[here] = np.swapaxes(np.linalg.solve(np.einsum("mki,mkj->mij", dx, dx),
                                                np.einsum("mki,mkj->mij", dx, drc)), 1, 2)
    return jac


def criteria(result: dict, large: str) -> dict:
    """The GPU item's targets, each with the measured value and whether it is met (None: not measured).

    The speed targets and the batch are CUDA's: a dry run (torch on the CPU) reports only the
    agreement targets.
    """
    phase, cuda = result.get("phase", {}), result["environment"]["device"] == "cuda"
    best = max((r["windows_per_s"] for r in phase.get("device", {}).values()), default=None)
    out = {"phase_windows_per_s >= 100000": best, "batch from free memory (not 256)": phase.get("planned_batch")} \
        if cuda else {}
    for tag, rec in result.get("match", {}).items():
        c = rec["compare"]
        out[f"{tag}: pre-correction difference < capture radius 16 px"] = c["precorrection_max_px"]
        out[f"{tag}: GCPs of the same windows within 0.01 px, at the same ground point"] = c.get("max_gcp_diff_px")
        if "fine" in rec:
            out[f"{tag}: GCPs of the same windows within 0.01 px, fine stage from the CPU pre-correction"] = \
                rec["fine"]["compare"].get("max_gcp_diff_px")
    if cuda and large in result.get("match", {}):
        out[f"{large}: whole match >= 5x faster than every CPU core"] = result["match"][large]["compare"].get("speedup")
    tests = {"phase_windows_per_s": lambda v: v >= 1e5, "batch from": lambda v: v != 256,
             "pre-correction": lambda v: v < CAPTURE_RADIUS_PX, "within 0.01 px": lambda v: v <= 0.01,
             ">= 5x": lambda v: v >= 5.0}
    return {k: {"value": v, "met": None if v is None else next(t(v) for key, t in tests.items() if key in k)}
            for k, v in out.items()}


def print_table(result: dict) -> None:
    env, phase = result["environment"], result.get("phase", {})
    print(f"\ncard: {env['card']}; CPUs: {env['cpu_count']}; load {env['loadavg_start']} -> {result['loadavg_end']}")
    for batch, rec in phase.get("device", {}).items():
        extra = f", peak {rec['peak_bytes_per_window']} B/window (budget {rec['budget_bytes_per_window']})" \
            if "peak_bytes_per_window" in rec else ""
        print(f"phase, device batch {batch:>6}: {rec['windows_per_s']:>9} windows/s{extra}")
    if "cpu" in phase:
        print(f"phase, cpu {phase['cpu']['threads']} threads: {phase['cpu']['windows_per_s']:>9} windows/s")
        a = phase["agreement"]
        print(f"phase agreement: max |d shift| {a['max_abs_shift_diff_px']:.2e} px over {a['valid_both']} pairs "
              f"(valid cpu {a['valid_cpu']}, device {a['valid_device']})")
    print("| scene | cpu s | device s | speedup | GCPs cpu / device | same windows | max GCP diff px | "
          "pre-correction max px |")
    for tag, rec in result.get("match", {}).items():
        for name, dev in (("", rec), (" (fine from CPU pre-correction)", rec.get("fine"))):
            if dev is None:
                continue
            c = dev["compare"]
            print(f"| {tag}{name} | {rec['cpu']['read_and_match_s']:.1f} | {dev['device']['read_and_match_s']:.1f} | "
                  f"{c.get('speedup')} | {c['gcps_cpu']} / {c['gcps_device']} | {c.get('same_windows')} | "
                  f"{c.get('max_gcp_diff_px')} | {c['precorrection_max_px']:.4f} |")
    for tag, rec in result.get("match", {}).items():
        print(f"{tag}: stage seconds cpu {rec['cpu']['timings']}, device {rec['device']['timings']}; peak RSS "
              f"{rec['cpu']['peak_rss_mib']:.0f} / {rec['device']['peak_rss_mib']:.0f} MiB")
    for name, rec in result.get("criteria", {}).items():
        print(f"{'met' if rec['met'] else 'NOT met' if rec['met'] is False else 'not measured'}: {name} "
              f"(measured {rec['value']})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", choices=["cuda", "cpu"],
                    help="cuda: --backend gpu; cpu: a dry run with torch on the CPU (--backend torch)")
    ap.add_argument("--small", action="store_true",
                    help="dry-run sizes: 1024 pairs timed once, the large scene at --scale 1/16")
    ap.add_argument("--scale", type=float, default=None, help="large scene's scale of seed 003 (default 1, --small 1/16)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/gpu_check"), help="generated inputs and outputs")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--scenes", default="small,large", help="matches to run: small, large (comma-separated)")
    ap.add_argument("--no-phase", action="store_true",
                    help="leave out the phase stage's throughput (windows per second on the device and the CPU)")
    ap.add_argument("--child-match", nargs=6, metavar=("SCENE", "DOM", "DEM", "BACKEND", "OUT", "MODEL"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child_match:
        match_child(*args.child_match)
        return 0
    out = args.out or (Path(os.environ["OUT"]) / "gpu_check.json" if os.environ.get("OUT")
                       else ROOT / "bench" / "results" / "gpu_check.json")
    scale = args.scale if args.scale is not None else (0.0625 if args.small else 1.0)
    backend = "gpu" if args.device == "cuda" else "torch"
    args.work.mkdir(parents=True, exist_ok=True)
    result = {"environment": environment(args.device), "backend": backend, "small": args.small, "match": {}}
    t_start = time.perf_counter()

    def save():
        result["loadavg_end"], result["elapsed_s"] = loadavg(), round(time.perf_counter() - t_start, 1)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1, default=str))

    if not args.no_phase:
        print("phase stage", flush=True)
        result["phase"] = phase_stage(args.device, args.small)
        save()
    makers = {"small": ("small", lambda: small_scene(args.work)),
              "large": (f"scale{scale:g}", lambda: large_scene(args.work, scale))}
    for tag, make in (makers[name] for name in args.scenes.split(",")):
        print(f"scene {tag}", flush=True)
        inputs = make()
        cpu, dev = run_match(inputs, "cpu", args.work, tag), run_match(inputs, backend, args.work, tag)
        result["match"][tag] = {"inputs": inputs, "cpu": cpu[0], "device": dev[0], "compare": compare_matches(cpu, dev)}
        save()
        # the fine stage alone: the device run from the CPU run's pre-corrected model, coarse skipped
        fine = run_match(inputs, backend, args.work, tag,
                         given_model=str((args.work / f"match_{tag}_cpu.npz").with_suffix(".model.pkl")))
        result["match"][tag]["fine"] = {"device": fine[0], "compare": compare_matches(cpu, fine)}
        result["criteria"] = criteria(result, f"scale{scale:g}")
        save()
    print_table(result)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
