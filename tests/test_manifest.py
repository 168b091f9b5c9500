"""The strict JSON scene manifest (format_version 1): reading, writing, and rejecting bad input."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from sensor_models.errors import ManifestError
from sensor_models.models.lab import LabBand, LabCamera, LabCcd, detector_angles
from sensor_models.readers.manifest import write_manifest
from sensor_models.readers import open_scene
from sensor_models.readers.scene import read_manifest, read_manifest_and_rasters

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "fixtures" / "example_pushbroom" / "manifest.json"

ROWS = np.array([0.5, 250.25, 1000.0, 1999.5, 1500.0])
COLS = np.array([0.5, 1023.5, 1024.5, 2047.5, 700.3])


def _load_maker():
    spec = importlib.util.spec_from_file_location("make_example_manifest", ROOT / "fixtures" / "make_example_manifest.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def built():
    return _load_maker().build()


@pytest.fixture(scope="module")
def example():
    return read_manifest(EXAMPLE)


@pytest.fixture(scope="module")
def doc():
    return json.loads(EXAMPLE.read_text(encoding="utf-8"))


def _write(tmp_path, d, name="manifest.json") -> Path:
    p = tmp_path / name
    p.write_text(json.dumps(d), encoding="utf-8")  # json.dumps writes NaN as the bare token NaN
    return p


def _expect_error(path: Path, field: str, *words):
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    msg = str(info.value)
    assert str(path) in msg, msg
    assert field in msg, msg
    for w in words:
        assert w in msg, msg
    assert "\n" not in msg
    return info.value


# --------------------------------------------------------------------------- good input
def test_example_reads_like_the_built_model(example, built):
    assert example.n_rows == built.n_rows == 2000
    assert example.image_shape == built.image_shape
    assert example.reference_band == built.reference_band
    assert example.name == "example_pushbroom"
    for height in (0.0, 2500.0):
        a = example.image_to_ground(ROWS, COLS, height=height)
        b = built.image_to_ground(ROWS, COLS, height=height)
        for x, y in zip(a, b):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
        # and back through both: the same image points to 1e-9 px
        ra, ca = example.ground_to_image(*a)
        rb, cb = built.ground_to_image(*b)
        assert np.max(np.abs(ra - rb)) < 1e-9 and np.max(np.abs(ca - cb)) < 1e-9
        inner = np.array([True, True, False, True, True])  # col 1024.5 lies where the CCDs overlap on the ground
        assert np.max(np.hypot(ra - ROWS, ca - COLS)[inner]) < 1e-6


def test_fixture_is_what_the_maker_writes(built, tmp_path):
    out = write_manifest(built, tmp_path / "m.json")
    assert json.loads(out.read_text()) == json.loads(EXAMPLE.read_text())


def test_round_trip(example, tmp_path):
    rasters = {"B1": tmp_path / "img" / "b1.tif", "B2": {"path": str(tmp_path / "img" / "b2.tif"), "index": 2}}
    out = write_manifest(example, tmp_path / "sub" / "scene.json", rasters=rasters)
    assert out.exists()
    assert [p.name for p in out.parent.iterdir()] == ["scene.json"]  # no temporary left behind
    d = json.loads(out.read_text())
    assert d["image"]["rasters"]["B1"] == {"path": "../img/b1.tif", "index": 1}  # relative to the manifest
    again, listed = read_manifest_and_rasters(out)
    assert listed["B1"]["path"] == str((tmp_path / "img" / "b1.tif").resolve())
    assert listed["B2"]["index"] == 2
    assert open_scene(out).rasters == listed
    a = example.image_to_ground(ROWS, COLS, height=300.0)
    b = again.image_to_ground(ROWS, COLS, height=300.0)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    # writing the read-back model with its rasters gives the same document; without, no rasters
    out2 = write_manifest(again, tmp_path / "sub" / "scene2.json", rasters=listed)
    assert json.loads(out2.read_text()) == d
    bare = json.loads(write_manifest(again, tmp_path / "sub" / "scene3.json").read_text())
    assert "rasters" not in bare["image"] and {**bare, "image": d["image"]} == d


# --------------------------------------------------------------------------- bad input
def test_missing_field(doc, tmp_path):
    d = copy.deepcopy(doc)
    del d["line_timing"]["line_period_s"]
    _expect_error(_write(tmp_path, d), "line_timing.line_period_s", "missing")


def test_zero_line_period_refused(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["line_timing"]["line_period_s"] = 0.0
    _expect_error(_write(tmp_path, d), "line_timing.line_period_s", "non-zero")


def test_unknown_key_top_level(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["comment"] = "hello"
    _expect_error(_write(tmp_path, d), "(root)", "unknown key", "'comment'")


def test_unknown_key_nested(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["orbit"]["acceleration_m_s2"] = []
    _expect_error(_write(tmp_path, d), "'orbit'", "unknown key", "acceleration_m_s2")
    d = copy.deepcopy(doc)
    d["interior"]["bands"]["B3"][1]["gain"] = 1.0
    _expect_error(_write(tmp_path, d), "interior.bands.B3[1]", "unknown key", "gain")


def test_wrong_type(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["image"]["n_rows"] = "2000"
    _expect_error(_write(tmp_path, d), "image.n_rows", "integer")
    d["image"]["n_rows"] = True
    _expect_error(_write(tmp_path, d), "image.n_rows", "integer")


def test_nan_in_orbit(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["orbit"]["position_m"][3][1] = float("nan")
    p = _write(tmp_path, d)
    assert "NaN" in p.read_text()
    _expect_error(p, "orbit.position_m", "NaN")


def test_non_monotonic_attitude_times(doc, tmp_path):
    d = copy.deepcopy(doc)
    s = d["attitude"]["seconds"]
    s[5], s[6] = s[6], s[5]
    _expect_error(_write(tmp_path, d), "attitude.seconds", "increase")


def test_attitude_not_covering_the_image(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["attitude"]["seconds"] = [t + 1e4 for t in d["attitude"]["seconds"]]
    _expect_error(_write(tmp_path, d), "attitude.seconds")


def test_orbit_partly_covering_the_image(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["orbit"]["seconds"] = [t + 30.0 for t in d["orbit"]["seconds"]]  # overlaps, but after the image
    _expect_error(_write(tmp_path, d), "orbit/attitude", "do not cover")


def test_unsupported_version(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["format_version"] = 2
    _expect_error(_write(tmp_path, d), "format_version", "unsupported")


def test_invalid_json(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text('{"format_version": 1,\n "sensor": }', encoding="utf-8")
    with pytest.raises(ManifestError) as info:
        read_manifest(p)
    msg = str(info.value)
    assert str(p) in msg and "JSON" in msg and "line 2" in msg


def test_string_inside_numeric_array(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["orbit"]["seconds"][0] = str(d["orbit"]["seconds"][0])
    _expect_error(_write(tmp_path, d), "orbit.seconds")


# --------------------------------------------------------------------------- lab interior
LAB = {
    "model": "lab",
    "focal_length_mm": 350.0,
    "pixel_size_mm": 0.013,
    "principal_point_mm": [0.01, -0.02],
    "radial_k": [2e-6, 0.0, 0.0],
    "decentering_p": [1e-6, -1e-6],
    "tilt_rad": 1e-3,
    "rotation_rad": 2e-4,
    "bands": {
        "PAN": {
            "offset_mm": [0.05, 0.0],
            "ccds": [
                {"name": "a", "first_col": 0, "n_detectors": 1000, "x_mm": 0.0, "y_mm": -13.0},
                {"name": "b", "first_col": 1000, "n_detectors": 1000, "x_mm": 0.1, "y_mm": 0.0},
            ],
        }
    },
}


def test_lab_interior(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["interior"] = copy.deepcopy(LAB)
    d["image"]["reference_band"] = "PAN"
    model = read_manifest(_write(tmp_path, d))
    assert list(model.bands) == ["PAN"]
    assert model.image_shape == (2000, 2000)
    camera = LabCamera(
        focal_length_mm=350.0,
        pixel_size_mm=0.013,
        bands=(),
        principal_point_mm=(0.01, -0.02),
        radial_k=(2e-6, 0.0, 0.0),
        decentering_p=(1e-6, -1e-6),
        tilt_rad=1e-3,
        rotation_rad=2e-4,
    )
    band = LabBand("PAN", (), (0.05, 0.0))
    for look, spec in zip(model.band_ccds("PAN"), LAB["bands"]["PAN"]["ccds"]):
        ccd = LabCcd(spec["name"], spec["first_col"], spec["n_detectors"], spec["x_mm"], spec["y_mm"])
        assert (look.name, look.first_col, look.n_detectors) == (ccd.name, ccd.first_col, ccd.n_detectors)
        s = np.linspace(0, ccd.n_detectors - 1, 37)
        tx, ty, _, _ = look.look(s)
        ex, ey = detector_angles(camera, band, ccd, s)
        assert np.max(np.abs(tx - ex)) < 1e-9 and np.max(np.abs(ty - ey)) < 1e-9  # cubic fit, << 1 px (3.7e-5 rad)
    # sensible geometry: across-track angles span about n * p / f for each CCD
    a, b = model.band_ccds("PAN")
    ty_a = a.look(np.array([0.0, 999.0]))[1]
    assert abs((ty_a[1] - ty_a[0]) - 999 * 0.013 / 350.0) < 1e-4  # distortion and tilt are small
    lon, lat, h = model.image_to_ground([1000.0], [1000.0], height=0.0)
    assert np.all(np.isfinite(lon)) and np.all(np.isfinite(lat))


def test_lab_interior_is_strict(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["interior"] = copy.deepcopy(LAB)
    d["image"]["reference_band"] = "PAN"
    del d["interior"]["focal_length_mm"]
    _expect_error(_write(tmp_path, d), "interior.focal_length_mm", "missing")
    d["interior"] = copy.deepcopy(LAB)
    d["interior"]["bands"]["PAN"]["ccds"][0]["z_mm"] = 1.0
    _expect_error(_write(tmp_path, d), "interior.bands.PAN.ccds[0]", "unknown key")
