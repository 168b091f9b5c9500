"""GCP truth error and sigma honesty under real radiometric change, before and after the change options.

Scenes are rendered from one real band and matched against the same band (``same``) or another
band of the same product (``cross``: Sentinel-2 red against near-infrared, whose contrast inverts
over vegetation), as :mod:`bench.change_pairs` describes (the shared test data hold no two
dates of one place). Each (pair, seed, reference) is matched through the production matcher
(:func:`gcpmatch.extract.extract_gcps`: coarse SIFT stage, reference chips, phase correlation,
outlier rejection, ``sigma_px``) with each variant of :data:`VARIANTS`, and its GCPs are graded
against the TRUE model (:func:`bench.change_pairs.truth_errors`).

Printed per row: GCPs, truth error rms / median / p95 (2-D, px), mean error (row, col) px, and
rms of truth error over ``sigma_px`` pooled and per axis (1: honest), and with ``detect`` the
scene's median spread ratio and whether it switched the change options on; then the rms pooled over the
seeds per (pair, reference, variant). Each ``cross`` row of a Sentinel-2 pair is followed by
``cross_band_offset_out``: the same GCPs graded against the source band's ground, the reference
band's own displacement (:data:`change_pairs.BAND_OFFSET_M`, measured by ``bench/band_offset.py``)
taken out of the truth, and ``cross_local_offset_out``: each GCP's own window displacement
between the bands (ECC, :func:`band_offset.local_offsets_m`) taken out instead, a diagnostic of
what a constant leaves.

Usage: ``python bench/bench_change.py [--cache DIR] [--seeds 11,12] [--pairs a,b] [--json FILE]``
(``--cache`` keeps the rendered scenes between runs; default a temporary folder; ``--json``
writes the figures there).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import band_offset  # noqa: E402
import change_pairs  # noqa: E402

DATA = change_pairs.DATA

#: name -> keywords of MatchOptions; ``default`` is the matcher as shipped; ``detect`` lets the
#: scene switch the change options on (``MatchOptions.detect_change``)
VARIANTS = {
    "default": {},
    "spread_sigma": {"spectral_spread_sigma": True},
    "change": {"spectral_spread_sigma": True, "max_spectral_spread": 1.0},
    "change_2": {"spectral_spread_sigma": True, "max_spectral_spread": 2.0},
    "detect": {"detect_change": True},
}


def run(cache: Path, pairs, seeds, variants) -> list:
    """Match every (pair, seed, reference, variant); one dict of figures per row."""
    from dataclasses import replace

    from gcpmatch.options import MatchOptions

    rows = []
    for name in pairs:
        source, refs = change_pairs.PAIRS[name]
        for seed in seeds:
            scene = change_pairs.render_scene(cache / f"{name}_seed{seed}", DATA / source, seed)
            for kind, ref in refs.items():
                for variant in variants:
                    t0 = time.perf_counter()
                    table, summary = change_pairs.match(scene, DATA / ref, replace(MatchOptions(), **VARIANTS[variant]))
                    row = {"pair": name, "seed": seed, "reference": kind, "variant": variant,
                           "seconds": time.perf_counter() - t0, "change": summary.get("change")}
                    if table is None:
                        row.update(n=0, message=summary.get("message", ""))
                    else:
                        err, sigma = change_pairs.truth_errors(scene, table)
                        row.update(change_pairs.figures(err, sigma), mean_px=err.mean(axis=0).round(4).tolist(),
                                   err=err.tolist(), sigma=sigma.tolist())
                    rows.append(row)
                    _print_row(row)
                    if table is not None and kind == "cross" and name in change_pairs.BAND_OFFSET_M:
                        nir = DATA / (source if "B08" in source else ref)
                        wet = change_pairs.water_fraction(table, nir)
                        print(f"{'':14s} {table.row.size} GCPs, {int(np.sum(wet >= 0.6))} on windows at least 60 % water")
                        # the same GCPs graded against the source band's ground: the reference
                        # band's own displacement (measured by bench/band_offset.py) taken out
                        err, sigma = change_pairs.truth_errors(scene, table, change_pairs.BAND_OFFSET_M[name],
                                                               change_pairs.dom_crs(DATA / ref))
                        fixed = {**row, "reference": "cross_band_offset_out"}
                        fixed.update(change_pairs.figures(err, sigma), mean_px=err.mean(axis=0).round(4).tolist(),
                                     err=err.tolist(), sigma=sigma.tolist())
                        rows.append(fixed)
                        _print_row(fixed)
                        # diagnostic: each GCP's own window displacement (ECC) taken out instead
                        err, sigma = change_pairs.truth_errors(
                            scene, table, band_offset.local_offsets_m(table, DATA / source, DATA / ref),
                            change_pairs.dom_crs(DATA / ref))
                        local = {**row, "reference": "cross_local_offset_out"}
                        local.update(change_pairs.figures(err, sigma), mean_px=err.mean(axis=0).round(4).tolist(),
                                     err=err.tolist(), sigma=sigma.tolist())
                        rows.append(local)
                        _print_row(local)
    return rows


def _print_row(r: dict) -> None:
    head = f"{r['pair']:14s} seed {r['seed']:3d} {r['reference']:21s} {r['variant']:12s}"
    if not r["n"]:
        print(f"{head} no GCP: {r.get('message', '')[:120]}")
        return
    print(f"{head} {r['n']:4d} GCPs  rms {r['rms_px']:.4f}  median {r['median_px']:.4f}  p95 {r['p95_px']:.4f}  "
          f"mean {r['mean_px']}  z {r['z']:.2f} ({r['z_row']:.2f}, {r['z_col']:.2f})  {r['seconds']:.1f} s"
          + (f"  change: median spread ratio {r['change']['median_spread_ratio']:.2f}, detected {r['change']['detected']}"
             if r.get("change") and r["change"]["median_spread_ratio"] is not None else ""))


def pooled(rows: list) -> list:
    """Figures over the seeds of each (pair, reference, variant): all their GCPs together."""
    out = []
    keys = sorted({(r["pair"], r["reference"], r["variant"]) for r in rows},
                  key=lambda k: (k[0], k[1], list(VARIANTS).index(k[2])))
    for pair, kind, variant in keys:
        sel = [r for r in rows if (r["pair"], r["reference"], r["variant"]) == (pair, kind, variant) and r["n"]]
        if not sel:
            out.append({"pair": pair, "reference": kind, "variant": variant, "n": 0})
            continue
        err = np.concatenate([np.array(r["err"]) for r in sel])
        sigma = np.concatenate([np.array(r["sigma"]) for r in sel])
        out.append({"pair": pair, "reference": kind, "variant": variant, **change_pairs.figures(err, sigma)})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, help="folder of the rendered scenes (kept); default: temporary")
    ap.add_argument("--seeds", default="11,12")
    ap.add_argument("--pairs", default=",".join(change_pairs.PAIRS))
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--json", type=Path, help="write the figures there")
    a = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"real test data not found at {DATA}", file=sys.stderr)
        return 1
    seeds = [int(s) for s in a.seeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        cache = a.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        rows = run(cache, a.pairs.split(","), seeds, a.variants.split(","))
    print("\npooled over seeds", seeds)
    summary = pooled(rows)
    for r in summary:
        head = f"{r['pair']:14s} {r['reference']:21s} {r['variant']:12s}"
        print(head + (" no GCP" if not r["n"] else
                      f" {r['n']:4d} GCPs  rms {r['rms_px']:.4f}  p95 {r['p95_px']:.4f}  z {r['z']:.2f} "
                      f"({r['z_row']:.2f}, {r['z_col']:.2f})"))
    if a.json:
        a.json.write_text(json.dumps({"rows": [{k: v for k, v in r.items() if k not in ("err", "sigma")} for r in rows],
                                      "pooled": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
