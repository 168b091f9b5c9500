"""Time-varying attitude: the correction's rotation and basis, its Jacobians against finite
differences, recovery of an injected sinusoid from synthetic GCPs, no loss without one, and the
manifest round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibrate.absolute import calibrate_model
from calibrate.attitude import MAX_SEGMENTS, candidate_corrections, jitter_spectrum
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from sensor_models.models.attitude_correction import AttitudeCorrection, rotation_matrices
from sensor_models.errors import InputError, ManifestError
from sensor_models.models.pushbroom_types import Installation
from sensor_models.readers.manifest import read_pushbroom_manifest, write_manifest
from sensor_models.models.synthetic import example_pushbroom_model

N_ROWS = 3000  # 22.6 s of lines at 7.5 ms
JITTER_HZ = 0.5
JITTER_RAD = 30e-6  # about 0.45 px at this camera's ~52 urad IFOV
INSTALLATION_ERROR = Installation(2e-4, -1e-4, 3e-4)


@pytest.fixture(scope="module")
def lab():
    return example_pushbroom_model(n_rows=N_ROWS)


def _span(model):
    return sorted(float(t) for t in model.line_timing.seconds(np.array(model.row_range)))


def _gcps(truth, n=4000, noise_px=0.05, seed=0, named=False):
    """GCPs of ``truth`` at random pixels and heights, observed with Gaussian noise."""
    rng = np.random.default_rng(seed)
    band = truth.reference_band
    rows = rng.uniform(1.0, N_ROWS - 1.0, n)
    cols = rng.uniform(1.0, truth.n_cols - 1.0, n)
    lon, lat, h = truth.image_to_ground(rows, cols, height=rng.uniform(0.0, 1500.0, n), band=band)
    ccd = np.array([c.name for c in truth.band_ccds(band)])[truth.ccd_index(cols, band=band)] if named else None
    return GcpTable.from_arrays(rows + rng.normal(0, noise_px, n), cols + rng.normal(0, noise_px, n), lon, lat, h,
                                band=np.full(n, band), ccd=ccd)  # fmt: skip


def _truth_error(truth, model):
    """RMS and max (px) of the calibrated model against the truth over every 10th line."""
    band = truth.reference_band
    rows, cols = np.meshgrid(np.arange(0.5, N_ROWS, 10.0), np.linspace(0.5, truth.n_cols - 0.5, 24))
    lon, lat, h = truth.image_to_ground(rows.ravel(), cols.ravel(), height=500.0, band=band)
    r, c = model.ground_to_image(lon, lat, h, band=band)
    e = np.hypot(r - rows.ravel(), c - cols.ravel())
    return float(np.sqrt(np.mean(e**2))), float(np.max(e))


# ------------------------------------------------------------------ rotation and basis
def test_rotation_matrices_are_the_installation_convention():
    angles = np.array([[3e-3, -2e-3, 5e-3], [0.2, 0.1, -0.3]])
    c, dc = rotation_matrices(angles)
    for i, a in enumerate(angles):
        inst = Installation(*a)
        np.testing.assert_allclose(c[i], inst.matrix(), atol=1e-15)
        for k in range(3):
            np.testing.assert_allclose(dc[k, i], inst.matrix_derivatives()[k], atol=1e-15)


def test_spline_basis_sums_to_one_and_derivatives_match():
    corr = AttitudeCorrection("spline", -2.0, 20.0, 7)
    t = np.linspace(-2.0, 20.0, 301)
    b, db = corr.basis(t)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-14)
    for kind, n in (("spline", 7), ("drift", 2)):
        corr = AttitudeCorrection(kind, -2.0, 20.0, n)
        h = 1e-5
        fd = (corr.basis(t + h)[0] - corr.basis(t - h)[0]) / (2 * h)
        np.testing.assert_allclose(corr.basis(t)[1][5:-5], fd[5:-5], atol=1e-6)


def test_bad_corrections_name_their_field():
    with pytest.raises(InputError) as err:
        AttitudeCorrection("harmonic", 0.0, 1.0, 3)
    assert err.value.field == "attitude_correction.kind"
    with pytest.raises(InputError) as err:
        AttitudeCorrection("spline", 0.0, 1.0, 4, np.zeros((3, 6)))
    assert err.value.field == "attitude_correction.coefficients_rad"
    with pytest.raises(InputError) as err:
        CalibrationOptions(attitude="wobbly")
    assert err.value.field == "attitude"


# ------------------------------------------------------------------ Jacobians
@pytest.mark.parametrize("kind, n_terms", [("spline", 6), ("drift", 2)])
def test_jacobian_matches_finite_differences(lab, kind, n_terms):
    rng = np.random.default_rng(1)
    corr = AttitudeCorrection(kind, *_span(lab), n_terms)
    corr = corr.with_coefficients(rng.normal(0.0, 20e-6, (3, corr.n_coefficients)))
    model = lab.with_attitude_correction(corr)
    rows, cols = rng.uniform(0, N_ROWS, 40), rng.uniform(0, model.n_cols, 40)
    lon, lat, h = model.image_to_ground(rows, cols, height=300.0)
    names = model.parameter_names()
    # the first and last spline coefficients act mostly in the margin beyond the image
    last = f"k{corr.n_coefficients - 1}"
    inner = [n for n in names if n.startswith("attitude.") and (kind == "drift" or not n.endswith((".k0", last)))]
    chosen = inner[::2] + ["installation.pitch"]
    _, _, jac = model.image_jacobian(lon, lat, h, names=chosen)
    x0 = model.parameters().values
    step = 1e-7
    for j, name in enumerate(chosen):
        xp, xm = x0.copy(), x0.copy()
        xp[names.index(name)] += step
        xm[names.index(name)] -= step
        rp, cp = model.with_parameters(xp).ground_to_image(lon, lat, h)
        rm, cm = model.with_parameters(xm).ground_to_image(lon, lat, h)
        fd = np.stack([rp - rm, cp - cm], axis=-1) / (2 * step)
        scale = np.abs(jac[:, :, j]).max()
        assert scale > 100.0, name  # pixels per radian: a live derivative
        assert np.abs(fd - jac[:, :, j]).max() < 1e-5 * scale + 2e-3, name  # 2e-3: FD round-off
    # the angle Jacobian of a coefficient is that of the angles times its basis function
    _, _, jd = model.attitude_angle_jacobian(lon, lat, h)
    basis, _ = corr.basis(model.line_timing.seconds(model.ground_to_image(lon, lat, h)[0]))
    k = int(chosen[1].rsplit("k", 1)[1])
    axis = ("roll", "pitch", "yaw").index(chosen[1].split(".")[1])
    np.testing.assert_allclose(jac[:, :, 1], jd[:, :, axis] * basis[:, k : k + 1], rtol=1e-9, atol=1e-6)


def test_projection_round_trip_with_a_correction(lab):
    corr = AttitudeCorrection("spline", *_span(lab), 9)
    model = lab.with_attitude_correction(corr.with_coefficients(np.full((3, 12), 40e-6) * np.sin(np.arange(12))))
    rows, cols = np.linspace(1, N_ROWS - 1, 50), np.linspace(1, model.n_cols - 1, 50)
    lon, lat, h = model.image_to_ground(rows, cols, height=200.0)
    r, c = model.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(r, rows, atol=1e-7)
    np.testing.assert_allclose(c, cols, atol=1e-7)
    r0, _ = lab.ground_to_image(lon, lat, h)
    assert np.abs(r0 - rows).max() > 0.3  # the correction moves the projections


# ------------------------------------------------------------------ recovery
@pytest.fixture(scope="module")
def jitter_case(lab):
    truth = example_pushbroom_model(
        n_rows=N_ROWS, installation=INSTALLATION_ERROR,
        attitude_kwargs=dict(jitter_amplitude_rad=(JITTER_RAD, JITTER_RAD, 0.0), jitter_frequency_hz=JITTER_HZ, seed=3))
    gcps = _gcps(truth)
    static = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="static"))
    auto = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="auto"))
    return truth, static, auto


def test_recovers_an_injected_sinusoid(jitter_case):
    truth, static, auto = jitter_case
    assert static.success and auto.success
    assert static.model.attitude_correction is None and auto.attitude["selected"]["kind"] == "spline"
    rms_static, max_static = _truth_error(truth, static.model)
    rms_auto, max_auto = _truth_error(truth, auto.model)
    assert rms_static > 0.3  # the jitter matters to the static model ...
    assert rms_auto < rms_static / 10.0 and max_auto < 0.1  # ... and is removed
    t_img = sorted(truth.line_timing.seconds(np.array([0.0, N_ROWS])))
    peaks = jitter_spectrum(auto.model.attitude_correction, *t_img)["axes"]
    for axis in ("roll", "pitch"):
        peak = peaks[axis]["peak"]
        assert abs(peak["amplitude_urad"] / (JITTER_RAD * 1e6) - 1.0) < 0.2, (axis, peak)
        assert abs(peak["frequency_hz"] / JITTER_HZ - 1.0) < 0.05, (axis, peak)
    assert auto.attitude["jitter"]["roll"]["frequency_hz"] == pytest.approx(peaks["roll"]["peak"]["frequency_hz"])


def test_no_jitter_keeps_the_static_accuracy(lab):
    truth = example_pushbroom_model(n_rows=N_ROWS, installation=INSTALLATION_ERROR)
    gcps = _gcps(truth, seed=5)
    static = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="static"))
    auto = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="auto"))
    # the orbit's own smooth error remains: a drift-like correction (few effective parameters)
    # or none, never a wiggly one
    assert auto.attitude["selected"]["edf"] < 12.0
    assert auto.attitude["smoothing"]["n_segments"] >= 100  # a dense P-spline was tried
    rms_static, _ = _truth_error(truth, static.model)
    rms_auto, _ = _truth_error(truth, auto.model)
    assert rms_auto <= 1.05 * rms_static


def test_drift_mode_recovers_a_drift(lab):
    drift = (4e-6, -3e-6, 0.0)  # rad/s: 90 and 68 urad over the scene
    truth = example_pushbroom_model(n_rows=N_ROWS, installation=INSTALLATION_ERROR,
                                    attitude_kwargs=dict(drift_rad_s=drift))
    gcps = _gcps(truth, n=1500, seed=7)
    static = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="static"))
    result = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="drift"))
    corr = result.model.attitude_correction
    assert corr is not None and corr.kind == "drift"
    t = np.array(sorted(truth.line_timing.seconds(np.array([0.0, N_ROWS]))))
    rate = np.diff(corr.angles(t), axis=0)[0] / np.diff(t)[0]
    np.testing.assert_allclose(rate[:2], drift[:2], rtol=0.1)
    assert _truth_error(truth, result.model)[0] < _truth_error(truth, static.model)[0] / 5.0


def test_candidates_follow_the_mode_and_the_data():
    assert candidate_corrections("static", 0.0, 10.0, n_points=10_000, n_lines=2000) == [None]
    drift = candidate_corrections("drift", 0.0, 10.0, n_points=10_000, n_lines=2000)
    assert [c and (c.kind, c.n_terms) for c in drift] == [None, ("drift", 1), ("drift", 2)]
    # the P-spline's knots follow the observations' distinct lines (twice as many segments),
    # bounded by 4 lines per segment and MAX_SEGMENTS: no GCPs-per-coefficient cap
    rows = np.random.default_rng(0).uniform(0, 2000, 100)
    few = candidate_corrections("spline", 0.0, 10.0, n_points=100, n_lines=2000, seconds=rows * 10.0 / 2000)
    assert [c and c.kind for c in few] == [None, "spline"]
    assert few[1].n_terms == 2 * np.unique(np.floor(rows)).size
    grid = np.repeat(np.arange(12.0, 2000.0, 24.0), 40)  # matched GCPs on rows every 24 lines
    rowed = candidate_corrections("spline", 0.0, 10.0, n_points=grid.size, n_lines=2000, seconds=grid * 10.0 / 2000)
    assert rowed[1].n_terms == 2 * 83
    many = candidate_corrections("auto", 0.0, 10.0, n_points=100_000, n_lines=2000)
    assert [c and c.kind for c in many] == [None, "drift", "drift", "spline"] and many[-1].n_terms == MAX_SEGMENTS
    short = candidate_corrections("auto", 0.0, 10.0, n_points=100_000, n_lines=200)
    assert short[-1].n_terms == 50  # 4 lines per segment


def test_report_shows_the_correction_and_its_spectrum(jitter_case, tmp_path):
    from calibrate.report.attitude import figure_attitude, section_attitude

    _, static, auto = jitter_case
    fig = figure_attitude(auto, tmp_path)
    png = tmp_path / "attitude.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    html = section_attitude(auto, fig)
    assert "spline" in html and "attitude.png" in html and "frequency (Hz)" in html
    assert figure_attitude(static, tmp_path / "none") is None
    assert "Static attitude" in section_attitude(static, None)
    # the injected jitter is on roll and pitch only: they are observed, yaw's correction is not
    from calibrate.report.attitude import attitude_observability

    verdicts = {o["axis"]: o for o in attitude_observability(auto)}
    print({a: (round(o["rms_urad"], 3), round(o["sigma_urad"], 3), o["verdict"]) for a, o in verdicts.items()})
    assert verdicts["roll"]["verdict"] == verdicts["pitch"]["verdict"] == "observed"
    assert verdicts["yaw"]["verdict"] != "observed" and "not clearly above its own uncertainty" in html
    doc = auto.to_dict(points=False)
    assert doc["attitude"]["selected"]["kind"] == "spline"
    assert abs(doc["attitude"]["jitter"]["pitch"]["amplitude_urad"] - JITTER_RAD * 1e6) < 0.2 * JITTER_RAD * 1e6
    json.dumps(doc)  # strict JSON


# ------------------------------------------------------------------ manifest
def test_manifest_round_trip(lab, tmp_path):
    corr = AttitudeCorrection("spline", *_span(lab), 5)
    coef = np.arange(24, dtype=float).reshape(3, 8) * 1.5e-6
    model = lab.with_attitude_correction(corr.with_coefficients(coef))
    path = write_manifest(model, tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert doc["attitude_correction"]["kind"] == "spline"
    assert doc["attitude_correction"]["coefficients_urad"]["pitch"][1] == pytest.approx(coef[1, 1] * 1e6)
    back = read_pushbroom_manifest(path)
    np.testing.assert_allclose(back.attitude_correction.coefficients_rad, coef, rtol=1e-12, atol=1e-18)
    assert back.parameter_names() == model.parameter_names()
    lon, lat, h = model.image_to_ground([100.0, 2500.0], [300.0, 1700.0], height=0.0)
    np.testing.assert_allclose(np.array(back.ground_to_image(lon, lat, h)), [[100.0, 2500.0], [300.0, 1700.0]],
                               atol=1e-7)  # fmt: skip
    # without the field the same file describes another (uncorrected) model
    del doc["attitude_correction"]
    (tmp_path / "plain.json").write_text(json.dumps(doc))
    plain = read_pushbroom_manifest(tmp_path / "plain.json")
    assert plain.attitude_correction is None
    assert np.abs(plain.ground_to_image(lon, lat, h)[0] - [100.0, 2500.0]).max() > 0.05
    # a malformed field names itself
    doc["attitude_correction"] = {**corr.to_dict(), "knots": 3}
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ManifestError) as err:
        read_pushbroom_manifest(tmp_path / "bad.json")
    assert "attitude_correction.knots" in str(err.value)


# ------------------------------------------------------------------ command line
def test_calibrate_command_writes_the_correction(jitter_case, lab, tmp_path, capsys):
    from calibrate.cli import main
    from gcpmatch.gcp_csv import write_gcps_csv

    truth, _, _ = jitter_case
    scene = write_manifest(lab, tmp_path / "lab.json")
    gcps = tmp_path / "gcps.csv"
    write_gcps_csv(_gcps(truth, n=2500, seed=9, named=True), gcps)
    for mode in ("static", "auto"):
        code = main(["-q", "calibrate", str(scene), "--gcps", str(gcps), "--out", str(tmp_path / mode),
                     "--attitude", mode, "--no-report"])  # fmt: skip
        assert code in (0, 4), capsys.readouterr().err
    static = json.loads((tmp_path / "static" / "manifest.json").read_text())
    auto = json.loads((tmp_path / "auto" / "manifest.json").read_text())
    assert "attitude_correction" not in static and auto["attitude_correction"]["kind"] == "spline"
    cal = json.loads((tmp_path / "auto" / "calibration.json").read_text())
    assert cal["attitude"]["selected"]["kind"] == "spline" and cal["attitude"]["mode"] == "auto"
    calibrated = read_pushbroom_manifest(tmp_path / "auto" / "manifest.json")
    assert _truth_error(truth, calibrated)[0] < 0.1 < _truth_error(truth, read_pushbroom_manifest(
        tmp_path / "static" / "manifest.json"))[0]  # fmt: skip
    assert main(["calibrate", str(scene), "--gcps", str(gcps), "--out", str(tmp_path / "x"), "--attitude", "wobbly"]) == 2


# ------------------------------------------------------------------ beyond the observations
def test_a_held_spline_keeps_its_end_values_outside_its_span():
    rng = np.random.default_rng(4)
    coef = rng.normal(0.0, 5e-6, (3, 9))
    held = AttitudeCorrection("spline", 2.0, 8.0, 6, coef, outside="hold")
    free = AttitudeCorrection("spline", 2.0, 8.0, 6, coef)
    inside = np.linspace(2.0, 8.0, 50)
    np.testing.assert_array_equal(held.angles(inside), free.angles(inside))
    before, after = np.array([0.0, 1.0, 1.9]), np.array([8.1, 9.0, 20.0])
    a, rate = held.angles(np.r_[before, after], derivative=True)
    np.testing.assert_allclose(a[:3], np.repeat(held.angles([2.0]), 3, axis=0), atol=1e-18)
    np.testing.assert_allclose(a[3:], np.repeat(held.angles([8.0]), 3, axis=0), atol=1e-18)
    assert np.all(rate == 0.0)
    assert np.max(np.abs(free.angles(after) - a[3:])) > 1e-6  # the cubic would have run away
    # the coefficient Jacobian is the basis at the held time (linear in the coefficients)
    b, _ = held.basis(after)
    np.testing.assert_allclose(np.einsum("nk,ak->na", b, coef), a[3:], atol=1e-18)


def test_outside_key_round_trips_and_is_checked():
    held = AttitudeCorrection("spline", 0.0, 1.0, 4, outside="hold")
    d = held.to_dict()
    assert d["outside"] == "hold" and AttitudeCorrection.from_dict(d).outside == "hold"
    free = AttitudeCorrection("spline", 0.0, 1.0, 4).to_dict()
    assert "outside" not in free and AttitudeCorrection.from_dict(free).outside == "continue"
    with pytest.raises(InputError, match="outside"):
        AttitudeCorrection.from_dict({**d, "outside": "wrap"})
    with pytest.raises(InputError, match="outside"):
        AttitudeCorrection("spline", 0.0, 1.0, 4, outside="extrapolate")


def test_lines_beyond_the_last_gcp_are_not_extrapolated(lab):
    """GCPs leave the first and last 150 lines bare: the spline spans the GCPs and holds its ends."""
    truth = example_pushbroom_model(
        n_rows=N_ROWS, installation=INSTALLATION_ERROR,
        attitude_kwargs=dict(jitter_amplitude_rad=(JITTER_RAD, JITTER_RAD, 0.0), jitter_frequency_hz=JITTER_HZ, seed=3))
    gcps = _gcps(truth, seed=11)
    keep = (gcps.row > 150.0) & (gcps.row < N_ROWS - 150.0)
    result = calibrate_model(lab, gcps.select(keep), options=CalibrationOptions(attitude="auto"))
    corr = result.model.attitude_correction
    assert corr.kind == "spline" and corr.outside == "hold"
    seconds = truth.line_timing.seconds(gcps.row[keep])
    assert (corr.t0_s, corr.t1_s) == pytest.approx((seconds.min(), seconds.max()))
    ends = _end_error(truth, result.model)
    continued = _end_error(truth, result.model.with_attitude_correction(
        AttitudeCorrection(corr.kind, corr.t0_s, corr.t1_s, corr.n_terms, corr.coefficients_rad)))
    # held: at most the jitter's own swing over the bare second (2 x 30 urad / 52 urad IFOV =
    # 1.15 px peak to peak) plus the fit; measured 1.14 px held, 8.3 px continued
    assert ends < 1.25
    assert continued > 5.0 * ends


def _end_error(truth, model, bare=150):
    band = truth.reference_band
    rows = np.r_[np.arange(0.5, bare, 5.0), np.arange(N_ROWS - bare + 0.5, N_ROWS, 5.0)]
    rows, cols = np.meshgrid(rows, np.linspace(0.5, truth.n_cols - 0.5, 12))
    lon, lat, h = truth.image_to_ground(rows.ravel(), cols.ravel(), height=500.0, band=band)
    r, c = model.ground_to_image(lon, lat, h, band=band)
    return float(np.max(np.hypot(r - rows.ravel(), c - cols.ravel())))
