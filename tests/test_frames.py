"""Tests of sensor_models.geometry.frames and sensor_models.geometry.timescales.

The GCRF -> ITRF rotation is checked against astropy (an independent implementation of the
same IAU 2006/2000A CIO-based chain, used here only as a cross-check) with astropy's bundled
IERS tables and no downloads. Angles are compared as the rotation angle of
``M_ours^T @ M_reference`` and reported in milliarcseconds.
"""

from __future__ import annotations

import datetime as dt

import erfa
import numpy as np
import pytest

from sensor_models.geometry import frames, timescales
from sensor_models.errors import InputError, OutOfRangeError
from sensor_models.geometry.frames import EarthRotation, gcrf_to_itrf_mat, orbital_to_frame_mat

RAD_TO_MAS = 180.0 / np.pi * 3600.0 * 1000.0
GM_EARTH_M3_S2 = 3.986004418e14


def rotation_angle_mas(m_a, m_b):
    """Rotation angle of ``m_a^T m_b`` in mas (from its axial vector: exact for small angles)."""
    r = np.swapaxes(m_a, -1, -2) @ m_b
    axial = 0.5 * np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    return np.arcsin(np.minimum(np.linalg.norm(axial, axis=-1), 1.0)) * RAD_TO_MAS


def random_epochs(rng, count, start="1990-01-01", stop="2026-06-30"):
    lo = np.datetime64(start, "s").astype(np.int64)
    hi = np.datetime64(stop, "s").astype(np.int64)
    picks = rng.integers(lo, hi, count)
    return [np.datetime64(int(s), "s").astype("datetime64[ns]") for s in picks]


# Epochs spanning 1990-2026; the 2016 one straddles the leap second of 2016-12-31 23:59:60.
FIXED_EPOCHS = ["1990-01-01T00:00:00", "2000-01-01T12:00:00", "2016-12-31T23:50:00.25"]


@pytest.fixture(scope="module")
def astropy_offline():
    """astropy with its bundled IERS tables: no download, out-of-range is an error."""
    pytest.importorskip("astropy")
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp(
        "iers_degraded_accuracy", "error"
    ):
        yield


def astropy_gcrs_to_itrs(epoch, seconds):
    """astropy's GCRS -> ITRS matrix: cirs_to_itrs_mat @ gcrs_to_cirs_mat at obstime."""
    import astropy.units as u
    from astropy.coordinates.builtin_frames.intermediate_rotation_transforms import (
        cirs_to_itrs_mat,
        gcrs_to_cirs_mat,
    )
    from astropy.time import Time

    # astropy adds a TimeDelta to a UTC time in TAI, i.e. elapsed SI seconds, as gcpcal does
    obstime = Time(str(epoch), scale="utc", precision=9) + np.asarray(seconds) * u.s
    return cirs_to_itrs_mat(obstime) @ gcrs_to_cirs_mat(obstime), obstime


# ---------------------------------------------------------------------------------------------
# (a) GCRF -> ITRF against astropy
# ---------------------------------------------------------------------------------------------
def test_gcrf_to_itrf_matches_astropy_matrices(astropy_offline):
    rng = np.random.default_rng(20240501)
    epochs = [timescales.parse_utc(e) for e in FIXED_EPOCHS] + random_epochs(rng, 12)
    worst_mas = 0.0
    for epoch in epochs:
        seconds = np.sort(rng.uniform(0.0, 1800.0, 40))
        ours = gcrf_to_itrf_mat(epoch, seconds)
        theirs, _ = astropy_gcrs_to_itrs(epoch, seconds)
        worst_mas = max(worst_mas, rotation_angle_mas(ours, theirs).max())
    print(f"\nGCRF->ITRF vs astropy, {len(epochs)} epochs 1990-2026: max {worst_mas:.3e} mas")
    assert worst_mas <= 1.0  # ARCHITECTURE acceptance


