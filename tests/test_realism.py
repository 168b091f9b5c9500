"""Error profiles of the push-broom simulator: ``ideal`` is today's output, ``realistic`` injects
what it says, each magnitude bracketed from both sides (docs/error_budget.md)."""

from __future__ import annotations

import hashlib
import importlib.util
import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from affine import Affine
from scipy.spatial.transform import Rotation

from calibrate.cli import main as cli
from compare_outputs import compare_folders
from sensor_models.simulate.config import SimConfig, config_from_dict
from sensor_models.simulate.kernel import (detector_response, footprint_offsets, integrate_footprint, optics_kernel,
                                           system_mtf)
from sensor_models.simulate.profiles import PROFILES, Sourced, get_profile, profile_table
from sensor_models.simulate.pushbroom_sim import simulate_pushbroom
from sensor_models.simulate.realistic_sim import apply_profile, detector_gains
from sensor_models.simulate.reference_pair import degrade_dem, degrade_dom
from sensor_models.simulate.scene import build_models
from sensor_models.simulate.true_lens import LensExtras, cubic_residual_px, lens_extras

REALISTIC = PROFILES["realistic"]

#: a scene large enough for the LAB model's ~260 px error to stay inside its lines (4 x 64 x 128)
MEDIUM = {"scene": {"n_rows": 128}, "camera": {"detectors_per_ccd": 64, "overlap_detectors": 6},
          "reference": {"margin_m": 1000.0}}

ROOT = Path(__file__).resolve().parents[1]

#: a small scene (4 CCDs x 32 detectors, 64 lines) of the default sensor; its output under the ideal
#: profile is the committed fixture ``fixtures/small_ideal_scene/`` (``make_small_ideal_scene.py``)
SMALL = {"scene": {"n_rows": 64}, "camera": {"detectors_per_ccd": 32, "overlap_detectors": 4},
         "reference": {"margin_m": 500.0, "relief_m": 300.0}}
SMALL_IDEAL = ROOT / "fixtures" / "small_ideal_scene"


