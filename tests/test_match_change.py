"""Matching under real radiometric change: a scene rendered from one real band, matched on another.

The scenes come from :mod:`bench.change_pairs` (the realistic profile's TRUE model, optics,
noise and sun shading; the reference a real file, exact by construction). ``same``: the
reference is the band the scene was rendered from; ``cross``: the Sentinel-2 red band against a
scene of its near-infrared band or the other way round (contrast inverted over vegetation; the
shared test data hold no two dates of one place). Each GCP is graded against the TRUE model, and
across bands also with the bands' own displacement (``change_pairs.BAND_OFFSET_M``, measured by
``bench/band_offset.py`` outside the matcher) taken out of the truth. The
figures in the comments are ``python bench/bench_change.py`` (docs/matching.md, "Matching under
real change").
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gcpmatch.options import MatchOptions
from gcpmatch.window_match import spectral_spread_px
from sensor_models.errors import InputError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import change_pairs  # noqa: E402

CHANGE = MatchOptions(spectral_spread_sigma=True, max_spectral_spread=1.0)


def _textures(n_pairs=24, size=64, shift=(0.35, -0.6), seed=0):
    """Band-limited random textures and the same shifted by ``shift`` px (Fourier shift)."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    ref = np.stack([gaussian_filter(rng.normal(size=(size, size)), 1.5) * 100 + 500 for _ in range(n_pairs)])
    kr = np.fft.fftfreq(size)[:, None]
    kc = np.fft.fftfreq(size)[None, :]
    mov = np.fft.ifft2(np.fft.fft2(ref) * np.exp(-2j * np.pi * (kr * shift[0] + kc * shift[1]))).real
    return ref, mov


def test_spectral_spread_is_small_for_a_faithful_pair_and_grows_with_change():
    from gcpmatch.phase import phase_correlate

    ref, mov = _textures()
    pm = phase_correlate(ref, mov, max_shift_px=16)
    same = spectral_spread_px(ref, mov, pm.shift_px, max_shift_px=16)
    assert np.all(same < 0.02), same.max()
    changed = ref.copy()
    changed[:, :, 32:] = 1000.0 - changed[:, :, 32:]  # contrast inverted over half of each window
    changed[:, 40:, :] += 60.0 * np.sin(np.arange(64) / 3.0)  # a structure the scene does not show
    pc = phase_correlate(changed, mov, max_shift_px=16)
    spread = spectral_spread_px(changed, mov, pc.shift_px, max_shift_px=16)
    assert np.median(spread) > 5 * np.median(same)


@pytest.mark.parametrize("field, value", [("spectral_spread_sigma", 1), ("max_spectral_spread", -1.0),
                                          ("max_spectral_spread", float("inf")), ("detect_change", "yes")])
def test_change_options_name_a_bad_field(field, value):
    with pytest.raises(InputError) as exc:
        replace(MatchOptions(), **{field: value}).validate()
    assert exc.value.field == field


def test_spread_options_off_by_default_leave_the_quality_alone():
    from gcpmatch.window_match import correlate_pairs

    ref, mov = _textures(n_pairs=4)
    assert "spectral_spread_px" not in correlate_pairs(ref, mov).quality
    assert np.all(np.isfinite(correlate_pairs(ref, mov, CHANGE).quality["spectral_spread_px"]))


def test_reference_disagrees_tells_a_changed_reference_from_a_faithful_one():
    from gcpmatch.window_match import correlate_pairs, reference_disagrees

    ref, mov = _textures(n_pairs=32)
    rng = np.random.default_rng(1)
    # a faithful reference, noisy scene: texture std 20, noise 2 (median ratio 0.65; noise 5 gives
    # 1.21: pure phase whitens the noise, so a very noisy scene can pass for a changed one)
    noisy = mov + rng.normal(scale=2.0, size=mov.shape)
    q = correlate_pairs(ref, noisy, MatchOptions(detect_change=True)).quality
    faithful, median_faithful = reference_disagrees(q["spectral_spread_px"], q["score"])
    changed = ref.copy()
    changed[:, :, 40:] = 1000.0 - changed[:, :, 40:]  # contrast inverted over a third of each window
    changed[:, 40:, :] += 30.0 * np.sin(np.arange(64) / 3.0)  # a structure the scene does not show
    q = correlate_pairs(changed, noisy, MatchOptions(detect_change=True)).quality
    other, median_changed = reference_disagrees(q["spectral_spread_px"], q["score"])
    assert not faithful and median_faithful < 1.0, median_faithful
    assert other and median_changed > 1.0, median_changed
    assert reference_disagrees(np.full(3, np.nan), np.full(3, 0.5)) == (False, pytest.approx(np.nan, nan_ok=True))


