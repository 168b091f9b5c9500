"""Tests of sensor_models.terrain: geoid, DEM access, ray/ellipsoid and ray/DEM intersection.

The ray/DEM tests compare the first crossing found by :meth:`Dem.intersect` with an
independent brute-force march (steps of 1/100 node spacing, exact geodetic conversions,
bisection) on synthetic terrain built to defeat coarse marching: a steep ridge, a cliff one
pixel wide and a one-pixel spike, seen at 30-45 degrees incidence.
"""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
from affine import Affine

from sensor_models.errors import DemError, GeoidGridMissingError, InputError
from sensor_models.geometry.geodesy import ecef_to_geodetic, enu_basis, geodetic_to_ecef
from sensor_models.terrain.dem import Dem
from sensor_models.terrain.ellipsoid import intersect_ellipsoid
from sensor_models.terrain.geoid import Geoid

ALTITUDE_M = 700e3


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------



@pytest.fixture(autouse=True)
def _no_installed_geoid(monkeypatch):
    """These tests say what happens without a geoid: hide any EGM96 grid installed in PROJ's folders."""
    import sensor_models.terrain.geoid as geoid

    monkeypatch.setattr(geoid, "proj_data_dirs", lambda: [])

def rays_through(lon, lat, h, incidence_deg, azimuth_deg, altitude_m=ALTITUDE_M):
    """Rays from a satellite ``altitude_m`` above ground points, passing through them.

    Returns origins (N, 3), unit directions (N, 3) and the ground points (N, 3), ITRF metres.
    """
    target = geodetic_to_ecef(lon, lat, h)
    east, north, up = enu_basis(lon, lat)
    inc = np.radians(incidence_deg)[..., None]
    az = np.radians(azimuth_deg)[..., None]
    to_sat = np.sin(inc) * (np.sin(az) * east + np.cos(az) * north) + np.cos(inc) * up
    origin = target + altitude_m / np.cos(inc) * to_sat
    return origin, -to_sat, target


def distance_to_ray(xyz, origin, direction):
    return np.linalg.norm(np.cross(xyz - origin, direction), axis=-1)


def geographic_dem(z, lon0, lat0, step_deg):
    """EPSG:4326 DEM whose first node centre is at (lon0, lat0), rows going south."""
    transform = Affine(step_deg, 0.0, lon0 - 0.5 * step_deg, 0.0, -step_deg, lat0 + 0.5 * step_deg)
    return Dem.from_array(z, transform, "EPSG:4326")


def brute_first_crossing(dem, origin, direction, *, step_nodes=0.01, n_bisect=40, batch=16):
    """First ``t`` where ``h_ray - h_dem <= 0``, by a fine exact march then bisection.

    The march runs between the DEM's maximum + 5 m and minimum - 5 m, in steps of
    ``step_nodes`` node spacings horizontally. Independent of Dem.intersect except for
    Dem.height_m (bilinear sampling) and the geodetic conversions.

    Returns
    -------
    t : ndarray, shape (N,)
        Ray parameter of the first crossing (to the bisection's precision, ~1e-9 m).
    step_t : ndarray, shape (N,)
        March step along each ray, metres.
    """
    h_lo, h_hi = dem.height_range_m
    p_top = intersect_ellipsoid(origin, direction, h_hi + 5.0)
    p_bot = intersect_ellipsoid(origin, direction, h_lo - 5.0)
    t_top = np.einsum("ij,ij->i", p_top - origin, direction)
    t_bot = np.einsum("ij,ij->i", p_bot - origin, direction)
    lon, lat, _ = ecef_to_geodetic(p_top)
    up = enu_basis(lon, lat)[2]
    sin_inc = np.sqrt(1.0 - np.einsum("ij,ij->i", up, direction) ** 2)
    step_t = step_nodes * dem.resolution_m / np.maximum(sin_inc, 1e-3)

    def residual(o, d, tt):
        lo, la, hh = ecef_to_geodetic(o[:, None, :] + tt[..., None] * d[:, None, :])
        return hh - dem.height_m(lo, la)

    t_a = np.empty(len(origin))
    t_b = np.empty(len(origin))
    for i in range(0, len(origin), batch):
        sl = slice(i, i + batch)
        n = int(np.ceil(np.max((t_bot[sl] - t_top[sl]) / step_t[sl]))) + 1
        t = t_top[sl, None] + np.minimum(np.arange(n)[None, :] * step_t[sl, None],
                                         (t_bot[sl] - t_top[sl])[:, None])
        below = residual(origin[sl], direction[sl], t) <= 0.0
        assert below.any(axis=1).all(), "brute force: a ray never reaches the surface"
        k = below.argmax(axis=1)
        rows = np.arange(len(t))
        t_a[sl], t_b[sl] = t[rows, np.maximum(k - 1, 0)], t[rows, k]
    for _ in range(n_bisect):
        mid = 0.5 * (t_a + t_b)
        above = residual(origin, direction, mid[:, None])[:, 0] > 0.0
        t_a = np.where(above, mid, t_a)
        t_b = np.where(above, t_b, mid)
    return t_b, step_t