def test_gcrf_to_itrf_matches_astropy_public_transform(astropy_offline):
    """Positions at LEO radius through astropy's public GCRS -> ITRS frame transform."""
    import astropy.units as u
    from astropy.coordinates import GCRS, ITRS, CartesianRepresentation

    rng = np.random.default_rng(7)
    worst_mas = 0.0
    for epoch in ["1995-07-14T03:00:00", "2012-06-30T23:59:30", "2024-02-29T18:30:00.5"]:
        seconds = rng.uniform(0.0, 60.0, 30)
        xyz_gcrf_m = rng.normal(size=(30, 3))
        xyz_gcrf_m *= 7.0e6 / np.linalg.norm(xyz_gcrf_m, axis=1, keepdims=True)
        _, obstime = astropy_gcrs_to_itrs(epoch, seconds)
        gcrs = GCRS(CartesianRepresentation(xyz_gcrf_m.T * u.m), obstime=obstime)
        theirs = gcrs.transform_to(ITRS(obstime=obstime)).cartesian.xyz.to_value(u.m).T
        ours = np.einsum("nij,nj->ni", gcrf_to_itrf_mat(epoch, seconds), xyz_gcrf_m)
        cos_angle = np.einsum("ni,ni->n", ours, theirs) / 7.0e6**2
        sin_angle = np.linalg.norm(np.cross(ours, theirs), axis=1) / 7.0e6**2
        worst_mas = max(worst_mas, (np.arctan2(sin_angle, cos_angle) * RAD_TO_MAS).max())
        np.testing.assert_allclose(np.linalg.norm(theirs, axis=1), 7.0e6, rtol=1e-14)
    print(f"\nGCRS->ITRS positions vs astropy frames: max {worst_mas:.3e} mas")
    assert worst_mas <= 1.0


def test_time_scales_match_astropy(astropy_offline):
    rng = np.random.default_rng(11)
    for epoch in FIXED_EPOCHS + ["2026-06-30T12:00:00"]:
        seconds = rng.uniform(0.0, 1200.0, 20)
        _, obstime = astropy_gcrs_to_itrs(epoch, seconds)
        tt1, tt2 = timescales.tt_jd(epoch, seconds)
        ut11, ut12 = timescales.ut1_jd(epoch, seconds)
        d_tt_s = ((tt1 - obstime.tt.jd1) + (tt2 - obstime.tt.jd2)) * 86400.0
        d_ut1_s = ((ut11 - obstime.ut1.jd1) + (ut12 - obstime.ut1.jd2)) * 86400.0
        assert np.abs(d_tt_s).max() < 1e-9, epoch
        assert np.abs(d_ut1_s).max() < 1e-9, epoch


def test_earth_orientation_matches_astropy_tables(astropy_offline):
    from astropy.time import Time
    from astropy.utils import iers

    table = iers.IERS_Auto.open()
    rng = np.random.default_rng(3)
    mjd = rng.uniform(41684.0, 61300.0, 5000)
    eop = timescales.default_eop()
    t = Time(mjd, format="mjd", scale="utc")
    np.testing.assert_allclose(
        eop.ut1_minus_utc_s(mjd), table.ut1_utc(t).to_value("s"), rtol=0, atol=1e-12
    )
    xp, yp = eop.polar_motion_rad(mjd)
    xp_ref, yp_ref = table.pm_xy(t)
    np.testing.assert_allclose(xp, xp_ref.to_value("rad"), rtol=0, atol=1e-16)
    np.testing.assert_allclose(yp, yp_ref.to_value("rad"), rtol=0, atol=1e-16)


# ---------------------------------------------------------------------------------------------
# (b) fast path against the exact function
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("epoch", "t_start", "t_end"),
    [
        ("2021-03-04T05:06:07.123456", 0.0, 900.0),
        ("2016-12-31T12:00:00", -3600.0, 86400.0),  # a whole day across the leap second
        ("1993-06-30T23:00:00", 0.0, 7200.0),  # leap second of 1993-06-30
        ("2008-02-29T10:00:00", 100.0, 100.0),  # a single instant
    ],
)
def test_earth_rotation_fast_path_matches_exact(epoch, t_start, t_end):
    rng = np.random.default_rng(5)
    seconds = np.concatenate([rng.uniform(t_start, t_end, 400), [t_start, t_end]])
    rotation = EarthRotation(epoch, t_start, t_end)
    error_mas = rotation_angle_mas(
        rotation.gcrf_to_itrf_mat(seconds), gcrf_to_itrf_mat(epoch, seconds)
    )
    print(f"\nEarthRotation vs exact {epoch} [{t_start}, {t_end}] s: max {error_mas.max():.2e} mas")
    assert error_mas.max() < 0.01
    np.testing.assert_array_equal(
        rotation.itrf_to_gcrf_mat(seconds), np.swapaxes(rotation.gcrf_to_itrf_mat(seconds), 1, 2)
    )