@pytest.fixture(scope="module")
def red_scene(tmp_path_factory, shared_data):
    """A realistic scene rendered from the Sentinel-2 red band (seed 11), with its two references."""
    source, refs = change_pairs.PAIRS["s2_red_vs_nir"]
    data = shared_data / "real_textures"
    if not (data / source).exists():
        pytest.skip(f"{data / source} not found")
    scene = change_pairs.render_scene(tmp_path_factory.mktemp("change") / "s2_red", data / source, 11)
    return scene, {k: data / v for k, v in refs.items()}


def _graded(scene, dom, options, band_offset_m=None):
    """Figures of the GCPs of ``scene`` on ``dom``; with ``band_offset_m`` (east, north m) the
    reference band's own displacement is taken out of the truth (:func:`change_pairs.truth_errors`)."""
    table, summary = change_pairs.match(scene, dom, options)
    assert table is not None, summary.get("message")
    raw = change_pairs.figures(*change_pairs.truth_errors(scene, table))
    if band_offset_m is None:
        return raw
    return raw, change_pairs.figures(*change_pairs.truth_errors(scene, table, band_offset_m, change_pairs.dom_crs(dom)))


def test_same_band_reference_keeps_the_matcher_accurate(red_scene):
    scene, refs = red_scene
    default = _graded(scene, refs["same"], MatchOptions())
    change = _graded(scene, refs["same"], CHANGE)
    print("same band: default", default, "change options", change)
    assert default["n"] > 80 and default["rms_px"] < 0.06  # measured 124 GCPs, 0.049 px
    # the self-consistency test drops few pairs of a faithful reference and loses no accuracy
    assert change["n"] > 0.75 * default["n"] and change["rms_px"] <= default["rms_px"] + 0.002


def test_cross_band_reference_gcps_and_honest_sigma(red_scene):
    """Red scene on the near-infrared band: GCPs are found (the coarse stage keeps to the RANSAC
    consensus when most SIFT matches are wrong), the window sigma alone is optimistic, the spectral
    spread makes it honest, and rejecting self-inconsistent pairs halves the truth error."""
    scene, refs = red_scene
    default = _graded(scene, refs["cross"], MatchOptions())
    spread = _graded(scene, refs["cross"], MatchOptions(spectral_spread_sigma=True))
    change, fixed = _graded(scene, refs["cross"], CHANGE, change_pairs.BAND_OFFSET_M["s2_red_vs_nir"])
    print("cross band: default", default, "spread sigma", spread, "change options", change, "band offset out", fixed)
    assert default["n"] > 40  # measured 74 GCPs (a coarse refit on all SIFT matches lands 4.7 km off: none)
    assert default["z"] > 1.8  # measured 2.4: the score-based sigma does not see the change
    assert 0.8 <= spread["z"] <= 1.2, spread["z"]  # measured 1.10
    assert change["n"] >= 15  # measured 26
    assert change["rms_px"] < 0.6 * default["rms_px"], (change["rms_px"], default["rms_px"])
    assert change["rms_px"] < 0.16  # measured 0.136 px (bias about 0.1 px along rows: not 0.06)
    assert 0.8 <= change["z"] <= 1.4, change["z"]  # measured 1.30: the common bias is not in sigma
    # the bias is the bands' own displacement (measured outside the matcher, bench/band_offset.py):
    # taken out of the truth, the same GCPs are graded 0.098 px, truth / sigma 1.04
    assert fixed["rms_px"] < 0.8 * change["rms_px"] and fixed["rms_px"] < 0.115, (fixed, change)
    assert 0.8 <= fixed["z"] <= 1.2, fixed["z"]


