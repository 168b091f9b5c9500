"""Earth views of the geostationary staring camera: simulate, match, calibrate, against the truth."""

from __future__ import annotations

import json

import pytest

from calibrate.cli import main


@pytest.fixture(scope="module")
def frame(tmp_path_factory):
    out = tmp_path_factory.mktemp("geo")
    cfg = out / "cfg.json"
    cfg.write_text(json.dumps({"image_px": 384, "seed": 11}))
    assert main(["-q", "simulate", "geo-earth", "--out", str(out / "scene"), "--config", str(cfg)]) == 0
    return out


def test_lab_model_is_tens_of_pixels_off_and_calibration_brings_it_below_a_tenth(frame, capsys):
    scene = frame / "scene"
    summary = json.loads((scene / "summary.json").read_text())
    assert 10.0 < summary["lab_truth_error_px"]["rms"] < 100.0
    assert main(["-q", "match", str(scene / "manifest.json"), "--dom", str(scene / "reference" / "dom.tif"),
                 "--dem", str(scene / "reference" / "dem.tif"), "--out", str(frame / "gcps.csv"), "--spacing", "16"]) == 0
    assert main(["-q", "calibrate", str(scene / "manifest.json"), "--gcps", str(frame / "gcps.csv"),
                 "--out", str(frame / "cal"), "--no-report"]) == 0
    capsys.readouterr()
    assert main(["truth", "error", str(frame / "cal" / "manifest.json"), "--truth", str(scene / "truth_manifest.json"),
                 "--dem", str(scene / "reference" / "dem.tif"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    print(f"geo earth view: {summary['lab_truth_error_px']['rms']:.1f} -> {result['rms_px']:.4f} px rms "
          f"(max {result['max_px']:.4f})")
    assert 0.0005 < result["rms_px"] <= 0.1 and result["max_px"] < 0.5


def test_bad_geo_configuration_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"image_pixels": 100}))
    assert main(["simulate", "geo-earth", "--out", str(tmp_path / "x"), "--config", str(cfg)]) == 1
    err = capsys.readouterr().err
    assert "image_pixels" in err and err.count("\n") == 1


def test_seed000_camera_earth_view(tmp_path, capsys):
    """Seed 000's camera (1250 mm, 25 um pixels: 716 m at nadir) over a 250 m reference."""
    cfg = tmp_path / "seed000.json"
    cfg.write_text(json.dumps({"pixel_size_mm": 0.025, "gsd_m": 715.7, "image_px": 384, "dom_resolution_m": 250,
                               "dem_resolution_m": 500, "margin_m": 30000, "installation_arcsec": [40, -30, 60]}))
    scene = tmp_path / "scene"
    assert main(["-q", "simulate", "geo-earth", "--out", str(scene), "--config", str(cfg)]) == 0
    ref = ["--dom", str(scene / "reference" / "dom.tif"), "--dem", str(scene / "reference" / "dem.tif")]
    assert main(["-q", "match", str(scene / "manifest.json"), *ref, "--out", str(tmp_path / "g.csv"), "--spacing", "16"]) == 0
    assert main(["-q", "calibrate", str(scene / "manifest.json"), "--gcps", str(tmp_path / "g.csv"),
                 "--out", str(tmp_path / "cal"), "--no-report"]) == 0
    capsys.readouterr()
    assert main(["truth", "error", str(tmp_path / "cal" / "manifest.json"), "--truth", str(scene / "truth_manifest.json"),
                 "--dem", str(scene / "reference" / "dem.tif"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["rms_px"] <= 0.1
