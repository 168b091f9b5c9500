"""Bounded memory: ortho reads the DEM by windows, simulate renders by blocks.

* An orthoimage made with the DEM read window by window is byte for byte the one made with the
  whole DEM in memory (fixture; Pleiades crop over SRTM with EGM96 heights), and the coarse DEM
  alone would not give it (so the windows do supply the heights).
* The peak RSS an ortho adds (fresh process, ``/proc/self/clear_refs``) does not grow with the
  scene: 4x the pixels add about the same, well below what loading that scene's DEM whole adds.
* Simulating by blocks of lines gives the scene that one block of the whole image gives (to the
  rounding of a DN: 1 DN on a few pixels where float sums of other lengths differ), and the
  summary's timings cover the whole render with a phase breakdown.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio

from sensor_models import open_model
from sensor_models.imaging.ortho import orthorectify_to_file
from sensor_models.terrain.dem_windows import DemWindows, open_ortho_dem
from sensor_models.terrain.dem import Dem

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "fixtures" / "hy1c_czi"
DEM = FIX / "reference" / "dem.tif"
B2 = FIX / "B2.tif"


def _pixels(path):
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform, ds.shape


@pytest.fixture(scope="module")
def truth():
    return open_model(FIX / "truth_manifest.json")


def test_windowed_dem_ortho_is_byte_identical_on_the_fixture(tmp_path, truth):
    whole = Dem.open(DEM)
    coarse, windows = open_ortho_dem(DEM, max_nodes=60_000)  # the fixture's DEM has 671 k nodes
    assert windows is not None and coarse.shape[0] * coarse.shape[1] <= 60_000
    a, b, c = tmp_path / "whole.tif", tmp_path / "windows.tif", tmp_path / "coarse.tif"
    sa = orthorectify_to_file(truth, B2, whole, a, block=256)
    sb = orthorectify_to_file(truth, B2, coarse, b, block=256, dem_windows=windows)
    windows.close()
    orthorectify_to_file(truth, B2, coarse, c, block=256)  # the coarse DEM alone
    va, ta, _ = _pixels(a)
    vb, tb, _ = _pixels(b)
    vc, _, _ = _pixels(c)
    assert ta == tb and np.array_equal(va, vb)
    assert sa["dem_read"] == "whole" and sb["dem_read"] == "windows"
    assert np.count_nonzero(va != vc) > 0.01 * va.size  # heights come from the windows, not the coarse copy
    # every block read a window, never the whole DEM
    assert 0 < windows.largest_window_nodes < 0.25 * windows.shape[0] * windows.shape[1]


def test_small_dem_is_read_whole():
    dem, windows = open_ortho_dem(DEM)
    assert windows is None and dem.shape == (721, 931)
    _, windows = open_ortho_dem(DEM, max_nodes=721 * 931 - 1)
    assert windows is not None
    windows.close()


def test_windows_refuse_what_the_whole_dem_refuses(tmp_path):
    from sensor_models.errors import DemError

    bare = tmp_path / "bare.tif"  # no vertical datum declared
    with rasterio.open(DEM) as src:
        profile = src.profile
        data = src.read(1)
    with rasterio.open(bare, "w", **profile) as dst:
        dst.write(data, 1)
    with pytest.raises(DemError, match="vertical datum"):
        open_ortho_dem(bare, max_nodes=1000)
    dem, windows = open_ortho_dem(bare, vertical_datum="ellipsoid", max_nodes=1000)
    assert windows is not None and dem.shape[0] * dem.shape[1] <= 1000
    windows.close()


@pytest.mark.shared_data
def test_windowed_dem_ortho_is_byte_identical_on_pleiades(shared_data, tmp_path):
    from sensor_models.readers.rpc_files import read_rpc
    from sensor_models.terrain.geoid import Geoid

    folder = shared_data / "pleiades_ventoux"
    with rasterio.open(folder / "left_image.tif") as ds:
        t, shape = ds.transform, (ds.height, ds.width)
    left = read_rpc(folder / "left_image.geom").cropped(t.f, t.c, shape)
    hgt, geoid = shared_data / "dem" / "N44E005.hgt", Geoid.open(shared_data / "dem" / "egm96_15.gtx")
    whole = Dem.open(hgt, vertical_datum="egm96", geoid=geoid)
    a, b = tmp_path / "whole.tif", tmp_path / "windows.tif"
    image = folder / "left_image.tif"
    orthorectify_to_file(left, image, whole, a, resolution_m=0.5, block=128)
    windows = DemWindows(hgt, "egm96", geoid)
    orthorectify_to_file(left, image, whole, b, resolution_m=0.5, block=128, dem_windows=windows)
    windows.close()
    va, ta, _ = _pixels(a)
    vb, tb, _ = _pixels(b)
    assert ta == tb and np.array_equal(va, vb) and np.count_nonzero(va) > 0.5 * va.size
    assert 0 < windows.largest_window_nodes < 0.01 * 3601 * 3601


def _synthetic_scene(folder: Path, side: int):
    """A 4-CCD model of ``side x side`` px at 30 m, its tiled uint16 raster and a 1" DEM (bench inputs)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_memory", ROOT / "bench" / "bench_memory.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    model = bench.build_model(side, side, 30.0)
    image = folder / f"scene_{side}.tif"
    bench.write_tiled_uint16(image, *model.image_shape)
    from sensor_models.simulate.render_io import footprint_lonlat

    lon, lat = footprint_lonlat(model, (200.0, 1700.0))
    dem = folder / f"dem_{side}.tif"
    bench.write_dem(dem, (lon.min(), lon.max()), (lat.min(), lat.max()), 1.0 / 3600.0)
    return model, image, dem


