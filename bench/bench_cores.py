"""Benchmark: how phase correlation, orthorectification and simulation scale with the cores.

Each stage runs in a fresh child process per core count ``n`` (``--cores 1,2,4,8,16``; counts
above the cores this process may run on are skipped), pinned to the first ``n`` of those cores
(``os.sched_setaffinity``, as ``taskset`` does) and given ``threads = n`` (BLAS too), so every
count sees the machine a job of that size would. The counts are interleaved: each repeat runs every
count once, in forward then reverse order, so a change of load over the run touches every count.

- ``phase``: :func:`gcpmatch.phase.phase_correlate` (CPU backend, defaults) on ``--pairs``
  64 x 64 px float32 window pairs (``bench/bench_phase.py``'s power-law textures with edges,
  SNR 50, a radiometric change; 2048 distinct pairs repeated), after a warm-up call: pairs per
  second.
- ``phase_procs``: the same pairs on ``n`` processes of one thread each, each pinned to one core
  with its share of the pairs, started together after their warm-up: what the cores give without
  a shared interpreter (no GIL, no shared allocator), the ceiling the threads are measured
  against. ``--phase-batch`` sets both stages' batch (pairs per kernel call, default 256).
- ``windows``: the matcher's window stage (``gcpmatch.extract._correlate_windows``: gather,
  screening, phase correlation, sigma model, in tasks of ``MatchOptions.batch`` windows on
  ``n`` threads) on a textured 4096 x 2048 px CCD against a shifted, noisy copy, windows every
  32 px: windows per second.
- ``ortho``: :func:`sensor_models.imaging.ortho.orthorectify_to_file` of the synthetic push-broom
  scene of ``bench/bench_ortho.py`` (``--ortho-scene`` px a side, 512 px blocks) at its GSD:
  output pixels per second.
- ``simulate``: :func:`sensor_models.simulate.pushbroom_sim.simulate_pushbroom` of a scene of
  ``--sim-rows`` lines, 2 cameras x 2 CCDs of ``--sim-detectors`` detectors, 4 bands, rendered
  from a DOM and a DEM file (``bench/bench_simulate.py``): rendered pixels per second.

Per count: the best and median wall time of the repeats, the process's CPU seconds (every
thread's), the rate per wall second and per CPU second (less sensitive to other jobs on a shared
machine), the speed-up over one core (best against best) and the efficiency (speed-up / n; the
target for phase correlation is >= 0.7 up to 16 cores). The load average is read before every
child. Each child also reports a digest of its result (the shifts, the orthoimage's pixels, the
scene's bytes): they must be the same for every count.

``--base-root PATH`` (a checkout of another revision, e.g. ``git worktree add /tmp/base REV``)
adds the stage ``phase_base``: the same phase runs with that revision's code, interleaved with
``phase`` (``workers = n`` there too), so the two compare on the same load.

Usage: ``python bench/bench_cores.py [--cores 1,2,4,8,16]
[--stages phase,phase_procs,windows,ortho,simulate] [--pairs 20000] [--phase-batch 256] [--repeat 3]
[--json PATH]``. Prints a table; writes JSON only with ``--json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

STAGES = ("phase", "phase_procs", "windows", "ortho", "simulate")
CHILD_STAGES = STAGES + ("phase_base",)
BASE_PAIRS = 2048
#: target efficiency of phase correlation (speed-up / cores)
TARGET_EFFICIENCY = 0.7


# --------------------------------------------------------------------------- children


def _pairs(args):
    """The phase stages' ``args.pairs`` window pairs: the prepared distinct pairs repeated."""
    import numpy as np

    base = np.load(Path(args.data) / "pairs.npy", mmap_mode="r")
    reps = -(-args.pairs // BASE_PAIRS)
    return (np.tile(np.asarray(base[0]), (reps, 1, 1))[:args.pairs],
            np.tile(np.asarray(base[1]), (reps, 1, 1))[:args.pairs])


def _phase_child(args) -> dict:
    import numpy as np

    from gcpmatch.phase import phase_correlate

    ref, mov = _pairs(args)
    phase_correlate(ref[:1024], mov[:1024], workers=args.threads)  # warm-up: plans, tables, pages
    wall, cpu = time.perf_counter(), time.process_time()
    m = phase_correlate(ref, mov, workers=args.threads, batch=args.phase_batch)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    digest = hashlib.sha256(np.ascontiguousarray(m.shift_px).tobytes() + m.score.tobytes()).hexdigest()[:16]
    return {"items": args.pairs, "unit": "pairs", "wall_s": wall, "cpu_s": cpu, "digest": digest,
            "valid_fraction": float(m.valid.mean())}


def _phase_procs_child(args) -> dict:
    """The phase stage on ``args.threads`` processes instead of threads, one per core (each
    pinned to one of this process's cores, one thread each, its share of the pairs; started
    together after their warm-up): what the cores give without a shared interpreter, the ceiling
    that threads are measured against."""
    import multiprocessing as mp

    import numpy as np

    from gcpmatch.phase import phase_correlate

    ref, mov = _pairs(args)
    n, cores = args.threads, sorted(os.sched_getaffinity(0))
    bounds = np.linspace(0, args.pairs, n + 1).astype(int)
    ctx = mp.get_context("fork")
    barrier, results = ctx.Barrier(n + 1), ctx.Queue()

    def work(i):
        os.sched_setaffinity(0, [cores[i % len(cores)]])
        a, b = bounds[i], bounds[i + 1]
        phase_correlate(ref[a:a + 256], mov[a:a + 256], workers=1, batch=args.phase_batch)
        barrier.wait()
        t0, c0 = time.perf_counter(), time.process_time()
        m = phase_correlate(ref[a:b], mov[a:b], workers=1, batch=args.phase_batch)
        results.put((i, time.perf_counter() - t0, time.process_time() - c0, m.shift_px, m.score))

    procs = [ctx.Process(target=work, args=(i,)) for i in range(n)]
    for pr in procs:
        pr.start()
    barrier.wait()
    wall = time.perf_counter()
    got = sorted((results.get() for _ in procs), key=lambda r: r[0])
    wall = time.perf_counter() - wall
    for pr in procs:
        pr.join()
    shift, score = np.concatenate([g[3] for g in got]), np.concatenate([g[4] for g in got])
    digest = hashlib.sha256(np.ascontiguousarray(shift).tobytes() + score.tobytes()).hexdigest()[:16]
    return {"items": args.pairs, "unit": "pairs", "wall_s": wall, "cpu_s": sum(g[2] for g in got),
            "digest": digest}


def _windows_child(args) -> dict:
    """The matcher's window stage (:func:`gcpmatch.extract._correlate_windows`: gather, screen,
    phase correlation, sigma model) on a textured 4096 x 2048 px CCD against a shifted, noisy
    reference, windows every 32 px, ``args.threads`` threads."""
    import numpy as np

    from gcpmatch.extract import _correlate_windows, grid_starts
    from gcpmatch.options import MatchOptions

    data = np.load(Path(args.data) / "ccd.npz")
    img, ref = data["img"], data["ref"]
    msk = np.zeros(img.shape, bool)
    rr, cc = (a.ravel() for a in np.meshgrid(grid_starts(img.shape[0], 64, 32), grid_starts(img.shape[1], 64, 32),
                                             indexing="ij"))
    opt = MatchOptions(threads=args.threads)
    _correlate_windows(img, ref, msk, rr[:512], cc[:512], opt)  # warm-up
    wall, cpu = time.perf_counter(), time.process_time()
    status, _, shift, _ = _correlate_windows(img, ref, msk, rr, cc, opt)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    digest = hashlib.sha256(np.ascontiguousarray(shift).tobytes() + "".join(status).encode()).hexdigest()[:16]
    return {"items": int(rr.size), "unit": "windows", "wall_s": wall, "cpu_s": cpu, "digest": digest,
            "matched_fraction": float(np.mean(status == ""))}


def _ortho_child(args) -> dict:
    import rasterio

    from bench_ortho import build_dem, build_model
    from sensor_models.imaging.ortho import orthorectify_to_file

    model, dem = build_model(args.ortho_scene), build_dem()
    out = Path(args.data) / f"ortho_{args.threads}_{os.getpid()}.tif"
    wall, cpu = time.perf_counter(), time.process_time()
    summary = orthorectify_to_file(model, str(Path(args.data) / "source.tif"), dem, out, block=512,
                                   threads=args.threads)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    with rasterio.open(out) as ds:
        digest = hashlib.sha256(ds.read(1).tobytes()).hexdigest()[:16]
    out.unlink()
    n_rows, n_cols = summary["shape"]
    return {"items": n_rows * n_cols, "unit": "output px", "wall_s": wall, "cpu_s": cpu, "digest": digest,
            "cog_s": summary["cog_seconds"]}


def _sim_config(args):
    from sensor_models.simulate.config import SimConfig

    cfg = SimConfig()
    return replace(cfg, scene=replace(cfg.scene, n_rows=args.sim_rows),
                   camera=replace(cfg.camera, detectors_per_ccd=args.sim_detectors, overlap_detectors=16)).validate()


def _simulate_child(args) -> dict:
    import shutil

    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    data = Path(args.data)
    out = data / f"scene_{args.threads}_{os.getpid()}"
    wall, cpu = time.perf_counter(), time.process_time()
    summary = simulate_pushbroom(out, config=_sim_config(args), dom=data / "dom.tif", dem=data / "dem.tif",
                                 workers=args.threads, record_timings=True)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    digest = hashlib.sha256(b"".join((out / f"{b}.tif").read_bytes() for b in summary["image"]["bands"]))
    shutil.rmtree(out)
    image = summary["image"]
    return {"items": image["n_rows"] * image["n_cols"] * len(image["bands"]), "unit": "rendered px",
            "wall_s": wall, "cpu_s": cpu, "digest": digest.hexdigest()[:16],
            "render_s": summary["render_seconds"]}


def child(args) -> None:
    """One stage at ``args.threads`` threads in this (pinned) process; prints one JSON line."""
    if args.code_root:  # another revision's packages first
        sys.path.insert(0, str(Path(args.code_root).resolve()))
    run = {"phase": _phase_child, "phase_base": _phase_child, "phase_procs": _phase_procs_child,
           "windows": _windows_child, "ortho": _ortho_child, "simulate": _simulate_child}[args.child]
    result = run(args)
    result.update(stage=args.child, threads=args.threads, affinity=len(os.sched_getaffinity(0)))
    print(json.dumps(result))


# --------------------------------------------------------------------------- parent


def prepare(stages, folder: Path, args) -> None:
    """The stages' inputs, written once into ``folder`` (not timed)."""
    import numpy as np

    if {"phase", "phase_procs"} & set(stages):
        from bench_phase import render_pairs

        ref, mov, _ = render_pairs(BASE_PAIRS, 64, seed=7)
        np.save(folder / "pairs.npy", np.stack([ref, mov]).astype(np.float32))
    if "windows" in stages:
        from scipy.ndimage import gaussian_filter, shift as nd_shift

        rng = np.random.default_rng(3)
        field = sum(gaussian_filter(rng.standard_normal((4096, 2048)), s) * s for s in (1.0, 3.0, 9.0))
        img = (1000.0 + 200.0 * field / field.std()).astype(np.float32)
        ref = nd_shift(img, (0.3, -0.2), order=3, mode="nearest") + rng.normal(0.0, 4.0, img.shape)
        np.savez(folder / "ccd.npz", img=img, ref=ref.astype(np.float32))
    if "ortho" in stages:
        from bench_ortho import write_source

        write_source(folder / "source.tif", args.ortho_scene)
    if "simulate" in stages:
        from bench_simulate import write_reference

        write_reference(_sim_config(args), folder)


def run_child(stage: str, n: int, cores: list[int], folder: Path, args) -> dict:
    """The stage in a child process pinned to the first ``n`` of ``cores``."""
    code_root = Path(args.base_root).resolve() if stage == "phase_base" else ROOT
    env = {k: v for k, v in os.environ.items() if k != "GCPCAL_THREADS"}
    # the code root first, then what the caller's path holds (packages carried beside the install)
    path = [str(code_root)] + [v for v in os.environ.get("PYTHONPATH", "").split(os.pathsep) if v]
    env.update(OMP_NUM_THREADS=str(n), OPENBLAS_NUM_THREADS=str(n), MKL_NUM_THREADS=str(n),
               PYTHONPATH=os.pathsep.join(path))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", stage, "--threads", str(n), "--data", str(folder),
           "--pairs", str(args.pairs), "--phase-batch", str(args.phase_batch), "--ortho-scene", str(args.ortho_scene),
           "--sim-rows", str(args.sim_rows), "--sim-detectors", str(args.sim_detectors), "--code-root", str(code_root)]
    load = os.getloadavg()[0]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False,
                          preexec_fn=lambda: os.sched_setaffinity(0, cores[:n]))
    if done.returncode != 0:
        raise SystemExit(f"{stage} at {n} threads failed:\n{done.stderr[-2000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["load_before"] = load
    return result


def summarize(runs: list[dict]) -> dict:
    """Per stage and count: best/median wall, median CPU, rates, speed-up and efficiency against 1 core."""
    out = {}
    for stage in dict.fromkeys(r["stage"] for r in runs):
        rows = {}
        for n in sorted({r["threads"] for r in runs if r["stage"] == stage}):
            mine = [r for r in runs if r["stage"] == stage and r["threads"] == n]
            items = mine[0]["items"]
            best = min(r["wall_s"] for r in mine)
            cpu = statistics.median(r["cpu_s"] for r in mine)
            rows[n] = {"repeats": len(mine), "unit": mine[0]["unit"], "items": items, "best_wall_s": best,
                       "median_wall_s": statistics.median(r["wall_s"] for r in mine), "median_cpu_s": cpu,
                       "rate_per_s": items / best, "rate_per_cpu_s": items / cpu,
                       "load": [round(r["load_before"], 2) for r in mine],
                       "digests": sorted({r["digest"] for r in mine})}
        one = rows.get(1)
        for n, row in rows.items():
            if one is not None:
                row["speedup"] = row["rate_per_s"] / one["rate_per_s"]
                row["efficiency"] = row["speedup"] / n
        digests = {d for row in rows.values() for d in row["digests"]}
        out[stage] = {"by_threads": rows, "same_result_for_every_count": len(digests) == 1}
    return out


def print_table(summary: dict) -> None:
    print(f"{'stage':9s} {'threads':>7s} {'best wall s':>11s} {'CPU s':>8s} {'rate /s':>11s} {'rate /CPU-s':>11s} "
          f"{'speed-up':>8s} {'eff.':>5s}  load")
    for stage, block in summary.items():
        for n, row in block["by_threads"].items():
            print(f"{stage:9s} {n:7d} {row['best_wall_s']:11.2f} {row['median_cpu_s']:8.2f} {row['rate_per_s']:11.0f} "
                  f"{row['rate_per_cpu_s']:11.0f} {row.get('speedup', float('nan')):8.2f} "
                  f"{row.get('efficiency', float('nan')):5.2f}  {row['load']}")
        print(f"{stage:9s} same result for every count: {block['same_result_for_every_count']}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cores", default="1,2,4,8,16", help="Core counts, comma-separated.")
    ap.add_argument("--stages", default=",".join(STAGES), help="Stages, comma-separated: " + ", ".join(STAGES))
    ap.add_argument("--pairs", type=int, default=20000, help="Window pairs of the phase stage.")
    ap.add_argument("--phase-batch", type=int, default=256,
                    help="Pairs per batch of the phase stages (phase_correlate's batch; 256 is its default).")
    ap.add_argument("--ortho-scene", type=int, default=2048, help="Side of the ortho stage's scene, px.")
    ap.add_argument("--sim-rows", type=int, default=1024, help="Lines of the simulated scene.")
    ap.add_argument("--sim-detectors", type=int, default=1024, help="Detectors per CCD of the simulated scene.")
    ap.add_argument("--repeat", type=int, default=3, help="Runs of every count (interleaved).")
    ap.add_argument("--json", type=Path, help="Write the runs and the summary here.")
    ap.add_argument("--base-root", type=Path, help="Another revision's checkout: adds the stage phase_base.")
    ap.add_argument("--child", choices=CHILD_STAGES, help=argparse.SUPPRESS)
    ap.add_argument("--code-root", help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args)
        return
    cores = sorted(os.sched_getaffinity(0))
    wanted = [int(v) for v in args.cores.split(",") if v.strip()]
    counts = [n for n in wanted if 1 <= n <= len(cores)]
    skipped = [n for n in wanted if n not in counts]
    stages = [s.strip() for s in args.stages.split(",") if s.strip()]
    if not counts or any(s not in STAGES for s in stages):
        raise SystemExit(f"bench_cores: counts within 1..{len(cores)} and stages among {', '.join(STAGES)} needed")
    if args.base_root is not None and "phase" in stages:
        stages.insert(stages.index("phase") + 1, "phase_base")
    if skipped:
        print(f"skipped counts above the {len(cores)} cores this process may run on: {skipped}")
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench_cores_") as tmp:
        folder = Path(tmp)
        prepare(stages, folder, args)
        for rep in range(args.repeat):
            order = counts if rep % 2 == 0 else counts[::-1]
            for stage in stages:
                for n in order:
                    runs.append(run_child(stage, n, cores, folder, args))
                    r = runs[-1]
                    print(f"  {stage} x{n}: {r['wall_s']:.2f} s wall, {r['cpu_s']:.2f} CPU-s, load {r['load_before']:.2f}",
                          flush=True)
    summary = summarize(runs)
    print(f"{platform.node()} ({platform.machine()}), {len(cores)} usable cores of {os.cpu_count()}; "
          f"load average {os.getloadavg()}")
    print_table(summary)
    if args.json is not None:
        doc = {"machine": {"cores_usable": len(cores), "cpu_count": os.cpu_count(), "machine": platform.machine(),
                           "python": platform.python_version(), "processor": platform.processor()},
               "options": {k: v for k, v in vars(args).items()
                           if k not in ("child", "threads", "data", "json", "code_root")},
               "skipped_counts": skipped, "target_phase_efficiency": TARGET_EFFICIENCY,
               "runs": runs, "summary": {s: {**b, "by_threads": {str(k): v for k, v in b["by_threads"].items()}}
                                         for s, b in summary.items()}}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1, default=str) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
