"""GCP truth error against the DOM's resolution: the figures behind ``MAX_DOM_GSD_RATIO``.

For each demo fixture the DOM is averaged over ``f x f`` pixels (a reference ``f`` times
coarser), the scene is matched with ``gcpcal match --allow-implausible`` (the CLI a user runs)
and each GCP's image point is compared with the TRUE model's projection of its ground point
(:func:`calibrate.experiments.simulate_seed003.gcp_truth_error`). The ratio of that RMS to the
RMS of the GCPs' own ``sigma_px`` says how far the stated uncertainty is from the truth.

Usage::

    PYTHONPATH=. python bench/bench_dom_ratio.py [hy1c_czi hy1c_czi_realistic]

Prints one line per (fixture, ratio) and writes ``bench/results/dom_ratio.json``.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine
from rasterio.enums import Resampling

ROOT = Path(__file__).resolve().parents[1]
#: DOM averaging factors per fixture: ratios about 0.5 to 5 of the scene's 30 m GSD
FACTORS = {"hy1c_czi": (1, 2, 4, 6, 8, 10), "hy1c_czi_realistic": (1, 2, 3, 4)}


def coarse_dom(src: Path, dst: Path, factor: int) -> float:
    """Write ``src`` averaged over ``factor`` x ``factor`` pixels to ``dst``; its pixel size, m."""
    with rasterio.open(src) as ds:
        h, w = ds.height // factor, ds.width // factor
        data = ds.read(out_shape=(ds.count, h, w), resampling=Resampling.average)
        profile = ds.profile | {"height": h, "width": w,
                                "transform": ds.transform * Affine.scale(ds.width / w, ds.height / h)}
        tags, res = ds.tags(), ds.res[0] * ds.width / w
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
        out.update_tags(**tags)
    return float(res)


def run(fixture: str, work: Path) -> list[dict]:
    from calibrate.cli import main
    from calibrate.experiments.simulate_seed003 import gcp_truth_error
    from gcpmatch.gcp_files import read_gcps
    from sensor_models.imaging.ortho_grid import scene_gsd_m
    from sensor_models.readers import open_scene

    fx = ROOT / "fixtures" / fixture
    truth = open_scene(fx / "truth_manifest.json").model
    gsd = scene_gsd_m(open_scene(fx / "manifest.json").model)
    rows = []
    for f in FACTORS[fixture]:
        dom = work / f"{fixture}_dom_{f}.tif"
        res = coarse_dom(fx / "reference" / "dom.tif", dom, f)
        out = work / f"{fixture}_gcps_{f}.csv"
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            code = main(["-q", "match", str(fx / "manifest.json"), "--dom", str(dom), "--dem",
                         str(fx / "reference" / "dem.tif"), "--out", str(out), "--spacing", "32", "--allow-implausible"])
        row = {"fixture": fixture, "dom_m": res, "gsd_m": gsd, "ratio": res / gsd, "exit": code}
        if code == 0:
            table = read_gcps(out)
            err = gcp_truth_error(truth, table)
            sigma_rms = float(np.sqrt(np.mean(np.asarray(table.sigma_px) ** 2)))
            row.update(gcps=len(table), truth_rms_px=err["rms_px"], truth_median_px=err["median_px"],
                       sigma_rms_px=sigma_rms, error_over_sigma=err["rms_px"] / sigma_rms)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


if __name__ == "__main__":
    names = sys.argv[1:] or list(FACTORS)
    with tempfile.TemporaryDirectory() as tmp:
        results = [r for name in names for r in run(name, Path(tmp))]
    out = ROOT / "bench" / "results" / "dom_ratio.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n")
