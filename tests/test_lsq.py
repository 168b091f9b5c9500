"""calibrate.lsq: textbook answers, chunking, robustness, rank diagnostics, honest covariance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from calibrate.lsq import solve
from calibrate.lsq_inputs import Chunk, Prior
from calibrate.normal_decomposition import summarize_names
from calibrate.robust_loss import CAUCHY_C, HUBER_C, robust_scale, robust_weights
from sensor_models.errors import InputError


def regression(n=500, noise=0.1, seed=0):
    """y = 2 + 3 t + 0.5 t^2 + noise on t in [-1, 1]."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(-1.0, 1.0, n)
    design = np.stack([np.ones(n), t, t * t], axis=1)
    y = design @ np.array([2.0, 3.0, 0.5]) + rng.normal(0.0, noise, n)
    return design, y


def linear_chunks(design, y, size, weight=None):
    def chunks(x):
        for a in range(0, y.size, size):
            sl = slice(a, a + size)
            yield Chunk(y[sl] - design[sl] @ x, design[sl], None if weight is None else weight[sl])

    return chunks


def test_linear_regression_matches_lstsq_and_the_analytic_covariance():
    design, y = regression()
    result = solve(linear_chunks(design, y, 77), np.zeros(3), robust="none")
    x_ref, rss, *_ = np.linalg.lstsq(design, y, rcond=None)
    s2 = rss[0] / (y.size - 3)
    cov_ref = s2 * np.linalg.inv(design.T @ design)
    assert result.success, result.message
    np.testing.assert_allclose(result.x, x_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(result.covariance, cov_ref, rtol=1e-9)
    assert result.sigma0 == pytest.approx(np.sqrt(s2), rel=1e-12)
    assert result.redundancy == y.size - 3
    np.testing.assert_allclose(result.residuals[:, 0], y - design @ x_ref, atol=1e-12)
    sd = np.sqrt(np.diag(cov_ref))
    np.testing.assert_allclose(result.correlation, cov_ref / np.outer(sd, sd), atol=1e-12)
    # the condition number is that of the Jacobi-equilibrated normal matrix
    n_mat = design.T @ design
    d = np.sqrt(np.diag(n_mat))
    assert result.condition_number == pytest.approx(np.linalg.cond(n_mat / np.outer(d, d)), rel=1e-9)


def test_weighted_regression_matches_the_weighted_textbook_solution():
    design, y = regression(seed=3)
    rng = np.random.default_rng(4)
    w = rng.uniform(0.2, 5.0, y.size)
    result = solve(linear_chunks(design, y, 64, w), np.zeros(3), robust="none")
    sw = np.sqrt(w)
    x_ref, rss, *_ = np.linalg.lstsq(design * sw[:, None], y * sw, rcond=None)
    np.testing.assert_allclose(result.x, x_ref, atol=1e-12)
    cov_ref = rss[0] / (y.size - 3) * np.linalg.inv(design.T @ (design * w[:, None]))
    np.testing.assert_allclose(result.covariance, cov_ref, rtol=1e-9)


@pytest.mark.parametrize("robust", ["none", "huber", "cauchy"])
def test_chunking_does_not_change_the_answer(robust):
    design, y = regression(n=2000, seed=5)
    y[::7] += 30.0  # outliers, so that the robust weights matter
    # (the first evaluation takes its robust scale from the first chunk, so the paths differ;
    # converged tightly, both reach the same fixed point)
    one = solve(linear_chunks(design, y, 10**6), np.zeros(3), robust=robust, tol=1e-9, max_iter=100)
    many = solve(linear_chunks(design, y, 37), np.zeros(3), robust=robust, tol=1e-9, max_iter=100)
    assert one.success and many.success, (one.message, many.message)
    np.testing.assert_allclose(many.x, one.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(many.covariance, one.covariance, rtol=1e-6)


def test_sparse_columns_equal_the_dense_problem():
    """Chunks that name their Jacobian columns accumulate into the right blocks."""
    rng = np.random.default_rng(6)
    n = 300
    group = rng.integers(0, 3, n)
    t = rng.uniform(-1, 1, n)
    truth = np.array([1.0, -2.0, 0.5, 3.0])  # common slope, then one offset per group
    y = truth[0] * t + truth[1:][group] + rng.normal(0, 0.05, n)
    dense = np.zeros((n, 4))
    dense[:, 0] = t
    dense[np.arange(n), 1 + group] = 1.0

    def sparse(x):
        for g in range(3):
            sel = group == g
            jac = np.stack([t[sel], np.ones(sel.sum())], axis=1)
            yield Chunk(y[sel] - x[0] * t[sel] - x[1 + g], jac, None, [0, 1 + g])

    a = solve(sparse, np.zeros(4), robust="none")
    b = solve(linear_chunks(dense, y, 50), np.zeros(4), robust="none")
    np.testing.assert_allclose(a.x, b.x, atol=1e-12)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-9)


def test_nonlinear_fit_from_a_far_start_matches_scipy():
    """Exponential decay y = A exp(-k t) + c, Levenberg-Marquardt from a poor start."""
    rng = np.random.default_rng(7)
    t = np.linspace(0, 5, 400)
    y = 4.0 * np.exp(-1.3 * t) + 0.5 + rng.normal(0, 0.02, t.size)

    def model(x):
        return x[0] * np.exp(-x[1] * t) + x[2]

    def chunks(x):
        e = np.exp(-x[1] * t)
        jac = np.stack([e, -x[0] * t * e, np.ones_like(t)], axis=1)
        for a in range(0, t.size, 90):
            yield Chunk((y - model(x))[a : a + 90], jac[a : a + 90])

    x0 = np.array([1.0, 5.0, 0.0])
    result = solve(chunks, x0, robust="none", max_iter=100, tol=1e-8)
    ref = least_squares(lambda x: model(x) - y, x0, method="lm", xtol=1e-14, ftol=1e-14)
    assert result.success, result.message
    np.testing.assert_allclose(result.x, ref.x, rtol=1e-6)
    assert 0.015 < result.sigma0 < 0.025


def test_robust_fits_with_40_percent_gross_outliers():
    """Cauchy keeps the accuracy of a fit of the inliers alone; Huber is bounded but worse."""
    design, y = regression(n=3000, seed=8)
    rng = np.random.default_rng(9)
    bad = rng.random(y.size) < 0.4
    y_bad = y.copy()
    y_bad[bad] += rng.uniform(5.0, 200.0, bad.sum()) * rng.choice([-1.0, 1.0], bad.sum())
    truth = np.array([2.0, 3.0, 0.5])
    inliers_only = solve(linear_chunks(design[~bad], y[~bad], 500), np.zeros(3), robust="none")
    cauchy = solve(linear_chunks(design, y_bad, 500), np.zeros(3), robust="cauchy")
    huber = solve(linear_chunks(design, y_bad, 500), np.zeros(3), robust="huber")
    plain = solve(linear_chunks(design, y_bad, 500), np.zeros(3), robust="none")
    assert cauchy.success and huber.success
    ratio = np.linalg.norm(cauchy.sigma) / np.linalg.norm(inliers_only.sigma)
    assert 0.9 < ratio < 1.2
    assert np.all(np.abs(cauchy.x - truth) < 4 * cauchy.sigma)
    assert np.all(np.abs(huber.x - truth) < 4 * huber.sigma)
    assert np.linalg.norm(huber.sigma) > 1.5 * np.linalg.norm(cauchy.sigma)
    assert np.linalg.norm(plain.x - truth) > 10 * np.linalg.norm(cauchy.x - truth)
    # the outliers get (almost) no weight, the inliers (almost) full weight
    assert np.median(cauchy.weights[bad]) < 0.01
    assert np.median(cauchy.weights[~bad]) > 0.9
    # the robust scale is the inlier noise (0.1) inflated by the median's 40 % contamination
    # (the 83rd percentile of |inlier| / 0.6745 = 0.2), not the outliers' (tens of units)
    assert 0.15 < cauchy.scale < 0.25


def test_two_component_points_share_one_robust_weight():
    """k = 2 components per point: an outlier in one component down-weights both."""
    rng = np.random.default_rng(10)
    n = 1000
    t = rng.uniform(-1, 1, n)
    truth = np.array([1.0, 2.0])
    obs = np.stack([truth[0] + truth[1] * t, truth[0] - truth[1] * t], axis=1) + rng.normal(0, 0.1, (n, 2))
    obs[:50, 0] += 50.0

    def chunks(x):
        pred = np.stack([x[0] + x[1] * t, x[0] - x[1] * t], axis=1)
        jac = np.stack([np.stack([np.ones(n), t], 1), np.stack([np.ones(n), -t], 1)], axis=1)
        yield Chunk(obs - pred, jac)

    result = solve(chunks, np.zeros(2), robust="huber")
    assert result.residuals.shape == (n, 2)
    assert np.all(result.weights[:50] < 0.05)
    assert np.all(np.abs(result.x - truth) < 4 * result.sigma)


def test_coverage_of_the_robust_covariance():
    """Huber's asymptotic covariance (module docstring) gives honest 95 % intervals."""
    hits, z2 = [], []
    for seed in range(120):
        design, y = regression(n=200, noise=0.1, seed=100 + seed)
        result = solve(linear_chunks(design, y, 200), np.zeros(3), robust="huber")
        z = (result.x - np.array([2.0, 3.0, 0.5])) / result.sigma
        hits.append(np.abs(z) < 1.96)
        z2.append(z * z)
    coverage = float(np.mean(hits))
    assert 0.92 < coverage < 0.98
    assert 0.8 < float(np.mean(z2)) < 1.25


def test_duplicated_column_is_reported_as_nearly_dependent():
    design, y = regression()
    design = np.concatenate([design, design[:, 1:2] * 2.0], axis=1)
    names = ("offset", "slope", "curvature", "slope_copy")
    result = solve(linear_chunks(design, y, 100), np.zeros(4), names=names, robust="none")
    assert not result.success
    assert "ill-conditioned" in result.message
    assert "slope" in result.message and "slope_copy" in result.message
    assert "offset" not in result.message.split("parameters", 1)[1]
    assert result.covariance is None
    np.testing.assert_array_equal(result.x, np.zeros(4))


def test_unconstrained_parameter_is_named():
    design, y = regression()
    design = np.concatenate([design, np.zeros((y.size, 2))], axis=1)
    names = ("a", "b", "c", "B3.ccd2.tan_psi_x.c0", "B3.ccd2.tan_psi_y.c0")
    result = solve(linear_chunks(design, y, 100), np.zeros(5), names=names)
    assert not result.success
    assert result.message == "no observations constrain B3.ccd2.*"
    assert result.unconstrained == names[3:]


def test_pseudo_observations_match_the_augmented_least_squares():
    design, y = regression(n=100, seed=11)
    prior = Prior.fixed([2], [0.3], [0.01], 3)
    result = solve(linear_chunks(design, y, 30), np.zeros(3), robust="none", prior=prior)
    aug = np.concatenate([design, [[0.0, 0.0, 1.0 / 0.01]]])
    rhs = np.concatenate([y, [0.3 / 0.01]])
    x_ref = np.linalg.lstsq(aug, rhs, rcond=None)[0]
    np.testing.assert_allclose(result.x, x_ref, atol=1e-10)
    assert abs(result.x[2] - 0.3) < 0.01


def test_non_finite_residuals_are_left_out_and_counted():
    design, y = regression(n=300, seed=12)
    y_nan = y.copy()
    y_nan[:40] = np.nan
    result = solve(linear_chunks(design, y_nan, 100), np.zeros(3), robust="none")
    ref = solve(linear_chunks(design[40:], y[40:], 100), np.zeros(3), robust="none")
    assert result.success
    assert result.n_valid == 260 and result.n_points == 300
    np.testing.assert_allclose(result.x, ref.x, atol=1e-12)
    assert np.all(np.isnan(result.residuals[:40])) and result.weights[:40].max() == 0.0


def test_too_few_observations_is_a_reported_failure():
    design, y = regression(n=3)
    result = solve(linear_chunks(design, y, 10), np.zeros(3), robust="none")
    assert not result.success and "too few observations" in result.message


def test_malformed_chunks_raise_input_errors():
    with pytest.raises(InputError, match="jacobian has shape"):
        solve(lambda x: [Chunk(np.zeros(5), np.zeros((5, 2)))], np.zeros(3))
    with pytest.raises(InputError, match="robust"):
        solve(lambda x: [], np.zeros(3), robust="tukey")
    with pytest.raises(InputError, match="no chunks"):
        solve(lambda x: [], np.zeros(3))


def test_robust_scale_and_weights():
    rng = np.random.default_rng(13)
    z = rng.normal(0, 2.0, (200_000, 2))
    assert robust_scale(np.abs(z[:, 0]), 1) == pytest.approx(2.0, rel=0.01)
    assert robust_scale(np.linalg.norm(z, axis=1), 2) == pytest.approx(2.0, rel=0.01)
    u = np.array([0.0, 1.0, HUBER_C, 2 * HUBER_C])
    np.testing.assert_allclose(robust_weights(u, "huber"), [1, 1, 1, 0.5])
    np.testing.assert_allclose(robust_weights(np.array([CAUCHY_C]), "cauchy"), [0.5])


def test_summarize_names_collapses_complete_groups():
    universe = ["installation.roll", "installation.pitch", "B1.ccd1.a", "B1.ccd1.b", "B1.ccd2.a"]
    assert summarize_names(["B1.ccd1.a", "B1.ccd1.b"], universe) == "B1.ccd1.*"
    assert summarize_names(["B1.ccd1.a", "installation.roll"], universe) == "B1.ccd1.a, installation.roll"
