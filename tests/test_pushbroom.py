"""Push-broom directional-angle model: round trips, Jacobians, ranges, CCDs and bands."""

from __future__ import annotations

import numpy as np
import pytest

from sensor_models.errors import InputError, OutOfRangeError
from sensor_models.models.pushbroom_types import Installation
from sensor_models.models.synthetic import example_pushbroom_model

ATTITUDE = dict(
    bias_rad=(2e-4, -3e-4, 1e-3),
    drift_rad_s=(1e-6, -1e-6, 2e-6),
    jitter_amplitude_rad=(2e-6, 2e-6, 1e-6),
    jitter_frequency_hz=1.3,
    noise_rad=0.0,
    seed=7,
)


@pytest.fixture(scope="module")
def model():
    """GCRF orbit, orbital-frame attitude with bias, drift and jitter, 3.5 degree yaw install."""
    return example_pushbroom_model(
        n_rows=1500,
        installation=Installation(1e-3, -2e-3, np.radians(3.55)),
        attitude_kwargs=ATTITUDE,
    )


def _grid(model, ccd, n=100):
    rows = np.linspace(0.5, model.n_rows - 0.5, n)
    cols = np.linspace(ccd.first_col + 0.5, ccd.last_col - 0.5, n)
    r, c = np.meshgrid(rows, cols, indexing="ij")
    return r.ravel(), c.ravel()


@pytest.mark.parametrize("height", [-300.0, 1500.0, 8000.0])
def test_round_trip_every_ccd_and_band(model, height):
    for band, ccds in model.bands.items():
        for i, ccd in enumerate(ccds):
            r, c = _grid(model, ccd)
            lon, lat, h = model.image_to_ground(r, c, height=height, band=band)
            np.testing.assert_allclose(h, height, atol=1e-6)
            r2, c2 = model.ground_to_image(lon, lat, h, band=band, array=i)
            err = np.hypot(r2 - r, c2 - c)
            assert np.sqrt(np.mean(err**2)) <= 1e-4, (band, ccd.name)
            assert err.max() <= 1e-3, (band, ccd.name)


def test_ccd_is_chosen_by_the_ground_point(model):
    ccds = model.band_ccds()
    overlap = 16
    # away from the overlap, an automatic choice finds the CCD that imaged the point
    r = np.full(200, 700.5)
    c = np.concatenate([np.linspace(0.5, ccds[0].last_col - overlap - 2, 100), np.linspace(ccds[1].first_col + overlap + 2, ccds[1].last_col - 0.5, 100)])
    lon, lat, h = model.image_to_ground(r, c, height=0.0)
    r2, c2 = model.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(c2, c, atol=1e-6)
    np.testing.assert_allclose(r2, r, atol=1e-6)


def test_bands_differ_by_their_focal_plane_offsets(model):
    lon, lat, h = model.image_to_ground([700.5], [500.5], height=0.0, band="B2")
    rows = {b: model.ground_to_image(lon, lat, h, band=b)[0][0] for b in model.bands}
    # seed-003-like design: along-track offsets -6, -2, 2, 6 px between B1..B4
    assert rows["B1"] - rows["B4"] == pytest.approx(12.0, abs=0.5)
    assert rows["B2"] == pytest.approx(700.5, abs=1e-6)


def _fd_jacobian(model, lon, lat, h, names, band):
    p = model.parameters()
    idx = p.index(names)
    _, _, jac = model.image_jacobian(lon, lat, h, band=band, names=names)
    fd = np.zeros_like(jac)
    for j, k in enumerate(idx):
        scale = np.abs(jac[:, :, j]).max()
        step = 1e-3 / scale  # moves the image point by about 1e-3 px
        v1, v2 = p.values.copy(), p.values.copy()
        v1[k] += step
        v2[k] -= step
        a = np.stack(model.with_parameters(v1).ground_to_image(lon, lat, h, band=band), -1)
        b = np.stack(model.with_parameters(v2).ground_to_image(lon, lat, h, band=band), -1)
        fd[:, :, j] = (a - b) / (2 * step)
    return jac, fd