def assert_first_crossing(dem, origin, direction, xyz, *, step_nodes=0.01, max_early=0.05):
    """``xyz`` are the first crossings of the rays, checked against a brute-force march."""
    t_dem = np.einsum("ij,ij->i", xyz - origin, direction)
    t_brute, step_t = brute_first_crossing(dem, origin, direction, step_nodes=step_nodes)
    # Never later than the brute-force first crossing: no crossing missed.
    assert np.all(t_dem <= t_brute + 1e-3)
    # Earlier by more than the brute-force step only where the ray clips a sliver of the
    # surface thinner than that step (at the crest of a ~89 degree ridge a dip of centimetres
    # lasts millimetres along the ray): confirm with a very fine search around the point.
    early = np.nonzero(t_dem < t_brute - step_t - 1e-3)[0]
    assert early.size <= max_early * len(t_dem)
    for i in early:
        tt = t_dem[i] + np.linspace(-0.05, 0.05, 10001)
        lo, la, hh = ecef_to_geodetic(origin[i] + tt[:, None] * direction[i])
        assert np.min(hh - dem.height_m(lo, la)) <= 1e-6  # 1e-6 m: touching counts


def check_on_surface_and_ray(dem, origin, direction, lon, lat, h, xyz, tol_m=1e-3):
    assert np.all(np.isfinite(h))
    np.testing.assert_allclose(h, dem.height_m(lon, lat), rtol=0.0, atol=tol_m)
    assert np.max(distance_to_ray(xyz, origin, direction)) < 1e-6
    lo, la, hh = ecef_to_geodetic(xyz)
    np.testing.assert_allclose(hh, h, rtol=0.0, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# (a) ray / ellipsoid
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("height_m", [-430.0, 0.0, 500.0, 3000.0, 8848.0])
def test_intersect_ellipsoid_is_exact_in_geodetic_height(height_m):
    rng = np.random.default_rng(11)
    n = 2000
    lon = rng.uniform(-180.0, 180.0, n)
    lat = rng.uniform(-85.0, 85.0, n)
    origin, direction, _ = rays_through(lon, lat, height_m, rng.uniform(0.0, 60.0, n),
                                        rng.uniform(0.0, 360.0, n))
    xyz = intersect_ellipsoid(origin, direction, height_m)
    _, _, h = ecef_to_geodetic(xyz)
    assert np.max(np.abs(h - height_m)) < 1e-6
    assert np.max(distance_to_ray(xyz, origin, direction)) < 1e-6
    # The near intersection: 1 m earlier along the ray is above the surface.
    _, _, h_before = ecef_to_geodetic(xyz - direction)
    assert np.all(h_before > height_m)
    # Each ray was built through a point of that height: it is what comes back.
    np.testing.assert_allclose(xyz, geodetic_to_ecef(lon, lat, height_m), rtol=0.0, atol=1e-5)


def test_intersect_ellipsoid_per_ray_heights_shapes_and_misses():
    rng = np.random.default_rng(12)
    heights = rng.uniform(-100.0, 5000.0, 50)
    origin, direction, _ = rays_through(np.full(50, 5.5), np.full(50, 44.5), heights,
                                        rng.uniform(0.0, 45.0, 50), rng.uniform(0.0, 360.0, 50))
    xyz = intersect_ellipsoid(origin, direction, heights)
    assert xyz.shape == (50, 3)
    assert np.max(np.abs(ecef_to_geodetic(xyz)[2] - heights)) < 1e-6
    single = intersect_ellipsoid(origin[0], direction[0], heights[0])
    assert single.shape == (3,)
    np.testing.assert_allclose(single, xyz[0], rtol=0.0, atol=1e-9)
    # Pointing away from the Earth, and passing beside it: NaN.
    away = intersect_ellipsoid(origin[:2], -direction[:2], 0.0)
    assert np.isnan(away).all()
    beside = intersect_ellipsoid([[0.0, 0.0, 8e6]], [[1.0, 0.0, 0.0]], 0.0)
    assert np.isnan(beside).all()
    with pytest.raises(InputError):
        intersect_ellipsoid(origin, np.zeros_like(direction), 0.0)
    with pytest.raises(InputError):
        intersect_ellipsoid(origin, direction, np.nan)


# ---------------------------------------------------------------------------------------------
# (b) synthetic terrain
# ---------------------------------------------------------------------------------------------

STEP_DEG = 1.0e-4  # ~11 m north-south, ~8 m east-west at 45 degrees
LON0, LAT0 = 10.0, 45.05


def node_lonlat(col, row):
    return LON0 + col * STEP_DEG, LAT0 - row * STEP_DEG


def test_flat_dem_equals_ellipsoid_intersection():
    rng = np.random.default_rng(21)
    dem = geographic_dem(np.full((200, 200), 250.0), LON0, LAT0, STEP_DEG)
    lon, lat = node_lonlat(rng.uniform(40, 160, 300), rng.uniform(40, 160, 300))
    origin, direction, _ = rays_through(lon, lat, 250.0, rng.uniform(0.0, 45.0, 300),
                                        rng.uniform(0.0, 360.0, 300))
    lon_d, lat_d, h_d, xyz_d = dem.intersect(origin, direction)
    xyz_e = intersect_ellipsoid(origin, direction, 250.0)
    assert np.max(np.linalg.norm(xyz_d - xyz_e, axis=1)) < 1e-4
    np.testing.assert_allclose(h_d, 250.0, rtol=0.0, atol=1e-4)
    check_on_surface_and_ray(dem, origin, direction, lon_d, lat_d, h_d, xyz_d)


# Synthetic terrain: 480 x 480 nodes (~3.8 x 5.3 km), the feature at node (240, 240) so that
# rays at 45 degrees stay on the DEM between its top and the ground.
N_NODES, MID = 480, 240


def _ridge():
    col = np.arange(N_NODES)[None, :]
    ridge = 100.0 + 1500.0 * np.maximum(0.0, 1.0 - np.abs(col - MID) / 3.0)  # ~89 degrees
    return np.broadcast_to(ridge, (N_NODES, N_NODES)).copy()


def _cliff():
    z = np.full((N_NODES, N_NODES), 50.0)
    z[:, MID:] = 1050.0  # a 1000 m step over one node spacing (~8 m): 89.5 degrees
    return z


def _spike():
    z = np.full((N_NODES, N_NODES), 200.0)
    z[MID, MID] = 1200.0
    return z


@pytest.mark.parametrize(("terrain", "spread_nodes"), [(_ridge, 8.0), (_cliff, 8.0), (_spike, 1.0)],
                         ids=["ridge", "cliff", "spike"])
def test_first_crossing_on_steep_synthetic_terrain(terrain, spread_nodes):
    rng = np.random.default_rng(31)
    z = terrain()
    dem = geographic_dem(z, LON0, LAT0, STEP_DEG)
    n = 240
    # Aim at surface points around the feature from all azimuths at 30-45 degrees.
    lon, lat = node_lonlat(rng.uniform(MID - spread_nodes, MID + spread_nodes, n),
                           rng.uniform(MID - spread_nodes, MID + spread_nodes, n))
    h_aim = np.nan_to_num(dem.height_m(lon, lat))
    origin, direction, _ = rays_through(lon, lat, h_aim, rng.uniform(30.0, 45.0, n),
                                        rng.uniform(0.0, 360.0, n))
    lon_d, lat_d, h_d, xyz_d = dem.intersect(origin, direction, outside="raise")
    check_on_surface_and_ray(dem, origin, direction, lon_d, lat_d, h_d, xyz_d)

    assert_first_crossing(dem, origin, direction, xyz_d)
    # The feature matters: many rays stop on it, well above the flat level.
    assert np.mean(h_d > np.min(z) + 50.0) > 0.25


def test_one_pixel_spike_is_hit_by_grazing_rays():
    # Rays from the north at 45 degrees through points 50 m under the spike's top (1000 m
    # above the plain, one node wide), offset east-west: those within 0.05 node of its axis
    # clip the tip, over less than a node of their track (slivers a half-pixel march
    # misses); the others fly past it.
    dem = geographic_dem(_spike(), LON0, LAT0, STEP_DEG)
    offsets = np.linspace(-0.06, 0.06, 36)  # none exactly at +-0.05 (tangent rays)
    lon, lat = node_lonlat(MID + offsets, np.full(offsets.size, float(MID)))
    origin, direction, _ = rays_through(lon, lat, np.full(offsets.size, 1150.0),
                                        np.full(offsets.size, 45.0), np.full(offsets.size, 0.0))
    lon_d, lat_d, h_d, xyz_d = dem.intersect(origin, direction)
    check_on_surface_and_ray(dem, origin, direction, lon_d, lat_d, h_d, xyz_d)
    assert_first_crossing(dem, origin, direction, xyz_d, step_nodes=0.002, max_early=1.0)
    on_spike = h_d > 1000.0
    assert np.array_equal(on_spike, np.abs(offsets) < 0.05)


def test_outside_policies_and_nodata():
    z = np.full((100, 100), 300.0)
    z[40:45, 40:45] = np.nan
    dem = geographic_dem(z, LON0, LAT0, STEP_DEG)
    lon, lat = node_lonlat(np.array([20.0, 42.0, 150.0]), np.array([20.0, 42.0, 20.0]))
    origin, direction, _ = rays_through(lon, lat, np.full(3, 300.0), np.zeros(3), np.zeros(3))

    lon_d, lat_d, h_d, xyz_d = dem.intersect(origin, direction)  # default: NaN
    assert np.isfinite(h_d[0]) and np.isnan(h_d[1:]).all() and np.isnan(xyz_d[1:]).all()

    with pytest.raises(DemError, match="2 of 3 rays"):
        dem.intersect(origin, direction, outside="raise")

    lon_f, lat_f, h_f, xyz_f = dem.intersect(origin, direction, outside=123.0)
    np.testing.assert_allclose(h_f[1:], 123.0, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(xyz_f[1:], intersect_ellipsoid(origin[1:], direction[1:], 123.0),
                               rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(xyz_f[0], xyz_d[0], rtol=0.0, atol=1e-9)
    with pytest.raises(InputError):
        dem.intersect(origin, direction, outside="clip")


def test_from_array_validation():
    z = np.zeros((10, 10))
    transform = Affine(STEP_DEG, 0.0, LON0, 0.0, -STEP_DEG, LAT0)
    with pytest.raises(GeoidGridMissingError, match="geoid="):
        Dem.from_array(z, transform, "EPSG:4326", vertical_datum="egm96")
    with pytest.raises(InputError):
        Dem.from_array(z, transform, "EPSG:4326", vertical_datum="navd88")
    with pytest.raises(DemError):
        Dem.from_array(np.full((10, 10), np.nan), transform, "EPSG:4326")
    with pytest.raises(DemError, match="contradicts"):
        Dem.from_array(z, transform, "EPSG:4326+5773", vertical_datum="ellipsoid")
    geoid = Geoid(np.full((3, 3), 40.0), Affine(10.0, 0.0, -5.0, 0.0, -10.0, 55.0))
    dem = Dem.from_array(z, transform, "EPSG:4326", vertical_datum="egm96", geoid=geoid)
    assert dem.height_range_m == (40.0, 40.0)


def test_geoid_longitude_wrap():
    # A global grid given over 0..360 degrees: values are a smooth function of longitude.
    lon_c = np.arange(0.0, 360.0, 10.0)
    lat_c = np.arange(90.0, -90.1, -10.0)
    values = np.cos(np.radians(lon_c))[None, :] * np.cos(np.radians(lat_c))[:, None] * 30.0
    geoid = Geoid(values, Affine(10.0, 0.0, -5.0, 0.0, -10.0, 95.0))
    lon = np.array([-175.0, -5.0, 5.0, 175.0, 355.0, 185.0, 360.0])
    lat = np.full(lon.size, 20.0)
    n = geoid.undulation_m(lon, lat)
    np.testing.assert_allclose(n, geoid.undulation_m(lon + 360.0, lat), rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(n[[0, 1]], geoid.undulation_m(lon[[0, 1]] + 360.0, lat[[0, 1]]))
    assert abs(geoid.undulation_m(-5.0, 20.0) - geoid.undulation_m(355.0, 20.0)) < 1e-12
    # Bilinear across the 350 -> 0 degree seam: halfway between the two columns.
    seam = geoid.undulation_m(355.0, 20.0)
    expected = 0.5 * (values[7, 35] + values[7, 0])
    assert abs(seam - expected) < 1e-12


# ---------------------------------------------------------------------------------------------
# (c) real data: SRTM tile N44E005 and EGM96
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def srtm(shared_data):
    hgt = shared_data / "dem" / "N44E005.hgt"
    gtx = shared_data / "dem" / "egm96_15.gtx"
    geoid = Geoid.open(gtx)
    return hgt, gtx, geoid, Dem.open(hgt, vertical_datum="egm96", geoid=geoid)


def test_egm96_undulation_over_the_tile(srtm):
    _, _, geoid, _ = srtm
    n = geoid.undulation_m(np.array([5.0, 5.5, 6.0]), np.array([44.0, 44.5, 45.0]))
    assert np.all((45.0 < n) & (n < 55.0))
    # Global grid with columns at -180..179.75: continuous across the antimeridian.
    assert abs(geoid.undulation_m(180.0, 10.0) - geoid.undulation_m(-180.0, 10.0)) < 1e-9
    assert np.isfinite(geoid.undulation_m(179.9, 10.0))


def test_srtm_heights_are_raw_plus_undulation_at_nodes(srtm):
    import rasterio

    hgt, _, geoid, dem = srtm
    with rasterio.open(hgt) as ds:
        raw = ds.read(1).astype(np.float64)
        nodata = ds.nodata
    rng = np.random.default_rng(41)
    rows = rng.integers(1, 1200, 400)
    cols = rng.integers(1, 1200, 400)
    block = np.stack([raw[rows + dr, cols + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
    keep = np.all(block != nodata, axis=0)
    rows, cols = rows[keep], cols[keep]
    lon, lat = 5.0 + cols / 1200.0, 45.0 - rows / 1200.0
    expected = raw[rows, cols] + geoid.undulation_m(lon, lat)
    np.testing.assert_allclose(dem.height_m(lon, lat), expected, rtol=0.0, atol=1e-6)
    lo, la, hi, ha = dem.bounds_lonlat
    assert (lo, la, hi, ha) == pytest.approx((5.0, 44.0, 6.0, 45.0), abs=1e-9)
    assert 60.0 < dem.resolution_m < 70.0  # 3 arc-seconds of longitude at 44.5 N
    assert dem.height_range_m[0] > 0.0 and dem.height_range_m[1] < 2900.0


def test_srtm_rays_from_orbit_land_on_the_surface(srtm):
    _, _, _, dem = srtm
    rng = np.random.default_rng(42)
    n = 20000
    lon = rng.uniform(5.1, 5.9, n)
    lat = rng.uniform(44.1, 44.9, n)
    h = dem.height_m(lon, lat)
    keep = np.isfinite(h)
    lon, lat, h = lon[keep], lat[keep], h[keep]
    origin, direction, target = rays_through(lon, lat, h, rng.uniform(0.0, 30.0, lon.size),
                                             rng.uniform(0.0, 360.0, lon.size))
    lon_d, lat_d, h_d, xyz_d = dem.intersect(origin, direction)
    ok = np.isfinite(h_d)
    assert ok.mean() > 0.98  # the rest pass over SRTM voids (nodata) before the surface
    check_on_surface_and_ray(dem, origin[ok], direction[ok], lon_d[ok], lat_d[ok], h_d[ok],
                             xyz_d[ok], tol_m=1e-4)
    # The target lies on the surface: the first crossing is there or, when the terrain hides
    # it, earlier along the ray; never later.
    t_dem = np.einsum("ij,ij->i", xyz_d[ok] - origin[ok], direction[ok])
    t_target = np.einsum("ij,ij->i", target[ok] - origin[ok], direction[ok])
    assert np.all(t_dem <= t_target + 1e-3)
    assert np.mean(np.abs(t_dem - t_target) < 1e-3) > 0.97


def test_srtm_windowed_read_matches_full_tile(srtm):
    hgt, gtx, _, dem = srtm
    small = Dem.open(hgt, vertical_datum="egm96", geoid=gtx, bounds=(5.2, 44.2, 5.3, 44.3),
                     margin_deg=0.01)
    assert small.shape[0] < 200 and small.shape[1] < 200
    lo, la, hi, ha = small.bounds_lonlat
    assert lo <= 5.19 and la <= 44.19 and hi >= 5.31 and ha >= 44.31
    rng = np.random.default_rng(43)
    lon, lat = rng.uniform(5.2, 5.3, 500), rng.uniform(44.2, 44.3, 500)
    np.testing.assert_allclose(small.height_m(lon, lat), dem.height_m(lon, lat), rtol=0.0,
                               atol=1e-9, equal_nan=True)
    with pytest.raises(DemError, match="do not overlap"):
        Dem.open(hgt, vertical_datum="egm96", geoid=gtx, bounds=(7.0, 44.2, 7.1, 44.3),
                 margin_deg=0.01)


def test_srtm_datum_errors(srtm, tmp_path):
    hgt, _, _, _ = srtm
    with pytest.raises(DemError, match="--dem-datum egm96"):
        Dem.open(hgt)
    with pytest.raises(GeoidGridMissingError, match="geoid="):
        Dem.open(hgt, vertical_datum="egm96")
    missing = tmp_path / "no_such_egm96.gtx"
    with pytest.raises(GeoidGridMissingError, match="no_such_egm96.gtx"):
        Dem.open(hgt, vertical_datum="egm96", geoid=missing)
    with pytest.raises(GeoidGridMissingError, match="no_such_egm96.gtx"):
        Geoid.open(missing)
    with pytest.raises(DemError, match="not found"):
        Dem.open(tmp_path / "no_such_dem.tif", vertical_datum="ellipsoid")


# ---------------------------------------------------------------------------------------------
# (d) projected CRS
# ---------------------------------------------------------------------------------------------

UTM31 = "EPSG:32631"
E0, N0 = 660000.0, 4930000.0  # near 5.0 E, 44.5 N


def _plane(e, n):
    return 400.0 + 0.05 * (e - E0) - 0.08 * (n - N0)


def _write_utm_dem(path, crs, offset_m=0.0):
    import rasterio

    spacing = 30.0
    n = 160
    transform = Affine(spacing, 0.0, E0, 0.0, -spacing, N0)
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    e = transform.c + transform.a * cols
    nn = transform.f + transform.e * rows
    z = (_plane(e, nn) - offset_m).astype(np.float64)
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float64",
                       crs=crs, transform=transform, nodata=-9999.0) as ds:
        ds.write(z, 1)
    return transform


def test_projected_dem_heights_and_intersection(tmp_path):
    path = tmp_path / "utm_plane.tif"
    _write_utm_dem(path, UTM31)
    dem = Dem.open(path, vertical_datum="ellipsoid")
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", UTM31, always_xy=True)
    lon0, lat0, lon1, lat1 = dem.bounds_lonlat
    rng = np.random.default_rng(51)
    lon = rng.uniform(lon0 + 0.01, lon1 - 0.01, 500)
    lat = rng.uniform(lat0 + 0.01, lat1 - 0.01, 500)
    e, n = to_utm.transform(lon, lat)
    # Bilinear interpolation of a plane is the plane: exact.
    np.testing.assert_allclose(dem.height_m(lon, lat), _plane(e, n), rtol=0.0, atol=1e-6)
    assert 29.0 < dem.resolution_m < 31.0

    # The same surface on a geographic grid: heights agree to the (tiny) bilinear error of a
    # plane in UTM seen in lon/lat.
    step = 2.5e-4
    lon_g = np.arange(lon0, lon1, step)
    lat_g = np.arange(lat1, lat0, -step)
    lon_n, lat_n = np.meshgrid(lon_g, lat_g)
    z_geo = _plane(*to_utm.transform(lon_n, lat_n))
    geo = geographic_dem(z_geo, lon_g[0], lat_g[0], step)
    np.testing.assert_allclose(geo.height_m(lon, lat), dem.height_m(lon, lat), rtol=0.0,
                               atol=1e-4)

    h = dem.height_m(lon, lat)
    origin, direction, target = rays_through(lon, lat, h, rng.uniform(0.0, 40.0, lon.size),
                                             rng.uniform(0.0, 360.0, lon.size))
    lon_p, lat_p, h_p, xyz_p = dem.intersect(origin, direction, outside="raise")
    check_on_surface_and_ray(dem, origin, direction, lon_p, lat_p, h_p, xyz_p, tol_m=1e-4)
    assert np.max(np.linalg.norm(xyz_p - target, axis=1)) < 1e-3  # a plane hides nothing
    _, _, _, xyz_g = geo.intersect(origin, direction, outside="raise")
    assert np.max(np.linalg.norm(xyz_g - xyz_p, axis=1)) < 1e-3


def test_vertical_datum_from_compound_crs(tmp_path):
    path = tmp_path / "utm_egm96.tif"
    _write_utm_dem(path, f"{UTM31}+5773", offset_m=47.0)
    with pytest.raises(GeoidGridMissingError, match="geoid="):
        Dem.open(path)
    with pytest.raises(DemError, match="contradicts"):
        Dem.open(path, vertical_datum="ellipsoid")
    geoid = Geoid(np.full((5, 5), 47.0), Affine(1.0, 0.0, 2.5, 0.0, -1.0, 46.5))
    dem = Dem.open(path, geoid=geoid)  # EGM96 taken from the metadata
    lon0, lat0, lon1, lat1 = dem.bounds_lonlat
    lon, lat = 0.5 * (lon0 + lon1), 0.5 * (lat0 + lat1)
    e, n = pyproj.Transformer.from_crs("EPSG:4326", UTM31, always_xy=True).transform(lon, lat)
    assert abs(dem.height_m(lon, lat) - _plane(e, n)) < 1e-6
