"""Grid-interpolated localization, RPC fitted to a push-broom model, and the lab camera model."""

from __future__ import annotations

import numpy as np
import pytest

from sensor_models.models.lab import LabBand, LabCamera, LabCcd, detector_angles, lab_to_directional_angles
from sensor_models.models.locgrid import InverseLocalizationGrid
from sensor_models.models.pushbroom_types import Installation
from sensor_models.models.rpc_fit import fit_rpc
from sensor_models.models.synthetic import example_pushbroom_model

JITTER = dict(bias_rad=(2e-4, -3e-4, 1e-3), jitter_amplitude_rad=(2e-6, 2e-6, 1e-6), jitter_frequency_hz=1.3, seed=5)


@pytest.fixture(scope="module")
def model():
    return example_pushbroom_model(n_rows=1200, installation=Installation(0.0, 0.0, np.radians(3.55)), attitude_kwargs=JITTER)


def test_inverse_grid_within_a_hundredth_of_a_pixel(model):
    rng = np.random.default_rng(11)
    ccd_index = rng.integers(0, 2, 20000)
    ccds = model.band_ccds()
    rows = rng.uniform(5, model.n_rows - 5, ccd_index.size)
    cols = np.array([ccds[i].first_col for i in ccd_index]) + rng.uniform(0.5, 1023.5, ccd_index.size)
    lon, lat, h = model.image_to_ground(rows, cols, height=rng.uniform(0, 2000, rows.size), array=ccd_index)
    grid = InverseLocalizationGrid(model, (lon.min() - 0.01, lon.max() + 0.01), (lat.min() - 0.01, lat.max() + 0.01), (0.0, 2000.0))
    r, c = grid.ground_to_image(lon, lat, h, array=ccd_index)
    err = np.hypot(r - rows, c - cols)
    assert err.max() <= 0.01
    assert err.max() > 1e-5  # it is an interpolation, not the exact model
    # outside the grid: NaN, never an extrapolation
    r, _ = grid.ground_to_image([lon.max() + 1.0], [lat[0]], [h[0]])
    assert np.isnan(r).all()


def test_rpc_fitted_to_pushbroom_ccd():
    """Acceptance: <= 0.01 px max over the scene and its height range (smooth attitude)."""
    smooth = example_pushbroom_model(n_rows=1200, installation=Installation(0.0, 0.0, np.radians(3.55)), attitude_kwargs=dict(bias_rad=(2e-4, -3e-4, 1e-3), drift_rad_s=(1e-6, 0.0, 2e-6)))
    for i in range(2):
        rpc, report = fit_rpc(smooth.detector_view(array=i), height_range_m=(-100.0, 3000.0))
        assert report["check_max_px"] <= 0.01
        lon, lat, h = smooth.image_to_ground([600.5], [smooth.band_ccds()[i].first_col + 500.5], height=1000.0)
        r, c = rpc.ground_to_image(lon, lat, h)
        assert abs(r[0] - 600.5) < 0.01 and abs(c[0] - 500.5) < 0.01


def test_rpc_cannot_follow_attitude_jitter(model):
    """A 1.3 Hz, 0.03 px jitter is beyond any RPC: the check grid shows it, the fit grid does not."""
    _, report = fit_rpc(model.detector_view(array=0), height_range_m=(0.0, 3000.0))
    assert 0.02 < report["check_max_px"] < 0.1


def test_lab_camera_to_directional_angles():
    cam = LabCamera(
        focal_length_mm=520.0,
        pixel_size_mm=0.0065,
        bands=(LabBand("B2", (LabCcd("ccd1", 0, 2048, 0.3, -13.3), LabCcd("ccd2", 2048, 2048, -0.3, 0.0)), (0.02, 0.0)),),
        principal_point_mm=(0.01, -0.02),
        radial_k=(2e-6, -1e-10, 0.0),
        decentering_p=(1e-6, -2e-6),
        tilt_rad=2e-4,
        rotation_rad=-3e-4,
    )
    bands, residual = lab_to_directional_angles(cam)
    ifov = 0.0065 / 520.0
    assert max(residual.values()) < 1e-3 * ifov  # the cubic represents the lab model
    c1 = bands["B2"][0]
    tx, ty = detector_angles(cam, cam.bands[0], cam.bands[0].ccds[0], np.array([0.0, 1023.0, 2047.0]))
    got = c1.look(np.array([0.0, 1023.0, 2047.0]))
    np.testing.assert_allclose(got[0], tx, atol=1e-3 * ifov)
    np.testing.assert_allclose(got[1], ty, atol=1e-3 * ifov)
    # one detector step is one IFOV across track, and the band offset shifts along track
    assert got[3][1] == pytest.approx(ifov, rel=1e-3)
    # detector 1023 without distortion: rotate (x, y) by -3e-4 rad, tilt, subtract the principal point
    x, y = 0.3 + 0.02, -13.3 + 1023 * 0.0065
    theta, tau = -3e-4, 2e-4
    xr, yr = np.cos(theta) * x - np.sin(theta) * y, np.sin(theta) * x + np.cos(theta) * y
    expected = (xr - 0.01) / (520.0 + yr * np.sin(tau))
    # the distortion terms (k1 r^2 ~ 1e-4, p1 r^2 ~ 5e-5 mm) stay below 3e-7 in tan psi here
    assert abs(tx[1] - expected) < 3e-7
    assert abs(tx[1] - expected) > 1e-8  # and they are applied