def test_analytic_jacobian_matches_central_differences(model):
    rng = np.random.default_rng(3)
    band = "B3"
    ccd = model.band_ccds(band)[1]
    r = rng.uniform(1, model.n_rows - 1, 40)
    c = rng.uniform(ccd.first_col + 20, ccd.last_col - 1, 40)
    lon, lat, h = model.image_to_ground(r, c, height=rng.uniform(0, 3000, 40), band=band)
    names = [n for n in model.parameter_names() if n.startswith("installation") or n.startswith(f"{band}.{ccd.name}.")]
    jac, fd = _fd_jacobian(model, lon, lat, h, names, band)
    rel = np.abs(jac - fd).max(axis=(0, 1)) / np.abs(jac).max(axis=(0, 1))
    assert rel.max() <= 1e-6, dict(zip(names, rel))
    # parameters of another CCD or band do not move these points
    _, _, other = model.image_jacobian(lon, lat, h, band=band, names=["B1.ccd1.tan_psi_y.c0", f"{band}.ccd1.tan_psi_x.c0"])
    assert np.all(other == 0.0)


def test_jacobian_installation_magnitudes(model):
    """A yaw of 1 microradian moves an edge pixel by about its distance from the centre / 1e6."""
    lon, lat, h = model.image_to_ground([750.5], [0.5], height=0.0)
    _, _, jac = model.image_jacobian(lon, lat, h, names=["installation.roll", "installation.pitch", "installation.yaw"])
    ifov = 50.0 / 782_121.0
    # roll moves columns by 1/ifov px per radian, pitch moves rows by the same
    assert abs(jac[0, 1, 0]) == pytest.approx(1 / ifov, rel=0.05)
    assert abs(jac[0, 0, 1]) == pytest.approx(1 / ifov, rel=0.05)
    assert abs(jac[0, 0, 2]) == pytest.approx(2032 / 2, rel=0.1)


def test_with_parameters_round_trip_and_change(model):
    p = model.parameters()
    same = model.with_parameters(p.values)
    lon, lat, h = model.image_to_ground([100.5, 900.5], [10.5, 2000.5], height=100.0)
    np.testing.assert_array_equal(np.stack(same.ground_to_image(lon, lat, h)), np.stack(model.ground_to_image(lon, lat, h)))
    v = p.values.copy()
    v[p.index(["installation.pitch"])] += 10 * 50.0 / 782_121.0  # ten pixels along track
    moved = model.with_parameters(v).ground_to_image(lon, lat, h)[0]
    assert np.all(np.abs(np.abs(moved - model.ground_to_image(lon, lat, h)[0]) - 10) < 0.5)
    with pytest.raises(InputError):
        model.with_parameters(v[:-1])
    assert model.installation.pitch == p.values[1]  # the original is untouched


def test_rows_outside_the_data_are_errors_and_unseen_points_nan(model):
    lo, hi = model.row_range
    with pytest.raises(OutOfRangeError, match="outside the rows"):
        model.image_to_ground([hi + 10.0], [5.0], height=0.0)
    lon, lat, h = model.image_to_ground([model.n_rows / 2], [1000.5], height=0.0)
    r, c = model.ground_to_image(lon + 20.0, lat, h)
    assert np.isnan(r).all() and np.isnan(c).all()
    with pytest.raises(InputError, match="NaN"):
        model.ground_to_image([np.nan], [0.0], [0.0])
    with pytest.raises(InputError, match="exactly one"):
        model.image_to_ground([1.0], [1.0])
    with pytest.raises(InputError, match="unknown band"):
        model.image_to_ground([1.0], [1.0], height=0.0, band="B9")


