"""The coarse stage's FLANN matcher and adaptive feature budget against brute force and the full budget.

The pre-correction of the default stage must land within the fine stage's capture radius
(``window_px / 4`` = 16 px) of the brute-force, full-budget one, on the realistic demo fixture as
it is and with a large initial error (0.8 degree roll, over 200 px across track, and a 4 degree
yaw); the first pass must be refused where its matches do not reach every detector array (60 %
cloud) and the stage must still fail on a reference without texture. The trust test is checked
on synthetic matches of known geometry.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gcpmatch.coarse import CoarseMatchError, coarse_match, spread_over_arrays
from gcpmatch.coarse_features import FeatureMatches, chance_inliers, corner_sigma_px, trusted

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi_realistic"
CAPTURE_PX = 16.0  # the fine stage's search radius with the default 64 px windows
BRUTE = {"matcher": "brute", "adaptive": False}


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
    new = coarse_match(inputs["img"], model, inputs["dem"], inputs["dom"], band="B2")
    old = coarse_match(inputs["img"], model, inputs["dem"], inputs["dom"], band="B2", **BRUTE)
    return new, old


def test_demo_first_pass_lands_with_the_brute_force_pre_correction(demo):
    new, old = _both(demo, demo["model"])
    gap = _corner_gap_px(old.model, new.model, demo["dem"], "B2")
    print(f"demo: passes {new.feature_passes}, inliers {new.n_inliers} vs {old.n_inliers}, gap {gap:.2f} px")
    assert new.feature_passes == 1  # the first pass is trusted on the clear demo scene
    assert gap < CAPTURE_PX / 4


def test_large_initial_error_lands_with_the_brute_force_pre_correction(demo):
    from sensor_models.simulate.truth import truth_error

    pv = demo["model"].parameters()
    x = pv.values.copy()
    x[pv.index(["installation.roll"])] += np.radians(0.8)
    x[pv.index(["installation.yaw"])] += np.radians(4.0)
    far = demo["model"].with_parameters(x)
    assert truth_error(demo["truth"], far, dem=demo["dem"], step_px=64)["rms_px"] > 200
    new, old = _both(demo, far)
    gap = _corner_gap_px(old.model, new.model, demo["dem"], "B2")
    err_new = truth_error(demo["truth"], new.model, dem=demo["dem"], step_px=32)["max_px"]
    err_old = truth_error(demo["truth"], old.model, dem=demo["dem"], step_px=32)["max_px"]
    print(f"far: passes {new.feature_passes}, gap {gap:.2f} px, vs TRUE {err_new:.2f} (brute {err_old:.2f}) px")
    assert gap < CAPTURE_PX / 2
    assert err_new < err_old + CAPTURE_PX / 4


@pytest.mark.slow  # a simulated scene: about 20 s on a loaded 2-core machine
def test_cloudy_scene_refuses_the_first_pass_and_matches_brute_force(tmp_path):
    from gcpmatch.extract import read_band
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_model, open_scene
    from sensor_models.simulate.config import SimConfig
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom
    from sensor_models.simulate.truth import truth_error
    from sensor_models.terrain.dem import Dem

    cfg = SimConfig()
    cam = replace(cfg.camera, detectors_per_ccd=160, bands=("B2",), reference_band="B2", band_offsets_px=(0.0,))
    rad = replace(cfg.radiometry, band_gain=(1.0,), band_offset_dn=(40.0,), band_gamma=(0.9,))
    cfg = replace(cfg, scene=replace(cfg.scene, n_rows=384), camera=cam, radiometry=rad,
                  clouds=replace(cfg.clouds, cover=0.6)).validate()
    simulate_pushbroom(tmp_path, config=cfg)
    truth = open_model(tmp_path / "truth_manifest.json")
    inputs = {"img": read_band(open_scene(tmp_path / "manifest.json"), "B2"),
              "dem": Dem.open(tmp_path / "reference" / "dem.tif"),
              "dom": MapImage.open(tmp_path / "reference" / "dom.tif")}
    new, old = _both(inputs, open_model(tmp_path / "manifest.json"))
    gap = _corner_gap_px(old.model, new.model, inputs["dem"], "B2")
    err_new = truth_error(truth, new.model, dem=inputs["dem"], step_px=32)["max_px"]
    print(f"clouds: passes {new.feature_passes}, gap {gap:.2f} px, vs TRUE {err_new:.2f} px")
    assert new.feature_passes == 2  # the first pass misses cloudy CCDs: the full budget runs
    assert gap < CAPTURE_PX / 4 and err_new < 2.0


def test_first_pass_must_reach_every_detector_array_with_matches(demo):
    model = demo["model"]
    arrays = model.detector_arrays("B2")
    rng = np.random.default_rng(1)

    def cols(i, n, span=0.9):
        look = arrays[i]
        return look.first_col + 0.5 + rng.uniform(0, span * look.n_detectors, n)

    every = np.concatenate([cols(i, 40) for i in range(len(arrays))])
    assert spread_over_arrays(model, "B2", every, every)
    missing_last = np.concatenate([cols(i, 40) for i in range(len(arrays) - 1)])
    assert not spread_over_arrays(model, "B2", missing_last, every)  # matches there, none kept
    assert spread_over_arrays(model, "B2", missing_last, missing_last)  # no matches there: nothing to fit
    bunched = np.concatenate([missing_last, cols(len(arrays) - 1, 40, span=0.3)])
    assert not spread_over_arrays(model, "B2", bunched, every)  # kept, but over 30 % of the array only


def test_no_texture_still_fails(demo):
    from sensor_models.maps.raster import MapImage

    dom = demo["dom"]
    flat = MapImage.from_array(np.full(dom.grid.shape, 1000, np.uint16), dom.grid.transform, dom.grid.crs)
    with pytest.raises(CoarseMatchError):
        coarse_match(demo["img"], demo["model"], demo["dem"], flat, band="B2")


def test_unknown_matcher_is_refused(demo):
    with pytest.raises(ValueError, match="matcher"):
        coarse_match(demo["img"], demo["model"], demo["dem"], demo["dom"], band="B2", matcher="lsh")


def _synthetic(rng, n_good, n_wrong, *, box=(0, 0, 500, 400), noise_px=0.3, size=(600, 500)):
    """Matches under a known affine map: ``n_good`` in ``box`` (x0, y0, x1, y1) with noise, and
    ``n_wrong`` uniform over the DOM, as RANSAC would flag them."""
    a = np.array([[0.98, 0.05, 40.0], [-0.04, 1.01, 25.0]])
    ps = np.c_[rng.uniform(box[0], box[2], n_good + n_wrong), rng.uniform(box[1], box[3], n_good + n_wrong)]
    pd = ps @ a[:, :2].T + a[:, 2]
    pd[:n_good] += rng.normal(0, noise_px, (n_good, 2))
    pd[n_good:] = np.c_[rng.uniform(0, size[0], n_wrong), rng.uniform(0, size[1], n_wrong)]
    inlier = np.zeros(n_good + n_wrong, bool)
    inlier[:n_good] = True
    return FeatureMatches(ps.astype(np.float32), pd.astype(np.float32), 1000, 1000, inlier, a)


@pytest.mark.parametrize("seed", range(5))
def test_trust_rule_on_synthetic_matches(seed):
    rng = np.random.default_rng(seed)
    corners = np.array([[0.0, 0.0], [500.0, 0.0], [0.0, 400.0], [500.0, 400.0]])
    kw = {"dom_area_px": 600.0 * 500.0, "ransac_px": 4.0, "capture_px": 16.0}
    assert trusted(_synthetic(rng, 150, 100), corners, **kw)  # many, spread: trusted
    assert not trusted(_synthetic(rng, 8, 100), corners, **kw)  # too few to pin an affine map
    # as many, bunched in a 40 px corner with 1 px noise: the far corners are not pinned
    bunched = _synthetic(rng, 150, 100, box=(0, 0, 40, 40), noise_px=1.0)
    assert corner_sigma_px(bunched.ps[:150], bunched.pd[:150], corners) > 3 * corner_sigma_px(
        *(lambda f: (f.ps[:150], f.pd[:150]))(_synthetic(rng, 150, 100, noise_px=1.0)), corners)
    assert not trusted(bunched, corners, **kw)
    # a set no larger than wrong matches give by chance over a small DOM is not trusted
    assert not trusted(_synthetic(rng, 14, 4000), corners, **{**kw, "dom_area_px": 200.0 * 200.0})
    assert chance_inliers(4000, 200.0 * 200.0, 4.0) > 14
