"""Pooling star tracks of several sessions into one calibration (calibrate/star_pooling.py)."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.config import StarOptions
from calibrate.star_calibration import process_frames
from calibrate.star_frames import load_frame, read_frame_list
from calibrate.star_pooling import StarSession, calibrate_pooled
from sensor_models.errors import InputError
from sensor_models.readers.geo_manifest import read_geo_manifest
from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

OPTIONS = StarOptions(mag_limit=10.5, compare_joint=False)
ARCSEC_PX = 1.0 / 4.125  # seed 000 camera: 25 um / 1250 mm = 20 urad = 4.125 arcsec per pixel


def _session(folder, day: int, installation=()):
    epoch = str(np.datetime64("2023-08-02T14:40:00") + np.timedelta64(day, "D"))
    cfg = GeoStarsConfig(n_frames=30, epoch_utc=epoch, seed=day, installation_error_arcsec=tuple(installation))
    summary = simulate_geo_stars(folder, config=cfg)
    paths, seconds, manifest = read_frame_list(folder)
    lab = read_geo_manifest(manifest)
    result = process_frames([load_frame(p) for p in paths], seconds, lab, options=OPTIONS)
    return result, StarSession.from_result(result, lab, seconds), np.asarray(summary["installation_error_arcsec"])


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    root = tmp_path_factory.mktemp("pool")
    r0, s0, inst0 = _session(root / "d0", 0)
    r1, s1, _ = _session(root / "d1", 1, installation=inst0)
    r2, s2, _ = _session(root / "d2", 2, installation=inst0 + np.array([12.0, 0.0, 0.0]))
    return {"r0": r0, "s0": s0, "r1": r1, "s1": s1, "r2": r2, "s2": s2, "inst0": inst0}


def _mean_abs(doc):
    return 0.5 * (doc["after"]["ra"]["mean_abs_px"] + doc["after"]["de"]["mean_abs_px"])


def test_one_session_pooled_alone_is_its_own_calibration(sessions):
    """Pooling a single session solves exactly what process_frames solved for it."""
    doc = calibrate_pooled([sessions["s0"]], options=OPTIONS)
    own = sessions["r0"]
    assert doc["success"] and own.success
    got = np.array(list(doc["parameters"].values()))
    assert np.allclose(got, own.parameters, rtol=0.0, atol=1e-8)  # 1e-8 rad = 5e-4 px: the solver tolerance
    assert doc["after"]["ra"]["mean_abs_px"] == pytest.approx(own.accuracy["after"]["ra"]["mean_abs_px"], abs=1e-3)


def test_sessions_sharing_the_installation_pool_without_loss(sessions):
    """Two days of one camera (other dates, attitudes and noise): the virtual stars of day 1 are
    carried into day 0's frame correctly, so one model fits both as well as each alone."""
    alone = [sessions["r0"].accuracy["after"], sessions["r1"].accuracy["after"]]
    alone_mean = np.mean([0.5 * (a["ra"]["mean_abs_px"] + a["de"]["mean_abs_px"]) for a in alone])
    doc = calibrate_pooled([sessions["s0"], sessions["s1"]], options=OPTIONS)
    assert doc["success"] and doc["sessions"] == 2
    assert alone_mean < 0.06  # ideal profile: a unit test, not an accuracy claim
    assert _mean_abs(doc) < 1.5 * alone_mean + 0.01
    # the LAB model is 22 px off on both days, before
    assert abs(doc["before"]["de"]["mean_px"]) > 15.0


def test_a_day_to_day_installation_change_shows_when_pooled(sessions):
    """Day 2's installation is 12 arcsec (2.9 px) off day 0's in roll: calibrated alone each day
    is fine; one model for both lands between them, and the held-out error shows it."""
    alone = sessions["r2"].accuracy["after"]
    assert 0.5 * (alone["ra"]["mean_abs_px"] + alone["de"]["mean_abs_px"]) < 0.06
    doc = calibrate_pooled([sessions["s0"], sessions["s2"]], options=OPTIONS)
    per = [0.5 * (p["ra_mean_abs_px"] + p["de_mean_abs_px"]) for p in doc["per_session"]]
    half_change_px = 0.5 * 12.0 * ARCSEC_PX  # ~1.45 px on the sky, split between RA and DE
    assert 0.25 * half_change_px < min(per) and max(per) < 1.5 * half_change_px


def test_sessions_of_another_camera_are_refused(sessions):
    other = sessions["s1"]
    lab = other.lab_model
    p = lab.parameters().values.copy()
    p[5] += 1e-3
    foreign = StarSession(lab.with_parameters(p), other.body_to_gcrf, other.observations)
    with pytest.raises(InputError, match="session 1 is not of the first session's camera"):
        calibrate_pooled([sessions["s0"], foreign], options=OPTIONS)
    with pytest.raises(InputError, match="no session"):
        calibrate_pooled([], options=OPTIONS)


def test_installation_given_outright_is_checked():
    with pytest.raises(InputError, match="installation_error_arcsec"):
        GeoStarsConfig(installation_error_arcsec=(1.0, 2.0)).validate()
    with pytest.raises(InputError, match="installation_error_arcsec"):
        GeoStarsConfig(installation_error_arcsec=(1.0, np.nan, 0.0)).validate()
