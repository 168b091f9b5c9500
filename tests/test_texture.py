"""The absolute texture measure (gcpmatch.texture) and the options that use it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from gcpmatch.options import MatchOptions
from gcpmatch.phase import phase_correlate
from gcpmatch.texture import band_noise_dn, cramer_rao_sigma_px, gradient_snr, texture_sigma_px, weak_texture
from gcpmatch.uncertainty import window_sigma
from sensor_models.errors import InputError


def _smooth_scene(shape=(256, 256), seed=0):
    """A smooth image (plane plus broad undulations), DN: almost nothing for the noise mask to see."""
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    return 1000.0 + 0.5 * r - 0.3 * c + gaussian_filter(rng.normal(size=shape), 12.0) * 2000.0


@pytest.mark.parametrize("sigma_dn", [2.0, 10.0, 40.0])
def test_band_noise_recovers_white_noise_on_a_smooth_scene(sigma_dn):
    rng = np.random.default_rng(1)
    img = _smooth_scene() + rng.normal(scale=sigma_dn, size=(256, 256))
    est = band_noise_dn(img)
    assert 0.93 * sigma_dn < est < 1.07 * sigma_dn


def test_band_noise_skips_non_finite_pixels_and_is_nan_without_valid_ones():
    rng = np.random.default_rng(2)
    img = _smooth_scene() + rng.normal(scale=5.0, size=(256, 256))
    img[:40] = np.nan
    assert 4.6 < band_noise_dn(img) < 5.4
    assert np.isnan(band_noise_dn(np.full((8, 8), np.nan)))


def test_gradient_snr_of_pure_noise_is_sqrt2_and_separates_the_axes():
    rng = np.random.default_rng(3)
    noise = rng.normal(scale=4.0, size=(64, 64, 64))
    snr = gradient_snr(noise, 4.0)
    # a forward difference of white noise has variance 2 sigma^2
    assert np.all(np.abs(np.median(snr, axis=0) - np.sqrt(2.0)) < 0.05)
    stripes = np.broadcast_to(np.sin(np.arange(64) / 2.0)[None, :] * 100.0, (1, 64, 64))  # varies along columns
    s = gradient_snr(stripes, 1.0)[0]
    assert s[0] == pytest.approx(0.0, abs=1e-9) and s[1] > 30.0
    assert np.isnan(gradient_snr(noise[:2], 0.0)).all()
    assert gradient_snr(np.zeros((0, 8, 8)), 1.0).shape == (0, 2)


def test_cramer_rao_bounds_the_phase_correlation_error_from_below():
    """Noisy copies of a texture, shifted by a known sub-pixel amount: the measured rms error of
    the shift lies above the bound of the windows' gradient snr, and within a few times it (the
    whitened phase correlation is not an efficient estimator: 3.5-4.5 times the bound here)."""
    rng = np.random.default_rng(4)
    n, w, sigma_dn, shift = 64, 64, 1.0, (0.3, -0.2)
    base = np.stack([gaussian_filter(rng.normal(size=(w, w)), 1.5) * 60.0 for _ in range(n)])
    kr, kc = np.fft.fftfreq(w)[:, None], np.fft.fftfreq(w)[None, :]
    moved = np.fft.ifft2(np.fft.fft2(base) * np.exp(-2j * np.pi * (kr * shift[0] + kc * shift[1]))).real
    ref = base + rng.normal(scale=sigma_dn, size=base.shape)
    mov = moved + rng.normal(scale=sigma_dn, size=base.shape)
    pm = phase_correlate(ref, mov, max_shift_px=w / 4)
    err = pm.shift_px - np.array(shift)
    rms = np.sqrt(np.mean(err**2, axis=0))
    bound = np.sqrt(np.mean(cramer_rao_sigma_px(gradient_snr(base, sigma_dn), w) ** 2, axis=0))
    assert np.all(rms > bound)
    assert np.all(rms < 6.0 * bound)


def test_weak_texture_and_texture_sigma():
    snr_r, snr_c = np.array([1.0, 5.0, 5.0, np.nan]), np.array([5.0, 5.0, 2.0, 3.0])
    assert weak_texture(snr_r, snr_c, 3.0).tolist() == [True, False, True, False]
    assert not weak_texture(snr_r, snr_c, 0.0).any()
    t = texture_sigma_px(snr_r, snr_c, 0.2)
    assert t[1] == pytest.approx(0.2 / 5.0)
    assert t[0] == pytest.approx(0.2 * np.sqrt((1.0 + 1 / 25) / 2))
    assert t[3] == 0.0


def test_window_sigma_adds_the_texture_term_only_when_asked():
    q = {"score": np.array([0.9, 0.9]), "gradient_snr_row": np.array([2.0, 20.0]),
         "gradient_snr_col": np.array([2.0, 20.0])}
    res = np.zeros((2, 2))
    base = window_sigma(np.nan, res, q, model="window", reference_sigma_px=0.02)
    assert base[0] == pytest.approx(base[1])
    more = window_sigma(np.nan, res, q, model="window", reference_sigma_px=0.02, texture_sigma_px=0.3)
    assert more[0] == pytest.approx(np.hypot(base[0], 0.15))
    assert more[1] == pytest.approx(np.hypot(base[1], 0.015))  # strong texture: little added
    ccd = window_sigma(0.05, res, q, model="ccd", texture_sigma_px=0.3)
    assert np.allclose(ccd, 0.05)


@pytest.mark.parametrize("field", ["min_gradient_snr", "texture_sigma_px", "mismatch_sigma_scale"])
@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf"), "1", True])
def test_options_reject_bad_texture_values(field, value):
    with pytest.raises(InputError) as info:
        MatchOptions(**{field: value}).validate()
    assert info.value.field == field
    assert MatchOptions(**{field: 2.5}).validate()


def test_mismatch_bound_follows_the_pair_noise_and_refuses_large_shifts():
    """With white noise in both windows the mismatch-noise bound lands on the bound of the true
    noise (bilinear resampling of the reference adds a little); NaN beyond the border."""
    from gcpmatch.texture import mismatch_cr_sigma_px

    rng = np.random.default_rng(5)
    n, w, shift = 32, 64, (0.3, -0.2)
    base = np.stack([gaussian_filter(rng.normal(size=(w, w)), 1.5) * 60.0 for _ in range(n)])
    kr, kc = np.fft.fftfreq(w)[:, None], np.fft.fftfreq(w)[None, :]
    moved = np.fft.ifft2(np.fft.fft2(base) * np.exp(-2j * np.pi * (kr * shift[0] + kc * shift[1]))).real
    medians = []
    for sigma_dn in (2.0, 4.0):
        ref = base + rng.normal(scale=sigma_dn, size=base.shape)
        mov = moved + rng.normal(scale=sigma_dn, size=base.shape)
        got = mismatch_cr_sigma_px(ref, mov, np.tile(shift, (n, 1)))
        bound = cramer_rao_sigma_px(gradient_snr(base, sigma_dn), w)
        ratio = np.median(got / bound, axis=0)
        assert np.all((0.7 < ratio) & (ratio < 1.3)), ratio  # measured 0.79 (noise in the scene gradients)
        medians.append(np.median(got))
    assert 1.3 < medians[1] / medians[0] < 2.1  # twice the noise: 1.5 x (the noise also adds to the scene gradients)
    far = mismatch_cr_sigma_px(base[:2], moved[:2], np.array([[9.0, 0.0], [np.nan, 0.0]]))
    assert np.isnan(far).all()
    assert mismatch_cr_sigma_px(base[:0], moved[:0], np.zeros((0, 2))).shape == (0, 2)


def test_mismatch_bound_does_not_depend_on_threads_or_chunks(monkeypatch):
    """Chunks on 1, 2 or 3 threads, or the whole set in one chunk: the same numbers, bit for bit."""
    import gcpmatch.texture as texture

    rng = np.random.default_rng(8)
    n, w = 700, 32  # three chunks of 256 windows
    ref = np.stack([gaussian_filter(rng.normal(size=(w, w)), 1.2) * 50.0 for _ in range(n)])
    mov = ref + rng.normal(scale=2.0, size=ref.shape)
    shift = rng.uniform(-3.0, 3.0, size=(n, 2))
    shift[::50] = np.nan
    serial = texture.mismatch_cr_sigma_px(ref, mov, shift, threads=1)
    assert np.isfinite(serial).mean() > 0.9
    for threads in (2, 3):
        np.testing.assert_array_equal(texture.mismatch_cr_sigma_px(ref, mov, shift, threads=threads), serial)
    monkeypatch.setattr(texture, "MISMATCH_CHUNK", 10 * n)
    np.testing.assert_array_equal(texture.mismatch_cr_sigma_px(ref, mov, shift, threads=2), serial)


def test_moved_windows_equal_bilinear_sampling_by_coordinates():
    """The grouped, slice-based bilinear move equals scipy's order-1 sampling with edge clipping."""
    from scipy.ndimage import map_coordinates

    from gcpmatch.texture import _bilinear_moved

    rng = np.random.default_rng(5)
    n, w, border = 40, 24, 5
    windows = rng.normal(size=(n, w, w)).astype(np.float32)
    offsets = rng.uniform(-border, border, size=(n, 2))
    offsets[:4] = [[border, border], [-border, -border], [border, -border], [0.0, 0.0]]  # the extremes
    got = _bilinear_moved(windows, offsets, border)
    inner = np.arange(border, w - border, dtype=float)
    for k in range(n):
        rr, cc = np.meshgrid(inner + offsets[k, 0], inner + offsets[k, 1], indexing="ij")
        want = map_coordinates(windows[k].astype(np.float64), [rr, cc], order=1, mode="nearest")
        np.testing.assert_allclose(got[k], want, rtol=0, atol=1e-12)


def test_sigma_bench_agrees_with_the_gather_formulation(tmp_path):
    """bench/bench_sigma.py: the current kernel gives the index-gather formulation's values."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "bench_sigma.py"
    spec = importlib.util.spec_from_file_location("bench_sigma", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--pairs", "220", "--repeat", "1", "--out", str(tmp_path / "s.json")]) == 0
    figures = json.loads((tmp_path / "s.json").read_text())
    assert figures["same_nan_pattern"] and figures["max_relative_difference"] < 1e-9
