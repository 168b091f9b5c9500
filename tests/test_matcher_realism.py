"""The matcher on the realistic profile: honest per-GCP sigma, window preparation, options.

The sigma tests simulate a small realistic scene (Sentinel-2 red band as source radiance, seed
other than the bench's), extract GCPs through the production pipeline with the DEFAULT options
(the window model, the reference accuracy that the simulated DOM states in its tags) and measure
each GCP's error against the TRUE model (its ground point projected through
``truth_manifest.json``), as ``bench/bench_matcher_realism.py`` does; ``sigma_px`` is honest
when the error over sigma has unit RMS per axis.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gcpmatch.options import MatchOptions
from gcpmatch.phase import phase_correlate
from gcpmatch.radiometry import prepare_windows, rank_windows
from gcpmatch.uncertainty import MATCH_FLOOR_PX, score_sigma_px, window_sigma
from sensor_models.errors import InputError

#: realistic DOM geolocation error per axis, metres, that a user reads in the reference's
#: specification: bias (1.2, -0.9) m and a 0.8 m rms field (sensor_models/simulate/profiles.py)
REALISTIC_REFERENCE_SIGMA_M = 1.3


def _texture(n=96, seed=0):
    """A band-limited random texture (smoothed white noise), float64, shape (n, n)."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    return gaussian_filter(rng.normal(size=(n, n)), 1.5) * 100.0 + 500.0


def _shifted_pairs(shift=(0.3, -0.45), n_pairs=8, size=64):
    """Reference windows and the same ground shifted by ``shift`` px (Fourier shift)."""
    refs, movs = [], []
    for k in range(n_pairs):
        tex = _texture(size, seed=k)
        f = np.fft.fft2(tex)
        kr = np.fft.fftfreq(size)[:, None]
        kc = np.fft.fftfreq(size)[None, :]
        mov = np.fft.ifft2(f * np.exp(-2j * np.pi * (kr * shift[0] + kc * shift[1]))).real
        refs.append(tex)
        movs.append(mov)
    return np.array(refs), np.array(movs)


def _gcp_truth_errors(scene, table):
    """(row, col) of each GCP minus the TRUE model's projection of its ground point, px (n, 2),
    and the GCPs' ``sigma_px`` (n,), where the truth projects."""
    from sensor_models.readers import open_model

    truth = open_model(scene / "truth_manifest.json")
    r_t, c_t = truth.ground_to_image(table.lon, table.lat, table.h, band=str(table.band[0]), array=table.ccd)
    err = np.stack([table.row - r_t, table.col - c_t], axis=1)
    ok = np.isfinite(err).all(axis=1)
    return err[ok], np.asarray(table.sigma_px, dtype=float)[ok]


@pytest.fixture(scope="module")
def realistic_s2_scene(tmp_path_factory, shared_data):
    """A realistic push-broom scene (256 lines, 20 m GSD, seed 11) on the Sentinel-2 red band."""
    from sensor_models.simulate.config import config_from_dict
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    s2 = shared_data / "real_textures" / "sentinel2" / "s2_B04.jp2"
    if not s2.exists():
        pytest.skip(f"{s2} not found")
    out = tmp_path_factory.mktemp("realistic-s2") / "scene"
    cfg = config_from_dict({"scene": {"gsd_m": 20.0, "n_rows": 256},
                            "reference": {"margin_m": 1000.0, "relief_m": 600.0}}).with_seed(11)
    simulate_pushbroom(out, config=cfg, profile="realistic", dom=s2, record_timings=False)
    return out


def _match(scene, options):
    """The production matcher on a simulated scene: (GcpTable, summary); the DOM's tags are read as a user's are."""
    from gcpmatch.extract import extract_gcps, read_band
    from sensor_models.maps.raster import MapImage
    from sensor_models.readers import open_scene
    from sensor_models.terrain.dem import Dem

    opened = open_scene(scene / "manifest.json")
    model = opened.model
    band = model.reference_band
    dem = Dem.open(scene / "reference" / "dem.tif")
    dom = MapImage.open(scene / "reference" / "dom.tif")
    return extract_gcps(model, read_band(opened, band), dem, dom, band=band, options=options)


def _z_rms(scene, table):
    """rms of truth error / sigma_px per axis (row, col), pooled over both axes, and the GCP count."""
    err, sigma = _gcp_truth_errors(scene, table)
    z = err / sigma[:, None]
    return np.sqrt(np.mean(z**2, axis=0)), float(np.sqrt(np.mean(z**2))), err.shape[0]