def test_earth_rotation_exact_across_leap_second_instant():
    """The UT1 knots at 0h UTC make the fast path exact through 2016-12-31 23:59:60."""
    epoch = "2016-12-31T23:59:00"
    seconds = np.array([59.0, 59.999999, 60.0, 60.5, 61.0, 61.000001, 62.0])
    rotation = EarthRotation(epoch, 0.0, 120.0)
    error_mas = rotation_angle_mas(
        rotation.gcrf_to_itrf_mat(seconds), gcrf_to_itrf_mat(epoch, seconds)
    )
    assert error_mas.max() < 0.01
    # UT1 is continuous across the leap second: ERA advances ~15 arcsec per second throughout
    ut11, ut12 = timescales.ut1_jd(epoch, seconds)
    d_ut1_s = (np.diff(ut11) + np.diff(ut12)) * 86400.0
    np.testing.assert_allclose(d_ut1_s / np.diff(seconds), 1.0, atol=1e-5)


def test_earth_rotation_handles_unsorted_and_shaped_times():
    rng = np.random.default_rng(9)
    rotation = EarthRotation("2019-09-09T09:09:09", 0.0, 5000.0)
    seconds = rng.uniform(0.0, 5000.0, (4, 25))
    mats = rotation.gcrf_to_itrf_mat(seconds)
    assert mats.shape == (4, 25, 3, 3)
    flat = rotation.gcrf_to_itrf_mat(np.sort(seconds.ravel()))
    by_time = mats.reshape(-1, 3, 3)[np.argsort(seconds.ravel())]
    np.testing.assert_allclose(by_time, flat, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# (c) state vectors
# ---------------------------------------------------------------------------------------------
def circular_orbit_gcrf(seconds, radius_m=7.0e6, inclination_rad=1.7):
    """Circular Keplerian orbit in GCRF: positions (m) and velocities (m/s)."""
    n = np.sqrt(GM_EARTH_M3_S2 / radius_m**3)
    u = n * np.asarray(seconds)
    ci, si = np.cos(inclination_rad), np.sin(inclination_rad)
    pos = radius_m * np.stack([np.cos(u), np.sin(u) * ci, np.sin(u) * si], axis=-1)
    vel = radius_m * n * np.stack([-np.sin(u), np.cos(u) * ci, np.cos(u) * si], axis=-1)
    return pos, vel


def test_state_round_trip():
    rng = np.random.default_rng(21)
    rotation = EarthRotation("2022-11-05T01:02:03", 0.0, 3000.0)
    seconds = rng.uniform(0.0, 3000.0, 1000)
    pos_g, vel_g = circular_orbit_gcrf(seconds)
    pos_i, vel_i = rotation.gcrf_to_itrf_state(seconds, pos_g, vel_g)
    pos_back, vel_back = rotation.itrf_to_gcrf_state(seconds, pos_i, vel_i)
    pos_err_m = np.abs(pos_back - pos_g).max()
    vel_err_m_s = np.abs(vel_back - vel_g).max()
    print(f"\nround trip: position {pos_err_m:.1e} m, velocity {vel_err_m_s:.1e} m/s")
    # a few units in the last place of 7e6 m (ulp 9.3e-10 m) and of 7.5e3 m/s (ulp 9.1e-13)
    assert pos_err_m < 1e-8
    assert vel_err_m_s < 1e-11
    # the ITRF speed differs from the inertial one by the Earth-rotation term (~500 m/s)
    assert 1.0 < np.abs(np.linalg.norm(vel_i, axis=1) - np.linalg.norm(vel_g, axis=1)).max() < 600.0


def test_itrf_velocity_is_derivative_of_itrf_position():
    """ITRF velocity against a 4th-order central difference of ITRF positions."""
    rng = np.random.default_rng(33)
    rotation = EarthRotation("2018-04-01T00:00:00", -10.0, 6000.0)
    seconds = rng.uniform(0.0, 5990.0, 200)
    h = 0.25

    def pos_itrf(t):
        pos_g, vel_g = circular_orbit_gcrf(t)
        return rotation.gcrf_to_itrf_state(t, pos_g, vel_g)[0]

    fd_vel = (
        -pos_itrf(seconds + 2 * h) + 8 * pos_itrf(seconds + h)
        - 8 * pos_itrf(seconds - h) + pos_itrf(seconds - 2 * h)
    ) / (12 * h)
    _, vel_i = rotation.gcrf_to_itrf_state(seconds, *circular_orbit_gcrf(seconds))
    err_m_s = np.abs(vel_i - fd_vel).max()
    print(f"\nITRF velocity vs finite difference: max {err_m_s:.1e} m/s")
    assert err_m_s < 1e-6


def test_velocity_term_is_earth_rotation_about_the_cip():
    """v_itrf = M v_gcrf - omega x r_itrf with omega along the CIP (rpom e3), ~7.292115e-5 rad/s."""
    epoch, seconds = "2023-08-15T12:00:00", np.linspace(0.0, 600.0, 50)
    rotation = EarthRotation(epoch, 0.0, 600.0)
    pos_g, vel_g = circular_orbit_gcrf(seconds)
    pos_i, vel_i = rotation.gcrf_to_itrf_state(seconds, pos_g, vel_g)
    m = rotation.gcrf_to_itrf_mat(seconds)
    tai1, tai2 = timescales.tai_jd(epoch, seconds)
    tt1, tt2, _, _, xp, yp = frames._earth_orientation_at(tai1, tai2, timescales.default_eop())
    cip_itrf = erfa.pom00(xp, yp, erfa.sp00(tt1, tt2))[:, :, 2]
    omega = frames.ERA_RATE_RAD_PER_UT1_S * cip_itrf
    expected = np.einsum("nij,nj->ni", m, vel_g) - np.cross(omega, pos_i)
    # difference: length-of-day excess (~1e-8 relative) and precession-nutation rates
    assert np.abs(vel_i - expected).max() < 1e-3
    assert 7.2921e-5 < frames.ERA_RATE_RAD_PER_UT1_S < 7.2922e-5


# ---------------------------------------------------------------------------------------------
# (d) orbital frame
# ---------------------------------------------------------------------------------------------
def test_orbital_frame_axes():
    rng = np.random.default_rng(42)
    seconds = rng.uniform(0.0, 6000.0, 500)
    pos, vel = circular_orbit_gcrf(seconds)
    m = orbital_to_frame_mat(pos, vel)
    assert m.shape == (500, 3, 3)
    identity = np.broadcast_to(np.eye(3), m.shape)
    np.testing.assert_allclose(np.swapaxes(m, 1, 2) @ m, identity, atol=1e-15)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-15)  # right-handed
    x, y, z = m[..., 0], m[..., 1], m[..., 2]
    np.testing.assert_allclose(z, -pos / np.linalg.norm(pos, axis=1, keepdims=True), atol=1e-15)
    np.testing.assert_allclose(x, vel / np.linalg.norm(vel, axis=1, keepdims=True), atol=1e-15)
    h = np.cross(pos, vel)
    np.testing.assert_allclose(y, -h / np.linalg.norm(h, axis=1, keepdims=True), atol=1e-15)
    # v_frame = M @ v_orbital: the orbital +Z axis maps to the direction of the Earth's centre
    np.testing.assert_allclose(m @ np.array([0.0, 0.0, 1.0]), z)


