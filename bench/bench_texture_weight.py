"""Matcher variants on the realistic demo, with each GCP's truth error split by texture class.

Runs ``gcpcal demo`` (:func:`calibrate.pipelines.demo.run_demo`, fixture ``hy1c_czi_realistic``
unless ``--fixture``) once per variant of :class:`gcpmatch.options.MatchOptions`, side by side in
one process, and reports per variant: GCP count, the GCP truth error (rms, px, 2-D) per texture
class, the truth / sigma calibration of the GCPs, the demo's truth error (rms / max over every CCD
and band) and its check RMSE.

* GCP truth error: the matched ``(row, col)`` minus the TRUE model's projection of the GCP's
  ``(lon, lat, h)`` (``truth_manifest.json``), as ``tests/test_matcher_realism.py`` and
  ``bench/bench_matcher_realism.py`` grade a GCP.
* Texture class: the share of the GCP's 64 px window (9 x 9 points, localized by the TRUE model
  on the TRUE DEM) inside a texture-poor patch of the procedural source
  (:func:`sensor_models.simulate.texture_poor.texture_poor_mask` redrawn with the simulator's seed
  and grid); classes ``<10 %``, ``10-50 %``, ``50-90 %``, ``>90 %``. An ``ideal`` fixture has no
  patches (all GCPs in ``<10 %``).

A variant only sets :class:`MatchOptions` fields; the demo's own ``spacing_px`` is kept.

Usage: ``python bench/bench_texture_weight.py [--variants default,cr] [--fixture ideal] [--out FILE]``
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
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "fixtures"))

CLASSES = ((0.0, 0.1, "<10%"), (0.1, 0.5, "10-50%"), (0.5, 0.9, "50-90%"), (0.9, 1.01, ">90%"))


def variants() -> dict:
    """Named ``MatchOptions`` overrides to measure."""
    return {
        "default": {},  # mismatch_sigma_scale 1
        "no_mismatch": {"mismatch_sigma_scale": 0.0},  # the sigma model before
        "gate_snr_3.5": {"mismatch_sigma_scale": 0.0, "min_gradient_snr": 3.5},
        "gate_snr_4.5": {"mismatch_sigma_scale": 0.0, "min_gradient_snr": 4.5},
        **{f"texture_sigma_{v}": {"mismatch_sigma_scale": 0.0, "texture_sigma_px": v} for v in (0.15, 0.2, 0.25, 0.3, 0.4)},
        "gate_snr_3.5_sigma_0.3": {"mismatch_sigma_scale": 0.0, "min_gradient_snr": 3.5, "texture_sigma_px": 0.3},
        **{f"mismatch_{v:g}": {"mismatch_sigma_scale": v} for v in (2.0, 4.0)},
    }


def patch_mask(fixture: Path):
    """The texture-poor patches of the fixture's procedural source: (mask, transform, crs), or None."""
    from make_hy1c_fixture import config

    from sensor_models.simulate.profiles import PROFILES
    from sensor_models.simulate.realistic_sim import realistic_setup
    from sensor_models.simulate.texture_poor import texture_poor_mask

    truth = json.loads((fixture / "truth.json").read_text())
    profile = PROFILES.get(truth.get("profile", "ideal"))
    if profile is None or float(profile.value("texture_poor_fraction")) == 0.0:
        return None
    cfg, _, _, source, _, data = realistic_setup(config(), profile, None)
    res_m = abs(source[1].a)
    mask = texture_poor_mask(source[0].shape, res_m, float(profile.value("texture_poor_fraction")),
                             seed=[cfg.seed, 40], exclude=data.water_mask)
    return mask, source[1], source[2]


def gcp_truth(fixture: Path, gcps_csv: Path, patches, window_px: int = 64) -> dict:
    """Truth error (n, 2) px, sigma_px (n,), score (n,) and patch share (n,) of the GCPs (kind gcp)."""
    import pyproj

    from gcpmatch.gcp_files import read_gcps
    from sensor_models.readers import open_model
    from sensor_models.terrain.dem import Dem

    table = read_gcps(gcps_csv)
    use = np.asarray(table.kind) == "gcp"
    truth = open_model(fixture / "truth_manifest.json")
    band = str(table.band[0])
    ccd = np.asarray(table.ccd)[use]
    row, col = np.asarray(table.row)[use], np.asarray(table.col)[use]
    r_t, c_t = truth.ground_to_image(np.asarray(table.lon)[use], np.asarray(table.lat)[use],
                                     np.asarray(table.h)[use], band=band, array=ccd)
    share = np.zeros(row.size)
    if patches is not None:
        mask, transform, crs = patches
        dem = Dem.open(fixture / "reference" / "truth" / "dem_true.tif")
        off = np.linspace(-0.5 * window_px, 0.5 * window_px, 9)
        dr, dc = (a.ravel() for a in np.meshgrid(off, off, indexing="ij"))
        rr, cc = (row[:, None] + dr).ravel(), (col[:, None] + dc).ravel()
        lon, lat, _ = truth.image_to_ground(rr, cc, dem=dem, band=band, array=np.repeat(ccd, dr.size))
        x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
        inv = ~transform
        px, py = inv * (np.asarray(x), np.asarray(y))
        i = np.clip(np.floor(py).astype(int), 0, mask.shape[0] - 1)
        j = np.clip(np.floor(px).astype(int), 0, mask.shape[1] - 1)
        share = mask[i, j].reshape(row.size, -1).mean(axis=1)
    return {"err": np.stack([row - r_t, col - c_t], axis=1), "sigma": np.asarray(table.sigma_px, float)[use],
            "score": np.asarray(table.score, float)[use], "share": share}


