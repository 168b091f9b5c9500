"""Star-track calibration of a geostationary staring camera (seed 000), end to end on simulations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibrate.config import StarOptions
from calibrate.star_accuracy import radec_errors_px
from calibrate.star_calibration import process_frames
from calibrate.star_frames import load_frame, read_frame_list
from calibrate.star_observations import smooth_track
from sensor_models.errors import InputError
from sensor_models.readers.geo_manifest import read_geo_manifest
from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

#: a star of the default field (Orion-Gemini Milky Way, 2023-08-02 14:40 UTC from 105 E)
ONE_STAR = 30886


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("geo_stars") / "sim"
    summary = simulate_geo_stars(out, n_frames=60, seed=3)
    frames, seconds, manifest = read_frame_list(out)
    lab = read_geo_manifest(manifest)
    result = process_frames(frames, seconds, lab, versus_points=(10, 20))
    return out, summary, result


def test_simulation_matches_seed000_initial_errors(sequence):
    out, summary, _ = sequence
    truth = json.loads((out / "truth.json").read_text())
    assert summary["frames"] == 60 and summary["distinct_stars"] >= 8
    assert summary["initial_error_centre_px"]["ra"] == pytest.approx(-7.0, abs=1e-6)
    assert summary["initial_error_centre_px"]["de"] == pytest.approx(-21.0, abs=1e-6)
    # installation errors of tens of arcseconds
    assert 20.0 < np.abs(truth["installation_error_arcsec"]).max() < 150.0
    truth_model = read_geo_manifest(out / "truth_manifest.json")
    # the error formula (eq. 18-19) is zero for the true model at the rendered positions
    from calibrate.star_calibration import resolve_catalog

    cat = resolve_catalog("hipparcos", 10.0)
    from sensor_models.geometry.star_catalogue import catalog_stars_in_frame

    m5 = truth_model.at_frame(truth["stars"][5]["seconds"])
    idx, vec, row, col = catalog_stars_in_frame(m5, cat, cat.unit_vectors(), 0.0)
    assert idx.size >= 1
    b = np.broadcast_to(m5.body_to_gcrf, (idx.size, 3, 3))
    ra, de, _ = radec_errors_px(truth_model, b, row, col, vec, pixel_rad=truth_model.ifov_rad)
    assert np.abs(ra).max() < 1e-4 and np.abs(de).max() < 1e-4


def test_calibration_recovers_held_out_points(sequence):
    out, _, r = sequence
    assert r.success, r.message
    before, after = r.accuracy["before"], r.accuracy["after"]
    assert r.frames["n_tracks"] >= 8 and r.frames["n_check_points"] == 5 * r.frames["n_tracks"]
    # seed 000 table 3: about -7 and -21 px before calibration
    assert -8.5 < before["ra"]["mean_px"] < -5.5
    assert -22.5 < before["de"]["mean_px"] < -19.5
    for axis in ("ra", "de"):
        assert 0.002 < after[axis]["mean_abs_px"] < 0.3
        assert 0.005 < after[axis]["two_sigma_px"] < 0.8
        assert r.accuracy["joint_after"][axis]["mean_abs_px"] < 0.3
    # the voted offset is the initial error seen in the image (DE ~ rows, RA ~ columns)
    assert r.frames["offset_px"][0] == pytest.approx(-21.0, abs=2.5)
    # figure 8: every subset calibrates to well under a pixel
    assert [v["points_per_track"] for v in r.versus_points] == [10, 20]
    assert all(v["success"] and v["de_mean_abs_px"] < 0.3 for v in r.versus_points)
    d = r.to_dict(points=True)
    json.dumps(d, allow_nan=False)
    assert len(d["points"]["hip"]) == r.frames["n_points"]


def test_calibrated_model_matches_truth_over_the_tracks(sequence):
    out, _, r = sequence
    truth = read_geo_manifest(out / "truth_manifest.json")
    obs = r.observations
    rows = np.linspace(obs.row.min(), obs.row.max(), 9)
    cols = np.linspace(20.0, 1004.0, 9)
    rr, cc = (a.ravel() for a in np.meshgrid(rows, cols))
    # same pixel, same instant: angle between what the two models see, in pixels
    dot = np.sum(r.model.object_vector_gcrf(rr, cc) * truth.object_vector_gcrf(rr, cc), axis=1)
    err_px = np.arccos(np.clip(dot, -1, 1)) / truth.ifov_rad
    lab_dot = np.sum(read_geo_manifest(out / "manifest.json").object_vector_gcrf(rr, cc)
                     * truth.object_vector_gcrf(rr, cc), axis=1)
    assert np.median(np.arccos(np.clip(lab_dot, -1, 1)) / truth.ifov_rad) > 15.0
    assert np.median(err_px) < 0.3 and err_px.max() < 1.0


def test_single_star_per_frame(tmp_path):
    cfg = GeoStarsConfig(n_frames=40, only_hip=(ONE_STAR,), seed=1)
    simulate_geo_stars(tmp_path / "one", config=cfg)
    frames, seconds, manifest = read_frame_list(tmp_path / "one" / "frames.json")
    r = process_frames(frames, seconds, read_geo_manifest(manifest), options=StarOptions(compare_joint=False))
    assert r.frames["n_tracks"] == 1
    assert r.frames["n_detections"] <= len(frames)
    assert r.success, r.message
    for axis in ("ra", "de"):
        assert abs(r.accuracy["before"][axis]["mean_px"]) > 5.0
        assert r.accuracy["after"][axis]["mean_abs_px"] < 0.3


def test_spline_smoothing_reduces_centroid_noise():
    rng = np.random.default_rng(0)
    t = np.arange(28) * 10.0
    true = np.stack([300.0 + 2e-6 * t**2, 10.0 + 3.58 * t + 1e-4 * t**2], -1)
    noisy = true + rng.normal(0.0, 0.1, true.shape)
    smooth = smooth_track(t, noisy, np.ones(t.size, bool), True)
    raw = np.sqrt(np.mean((noisy - true) ** 2))
    fit = np.sqrt(np.mean((smooth - true) ** 2))
    assert 0.01 < fit < 0.6 * raw


def test_bad_inputs(sequence, tmp_path):
    out, _, _ = sequence
    frames, seconds, manifest = read_frame_list(out)
    lab = read_geo_manifest(manifest)
    with pytest.raises(InputError, match="out of time order"):
        process_frames(frames[:3], seconds[[0, 2, 1]], lab)
    rng = np.random.default_rng(0)
    blank = [300.0 + 9.0 * rng.standard_normal(lab.image_shape).astype(np.float32) for _ in range(3)]
    with pytest.raises(InputError, match="no stars detected"):
        process_frames(blank, seconds[:3], lab)
    with pytest.raises(InputError, match="unknown star catalogue"):
        process_frames(frames[:3], seconds[:3], lab, options=StarOptions(catalog="tycho"))
    with pytest.raises(InputError, match="2 times for 3 frames"):
        process_frames(frames[:3], seconds[:2], lab)


def test_cli_round_trip_and_one_line_errors(sequence, tmp_path, capsys):
    from calibrate.cli import main

    out, _, _ = sequence
    assert main(["stars", str(out), "--out", str(tmp_path / "cal")]) == 0
    doc = json.loads((tmp_path / "cal" / "stars.json").read_text())
    assert doc["success"] and doc["accuracy"]["after"]["de"]["mean_abs_px"] < 0.3
    calibrated = read_geo_manifest(tmp_path / "cal" / "manifest.json")
    assert calibrated.parameters().values[0] != read_geo_manifest(out / "manifest.json").parameters().values[0]
    capsys.readouterr()
    assert main(["stars", str(out), "--out", str(tmp_path / "x"), "--catalog", "tycho"]) == 1
    err = capsys.readouterr().err.strip()
    assert "unknown star catalogue" in err and "\n" not in err
    bad = json.loads((out / "frames.json").read_text())
    bad["frames"][1]["seconds"], bad["frames"][2]["seconds"] = 20.0, 10.0
    (tmp_path / "bad.json").write_text(json.dumps({**bad, "manifest": str(out / "manifest.json")}))
    for f in bad["frames"]:
        f["path"] = str(out / f["path"])
    (tmp_path / "bad.json").write_text(json.dumps({**bad, "manifest": str(out / "manifest.json")}))
    assert main(["stars", str(tmp_path / "bad.json"), "--out", str(tmp_path / "y")]) == 1
    err = capsys.readouterr().err
    assert "out of time order" in err and "bad.json: field 'frames[].seconds'" in err  # the file and the field
    bad["frames"][1]["seconds"] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps({**bad, "manifest": str(out / "manifest.json")}))
    assert main(["stars", str(tmp_path / "nan.json"), "--out", str(tmp_path / "z")]) == 1
    err = capsys.readouterr().err
    assert "nan.json: field 'frames[].seconds': frame times must be finite" in err and err.count("\n") == 1
    assert not (tmp_path / "y").exists() and not (tmp_path / "z").exists()


def test_calibrated_manifest_names_the_raster_of_the_lab_manifest(sequence, tmp_path):
    """A LAB manifest naming a frame raster: the calibrated manifest names the same file (relative to it)."""
    from calibrate.cli import main

    out, _, _ = sequence
    doc = json.loads((out / "manifest.json").read_text())
    assert "raster" not in doc["image"]
    doc["image"]["raster"] = {"path": str(out / "frames" / "frame_0000.tif"), "index": 1}
    (tmp_path / "lab.json").write_text(json.dumps(doc))
    assert main(["-q", "stars", str(out), "--manifest", str(tmp_path / "lab.json"), "--out", str(tmp_path / "cal")]) == 0
    written = json.loads((tmp_path / "cal" / "manifest.json").read_text())["image"]["raster"]
    assert (tmp_path / "cal" / written["path"]).resolve() == (out / "frames" / "frame_0000.tif").resolve() and written["index"] == 1
    assert main(["-q", "stars", str(out), "--out", str(tmp_path / "plain")]) == 0
    assert "raster" not in json.loads((tmp_path / "plain" / "manifest.json").read_text())["image"]


def test_simulation_is_deterministic(tmp_path):
    a = simulate_geo_stars(tmp_path / "a", n_frames=3, seed=7)
    b = simulate_geo_stars(tmp_path / "b", n_frames=3, seed=7)
    assert a["installation_error_arcsec"] == b["installation_error_arcsec"]
    for k in range(3):
        name = f"frames/frame_{k:04d}.tif"
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert (tmp_path / "a" / "truth.json").read_text() == (tmp_path / "b" / "truth.json").read_text()
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_truth_error_of_a_star_frame_compares_lines_of_sight(sequence, tmp_path, capsys):
    """A frame pointed at the stars sees no ground: ``gcpcal truth error`` compares the lines of
    sight (each pixel's TRUE GCRF direction projected through the model under test), the same
    figure as projecting the directions by hand, and says so."""
    from calibrate.cli import main

    out, _, _ = sequence
    capsys.readouterr()
    assert main(["truth", "error", str(out / "manifest.json"), "--truth", str(out / "truth_manifest.json"),
                 "--step", "32", "--out", str(tmp_path / "e.json")]) == 0
    said = capsys.readouterr().out
    result = json.loads((tmp_path / "e.json").read_text())
    assert result["compared"] == "lines of sight" and "lines of sight" in said
    truth, lab = read_geo_manifest(out / "truth_manifest.json"), read_geo_manifest(out / "manifest.json")
    n_rows, n_cols = truth.image_shape
    k_r, k_c = (int(np.ceil((n - 1) / 32.0)) + 1 for n in (n_rows, n_cols))  # pixel centres, both ends
    rows, cols = (a.ravel() for a in np.meshgrid(np.linspace(0.5, n_rows - 0.5, k_r),
                                                 np.linspace(0.5, n_cols - 0.5, k_c), indexing="ij"))
    r, c = lab.star_to_image(truth.object_vector_gcrf(rows, cols))
    by_hand = np.hypot(r - rows, c - cols)
    assert result["n_points"] == by_hand.size
    assert result["rms_px"] == pytest.approx(float(np.sqrt(np.mean(by_hand ** 2))), rel=1e-9)
    assert result["rms_px"] > 5.0  # the LAB model is tens of pixels off (seed 000's initial errors)


def test_frames_kept_in_memory_equal_the_written_frames(tmp_path):
    """``frames_out`` holds the values the GeoTIFF frames hold (the profile's errors included),
    writes no frame files nor frame list, and leaves the truth and the manifest as written."""
    from sensor_models.simulate.profiles import get_profile

    profile = get_profile("paper-000", "stars")
    cfg = GeoStarsConfig(n_frames=3, seed=5)
    simulate_geo_stars(tmp_path / "files", config=cfg, profile=profile)
    kept = []
    simulate_geo_stars(tmp_path / "memory", config=cfg, profile=profile, frames_out=kept)
    paths, _, _ = read_frame_list(tmp_path / "files")
    assert len(kept) == 3 and all(f.dtype == np.uint16 for f in kept)
    for path, frame in zip(paths, kept):
        np.testing.assert_array_equal(load_frame(path), frame.astype(np.float32))
    assert not (tmp_path / "memory" / "frames").exists() and not (tmp_path / "memory" / "frames.json").exists()
    for name in ("truth.json", "manifest.json"):
        assert (tmp_path / "memory" / name).read_text() == (tmp_path / "files" / name).read_text()
