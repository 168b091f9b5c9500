"""The cloud detector's passes with few full-size temporaries give the numbers of the direct
formulas: the local cross-correlation written out, the land pixels listed whole and then
subsampled, the full-resolution tests on whole images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import scipy.ndimage as ndi

from gcpmatch import clouds
from gcpmatch.clouds import LAND_SAMPLES, _land_decimated, _local_ncc, detect_clouds


def _direct_ncc(a, b, size):
    def box(x):
        return cv2.boxFilter(x, -1, (size, size), normalize=True, borderType=cv2.BORDER_REFLECT)

    ma, mb = box(a), box(b)
    cov = box(a * b) - ma * mb
    va = np.maximum(box(a * a) - ma * ma, 0.0)
    vb = np.maximum(box(b * b) - mb * mb, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return cov / np.sqrt(va * vb + 1e-12)


def _direct_land(scene, reference, ok, f, ncc_land, box_px):
    n_rows, n_cols = (scene.shape[0] // f) * f, (scene.shape[1] // f) * f
    crop = ok[:n_rows, :n_cols]
    full = crop[::f, ::f].copy()
    for a in range(f):
        for b in range(f):
            full &= crop[a::f, b::f]
    means = [np.where(full, cv2.resize(im[:n_rows, :n_cols], (n_cols // f, n_rows // f), interpolation=cv2.INTER_AREA),
                      np.float32(0.0)) for im in (scene, reference)]
    i, j = np.nonzero(full & (_direct_ncc(means[0], means[1], box_px) > ncc_land))
    flat = (i * f + f // 2) * scene.shape[1] + (j * f + f // 2)
    flat = flat[ok.ravel()[flat]]
    return flat[:: max(1, flat.size // LAND_SAMPLES)], flat.size, i.size * f * f


def _cloudy_pair(seed):
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(250, 700)), int(rng.integers(250, 700)))
    ref = (ndi.gaussian_filter(rng.normal(size=shape), 3) * 50 + 200).astype(np.float32)
    scene = (1.1 * ref + 5 + rng.normal(0, 2, shape)).astype(np.float32)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    cloud = (yy - shape[0] * 0.4) ** 2 + (xx - shape[1] * 0.6) ** 2 < (min(shape) * rng.uniform(0.1, 0.45)) ** 2
    scene[cloud] += (150 + rng.normal(0, 20, cloud.sum())).astype(np.float32)
    ref[rng.random(shape) < 0.02] = np.nan
    scene[:int(rng.integers(1, 30))] = 0.0
    return scene, ref


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("f", [2, 3])
def test_land_and_correlation_equal_the_direct_formulas(seed, f):
    scene, ref = _cloudy_pair(seed)
    a, b = np.nan_to_num(scene), np.nan_to_num(ref)
    assert np.array_equal(_local_ncc(a, b, 15), _direct_ncc(a, b, 15), equal_nan=True)
    ok = np.isfinite(ref) & (scene > 0) & (scene < np.inf)
    got, want = _land_decimated(scene, ref, ok, f, 0.5, 7), _direct_land(scene, ref, ok, f, 0.5, 7)
    assert np.array_equal(got[0], want[0]) and got[1:] == want[1:] and want[1] > LAND_SAMPLES // 10


@pytest.mark.parametrize("seed", range(4))
def test_detector_by_bands_of_lines_equals_one_band(monkeypatch, seed):
    scene, ref = _cloudy_pair(seed)
    whole_mask, whole_fraction = detect_clouds(scene, ref)
    monkeypatch.setattr(clouds, "BAND_PX", 3000)  # a few lines a band
    mask, fraction = detect_clouds(scene, ref)
    assert np.array_equal(mask, whole_mask) and fraction == whole_fraction and 0.02 < fraction < 0.8