def test_default_sigma_is_honest_on_a_realistic_scene(realistic_s2_scene):
    """The DEFAULT options (window model, the DOM's own accuracy statement) give unit-rms normalized errors."""
    table, summary = _match(realistic_s2_scene, MatchOptions())
    acc = summary["reference_accuracy"]
    # the simulator states the realistic DOM's accuracy as a producer would: per-axis rms of its error model
    assert (acc["east_m"], acc["north_m"], acc["assumed"]) == (1.4, 1.2, False) and acc["source"].startswith("tag ")
    assert "reference_note" not in summary
    z_axes, z_pooled, n = _z_rms(realistic_s2_scene, table)
    print("default: truth error / sigma_px rms (row, col)", z_axes, "pooled", z_pooled, "GCPs", n)
    assert n > 50
    assert 0.8 <= z_pooled <= 1.2, z_pooled
    assert np.all((0.8 <= z_axes) & (z_axes <= 1.2)), z_axes


def test_reference_term_brackets_the_default(realistic_s2_scene):
    """Leaving the reference term out is optimistic, doubling it pessimistic: the default sits between."""
    bare, _ = _match(realistic_s2_scene, MatchOptions(reference_sigma_m=0.0))
    _, z_bare, _ = _z_rms(realistic_s2_scene, bare)
    double, _ = _match(realistic_s2_scene, MatchOptions(reference_sigma_m=2 * REALISTIC_REFERENCE_SIGMA_M))
    _, z_double, _ = _z_rms(realistic_s2_scene, double)
    print("pooled z without the reference term", z_bare, "with 2.6 m", z_double)
    assert z_bare > 1.3, z_bare
    assert z_double < 0.75, z_double


def test_rank_transform_removes_gain_offset_and_gamma():
    ref, mov = _shifted_pairs(shift=(0.3, -0.45))
    lo = ref.min()
    changed = 3.0 * ((ref - lo) / np.ptp(ref)) ** 0.5 + 40.0  # another sensor: gain, offset, gamma 0.5
    assert np.array_equal(rank_windows(changed), rank_windows(ref))
    r, m = prepare_windows(changed, mov, method="rank")
    pm = phase_correlate(r, m)
    err = np.hypot(pm.shift_row_px - 0.3, pm.shift_col_px + 0.45)
    assert pm.valid.all()
    rms_rank = np.sqrt(np.mean(err**2))
    assert 1e-4 < rms_rank < 0.015  # measured 0.005 px (the scene side is not a grey-level map of the reference)
    raw = phase_correlate(changed, mov)  # without the transform: measured 0.022 px
    rms_raw = np.sqrt(np.mean((raw.shift_row_px - 0.3) ** 2 + (raw.shift_col_px + 0.45) ** 2))
    assert rms_raw > 2.0 * rms_rank


def test_prepare_windows_rejects_an_unknown_method():
    ref, mov = _shifted_pairs(n_pairs=1)
    with pytest.raises(InputError) as exc:
        prepare_windows(ref, mov, method="census")
    assert exc.value.field == "radiometry"


@pytest.mark.parametrize("field, value", [("radiometry", "census"), ("sigma_model", "global"),
                                          ("reference_sigma_m", -1.0), ("phase_eps", -0.1),
                                          ("lowpass_cycles_px", 0.0)])
def test_match_options_name_a_bad_field(field, value):
    with pytest.raises(InputError) as exc:
        replace(MatchOptions(), **{field: value}).validate()
    assert exc.value.field == field


def test_score_sigma_falls_with_the_score_down_to_the_floor():
    s = np.array([0.5, 0.8, 0.95, 0.999, 1.0])
    sig = score_sigma_px(s)
    assert np.all(np.diff(sig) < 0)
    assert sig[-1] == pytest.approx(MATCH_FLOOR_PX)
    assert 0.07 < sig[0] < 0.1  # hypot(0.071, 0.032) at s = 0.5
    assert score_sigma_px(s, window_px=32)[2] == pytest.approx(2 * sig[2])


