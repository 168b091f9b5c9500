"""Star catalogue and apparent directions (sensor_models.geometry.star_catalogue).

Independent reference: astropy (test-only dependency). ``SkyCoord.apply_space_motion`` then
``transform_to(GCRS(obstime, obsgeoloc, obsgeovel))`` gives the proper direction seen by an
observer at ``obsgeoloc`` moving at ``obsgeovel``; we put the observer on a geostationary orbit.
"""

from __future__ import annotations

import numpy as np
import pytest

from sensor_models.errors import InputError, OutOfRangeError
from sensor_models.geometry.star_catalogue import (
    AU_M,
    StarCatalog,
    apparent_directions,
    radec_to_unit,
    unit_to_radec,
)

MAS = np.pi / (180 * 3600 * 1000)
EPOCH = "2024-03-01T12:00:00"
GEO_RADIUS_M = 42_164_172.0
EARTH_RATE = 7.2921159e-5


def _geo_state(lon_deg: float = 30.0):
    lon = np.deg2rad(lon_deg)
    pos = GEO_RADIUS_M * np.array([np.cos(lon), np.sin(lon), 0.0])
    vel = GEO_RADIUS_M * EARTH_RATE * np.array([-np.sin(lon), np.cos(lon), 0.0])
    return pos, vel


def _separation_mas(a, b):
    return 2 * np.arcsin(np.clip(np.linalg.norm(a - b, axis=-1) / 2, 0, 1)) / MAS


@pytest.fixture(scope="module")
def bright():
    return StarCatalog.load(mag_limit=5.0)


@pytest.fixture(scope="module")
def sample(bright):
    """Bright stars with positive parallaxes (astropy needs a distance), plus the fast movers."""
    pick = np.flatnonzero(bright.parallax_mas > 0.5)[::4]
    return bright.select(pick)


# --------------------------------------------------------------------------------------------
# catalogue
# --------------------------------------------------------------------------------------------
def test_load_filters_sorts_and_counts(bright):
    assert np.all(bright.vmag <= 5.0)
    assert np.all(np.diff(bright.vmag) >= 0)
    assert 1_400 < len(bright) < 1_800  # ~1,600 stars brighter than V = 5
    n6 = len(StarCatalog.load(mag_limit=6.0))
    assert 4_800 < n6 < 5_400
    assert len(StarCatalog.load()) == 117_955  # the whole new reduction (I/311)


def test_known_stars(bright):
    """Sirius, Vega, Arcturus: astrometry of I/311 and V within 0.1 mag of the literature."""
    row = {h: i for i, h in enumerate(bright.hip)}
    sirius = row[32349]
    assert np.rad2deg(bright.ra_rad[sirius]) == pytest.approx(101.28854, abs=1e-4)
    assert np.rad2deg(bright.dec_rad[sirius]) == pytest.approx(-16.71314, abs=1e-4)
    assert bright.parallax_mas[sirius] == pytest.approx(379.21, abs=0.01)
    assert bright.pm_ra_cosdec_mas_yr[sirius] == pytest.approx(-546.01, abs=0.005)
    assert bright.pm_dec_mas_yr[sirius] == pytest.approx(-1223.07, abs=0.005)
    for hip, v in ((91262, 0.03), (69673, -0.05), (24608, 0.08), (11767, 1.98)):
        assert abs(bright.vmag[row[hip]] - v) < 0.1, hip
    assert np.all(bright.radial_velocity_km_s == 0.0)
    assert bright.epoch_jyear == 1991.25


def test_load_is_strict(tmp_path):
    with pytest.raises(InputError, match="unknown star catalogue"):
        StarCatalog.load(source="tycho2")
    with pytest.raises(InputError, match="mag_limit"):
        StarCatalog.load(mag_limit=float("nan"))
    bad = tmp_path / "hip2.dat"
    bad.write_text("not a catalogue\n")
    with pytest.raises(InputError, match="hip2.dat"):
        StarCatalog.load(path=bad)
    with pytest.raises(InputError, match="not found"):
        StarCatalog.load(path=tmp_path / "missing.dat")


