"""The time-varying attitude over a randomized family of scenes (docs/attitude.md "Randomized family").

Each draw of :mod:`sensor_models.simulate.attitude_family` is a TRUE model whose attitude holds
sums of sinusoids and a drift (outside the estimator's spline and drift families), synthetic GCPs
through it with Gaussian noise, and the LAB model calibrated static and ``auto``
(``bench/bench_attitude_family.py`` holds the harness and the criteria):

* observable jitter (below the GCPs' Nyquist rate): truth error <= 0.15 px or <= 1.5 x the noise
  floor, and <= 0.35 x static where static is above 0.5 px and the floor allows it;
* no jitter: never worse than static by more than 5 %.

The default suite runs a fast subset (one band, 100-1000 GCPs over 2-10 s); the whole family (100 draws of
100-100 000 GCPs, one band or four, and 30 draws of 100-300 GCPs) is marked slow, with the pass
counts measured there (docs/attitude.md): every accuracy and gain claim holds where the largest
gap between GCP lines is below half the jitter's period; a few draws outside that, and one
drift-only draw, miss.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from calibrate.pspline import difference_penalty, pspline_segments, recovered_spectrum, smooth
from sensor_models.models.attitude_correction import AttitudeCorrection
from sensor_models.simulate import attitude_family as fam

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_attitude_family", ROOT / "bench" / "bench_attitude_family.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def _check(results):
    for r in results:
        assert r["success"], r["draw"]
        for key in ("accuracy", "gain", "no_jitter"):
            assert r[key] in (None, True), (key, r["draw"], r["static_px"], r["auto_px"], r["floor_px"])


# ------------------------------------------------------------------ the P-spline itself
def test_smoothing_recovers_a_sampled_sine_and_its_spectrum():
    """A 1.2 Hz sine sampled at 400 noisy random times: the chosen smoothing follows it within
    the noise, leaves far fewer effective parameters than coefficients, and the periodogram of
    the fit peaks at 1.2 Hz with about its amplitude."""
    rng = np.random.default_rng(4)
    t = np.sort(rng.uniform(0.0, 10.0, 400))
    truth = 10.0 * np.sin(2 * np.pi * 1.2 * t + 0.3)
    y = truth + rng.normal(0.0, 2.0, t.size)
    n_seg = pspline_segments(t, 0.0, 10.0, n_lines=2000)
    assert n_seg == 256  # 2 x ~400 distinct lines, bounded
    corr = AttitudeCorrection("spline", 0.0, 10.0, n_seg)
    b, _ = corr.basis(t)
    k = corr.n_coefficients
    # one axis of data; the other two held by a stiff ridge
    x = np.zeros((t.size, 3 * k))
    x[:, :k] = b
    normal, rhs = x.T @ x, x.T @ y
    penalty = np.zeros((3 * k, 3 * k))
    penalty[:k, :k] = difference_penalty(k)
    ridge = np.r_[np.zeros(k), np.full(2 * k, 1e6)]
    coef, _, edf, rss, sm = smooth(normal, rhs, float(y @ y), t.size, penalty, ridge)
    fit = b @ coef[:k]
    err = np.sqrt(np.mean((fit - truth) ** 2))
    assert 0.2 < err < 1.0  # noise 2.0: averaged down, not interpolated
    assert 24.0 < edf < 120.0 and sm.at_bound is None  # 2 x 1.2 Hz x 10 s; 259 coefficients
    assert sm.criterion == "gcv" and len(sm.curve_score) == len(sm.curve_lambda)
    fitted = corr.with_coefficients(np.vstack([coef[:k], np.zeros((2, k))]) * 1e-6)
    spec = recovered_spectrum(fitted, 0.0, 10.0)
    amp = np.asarray(spec["amplitude_urad"]["roll"])
    f = np.asarray(spec["frequency_hz"])
    assert abs(f[np.argmax(amp)] - 1.2) < 0.06
    assert 8.0 < amp.max() < 11.0


def test_draws_are_seeded_and_in_their_ranges():
    ranges = fam.FamilyRanges()
    draws = [fam.draw_scene(s) for s in range(60)]
    assert fam.draw_scene(7).to_dict() == fam.draw_scene(7).to_dict()
    for d in draws:
        assert ranges.duration_s[0] <= d.duration_s <= ranges.duration_s[1]
        assert ranges.n_gcps[0] <= d.n_gcps <= ranges.n_gcps[1]
        assert ranges.noise_px[0] <= d.noise_px <= ranges.noise_px[1]
        assert d.n_bands in (1, 4)
        for amp, f, _ in d.jitter:
            assert ranges.jitter_hz[0] <= f <= ranges.jitter_hz[1] and np.all(np.asarray(amp) <= 40.0)
    assert {d.n_bands for d in draws} == {1, 4} and any(not d.has_jitter for d in draws)
    small = fam.draw_scene(3, n_gcps=(100, 300))
    assert 100 <= small.n_gcps <= 300


def test_fast_family():
    """12 draws, one band, 100-1000 GCPs over 2-10 s, every noise and jitter of the family."""
    bench = _bench()
    ranges = fam.FamilyRanges(duration_s=(2.0, 10.0), n_gcps=(100, 1000), p_four_bands=0.0)
    results = [bench.run_draw(d) for d in bench.draws(12, first_seed=500, ranges=ranges)]
    summary = bench.summarize(results)
    bench.print_table("fast family", summary)
    assert summary["accuracy"]["applies"] >= 4 and summary["no_jitter"]["applies"] >= 2
    _check(results)


def _rates(summary):
    return {k: (summary[k]["passed"], summary[k]["applies"]) for k in
            ("accuracy", "gain", "no_jitter", "accuracy_gap", "gain_gap")}


@pytest.mark.slow
def test_whole_family():
    """100 draws (seeds 0-99). Measured: accuracy 75 of 76, gain 16 of 16, no_jitter 23 of 24; where
    the largest gap between GCP lines is below half the jitter's period, 71 of 71 and 16 of 16.
    The misses: seed 46 (170 GCPs over 18.3 s, jitter to 1.28 Hz: 0.170 px, 1.13 x its bound) and
    seed 17 (no jitter, a small drift: a 22-parameter P-spline, 0.091 px against static 0.067)."""
    bench = _bench()
    results = [bench.run_draw(d) for d in bench.draws(100)]
    summary = bench.summarize(results)
    bench.print_table("family", summary)
    rates = _rates(summary)
    assert all(r["success"] for r in results)
    assert rates["accuracy_gap"][0] == rates["accuracy_gap"][1] >= 60
    assert rates["gain_gap"][0] == rates["gain_gap"][1] >= 10
    assert rates["gain"][0] == rates["gain"][1]
    assert rates["accuracy"][0] >= rates["accuracy"][1] - 1 and summary["accuracy"]["worst"]["ratio"] < 1.2
    assert rates["no_jitter"][0] >= rates["no_jitter"][1] - 1 and summary["no_jitter"]["worst"]["ratio"] < 1.4


@pytest.mark.slow
def test_family_of_few_gcps():
    """30 draws of 100-300 GCPs (seeds 100000-100029). Measured: accuracy 17 of 19, gain 2 of 3,
    no_jitter 11 of 11; where the largest gap between GCP lines is below half the jitter's period,
    15 of 15 and 2 of 2. The misses (seeds 100008, 100021: 166-173 GCPs over 16-20 s, jitter to
    2.2 Hz, gaps between GCP lines of 0.4 s) are jitter the sampling does not hold."""
    bench = _bench()
    results = [bench.run_draw(d) for d in bench.draws(30, first_seed=100_000, n_gcps=bench.SMALL_GCPS)]
    summary = bench.summarize(results)
    bench.print_table("100-300 GCPs", summary)
    rates = _rates(summary)
    assert all(r["success"] for r in results)
    assert rates["accuracy_gap"][0] == rates["accuracy_gap"][1] >= 10
    assert rates["gain_gap"][0] == rates["gain_gap"][1]
    assert rates["no_jitter"][0] == rates["no_jitter"][1] >= 5
    assert rates["accuracy"][0] >= rates["accuracy"][1] - 2
