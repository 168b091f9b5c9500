"""calibrate.accuracy: check-point statistics against known noise, offsets and ground spacing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from calibrate.absolute import calibrate_model
from gcpmatch.gcps import GcpTable
from calibrate.accuracy import (
    check_point_accuracy,
    check_residuals,
    error_versus_gcp_count,
    fit_normal,
    ground_steps,
    summarize_residuals,
)
from sensor_models.errors import InputError
from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model


@pytest.fixture(scope="module")
def model():
    design = CameraDesign(n_ccds=2, detectors_per_ccd=512, band_names=("B1", "B2"), band_offsets_px=(-2.0, 2.0))
    return example_pushbroom_model(n_rows=2000, design=design)


def points(model, n, *, band="B2", seed=0):
    """Exact image points and their ground coordinates on a smooth terrain.

    Points stay 20 columns away from the CCD junction: the CCDs overlap by 16 detectors in
    look, so a point shifted across the junction (noise, offsets) is, by its column, observed
    on the other CCD, where it projects about 16 px away.
    """
    rng = np.random.default_rng(seed)
    row = rng.uniform(2.0, model.n_rows - 2.0, n)
    col = rng.uniform(1.0, model.n_cols - 41.0, n)
    col = np.where(col > 492.0, col + 40.0, col)
    h = 300.0 + 200.0 * np.sin(row / 500.0)
    lon, lat, h = model.image_to_ground(row, col, height=h, band=band, array=model.ccd_index(col, band=band))
    return row, col, lon, lat, h


def test_residuals_vanish_for_exact_points_and_equal_the_added_noise(model):
    row, col, lon, lat, h = points(model, 2000)
    res, ccd = check_residuals(model, row, col, lon, lat, h, band="B2")
    assert np.abs(res).max() < 1e-6
    assert set(ccd) == {0, 1}
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, 0.3, (2000, 2))
    res, _ = check_residuals(model, row + noise[:, 0], col + noise[:, 1], lon, lat, h, band="B2")
    np.testing.assert_allclose(res, noise, atol=1e-6)


def test_rmse_of_known_noise_in_pixels_and_metres(model):
    row, col, lon, lat, h = points(model, 5000, seed=2)
    rng = np.random.default_rng(3)
    report = check_point_accuracy(model, row + rng.normal(0, 0.3, row.size), col + rng.normal(0, 0.3, row.size), lon, lat, h, band="B2")
    a = report.absolute
    assert a.n == 5000
    assert 0.28 < a.rmse_row_px < 0.32 and 0.28 < a.rmse_col_px < 0.32
    assert 0.40 < a.rmse_px < 0.45  # sqrt(2) x 0.3
    assert abs(a.mean_row_px) < 0.02 and abs(a.mean_col_px) < 0.02
    # about 50 m pixels (ifov x altitude), so about 15 m per 0.3 px
    assert 13.0 < a.rmse_row_m < 18.0 and 13.0 < a.rmse_col_m < 18.0
    assert 19.0 < a.rmse_m < 26.0
    hist = report.histograms["row"]
    assert hist.mean_ci[0] < 0.0 < hist.mean_ci[1]
    assert hist.std_ci[0] < 0.3 < hist.std_ci[1]
    json.dumps(report.to_dict(points=True), allow_nan=False)


def test_ground_steps_are_the_pixel_size(model):
    row, col, _, _, h = points(model, 500, seed=4)
    g_row, g_col = ground_steps(model, row, col, h, band="B2")
    size_row = np.linalg.norm(g_row, axis=1)
    size_col = np.linalg.norm(g_col, axis=1)
    # 50 m at nadir over 782 km, slightly larger off nadir, smaller with terrain height
    assert np.all((size_row > 45.0) & (size_row < 56.0))
    assert np.all((size_col > 45.0) & (size_col < 56.0))
    # rows run along track, columns across: the steps are nearly orthogonal
    cos = np.sum(g_row * g_col, axis=1) / (size_row * size_col)
    assert np.all(np.abs(cos) < 0.05)


def test_given_gsd_scales_pixels_to_metres(model):
    row, col, lon, lat, h = points(model, 300, seed=5)
    report = check_point_accuracy(model, row + 1.0, col - 2.0, lon, lat, h, band="B2", gsd_m=(40.0))
    assert report.absolute.rmse_row_m == pytest.approx(40.0, rel=1e-6)
    assert report.absolute.rmse_col_m == pytest.approx(80.0, rel=1e-6)
    assert report.absolute.rmse_m == pytest.approx(40.0 * np.sqrt(5.0), rel=1e-6)
    gsd = np.tile([10.0, 20.0], (row.size, 1))
    report = check_point_accuracy(model, row + 1.0, col - 2.0, lon, lat, h, band="B2", gsd_m=gsd)
    assert report.absolute.rmse_col_m == pytest.approx(40.0, rel=1e-6)
    with pytest.raises(InputError, match="gsd_m"):
        check_point_accuracy(model, row, col, lon, lat, h, band="B2", gsd_m=-1.0)


def test_relative_accuracy_removes_a_common_offset(model):
    """Seed 003 eq. 4-6: residuals relative to a reference point, divided by n - 1."""
    row, col, lon, lat, h = points(model, 400, seed=6)
    report = check_point_accuracy(model, row + 5.0, col - 3.0, lon, lat, h, band="B2")
    assert report.absolute.rmse_px == pytest.approx(np.hypot(5.0, 3.0), abs=1e-5)
    assert report.relative.rmse_px < 1e-5
    assert report.relative.n == 399
    # in metres the same pixel offset differs slightly across the swath (the pixel grows off
    # nadir), so the relative error is small but not zero
    assert report.relative.rmse_m < 0.02 * report.absolute.rmse_m
    # by hand, with a chosen reference point and noise
    rng = np.random.default_rng(7)
    e = rng.normal(0.0, 0.5, (400, 2))
    report = check_point_accuracy(model, row + e[:, 0], col + e[:, 1], lon, lat, h, band="B2", reference_index=17)
    d = np.delete(e - e[17], 17, axis=0)
    assert report.relative.rmse_row_px == pytest.approx(np.sqrt(np.sum(d[:, 0] ** 2) / 399), rel=1e-6)
    assert report.relative.rmse_col_px == pytest.approx(np.sqrt(np.sum(d[:, 1] ** 2) / 399), rel=1e-6)
    # the default reference is the point nearest the centroid
    default = check_point_accuracy(model, row, col, lon, lat, h, band="B2")
    centre = np.array([row.mean(), col.mean()])
    assert default.reference_index == int(np.argmin(np.hypot(row - centre[0], col - centre[1])))


def test_per_ccd_and_per_band_tables(model):
    row, col, lon, lat, h = points(model, 600, seed=8, band="B1")
    row2, col2, lon2, lat2, h2 = points(model, 600, seed=9, band="B2")
    offset = np.where(col >= 512.0, 2.0, -1.0)  # B1: CCD2 shifted by 2 px, CCD1 by -1 px
    band = np.array(["B1"] * 600 + ["B2"] * 600)
    report = check_point_accuracy(
        model,
        np.concatenate([row + offset, row2]),
        np.concatenate([col, col2]),
        np.concatenate([lon, lon2]),
        np.concatenate([lat, lat2]),
        np.concatenate([h, h2]),
        band=band,
        metres=False,
    )
    g = report.groups
    assert set(g) == {"B1", "B1.ccd1", "B1.ccd2", "B2", "B2.ccd1", "B2.ccd2"}
    assert g["B1.ccd1"].mean_row_px == pytest.approx(-1.0, abs=1e-6)
    assert g["B1.ccd2"].mean_row_px == pytest.approx(2.0, abs=1e-6)
    assert g["B2"].rmse_px < 1e-6
    assert g["B1.ccd1"].n + g["B1.ccd2"].n == g["B1"].n == 600
    assert report.absolute.rmse_m is None


def test_normal_fit_matches_scipy_and_the_two_sigma_rule():
    rng = np.random.default_rng(10)
    x = rng.normal(0.1, 0.5, 20000)
    fit = fit_normal(x, bins=50)
    mu, sd = stats.norm.fit(x)
    assert fit.mean == pytest.approx(mu, abs=1e-12)
    assert fit.std == pytest.approx(np.std(x, ddof=1), rel=1e-12)
    assert fit.mean_ci[0] < 0.1 < fit.mean_ci[1]
    assert fit.std_ci[0] < 0.5 < fit.std_ci[1]
    assert fit.mean_ci[1] - fit.mean_ci[0] == pytest.approx(2 * 1.96 * sd / np.sqrt(x.size), rel=0.01)
    assert abs(fit.fraction_within_two_sigma - 0.9545) < 0.005
    assert fit.counts.sum() == x.size
    assert np.abs(fit.counts - fit.normal_counts).max() < 5 * np.sqrt(fit.normal_counts.max())
    assert fit.two_sigma == pytest.approx((fit.mean - 2 * fit.std, fit.mean + 2 * fit.std))
    with pytest.raises(InputError):
        fit_normal([1.0])


def test_summary_ignores_points_without_projection():
    res = np.array([[1.0, 0.0], [np.nan, 0.0], [0.0, -1.0]])
    s = summarize_residuals(res)
    assert s.n == 2 and s.rmse_px == pytest.approx(1.0) and s.max_px == pytest.approx(1.0)


def test_error_decreases_with_the_number_of_gcps(model):
    """Seed 000 fig. 8: calibrations from more GCPs score better on check points."""
    p = model.parameters()
    v = p.values.copy()
    pos = {n: i for i, n in enumerate(p.names)}
    v[pos["installation.roll"]] += 1e-3
    v[pos["installation.yaw"]] -= 2e-3
    v[pos["B2.ccd1.tan_psi_y.c0"]] += 2.0 * 6.4e-5
    true = model.with_parameters(v)
    rng = np.random.default_rng(11)
    row, col, lon, lat, h = points(true, 1200, seed=12)
    gcps = {"row": row + rng.normal(0, 0.5, row.size), "col": col + rng.normal(0, 0.5, row.size), "lon": lon, "lat": lat, "h": h, "band": "B2"}
    crow, ccol, clon, clat, ch = points(true, 500, seed=13)
    checks = {"row": crow, "col": ccol, "lon": clon, "lat": clat, "h": ch, "band": "B2"}
    table = error_versus_gcp_count(model, gcps, checks, [60, 200, 1200], repeats=2, seed=0)
    assert [r["n_gcps"] for r in table] == [60, 200, 1200]
    assert all(r["successes"] == 2 for r in table)
    errors = [r["rmse_px_mean"] for r in table]
    assert errors[0] > errors[1] > errors[2]
    assert 0.005 < errors[2] < 0.1
    before = summarize_residuals(check_residuals(model, crow, ccol, clon, clat, ch, band="B2")[0]).rmse_px
    assert before > 10.0 * errors[0]
    with pytest.raises(InputError, match="subset size"):
        error_versus_gcp_count(model, gcps, checks, [5000])


def test_calibration_improves_check_point_accuracy(model):
    """End to end: GCPs and separate check points, before and after."""
    p = model.parameters()
    v = p.values.copy()
    v[1] += 2e-3  # pitch: about 30 lines
    true = model.with_parameters(v)
    rng = np.random.default_rng(14)
    row, col, lon, lat, h = points(true, 1500, seed=15)
    gcps = GcpTable.from_arrays(row + rng.normal(0, 0.3, row.size), col + rng.normal(0, 0.3, row.size), lon, lat, h, band="B2")
    result = calibrate_model(model, gcps)
    crow, ccol, clon, clat, ch = points(true, 400, seed=16)
    before = check_point_accuracy(model, crow, ccol, clon, clat, ch, band="B2")
    after = check_point_accuracy(result.model, crow, ccol, clon, clat, ch, band="B2")
    assert before.absolute.rmse_row_px > 20.0
    assert 0.005 < after.absolute.rmse_px < 0.1
