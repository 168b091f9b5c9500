"""Thermal drift of a staring camera's installation angles (seed 002 section 3.3, figure 11)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from calibrate.schemes.thermal import ARCSEC, DAY_S, evaluate_positioning, fit_installation, with_installation
from calibrate.schemes.thermal_figures import plot_positioning, plot_thermal_angles
from calibrate.schemes.thermal_model import ThermalModel
from calibrate.schemes.thermal_simulation import ThermalDrift, simulate_thermal_series
from sensor_models.errors import InputError
from sensor_models.models.synthetic import example_geo_staring_model

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def lab():
    return example_geo_staring_model()


@pytest.fixture(scope="module")
def experiment(lab):
    """Five days every 30 min; the first four fit the model, the last is held out."""
    drift = ThermalDrift()
    times = np.arange(0.0, 5 * DAY_S, 1800.0)
    series = simulate_thermal_series(lab, times, drift, n_points=400, sigma_px=0.1, seed=1)
    train = times < 4 * DAY_S
    model = ThermalModel.fit(times[train], series.angles[train], series.sigma[train], max_order=4)
    return drift, times, series, train, model


def test_per_epoch_exterior_recovers_the_injected_angles(experiment):
    _, _, series, _, _ = experiment
    assert series.success.all()
    err = (series.angles - series.true_angles) / series.sigma
    # standardized errors: the reported sigmas are honest (chi-square per dof near 1)
    chi2 = np.mean(err ** 2, axis=0)
    assert np.all((0.7 < chi2) & (chi2 < 1.4)), chi2
    rec = series.recovery_arcsec()
    assert np.all((0.005 < rec[:2]) & (rec[:2] < 0.05)), rec  # roll, pitch: 0.1 px of 4.1 arcsec over 400 points
    assert 1.0 < rec[2] < 4.0, rec  # yaw: lever arm of half a frame only


def test_direct_fit_matches_calibrate_model_exterior(lab):
    from calibrate.absolute import calibrate_model
    from calibrate.config import CalibrationOptions
    from gcpmatch.gcps import GcpTable

    truth = with_installation(lab, np.array([40.0, -30.0, 60.0]) * ARCSEC)
    rng = np.random.default_rng(5)
    r, c = rng.uniform(0, 1024, 300), rng.uniform(0, 1024, 300)
    lon, lat, h = truth.image_to_ground(r, c, height=0.0)
    r_obs, c_obs = r + rng.normal(0, 0.1, r.size), c + rng.normal(0, 0.1, c.size)
    fit = fit_installation(lab, r_obs, c_obs, lon, lat, h, sigma_px=0.1)
    gcps = GcpTable.from_arrays(r_obs, c_obs, lon, lat, h, sigma_px=0.1)
    res = calibrate_model(lab, gcps, options=CalibrationOptions(scheme="exterior"))
    assert fit.success and res.success and fit.iterations <= 4
    assert np.all(np.abs(fit.angles - res.values[:3]) < 0.5 * fit.sigma)
    assert np.allclose(fit.sigma, res.sigma[:3], rtol=0.1)
    assert np.all(np.abs(fit.angles - truth.installation.as_array()) < 4 * fit.sigma)
    assert 0.1 < fit.rms_px < 0.2  # sqrt(2) * 0.1


def test_fit_installation_reports_failure_instead_of_raising(lab):
    fit = fit_installation(lab, [1.0, 2.0], [1.0, 2.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0])
    assert not fit.success and "project" in fit.message and np.isnan(fit.angles).all()


def test_daily_curve_recovered_below_one_arcsec(experiment):
    drift, times, series, train, model = experiment
    assert model.cv_scheme == "leave-one-day-out"
    # two injected harmonics: CV picks order 2 (order 1 leaves arcseconds, 3 and 4 add nothing)
    assert list(model.orders) == [2, 2, 2]
    scores = model.cv_scores_arcsec[0]
    assert np.all(scores[1] > 2.5 * scores[2]) and np.all(scores[1, :2] > 10 * scores[2, :2])
    assert np.all(scores[3:] > 0.98 * scores[2])
    curve = model.predict(times[train])
    rms = np.sqrt(np.mean((curve - series.smooth_angles[train]) ** 2, axis=0)) / ARCSEC
    print("curve vs injected, arcsec:", rms)
    assert np.all(rms < 1.0) and np.all(rms > 0.01), rms
    # amplitudes really are tens of arcseconds
    span = np.ptp(series.smooth_angles[train], axis=0) / ARCSEC
    assert np.all(span > 40.0)


def test_prediction_on_a_held_out_day_cuts_positioning_error(lab, experiment):
    _, times, series, train, model = experiment
    test = ~train
    pred, sig = model.predict(times[test], return_sigma=True)
    assert np.all(np.isfinite(sig)) and np.all(sig < 1.0 * ARCSEC)
    rms = np.sqrt(np.mean((pred - series.smooth_angles[test]) ** 2, axis=0)) / ARCSEC
    assert np.all(rms < 1.0), rms
    const = series.angles[train].mean(axis=0)
    err = evaluate_positioning(lab, series.true_angles[test], {"constant": const, "predicted": pred})
    before, after = err["constant_rms_px"], err["predicted_rms_px"]
    print(f"held-out day: constant {before:.3f} px, predicted {after:.3f} px")
    assert 3.0 < before < 20.0
    assert 0.02 < after < 0.3
    assert 1.0 - after / before >= 0.9
    # the truth itself gives zero error (the evaluation is consistent)
    zero = evaluate_positioning(lab, series.true_angles[test][:3], {"truth": series.true_angles[test][:3]})
    assert zero["truth_rms_px"] < 1e-6


def test_temperature_regressor_chosen_when_it_explains_non_periodic_drift():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4 * DAY_S, 3600.0)
    # temperature with a day-to-day amplitude change (eclipse season): not a fixed daily curve
    amp = np.array([10.0, 4.0, 12.0, 6.0])[(t // DAY_S).astype(int)]
    temp = 20.0 + amp * np.cos(2 * np.pi * t / DAY_S - 1.0)
    truth = np.outer(temp - 20.0, [2.0, -1.5, 0.5]) * ARCSEC + np.array([5.0, 0.0, -3.0]) * ARCSEC
    sigma = np.full((t.size, 3), 0.2 * ARCSEC)
    angles = truth + rng.normal(0, 0.2 * ARCSEC, truth.shape)
    m_time = ThermalModel.fit(t, angles, sigma, max_order=3)
    m_temp = ThermalModel.fit(t, angles, sigma, temp, max_order=3)
    assert m_temp.use_temperature.all()
    rms_time = np.sqrt(np.mean((m_time.predict(t) - truth) ** 2, axis=0)) / ARCSEC
    rms_temp = np.sqrt(np.mean((m_temp.predict(t, temp) - truth) ** 2, axis=0)) / ARCSEC
    assert np.all(rms_temp < 0.15) and np.all(rms_temp > 0.005)
    assert np.all(rms_time[:2] > 3.0 * rms_temp[:2])
    with pytest.raises(InputError, match="temperatures"):
        m_temp.predict(t)


def test_short_series_uses_k_fold_and_datetime_times():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 1.5 * DAY_S, 1800.0)
    epoch = np.datetime64("2024-03-01T00:00:00", "ns")
    times = epoch + (t * 1e9).astype("timedelta64[ns]")
    truth = np.stack([20 * np.cos(2 * np.pi * t / DAY_S - k) for k in range(3)], axis=1) * ARCSEC
    angles = truth + rng.normal(0, 0.1 * ARCSEC, truth.shape)
    m = ThermalModel.fit(times, angles, max_order=3, trend_degree=0)
    assert m.cv_scheme.startswith("5-fold")
    assert list(m.orders) == [1, 1, 1]
    rms = np.sqrt(np.mean((m.predict(times) - truth) ** 2)) / ARCSEC
    assert 0.005 < rms < 0.1
    d = json.loads(json.dumps(m.to_dict()))
    assert d["orders"] == {"roll": 1, "pitch": 1, "yaw": 1}


@pytest.mark.parametrize("case, match", [
    ("decreasing", "strictly increasing"),
    ("nan", "NaN"),
    ("few", "too few"),
    ("shape", "shape"),
])
def test_bad_input_is_a_one_line_input_error(case, match):
    t = np.arange(0.0, 3 * DAY_S, 3600.0)
    angles = np.zeros((t.size, 3))
    if case == "decreasing":
        t[5] = t[4]
    elif case == "nan":
        angles[7, 1] = np.nan
    elif case == "few":
        t, angles = t[:10], angles[:10]
    elif case == "shape":
        angles = angles[:, :2]
    with pytest.raises(InputError, match=match) as info:
        ThermalModel.fit(t, angles, max_order=4)
    assert "\n" not in str(info.value)


def test_figures_are_pngs(tmp_path, experiment):
    drift, times, series, train, model = experiment
    p1 = plot_thermal_angles(tmp_path / "angles.png", series, model, train=train, drift=drift)
    errors = {"constant": np.full(4, 5.0), "predicted": np.full(4, 0.1), "constant_rms_px": 5.0,
              "predicted_rms_px": 0.1}
    p2 = plot_positioning(tmp_path / "pos.png", times[:4], errors)
    for p in (p1, p2):
        data = p.read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000


def test_cli_writes_json_and_figures(tmp_path):
    from calibrate.cli.thermal import command

    out = tmp_path / "run"
    res = CliRunner().invoke(command, ["--out", str(out), "--days", "4", "--interval-min", "60",
                                       "--points", "200", "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["positioning_reduction"] > 0.9
    doc = json.loads((out / "thermal.json").read_text())
    assert doc["n_epochs"] == 96 and doc["n_train"] == 72
    for name in doc["figures"]:
        assert (out / name).read_bytes().startswith(PNG)
    bad = CliRunner().invoke(command, ["--out", str(out), "--days", "1", "--holdout-days", "2"])
    assert bad.exit_code != 0