def test_row_time_and_ground_track_are_consistent(model):
    """Successive lines step by one line period of ground track (about one IFOV on the ground)."""
    lon, lat, h = model.image_to_ground([500.5, 600.5], [1016.5, 1016.5], height=0.0)
    from sensor_models.geometry.geodesy import geodetic_to_ecef

    xyz = geodetic_to_ecef(lon, lat, h)
    step_m = np.linalg.norm(xyz[1] - xyz[0]) / 100.0
    assert 45.0 < step_m < 55.0


def test_round_trip_over_real_srtm(shared_data):
    """Acceptance: image -> DEM -> image over the real SRTM tile (EGM96 heights converted)."""
    from sensor_models.terrain.dem import Dem

    dem = Dem.open(shared_data / "dem" / "N44E005.hgt", vertical_datum="egm96", geoid=shared_data / "dem" / "egm96_15.gtx")
    model = example_pushbroom_model(n_rows=1500, installation=Installation(0.0, 0.0, np.radians(3.55)), attitude_kwargs=ATTITUDE)
    for i, ccd in enumerate(model.band_ccds()):
        r, c = _grid(model, ccd)
        lon, lat, h = model.image_to_ground(r, c, dem=dem)
        inside = np.isfinite(lon)
        assert inside.mean() > 0.6  # the 100 km scene overhangs the 1x1 degree tile
        np.testing.assert_allclose(h[inside], dem.height_m(lon[inside], lat[inside]), atol=1e-3)
        r2, c2 = model.ground_to_image(lon[inside], lat[inside], h[inside], array=i)
        err = np.hypot(r2 - r[inside], c2 - c[inside])
        assert np.sqrt(np.mean(err**2)) <= 1e-4 and err.max() <= 1e-3


def test_points_beyond_the_rows_stop_early_with_the_same_result(model, monkeypatch):
    """Newton stops a point it sends past the line table's edge twice running (it would end
    there: not imaged) instead of stepping against the edge until ``max_iter`` (30 steps); the
    points inside come out bit for bit as when each is solved alone."""
    import sensor_models.models.pushbroom_inverse as inverse

    lo, hi = model.row_range
    rows = np.r_[np.linspace(lo + 5.0, hi - 5.0, 40), np.linspace(hi + 50.0, hi + 900.0, 20),
                 np.linspace(lo - 900.0, lo - 50.0, 20)]
    cols = np.linspace(20.5, model.n_cols - 20.5, rows.size)
    inside = (rows > lo) & (rows < hi)
    lon, lat, h = model.image_to_ground(rows[inside], cols[inside], height=300.0)
    # points beyond the rows: extrapolate the ground track along the scene's first and last lines
    lon_e, lat_e, _ = model.image_to_ground(np.r_[lo + 1.0, hi - 1.0], np.r_[1000.5, 1000.5], height=300.0)
    t = (rows[~inside] - (lo + 1.0)) / ((hi - 1.0) - (lo + 1.0))
    lon = np.r_[lon, lon_e[0] + t * (lon_e[1] - lon_e[0])]
    lat = np.r_[lat, lat_e[0] + t * (lat_e[1] - lat_e[0])]
    h = np.full(lon.size, 300.0)
    calls = []
    collinearity = inverse.collinearity

    def counted(*args, **kwargs):
        calls.append(args[1].size)
        return collinearity(*args, **kwargs)

    monkeypatch.setattr(inverse, "collinearity", counted)
    r, c = model.ground_to_image(lon, lat, h, array=0)
    n_inside = int(inside.sum())
    assert np.isnan(r[n_inside:]).all() and np.isfinite(r[:n_inside]).sum() > 0
    assert len(calls) < 20  # against max_iter = 30 steps with the edge points left running
    # each point alone: its own steps only (a point's Newton steps never depend on the others)
    for k in range(lon.size):
        r1, c1 = model.ground_to_image(lon[k:k + 1], lat[k:k + 1], h[k:k + 1], array=0)
        np.testing.assert_array_equal(r1, r[k:k + 1])
        np.testing.assert_array_equal(c1, c[k:k + 1])
