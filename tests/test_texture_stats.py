"""Texture statistics and the realistic profile's contrast calibration on real crops (issue 13 item 1)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from sensor_models.simulate.procedural import generate_reference
from sensor_models.simulate.profiles import get_profile
from sensor_models.simulate.texture_stats import block_average, rms_contrast_median, scale_contrast, spectral_slope


def _fractal(n: int, beta: float, seed: int = 0) -> np.ndarray:
    """Gaussian field with power spectrum k^-beta (plus a mean, so that it is positive)."""
    rng = np.random.default_rng(seed)
    k = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.fftfreq(n)[None, :])
    k[0, 0] = 1.0
    f = np.fft.ifft2(np.fft.fft2(rng.normal(size=(n, n))) * k ** (-beta / 2.0)).real
    return 10.0 + f / f.std()


@pytest.mark.parametrize("beta", [1.5, 2.0, 2.5])
def test_spectral_slope_recovers_a_known_spectrum(beta):
    est = np.mean([spectral_slope(_fractal(256, beta, seed=s)) for s in range(4)])
    assert beta - 0.15 < est < beta + 0.15


def test_rms_contrast_of_a_known_field():
    rng = np.random.default_rng(1)
    img = 100.0 + 20.0 * rng.normal(size=(256, 256))  # std/mean = 0.2 in every block
    assert 0.19 < rms_contrast_median(img) < 0.21
    valid = np.ones(img.shape, bool)
    valid[:32, :32] = False
    assert 0.19 < rms_contrast_median(img, valid) < 0.21
    d, v = block_average(img, valid, 2)
    assert d.shape == (128, 128) and not v[:16, :16].any() and v[16:, 16:].all()


def test_procedural_texture_is_brought_to_the_real_contrast():
    """The procedural texture is twice as contrasted as the Sentinel-2 crop; the realistic
    profile's source is scaled to it (within 3 %), the spectrum's shape untouched."""
    data = generate_reference(5.5, 44.5, 9000.0, 9000.0, seed=3, dom_resolution_m=15.0, dem_resolution_m=30.0,
                              relief_m=600.0, mean_height_m=500.0)
    target = float(get_profile("realistic").value("procedural_rms_contrast"))
    out, gain, (before, after) = scale_contrast(data.dom.astype(np.float32), 15.0, target)
    assert before > 1.5 * target
    assert 0.97 * target < after < 1.03 * target and 0.2 < gain < 0.8
    src = data.dom.astype(np.float64)
    assert np.corrcoef(out.ravel(), src.ravel())[0, 1] > 0.99  # an affine change where not clipped
    assert get_profile("ideal").value("procedural_rms_contrast") == 0.0


def test_the_cited_sentinel2_contrast(shared_data):
    """The profile's 0.195 is what the real crop measures at 30 m (bench/bench_texture_stats.py)."""
    with rasterio.open(shared_data / "real_textures" / "sentinel2" / "s2_B04.jp2") as ds:
        img = ds.read(1).astype(np.float64)
    d, v = block_average(img, img > 0, 3)
    c = rms_contrast_median(d, v)
    assert 0.185 < c < 0.205
    assert float(get_profile("realistic").value("procedural_rms_contrast")) == pytest.approx(c, abs=0.01)
