"""The star fallback: a fully clouded Earth view is calibrated through star frames instead."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from calibrate.cli import main


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("fallback")
    cfg = root / "geo.json"
    # the Earth view is taken by the star frames' camera (seed 000 optics: 1024 x 1024 px of 25 um behind
    # 1250 mm, 715.72 m at nadir): frames of another camera are refused (tests/test_status_and_inputs.py)
    cfg.write_text(json.dumps({"image_px": 1024, "seed": 5, "pixel_size_mm": 0.025, "gsd_m": 715.72,
                               "dom_resolution_m": 240.0, "dem_resolution_m": 480.0, "margin_m": 20000.0}))
    assert main(["-q", "simulate", "geo-earth", "--out", str(root / "earth"), "--config", str(cfg)]) == 0
    assert main(["-q", "simulate", "geo-stars", "--out", str(root / "stars"), "--frames", "40"]) == 0
    return root


def _dem(scene):
    return ["--dom", str(scene / "reference" / "dom.tif"), "--dem", str(scene / "reference" / "dem.tif")]


def test_clear_scene_takes_the_gcp_path(scenes):
    earth = scenes / "earth"
    out = scenes / "run_clear"
    assert main(["-q", "run", str(earth / "manifest.json"), *_dem(earth), "--out", str(out),
                 "--star-frames", str(scenes / "stars")]) == 0
    s = json.loads((out / "run.summary.json").read_text())
    assert s["path"] == "gcps" and s["success"] and s["check_rmse_px"]["after"] < 0.1


def test_fully_clouded_scene_falls_back_on_stars_and_says_why(scenes):
    earth = scenes / "earth"
    with rasterio.open(earth / "B1.tif") as ds:
        profile, shape = ds.profile, (ds.height, ds.width)
    rng = np.random.default_rng(1)
    cloud = (3300 + 60 * rng.standard_normal(shape)).astype("uint16")  # an overcast, featureless frame
    clouded = scenes / "clouded"
    clouded.mkdir()
    with rasterio.open(clouded / "B1.tif", "w", **profile) as ds:
        ds.write(cloud, 1)
    doc = json.loads((earth / "manifest.json").read_text())
    doc["image"]["raster"]["path"] = str(clouded / "B1.tif")
    (clouded / "manifest.json").write_text(json.dumps(doc))
    out = scenes / "run_cloudy"
    assert main(["-q", "run", str(clouded / "manifest.json"), *_dem(earth), "--out", str(out),
                 "--star-frames", str(scenes / "stars")]) == 0
    s = json.loads((out / "run.summary.json").read_text())
    print(f"fallback: path {s['path']}, reason: {s['reason']}")
    assert s["path"] == "stars" and s["success"]
    assert "matching failed" in s["reason"] or "too few" in s["reason"]
    assert (out / "stars" / "manifest.json").exists()
    # without star frames the run fails, with the reason, exit code 3
    assert main(["-q", "run", str(clouded / "manifest.json"), *_dem(earth), "--out", str(scenes / "run_none")]) == 3
