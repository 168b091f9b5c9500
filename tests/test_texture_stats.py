"""Texture statistics and the realistic profile's texture calibration on real crops (issue 13 item 1)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from sensor_models.simulate.procedural import generate_reference
from sensor_models.simulate.profiles import get_profile
import sys
from dataclasses import replace
from pathlib import Path

from sensor_models.errors import InputError
from sensor_models.simulate.profiles import Sourced
from sensor_models.simulate.texture_poor import attenuate_texture, texture_poor_cover, texture_poor_mask
from sensor_models.simulate.texture_stats import (block_average, block_gradient_energy, matcher_gate_fraction,
                                                  rms_contrast_median, scale_contrast, spectral_slope,
                                                  textured_fraction, untextured_gradient_ratio)

ROOT = Path(__file__).resolve().parents[1]
#: textured-block share of the real crops at 30 m (`python bench/bench_texture_stats.py`: Landsat-8 red 0.430,
#: Landsat-8 pan 0.643, Sentinel-2 red 0.657)
REAL_RANGE = (0.43, 0.66)


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


# ------------------------------------------------------------------ textured blocks and texture-poor land
def test_textured_fraction_of_known_fields():
    """A flat field with 0.5 % noise has no textured block, one with 5 % noise (and a fractal) only textured ones."""
    rng = np.random.default_rng(2)
    flat = 1000.0 * (1.0 + 0.005 * rng.normal(size=(256, 256)))
    noisy = 1000.0 * (1.0 + 0.05 * rng.normal(size=(256, 256)))
    assert textured_fraction(flat) == 0.0 and textured_fraction(noisy) == 1.0
    half = np.vstack([flat[:128], noisy[128:]])
    assert textured_fraction(half) == pytest.approx(0.5)
    # 0.5 % noise: |grad|^2 / mean^2 = 2 x 0.005^2 / 2 (central differences) per axis pair
    assert 1.5e-5 < np.median(block_gradient_energy(flat)) < 3.5e-5
    assert 0.04 < untextured_gradient_ratio(half) < 0.15  # 0.005 / 0.05 = 0.1
    assert np.isnan(untextured_gradient_ratio(flat))
    # the matcher's gate is relative: it keeps every block of a wholly flat field, but rejects a flat
    # quarter beside textured ground
    quarter = np.vstack([flat[:64], noisy[64:]])
    assert matcher_gate_fraction(flat) == 1.0 and matcher_gate_fraction(quarter) == pytest.approx(0.75)


def test_texture_poor_mask_covers_its_share_of_the_land_with_smooth_patches():
    shape, water = (600, 800), np.zeros((600, 800), bool)
    water[:, :200] = True
    m = texture_poor_mask(shape, 15.0, 0.5, seed=[7, 40], exclude=water)
    assert not m[water].any()
    assert 0.49 < m[~water].mean() < 0.51
    assert np.array_equal(m, texture_poor_mask(shape, 15.0, 0.5, seed=[7, 40], exclude=water))  # seeded
    assert not np.array_equal(m, texture_poor_mask(shape, 15.0, 0.5, seed=[8, 40], exclude=water))
    # smooth-edged km-scale patches, not speckle: few boundary pixels for the area
    edges = (m[1:, :] != m[:-1, :]).sum() + (m[:, 1:] != m[:, :-1]).sum()
    assert edges < 0.03 * m.sum()
    assert not texture_poor_mask(shape, 15.0, 0.0, seed=1).any()
    with pytest.raises(InputError, match="fraction"):
        texture_poor_mask(shape, 15.0, 1.0, seed=1)


def test_attenuation_keeps_tone_a_little_texture_and_sharp_edges():
    rng = np.random.default_rng(3)
    img = (1000.0 + 100.0 * rng.normal(size=(400, 400))).astype(np.float32)
    img[:, 200:] += 500.0  # a step: the patch's right neighbour is brighter
    mask = np.zeros(img.shape, bool)
    mask[:, 60:200] = True  # the patch ends at the step
    out = attenuate_texture(img, mask, 0.17, res_m=15.0)
    assert np.array_equal(out[~mask], img[~mask])  # outside untouched
    inside = out[:, 100:190] - img[:, 100:190].mean()
    assert 0.15 < inside.std() / img[:, 100:190].std() < 0.19  # the texture scaled by 0.17
    assert abs(out[:, 100:190].mean() - img[:, 100:190].mean()) < 2.0  # tone kept
    # the brighter neighbour does not leak into the patch: its last column keeps its tone
    assert abs(out[:, 199].mean() - 1000.0) < 10.0 and out[:, 200].mean() > 1450.0
    assert np.array_equal(attenuate_texture(img, mask, 1.0, res_m=15.0), img)
    with pytest.raises(InputError, match="attenuation"):
        attenuate_texture(img, mask, 1.5, res_m=15.0)


def _realistic_source(profile):
    sys.path.insert(0, str(ROOT / "fixtures"))
    from make_hy1c_fixture import config

    from sensor_models.simulate.realistic_sim import source_radiance

    radiance, transform, _ = source_radiance(config(), profile)
    img, ok = block_average(radiance.astype(np.float64), np.isfinite(radiance), 2)  # 15 m -> 30 m
    return img, ok


def test_realistic_source_has_the_real_share_of_textured_blocks():
    """The realistic fixture's procedural source, at 30 m: inside the crops' textured share with its
    texture-poor patches, above it without them (as the ideal texture); the spectrum's slope kept."""
    realistic = get_profile("realistic")
    img, ok = _realistic_source(realistic)
    with_patches = textured_fraction(img, ok)
    assert REAL_RANGE[0] < with_patches < REAL_RANGE[1], with_patches  # 0.556 measured
    assert 2.0 < spectral_slope(img[200:456, 300:556]) < 2.4
    assert 0.05 < rms_contrast_median(img, ok) < 0.2  # 0.119 measured, crops 0.067-0.195
    without = replace(realistic, texture_poor_fraction=Sourced(0.0, "test"))
    img0, ok0 = _realistic_source(without)
    assert textured_fraction(img0, ok0) > REAL_RANGE[1] + 0.1  # 0.875 measured
    assert rms_contrast_median(img0, ok0) == pytest.approx(0.195, abs=0.005)  # scaled before the patches