def test_detect_change_lets_the_scene_choose(red_scene):
    """``detect_change``: on the scene's own band the matcher is the default one (same GCPs); on
    the other band the scene switches the change options on (same GCPs as with them)."""
    scene, refs = red_scene
    detect = MatchOptions(detect_change=True)
    same_table, same_summary = change_pairs.match(scene, refs["same"], detect)
    default_table, _ = change_pairs.match(scene, refs["same"], MatchOptions())
    cross_table, cross_summary = change_pairs.match(scene, refs["cross"], detect)
    change_table, _ = change_pairs.match(scene, refs["cross"], CHANGE)
    print(same_summary["change"], cross_summary["change"])
    assert not same_summary["change"]["detected"] and same_summary["change"]["median_spread_ratio"] < 0.8
    assert cross_summary["change"]["detected"] and cross_summary["change"]["median_spread_ratio"] > 1.05
    for got, want in ((same_table, default_table), (cross_table, change_table)):
        assert len(got) == len(want)
        assert np.array_equal(got.row, want.row) and np.array_equal(got.sigma_px, want.sigma_px)
    fixed = change_pairs.figures(*change_pairs.truth_errors(scene, cross_table, change_pairs.BAND_OFFSET_M["s2_red_vs_nir"],
                                                            change_pairs.dom_crs(refs["cross"])))
    assert fixed["rms_px"] < 0.115 and 0.8 <= fixed["z"] <= 1.2, fixed  # the default matcher: 0.22 px, 2.1


@pytest.mark.slow
def test_cross_band_family(tmp_path, shared_data):
    """Both directions (red on near-infrared, near-infrared on red), seeds 11 and 12, pooled."""
    data = shared_data / "real_textures"
    err = {"spread": [], "change": [], "change_band_offset_out": []}
    sig = {"spread": [], "change": [], "change_band_offset_out": []}
    for name in ("s2_red_vs_nir", "s2_nir_vs_red"):
        source, refs = change_pairs.PAIRS[name]
        for seed in (11, 12):
            scene = change_pairs.render_scene(tmp_path / f"{name}_{seed}", data / source, seed)
            for key, opt in (("spread", MatchOptions(spectral_spread_sigma=True)), ("change", CHANGE)):
                table, _ = change_pairs.match(scene, data / refs["cross"], opt)
                e, s = change_pairs.truth_errors(scene, table)
                err[key].append(e)
                sig[key].append(s)
                if key == "change":
                    e, s = change_pairs.truth_errors(scene, table, change_pairs.BAND_OFFSET_M[name],
                                                     change_pairs.dom_crs(data / refs["cross"]))
                    err["change_band_offset_out"].append(e)
                    sig["change_band_offset_out"].append(s)
    fig = {k: change_pairs.figures(np.concatenate(err[k]), np.concatenate(sig[k])) for k in err}
    print(fig)
    assert 0.8 <= fig["spread"]["z"] <= 1.2, fig["spread"]  # measured 1.12
    assert fig["change"]["rms_px"] < 0.16, fig["change"]  # measured 0.134
    assert fig["change"]["z"] <= 1.35, fig["change"]  # measured 1.23
    # the row bias is the bands' own displacement: taken out of the truth, 0.090 px and 0.92 (the
    # 0.06 px target is not reached: 0.088 px rms is left about the mean, twice the same-band error)
    fixed = fig["change_band_offset_out"]
    assert fixed["rms_px"] < 0.105 and fixed["rms_px"] < 0.75 * fig["change"]["rms_px"], fixed
    assert 0.8 <= fixed["z"] <= 1.2, fixed


def test_match_command_change_option(red_scene, tmp_path, capsys):
    """``gcpcal match --change auto`` on the other band: the scene decides, the printed line says so,
    and the GCP table is the one ``--change on`` writes; ``--change`` refuses other words."""
    import json

    from calibrate.cli import main
    from calibrate.cli.match import change_options

    scene, refs = red_scene
    args = [str(scene / "manifest.json"), "--dom", str(refs["cross"]), "--dem", str(scene / "reference" / "dem.tif"),
            "--reference-sigma-m", "0"]
    assert main(["match", *args, "--out", str(tmp_path / "auto.csv"), "--change", "auto"]) == 0
    printed = capsys.readouterr().out
    assert "change: median spectral spread over its noise" in printed and "change options on" in printed, printed
    summary = json.loads((tmp_path / "auto.summary.json").read_text())
    assert summary["change"]["detected"] is True
    assert main(["match", *args, "--out", str(tmp_path / "on.csv"), "--change", "on"]) == 0
    assert (tmp_path / "auto.csv").read_bytes() == (tmp_path / "on.csv").read_bytes()
    assert change_options("on") == {"spectral_spread_sigma": True, "max_spectral_spread": 1.0}
    assert change_options("off") == {}
    assert main(["match", *args, "--out", str(tmp_path / "x.csv"), "--change", "maybe"]) == 2
