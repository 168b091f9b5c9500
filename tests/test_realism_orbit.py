"""The realistic profile's orbit error is smooth, as precise orbit determination leaves it."""

from __future__ import annotations

import numpy as np

from sensor_models.simulate.profiles import get_profile
from sensor_models.simulate.scene import smooth_orbit_error


def test_smooth_orbit_error_has_its_rms_and_a_consistent_rate():
    t = np.arange(0.0, 20000.0, 1.0)
    err, rate = smooth_orbit_error(t, 1.0, 600.0, np.random.default_rng(3))
    assert err.shape == rate.shape == (t.size, 3)
    assert np.all((0.6 < err.std(axis=0)) & (err.std(axis=0) < 1.4))
    np.testing.assert_allclose(np.gradient(err, t, axis=0)[1:-1], rate[1:-1], atol=2e-5)
    # smooth: from one 1 s sample to the next it moves by millimetres, not by its rms
    assert np.abs(np.diff(err, axis=0)).max() < 0.02
    assert np.abs(rate).max() < 0.05  # m/s: 1 m over >= 600 s periods


def test_realistic_measured_orbit_has_no_velocity_noise_between_samples():
    """White 1 m noise on 1 s samples gave 1.3-1.7 m/s of velocity error through the orbit
    interpolant (a 200 urad yaw of the orbital frame, 2 px at +-32 deg; full-size bench); the
    realistic profile's error is smooth, so the interpolated velocity stays within cm/s."""
    from sensor_models.simulate.config import SimConfig
    from sensor_models.simulate.realistic_sim import apply_profile
    from sensor_models.simulate.scene import build_models

    cfg = apply_profile(SimConfig(), get_profile("realistic"))
    assert cfg.errors.orbit_noise_period_s == 600.0 and cfg.errors.orbit_noise_m == 1.0
    models = build_models(cfg)
    true_orbit, lab_orbit = models.true_model.orbit, models.lab_model.orbit
    t0, t1 = lab_orbit.span
    t = np.linspace(t0, t1, 997)
    dv = np.linalg.norm(lab_orbit.velocity(t) - true_orbit.velocity(t), axis=-1)
    dp = np.linalg.norm(lab_orbit.position(t) - true_orbit.position(t), axis=-1)
    assert dv.max() < 0.05
    assert 0.2 < np.sqrt(np.mean(dp**2)) < 4.0
    assert get_profile("ideal").value("orbit_noise_period_s") == 0.0
