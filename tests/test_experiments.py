"""Seed experiments and their error profiles: ``gcpcal experiment``, staring/thermal/star truths.

The experiment runs use ``--quick`` through the real CLI (files written, read back). Figures
are bracketed from both sides: ``ideal`` stays as good as today's simulator, ``realistic`` is
worse by a bounded amount, and the tables carry the papers' numbers as typed in from the seeds.
"""

from __future__ import annotations

import hashlib
import inspect
import json
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from calibrate.cli import main
from sensor_models.simulate.profiles import KIND_PROFILES, PROFILES, Sourced, get_profile, profile_table


def _run(tmp_path, seed, profile, capsys):
    out = tmp_path / f"e{seed}_{profile}"
    assert main(["-q", "experiment", seed, "--profile", profile, "--out", str(out), "--quick"]) == 0
    capsys.readouterr()
    doc = json.loads((out / "experiment.json").read_text())
    for name in doc["files"]:
        assert (out / name).stat().st_size > 0, name
    html = (out / "report.html").read_text()
    assert "Paper beside ours" in html and doc["tables"][0]["source"] in html
    assert doc["curves"] and all(len(c["x"]) >= 2 for c in doc["curves"])
    for c in doc["curves"]:
        data = json.loads((out / "sensitivity" / f"{c['name']}.json").read_text())
        assert data["profile"] == profile and len(data["x"]) == len(next(iter(data["series"].values())))
    return doc


def _cell(doc, label, column, table=0):
    t = doc["tables"][table]
    row = next(r for r in t["rows"] if r[0] == label)
    return row[list(t["columns"]).index(column)]


# --------------------------------------------------------------------------- profiles
def test_every_kind_has_ideal_realistic_and_its_paper_profile_with_sources():
    papers = {"pushbroom": "paper-003", "staring": "paper-002", "thermal": "paper-002", "stars": "paper-000",
              "oalr": "paper-004"}
    for kind, table in KIND_PROFILES.items():
        assert set(table) == {"ideal", "realistic", papers[kind]}, kind
        for profile in table.values():
            assert profile.kind == kind and get_profile(profile.name, kind) is profile
            rows = profile_table(profile)
            assert len(rows) == sum(isinstance(getattr(profile, f.name), Sourced) for f in fields(profile)) >= 3
            assert all(src and unit and model for _, _, unit, model, src in rows)
    assert KIND_PROFILES["pushbroom"] is PROFILES
    with pytest.raises(Exception, match="unknown profile kind 'nope'"):
        get_profile("ideal", "nope")
    with pytest.raises(Exception, match="unknown profile 'paper-003'"):
        get_profile("paper-003", "stars")


def test_ideal_profiles_record_todays_defaults():
    from calibrate.schemes.autocollimation import render_cross
    from calibrate.schemes.thermal_simulation import ThermalDrift
    from sensor_models.simulate.star_sky import GeoStarsConfig

    stars, cfg = get_profile("ideal", "stars"), GeoStarsConfig()
    for name in ("attitude_noise_arcsec", "attitude_jitter_arcsec", "attitude_jitter_hz", "attitude_drift_arcsec_s"):
        assert stars.value(name) == getattr(cfg, name), name
    assert get_profile("ideal", "thermal").value("epoch_noise_arcsec") == ThermalDrift().noise_arcsec
    defaults = {k: p.default for k, p in inspect.signature(render_cross).parameters.items()}
    oalr = get_profile("ideal", "oalr")
    for name in ("amplitude_e", "background_e", "read_noise_e", "psf_sigma_px"):
        assert oalr.value(name) == defaults[name], name
    # realistic magnitudes are the ranges, not tuned
    assert 3.0 <= get_profile("realistic", "thermal").value("day_to_day_arcsec") <= 6.0
    assert get_profile("realistic", "stars").value("attitude_noise_arcsec") == 1.0


# --------------------------------------------------------------------------- truths
def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.name != "summary.json":
            h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


