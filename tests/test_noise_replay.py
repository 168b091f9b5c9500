"""Noise draws replayed between simulations of one seed: the same values and frames to the bit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sensor_models.files.memory import available_memory_bytes
from sensor_models.simulate.noise_replay import NormalReplay


def test_replayed_draws_equal_fresh_ones_and_leave_the_generator_where_drawing_does():
    """Two generators of one seed: the second copies the first's draws, and its later draws (any
    method) are those of a generator that drew them itself; another seed draws afresh."""
    replay = NormalReplay(1 << 30)
    a = replay.generator(np.random.default_rng(7))
    first = [a.standard_normal((40, 30)) for _ in range(3)]
    b = replay.generator(np.random.default_rng(7))
    out = np.empty((40, 30))
    second = [b.standard_normal(out=out).copy(), b.standard_normal((40, 30)), b.standard_normal((40, 30))]
    plain = np.random.default_rng(7)
    for x, y in zip(first, second):
        want = plain.standard_normal((40, 30))
        np.testing.assert_array_equal(x, want)
        np.testing.assert_array_equal(y, want)
    assert replay.replayed == 3 and replay.drawn == 3
    np.testing.assert_array_equal(b.uniform(size=5), plain.uniform(size=5))  # the state after the replay
    c = replay.generator(np.random.default_rng(8))
    assert not np.array_equal(c.standard_normal((40, 30)), first[0])
    assert replay.drawn == 4


def test_the_budget_bounds_what_is_kept():
    """Draws beyond the budget are made and not kept (the next generator draws them itself)."""
    replay = NormalReplay(2 * 40 * 30 * 8)
    a = replay.generator(np.random.default_rng(1))
    for _ in range(4):
        a.standard_normal((40, 30))
    assert replay.kept_bytes == 2 * 40 * 30 * 8
    b = replay.generator(np.random.default_rng(1))
    plain = np.random.default_rng(1)
    for _ in range(4):
        np.testing.assert_array_equal(b.standard_normal((40, 30)), plain.standard_normal((40, 30)))
    assert replay.replayed == 2 and replay.drawn == 6
    assert NormalReplay(0).max_bytes == 0
    free = available_memory_bytes()
    assert free is None or free > 0


def test_star_frames_of_one_day_are_the_same_with_the_noise_replayed(tmp_path):
    """Sessions of one day under another attitude noise and installation (the seed 000
    experiment's sensitivity sessions): their frames with the first one's noise replayed equal
    their frames rendered alone, bit for bit; the noise was drawn once."""
    from sensor_models.simulate.profiles import Sourced, get_profile
    from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

    profile = get_profile("paper-000", "stars")
    variants = [(profile, ()), (replace(profile, name="noise-0.1", attitude_noise_arcsec=Sourced(0.1, "test")), ()),
                (profile, (80.0, -30.0, 25.0))]
    replay = NormalReplay(1 << 30)

    def frames(prof, inst, noise_replay, name):
        out = []
        cfg = GeoStarsConfig(n_frames=4, epoch_utc="2023-08-03T14:40:00", seed=1, installation_error_arcsec=inst)
        simulate_geo_stars(tmp_path / name, config=cfg, profile=prof, frames_out=out, noise_replay=noise_replay)
        return np.stack(out)

    for i, (prof, inst) in enumerate(variants):
        np.testing.assert_array_equal(frames(prof, inst, replay, f"r{i}"), frames(prof, inst, None, f"p{i}"))
    assert replay.drawn == 4 and replay.replayed == 8


@pytest.mark.slow
def test_seed000_group_of_one_day_equals_its_sessions_run_alone(tmp_path):
    """A group of one day's sessions (one worker, the noise drawn once) gives each session's
    figures and track points as a run of that session alone, to the last bit."""
    from calibrate.experiments.simulate_seed000 import SessionPool, run_session
    from sensor_models.simulate.profiles import Sourced, get_profile

    profile = get_profile("paper-000", "stars")
    other = replace(profile, name="wobble-0", wobble_arcsec=Sourced(0.0, "test"))
    sessions = [(profile, dict(day=2, n_frames=30, installation_error_arcsec=(1.0, -2.0, 3.0))),
                (other, dict(day=2, n_frames=30, installation_error_arcsec=(1.0, -2.0, 3.0))),
                (profile, dict(day=2, n_frames=30, installation_error_arcsec=(2.0, -1.0, 3.0)))]
    pool = SessionPool(tmp_path / "pool", workers=2)
    try:
        got = [f.result() for f in pool.submit_group(sessions)]
    finally:
        pool.close()
    for (prof, kw), g in zip(sessions, got):
        want = run_session(tmp_path / "one", prof, **kw)
        assert {k: v for k, v in g.items() if k != "session"} == {k: v for k, v in want.items() if k != "session"}
        for name in ("row_smooth", "col_smooth", "virtual_gcrf"):
            np.testing.assert_array_equal(getattr(g["session"].observations, name),
                                          getattr(want["session"].observations, name))
