"""Memory of ``gcpcal simulate pushbroom --profile realistic``: by strips, the same scene; per source pixel, a bounded cost.

* The realistic render's steps over the whole source grid (the procedural DOM's texture and PSF,
  contrast scaling, texture-poor patches, the suns' light, the reference DOM's degradation) work
  by strips of rows sized in pixels (``_STRIP_PIXELS`` of each module). Run with strips of a few
  rows, the scene, its reference DOM and DEM and its summary equal the run with one strip per
  step (the whole raster), to the tolerances of ``tests/compare_outputs.py``.
* The peak RSS of the command (a child process, ``ru_maxrss``) grows with the source grid by at
  most :data:`MAX_BYTES_PER_SOURCE_PIXEL` between two widths of the seed-003 geometry (measured:
  15.0 bytes a pixel, with the source, the lit radiances and the PSF planes in scratch files read
  by strips and windows; 23.8 with them whole in memory; the same steps on whole rasters, each
  holding its whole-grid temporaries, 56.6: docs/memory.md).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import rasterio

from compare_outputs import compare_folders
from sensor_models.simulate import illumination, procedural_dom, realistic_sim, reference_pair, texture_poor, texture_stats
from sensor_models.simulate.config import config_from_dict
from sensor_models.simulate.profiles import get_profile
from sensor_models.simulate.realistic_sim import simulate_realistic

ROOT = Path(__file__).resolve().parents[1]
#: modules whose whole-grid steps run by strips of ``_STRIP_PIXELS`` pixels
STRIPPED = (illumination, procedural_dom, realistic_sim, reference_pair, texture_poor, texture_stats)
#: a small scene with a sun and a wide-enough source grid for many strips of a few rows
SCENE = {"scene": {"n_rows": 128}, "camera": {"detectors_per_ccd": 64, "overlap_detectors": 6},
         "reference": {"margin_m": 1000.0}}
#: bound on the peak RSS added per source pixel (bytes)
MAX_BYTES_PER_SOURCE_PIXEL = 20.0


def _render(out: Path, monkeypatch, strip_pixels: int) -> list:
    """Render :data:`SCENE` under ``realistic`` with every strip at most ``strip_pixels`` pixels; the progress totals."""
    for module in STRIPPED:
        monkeypatch.setattr(module, "_STRIP_PIXELS", strip_pixels)
    totals = []
    simulate_realistic(out, config_from_dict(SCENE), get_profile("realistic"), workers=1, record_timings=False,
                       progress=lambda done, total: totals.append(total))
    return totals


def test_realistic_scene_by_strips_equals_the_whole(tmp_path, monkeypatch):
    whole, strips = tmp_path / "whole", tmp_path / "strips"
    totals_whole = _render(whole, monkeypatch, 1 << 40)
    totals_strips = _render(strips, monkeypatch, 2_000)
    # the procedural DOM counts its strips in the progress: a few rows each here, one strip there
    assert totals_strips[-1] > totals_whole[-1] + 20
    with rasterio.open(strips / "reference" / "dom.tif") as ds:  # 30 m; the source grid is at 15 m
        source_cols, source_rows = ds.width * abs(ds.transform.a) / 15.0, ds.height * abs(ds.transform.e) / 15.0
    assert source_cols > 500 and source_rows > 100 * (2_000 // source_cols)  # strips of a few rows, many of them
    assert not compare_folders(whole, strips)


_CHILD = """
import json, sys
from calibrate.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _peak(tmp: Path, detectors_per_ccd: int) -> dict:
    """Peak RSS (bytes) of ``gcpcal simulate pushbroom --profile realistic`` in a child, and its source pixels."""
    doc = {"scene": {"n_rows": 256, "gsd_m": 45.0},
           "camera": {"detectors_per_ccd": detectors_per_ccd, "overlap_detectors": 12, "bands": ["B2"],
                      "band_offsets_px": [-2.0]},
           "radiometry": {"band_gain": [1.0], "band_offset_dn": [40.0], "band_gamma": [1.0]},
           "reference": {"dom_resolution_m": 22.5, "dem_resolution_m": 90.0, "relief_m": 1500.0, "margin_m": 3000.0}}
    cfg = tmp / f"cfg_{detectors_per_ccd}.json"
    cfg.write_text(json.dumps(doc))
    out = tmp / f"scene_{detectors_per_ccd}"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, "simulate", "pushbroom", "--config", str(cfg), "--profile",
                             "realistic", "--out", str(out), "--workers", "1"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    assert status == 0, proc.stderr.read().decode()[-2000:]
    proc.stderr.close()
    with rasterio.open(out / "reference" / "dom.tif") as ds:  # the source grid's extent, at 22.5 m
        source_pixels = ds.width * abs(ds.transform.a) * ds.height * abs(ds.transform.e) / 22.5**2
    return {"peak_bytes": usage.ru_maxrss * 1024.0, "source_pixels": source_pixels}


@pytest.mark.slow
def test_realistic_peak_memory_per_source_pixel_is_bounded(tmp_path):
    """About 30 s: two renders of the seed-003 geometry at 1/32 and 1/8 of its
    width (170 and 681 detectors per CCD), 256 lines, one band."""
    small, large = _peak(tmp_path, 170), _peak(tmp_path, 681)
    assert large["source_pixels"] > 3.0 * small["source_pixels"]
    per_pixel = (large["peak_bytes"] - small["peak_bytes"]) / (large["source_pixels"] - small["source_pixels"])
    assert per_pixel < MAX_BYTES_PER_SOURCE_PIXEL, per_pixel
