"""The coarse stage on the torch backend: exact descriptor matching, the CPU path's pre-correction."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from gcpmatch.coarse import coarse_match
from gcpmatch.extract import read_band
from gcpmatch.reference import scene_gsd_m
from sensor_models.maps.raster import MapImage
from sensor_models.readers import open_model, open_scene
from sensor_models.simulate.config import SimConfig
from sensor_models.simulate.pushbroom_sim import simulate_pushbroom
from sensor_models.terrain.dem import Dem

torch = pytest.importorskip("torch", reason="torch (optional 'gpu' extra) is not installed")

from gcpmatch._features_torch import ratio_test_pairs  # noqa: E402  (needs torch)

#: the fine stage's capture radius with the default 64 px windows: a quarter of the window, px
CAPTURE_RADIUS_PX = 16.0


def _textured(rng, shape, sigma_px):
    img = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), sigma_px)
    img = (img - img.min()) / (img.max() - img.min())
    return (255 * img).astype(np.uint8)


def _brute_force_ratio(des_a, des_b, ratio=0.8):
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(des_a, des_b, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    return np.array([m.queryIdx for m in good]), np.array([m.trainIdx for m in good])


@pytest.mark.parametrize("kornia_installed", [True, False])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_device_matches_are_the_brute_force_matchers(seed, kornia_installed, monkeypatch):
    """Random textures, a rotated and rescaled copy of each: the torch matcher keeps exactly the
    ratio-test matches of OpenCV's brute-force matcher (same query, same train index), through
    kornia's ratio test and through the torch-only one used where kornia is not installed."""
    import gcpmatch._features_torch as features

    if kornia_installed:
        pytest.importorskip("kornia", reason="kornia (optional 'gpu' extra) is not installed")
    else:
        monkeypatch.setattr(features, "_kornia_match_snn", lambda: features._match_snn_torch)
    rng = np.random.default_rng(seed)
    a = _textured(rng, (360, 420), float(rng.uniform(1.0, 3.0)))
    angle, scale = float(rng.uniform(-20, 20)), float(rng.uniform(0.8, 1.2))
    warp = cv2.getRotationMatrix2D((210.0, 180.0), angle, scale)
    b = cv2.warpAffine(a, warp, (420, 360), borderMode=cv2.BORDER_REFLECT)
    sift = cv2.SIFT_create(nfeatures=1500, contrastThreshold=0.01)
    _, des_a = sift.detectAndCompute(a, None)
    _, des_b = sift.detectAndCompute(b, None)
    query, train = ratio_test_pairs(des_a, des_b, device="cpu")
    bf_query, bf_train = _brute_force_ratio(des_a, des_b)
    assert len(query) > 100
    np.testing.assert_array_equal(query, bf_query)
    np.testing.assert_array_equal(train, bf_train)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("coarse_torch")
    cfg = SimConfig()
    cam = replace(cfg.camera, detectors_per_ccd=160, bands=("B2",), reference_band="B2", band_offsets_px=(0.0,))
    rad = replace(cfg.radiometry, band_gain=(1.0,), band_offset_dn=(40.0,), band_gamma=(0.9,))
    simulate_pushbroom(d, config=replace(cfg, scene=replace(cfg.scene, n_rows=384), camera=cam,
                                         radiometry=rad).validate())
    return (open_model(d / "manifest.json"), Dem.open(d / "reference" / "dem.tif"),
            MapImage.open(d / "reference" / "dom.tif"), read_band(open_scene(d / "manifest.json"), "B2"))


def corner_difference_px(model_a, model_b, dem, band="B2") -> np.ndarray:
    """Ground distance, in scene pixels, between where two models put the scene's corners and
    mid-edges (localized at the scene's median DEM height)."""
    from gcpmatch.coarse import scene_height_m
    from gcpmatch.precorrect import ground_distance_m

    n_rows, n_cols = model_a.image_shape
    rows = np.array([0.5, 0.5, n_rows - 0.5, n_rows - 0.5, 0.5 * n_rows, 0.5 * n_rows, 0.5, n_rows - 0.5])
    cols = np.array([0.5, n_cols - 0.5, 0.5, n_cols - 0.5, 0.5, n_cols - 0.5, 0.5 * n_cols, 0.5 * n_cols])
    h = scene_height_m(model_a, dem, band=band)
    lon, lat, _ = model_a.image_to_ground(rows, cols, height=h, band=band)
    dist_m = ground_distance_m(model_b, rows, cols, lon, lat, np.full(rows.size, h), band=band)
    return dist_m / scene_gsd_m(model_a, band=band, height_m=h)


def test_torch_coarse_stage_gives_the_cpu_pre_correction(scene):
    """Same SIFT features and RANSAC, exact instead of FLANN neighbours: the two pre-corrected
    models put the scene's corners within a tenth of the fine stage's capture radius of each
    other (the model started 260 px off)."""
    lab, dem, dom, img = scene
    cpu = coarse_match(img, lab, dem, dom, band="B2")
    tor = coarse_match(img, lab, dem, dom, band="B2", backend="torch", device="cpu")
    diff = corner_difference_px(cpu.model, tor.model, dem)
    start = corner_difference_px(lab, cpu.model, dem)
    print(f"coarse torch vs cpu: corners {np.round(diff, 3)} px (start {start.max():.0f} px); "
          f"inliers {tor.n_inliers} vs {cpu.n_inliers}, ratio matches {tor.n_matches} vs {cpu.n_matches}")
    assert start.min() > 100
    assert diff.max() < 0.1 * CAPTURE_RADIUS_PX
    assert abs(tor.n_inliers - cpu.n_inliers) < 0.2 * cpu.n_inliers
