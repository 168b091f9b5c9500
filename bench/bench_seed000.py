"""Benchmark: experiment 000 (seed 000 star tracks) at the paper's scale, timed, its figures kept.

Runs :func:`calibrate.experiments.simulate_seed000.run` (``--profile paper-000``: the paper's 20
daily sessions of 120 frames, each calibrated alone and all pooled, plus the sensitivity
curves' sessions) with ``--workers`` processes, and records the wall time, the load of the
machine before and after (``/proc/loadavg``, the machine is shared), the CPU seconds of all
sessions and that divided by the workers (the wall time on idle cores, bar the serial rest), the
tables, curves and headline. With ``--reference`` (an earlier output of this script, e.g. from another revision or
worker count) it also records the largest absolute difference of any number of the tables,
curves and headline, and where.

Usage: ``python bench/bench_seed000.py [--profile paper-000] [--workers N] [--quick] [--frames N]
[--reference OLD.json] [--out FILE]`` (JSON on stdout without ``--out``).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _load() -> list:
    try:
        return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return []


def max_difference(a, b, path: str = "") -> tuple:
    """Largest ``|a - b|`` over the numbers of two nested documents, and its path.

    Parameters
    ----------
    a, b : dict, list, float, int, str or None
        Documents of the same structure (strings, booleans and None must be equal).

    Returns
    -------
    (float, str)
        The difference (0 when every number is equal) and the path of the worst one.

    Raises
    ------
    ValueError
        Where the structures or the non-numbers differ.
    """
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            raise ValueError(f"{path}: keys differ: {sorted(set(a) ^ set(b))}")
        pairs = [(a[k], b[k], f"{path}.{k}") for k in a]
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            raise ValueError(f"{path}: lengths {len(a)} and {len(b)}")
        pairs = [(u, v, f"{path}[{i}]") for i, (u, v) in enumerate(zip(a, b))]
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return abs(float(a) - float(b)), path
    else:
        if a != b:
            raise ValueError(f"{path}: {a!r} != {b!r}")
        return 0.0, path
    worst = (0.0, path)
    for u, v, p in pairs:
        d = max_difference(u, v, p)
        if d[0] > worst[0]:
            worst = d
    return worst


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="paper-000", choices=("ideal", "realistic", "paper-000"))
    ap.add_argument("--workers", type=int, default=None, help="worker processes (default: the usable cores)")
    ap.add_argument("--quick", action="store_true", help="the experiment's reduced run")
    ap.add_argument("--frames", type=int, default=None, help="frames per session (default the experiment's: 120)")
    ap.add_argument("--reference", type=Path, help="an earlier output of this script to compare the figures with")
    ap.add_argument("--out", type=Path, help="write the JSON here (default: stdout)")
    args = ap.parse_args(argv)

    from calibrate.experiments.simulate_seed000 import default_workers, run

    workers = default_workers() if args.workers is None else args.workers
    load_before = _load()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_seed000-") as work:
        result = run(args.profile, quick=args.quick, work_dir=Path(work), workers=workers, frames=args.frames)
    wall = time.perf_counter() - t0
    doc = {
        "command": "python bench/bench_seed000.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "profile": args.profile, "quick": bool(args.quick), "workers": workers,
        "usable_cores": default_workers(), "machine": platform.machine(), "python": platform.python_version(),
        "wall_s": round(wall, 2), "load_before": load_before, "load_after": _load(),
        "frames_per_session": result.scale["frames_per_session"], "sessions_run": result.scale["sessions_run"], "sessions_simulated": result.scale["sessions_simulated"],
        "session_cpu_s": result.scale["session_cpu_s"],
        "cpu_bound_wall_s": round(result.scale["session_cpu_s"] / workers, 1),
        "tracks": result.headline.get("tracks"),
        "tables": [asdict(t) for t in result.tables], "curves": [asdict(c) for c in result.curves],
        "headline": result.headline,
    }
    if args.reference is not None:
        ref = json.loads(args.reference.read_text())
        diff, where = max_difference({k: ref[k] for k in ("tables", "curves", "headline")},
                                     json.loads(json.dumps({k: doc[k] for k in ("tables", "curves", "headline")})))
        doc["reference"] = {"file": str(args.reference), "wall_s": ref.get("wall_s"), "max_abs_diff": diff,
                            "where": where}
    text = json.dumps(doc, indent=1, default=str)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n", encoding="utf-8")
    else:
        print(text)
    print(f"experiment 000 {args.profile}{' quick' if args.quick else ''}: {wall:.1f} s with {workers} workers "
          f"(load {load_before} -> {doc['load_after']})"
          + (f"; max |diff| vs reference {doc['reference']['max_abs_diff']:.3g}" if args.reference else ""),
          file=sys.stderr)
    return doc


if __name__ == "__main__":
    main()
