"""Band parallax as attitude observations (calibrate.parallax): the tie transfer's Jacobians against
finite differences, and jitter faster than the GCP rows resolve recovered from GCPs and ties
together on a synthetic scene (TRUE attitude sampled at 100 Hz, outside the spline family)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.absolute import calibrate_model
from calibrate.config import CalibrationOptions
from calibrate.parallax import (AngleObservations, calibrate_with_parallax, joint_candidates, joint_select,
                                tie_observations, tie_transfer)
from calibrate.tie_points import TiePoints
from gcpmatch.gcps import GcpTable
from sensor_models.models.attitude_correction import AttitudeCorrection
from sensor_models.geometry.ephemeris import Attitude
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.models.pushbroom_types import Installation
from sensor_models.models.synthetic import example_pushbroom_model

HEIGHT_M = 300.0
IFOV_RAD = 50.0 / 782_121.0  # the example camera's


def _span(model):
    return sorted(float(t) for t in model.line_timing.seconds(np.array(model.row_range)))


def _ties(truth, model, band, *, row_step=8.0, col_step=128.0, noise_px=0.0, seed=0):
    """Ties of ``band``: the truth's transfer map of a reference-band grid (plus noise)."""
    rng = np.random.default_rng(seed)
    ref = truth.reference_band
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(16.0, truth.n_rows - 16, row_step),
                                                 np.arange(8.0, truth.n_cols - 8, col_step), indexing="ij"))
    ccd_ref = truth.ccd_index(cols, band=ref).reshape(-1)
    lon, lat, h = truth.image_to_ground(rows, cols, height=HEIGHT_M, band=ref, array=ccd_ref)
    qr, qc = truth.ground_to_image(lon, lat, h, band=band)
    qr, qc = qr + rng.normal(0, noise_px, qr.size), qc + rng.normal(0, noise_px, qc.size)
    ccd = truth.ccd_index(qc, band=band).reshape(-1)
    glon, glat, gh = model.image_to_ground(rows, cols, height=HEIGHT_M, band=ref, array=ccd_ref)
    n = rows.size
    sigma = max(noise_px, 0.01)
    return TiePoints(band, rows, cols, ccd_ref, glon, glat, gh, qr, qc, ccd, qr, qc, np.ones(n), np.full(n, sigma))


# ------------------------------------------------------------------ Jacobians
def test_tie_jacobian_matches_finite_differences():
    lab = example_pushbroom_model(n_rows=1500)
    rng = np.random.default_rng(1)
    corr = AttitudeCorrection("spline", *_span(lab), 12)
    model = lab.with_attitude_correction(corr.with_coefficients(rng.normal(0.0, 20e-6, (3, corr.n_coefficients))))
    ties = _ties(model, model, "B4", row_step=97.0, col_step=301.0)
    predicted, jac_b, jac_r, t_b, t_r = tie_transfer(model, ties, height=HEIGHT_M)
    np.testing.assert_allclose(predicted, np.stack([ties.row, ties.col], axis=-1), atol=1e-6)
    # B4 sits 8 detectors from B2 along track: it sees B2's ground 8 lines (60 ms) earlier
    assert np.allclose(t_b - t_r, -8 * lab.line_timing.line_period_s, rtol=0.02)
    names, x0 = model.parameter_names(), model.parameters().values
    basis = model.attitude_correction.basis
    for axis in ("roll", "pitch", "yaw"):
        for j in (3, 8):
            i, step = names.index(f"attitude.{axis}.k{j}"), 1e-7
            xp, xm = x0.copy(), x0.copy()
            xp[i] += step
            xm[i] -= step
            fd = (tie_transfer(model.with_parameters(xp), ties, height=HEIGHT_M)[0]
                  - tie_transfer(model.with_parameters(xm), ties, height=HEIGHT_M)[0]) / (2 * step)
            a = ("roll", "pitch", "yaw").index(axis)
            analytic = jac_b[:, :, a] * basis(t_b)[0][:, j, None] - jac_r[:, :, a] * basis(t_r)[0][:, j, None]
            scale = np.abs(analytic).max()
            assert scale > 5.0, axis  # px per radian: a live derivative (yaw is weak near the boresight)
            assert np.abs(fd - analytic).max() < 1e-5 * max(scale, 100.0) + 2e-3, (axis, j)
            # the two terms nearly cancel: a tie sees the change of the attitude, not the attitude
            assert np.abs(analytic).max() < 0.5 * np.abs(jac_b[:, :, a] * basis(t_b)[0][:, j, None]).max()


