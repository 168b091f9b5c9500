"""What bounds the match's memory whatever the machine: freed heap handed back between its
stages, GDAL's tile cache held to a set size while a reference chip renders, and the window
tasks in flight held to a set number of windows.

* :func:`sensor_models.files.memory.release_free_heap` returns the free pages a thread's arena
  keeps (glibc): 192 MiB of 64 KiB arrays allocated on a thread, fifteen in sixteen freed (the
  rest pin the heap, so glibc cannot shrink it from the top by itself); the resident size falls
  by most of the freed bytes, and the arrays still alive keep their values.
* :func:`gcpmatch.reference.reference_for_ccd` renders its blocks under
  ``REFERENCE_GDAL_CACHE_BYTES`` of GDAL cache (its default is 5 % of the RAM, so the match's
  peak grew with the machine) and gives the cap back when it returns; the chip does not change
  with the cap (tiles decoded again read the same pixels).
* The window stage runs at most the tasks whose scratch fits ``CPU_HOST_WINDOW_BYTES`` at once on
  the CPU backend, whatever the threads, and its results are those of one thread.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from sensor_models.files.memory import _malloc_trim, release_free_heap

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"


def _rss_bytes() -> int:
    with open("/proc/self/status", encoding="ascii") as status:
        return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmRSS:"))


@pytest.mark.skipif(_malloc_trim() is None or not Path("/proc/self/status").exists(),
                    reason="needs glibc's malloc_trim and Linux's /proc/self/status")
def test_free_pages_of_a_threads_arena_go_back_and_live_arrays_keep_their_values():
    kept = []

    def allocate():  # on its own thread: glibc gives it an arena of its own
        arrays = [np.full(8192, i, dtype=np.float64) for i in range(3072)]  # 64 KiB each, 192 MiB
        kept.extend(arrays[::16])

    worker = threading.Thread(target=allocate)
    worker.start()
    worker.join()
    # the freed 15/16 lie between live arrays: the heap cannot shrink from its top
    before = _rss_bytes()
    assert release_free_heap()
    after = _rss_bytes()
    freed = 3072 * 15 // 16 * 65536
    assert before - after > 0.6 * freed, (before, after)
    assert all(np.all(a == 16 * i) for i, a in enumerate(kept))


def test_the_reference_renders_under_the_capped_tile_cache_and_restores_it(monkeypatch):
    import gcpmatch.reference as reference
    from rasterio._env import get_gdal_config

    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model
    from sensor_models.terrain.dem import Dem

    model = open_model(FIXTURE / "truth_manifest.json")
    dem = Dem.open(FIXTURE / "reference" / "dem.tif")
    dom = MapImage.open(FIXTURE / "reference" / "dom.tif")
    seen = []
    sample = reference.sample_map_image

    def sample_and_note(*args, **kwargs):  # the renderer's own sampling, noting the cache cap
        seen.append(int(get_gdal_config("GDAL_CACHEMAX")))
        return sample(*args, **kwargs)

    monkeypatch.setattr(reference, "sample_map_image", sample_and_note)
    default = int(get_gdal_config("GDAL_CACHEMAX"))
    chip = reference.reference_for_ccd(model, dem, dom, band="B2", ccd=1, block_lines=128, workers=2)
    assert len(seen) == 4 and set(seen) == {reference.REFERENCE_GDAL_CACHE_BYTES}
    assert reference.REFERENCE_GDAL_CACHE_BYTES != default  # else the test could not tell
    assert int(get_gdal_config("GDAL_CACHEMAX")) == default
    # a cache too small to keep any tile decodes tiles again: the same pixels
    monkeypatch.setattr(reference, "REFERENCE_GDAL_CACHE_BYTES", 1 << 10)
    again = reference.reference_for_ccd(model, dem, dom, band="B2", ccd=1, block_lines=128, workers=2)
    np.testing.assert_array_equal(chip, again)
    assert np.isfinite(chip).mean() > 0.9


def test_window_tasks_in_flight_stay_within_the_host_windows_and_keep_the_results(monkeypatch):
    import cv2

    import gcpmatch.extract as extract
    from gcpmatch.extract import _correlate_windows, grid_starts
    from gcpmatch.options import MatchOptions

    rng = np.random.default_rng(5)
    ref = cv2.GaussianBlur(rng.standard_normal((384, 160)).astype(np.float32), (0, 0), 1.5) * 300.0 + 1000.0
    scene = np.roll(ref, (1, -2), axis=(0, 1)) + rng.normal(0.0, 3.0, ref.shape).astype(np.float32)
    mask = np.zeros(ref.shape, bool)
    rr, cc = (a.ravel() for a in np.meshgrid(grid_starts(384, 32, 16), grid_starts(160, 32, 16), indexing="ij"))
    assert rr.size == 207
    at_once = []
    map_ordered = extract.map_ordered

    def map_and_note(function, items, threads, **kwargs):  # the stage's own pool, noting its size
        at_once.append(threads)
        return map_ordered(function, items, threads, **kwargs)

    monkeypatch.setattr(extract, "map_ordered", map_and_note)
    task_bytes = extract.WINDOW_SCRATCH_BYTES_PER_PX * 32**2 * 16  # a task of 16 windows of 32 px
    monkeypatch.setattr(extract, "CPU_HOST_WINDOW_BYTES", 3 * task_bytes + task_bytes // 2)  # room for three
    runs = {n: _correlate_windows(scene, ref, mask, rr, cc, MatchOptions(window_px=32, spacing_px=16, batch=16,
                                                                          threads=n))
            for n in (1, 2, 8)}
    assert at_once == [1, 2, 3]
    status, _, shift, _ = runs[1]
    assert np.count_nonzero(status == "") > 150
    np.testing.assert_allclose(np.nanmedian(shift, axis=0), [1.0, -2.0], atol=0.02)
    for n in (2, 8):
        assert list(runs[n][0]) == list(status)
        np.testing.assert_array_equal(runs[n][2], shift)