def test_small_scene_is_the_fixture_scripts_scene():
    spec = importlib.util.spec_from_file_location("make_small", ROOT / "fixtures" / "make_small_ideal_scene.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.SMALL == SMALL


def test_ideal_profile_is_the_output_before_profiles(tmp_path):
    """The ideal profile (and no profile) renders what the simulator gave before profiles existed.

    ``fixtures/small_ideal_scene`` holds that output (its pixel arrays and JSON files had the
    sha256 prefixes 577a7678..., cca64e09..., a43e6ebc... at commit e24eb4b); the comparison
    tolerates the last-bit rounding that differs between CPUs (tests/compare_outputs.py). Within
    one run, the two spellings of the ideal profile must agree to the bit.
    """
    cfg = config_from_dict(SMALL)
    simulate_pushbroom(tmp_path / "none", config=cfg, record_timings=False, profile=None)
    simulate_pushbroom(tmp_path / "ideal", config=cfg, record_timings=False, profile="ideal")
    assert compare_folders(SMALL_IDEAL, tmp_path / "ideal") == []
    for p in (tmp_path / "none").rglob("*"):
        if p.is_file():
            assert p.read_bytes() == (tmp_path / "ideal" / p.relative_to(tmp_path / "none")).read_bytes(), p


def test_the_comparison_sees_a_change_of_the_simulator(tmp_path):
    """A scene rendered with another seed is not the fixture: the tolerances can fail."""
    cfg = config_from_dict({**SMALL, "seed": 7})
    simulate_pushbroom(tmp_path, config=cfg, record_timings=False, profile="ideal")
    assert compare_folders(SMALL_IDEAL, tmp_path)


def test_every_magnitude_names_its_source():
    for profile in PROFILES.values():
        rows = profile_table(profile)
        assert len(rows) >= 30
        for name, value, unit, model, source in rows:
            assert source and unit and model, name
    assert get_profile("realistic") is REALISTIC
    assert isinstance(REALISTIC.jitter_frequency_hz, Sourced)
    with pytest.raises(Exception, match="unknown profile 'nope'"):
        get_profile("nope")


def test_mtf_at_nyquist_is_that_of_a_real_imager():
    kw = dict(defocus_radius_px=REALISTIC.value("defocus_radius_px"), halo_fraction=REALISTIC.value("halo_fraction"),
              halo_sigma_px=REALISTIC.value("halo_sigma_px"), supersampling=REALISTIC.value("supersampling"),
              smear_lines=REALISTIC.value("motion_smear_lines"), source_px_per_px=2.0)
    across = system_mtf([0.5], axis="col", **kw)[0]
    along = system_mtf([0.5], axis="row", **kw)[0]
    assert 0.15 <= across <= 0.30  # Sentinel-2 MSI range
    assert 0.10 <= along < across  # the along-track smear lowers it further


def test_rendered_sine_target_has_the_predicted_modulation():
    """The kernel's own rendering of a sine target against system_mtf (independent paths)."""
    v = REALISTIC.value
    scale, f_px = 2.0, 0.3  # source px per detector pitch; target frequency, cycles per pitch
    cols = np.arange(800, dtype=np.float32)
    radiance = np.tile(0.5 + 0.4 * np.sin(2 * np.pi * (f_px / scale) * cols), (120, 1)).astype(np.float32)
    kern = optics_kernel(v("defocus_radius_px"), v("halo_fraction"), v("halo_sigma_px"), source_px_per_px=scale)
    filtered = cv2.filter2D(radiance, cv2.CV_32F, kern, borderType=cv2.BORDER_REFLECT)
    rr, cc = np.mgrid[0:20, 0:300].astype(np.float32)
    u, v_ = 100 + scale * cc, 40 + scale * rr
    out = integrate_footprint(filtered, u, v_, *footprint_offsets(v("supersampling"), v("motion_smear_lines")))
    line = out[10, 20:280].astype(np.float64)
    x = np.arange(20, 280)
    design = np.stack([np.ones_like(x), np.sin(2 * np.pi * f_px * x), np.cos(2 * np.pi * f_px * x)], axis=1)
    coef = np.linalg.lstsq(design, line, rcond=None)[0]
    measured = np.hypot(coef[1], coef[2]) / 0.4
    predicted = system_mtf([f_px], defocus_radius_px=v("defocus_radius_px"), halo_fraction=v("halo_fraction"),
                           halo_sigma_px=v("halo_sigma_px"), supersampling=v("supersampling"),
                           smear_lines=v("motion_smear_lines"), source_px_per_px=scale, axis="col")[0]
    assert 0.2 < measured < 0.9
    assert abs(measured - predicted) < 0.05 * predicted


def test_prnu_and_ccd_gain_steps_on_a_flat_field():
    cfg = apply_profile(SimConfig(), REALISTIC)
    n, lines = cfg.camera.detectors_per_ccd, 400
    flat = np.full((lines, n), 0.5, np.float32)
    rel, ccd_means = [], []
    for ccd in range(4):
        gain, offset = detector_gains(REALISTIC, cfg.seed, 0, ccd, n, 4)
        dn = detector_response(flat, gain=1.0, gamma=1.0, offset_dn=0.0, nonlinearity=0.0, pixel_gain=gain,
                               pixel_offset_dn=offset, snr=cfg.radiometry.snr, bits=cfg.radiometry.bits,
                               rng=np.random.default_rng(ccd)).astype(np.float64)
        col = dn.mean(axis=0)
        rel.append(col / col.mean() - 1.0)
        ccd_means.append(col.mean())
    prnu = float(np.sqrt(np.mean(np.concatenate(rel) ** 2)))
    assert 0.004 < prnu < 0.0065  # 0.5 % PRNU plus 2 DN striping at ~1640 DN
    steps = np.std(np.asarray(ccd_means) / np.mean(ccd_means))
    assert 0.002 < steps < 0.05  # CCD gain steps of 2 % rms (four draws)


def test_jitter_is_in_the_truth_only_at_the_configured_frequency():
    cfg = apply_profile(config_from_dict(SMALL), REALISTIC)
    models = build_models(cfg, lens=lens_extras(REALISTIC, cfg.seed), orbit_bias_m=3.0)

    def roll_spectrum(att):
        t = att.seconds
        roll = Rotation.from_quat(att.quaternions_xyzw).as_euler("ZYX")[:, 2]
        roll = roll - np.polyval(np.polyfit(t, roll, 1), t)  # bias and drift out
        n = 16 * t.size
        spec = np.abs(np.fft.rfft(roll, n)) * 2.0 / t.size
        return np.fft.rfftfreq(n, t[1] - t[0]), spec

    f, s = roll_spectrum(models.true_model.attitude)
    band = (f > 0.05) & (f < 3.0)
    peak = f[band][np.argmax(s[band])]
    assert abs(peak - 0.3) < 0.05 * 0.3
    assert 4.0e-6 < s[band].max() < 6.0e-6  # 5 urad
    f, s = roll_spectrum(models.lab_model.attitude)
    near = (f > 0.25) & (f < 0.35)
    assert s[near].max() < 1.5e-6  # the LAB attitude knows only star-tracker noise (3 urad white)


def test_true_lens_lies_outside_the_cubic_family():
    cfg = config_from_dict(SMALL)
    lens = lens_extras(REALISTIC, cfg.seed)
    real = cubic_residual_px(build_models(cfg, lens=lens), lens)
    assert 0.01 < real["smooth_rms_px"] < 0.2  # k2, k3, curvature, bending alone
    assert 0.02 < real["rms_px"] < 1.0  # plus 0.03 px per-detector irregularity
    ideal = cubic_residual_px(build_models(cfg), LensExtras())
    assert ideal["rms_px"] < 1e-3  # today's truth: inside the family


def _hills(n=240, res=30.0):
    y, x = np.mgrid[0:n, 0:n] * res
    dem = 400 + 300 * np.sin(x / 2500.0) * np.cos(y / 1800.0) + 0.02 * x
    return dem.astype(np.float32), Affine(res, 0, 500000.0, 0, -res, 4_900_000.0)


def test_user_dem_is_srtm_like():
    dem, tr = _hills()
    out = degrade_dem(dem, tr, REALISTIC, seed=3)
    assert abs(out.transform.a - 90.0) < 1.0
    assert 5.0 <= out.figures["added_error_rms_m"] <= 16.0
    coarse = cv2.resize(dem, out.values.shape[::-1], interpolation=cv2.INTER_AREA)
    diff = (out.values - coarse)[np.isfinite(out.values)]
    assert 5.0 <= float(np.sqrt(np.mean(diff**2))) <= 16.0
    assert 0.001 <= out.figures["void_fraction"] <= 0.01
    assert np.isnan(out.values).any()


def _phase_shift_m(a, b, res):
    """East, north shift (m) of the content of ``b`` relative to ``a`` (sign set by an np.roll probe)."""
    probe = cv2.phaseCorrelate(a, np.roll(a, 1, axis=1))[0][0]  # content moved one pixel east
    (dx, dy), _ = cv2.phaseCorrelate(a, b)
    sign = np.sign(probe)
    return sign * dx * res, -sign * dy * res


def test_dom_geolocation_error_is_1_to_3_m():
    rng = np.random.default_rng(0)
    tex = cv2.GaussianBlur(rng.random((600, 600)).astype(np.float32), (0, 0), 3.0)
    tex = (tex - tex.min()) / np.ptp(tex)
    tr = Affine(10.0, 0, 400000.0, 0, -10.0, 4_100_000.0)
    out = degrade_dom(tex, tr, REALISTIC, seed=5)
    assert 1.0 <= out.figures["geolocation_rms_m"] <= 3.0
    assert out.figures["geolocation_max_m"] < 6.0
    flat = replace(REALISTIC, dom_bias_m=Sourced((0.0, 0.0), "test"), dom_field_rms_m=Sourced(0.0, "test"))
    ref = degrade_dom(tex, tr, flat, seed=5)
    east, north = _phase_shift_m(ref.values.astype(np.float32), out.values.astype(np.float32), 30.0)
    # the DOM shows the ground at p + e at p: its content moves by -e (bias 1.2 m east, -0.9 m north)
    assert 1.0 <= np.hypot(east, north) <= 3.0
    assert -1.9 < east < -0.6 and 0.3 < north < 1.6


def test_cli_realistic_scene_carries_its_profile(tmp_path, monkeypatch, capsys):
    """Off a terminal the rendering prints counted tenths, the procedural source's parts included."""
    import re

    import calibrate.cli._progress as progress_module

    monkeypatch.setattr(progress_module, "PLAIN_AFTER_S", 0.0)
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(MEDIUM))
    out = tmp_path / "scene"
    assert cli(["simulate", "pushbroom", "--out", str(out), "--config", str(cfg), "--profile", "realistic"]) == 0
    counts = [tuple(int(v) for v in m) for m in
              re.findall(r"gcpcal simulate pushbroom: rendering (\d+) % \((\d+)/(\d+)\)", capsys.readouterr().err)]
    assert len(counts) >= 5 and len({t for _, _, t in counts}) == 1  # one total from the first line on
    percent, done, total = zip(*counts)
    assert list(done) == sorted(done) and counts[-1] == (100, total[0], total[0])
    blocks = -(-MEDIUM["scene"]["n_rows"] // 256)
    assert total[0] > 2 + blocks  # the set-up's first step counted in parts (source radiance and DEM)
    assert counts[0][1] < total[0] - 2 - blocks  # a line came while the source was being built
    summary = json.loads((out / "summary.json").read_text())
    assert summary["profile"] == "realistic"
    inj = summary["injected"]
    assert 0.15 <= inj["mtf_nyquist"]["col"] <= 0.30
    assert 5.0 <= inj["dem_error_under_footprint_m"]["rms"] <= 16.0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["profile"] == "realistic" and truth["orbit_bias_m"] == 3.0
    # the user's reference is not what rendered the scene
    with rasterio.open(out / "reference" / "dom.tif") as ds:
        assert abs(ds.res[0] - 30.0) < 0.5
    with rasterio.open(out / "reference" / "dem.tif") as ds:
        assert abs(ds.res[0] - 90.0) < 1.0 and ds.nodata == -32768.0
    assert (out / "reference" / "truth" / "dem_true.tif").exists()


def test_cli_profile_usage_errors(tmp_path, capsys):
    assert cli(["simulate", "pushbroom", "--out", str(tmp_path / "a"), "--profile", "nope"]) == 2
    dem = tmp_path / "dem.tif"
    dem.write_bytes(b"")
    capsys.readouterr()
    code = cli(["simulate", "pushbroom", "--out", str(tmp_path / "b"), "--profile", "realistic", "--dem", str(dem),
                "--dom", str(dem)])
    err = capsys.readouterr().err
    assert code == 1
    assert "give --dom only" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())