def test_radec_unit_round_trip():
    rng = np.random.default_rng(3)
    ra = rng.uniform(0, 2 * np.pi, 100)
    dec = rng.uniform(-np.pi / 2, np.pi / 2, 100)
    ra2, dec2 = unit_to_radec(radec_to_unit(ra, dec))
    np.testing.assert_allclose(ra2, ra, atol=1e-12)
    np.testing.assert_allclose(dec2, dec, atol=1e-12)


# --------------------------------------------------------------------------------------------
# apparent directions against astropy
# --------------------------------------------------------------------------------------------
def _astropy_coords(cat: StarCatalog, epoch: str):
    u = pytest.importorskip("astropy.units")
    from astropy.coordinates import Distance, SkyCoord
    from astropy.time import Time

    t = Time(epoch, scale="utc")
    c = SkyCoord(
        ra=cat.ra_rad * u.rad, dec=cat.dec_rad * u.rad,
        distance=Distance(parallax=cat.parallax_mas * u.mas),
        pm_ra_cosdec=cat.pm_ra_cosdec_mas_yr * u.mas / u.yr,
        pm_dec=cat.pm_dec_mas_yr * u.mas / u.yr, radial_velocity=0 * u.km / u.s,
        obstime=Time(cat.epoch_jyear, format="jyear", scale="tdb"), frame="icrs",
    )
    return c.apply_space_motion(new_obstime=t), t


def _unit(xyz):
    v = np.asarray(xyz, dtype=np.float64).T
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_apparent_matches_astropy_gcrs_for_geo_observer(sample):
    """Full chain (space motion, parallax, deflection, annual + orbital aberration) <= 5 mas;
    in fact the two agree to ~1e-4 mas (same ERFA models)."""
    u = pytest.importorskip("astropy.units")
    from astropy.coordinates import GCRS, CartesianRepresentation

    pos, vel = _geo_state()
    moved, t = _astropy_coords(sample, EPOCH)
    frame = GCRS(obstime=t, obsgeoloc=CartesianRepresentation(pos * u.m),
                 obsgeovel=CartesianRepresentation(vel * u.m / u.s))
    ref = _unit(moved.transform_to(frame).cartesian.xyz.value)
    mine = apparent_directions(sample, EPOCH, observer_position_gcrf_m=pos,
                               observer_velocity_gcrf_m_s=vel)
    sep = _separation_mas(mine, ref)
    assert sep.max() < 0.01  # requirement: 5 mas
    np.testing.assert_allclose(np.linalg.norm(mine, axis=1), 1.0, atol=1e-14)


def test_without_aberration_matches_astropy_astrometric(sample):
    """aberration=False, light_deflection=False: the ICRS position propagated by astropy, seen
    from the observer's barycentric position (parallax), agrees to < 0.01 mas; the plain
    barycentric direction differs by the parallax displacement only (<= parallax), so within a
    few mas for distant stars."""
    u = pytest.importorskip("astropy.units")
    from astropy.coordinates import get_body_barycentric

    pos, vel = _geo_state()
    moved, t = _astropy_coords(sample, EPOCH)
    earth = get_body_barycentric("earth", t).xyz.to_value(u.au)
    star_au = moved.cartesian.xyz.to_value(u.au).T
    ref = star_au - (earth + pos / AU_M)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    mine = apparent_directions(sample, EPOCH, observer_position_gcrf_m=pos,
                               observer_velocity_gcrf_m_s=vel, aberration=False,
                               light_deflection=False)
    assert _separation_mas(mine, ref).max() < 0.01
    barycentric = _unit(moved.cartesian.xyz.value)
    shift = _separation_mas(mine, barycentric)
    assert np.all(shift <= sample.parallax_mas * 1.02 + 0.01)
    distant = sample.parallax_mas < 3.0
    assert distant.sum() > 20 and shift[distant].max() < 3.0