def gcp_metrics(g: dict) -> dict:
    """GCP count, truth rms (2-D, px) per texture class and z = error / sigma rms per axis."""
    d2 = np.sum(g["err"] ** 2, axis=1)
    z = g["err"] / g["sigma"][:, None]
    out = {"gcps": int(d2.size), "truth_rms_px": float(np.sqrt(d2.mean())), "by_class": {},
           "z_rms": float(np.sqrt(np.mean(z**2))),
           "z_rms_row": float(np.sqrt(np.mean(z[:, 0] ** 2))), "z_rms_col": float(np.sqrt(np.mean(z[:, 1] ** 2)))}
    for lo, hi, name in CLASSES:
        sel = (g["share"] >= lo) & (g["share"] < hi)
        out["by_class"][name] = {"gcps": int(sel.sum()),
                                 "truth_rms_px": float(np.sqrt(d2[sel].mean())) if sel.any() else None,
                                 "sigma_rms_px": float(np.sqrt(np.mean(g["sigma"][sel] ** 2))) if sel.any() else None,
                                 "z_rms": float(np.sqrt(np.mean(z[sel] ** 2))) if sel.any() else None}
    return out


def run_variant(fixture: Path, overrides: dict, out: Path) -> dict:
    """The demo with ``MatchOptions`` defaults replaced by ``overrides``; its summary."""
    import functools

    import gcpmatch.options as mo
    from calibrate.pipelines.demo import run_demo

    original = mo.MatchOptions
    mo.MatchOptions = functools.partial(original, **overrides)
    try:
        return run_demo(out, fixture_dir=fixture)
    finally:
        mo.MatchOptions = original


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fixture", default="realistic", help="realistic, ideal or a fixture folder")
    ap.add_argument("--variants", default=None, help="comma-separated names (default: all)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    named = {"realistic": ROOT / "fixtures" / "hy1c_czi_realistic", "ideal": ROOT / "fixtures" / "hy1c_czi"}
    fixture = named.get(args.fixture, Path(args.fixture))
    table = variants()
    names = args.variants.split(",") if args.variants else list(table)
    patches = patch_mask(fixture)
    results = {"fixture": str(fixture.relative_to(ROOT) if fixture.is_relative_to(ROOT) else fixture),
               "loadavg": Path("/proc/loadavg").read_text().split()[:3], "variants": {}}
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            s = run_variant(fixture, table[name], Path(tmp))
            g = gcp_metrics(gcp_truth(fixture, Path(tmp) / "gcps.csv", patches))
        r = {"options": table[name], "demo_gcps": s["gcps"], "check_points": s["check_points"],
             "check_rmse_px": s["check_rmse_px"]["after"], "truth_error_px": s["truth_error_px"]["rms"],
             "truth_error_max_px": s["truth_error_px"]["max"], "gcp_truth": g, "seconds": time.perf_counter() - t0}
        results["variants"][name] = r
        cls = " ".join(f"{k} {v['gcps']}:{v['truth_rms_px'] or float('nan'):.3f} z{v['z_rms'] or float('nan'):.2f}"
                       for k, v in g["by_class"].items())
        print(f"{name:>18}: {r['demo_gcps']} GCPs, check {r['check_rmse_px']:.4f}, truth {r['truth_error_px']:.4f} / "
              f"{r['truth_error_max_px']:.3f} px; GCP truth {g['truth_rms_px']:.4f} [{cls}] "
              f"z {g['z_rms_row']:.2f}/{g['z_rms_col']:.2f} pooled {g['z_rms']:.2f}", flush=True)
    results["loadavg_end"] = Path("/proc/loadavg").read_text().split()[:3]
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