def test_realistic_scene_from_sentinel2_red(tmp_path, shared_data):
    s2 = shared_data / "real_textures" / "sentinel2" / "s2_B04.jp2"
    if not s2.exists():
        pytest.skip(f"{s2} not found")
    cfg = config_from_dict({**MEDIUM, "scene": {"n_rows": 128, "gsd_m": 20.0}})
    s = simulate_pushbroom(tmp_path, config=cfg, profile="realistic", dom=s2)
    assert s["injected"]["source_radiance"].endswith("s2_B04.jp2")
    with rasterio.open(tmp_path / "B2.tif") as ds:
        img = ds.read(1).astype(np.float64)
    assert img.std() > 50  # real texture, not a flat field
    # the reference is a degraded copy of the source on its own 30 m grid: alike, never equal
    with rasterio.open(s2) as ds:
        src = ds.read(1).astype(np.float32)
    with rasterio.open(tmp_path / "reference" / "dom.tif") as ds:
        ref = ds.read(1).astype(np.float32)
    src30 = cv2.resize(src, ref.shape[::-1], interpolation=cv2.INTER_AREA)
    r = np.corrcoef(src30.ravel(), ref.ravel())[0, 1]
    assert 0.7 < r < 0.99


def test_realistic_scene_is_a_function_of_its_seed(tmp_path):
    cfg = config_from_dict(MEDIUM)
    digests = []
    for k, workers in enumerate((1, 2)):
        out = tmp_path / f"s{k}"
        simulate_pushbroom(out, config=cfg, profile="realistic", record_timings=False, workers=workers)
        digests.append({p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in (out / "B2.tif", out / "reference" / "dom.tif", out / "reference" / "dem.tif",
                                  out / "truth.json", out / "manifest.json")})
    assert digests[0] == digests[1]
    other = tmp_path / "other"
    simulate_pushbroom(other, config=cfg.with_seed(7), profile="realistic", record_timings=False)
    assert hashlib.sha256((other / "B2.tif").read_bytes()).hexdigest() != digests[0]["B2.tif"]