# ------------------------------------------------------------------ joint least squares
def test_joint_fit_of_exact_linear_observations_returns_the_coefficients():
    """Residuals made linear in a known spline (+ per-CCD offsets on the ties) are fitted back."""
    lab = example_pushbroom_model(n_rows=1200)
    true = AttitudeCorrection("spline", *_span(lab), 16)
    rng = np.random.default_rng(2)
    true = true.with_coefficients(rng.normal(0.0, 5e-6, (3, true.n_coefficients)))
    ties = _ties(lab, lab, "B4", row_step=6.0, col_step=64.0)
    obs = tie_observations(lab, ties, height=HEIGHT_M)
    n = 3000
    rows, cols = rng.uniform(1, lab.n_rows - 1, n), rng.uniform(1, lab.n_cols - 1, n)
    _, _, jac = lab.attitude_angle_jacobian(*lab.image_to_ground(rows, cols, height=HEIGHT_M))
    t = lab.line_timing.seconds(rows)
    gcp = AngleObservations(np.zeros((n, 2)), np.full(n, 100.0), jac[None], t[None], np.full(n, -1), np.zeros(n), "gcp")
    offsets = np.array([[0.3, -0.2], [0.1, 0.4]])  # per CCD (row, col) px: the nuisance
    gcp = replace(gcp, residual_px=gcp.linear_effect(true))
    obs = replace(obs, residual_px=obs.linear_effect(true) + offsets[obs.group], weight=np.full(len(obs), 1e4))
    chosen, cov, table = joint_select([gcp, obs], [None, true.with_coefficients(np.zeros_like(true.coefficients_rad))])
    assert [row["chosen"] for row in table] == [False, True]
    err = (chosen.angles(t) - true.angles(t)) * 1e6
    assert np.abs(err[:, :2]).max() < 0.05  # µrad, roll and pitch
    assert table[0]["rss"] > 1e3 * table[1]["rss"]


def test_blocks_get_the_weight_their_residuals_support():
    """Ties whose stated sigma (0.01 px) is five times too small get a variance factor near 25."""
    lab = example_pushbroom_model(n_rows=1200)
    rng = np.random.default_rng(4)
    ties = _ties(lab, lab, "B4", row_step=6.0, col_step=64.0)
    obs = tie_observations(lab, ties, height=HEIGHT_M)
    obs = replace(obs, residual_px=rng.normal(0.0, 0.05, obs.residual_px.shape), weight=np.full(len(obs), 1e4))
    n = 3000
    rows, cols = rng.uniform(1, lab.n_rows - 1, n), rng.uniform(1, lab.n_cols - 1, n)
    _, _, jac = lab.attitude_angle_jacobian(*lab.image_to_ground(rows, cols, height=HEIGHT_M))
    gcp = AngleObservations(rng.normal(0.0, 0.1, (n, 2)), np.full(n, 100.0), jac[None],
                            lab.line_timing.seconds(rows)[None], np.full(n, -1), np.zeros(n), "gcp")
    _, _, table = joint_select([gcp, obs], [None, AttitudeCorrection("spline", *_span(lab), 8)])
    factors = next(row for row in table if row["chosen"])["variance_factors"]
    assert 0.8 < factors["gcp"] < 1.2
    assert 18.0 < factors["B4"] < 32.0
    assert next(row for row in table if row["chosen"])["kind"] == "static"  # pure noise: nothing to fit


