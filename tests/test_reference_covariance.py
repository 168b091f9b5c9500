"""Issue 12 item 7 (calibration side): the covariance floor and the reference DOM's common-shift term.

A synthetic push-broom calibration checks that a known common shift of the GCPs' ground points
moves the installation angles by what ``G = (J^T W J)^-1 J^T W A`` predicts, that the term added
to the covariance is ``G Sigma_d G^T``, that a variance factor below 1 no longer shrinks the
covariance (and one above 1 still inflates it), and that the match summary's and the option's
reference accuracy reach ``calibration.json`` through ``gcpcal calibrate``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from calibrate.absolute import calibrate_model
from calibrate.config import CalibrationOptions
from calibrate.reference_covariance import floor_factor
from sensor_models.imaging.ground_shift import ground_shift_jacobian
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi_realistic"
EXTERIOR = ("installation.roll", "installation.pitch", "installation.yaw")
SHIFT_M = np.array([12.0, -8.0])  # east, north


@pytest.fixture(scope="module")
def true_model():
    design = CameraDesign(n_ccds=2, detectors_per_ccd=512, band_names=("B2",), band_offsets_px=(0.0,))
    lab = example_pushbroom_model(n_rows=3000, design=design)
    p = lab.parameters()
    v = p.values.copy()
    pos = {n: i for i, n in enumerate(p.names)}
    for name, deg in (("roll", 0.02), ("pitch", -0.01), ("yaw", 0.05)):
        v[pos[f"installation.{name}"]] += np.radians(deg)
    return lab, lab.with_parameters(v)


def _gcps(true, n=800, noise=0.05, seed=3):
    rng = np.random.default_rng(seed)
    row, col = rng.uniform(1.0, true.n_rows - 1.0, n), rng.uniform(0.5, true.n_cols - 0.5, n)
    ccd = true.ccd_index(col, band="B2")
    lon, lat, h = true.image_to_ground(row, col, height=np.full(n, 300.0), band="B2", array=ccd)
    return row + rng.normal(0, noise, n), col + rng.normal(0, noise, n), lon, lat, h


def _shifted(lon, lat, shift_m):
    """Ground points moved by ``shift_m`` (east, north) metres (local sphere radius is enough here)."""
    r = 6378137.0
    return lon + np.degrees(shift_m[0] / (r * np.cos(np.radians(lat)))), lat + np.degrees(shift_m[1] / r)


def _fit(model, row, col, lon, lat, h, sigma_px, **options):
    table = GcpTable.from_arrays(row, col, lon, lat, h, band="B2", sigma_px=sigma_px)
    return calibrate_model(model, table, options=CalibrationOptions(**options))


def _exterior(result):
    pos = {n: j for j, n in enumerate(result.names)}
    return np.array([result.values[pos[n]] for n in EXTERIOR]), [pos[n] for n in EXTERIOR]


@pytest.mark.parametrize("scheme", ["exterior", "exterior-interior"])
def test_common_ground_shift_moves_roll_and_pitch_as_predicted(true_model, scheme):
    lab, true = true_model
    row, col, lon, lat, h = _gcps(true)
    sigma = (5.0, 5.0)
    base = _fit(lab, row, col, lon, lat, h, 0.05, scheme=scheme, reference_sigma_m=sigma)
    lon_s, lat_s = _shifted(lon, lat, SHIFT_M)
    moved = _fit(lab, row, col, lon_s, lat_s, h, 0.05, scheme=scheme, reference_sigma_m=sigma)
    assert base.success and moved.success, (base.message, moved.message)
    gain = np.array([base.uncertainty["reference_gain_per_m"][n] for n in EXTERIOR])  # rad per m
    predicted = -gain @ SHIFT_M
    actual = _exterior(moved)[0] - _exterior(base)[0]
    sd = base.sigma[_exterior(base)[1]]
    # roll and pitch move by ~1/altitude per metre: many times their noise sigma, and as predicted
    altitude_m = 782_121.0
    for k in (0, 1):
        assert 0.5 * np.linalg.norm(SHIFT_M) / altitude_m < abs(actual[k]) < 2.0 * np.linalg.norm(SHIFT_M) / altitude_m
        assert abs(actual[k] - predicted[k]) < 0.05 * abs(actual[k])
    assert abs(actual[2] - predicted[2]) < 0.2 * abs(actual[2]) + 0.1 * sd[2]
    # the term in the covariance is G Sigma_d G^T on the exterior block
    term = gain @ np.diag(np.square(sigma)) @ gain.T
    without = _fit(lab, row, col, lon, lat, h, 0.05, scheme=scheme)
    idx = _exterior(base)[1]
    np.testing.assert_allclose(base.covariance[np.ix_(idx, idx)] - without.covariance[np.ix_(idx, idx)], term,
                               rtol=1e-6, atol=1e-9 * np.max(term))
    ref_sigma = np.array([base.uncertainty["reference_sigma"][n] for n in EXTERIOR])
    np.testing.assert_allclose(ref_sigma, np.sqrt(np.diag(term)), rtol=1e-9)
    noise_sd = without.sigma[idx]
    assert np.all(ref_sigma[:2] > 10 * noise_sd[:2])  # 5 m at 782 km against 800 GCPs of 0.05 px
    np.testing.assert_allclose(sd, np.sqrt(noise_sd**2 + ref_sigma**2), rtol=1e-9)
    # interior sigmas are untouched by the term (it lives on the exterior block)
    other = [j for j, n in enumerate(base.names) if n not in EXTERIOR]
    np.testing.assert_allclose(np.diag(base.covariance)[other], np.diag(without.covariance)[other], rtol=1e-9)
    assert without.uncertainty["reference_accuracy"]["east_m"] is None


def test_staring_camera_gets_the_term_too():
    """A geostationary staring camera: 100 m east moves the installation by what G predicts (~0.58 arcsec)."""
    from sensor_models.models.synthetic import example_geo_staring_model
    from sensor_models.models.pushbroom_types import Installation

    arcsec = np.pi / 180.0 / 3600.0
    installation = Installation(72 * arcsec, -72 * arcsec, 72 * arcsec)
    truth = example_geo_staring_model(image_shape=(1024, 1024), installation=installation)
    lab = example_geo_staring_model()
    rng = np.random.default_rng(0)
    r, c = rng.uniform(0, 1024, 600), rng.uniform(0, 1024, 600)
    lon, lat, h = truth.image_to_ground(r, c, height=0.0)
    r, c = r + rng.normal(0, 0.1, r.size), c + rng.normal(0, 0.1, c.size)
    opts = CalibrationOptions(reference_sigma_m=(100.0, 100.0))
    base = calibrate_model(lab, GcpTable.from_arrays(r, c, lon, lat, h, sigma_px=0.1), options=opts)
    lon_s, lat_s = _shifted(lon, lat, (100.0, 0.0))
    moved = calibrate_model(lab, GcpTable.from_arrays(r, c, lon_s, lat_s, h, sigma_px=0.1), options=opts)
    assert base.success and moved.success
    gain = np.array([base.uncertainty["reference_gain_per_m"][n] for n in EXTERIOR])
    actual = _exterior(moved)[0] - _exterior(base)[0]
    assert 0.4 * arcsec < abs(actual[1]) < 0.8 * arcsec  # 100 m from ~35 800 km
    assert abs(actual[1] + 100.0 * gain[1, 0]) < 0.02 * abs(actual[1])
    assert base.uncertainty["reference_sigma"]["installation.pitch"] == pytest.approx(100.0 * np.hypot(*gain[1]))


def test_field_part_between_common_shift_and_independent_errors(true_model):
    """A field of infinite correlation length is the common shift; of zero length, independent errors."""
    lab, true = true_model
    pts = _gcps(true, n=400)
    common = _fit(lab, *pts, 0.05, scheme="exterior", reference_sigma_m=(2.0, 2.0))
    floor_only = _fit(lab, *pts, 0.05, scheme="exterior")
    long = _fit(lab, *pts, 0.05, scheme="exterior", reference_sigma_m=(2.0, 2.0), reference_field_m=(1.5, 1e9))
    np.testing.assert_allclose(long.covariance, common.covariance, rtol=1e-6)
    short = _fit(lab, *pts, 0.05, scheme="exterior", reference_sigma_m=(2.0, 2.0), reference_field_m=(1.5, 1e-3))
    reduced = _fit(lab, *pts, 0.05, scheme="exterior", reference_sigma_m=(np.sqrt(4 - 1.5**2),) * 2)
    idx = _exterior(short)[1]
    var = {k: np.diag(r.covariance)[idx] for k, r in (("short", short), ("reduced", reduced), ("none", floor_only),
                                                      ("common", common))}
    # white field: 1.5 m per GCP averages down over 400 GCPs: on roll and pitch under 5 % of a common
    # shift of 1.5 m; on yaw like extra measurement noise of 1.5 m x ~0.02 px/m = 0.03 px against
    # the GCPs' 0.05 px: (0.03 / 0.05)^2 ~ 0.36 of the noise variance
    added = var["short"] - var["reduced"]
    assert np.all(added > 0)
    assert np.all(added[:2] < 0.05 * (var["common"] - var["none"])[:2] * 1.5**2 / 4.0)
    assert 0.15 * var["none"][2] < added[2] < 0.7 * var["none"][2]
    # a 3 km field on a ~75 km scene: yaw, which a common shift leaves alone, grows
    mid = _fit(lab, *pts, 0.05, scheme="exterior", reference_sigma_m=(2.0, 2.0), reference_field_m=(1.5, 3000.0))
    assert np.diag(mid.covariance)[idx][2] > 2.0 * var["common"][2]
    assert mid.uncertainty["reference_field"] == {"rms_m": 1.5, "length_m": 3000.0}
    with pytest.raises(InputError, match="correlation length"):
        CalibrationOptions(reference_field_m=(1.0, 0.0))


def test_ground_shift_jacobian_is_about_one_gsd_per_gsd(true_model):
    _lab, true = true_model
    _row, _col, lon, lat, h = _gcps(true, n=50)
    ccd = true.ccd_index(_col, band="B2")
    a = np.concatenate([ground_shift_jacobian(true, lon[ccd == k], lat[ccd == k], h[ccd == k], band="B2", array=k)
                        for k in np.unique(ccd)])
    # |dA| per metre of shift is about 1 / GSD (50 m pixels at 782 km here): between 0.01 and 0.04 px/m
    norms = np.linalg.norm(a, axis=1)  # per column (east, north): image motion px per m
    assert np.all((norms > 0.01) & (norms < 0.04))


def test_a_variance_factor_below_one_no_longer_shrinks_the_covariance(true_model):
    lab, true = true_model
    pts = _gcps(true, noise=0.05)
    floored = _fit(lab, *pts, 0.2, scheme="exterior")  # stated 4x the noise: vf ~ 1/16
    scaled = _fit(lab, *pts, 0.2, scheme="exterior", covariance_floor=False)
    vf = floored.variance_factor
    assert 0.02 < vf < 0.2
    ratio = np.diag(floored.covariance) / np.diag(scaled.covariance)
    np.testing.assert_allclose(ratio, 1.0 / vf, rtol=1e-9)
    assert floored.uncertainty["covariance_factor"] == 1.0
    assert scaled.uncertainty["covariance_factor"] == pytest.approx(vf)
    # errors larger than stated still inflate it: the floor is a floor
    noisy = _gcps(true, noise=0.2)
    over = _fit(lab, *noisy, 0.05, scheme="exterior")
    over_off = _fit(lab, *noisy, 0.05, scheme="exterior", covariance_floor=False)
    assert over.variance_factor > 5.0
    np.testing.assert_allclose(over.covariance, over_off.covariance, rtol=1e-12)
    assert over.uncertainty["covariance_factor"] == pytest.approx(over.variance_factor)
    # a table stating no sigma_px (the default 1: unit weights) keeps sigma0^2: its scale is the data's
    unit = _fit(lab, *pts, 1.0, scheme="exterior")
    assert unit.uncertainty["covariance_factor"] == pytest.approx(unit.variance_factor) and unit.variance_factor < 0.01
    assert "max(1, sigma0^2)" in floored.to_dict(points=False)["covariance_scaling"]
    assert floor_factor(0.5) == 1.0 and floor_factor(2.0) == 4.0 and floor_factor(float("nan")) == 1.0


def test_reference_sigma_option_is_checked():
    assert CalibrationOptions(reference_sigma_m=2.0).reference_sigma_m == (2.0, 2.0)
    assert CalibrationOptions(reference_sigma_m=(1.0, 3)).reference_sigma_m == (1.0, 3.0)
    for bad in (-1.0, (1.0, float("nan")), (1.0, 2.0, 3.0), "x"):
        with pytest.raises(InputError, match="reference_sigma_m"):
            CalibrationOptions(reference_sigma_m=bad)


# --------------------------------------------------------------------------- plumbing
@pytest.fixture(scope="module")
def matched(tmp_path_factory):
    """``gcpcal match`` of the realistic fixture: gcps.csv and gcps.summary.json (its DOM states 1.4/1.2 m)."""
    from calibrate.cli import main

    folder = tmp_path_factory.mktemp("ref_match")
    assert main(["-q", "match", str(FIXTURE / "manifest.json"), "--dom", str(FIXTURE / "reference" / "dom.tif"),
                 "--dem", str(FIXTURE / "reference" / "dem.tif"), "--out", str(folder / "gcps.csv")]) == 0
    return folder


def _calibrate(capsys, gcps, out, *extra):
    from calibrate.cli import main

    code = main(["-q", "calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(gcps), "--out", str(out),
                 "--no-report", *extra])
    _out, err = capsys.readouterr()
    assert "Traceback" not in err
    assert code in (0, 4), err  # partial: the other bands wait for `gcpcal relative`
    return json.loads((out / "calibration.json").read_text())


def _roll_sigma(doc):
    return next(p["sigma_arcsec"] for p in doc["parameters"] if p["name"] == "installation.roll")


def test_match_summary_and_option_reach_calibration_json(matched, tmp_path, capsys):
    stated = json.loads((matched / "gcps.summary.json").read_text())["reference_accuracy"]
    assert (stated["east_m"], stated["north_m"]) == (1.4, 1.2)
    doc = _calibrate(capsys, matched / "gcps.csv", tmp_path / "from_summary")
    acc = doc["reference_accuracy"]
    assert (acc["east_m"], acc["north_m"]) == (1.4, 1.2) and "gcps.summary.json" in acc["source"]
    # 1.3 m rms over ~800 km: about 0.34 arcsec on roll and pitch, far above their noise sigma
    assert 0.2 < doc["reference_sigma"]["installation.roll"] * 206264.8 < 0.6
    assert doc["covariance_factor"] >= 1.0 and doc["covariance_floor"]["exterior"]["factor_applied"] >= 1.0
    # the option wins over the summary
    opt = _calibrate(capsys, matched / "gcps.csv", tmp_path / "option", "--reference-sigma-m", "3,0.5")
    assert (opt["reference_accuracy"]["east_m"], opt["reference_accuracy"]["north_m"]) == (3.0, 0.5)
    assert opt["reference_accuracy"]["source"] == "option"
    # a table without a summary (older runs, other tools): no reference term, said so
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(matched / "gcps.csv", bare / "gcps.csv")
    none = _calibrate(capsys, bare / "gcps.csv", tmp_path / "none")
    assert none["reference_accuracy"]["east_m"] is None and none["reference_accuracy"]["source"].startswith("none")
    assert none["reference_sigma"] == {}
    assert _roll_sigma(none) < 0.5 * _roll_sigma(doc) < _roll_sigma(opt)
    summary = json.loads((tmp_path / "from_summary" / "calibrate.summary.json").read_text())
    assert summary["reference_accuracy"]["east_m"] == 1.4


def test_bad_reference_sigma_is_a_usage_error(matched, tmp_path, capsys):
    from calibrate.cli import main

    for option, value in (("--reference-sigma-m", "1,a"), ("--reference-sigma-m", "-1"),
                          ("--reference-field-m", "1"), ("--reference-field-m", "1,0")):
        code = main(["calibrate", str(FIXTURE / "manifest.json"), "--gcps", str(matched / "gcps.csv"), "--out",
                     str(tmp_path / "x"), option, value])
        _out, err = capsys.readouterr()
        assert code == 2 and option in err and "Traceback" not in err, (option, value, err)
        assert not (tmp_path / "x").exists()


def test_reference_field_option_reaches_calibration_json(matched, tmp_path, capsys):
    plain = _calibrate(capsys, matched / "gcps.csv", tmp_path / "plain")
    field = _calibrate(capsys, matched / "gcps.csv", tmp_path / "field", "--reference-field-m", "0.8,4000")
    assert field["reference_field"] == {"rms_m": 0.8, "length_m": 4000.0} and "reference_field" not in plain
    yaw = {k: next(p["sigma_arcsec"] for p in d["parameters"] if p["name"] == "installation.yaw")
           for k, d in (("plain", plain), ("field", field))}
    assert yaw["field"] > 1.5 * yaw["plain"]