def test_orbital_frame_rejects_degenerate_states():
    with pytest.raises(InputError):
        orbital_to_frame_mat([7e6, 0.0, 0.0], [1.0, 0.0, 0.0])  # velocity along the radius
    with pytest.raises(InputError):
        orbital_to_frame_mat([0.0, 0.0, 0.0], [0.0, 7e3, 0.0])
    with pytest.raises(InputError):
        orbital_to_frame_mat(np.ones((2, 3)), np.ones((3, 3)))


# ---------------------------------------------------------------------------------------------
# (e) ranges and parsing
# ---------------------------------------------------------------------------------------------
def test_earth_orientation_out_of_range():
    eop = timescales.default_eop()
    lo, hi = eop.span_mjd
    assert lo <= 37665.0 and hi >= 61300.0  # 1962 to at least late 2026
    for bad in (lo - 0.5, hi + 0.5, np.nan):
        with pytest.raises(OutOfRangeError, match="astropy-iers-data"):
            eop.ut1_minus_utc_s(np.array([50000.0, bad]))
        with pytest.raises(OutOfRangeError):
            eop.polar_motion_rad(bad)
    eop.ut1_minus_utc_s([lo, hi])  # the end days themselves are inside
    with pytest.raises(OutOfRangeError):
        gcrf_to_itrf_mat("1961-06-01T00:00:00", [0.0])
    with pytest.raises(OutOfRangeError):
        gcrf_to_itrf_mat("2040-01-01T00:00:00", [0.0])
    with pytest.raises(OutOfRangeError):
        EarthRotation("2040-01-01T00:00:00", 0.0, 10.0)