def test_aberration_sizes(sample):
    """Satellite velocity adds v/c = 2.115 arcsec at most; Earth's orbit about 20.5 arcsec."""
    pos, vel = _geo_state()
    with_sat = apparent_directions(sample, EPOCH, observer_position_gcrf_m=pos,
                                   observer_velocity_gcrf_m_s=vel)
    no_sat = apparent_directions(sample, EPOCH, observer_position_gcrf_m=pos)
    none = apparent_directions(sample, EPOCH, observer_position_gcrf_m=pos, aberration=False)
    sat = _separation_mas(with_sat, no_sat) / 1000
    v_over_c_arcsec = np.linalg.norm(vel) / 299_792_458.0 * 206_264.806
    assert 0.9 * v_over_c_arcsec < sat.max() <= v_over_c_arcsec * 1.0001
    annual = _separation_mas(no_sat, none) / 1000
    assert 17.0 < annual.max() < 21.0


def test_light_deflection_follows_the_elongation_law():
    """Deflection = 1.7512 arcsec * (R_sun / 1 au) (1 + cos E) / sin E  ~ 4.07 mas at E = 90 deg
    (Urban & Seidelmann 2013, eq. 7.34 with gamma = 1)."""
    import erfa

    cat = StarCatalog.load(mag_limit=4.0)
    with_ld = apparent_directions(cat, EPOCH, aberration=False)
    without = apparent_directions(cat, EPOCH, aberration=False, light_deflection=False)
    from sensor_models.geometry.timescales import tt_jd

    tt1, tt2 = tt_jd(EPOCH, 0.0)
    pvh, _ = erfa.epv00(float(tt1), float(tt2))
    sun_distance_au = np.linalg.norm(pvh["p"])
    sun = -pvh["p"] / sun_distance_au
    elong = np.arccos(without @ sun)
    far = elong > np.deg2rad(20)
    two_gm_over_c2_au = 2 * 1.32712440041e20 / 299_792_458.0**2 / AU_M  # 1.974e-8 rad
    expected = (two_gm_over_c2_au / sun_distance_au * (1 + np.cos(elong[far]))
                / np.sin(elong[far]) / MAS)
    got = _separation_mas(with_ld[far], without[far])
    np.testing.assert_allclose(got, expected, rtol=0.01)
    assert np.min(np.abs(elong[far] - np.pi / 2)) < 0.05
    at_90 = got[np.argmin(np.abs(elong[far] - np.pi / 2))]
    assert 3.9 < at_90 < 4.3


def test_proper_motion_of_barnards_star():
    """HIP 87937 moves 10.39 arcsec/yr: 34.9 years after J1991.25 it has moved ~362 arcsec."""
    cat = StarCatalog.load(mag_limit=10.0)
    barnard = cat.select(np.flatnonzero(cat.hip == 87937))
    moved = apparent_directions(barnard, "2026-06-01T00:00:00", aberration=False,
                                light_deflection=False)
    start = barnard.unit_vectors()
    pm = np.hypot(barnard.pm_ra_cosdec_mas_yr, barnard.pm_dec_mas_yr)[0]
    years = 2026 + 151 / 365.25 - 1991.25
    got = _separation_mas(moved, start)[0]
    # parallax (548 mas) displaces it by up to 0.55 arcsec besides the proper motion
    assert abs(got - pm * years) < 600.0
    assert 10_300 < pm < 10_450


def test_errors():
    cat = StarCatalog.load(mag_limit=2.0)
    with pytest.raises(InputError, match="observer_position_gcrf_m"):
        apparent_directions(cat, EPOCH, observer_position_gcrf_m=[1.0, 2.0])
    with pytest.raises(InputError, match="observer_velocity_gcrf_m_s"):
        apparent_directions(cat, EPOCH, observer_velocity_gcrf_m_s=[np.nan, 0, 0])
    with pytest.raises(InputError, match="StarCatalog"):
        apparent_directions(np.zeros((3, 3)), EPOCH)
    with pytest.raises(OutOfRangeError):
        apparent_directions(cat, "2160-01-01T00:00:00")
