"""Tests of gcpmatch.coarse_reduce: the banded reduction equals the whole-scene one to the bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gcpmatch import coarse_reduce
from gcpmatch.coarse import _reduce_scene, reduction_factor
from gcpmatch.coarse_reduce import reduce_scene


def _whole(scene, f):
    """The reduction of the whole scene at once (OpenCV's area resampling of the masked scene)."""
    n_rows, n_cols = scene.shape
    valid = np.isfinite(scene) & (scene > 0)
    size = (n_cols // f, n_rows // f)
    small = cv2.resize(np.where(valid, scene, 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    return small, cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.99


def _scene(shape, dtype=np.float32, seed=0):
    rng = np.random.default_rng(seed)
    scene = rng.gamma(2.0, 400.0, size=shape)
    if np.issubdtype(dtype, np.floating):
        scene[rng.random(shape) < 0.01] = np.nan
        scene[rng.random(shape) < 0.005] = np.inf
        scene[rng.random(shape) < 0.01] = -3.0
        scene[:17, :] = 0.0  # a no-data margin
    return scene.astype(dtype)


@pytest.mark.parametrize("shape, f", [((120, 90), 1), ((120, 90), 2), ((120, 90), 3), ((125, 95), 5),
                                      ((121, 90), 2), ((120, 91), 3)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint16])
def test_banded_reduction_equals_the_whole_scene(monkeypatch, shape, f, dtype):
    monkeypatch.setattr(coarse_reduce, "BAND_PX", 700)  # bands of a few lines: many boundaries
    scene = _scene(shape, dtype)
    want_small, want_valid = _whole(scene, f)
    for threads in (1, 3):
        small, valid = reduce_scene(scene, f, threads=threads)
        assert small.dtype == np.float32 and valid.dtype == bool
        assert np.array_equal(small, want_small) and np.array_equal(valid, want_valid)
    if np.issubdtype(dtype, np.floating):
        assert 0 < want_valid.mean() < 1  # both kinds of blocks are there


def test_reduce_scene_uses_the_factor_of_reduction_factor():
    scene = _scene((600, 2000))
    small, valid, f = _reduce_scene(scene, 400, threads=2)
    assert f == reduction_factor(600, 2000, 400) == 2 and small.shape == (300, 1000)
    want_small, want_valid = _whole(scene, f)
    assert np.array_equal(small, want_small) and np.array_equal(valid, want_valid)


@pytest.mark.parametrize("shape, f", [((120, 90), 3), ((121, 97), 4)])
def test_all_valid_lines_go_to_opencv_as_they_are(monkeypatch, shape, f):
    monkeypatch.setattr(coarse_reduce, "BAND_PX", 500)
    scene = _scene(shape, seed=4)
    scene[~(np.isfinite(scene) & (scene > 0))] = 7.0  # every pixel valid
    scene.setflags(write=False)  # read-only input (a memory-mapped band) is fine
    want_small, want_valid = _whole(scene, f)
    small, valid = reduce_scene(scene, f, threads=2)
    assert np.array_equal(small, want_small) and np.array_equal(valid, want_valid) and valid.all()
    partly = scene.copy()
    partly[60, 5] = 0.0  # one invalid pixel: that band (or the scene) takes the masked path
    want_small, want_valid = _whole(partly, f)
    small, valid = reduce_scene(partly, f, threads=2)
    assert np.array_equal(small, want_small) and np.array_equal(valid, want_valid) and not valid.all()