_PEAK_CHILD = """
import json, sys
from pathlib import Path
from sensor_models.imaging.ortho import orthorectify_to_file
from sensor_models.terrain.dem_windows import open_ortho_dem
from sensor_models import open_model

def status(key):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0

manifest, image, dem_path, out, what = sys.argv[1:6]
model = open_model(manifest)
Path("/proc/self/clear_refs").write_text("5\\n")  # the peak (VmHWM) restarts from the current RSS
base = status("VmRSS")
if what == "ortho":
    dem, windows = open_ortho_dem(dem_path, max_nodes=20_000)
    summary = orthorectify_to_file(model, image, dem, out, block=128, dem_windows=windows)
    shape = summary["shape"]
else:  # the whole DEM, as the ortho loaded it before
    from sensor_models.terrain.dem import Dem
    shape = list(Dem.open(dem_path).shape)
print(json.dumps({"added_mib": status("VmHWM") - base, "shape": shape}))
"""


def _peak_added_mib(folder: Path, side: int, what: str = "ortho") -> dict:
    """Peak RSS (MiB) an ortho of a ``side``-pixel scene adds in a fresh process, and its output shape."""
    import os
    import subprocess
    import sys

    from sensor_models.readers.manifest import write_manifest

    model, image, dem = _synthetic_scene(folder, side)
    manifest = write_manifest(model, folder / f"scene_{side}.json", rasters={b: image for b in model.bands})
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    res = subprocess.run([sys.executable, "-c", _PEAK_CHILD, str(manifest), str(image), str(dem),
                          str(folder / f"ortho_{side}.tif"), what], env=env, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc/self/clear_refs")
def test_ortho_peak_memory_does_not_grow_with_the_scene(tmp_path):
    small = _peak_added_mib(tmp_path, 512)
    large = _peak_added_mib(tmp_path, 1024)
    # what loading a DEM whole adds grows with the scene (a scene twice as wide: 4x the nodes), where
    # the windowed ortho's peak does not (a Dem builds its bounds at about 40 bytes a node and holds
    # 23: on the large scene's own 3.2 M nodes that is about twice the windowed ortho's peak)
    whole_dem = _peak_added_mib(tmp_path, 2048, "dem")
    assert np.prod(large["shape"]) > 3.5 * np.prod(small["shape"])  # 4x the output pixels ...
    assert large["added_mib"] < 1.3 * small["added_mib"] + 16.0  # ... not 4x the memory
    assert np.prod(whole_dem["shape"]) > 8e6 and whole_dem["added_mib"] > 2.0 * large["added_mib"]


# ---------------------------------------------------------------- simulate by blocks
def _noiseless_config():
    from sensor_models.simulate.config import SimConfig

    cfg = SimConfig()
    return replace(cfg, scene=replace(cfg.scene, n_rows=192), radiometry=replace(cfg.radiometry, snr=float("inf"))
                   ).validate()


def test_simulate_by_blocks_equals_simulate_at_once(tmp_path):
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    cfg = _noiseless_config()  # without noise (whose draws are seeded per block) the blocks must agree
    steps = []
    s_blocks = simulate_pushbroom(tmp_path / "blocks", config=cfg, workers=1, block_lines=32,
                                  progress=lambda done, total: steps.append((done, total)))
    s_once = simulate_pushbroom(tmp_path / "once", config=cfg, workers=1, block_lines=192)
    va, _, _ = _pixels(tmp_path / "blocks" / "B2.tif")
    vb, _, _ = _pixels(tmp_path / "once" / "B2.tif")
    assert va.shape == (192, cfg.camera.n_cameras * cfg.camera.ccds_per_camera * cfg.camera.detectors_per_ccd)
    # the same radiance to rounding: a block's float sums may differ from the whole's in the last
    # bits (vectorized loops over other lengths; 1 DN on 0.13 % of the pixels on an AVX2 CPU, 0 on
    # AVX-512), which flips a DN that lies on a rounding edge, never more
    differ = va != vb
    assert np.abs(va.astype(np.int64) - vb).max() <= 1 and differ.mean() < 0.01
    assert va.std() > 100  # textured
    # progress: two set-up steps (models, reference: the procedural reference counted in its
    # phases and DOM strips, P parts), then one step per block of 32 lines
    total = steps[-1][1]
    parts = total - 8
    assert parts > 0 and steps[0] == (1, 8) and steps[-1] == (total, total)
    assert [d for d, _ in steps] == sorted(d for d, _ in steps)
    assert steps[-7:] == [(parts + k, total) for k in range(2, 9)]  # reference done, then the 6 blocks
    # timings: "rendered in" covers the set-up and the blocks; the phases add up to the command
    phases = s_blocks["phase_seconds"]
    assert list(phases) == ["models", "reference", "blocks", "truth_error", "outputs"]
    assert s_blocks["render_seconds"] == pytest.approx(phases["models"] + phases["reference"] + phases["blocks"],
                                                       abs=0.01)
    assert s_blocks["seconds"] == pytest.approx(sum(phases.values()), abs=0.05)
    assert s_blocks["render_seconds"] > phases["blocks"] > 0 and s_once["seconds"] > 0
    written = json.loads((tmp_path / "blocks" / "summary.json").read_text())
    assert written["phase_seconds"] == phases


def test_untimed_summary_holds_no_phase_times(tmp_path):
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    cfg = replace(_noiseless_config(), scene=replace(_noiseless_config().scene, n_rows=64))
    summary = simulate_pushbroom(tmp_path / "s", config=cfg, workers=1, record_timings=False)
    assert not {"phase_seconds", "render_seconds", "seconds"} & set(summary)
    assert "phase_seconds" not in json.loads((tmp_path / "s" / "summary.json").read_text())
