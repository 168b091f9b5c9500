"""Benchmark: the per-window sigma model (:func:`gcpmatch.texture.mismatch_cr_sigma_px`).

The function moves each reference window by its measured shift (bilinear), fits the scene window
by a gain and offset of it and divides the residual variance by the window's squared gradient.
This bench times it, at one thread (BLAS and OpenMP pinned before numpy loads), interleaved with
the index-gather formulation it replaced (every sample gathered by four fancy-index lookups and
the sums formed from full temporaries), on the same float32 window pairs as the matcher's chips:
synthetic correlated textures of 64 x 64 px, a scene window = the reference moved by one line
plus white noise, shifts uniform in +/- 3 px and a few at the border. Both are run ``--repeat``
times in alternation; the best CPU time of each is kept (robust to other jobs on the machine).
The two results are compared (NaN pattern identical, largest relative difference printed).

Simulated windows, not real data: the figure is the kernel's own cost per pair.

Usage: ``python bench/bench_sigma.py [--pairs 2048] [--repeat 7] [--out FILE.json]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gcpmatch.texture import mismatch_cr_sigma_px  # noqa: E402


def gather_sigma_px(reference, scene, shift_px, border_px: int = 8) -> np.ndarray:
    """The index-gather formulation (same equations as ``mismatch_cr_sigma_px``), for comparison."""
    ref, scn = np.asarray(reference, np.float64), np.asarray(scene, np.float64)
    n, w = ref.shape[0], ref.shape[-1]
    d = np.nan_to_num(np.asarray(shift_px, np.float64), nan=0.0)
    ok = np.isfinite(shift_px).all(axis=1) & (np.abs(shift_px) <= border_px).all(axis=1)
    d[~ok] = 0.0
    offset = -d
    base = np.floor(offset).astype(np.intp)
    frac = offset - base
    inner = np.arange(border_px, w - border_px)
    k = np.arange(n)[:, None, None]
    r0 = inner[None, :, None] + base[:, 0, None, None]
    c0 = inner[None, None, :] + base[:, 1, None, None]
    r1, c1 = np.clip(r0 + 1, 0, w - 1), np.clip(c0 + 1, 0, w - 1)
    r0, c0 = np.clip(r0, 0, w - 1), np.clip(c0, 0, w - 1)
    fr, fc = frac[:, 0, None, None], frac[:, 1, None, None]
    top = (1.0 - fc) * ref[k, r0, c0] + fc * ref[k, r0, c1]
    bottom = (1.0 - fc) * ref[k, r1, c0] + fc * ref[k, r1, c1]
    moved = (1.0 - fr) * top + fr * bottom
    core = scn[:, border_px:w - border_px, border_px:w - border_px]
    x = moved - moved.mean(axis=(1, 2), keepdims=True)
    y = core - core.mean(axis=(1, 2), keepdims=True)
    gain = np.sum(x * y, axis=(1, 2)) / np.maximum(np.sum(x * x, axis=(1, 2)), 1e-30)
    v = np.mean((y - gain[:, None, None] * x) ** 2, axis=(1, 2))
    g_row = np.sum(np.diff(core, axis=1) ** 2, axis=(1, 2))
    g_col = np.sum(np.diff(core, axis=2) ** 2, axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.sqrt(v[:, None] / np.stack([g_row, g_col], axis=1))
    out[~ok] = np.nan
    return out


def windows(n: int, size: int = 64, seed: int = 1):
    """Correlated float32 textures, the scene moved by one line plus noise, shifts in +/- 3 px."""
    rng = np.random.default_rng(seed)
    ref = rng.normal(size=(n, size, size)).cumsum(axis=1).cumsum(axis=2).astype(np.float32)
    scn = (np.roll(ref, 1, axis=1) + rng.normal(scale=3.0, size=ref.shape)).astype(np.float32)
    shift = rng.uniform(-3.0, 3.0, size=(n, 2))
    shift[::97] = [8.0, -8.0]  # at the border
    shift[5::211] = np.nan  # not matched
    return ref, scn, shift


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=2048)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = parser.parse_args(argv)
    ref, scn, shift = windows(args.pairs)
    best = {"current": np.inf, "gather": np.inf}
    results = {}
    for _ in range(args.repeat):
        for name, fn in (("gather", gather_sigma_px), ("current", mismatch_cr_sigma_px)):
            t0 = time.process_time()
            results[name] = fn(ref, scn, shift)
            best[name] = min(best[name], time.process_time() - t0)
    a, b = results["gather"], results["current"]
    same_nan = bool(np.array_equal(np.isnan(a), np.isnan(b)))
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = float(np.nanmax(np.abs(a - b) / np.abs(a)))
    figures = {
        "input": f"simulated float32 windows, {args.pairs} pairs of 64 x 64 px",
        "us_per_pair": {k: 1e6 * v / args.pairs for k, v in best.items()},
        "speedup": best["gather"] / best["current"],
        "same_nan_pattern": same_nan, "max_relative_difference": rel,
        "load_average": os.getloadavg()[0], "threads": 1, "repeat": args.repeat,
    }
    print(f"per-window sigma, 1 thread, best of {args.repeat} (load {figures['load_average']:.1f}): "
          f"{figures['us_per_pair']['current']:.1f} us/pair, index gather {figures['us_per_pair']['gather']:.1f} "
          f"us/pair: x{figures['speedup']:.2f}; NaN pattern {'identical' if same_nan else 'DIFFERS'}, "
          f"largest relative difference {rel:.1e}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(figures, indent=2))
    return 0 if same_nan and rel < 1e-9 else 1


if __name__ == "__main__":
    raise SystemExit(main())
