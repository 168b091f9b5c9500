"""Outlier rejection of dense matches (``gcpmatch.outliers``): the robust smooth fit per CCD.

Synthetic shifts on a 20 x 15 window grid: a smooth field (what a pre-corrected model leaves:
an offset, a cubic across track, a drift along track) plus Gaussian matching noise, with the
kinds of bad matches real scenes give: isolated gross errors, and a compact cluster of windows
that are all wrong the same way (a cast shadow that moved with the season, a changed field),
which agrees with its neighbours and so passes the local-consistency test.
"""

from __future__ import annotations

import numpy as np
import pytest

from gcpmatch.outliers import smooth_residuals

SIGMA_PX = 0.06


def _field(row, col):
    u, v = col / 1000.0, row / 800.0
    return np.stack([0.4 + 0.3 * u - 0.2 * u**3 + 0.15 * v, -0.2 + 0.1 * u * u + 0.25 * v * v], axis=-1)


@pytest.fixture()
def grid():
    rng = np.random.default_rng(17)
    row, col = (g.ravel().astype(float) for g in np.meshgrid(np.arange(20) * 40.0 + 32, np.arange(15) * 64.0 + 32,
                                                             indexing="ij"))
    truth = _field(row, col)
    return rng, row, col, truth, truth + rng.normal(0.0, SIGMA_PX, truth.shape)


def test_clean_matches_are_kept_and_sigma_is_the_noise(grid):
    _, row, col, truth, shift = grid
    inlier, sigma, res = smooth_residuals(row, col, shift[:, 0], shift[:, 1])
    assert inlier.mean() >= 0.99
    assert 0.8 * SIGMA_PX < sigma < 1.2 * SIGMA_PX
    fitted = shift - res
    assert np.sqrt(np.mean((fitted - truth) ** 2)) < 0.4 * SIGMA_PX


def test_isolated_gross_errors_are_rejected(grid):
    rng, row, col, truth, shift = grid
    bad = rng.choice(row.size, 15, replace=False)
    shift[bad] += rng.choice([-1.0, 1.0], (15, 2)) * rng.uniform(1.0, 3.0, (15, 2))
    inlier, _, _ = smooth_residuals(row, col, shift[:, 0], shift[:, 1])
    assert not inlier[bad].any()
    assert np.delete(inlier, bad).mean() >= 0.98


def test_a_consistent_cluster_is_rejected_only_with_the_redescending_weights(grid):
    """9 % of the windows in the middle of the CCD, all off by 0.45 px the same way (about 7.5
    sigma per axis): Huber weights let the cluster pull the fit toward itself, so about half of
    it hides below the threshold; the biweight gives it no weight and rejects almost all of it.
    (Measured on this grid: Huber keeps 46 %, the biweight 7 %; at 0.5 px 14 % and 0 %.)"""
    _, row, col, truth, shift = grid
    cluster = (np.abs(row - 400.0) < 130.0) & (np.abs(col - 500.0) < 130.0)
    assert 0.08 < cluster.mean() < 0.11
    shift[cluster] += 0.45 * np.array([-0.75, -0.66])
    kept_huber, _, _ = smooth_residuals(row, col, shift[:, 0], shift[:, 1], redescending_iterations=0)
    inlier, sigma, res = smooth_residuals(row, col, shift[:, 0], shift[:, 1])
    assert kept_huber[cluster].mean() > 0.3
    assert inlier[cluster].mean() < 0.15
    assert inlier[~cluster].mean() >= 0.97
    assert sigma < 1.3 * SIGMA_PX
    fitted = shift - res
    assert np.sqrt(np.mean((fitted[~cluster] - truth[~cluster]) ** 2)) < 0.5 * SIGMA_PX


def test_huber_only_is_the_former_estimator(grid):
    """redescending_iterations=0 is the Huber IRLS alone, bit for bit (8 fits, the last weights unused)."""
    _, row, col, _, shift = grid
    shift[:5] += 2.0
    a = smooth_residuals(row, col, shift[:, 0], shift[:, 1], redescending_iterations=0)
    b = smooth_residuals(row, col, shift[:, 0], shift[:, 1], iterations=8, redescending_iterations=0)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[2], b[2])


def test_few_matches_are_all_kept():
    row = np.arange(9.0)
    inlier, sigma, res = smooth_residuals(row, row, row * 0.0, row * 0.0 + 5.0)
    assert inlier.all() and np.isnan(sigma) and not res.any()
