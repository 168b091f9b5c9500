"""The coarse stage's half-resolution pass (gcpmatch/coarse_fast.py) against the reference search.

The fast search's pre-correction must land where the brute-force, full-budget search's does on
the realistic demo fixture (a fraction of a pixel at the image's corners) and within the fine
stage's reach with a large initial error (0.8 degree roll, over 200 px across track, and a 4
degree yaw); the stage must still fail on a reference without texture; the full-resolution
measurement must recover known sub-pixel offsets of real texture; the trust test is checked on
synthetic matches of known geometry.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gcpmatch.coarse import CoarseMatchError, coarse_match
from gcpmatch.coarse_fast import chance_inliers, corner_sigma_px, refine_at_full_resolution, trusted

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi_realistic"
CAPTURE_PX = 16.0  # the fine stage's search radius with the default 64 px windows


def _corner_gap_px(a, b, dem, band) -> float:
    """Largest distance, at four points 2 % inside the image corners, between where ``a`` and
    ``b`` see the ground point ``a`` localizes there."""
    from gcpmatch.coarse import scene_height_m

    n_rows, n_cols = a.image_shape
    rows = np.array([0.02, 0.02, 0.98, 0.98]) * n_rows
    cols = np.array([0.02, 0.98, 0.02, 0.98]) * n_cols
    h = scene_height_m(a, dem, band=band)
    lon, lat, _ = a.image_to_ground(rows, cols, height=h, band=band)
    arrays = a.detector_index(cols, band=band)
    gap = []
    for k in range(4):
        r, c = b.ground_to_image(lon[k:k + 1], lat[k:k + 1], np.array([h]), band=band, array=int(arrays[k]))
        gap.append(float(np.hypot(r[0] - rows[k], c[0] - cols[k])))
    return max(gap)


@pytest.fixture(scope="module")
def demo():
    from gcpmatch.extract import read_band
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.terrain.dem import Dem

    scene = open_scene(FIXTURE / "manifest.json")
    return {"img": read_band(scene, "B2"), "model": scene.model, "truth": open_model(FIXTURE / "truth_manifest.json"),
            "dem": Dem.open(FIXTURE / "reference" / "dem.tif"), "dom": MapImage.open(FIXTURE / "reference" / "dom.tif")}


def _both(inputs, model):
    fast = coarse_match(inputs["img"], model, inputs["dem"], inputs["dom"], band="B2", search="fast")
    ref = coarse_match(inputs["img"], model, inputs["dem"], inputs["dom"], band="B2", search="exhaustive")
    return fast, ref


def test_demo_fast_pass_lands_with_the_reference_pre_correction(demo):
    from sensor_models.simulate.truth import truth_error

    fast, ref = _both(demo, demo["model"])
    gap = _corner_gap_px(ref.model, fast.model, demo["dem"], "B2")
    err_fast = truth_error(demo["truth"], fast.model, dem=demo["dem"], step_px=32)["rms_px"]
    err_ref = truth_error(demo["truth"], ref.model, dem=demo["dem"], step_px=32)["rms_px"]
    print(f"demo: fast pass {fast.fast_pass}, inliers {fast.n_inliers} vs {ref.n_inliers}, gap {gap:.3f} px, "
          f"vs TRUE {err_fast:.3f} (reference {err_ref:.3f}) px rms")
    assert fast.fast_pass  # trusted on the clear demo scene
    assert gap < 0.1  # a small fraction of a pixel
    # against the TRUE model (rms over the image): reference 4.009 px, adaptive search 4.062, fast 4.069
    assert err_fast < err_ref + 0.1


def test_large_initial_error_lands_with_the_reference_pre_correction(demo):
    from sensor_models.simulate.truth import truth_error

    pv = demo["model"].parameters()
    x = pv.values.copy()
    x[pv.index(["installation.roll"])] += np.radians(0.8)
    x[pv.index(["installation.yaw"])] += np.radians(4.0)
    far = demo["model"].with_parameters(x)
    assert truth_error(demo["truth"], far, dem=demo["dem"], step_px=64)["rms_px"] > 200
    fast, ref = _both(demo, far)
    gap = _corner_gap_px(ref.model, fast.model, demo["dem"], "B2")
    err_fast = truth_error(demo["truth"], fast.model, dem=demo["dem"], step_px=32)["max_px"]
    err_ref = truth_error(demo["truth"], ref.model, dem=demo["dem"], step_px=32)["max_px"]
    print(f"far: fast pass {fast.fast_pass}, gap {gap:.3f} px, vs TRUE {err_fast:.2f} (reference {err_ref:.2f}) px")
    assert gap < 0.5
    assert err_fast < err_ref + 0.5


def test_no_texture_still_fails(demo):
    from sensor_models.maps.raster import MapImage

    dom = demo["dom"]
    flat = MapImage.from_array(np.full(dom.grid.shape, 1000, np.uint16), dom.grid.transform, dom.grid.crs)
    with pytest.raises(CoarseMatchError):
        coarse_match(demo["img"], demo["model"], demo["dem"], flat, band="B2", search="fast")


def test_unknown_search_is_refused(demo):
    with pytest.raises(ValueError, match="search"):
        coarse_match(demo["img"], demo["model"], demo["dem"], demo["dom"], band="B2", search="lsh")


@pytest.mark.parametrize("seed", range(4))
def test_full_resolution_measurement_recovers_known_offsets(demo, seed):
    """Patches of the demo's DOM moved by known sub-pixel offsets, rotated by up to 4 degrees,
    matched from positions 1.5 px off (what half-resolution keypoints give): the measured DOM
    points are within 0.1 px of the truth."""
    rng = np.random.default_rng(seed)
    dom = demo["dom"].read(0, 400, 0, 400).astype(np.float32)
    dom_u8 = cv2.normalize(dom, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    angle = np.radians(rng.uniform(-4, 4))
    lin = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])  # scene -> DOM
    t = rng.uniform(-20, 20, 2)
    to_scene = cv2.invertAffineTransform(np.c_[lin, t])  # the scene is the DOM seen through the inverse map
    scene = cv2.warpAffine(dom_u8, to_scene, (400, 400), flags=cv2.INTER_CUBIC)
    valid = cv2.warpAffine(np.ones((400, 400), np.uint8), to_scene, (400, 400), flags=cv2.INTER_NEAREST)
    valid = cv2.erode(valid, np.ones((5, 5), np.uint8)) > 0
    ps = rng.uniform(80, 320, (60, 2))
    pd_true = ps @ lin.T + t
    pd_start = pd_true + rng.uniform(-1.5, 1.5, pd_true.shape)
    got_s, got_d = refine_at_full_resolution(scene, valid, dom_u8, np.ones_like(valid), lin, ps, pd_start)
    assert len(got_s) >= 50
    err = np.hypot(*(got_d - (got_s @ lin.T + t)).T)
    print(f"seed {seed}: {len(got_s)} measured, error median {np.median(err):.3f} max {err.max():.3f} px")
    assert np.median(err) < 0.05 and err.max() < 0.1


def _synthetic(rng, n_good, n_wrong, *, box=(0, 0, 500, 400), noise_px=0.3, size=(600, 500)):
    """Matches under a known affine map: ``n_good`` in ``box`` (x0, y0, x1, y1) with noise, and
    ``n_wrong`` uniform over the DOM."""
    a = np.array([[0.98, 0.05, 40.0], [-0.04, 1.01, 25.0]])
    ps = np.c_[rng.uniform(box[0], box[2], n_good + n_wrong), rng.uniform(box[1], box[3], n_good + n_wrong)]
    pd = ps @ a[:, :2].T + a[:, 2]
    pd[:n_good] += rng.normal(0, noise_px, (n_good, 2))
    pd[n_good:] = np.c_[rng.uniform(0, size[0], n_wrong), rng.uniform(0, size[1], n_wrong)]
    return ps[:n_good], pd[:n_good], n_good + n_wrong


@pytest.mark.parametrize("seed", range(5))
def test_trust_rule_on_synthetic_matches(seed):
    rng = np.random.default_rng(seed)
    corners = np.array([[0.0, 0.0], [500.0, 0.0], [0.0, 400.0], [500.0, 400.0]])
    kw = {"dom_area_px": 600.0 * 500.0, "ransac_px": 4.0, "capture_px": 16.0}
    assert trusted(*_synthetic(rng, 150, 100), corners, **kw)  # many, spread: trusted
    assert not trusted(*_synthetic(rng, 8, 100), corners, **kw)  # too few to pin an affine map
    assert not trusted(*_synthetic(rng, 40, 100), corners, **kw)  # fewer than the adaptive first pass needs
    # as many, bunched in a 40 px corner with 1 px noise: the far corners are not pinned
    bunched = _synthetic(rng, 150, 100, box=(0, 0, 40, 40), noise_px=1.0)
    spread = _synthetic(rng, 150, 100, noise_px=1.0)
    assert corner_sigma_px(bunched[0], bunched[1], corners) > 3 * corner_sigma_px(spread[0], spread[1], corners)
    assert not trusted(*bunched, corners, **kw)
    # a set no larger than wrong matches give by chance over a small DOM is not trusted
    assert not trusted(*_synthetic(rng, 14, 4000), corners, **{**kw, "dom_area_px": 200.0 * 200.0})
    assert chance_inliers(4000, 200.0 * 200.0, 4.0) > 14


def test_match_options_name_the_search():
    from gcpmatch.options import COARSE_SEARCHES, MatchOptions
    from sensor_models.errors import InputError

    assert MatchOptions().coarse_search == COARSE_SEARCHES[0] == "adaptive"
    assert MatchOptions(coarse_search="fast").validate().coarse_search == "fast"
    with pytest.raises(InputError, match="coarse search"):
        MatchOptions(coarse_search="lsh").validate()
