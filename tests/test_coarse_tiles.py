"""The coarse stage under a SIFT memory budget: tiles that follow it, the same pre-correction.

A scene whose warped image or DOM window would need more than the budget for SIFT's scale space
(``SIFT_BYTES_PER_PX`` a pixel) is matched by overlapping tiles, each against the DOM around its
own footprint, the matches merged in scene coordinates before the one pre-correction fit. The
realistic demo fixture (512 x 768 px, LAB model 260 px off) with a forced small budget is tiled;
its pre-correction must match the whole-image one within a fraction of the fine stage's capture
radius.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gcpmatch.coarse as coarse
from gcpmatch.coarse import MIN_REDUCED_SIDE_PX, SIFT_BYTES_PER_PX, coarse_match, plan_tiles
from gcpmatch.options import MatchOptions
from gcpmatch.reference import scene_gsd_m

#: search margin of these tests, scene pixels: the fixture's DOM reaches 100-200 px beyond the
#: scene, so a wider margin is clipped to the raster and every tile would search the whole DOM
MAX_OFFSET_PX = 100.0


def _geo(model, dem, band):
    h_mid = coarse.scene_height_m(model, dem, band=band)
    gsd = scene_gsd_m(model, band=band, height_m=h_mid)
    return {"band": band, "h_mid": h_mid, "gsd": gsd, "coarse_res": gsd, "max_offset_px": MAX_OFFSET_PX}


def test_the_plan_follows_the_budget(realistic_demo_inputs):
    _, model, dem, dom, band, _ = realistic_demo_inputs
    geo = _geo(model, dem, band)
    small = model.image_shape  # factor 1: the fixture is not reduced
    assert plan_tiles(model, dom, small, 1, budget_px=10**9, **geo) is None  # fits: the whole-image path
    whole = coarse._cost_px(model, dom, 1, (0, small[0], 0, small[1]), geo)
    counts = []
    for share in (0.9, 0.7, 0.6):
        budget = int(share * whole)
        tiles = plan_tiles(model, dom, small, 1, budget_px=budget, **geo)
        assert tiles is not None and max(t.cost_px for t in tiles) <= budget
        counts.append(len(tiles))
        # cores partition the reduced scene; boxes hold their cores and keep SIFT's minimum side
        owner = np.zeros(small, int)
        for t in tiles:
            r0, r1, c0, c1 = t.box
            assert min(r1 - r0, c1 - c0) >= MIN_REDUCED_SIDE_PX
            k0, k1, j0, j1 = (int(np.clip(v, 0, n)) for v, n in zip(t.core, (small[0],) * 2 + (small[1],) * 2))
            assert r0 <= k0 < k1 <= r1 and c0 <= j0 < j1 <= c1
            owner[k0:k1, j0:j1] += 1
        assert (owner == 1).all()
    assert counts == sorted(counts) and counts[-1] > 1
    # a budget below what any tile of the minimum side can meet: the finest grid, the least memory
    finest = plan_tiles(model, dom, small, 1, budget_px=1000, **geo)
    assert len(finest) == (small[0] // MIN_REDUCED_SIDE_PX) * (small[1] // MIN_REDUCED_SIDE_PX)


def test_tiled_precorrection_equals_the_whole_image_one(realistic_demo_inputs):
    from sensor_models.simulate.truth import truth_error

    scene, model, dem, dom, band, truth = realistic_demo_inputs
    kw = {"band": band, "max_offset_px": MAX_OFFSET_PX, "n_features": 4000}
    whole = coarse_match(scene, model, dem, dom, **kw)
    geo = _geo(model, dem, band)
    budget_px = int(0.8 * coarse._cost_px(model, dom, 1, (0, scene.shape[0], 0, scene.shape[1]), geo))
    tiled = coarse_match(scene, model, dem, dom, sift_budget_bytes=budget_px * SIFT_BYTES_PER_PX, **kw)
    assert whole.tiles == 1 and tiled.tiles >= 2 and tiled.summary()["tiles"] == tiled.tiles
    apart = truth_error(whole.model, tiled.model, dem=dem, step_px=32)
    capture_px = MatchOptions().window_px / 4.0  # the fine stage's search radius
    print(f"whole vs {tiled.tiles} tiles: {apart['rms_px']:.3f} px rms, {apart['max_px']:.3f} px max; "
          f"inliers {whole.n_inliers} / {tiled.n_inliers}")
    assert apart["max_px"] < 0.25 * capture_px
    for result in (whole, tiled):  # both where the fine stage takes over (LAB: 260 px)
        assert truth_error(truth, result.model, dem=dem, step_px=32)["max_px"] < 0.5 * capture_px


SIFT_PROBE = """
import sys
import cv2, numpy as np


def hwm_bytes():  # this process's peak resident memory (not inherited across exec, unlike ru_maxrss)
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmHWM:"))


n = int(sys.argv[1])
rng = np.random.default_rng(0)
img = cv2.GaussianBlur((rng.random((n, n)) * 255).astype(np.float32), (0, 0), 2.0)
img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
mask = np.full((n, n), 255, np.uint8)
base = hwm_bytes()
cv2.SIFT_create(nfeatures=4000, contrastThreshold=0.01).detectAndCompute(img, mask)
print((hwm_bytes() - base) / (n * n))
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux's /proc/self/status (VmHWM)")
def test_sift_scale_space_costs_the_documented_bytes_a_pixel():
    # the peak resident memory of a fresh process: OpenCV allocates outside numpy, where
    # tracemalloc cannot see it
    out = subprocess.run([sys.executable, "-c", SIFT_PROBE, "1200"], capture_output=True, text=True, check=True)
    per_px = float(out.stdout.strip())
    print(f"SIFT: {per_px:.0f} bytes a pixel (documented {SIFT_BYTES_PER_PX})")
    assert 0.85 * SIFT_BYTES_PER_PX < per_px <= 1.05 * SIFT_BYTES_PER_PX