def _jittered_truth(lab, lines, seed=5):
    """TRUE model: installation error, sinusoids ``[(amp_urad (3,), f_hz)]`` in the attitude at 100 Hz,
    the other bands' CCDs 0.3 px along and -0.2 px across track off the laboratory values."""
    rng = np.random.default_rng(seed)
    lo, hi = lab.attitude.span
    t = np.linspace(lo, hi, int((hi - lo) / 0.01) + 1)
    angles = sum(np.asarray(a) * 1e-6 * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 2 * np.pi, 3))
                 for a, f in lines)
    quat = (lab.attitude.rotation(t) * Rotation.from_euler("ZYX", angles[:, ::-1])).as_quat()
    shift = np.array([0.3, -0.2]) * IFOV_RAD
    bands = {b: tuple(c if b == lab.reference_band else
                      replace(c, tan_psi_x=c.tan_psi_x + np.r_[shift[0], np.zeros(c.tan_psi_x.size - 1)],
                              tan_psi_y=c.tan_psi_y + np.r_[shift[1], np.zeros(c.tan_psi_y.size - 1)])
                      for c in lab.band_ccds(b)) for b in lab.bands}
    return PushbroomModel(orbit=lab.orbit, attitude=Attitude(t, quat, frame=lab.attitude.frame),
                          line_timing=lab.line_timing, bands=bands, installation=Installation(2e-4, -1e-4, 3e-4),
                          n_rows=lab.n_rows, reference_band=lab.reference_band)


def _error(truth, model, band, step=4.0):
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(0.5, truth.n_rows, step), np.linspace(1, truth.n_cols - 1, 12)))
    lon, lat, h = truth.image_to_ground(rows, cols, height=HEIGHT_M, band=band)
    r, c = model.ground_to_image(lon, lat, h, band=band)
    return float(np.sqrt(np.nanmean((r - rows) ** 2 + (c - cols) ** 2)))


@pytest.fixture(scope="module")
def jitter_case():
    """1200 lines (9 s); 5 µrad at 0.3 Hz and 3 µrad at 2.5 Hz; GCP rows every 24 lines (0.15 px noise)."""
    lab = example_pushbroom_model(n_rows=1200)
    truth = _jittered_truth(lab, [((5.0, 5.0, 2.0), 0.3), ((3.0, 3.0, 1.0), 2.5)])
    rng = np.random.default_rng(0)
    rows, cols = (a.ravel() for a in np.meshgrid(np.arange(12.0, 1200, 24.0), np.linspace(4, truth.n_cols - 4, 40)))
    lon, lat, h = truth.image_to_ground(rows, cols, height=rng.uniform(0, 1500, rows.size), band="B2")
    gcps = GcpTable.from_arrays(rows + rng.normal(0, 0.15, rows.size), cols + rng.normal(0, 0.15, rows.size), lon, lat,
                                h, band="B2", sigma_px=0.15)
    ref = calibrate_model(lab, gcps, options=CalibrationOptions(attitude="auto"))
    assert ref.success, ref.message
    model, ties = ref.model, {}
    for band in ("B1", "B3", "B4"):
        ties[band] = _ties(truth, model, band, noise_px=0.02, seed=len(ties))
        model = calibrate_model(model, ties[band].as_gcp_table(), options=CalibrationOptions(scheme="interior")).model
    return {"truth": truth, "gcp_only": model, "ties": ties, "gcps": gcps,
            "gcp_only_edf": ref.attitude["selected"]["edf"]}


