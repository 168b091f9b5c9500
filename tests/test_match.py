"""GCP extraction on simulated scenes: accuracy against the truth, clouds, large errors, bad input."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from gcpmatch.coarse import CoarseMatchError, coarse_match
from gcpmatch.extract import extract_gcps, read_band
from gcpmatch.gcp_files import read_gcps
from gcpmatch.options import MatchOptions
from calibrate.cli import main
from sensor_models.errors import GcpcalError, InputError
from sensor_models.readers import open_model, open_scene
from sensor_models.simulate.config import SimConfig
from sensor_models.simulate.pushbroom_sim import simulate_pushbroom
from sensor_models.maps.raster import MapImage
from sensor_models.simulate.truth import truth_error
from sensor_models.terrain.dem import Dem


def _config(**errors) -> SimConfig:
    cfg = SimConfig()
    cam = replace(cfg.camera, detectors_per_ccd=160, bands=("B2",), reference_band="B2", band_offsets_px=(0.0,))
    rad = replace(cfg.radiometry, band_gain=(1.0,), band_offset_dn=(40.0,), band_gamma=(0.9,))
    return replace(cfg, scene=replace(cfg.scene, n_rows=384), camera=cam, radiometry=rad,
                   errors=replace(cfg.errors, **errors)).validate()


def _open(d):
    lab = open_model(d / "manifest.json")
    return (lab, open_model(d / "truth_manifest.json"), Dem.open(d / "reference" / "dem.tif"),
            MapImage.open(d / "reference" / "dom.tif"), read_band(open_scene(d / "manifest.json"), "B2"))


def _errors_vs_truth(table, truth):
    names = {c.name: i for i, c in enumerate(truth.band_ccds("B2"))}
    idx = np.array([names[c] for c in table.ccd])
    r, c = np.empty(len(table)), np.empty(len(table))
    for i in range(len(names)):
        s = idx == i
        r[s], c[s] = truth.ground_to_image(table.lon[s], table.lat[s], table.h[s], band="B2", array=i)
    return np.hypot(table.row - r, table.col - c), idx


@pytest.fixture(scope="module")
def clear_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("clear")
    simulate_pushbroom(d, config=_config())
    return d


def test_dense_gcps_are_within_a_twentieth_of_a_pixel(clear_scene):
    lab, truth, dem, dom, img = _open(clear_scene)
    table, summary = extract_gcps(lab, img, dem, dom, band="B2", options=MatchOptions(spacing_px=24))
    err, idx = _errors_vs_truth(table, truth)
    rms = float(np.sqrt(np.mean(err**2)))
    print(f"clear: {len(table)} GCPs, rms {rms:.4f} px, max {err.max():.3f} px")
    assert 0.005 < rms < 0.05 and err.max() < 1.0
    assert set(idx) == {0, 1, 2, 3}  # every CCD covered
    assert summary["check_points"] > 0.1 * len(table)
    assert summary["coarse"]["inliers"] > 100


def test_coarse_stage_lands_within_two_pixels(clear_scene):
    lab, truth, dem, dom, img = _open(clear_scene)
    before = truth_error(truth, lab, dem=dem, step_px=24)
    result = coarse_match(img, lab, dem, dom, band="B2")
    after = truth_error(truth, result.model, dem=dem, step_px=24)
    print(f"coarse: {before['rms_px']:.1f} px -> {after['rms_px']:.3f} px rms, max {after['max_px']:.3f}")
    assert before["rms_px"] > 100
    assert after["max_px"] < 2.0


def test_thousand_pixel_offset_and_five_degree_rotation(tmp_path):
    # roll 2.2 degrees ~ 1000 px across track at 30 m, yaw 5 degrees
    d = tmp_path / "far"
    cfg = _config(installation_deg=(2.2, 0.3, 5.0))
    cfg = replace(cfg, reference=replace(cfg.reference, margin_m=1000.0))
    simulate_pushbroom(d, config=cfg)
    lab, truth, dem, dom, img = _open(d)
    before = truth_error(truth, lab, dem=dem, step_px=32)
    result = coarse_match(img, lab, dem, dom, band="B2", max_offset_px=1200)
    after = truth_error(truth, result.model, dem=dem, step_px=32)
    print(f"far: {before['rms_px']:.0f} px -> {after['max_px']:.3f} px max")
    assert before["rms_px"] > 900
    assert after["max_px"] < 2.0


def test_thirty_percent_clouds_still_no_blunder(tmp_path):
    d = tmp_path / "cloudy"
    cfg = _config()
    simulate_pushbroom(d, config=replace(cfg, clouds=replace(cfg.clouds, cover=0.3)))
    lab, truth, dem, dom, img = _open(d)
    table, summary = extract_gcps(lab, img, dem, dom, band="B2", options=MatchOptions(spacing_px=24))
    err, idx = _errors_vs_truth(table, truth)
    print(f"cloudy: {len(table)} GCPs, rms {np.sqrt(np.mean(err**2)):.4f} px, max {err.max():.3f} px, "
          f"cloud fraction {summary['cloud_fraction']:.2f}")
    assert err.max() < 1.0
    assert set(idx) == {0, 1, 2, 3}
    # with the true mask, cloudy windows are named as such
    import rasterio

    with rasterio.open(d / "cloud_mask.tif") as ds:
        mask = ds.read(1) > 0
    _, s2 = extract_gcps(lab, img, dem, dom, band="B2", mask=mask, options=MatchOptions(spacing_px=24))
    assert s2["rejected"]["cloud"] > 0.15 * s2["windows"]


def test_match_cli_writes_csv_gpkg_geotiff_and_summary(clear_scene, tmp_path):
    out = tmp_path / "gcps.csv"
    rc = main(["-q", "match", str(clear_scene / "manifest.json"), "--dom", str(clear_scene / "reference" / "dom.tif"),
               "--dem", str(clear_scene / "reference" / "dem.tif"), "--out", str(out),
               "--gpkg", str(tmp_path / "g.gpkg"), "--geotiff", str(tmp_path / "g.tif")])
    assert rc == 0
    table = read_gcps(out)
    assert len(read_gcps(tmp_path / "g.gpkg")) == len(table)
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["gcps"] + summary["check_points"] == len(table)
    assert {p["ccd"] for p in summary["per_ccd"]} == set(table.ccd)


def test_bad_inputs_fail_cleanly(clear_scene, tmp_path, capsys):
    lab, truth, dem, dom, img = _open(clear_scene)
    # no texture at all
    flat = MapImage.from_array(np.full(dom.grid.shape, 1000, np.uint16), dom.grid.transform, dom.grid.crs)
    with pytest.raises(CoarseMatchError):
        coarse_match(img, lab, dem, flat, band="B2")
    # all clouds: the scene is saturated white
    with pytest.raises(GcpcalError):
        extract_gcps(lab, np.full_like(img, 3400.0), dem, dom, band="B2")
    # unreadable DOM through the CLI: one line, exit 1, no GCP file
    bad = tmp_path / "dom.tif"
    bad.write_text("not a raster")
    out = tmp_path / "g.csv"
    rc = main(["match", str(clear_scene / "manifest.json"), "--dom", str(bad),
               "--dem", str(clear_scene / "reference" / "dem.tif"), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "dom.tif" in err and err.count("\n") == 1 and not out.exists()
    with pytest.raises(InputError):
        MatchOptions(window_px=10).validate()


def test_torch_backend_gives_the_same_gcps(clear_scene):
    pytest.importorskip("torch")
    from gcpmatch.phase import phase_correlate

    lab, truth, dem, dom, img = _open(clear_scene)
    table, summary = extract_gcps(lab, img, dem, dom, band="B2",
                                  options=MatchOptions(spacing_px=32, backend="torch", check_fraction=0.0))
    err, idx = _errors_vs_truth(table, truth)
    print(f"torch backend: {len(table)} GCPs, rms {np.sqrt(np.mean(err**2)):.4f} px, max {err.max():.3f} px")
    assert np.sqrt(np.mean(err**2)) < 0.05 and err.max() < 1.0 and set(idx) == {0, 1, 2, 3}
    # the fine stage alone: same windows, numpy and torch kernels agree within 0.01 px
    rng = np.random.default_rng(3)
    r0 = rng.integers(0, img.shape[0] - 70, 200)
    c0 = rng.integers(0, 160 - 70, 200)
    from gcpmatch.reference import reference_for_ccd

    ref = reference_for_ccd(truth, dem, dom, band="B2", ccd=1)  # windows that correspond
    look = lab.band_ccds("B2")[1]
    scene = img[:, look.first_col : look.first_col + look.n_detectors]
    a = np.stack([ref[r : r + 64, c : c + 64] for r, c in zip(r0, c0)])
    b = np.stack([scene[r + 3 : r + 67, c + 2 : c + 66] for r, c in zip(r0, c0)])
    finite = np.isfinite(a).all(axis=(1, 2))  # the reference has no data over parts of the sea
    a, b = a[finite], b[finite]
    cpu = phase_correlate(a, b, max_shift_px=16)
    tor = phase_correlate(a, b, max_shift_px=16, backend="torch", device="cpu")
    both = cpu.valid & tor.valid
    assert both.sum() > 150
    assert np.abs(cpu.shift_px[both] - tor.shift_px[both]).max() < 0.01


def test_mostly_cloudy_scene_reports_its_cloud_fraction(tmp_path):
    """Issue 12: without a mask the detector's estimate is reported (it said ~4 % at 61 % cloud)."""
    d = tmp_path / "mostly_cloudy"
    cfg = _config()
    truth_summary = simulate_pushbroom(d, config=replace(cfg, clouds=replace(cfg.clouds, cover=0.6)))
    lab, truth, dem, dom, img = _open(d)
    _table, summary = extract_gcps(lab, img, dem, dom, band="B2", options=MatchOptions(spacing_px=24))
    assert abs(summary["cloud_fraction"] - truth_summary["cloud_fraction"]) < 0.1
    worst = max(summary["per_ccd"], key=lambda c: c["cloud_fraction"])
    assert worst["cloud_fraction"] > 0.7
    assert all(c["cause"] is None or c["cause"].startswith("clouds cover") for c in summary["per_ccd"])


def test_cloud_fraction_unknown_when_the_detector_cannot_tell():
    from gcpmatch.clouds import detect_clouds

    rng = np.random.default_rng(0)
    reference = rng.uniform(500, 1500, (200, 120)).astype(np.float32)
    overcast = (3300 + 30 * rng.standard_normal((200, 120))).astype(np.float32)  # no ground seen
    mask, fraction = detect_clouds(overcast, reference)
    assert fraction is None and not mask.any()
    clear = reference * 1.1 + 40
    mask, fraction = detect_clouds(clear, reference)
    assert fraction == 0.0
