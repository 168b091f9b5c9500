"""Experiment 000's fast session path against the reference path, within 1e-3 px.

The fast path (:func:`calibrate.experiments.simulate_seed000.run_session`) keeps the simulated
frames in memory and takes each track's smoothing weight from the closed-form GCV
(:mod:`calibrate.spline_gcv`). The reference path is the user's chain: the frames written as
GeoTIFF files, listed in ``frames.json`` and read back (:func:`calibrate.star_frames.read_frame_list`,
:func:`calibrate.star_frames.load_frame`), and each spline's weight chosen by SciPy itself
(``make_smoothing_spline(lam=None)``). Both must give the same held-out figures to 1e-3 px
(they agree to ~1e-13 px on the sessions tried) and the same tracks.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import make_smoothing_spline

import calibrate.star_observations as star_observations
from calibrate.experiments.simulate_seed000 import OPTIONS, run_session
from calibrate.star_calibration import process_frames
from calibrate.star_frames import load_frame, read_frame_list
from sensor_models.readers.geo_manifest import read_geo_manifest
from sensor_models.simulate.profiles import get_profile
from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

TOLERANCE_PX = 1e-3


def _scipy_gcv_smooth_track(t, y, good, smooth):
    """smooth_track with SciPy choosing each spline's GCV weight itself."""
    tg = t[good]
    coef = np.polyfit(tg, y[good], 1)
    line = t[:, None] * coef[0] + coef[1]
    if not smooth or tg.size < 5:
        return line
    x = (t - tg.min()) / max(float(tg.max() - tg.min()), 1e-9)
    out = line.copy()
    for j in range(y.shape[1]):
        out[:, j] += make_smoothing_spline(x[good], (y[:, j] - line[:, j])[good], lam=None)(x)
    return out


def _reference_session(folder, profile, day: int, n_frames: int) -> dict:
    epoch = str(np.datetime64("2023-08-02T14:40:00") + np.timedelta64(day, "D"))
    simulate_geo_stars(folder, config=GeoStarsConfig(n_frames=n_frames, epoch_utc=epoch, seed=day), profile=profile)
    paths, seconds, manifest = read_frame_list(folder)
    r = process_frames([load_frame(p) for p in paths], seconds, read_geo_manifest(manifest), options=OPTIONS)
    out = {"tracks": int(r.frames["n_tracks"])}
    for k in ("ra", "de"):
        out[f"{k}_before_px"] = r.accuracy["before"][k]["mean_px"]
        out[f"{k}_mean_abs_px"] = r.accuracy["after"][k]["mean_abs_px"]
        out[f"{k}_two_sigma_px"] = r.accuracy["after"][k]["two_sigma_px"]
    return out


def test_fast_session_equals_the_files_and_scipy_gcv_path(tmp_path, monkeypatch):
    """paper-000, day 2, 40 frames (a reduced session: same camera, profile and processing)."""
    profile = get_profile("paper-000", "stars")
    fast = run_session(tmp_path / "fast", profile, day=2, n_frames=40)
    monkeypatch.setattr(star_observations, "smooth_track", _scipy_gcv_smooth_track)
    want = _reference_session(tmp_path / "reference", profile, day=2, n_frames=40)
    assert fast["tracks"] == want["tracks"] > 0
    for key, value in want.items():
        if key.endswith("_px"):
            assert fast[key] == pytest.approx(value, abs=TOLERANCE_PX), key
    obs = fast["session"].observations
    assert np.all(np.isfinite(obs.row_smooth[~obs.check & ~obs.rejected]))