def test_parallax_recovers_jitter_the_gcp_rows_cannot(jitter_case, tmp_path):
    truth, gcp_only = jitter_case["truth"], jitter_case["gcp_only"]
    ties = {b: jitter_case["ties"][b] for b in ("B1", "B4")}  # 4 and 8 lines from B2 (the test's time)
    joint = calibrate_with_parallax(gcp_only, ties, jitter_case["gcps"], height=HEIGHT_M)
    assert joint.success, joint.message
    assert joint.n_ties > 4000 and joint.n_gcps > 1500
    # 2.5 Hz (0.4 s) needs the freedom of about 2 x 2.5 x 9 s = 45 parameters per axis; the GCP
    # rows (24 lines, 0.18 s, 0.15 px) support a far smoother P-spline
    assert joint.correction.kind == "spline"
    joint_edf = next(r for r in joint.candidates if r["chosen"])["n_parameters"]
    gcp_edf = jitter_case["gcp_only_edf"]
    print(f"effective degrees of freedom: GCP-only {gcp_edf}, joint {joint_edf}")
    assert joint_edf > 2.0 * gcp_edf
    for band in ("B2", "B4"):
        before, after = _error(truth, gcp_only, band), _error(truth, joint.model, band)
        print(f"{band}: truth error GCP-only {before:.4f} px, joint {after:.4f} px")
        assert before > 0.04  # the 2.5 Hz line (3 µrad, 0.05 px) is left in the GCP-only model
        assert 0.002 < after < 0.5 * before
    # the report's section: joint against GCP-only, time series and spectra per axis
    from calibrate.relative import RelativeResult
    from calibrate.report.attitude import figure_parallax, section_parallax

    relative = RelativeResult(joint.model, "B2", {}, {}, parallax={"used": True, **joint.to_dict(), "result": joint})
    figure = figure_parallax(relative, tmp_path)
    assert (tmp_path / "attitude_parallax.png").stat().st_size > 10_000
    html = section_parallax(relative, figure)
    assert f"{joint.n_ties} band-to-band tie points" in html and f"spline ({gcp_only.attitude_correction.n_terms})" in html
    assert "not used" in section_parallax(RelativeResult(gcp_only, "B2", {}, {}, parallax={"used": False, "reason": "x"}),
                                          None)


def test_static_mode_and_no_jitter_keep_the_model(jitter_case):
    joint = calibrate_with_parallax(jitter_case["gcp_only"], dict(jitter_case["ties"]), jitter_case["gcps"],
                                    height=HEIGHT_M, options=CalibrationOptions(attitude="static"))
    assert joint.success and joint.correction is None
    cands = joint_candidates("static", jitter_case["gcp_only"], [tie_observations(
        jitter_case["gcp_only"], jitter_case["ties"]["B4"], height=HEIGHT_M)])
    assert cands == [None]


def test_a_yaw_prior_bounds_the_weakly_observed_yaw(jitter_case):
    """The narrow camera sees yaw weakly: unconstrained it wanders tens of µrad (truth <= 3 µrad);
    a 5 µrad prior (CalibrationOptions.attitude_yaw_sigma_urad) holds it within 10 µrad and leaves
    roll and pitch and the fit's RSS unchanged."""
    from calibrate.parallax import gcp_observations

    model, ties = jitter_case["gcp_only"], jitter_case["ties"]
    obs = [gcp_observations(model, jitter_case["gcps"]), tie_observations(model, ties["B4"], height=HEIGHT_M),
           tie_observations(model, ties["B1"], height=HEIGHT_M, group_offset=2)]
    cand = [AttitudeCorrection("spline", *_span(model), 91)]
    t = model.line_timing.seconds(np.arange(0.5, model.n_rows, 2.0))
    fits = {}
    for sigma in (None, 5e-6):
        chosen, _, table = joint_select(obs, cand, base=model.attitude_correction, yaw_sigma_rad=sigma, reweight=False)
        a = chosen.angles(t) * 1e6
        fits[sigma] = (np.abs(a - a.mean(axis=0)).max(axis=0), a.std(axis=0), table[0]["rss"])
    free, prior = fits[None], fits[5e-6]
    assert free[0][2] > 15.0  # µrad: the free yaw wanders
    assert prior[0][2] < 10.0
    np.testing.assert_allclose(prior[1][:2], free[1][:2], rtol=0.03)  # roll and pitch
    assert free[2] <= prior[2] < 1.02 * free[2]
    assert CalibrationOptions(attitude_yaw_sigma_urad=5.0).attitude_yaw_sigma_urad == 5.0
    with pytest.raises(Exception, match="attitude_yaw_sigma_urad"):
        CalibrationOptions(attitude_yaw_sigma_urad=-1.0)