def test_earth_rotation_rejects_times_outside_its_span():
    rotation = EarthRotation("2020-01-01T00:00:00", 10.0, 70.0)
    rotation.gcrf_to_itrf_mat([10.0, 70.0])
    for bad in (9.0, 71.0, np.nan):
        with pytest.raises(OutOfRangeError, match="span"):
            rotation.gcrf_to_itrf_mat([20.0, bad])
    with pytest.raises(InputError):
        EarthRotation("2020-01-01T00:00:00", 10.0, 5.0)
    with pytest.raises(InputError):
        EarthRotation("2020-01-01T00:00:00", 0.0, 5.0, node_spacing_s=601.0)


def test_parse_utc_accepts_iso_datetime_and_datetime64():
    expected = np.datetime64("2021-03-04T05:06:07.123456", "ns")
    assert timescales.parse_utc("2021-03-04T05:06:07.123456Z") == expected
    assert timescales.parse_utc("2021-03-04T05:06:07.123456") == expected
    assert timescales.parse_utc("2021-03-04 05:06:07.123456+00:00") == expected
    assert timescales.parse_utc(dt.datetime(2021, 3, 4, 5, 6, 7, 123456)) == expected
    aware = dt.datetime(2021, 3, 4, 5, 6, 7, 123456, tzinfo=dt.timezone.utc)
    assert timescales.parse_utc(aware) == expected
    assert timescales.parse_utc(np.datetime64("2021-03-04T05:06:07.123456", "us")) == expected
    assert timescales.parse_utc("2021-03-04T05:06:07.123456789Z") == np.datetime64(
        "2021-03-04T05:06:07.123456789", "ns"
    )
    assert timescales.parse_utc("2021-03-04").dtype == np.dtype("datetime64[ns]")


@pytest.mark.parametrize(
    "bad",
    [
        "garbage",
        "",
        "2021-13-01T00:00:00",
        "2021-02-30T00:00:00",
        "2021-03-04T25:00:00",
        "2021-03-04T05:06:07+01:00",
        "2016-12-31T23:59:60Z",
        "2021/03/04 05:06:07",
        "1600-01-01T00:00:00",  # outside datetime64[ns]
        None,
        12345,
        np.datetime64("NaT"),
        dt.datetime(2021, 3, 4, tzinfo=dt.timezone(dt.timedelta(hours=-5))),
    ],
)
def test_parse_utc_rejects_garbage(bad):
    with pytest.raises(InputError):
        timescales.parse_utc(bad)


def test_seconds_are_elapsed_si_seconds_across_a_leap_second():
    """2016-12-31T23:59:59 + 2 SI seconds = 2017-01-01T00:00:00 (23:59:60 in between)."""
    utc1, utc2 = timescales.utc_jd("2016-12-31T23:59:59", [2.0])
    year, month, day, hmsf = erfa.d2dtf("UTC", 6, utc1, utc2)
    assert (year[0], month[0], day[0]) == (2017, 1, 1)
    assert tuple(hmsf[0]) == (0, 0, 0, 0)
    year, month, day, hmsf = erfa.d2dtf("UTC", 6, *timescales.utc_jd("2016-12-31T23:59:59", [1.5]))
    assert (year[0], month[0], day[0], tuple(hmsf[0])) == (2016, 12, 31, (23, 59, 60, 500000))
    tt1, tt2 = timescales.tt_jd("2016-12-31T23:59:59", [0.0])
    tai1, tai2 = timescales.tai_jd("2016-12-31T23:59:59", [0.0])
    assert ((tt1 - tai1) + (tt2 - tai2))[0] * 86400.0 == pytest.approx(32.184, abs=1e-9)