def test_ideal_texture_is_unchanged():
    """The ideal profile draws no patch, and the ideal fixture's DOM keeps its textured share (0.881)."""
    ideal = get_profile("ideal")
    assert ideal.value("texture_poor_fraction") == 0.0 and ideal.value("texture_poor_attenuation") == 1.0
    with rasterio.open(ROOT / "fixtures" / "hy1c_czi" / "reference" / "dom.tif") as ds:
        dom = ds.read(1).astype(np.float64)
    img, ok = block_average(dom, dom > 0, 2)
    assert 0.87 < textured_fraction(img, ok) < 0.89


def test_texture_poor_cover_is_what_the_profile_sets():
    realistic = get_profile("realistic")
    fraction, attenuation = realistic.value("texture_poor_fraction"), realistic.value("texture_poor_attenuation")
    rng = np.random.default_rng(4)
    img = (1000.0 + 100.0 * rng.normal(size=(300, 300))).astype(np.float32)
    out, mask = texture_poor_cover(img, 15.0, fraction, attenuation, seed=[1, 40])
    assert 0.45 < mask.mean() < 0.55
    assert out[mask].std() < 0.3 * img[mask].std() and np.array_equal(out[~mask], img[~mask])


def test_the_cited_sentinel2_attenuation(shared_data):
    """The profile's 0.17: the untextured blocks of the Sentinel-2 crop keep 0.17 of the textured ones' gradient."""
    with rasterio.open(shared_data / "real_textures" / "sentinel2" / "s2_B04.jp2") as ds:
        img = ds.read(1).astype(np.float64)
    d, v = block_average(img, img > 0, 3)
    ratio = untextured_gradient_ratio(d, v)
    assert 0.15 < ratio < 0.20
    assert REAL_RANGE[0] < textured_fraction(d, v) < REAL_RANGE[1] + 0.005
    assert float(get_profile("realistic").value("texture_poor_attenuation")) == pytest.approx(ratio, abs=0.01)
