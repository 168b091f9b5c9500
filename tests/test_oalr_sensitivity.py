"""Seed 004 table 4 (in-orbit measurement sensitivity): measured mark noise through table 2,
bracketed by a Monte Carlo of rendered, located and averaged marks through eq. 2-5."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.schemes.autocollimation import OalrGeometry, measurement_sigmas
from calibrate.schemes.oalr_sensitivity import (PAPER_TABLE4, TABLE4_ROWS, monte_carlo_table4, reading_noise,
                                                sensitivity_table4)
from sensor_models.errors import InputError

#: the paper-004 profile's rendering (sensor_models/simulate/profiles.py)
RENDER = dict(psf_sigma_px=0.8, amplitude_e=1000.0, background_e=50.0, read_noise_e=10.0)
SPREAD = {"delta_f_mm": 0.003, "rot_x_arcsec": 0.005, "rot_y_arcsec": 0.005, "rot_z_arcsec": 0.2}


def test_table4_rows_are_table2_at_the_averaged_mark_noise():
    g = OalrGeometry()
    t = sensitivity_table4(0.02, readings=4, level=3.0, geometry=g)
    assert t["sigma_k_px"] == pytest.approx(3.0 * 0.02 / 2.0, rel=1e-12)
    s = measurement_sigmas(0.03, g)
    assert t["rows"]["sigma_f_mm"]["ours"] == pytest.approx(s["sigma_f_mm"], rel=1e-12)
    assert set(t["rows"]) == set(TABLE4_ROWS) == set(PAPER_TABLE4)
    # each paper row inverted through table 2 gives back the paper's value at that mark noise
    for k in TABLE4_ROWS:
        back = sensitivity_table4(t["paper_sigma_k_px"][k], readings=1, level=1.0, geometry=g)["rows"][k]["ours"]
        assert back == pytest.approx(PAPER_TABLE4[k], rel=1e-6)  # table 2 keeps arctg: linear to ~1e-9
    # the readings that would match the paper bring ours onto it (focal and Z rows: one factor)
    n = t["readings_for_paper"]
    again = sensitivity_table4(0.02, readings=max(1, round(n)), geometry=g)["rows"]
    assert 0.8 < again["sigma_f_mm"]["ratio"] < 1.25
    with pytest.raises(InputError):
        sensitivity_table4(-1.0)


def test_measured_table4_is_bracketed_by_a_rendered_monte_carlo():
    """Ours (measured single-reading noise, /sqrt(N), through table 2) against simulated
    measurements (true changes, N rendered readings per mark located and averaged, eq. 2-5):
    inside the Monte Carlo's 95 % interval on every row; and the measured noise itself sits where
    a peak SNR of ~30 puts a cross-bar fit (0.005-0.03 px)."""
    noise = reading_noise(RENDER, centres=8, readings=8, seed=3)
    assert 0.005 < noise["sigma_px"] < 0.03
    assert abs(noise["sigma_row_px"] / noise["sigma_col_px"] - 1.0) < 0.35
    readings = 3
    ours = sensitivity_table4(noise["sigma_px"], readings=readings)
    mc = monte_carlo_table4(RENDER, readings=readings, trials=40, spread=SPREAD, seed=5)
    for k in TABLE4_ROWS:
        assert mc[k]["low"] < ours["rows"][k]["ours"] < mc[k]["high"], (k, ours["rows"][k]["ours"], mc[k])
    # averaging works: 3 readings are ~sqrt(3) better than one (same formula, measured noise)
    one = sensitivity_table4(noise["sigma_px"], readings=1)["rows"]["sigma_f_mm"]["ours"]
    assert one / ours["rows"]["sigma_f_mm"]["ours"] == pytest.approx(np.sqrt(3.0), rel=1e-9)