def test_window_sigma_models():
    res = np.zeros((3, 2))
    q = {"score": np.array([0.6, 0.9, 0.99])}
    assert np.all(window_sigma(0.07, res, q, model="ccd") == 0.07)
    assert np.all(window_sigma(float("nan"), res, q, model="ccd") == 0.1)  # too few matches: fallback
    w = window_sigma(0.07, res, q, model="window", reference_sigma_px=0.065)
    assert np.all(np.diff(w) < 0)
    assert np.all(w >= np.hypot(MATCH_FLOOR_PX, 0.065) - 1e-12)
    assert np.all(w < np.hypot(score_sigma_px(q["score"]), 0.065) + 1e-12)


def test_correlate_pairs_applies_the_phase_options():
    from gcpmatch.window_match import correlate_pairs

    ref, mov = _shifted_pairs(shift=(1.2, 0.7))
    rng = np.random.default_rng(3)
    mov = mov + rng.normal(scale=2.0, size=mov.shape)  # SNR about 10 (texture std about 19)
    opt = MatchOptions(phase_eps=1.0, lowpass_cycles_px=0.25)
    got = correlate_pairs(ref, mov, opt)
    want = phase_correlate(ref, mov, eps=1.0, lowpass=0.25, max_shift_px=16.0)
    default = phase_correlate(ref, mov, max_shift_px=16.0)
    assert np.array_equal(got.shift_px, want.shift_px)
    assert not np.array_equal(got.shift_px, default.shift_px)
    assert np.all(got.status == "")
    assert np.sqrt(np.mean((got.shift_px - [1.2, 0.7]) ** 2)) < 0.05


def test_match_command_takes_the_sigma_model(tmp_path):
    """``gcpcal match`` defaults to the window model. The ideal fixture's DOM states 0 m (the scene
    was rendered from it): no reference term. The same DOM without its statement: assumed 5.6 m.
    ``--sigma-model ccd`` reaches the matcher: one smaller sigma per CCD, no reference term."""
    import json
    from pathlib import Path

    import rasterio

    from calibrate.cli import main
    from gcpmatch.gcp_files import read_gcps
    from sensor_models.maps.dom_inputs import ACCURACY_TAG, ASSUMED_REFERENCE_SIGMA_M

    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
    dom = fixture / "reference" / "dom.tif"
    silent = tmp_path / "dom_silent.tif"
    with rasterio.open(dom) as src:
        profile, data = src.profile, src.read()
        tags = {k: v for k, v in src.tags().items() if k != ACCURACY_TAG}
    with rasterio.open(silent, "w", **profile) as dst:
        dst.write(data)
        dst.update_tags(**tags)
    base = ["-q", "match", str(fixture / "manifest.json"), "--dem", str(fixture / "reference" / "dem.tif"),
            "--spacing", "64"]
    assert main([*base, "--dom", str(dom), "--sigma-model", "ccd", "--out", str(tmp_path / "ccd.csv")]) == 0
    assert main([*base, "--dom", str(dom), "--out", str(tmp_path / "stated.csv")]) == 0
    assert main([*base, "--dom", str(silent), "--out", str(tmp_path / "win.csv")]) == 0
    ccd_summary = json.loads((tmp_path / "ccd.summary.json").read_text())
    stated_summary = json.loads((tmp_path / "stated.summary.json").read_text())
    win_summary = json.loads((tmp_path / "win.summary.json").read_text())
    assert ccd_summary["options"]["sigma_model"] == "ccd" and "reference_accuracy" not in ccd_summary
    assert stated_summary["reference_accuracy"]["assumed"] is False
    assert stated_summary["reference_accuracy"]["east_m"] == 0.0
    assert all(max(c["reference_sigma_px"]) == 0.0 for c in stated_summary["per_ccd"])
    assert win_summary["options"]["sigma_model"] == "window" and win_summary["options"]["reference_sigma_m"] is None
    assert win_summary["reference_accuracy"]["assumed"] is True
    assert win_summary["reference_accuracy"]["east_m"] == pytest.approx(ASSUMED_REFERENCE_SIGMA_M)
    ccd, win, stated = (read_gcps(tmp_path / f"{n}.csv") for n in ("ccd", "win", "stated"))
    # an assumed 5.6 m on the fixture's GSD (about 30 m) adds about 0.19 px in quadrature to every window
    ref_px = np.array([c["reference_sigma_px"] for c in win_summary["per_ccd"]])
    assert np.all((0.12 < ref_px) & (ref_px < 0.3)), ref_px
    assert np.all(win.sigma_px >= ref_px.min()) and np.median(win.sigma_px) > 2 * np.median(ccd.sigma_px)
    assert np.median(stated.sigma_px) < 0.5 * np.median(win.sigma_px)