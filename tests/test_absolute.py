"""calibrate.absolute: a LAB push-broom model calibrated against a known TRUE model.

The TRUE model is the LAB model (same orbit and attitude) with installation errors of a few
tenths of a degree and directional-angle offsets, scale errors and distortion of a few pixels;
GCPs are localized with TRUE on a smooth terrain and observed with 0.3 px Gaussian noise.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibrate.absolute import calibrate_model
from calibrate.calibration_result import parameter_unit
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.synthetic import CameraDesign, example_pushbroom_model

IFOV = 50.0 / 782_121.0
INSTALLATION_DEG = {"roll": 0.3, "pitch": -0.2, "yaw": 0.5}


@pytest.fixture(scope="module")
def lab():
    design = CameraDesign(n_ccds=2, detectors_per_ccd=512, band_names=("B1", "B2", "B3"), band_offsets_px=(-4.0, 0.0, 4.0))
    return example_pushbroom_model(n_rows=3000, design=design)


def perturbed(lab, *, installation=True, interior=True, gauge_free=None, seed=0, scale_deg=1.0):
    """TRUE model: LAB plus installation and interior errors.

    ``gauge_free=(band, ccd)`` perturbs that CCD only with shapes of zero mean and zero slope
    along track and zero mean across track (Legendre P2, P3 and P1..P3), so that the joint
    scheme's gauge (held at the LAB values) is the TRUE one.
    """
    p = lab.parameters()
    v = p.values.copy()
    pos = {n: i for i, n in enumerate(p.names)}
    if installation:
        for name, deg in INSTALLATION_DEG.items():
            v[pos[f"installation.{name}"]] += np.radians(deg * scale_deg)
    rng = np.random.default_rng(seed)
    if interior:
        for band in lab.bands:
            for c in lab.band_ccds(band):
                n = c.n_detectors
                pre = f"{band}.{c.name}."
                if gauge_free == (band, c.name):
                    to_unit = np.polynomial.Polynomial([-1.0, 2.0 / (n - 1)])  # s -> [-1, 1]
                    for axis, degrees in (("tan_psi_x", (2, 3)), ("tan_psi_y", (1, 2, 3))):
                        for deg in degrees:
                            shape = np.polynomial.legendre.Legendre.basis(deg)(to_unit).coef
                            idx = [pos[f"{pre}{axis}.c{j}"] for j in range(shape.size)]
                            v[idx] += rng.uniform(-2.0, 2.0) * IFOV * shape
                    continue
                for axis in ("tan_psi_x", "tan_psi_y"):
                    for k, px in enumerate((3.0, 2.0, 2.0, 1.0)):
                        v[pos[f"{pre}{axis}.c{k}"]] += rng.uniform(-px, px) * IFOV / n**k
    return lab.with_parameters(v)


def fit(model, row, col, lon, lat, h, *, band=None, ccd=None, sigma_px=None, score=None, kind=None, **options):
    """``calibrate_model`` on a table of these columns with these options."""
    table = GcpTable.from_arrays(row, col, lon, lat, h, band=band, ccd=ccd, sigma_px=sigma_px, score=score, kind=kind)
    return calibrate_model(model, table, options=CalibrationOptions(**options))


def height(row, col):
    return 400.0 + 300.0 * np.sin(row / 700.0) * np.cos(col / 500.0)


def simulate(true, n, *, band="B2", noise=0.3, seed=1, row=None, col=None):
    rng = np.random.default_rng(seed)
    row = rng.uniform(1.0, true.n_rows - 1.0, n) if row is None else np.broadcast_to(row, (n,)).astype(float)
    col = rng.uniform(0.5, true.n_cols - 0.5, n) if col is None else np.broadcast_to(col, (n,)).astype(float)
    ccd = true.ccd_index(col, band=band)
    lon, lat, h = true.image_to_ground(row, col, height=height(row, col), band=band, array=ccd)
    return row + rng.normal(0.0, noise, n), col + rng.normal(0.0, noise, n), lon, lat, h


def grid_rms(true, model, band="B2", n=30, ccds=None):
    """RMS (px) of ``model`` against ``true`` over a dense grid of every CCD of a band."""
    errors = []
    for k, c in enumerate(true.band_ccds(band)):
        if ccds is not None and k not in ccds:
            continue
        r, cc = np.meshgrid(
            np.linspace(5.0, true.n_rows - 5.0, n), np.linspace(c.first_col + 0.5, c.last_col - 0.5, n), indexing="ij"
        )
        r, cc = r.ravel(), cc.ravel()
        lon, lat, h = true.image_to_ground(r, cc, height=height(r, cc), band=band, array=k)
        rr, ccc = model.ground_to_image(lon, lat, h, band=band, array=k)
        errors.append(np.hypot(rr - r, ccc - cc))
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(e * e)))


@pytest.fixture(scope="module")
def true(lab):
    return perturbed(lab)


@pytest.fixture(scope="module")
def gcps(true):
    return simulate(true, 3000)


@pytest.fixture(scope="module")
def stepwise(lab, gcps):
    return fit(lab, *gcps, band="B2")


# --------------------------------------------------------------------------- accuracy
def test_exterior_interior_reproduces_the_true_model(lab, true, stepwise):
    result = stepwise
    assert result.success, result.message
    assert grid_rms(true, lab) > 50.0  # hundred-pixel errors before calibration
    rms = grid_rms(true, result.model)
    assert 0.01 < rms < 0.1, rms  # 0.3 px noise, 3000 GCPs
    after = result.statistics("after")
    assert 0.38 < after["rms_px"] < 0.47  # sqrt(2) x 0.3 px: the noise, nothing left
    assert result.statistics("before")["rms_px"] > 50.0
    assert result.inlier.mean() > 0.99
    # steps: exterior, interior, then an exterior step that no longer moves
    assert [s["step"] for s in result.steps][:2] == ["exterior", "interior"]
    assert result.steps[-1]["step"] == "exterior"
    assert result.covariance_kind == "conditional-blocks"
    assert set(result.condition_numbers) == {"exterior", "interior"}
    assert result.condition_numbers["exterior"] < 10.0
    # the other bands' interiors are not estimated
    assert not any(n.startswith(("B1.", "B3.")) for n in result.names)
    assert len(result.names) == 3 + 2 * 8


def test_a_single_round_is_the_seed_003_pass(lab, true, gcps):
    result = fit(lab, *gcps, band="B2", max_outer=1)
    assert result.success, result.message
    assert [s["step"] for s in result.steps] == ["exterior", "interior"]
    assert 0.01 < grid_rms(true, result.model) < 0.1


@pytest.mark.parametrize("scheme", ["interior-exterior", "joint", "interior"])
def test_other_complete_schemes_also_reproduce_the_true_model(lab, true, gcps, scheme):
    result = fit(lab, *gcps, band="B2", scheme=scheme)
    assert result.success, result.message
    assert 0.01 < grid_rms(true, result.model) < 0.1
    if scheme == "joint":
        assert "largest installation/interior correlation" in result.message
        assert result.covariance_kind == "joint"


def test_exterior_only_leaves_the_interior_errors(lab, true, gcps):
    result = fit(lab, *gcps, band="B2", scheme="exterior")
    assert result.success, result.message
    assert result.names == ("installation.roll", "installation.pitch", "installation.yaw")
    assert 0.5 < grid_rms(true, result.model) < 10.0  # the CCD offsets and distortion remain


def test_installation_angles_within_three_sigma_with_the_true_interior(lab):
    true = perturbed(lab, interior=False)
    result = fit(lab, *simulate(true, 2000, seed=3), band="B2", scheme="exterior")
    assert result.success, result.message
    truth = true.parameters().values[:3]
    z = (result.values - truth) / result.sigma
    assert np.all(np.abs(z) < 3.0), z
    # sensible precision: a few hundredths of a pixel equivalent for roll and pitch
    assert np.all(result.sigma[:2] / IFOV < 0.05) and np.all(result.sigma[:2] / IFOV > 1e-4)


def test_joint_gauge_recovers_installation_and_interior(lab):
    true = perturbed(lab, gauge_free=("B2", "ccd2"), scale_deg=0.2)
    result = fit(lab, *simulate(true, 3000, seed=4), band="B2", scheme="joint", reference_ccd=("B2", "ccd2"))
    assert result.success, result.message
    truth = true.parameters().as_dict()
    z = np.array([(v - truth[n]) / s for n, v, s in zip(result.names, result.values, result.sigma)])
    assert np.all(np.abs(z) < 4.0), dict(zip(result.names, np.round(z, 2)))
    assert np.all(np.abs(z[:3]) < 3.0)
    assert 0.01 < grid_rms(true, result.model) < 0.1


# --------------------------------------------------------------------------- robustness
def test_forty_percent_gross_outliers(lab, true, gcps):
    row, col, lon, lat, h = gcps
    rng = np.random.default_rng(5)
    bad = rng.random(row.size) < 0.4
    size = rng.uniform(5.0, 200.0, bad.sum())
    angle = rng.uniform(0.0, 2.0 * np.pi, bad.sum())
    row_bad, col_bad = row.copy(), col.copy()
    row_bad[bad] += size * np.sin(angle)
    col_bad[bad] += size * np.cos(angle)
    clean_all = grid_rms(true, fit(lab, row, col, lon, lat, h, band="B2").model)
    clean_inliers = grid_rms(true, fit(lab, row[~bad], col[~bad], lon[~bad], lat[~bad], h[~bad], band="B2").model)
    result = fit(lab, row_bad, col_bad, lon, lat, h, band="B2")  # Cauchy (default)
    assert result.success, result.message
    rms = grid_rms(true, result.model)
    # as good as a clean fit of the same inliers; the lost 40 % cost at most 1/sqrt(0.6)
    assert rms < 1.2 * clean_inliers, (rms, clean_inliers)
    assert rms < 1.2 / np.sqrt(0.6) * clean_all, (rms, clean_all)
    assert (~result.inlier[bad]).mean() > 0.99  # every gross error flagged
    assert (~result.inlier[~bad]).mean() < 0.01
    assert np.median(result.weights[bad]) < 0.01 and result.weights[bad].max() < 0.15
    # Huber bounds the damage but loses accuracy: why Cauchy is the default
    huber = fit(lab, row_bad, col_bad, lon, lat, h, band="B2", robust="huber")
    assert rms < grid_rms(true, huber.model) < 0.5


# --------------------------------------------------------------------------- ill-posed input
def test_a_ccd_with_five_points_keeps_its_interior(lab, true, gcps):
    row, col, lon, lat, h = gcps
    on_ccd2 = col >= 512.0
    keep = ~on_ccd2 | (np.cumsum(on_ccd2) <= 5)
    result = fit(lab, row[keep], col[keep], lon[keep], lat[keep], h[keep], band="B2")
    assert result.success, result.message
    assert "B2.ccd2: 5 GCPs < 24 needed (3 x 8 unknowns); its interior is not estimated" in result.message
    assert [s["ccd"] for s in result.skipped] == ["ccd2"]
    assert not any(n.startswith("B2.ccd2.") for n in result.names)
    lab_values = lab.parameters().as_dict()
    new_values = result.model.parameters().as_dict()
    assert all(new_values[n] == lab_values[n] for n in new_values if n.startswith("B2.ccd2."))
    assert 0.01 < grid_rms(true, result.model, ccds=[0]) < 0.1


def test_gcps_on_one_detector_column_do_not_fit_a_polynomial(lab, true):
    row, col, lon, lat, h = simulate(true, 400, col=300.0, seed=6)
    row2, col2, lon2, lat2, h2 = simulate(true, 2000, seed=7)
    on_ccd2 = col2 >= 512.0
    args = [np.concatenate([a, b[on_ccd2]]) for a, b in zip((row, col, lon, lat, h), (row2, col2, lon2, lat2, h2))]
    result = fit(lab, *args, band="B2")
    assert result.success, result.message
    assert "B2.ccd1: GCPs span 0 % of its detectors < 50 %; its interior is not estimated" in result.message
    assert not any(n.startswith("B2.ccd1.") for n in result.names)
    assert 0.01 < grid_rms(true, result.model, ccds=[1]) < 0.15
    # jointly, one detector column cannot fix the rotation about its own line of sight
    joint = fit(lab, *args, band="B2", scheme="joint")
    assert not joint.success
    assert "nearly dependent" in joint.message and "installation.yaw" in joint.message


def test_gcps_on_one_image_line_suffice_for_this_model(lab, true):
    """No parameter depends on time: one line still determines installation and interior."""
    result = fit(lab, *simulate(true, 3000, row=1500.0, seed=8), band="B2")
    assert result.success, result.message
    assert 0.01 < grid_rms(true, result.model) < 0.1


def test_joint_without_gauge_is_reported_as_nearly_dependent(lab, gcps):
    result = fit(lab, *gcps, band="B2", scheme="joint", gauge=False)
    assert not result.success
    assert "ill-conditioned" in result.message and "nearly dependent" in result.message
    assert "installation" in result.message and "tan_psi_y.c0" in result.message
    assert result.covariance is None


def test_too_few_gcps_for_the_exterior_is_a_reported_failure(lab, true):
    row, col, lon, lat, h = simulate(true, 1, seed=9)
    result = fit(lab, row, col, lon, lat, h, band="B2", scheme="exterior")
    assert not result.success
    assert "too few observations" in result.message


# --------------------------------------------------------------------------- mechanics
def test_chunk_size_does_not_change_the_answer(lab, gcps):
    a = fit(lab, *gcps, band="B2", tol=1e-3, max_iter=60)
    b = fit(lab, *gcps, band="B2", tol=1e-3, max_iter=60, chunk_points=257)
    assert a.success and b.success
    assert np.all(np.abs(a.values - b.values) < 1e-2 * a.sigma)


def test_weights_from_sigma_and_score(lab, true, gcps):
    row, col, lon, lat, h = gcps
    base = fit(lab, row, col, lon, lat, h, band="B2", scheme="exterior", robust="none")
    # a uniform sigma changes the weights' unit, not the estimate or its covariance
    scaled = fit(lab, row, col, lon, lat, h, band="B2", scheme="exterior", robust="none", sigma_px=0.3)
    np.testing.assert_allclose(scaled.values, base.values, atol=1e-3 * base.sigma.min())
    np.testing.assert_allclose(scaled.sigma, base.sigma, rtol=1e-6)
    assert scaled.sigma0 == pytest.approx(base.sigma0 / 0.3, rel=1e-6)
    # zero-score points do not count, even with absurd coordinates
    junk = np.arange(row.size) % 5 == 0
    row_j = np.where(junk, row + 500.0, row)
    dropped = fit(lab, row_j, col, lon, lat, h, band="B2", scheme="exterior", robust="none", score=np.where(junk, 0.0, 1.0))
    ref = fit(lab, row[~junk], col[~junk], lon[~junk], lat[~junk], h[~junk], band="B2", scheme="exterior", robust="none")
    np.testing.assert_allclose(dropped.values, ref.values, atol=1e-3 * ref.sigma.min())
    assert not dropped.inlier[junk].any() and np.all(dropped.weights[junk] == 0.0)
    assert np.all(np.abs(dropped.residuals_after[junk, 0]) > 100.0)  # still reported


def test_several_bands_share_the_exterior(lab, true):
    b1 = simulate(true, 1500, band="B1", seed=10)
    b3 = simulate(true, 1500, band="B3", seed=11)
    args = [np.concatenate([a, b]) for a, b in zip(b1, b3)]
    band = np.array(["B1"] * 1500 + ["B3"] * 1500)
    result = fit(lab, *args, band=band)
    assert result.success, result.message
    assert {n.split(".")[0] for n in result.names} == {"installation", "B1", "B3"}
    assert 0.01 < grid_rms(true, result.model, band="B1") < 0.15
    assert 0.01 < grid_rms(true, result.model, band="B3") < 0.15
    assert set(result.band) == {"B1", "B3"}


def test_result_serializes_to_strict_json(stepwise):
    d = stepwise.to_dict()
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    assert back["format"] == "gcpcal.calibration" and back["success"] is True
    roll = back["parameters"][0]
    assert roll["name"] == "installation.roll" and roll["unit"] == "rad"
    assert roll["value_arcsec"] == pytest.approx(np.degrees(roll["value"]) * 3600.0)
    assert len(back["covariance"]["matrix"]) == len(back["parameters"])
    assert len(back["points"]["row_residual_after_px"]) == 3000
    assert back["steps"][0]["log"][0]["iteration"] == 0
    assert back["statistics"]["after"]["rms_px"] < 0.5
    assert parameter_unit("B2.ccd1.tan_psi_y.c3") == "detector^-3"
    assert "points" not in stepwise.to_dict(points=False)


def test_ccd_per_point_as_names_indices_or_missing(lab, gcps):
    row, col, lon, lat, h = gcps
    ccd = np.where(col < 512.0, "ccd1", None).astype(object)
    ccd[::3] = (col[::3] >= 512.0).astype(float)  # indices, as read from a CSV column
    a = fit(lab, *gcps, band="B2", ccd=ccd, scheme="exterior")
    b = fit(lab, *gcps, band="B2", scheme="exterior")
    np.testing.assert_array_equal(a.ccd, b.ccd)
    np.testing.assert_array_equal(a.values, b.values)
    with pytest.raises(InputError, match="out of range"):
        fit(lab, *gcps, band="B2", ccd=np.full(row.size, "2.5"))


def test_input_errors(lab, gcps):
    row, col, lon, lat, h = gcps
    with pytest.raises(InputError, match="col"):
        fit(lab, row, col[:-1], lon, lat, h)
    with pytest.raises(InputError, match="unknown band"):
        fit(lab, row, col, lon, lat, h, band="B9")
    with pytest.raises(InputError, match="scheme"):
        fit(lab, row, col, lon, lat, h, scheme="both")
    with pytest.raises(InputError, match="sigma_px"):
        fit(lab, row, col, lon, lat, h, sigma_px=-1.0)
    with pytest.raises(InputError, match="NaN"):
        fit(lab, np.where(row > 100, row, np.nan), col, lon, lat, h)
    with pytest.raises(InputError, match="unknown CCD"):
        fit(lab, row, col, lon, lat, h, ccd="ccd7")


def test_check_points_are_never_fitted(lab, gcps):
    row, col, lon, lat, h = gcps
    kind = np.where(np.arange(row.size) % 4 == 0, "check", "gcp")
    fitted = kind == "gcp"
    row_c = np.where(fitted, row, row + 300.0)  # check points this far off would spoil a fit
    with_checks = fit(lab, row_c, col, lon, lat, h, band="B2", kind=kind, scheme="exterior")
    alone = fit(lab, *(a[fitted] for a in gcps), band="B2", scheme="exterior")
    np.testing.assert_array_equal(with_checks.values, alone.values)
    assert with_checks.residuals_after.shape == (int(fitted.sum()), 2)
    with pytest.raises(InputError, match="kind 'gcp'"):
        fit(lab, row, col, lon, lat, h, kind="check")
    with pytest.raises(InputError, match="GcpTable"):
        calibrate_model(lab, gcps)


# --------------------------------------------------------------------------- covariance
def _z_scores(lab, true, runs, *, scheme, seed0, n_points, **kw):
    truth = true.parameters().as_dict()
    z = []
    for i in range(runs):
        result = fit(lab, *simulate(true, n_points, seed=seed0 + i), band="B2", scheme=scheme, **kw)
        assert result.success, result.message
        z.append([(v - truth[n]) / s for n, v, s in zip(result.names, result.values, result.sigma)])
    return np.array(z)


def test_reported_sigmas_are_not_absurd(lab):
    """Fast version of the coverage test: 10 noise seeds, nothing absurd."""
    true = perturbed(lab, interior=False)
    z = _z_scores(lab, true, 10, scheme="exterior", seed0=100, n_points=800)
    assert np.abs(z).max() < 5.0
    assert 0.3 < np.mean(z * z) < 3.0


@pytest.mark.slow
def test_coverage_of_the_95_percent_intervals(lab):
    """50 noise seeds: the reported 95 % intervals hold the truth about 95 % of the time."""
    true = perturbed(lab, interior=False)
    z_ext = _z_scores(lab, true, 50, scheme="exterior", seed0=1000, n_points=1000)
    true_j = perturbed(lab, gauge_free=("B2", "ccd2"), scale_deg=0.2, seed=3)
    z_joint = _z_scores(lab, true_j, 50, scheme="joint", seed0=2000, n_points=2000, reference_ccd=("B2", "ccd2"))
    for z in (z_ext, z_joint):
        coverage = float(np.mean(np.abs(z) < 1.96))
        assert 0.92 < coverage < 0.98, coverage
        assert 0.8 < float(np.mean(z * z)) < 1.3


# --------------------------------------------------------------------------- RPC bias (real RPC)
def _pleiades(shared_data):
    from sensor_models.readers import open_model

    folder = shared_data / "pleiades_ventoux"
    return open_model(folder / "right_image.geom"), open_model(folder / "right_image_bias.geom")


def _rpc_gcps(rpc, n, seed):
    """Ground points of the right crop (full-scene rows 5162+, cols 4915+) via the good RPC."""
    rng = np.random.default_rng(seed)
    row = rng.uniform(5162.0, 5162.0 + 498.0, n)
    col = rng.uniform(4915.0, 4915.0 + 495.0, n)
    lon, lat, h = rpc.image_to_ground(row, col, height=rng.uniform(400.0, 600.0, n))
    return row, col, lon, lat, h


def test_rpc_bias_offset_recovers_the_60_line_shift(shared_data, tmp_path):
    from calibrate.rpc_bias import compensate_rpc_bias
    from sensor_models.readers.rpc_files import read_rpc, write_rpc

    good, biased = _pleiades(shared_data)
    row, col, lon, lat, h = _rpc_gcps(good, 100, seed=20)
    result = compensate_rpc_bias(biased, row, col, lon, lat, h, terms="offset")
    assert result.success, result.message
    # right_image_bias.geom has line_off + 60: it projects 60 lines too far, a0 brings it back
    assert abs(result.bias["bias.row.a0"] + 60.0) < 1e-3
    assert abs(result.bias["bias.col.b0"]) < 1e-3
    assert result.rms_before_px == pytest.approx(60.0, abs=1e-3)
    assert result.rms_after_px < 1e-3
    assert result.writable
    # written with the RPC writer (bias folded into the offsets) and read back
    path = write_rpc(result.model, tmp_path / "corrected_RPC.TXT")
    back = read_rpc(path)
    r_back, c_back = back.ground_to_image(lon, lat, h)
    r_good, c_good = good.ground_to_image(lon, lat, h)
    assert np.abs(r_back - r_good).max() < 1e-6 and np.abs(c_back - c_good).max() < 1e-6
    json.dumps(result.to_dict(), allow_nan=False)


def test_rpc_bias_affine_with_noise_and_outliers(shared_data):
    from calibrate.rpc_bias import compensate_rpc_bias

    good, biased = _pleiades(shared_data)
    row, col, lon, lat, h = _rpc_gcps(good, 400, seed=21)
    rng = np.random.default_rng(22)
    row = row + rng.normal(0.0, 0.3, row.size)
    col = col + rng.normal(0.0, 0.3, col.size)
    bad = rng.random(row.size) < 0.2
    row[bad] += rng.uniform(5.0, 50.0, bad.sum())
    result = compensate_rpc_bias(biased, row, col, lon, lat, h, terms="affine")
    assert result.success, result.message
    # the affine terms are not identifiable separately from a0 over a 500 px crop of a
    # 40000 px scene; the model is: projections within the noise, a shift of -60 lines
    check_row, check_col, clon, clat, ch = _rpc_gcps(good, 200, seed=23)
    r, c = result.model.ground_to_image(clon, clat, ch)
    assert 0.005 < np.sqrt(np.mean((r - check_row) ** 2 + (c - check_col) ** 2)) < 0.15
    assert (~result.calibration.inlier[bad]).mean() > 0.95
    offset = compensate_rpc_bias(biased, row, col, lon, lat, h, terms="offset")
    z = (offset.bias["bias.row.a0"] + 60.0) / offset.sigma["bias.row.a0"]
    assert abs(z) < 3.0 and 0.005 < offset.sigma["bias.row.a0"] < 0.05


def test_rpc_models_need_the_joint_scheme(shared_data):
    good, _ = _pleiades(shared_data)
    row, col, lon, lat, h = _rpc_gcps(good, 10, seed=24)
    with pytest.raises(InputError, match="scheme='joint'"):
        fit(good, row, col, lon, lat, h)