def test_star_profile_ideal_is_todays_sequence_and_realistic_differs(tmp_path):
    from sensor_models.simulate.star_sky import simulate_geo_stars

    kw = dict(n_frames=3, seed=3, image_shape=(256, 256))
    simulate_geo_stars(tmp_path / "none", **kw)
    simulate_geo_stars(tmp_path / "ideal", profile=get_profile("ideal", "stars"), **kw)
    simulate_geo_stars(tmp_path / "real", profile=get_profile("realistic", "stars"), **kw)
    assert _digest(tmp_path / "none") == _digest(tmp_path / "ideal")
    assert _digest(tmp_path / "none") != _digest(tmp_path / "real")
    t0 = json.loads((tmp_path / "none" / "truth.json").read_text())
    t1 = json.loads((tmp_path / "real" / "truth.json").read_text())
    assert t1["config"]["attitude_noise_arcsec"] == 1.0 and t0["config"]["attitude_noise_arcsec"] == 0.1


def test_star_truth_pieces_have_their_magnitudes():
    from sensor_models.simulate.star_truth import MAS, perturb_catalogue, pixel_phase_shift, wobble_angles

    rng = np.random.default_rng(0)
    v = rng.normal(size=(4000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    w = perturb_catalogue(v, 1.0, 1.0, 2023.25, rng)
    sep_mas = np.arccos(np.clip(np.sum(v * w, 1), -1, 1)) / MAS
    expected = np.hypot(1.0, 32.0)  # per axis; the separation is Rayleigh: rms = sqrt(2) sigma
    assert 0.9 * np.sqrt(2) * expected < np.sqrt(np.mean(sep_mas**2)) < 1.1 * np.sqrt(2) * expected
    assert np.allclose(pixel_phase_shift([0.5, 1.5, 0.0, 1.0], 0.05), 0.0, atol=1e-12)
    assert pixel_phase_shift([0.75], 0.05)[0] == pytest.approx(0.05)
    a = wobble_angles(np.linspace(0, 1200, 1201), 2.0, 1200.0, rng)
    assert np.abs(a).max() / (np.pi / 648000) == pytest.approx(2.0, rel=1e-3)


def test_physical_staring_truth_lies_outside_the_cubic_and_schemes_stop_at_its_residual():
    from calibrate.experiments.simulate_seed002 import staring_models
    from calibrate.schemes.compensation_study import run_seed002

    assert staring_models(get_profile("ideal", "staring")) is None
    lens, truth, lab = staring_models(get_profile("realistic", "staring"))
    beyond = truth.lab_fit_residual["physical_fit_residual_px"]
    assert 0.03 < beyond < 0.5
    # round trip of the physical truth: ground -> image -> ground
    row, col = np.array([100.5, 5000.0, 10100.0]), np.array([200.0, 5100.5, 9900.0])
    lon, lat, h = truth.image_to_ground(row, col, height=0.0)
    r2, c2 = truth.ground_to_image(lon, lat, h)
    assert np.max(np.hypot(r2 - row, c2 - col)) < 1e-4
    real = {r["scheme"]: r for r in run_seed002(step_px=1000.0, schemes=["ICBEC"], models=(lens, truth, lab)).rows}
    ideal = {r["scheme"]: r for r in run_seed002(step_px=1000.0, schemes=["ICBEC"]).rows}
    assert ideal["ICBEC"]["total_px"] < 1e-3
    assert 0.003 < real["ICBEC"]["total_px"] < beyond


def test_day_to_day_offsets_walk_by_their_magnitude_and_are_smooth():
    from sensor_models.simulate.thermal_truth import ARCSEC, DAY_S, day_to_day_offsets

    t = np.arange(0.0, 400 * DAY_S, 3600.0)
    assert not day_to_day_offsets(t, 0.0).any()
    off = day_to_day_offsets(t, 4.0, seed=1) / ARCSEC
    mid = off[12::24]  # noon of each day
    steps = np.diff(mid, axis=0)
    assert 3.6 < steps.std() < 4.4
    assert np.abs(np.diff(off, axis=0)).max() < 4.0 * 4.0 / 24 * 4  # no jump within an hour
    assert np.array_equal(off, day_to_day_offsets(t, 4.0, seed=1) / ARCSEC)


# --------------------------------------------------------------------------- experiments
def test_unknown_seed_or_profile_is_a_usage_or_input_error(tmp_path, capsys):
    assert main(["experiment", "001", "--out", str(tmp_path / "x")]) == 2
    assert main(["-q", "experiment", "002", "--profile", "paper-000", "--out", str(tmp_path / "y")]) == 1
    err = capsys.readouterr().err
    assert "takes the profiles ideal, realistic, paper-002" in err
    assert not (tmp_path / "y").exists()


def test_experiment_002_quick(tmp_path, capsys):
    ideal = _run(tmp_path, "002", "ideal", capsys)
    real = _run(tmp_path, "002", "realistic", capsys)
    assert _cell(ideal, "ICBEC", "paper total") == 1.065 and _cell(ideal, "ICO", "paper total") == 47.518
    assert ideal["headline"]["icbec_rms_px"] < 1e-3
    assert 0.01 < real["headline"]["icbec_rms_px"] < 0.5
    assert ideal["headline"]["thermal_predicted_rms_px"] < 0.3
    assert 0.5 < real["headline"]["thermal_predicted_rms_px"] < 3.0
    assert {c["name"] for c in real["curves"]} == {"vcp_noise", "thermal_day_to_day"}
    # negative control: on error-free VCPs the free cubic absorbs the installation, ICO = ECBIC =
    # ICBEC at the numerical floor, ECO keeps the distortion: the degenerate ranking, not the paper's
    t3 = _table3_002(ideal)
    ours = {r[0]: r[t3["columns"].index("ours total RMS")] for r in t3["rows"]}
    assert max(ours["ICO"], ours["ECBIC"], ours["ICBEC"]) < 1e-3 < 1.0 < ours["ECO"]
    assert ideal["headline"]["paper_ranking_reproduced"] is False


def _table3_002(doc):
    t3 = [t for t in doc["tables"] if t["source"] == "seed 002 table 3"]
    assert len(t3) == 1
    return t3[0]


def test_experiment_002_paper_flow_quick(tmp_path, capsys):
    from calibrate.schemes.compensation_study import SEED002_TABLE3

    doc = _run(tmp_path, "002", "paper-002", capsys)
    t3 = _table3_002(doc)
    cols = list(t3["columns"])
    assert cols[:4] == ["scheme", "paper X", "paper Y", "paper total"]
    rows = {r[0]: r for r in t3["rows"]}
    assert {"ICO", "ECO", "ECBIC", "ICBEC"} <= set(rows)
    for name in ("ICO", "ECO", "ECBIC", "ICBEC"):
        assert tuple(rows[name][1:4]) == SEED002_TABLE3[name]
        x, y, total = (rows[name][cols.index(c)] for c in ("ours X RMS", "ours Y RMS", "ours total RMS"))
        assert abs(np.hypot(x, y) - total) < 1e-9 * max(total, 1.0)
    # the ranking claim is read off the computed totals, not typed in
    totals = {k: rows[k][cols.index("ours total RMS")] for k in ("ICO", "ECO", "ECBIC", "ICBEC")}
    order = sorted(totals, key=totals.get)
    assert doc["headline"]["ranking"] == order
    assert doc["headline"]["paper_ranking_reproduced"] == (order == ["ICBEC", "ECBIC", "ECO", "ICO"])
    assert doc["headline"]["paper_ranking_reproduced"] is True
    # ICO leaves the installation error (no better than before, as the paper's 47.5 > 43.3 px)
    assert totals["ICO"] > 0.99 * rows["before"][cols.index("ours total RMS")]
    # the sensitivity: the ranking holds at the profile's magnitudes; the lab noise that breaks it is named
    curves = {c["name"]: c for c in doc["curves"]}
    lab = curves["lab_noise_ranking"]
    held = lab["series"]["paper ranking held (1 yes, 0 no)"]
    assert held[lab["x"].index(0.43)] == 1.0 and held[-1] == 0.0
    assert all(v == 1.0 for v in curves["attitude_noise_ranking"]["series"]["paper ranking held (1 yes, 0 no)"])


def test_paper_flow_pieces():
    from calibrate.schemes.paper_flow import attitude_noise, lab_pointing_interior, ranking
    from calibrate.schemes.virtual_points import virtual_control_points
    from sensor_models.models.synthetic import example_geo_staring_model

    truth = example_geo_staring_model(image_shape=(1024, 1024))
    a, b = lab_pointing_interior(truth, step_px=100.0)
    assert np.allclose(a, truth.interior.tan_psi_x, atol=1e-12) and np.allclose(b, truth.interior.tan_psi_y, atol=1e-12)
    a1, _ = lab_pointing_interior(truth, step_px=100.0, noise_px=0.5, seed=3)
    assert 0 < np.abs(a1 - a).max() < 0.5 * truth.ifov_rad
    vcp = virtual_control_points(truth, step_px=100.0)
    assert attitude_noise(vcp, 0.0, truth.ifov_rad, truth.image_shape) is vcp
    moved = attitude_noise(vcp, truth.ifov_rad, truth.ifov_rad, truth.image_shape, seed=1)
    d = np.concatenate([moved.row - vcp.row, moved.col - vcp.col])
    assert 0.8 < np.std(d) < 1.3 and np.array_equal(moved.lon, vcp.lon)
    assert ranking({"A": 2.0, "B": float("nan"), "C": 1.0}) == ("C", "A", "B")


def test_experiment_004_quick(tmp_path, capsys):
    paper = _run(tmp_path, "004", "paper-004", capsys)
    assert _cell(paper, "sigma_f_mm", "paper flight") == 0.034
    assert _cell(paper, "sigma_rot_z_arcsec", "paper lab") == 6.396
    # the paper's sigma_k injected: our Monte Carlo meets the eq. 2-5 propagation within sampling error
    for k in ("sigma_f_mm", "sigma_rot_x_arcsec", "sigma_rot_z_arcsec"):
        mc = paper["headline"][k]
        assert 0.75 < mc / _cell(paper, k, "ours eq. 2-5 propagation at flight sigma_k") < 1.25, k
    # table 4: the four rows, the paper's values, ours from the measured mark noise inside the
    # Monte Carlo's interval, and the factor to the paper's within the mark-noise explanation
    t4 = next(i for i, t in enumerate(paper["tables"]) if "seed 004 table 4" in t["source"])
    rows = {r[0]: r for r in paper["tables"][t4]["rows"]}
    assert {"sigma_f_mm", "sigma_rot_x_arcsec", "sigma_rot_y_arcsec", "sigma_rot_z_arcsec"} <= set(rows)
    assert _cell(paper, "sigma_f_mm", "paper", table=t4) == 0.0015
    assert _cell(paper, "sigma_rot_z_arcsec", "paper", table=t4) == 0.0936
    for k in ("sigma_f_mm", "sigma_rot_x_arcsec", "sigma_rot_y_arcsec", "sigma_rot_z_arcsec"):
        ours = _cell(paper, k, "ours", table=t4)
        assert _cell(paper, k, "Monte Carlo 95 % low", table=t4) < ours < _cell(paper, k, "Monte Carlo 95 % high", table=t4)
        assert 0.5 < ours / _cell(paper, k, "paper", table=t4) < 3.0, k
    assert any("Table 4" in n for n in paper["notes"])


@pytest.mark.slow
def test_experiment_004_rendered_profiles(tmp_path, capsys):
    ideal = _run(tmp_path, "004", "ideal", capsys)["headline"]
    real = _run(tmp_path, "004", "realistic", capsys)["headline"]
    assert ideal["sigma_k_px"] < 0.04
    assert 2.0 < real["sigma_k_px"] / ideal["sigma_k_px"] < 15.0


@pytest.mark.slow
def test_experiment_000_quick(tmp_path, capsys):
    ideal = _run(tmp_path, "000", "ideal", capsys)
    real = _run(tmp_path, "000", "realistic", capsys)
    assert _cell(ideal, "mean |RA| after (px)", "paper") == 0.84175
    assert _cell(ideal, "DE 2-sigma after (px)", "paper") == 2.35
    for k in ("ra", "de"):
        assert ideal["headline"][f"{k}_mean_abs_px"] < 0.05
        assert 0.1 < real["headline"][f"{k}_mean_abs_px"] < 2.0
    assert {c["name"] for c in real["curves"]} == {"attitude_noise", "wobble"}


@pytest.mark.slow
def test_experiment_003_quick(tmp_path, capsys):
    ideal = _run(tmp_path, "003", "ideal", capsys)
    real = _run(tmp_path, "003", "realistic", capsys)
    assert _cell(ideal, "CCD4 (cam2_ccd2)", "paper planar after") == 0.482
    assert _cell(ideal, "CCD1 (cam1_ccd1)", "paper across before") == 350.59
    gi, gr = ideal["headline"]["gcp_truth_error_rms_px"], real["headline"]["gcp_truth_error_rms_px"]
    assert gi < 0.05 and 2.0 < gr / gi < 20.0
    assert real["headline"]["truth_error_rms_px"] > ideal["headline"]["truth_error_rms_px"]
    assert {c["name"] for c in real["curves"]} == {"gcp_noise", "jitter", "dem_error", "dom_error"}


def test_source_radiance_is_an_option_of_the_realistic_003_run(tmp_path):
    """The product names no data path: ``--source`` is given, and refused where it does not apply."""
    from calibrate.cli import main
    from calibrate.experiments.registry import run_experiment
    from sensor_models.errors import InputError

    with pytest.raises(InputError, match="applies to experiment 003"):
        run_experiment("000", "realistic", quick=True, work_dir=tmp_path, source=tmp_path / "x.tif")
    with pytest.raises(InputError, match="realistic profile's source radiance"):
        run_experiment("003", "ideal", work_dir=tmp_path, source=tmp_path / "x.tif")
    with pytest.raises(InputError, match="no such file"):
        run_experiment("003", "realistic", work_dir=tmp_path, source=tmp_path / "missing.jp2")
    assert main(["-q", "experiment", "003", "--quick", "--source", str(tmp_path / "x.tif"),
                 "--out", str(tmp_path / "o")]) == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_experiment_000_paper_pools_its_sessions(tmp_path, capsys):
    """paper-000 (quick: two sessions) reports each session alone and one calibration of both,
    with the day-to-day installation curve."""
    paper = _run(tmp_path, "000", "paper-000", capsys)
    h = paper["headline"]
    assert paper["scale"]["sessions_run"] == 2 and paper["scale"]["day_to_day_installation_arcsec"] == 1.0
    for k in ("ra", "de"):
        assert 0.05 < h[f"pooled_{k}_mean_abs_px"] < 2.0
        assert 0.05 < h[f"{k}_mean_abs_px"] < 2.0
    assert _cell(paper, "mean |RA| after (px)", "ours, one calibration of all sessions") == h["pooled_ra_mean_abs_px"]
    assert "installation_day_to_day" in {c["name"] for c in paper["curves"]}


def test_seed000_sessions_in_worker_processes_equal_those_of_one_process(tmp_path):
    """The sessions of experiment 000 run in worker processes (its speed at the paper's scale):
    the same figures and track points as in this process, to the last bit; a session asked for
    twice runs once."""
    from calibrate.experiments.simulate_seed000 import SessionPool, run_session

    profile = get_profile("paper-000", "stars")
    inst = (1.0, -2.0, 3.0)
    pool = SessionPool(tmp_path / "pool", workers=2)
    try:
        future = pool.submit(profile, day=1, n_frames=30, installation_error_arcsec=inst)
        assert pool.submit(profile, day=1, n_frames=30, installation_error_arcsec=list(inst)) is future
        got = future.result()
    finally:
        pool.close()
    want = run_session(tmp_path / "one", profile, day=1, n_frames=30, installation_error_arcsec=inst)
    assert {k: v for k, v in got.items() if k != "session"} == {k: v for k, v in want.items() if k != "session"}
    assert got["tracks"] > 0 and got["installation_error_arcsec"] == pytest.approx(list(inst), abs=1e-3)
    for name in ("row_smooth", "col_smooth", "virtual_gcrf", "check"):
        np.testing.assert_array_equal(getattr(got["session"].observations, name),
                                      getattr(want["session"].observations, name))
    np.testing.assert_array_equal(got["session"].body_to_gcrf, want["session"].body_to_gcrf)


def test_frames_per_session_is_an_option_of_experiment_000(tmp_path, capsys):
    """``--frames`` sets experiment 000's session length; refused below a track's length and
    for the other experiments, before anything is simulated or written."""
    from calibrate.experiments.registry import run_experiment
    from sensor_models.errors import InputError

    with pytest.raises(InputError, match="applies to experiment 000"):
        run_experiment("002", "ideal", quick=True, work_dir=tmp_path, frames=60)
    with pytest.raises(InputError, match="at least 30 frames"):
        run_experiment("000", "ideal", quick=True, work_dir=tmp_path, frames=20)
    assert main(["experiment", "000", "--frames", "20", "--out", str(tmp_path / "o")]) == 2
    assert main(["-q", "experiment", "004", "--quick", "--frames", "60", "--out", str(tmp_path / "p")]) == 1
    assert "applies to experiment 000" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (tmp_path / "p").exists()
