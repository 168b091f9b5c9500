"""Rendering through a given push-broom model (``gcpcal simulate pushbroom --model``) and model windows."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from calibrate.cli import main
from sensor_models.errors import InputError
from sensor_models.models.pushbroom_window import shifted_polynomial, window_model
from sensor_models.readers.manifest import write_manifest
from sensor_models.readers.scene import read_manifest
from sensor_models.simulate.pushbroom_sim import perturbed_model, simulate_through_model
from sensor_models.simulate.scene import build_models
from sensor_models.simulate.truth import truth_error
from tests.test_simulate import small_config, write_reference


def test_shifted_polynomial_is_the_change_of_variable():
    c = np.array([0.1, -2e-5, 3e-9, -4e-13])
    s = np.linspace(0.0, 500.0, 11)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(s, shifted_polynomial(c, 700.0)),
                               np.polynomial.polynomial.polyval(s + 700.0, c), rtol=0, atol=1e-15)


def test_a_window_localizes_as_the_whole_model_at_shifted_pixels():
    model = build_models(small_config()).lab_model
    n_rows, n_cols = model.image_shape
    row0, col0, rows, cols = 40, 150, 100, 100  # across a CCD boundary: two CCDs per band kept
    win = window_model(model, row0, col0, rows, cols)
    assert win.image_shape == (rows, cols)
    assert all(len(win.band_ccds(b)) == 2 for b in win.bands)
    for band in win.bands:
        for k, ccd in enumerate(win.band_ccds(band)):
            r = np.array([0.5, 50.2, 99.5])
            c = ccd.first_col + np.array([0.5, 0.5 * ccd.n_detectors, ccd.n_detectors - 0.5])
            a = np.array(win.image_to_ground(r, c, height=500.0, band=band, array=k))
            full_ccd = [i for i, f in enumerate(model.band_ccds(band)) if f.name == ccd.name][0]
            b = np.array(model.image_to_ground(r + row0, c + col0, height=500.0, band=band, array=full_ccd))
            assert np.abs(a[:2] - b[:2]).max() < 1e-10 and np.abs(a[2] - b[2]).max() < 1e-6
    with pytest.raises(InputError, match="does not lie inside"):
        window_model(model, 0, 0, n_rows + 1, 10)


def test_the_perturbed_model_carries_the_configured_errors():
    cfg = small_config()
    model = build_models(cfg).lab_model
    true_model, record = perturbed_model(model, cfg)
    assert np.allclose(record["installation_rad"], np.radians(cfg.errors.installation_deg))
    assert true_model.attitude_correction is not None and true_model.attitude_correction.kind == "drift"
    ccd, true_ccd = model.band_ccds()[0], true_model.band_ccds()[0]
    np.testing.assert_allclose(true_ccd.tan_psi_y * cfg.errors.focal_length_ratio, ccd.tan_psi_y)
    # the drift's rate: the correction's angles change by rate x time
    t = model.line_timing.seconds(np.array([0.0, float(model.n_rows)]))
    angles = true_model.attitude_correction.angles(t)
    rate = np.radians(np.asarray(cfg.errors.attitude_drift_arcsec_s) / 3600.0)
    np.testing.assert_allclose((angles[1] - angles[0]) / (t[1] - t[0]), rate, rtol=1e-9, atol=1e-15)


def test_rendering_through_a_given_model_writes_it_as_delivered(tmp_path):
    cfg = small_config()
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    given = window_model(build_models(cfg).lab_model, 20, 100, 128, 180)
    summary = simulate_through_model(tmp_path / "scene", given, dom=p_dom, dem=p_dem, config=cfg,
                                     source={"window": [20, 100, 128, 180]})
    delivered = read_manifest(tmp_path / "scene" / "manifest.json")
    true_model = read_manifest(tmp_path / "scene" / "truth_manifest.json")
    assert truth_error(given, delivered, heights_m=(0.0, 1000.0))["max_px"] < 1e-6
    expected, _ = perturbed_model(given, cfg)
    assert truth_error(expected, true_model, heights_m=(0.0, 1000.0))["max_px"] < 1e-6
    assert summary["image"] == {"n_rows": 128, "n_cols": 180, "bands": ["B1", "B2"], "ccds": 2}
    assert summary["lab_truth_error_px"]["rms"] > 10.0  # the configured errors are there
    assert json.loads((tmp_path / "scene" / "truth.json").read_text())["source"] == {"window": [20, 100, 128, 180]}
    with rasterio.open(tmp_path / "scene" / "B2.tif") as ds:
        assert ds.shape == (128, 180) and ds.read(1).std() > 50


def test_cli_renders_through_a_model_file_and_refuses_a_window_alone(tmp_path, capsys):
    cfg = small_config()
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    write_manifest(build_models(cfg).lab_model, tmp_path / "product.json")
    out = tmp_path / "scene"
    assert main(["-q", "simulate", "pushbroom", "--model", str(tmp_path / "product.json"), "--window",
                 "10,100,96,150", "--dom", str(p_dom), "--dem", str(p_dem), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "96 x 150 px, 2 bands, 2 CCDs; delivered model (manifest.json) off by" in printed
    assert read_manifest(out / "manifest.json").image_shape == (96, 150)
    assert main(["-q", "simulate", "pushbroom", "--window", "0,0,10,10", "--out", str(tmp_path / "x")]) == 1
    assert "give --model" in capsys.readouterr().err
    assert main(["-q", "simulate", "pushbroom", "--model", str(tmp_path / "product.json"), "--window", "0,0,10",
                 "--dom", str(p_dom), "--dem", str(p_dem), "--out", str(tmp_path / "y")]) == 2
