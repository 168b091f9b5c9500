"""RPC localization over a DEM by Newton's method against the bracketed search and GDAL, on the
real Pleiades RPCs and SRTM of ``../shared/data`` (skipped when absent).

``RpcModel.image_to_ground(..., dem=)`` takes Newton's method in (lon, lat, h) when the DEM gives
its slopes (:meth:`Dem.height_and_slope_m`) and the bracketed (Illinois) search otherwise, or for
the points Newton leaves. Both must give the same points (the 1 mm height tolerance apart), every
point within 1e-4 px of the RPC and 1 mm of the DEM, on the real terrain, on steeper terrain
(SRTM's relief multiplied), over voids and across the DEM's edge.
"""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from sensor_models.models.rpc_dem import derivative_coefficients, rpc00b_monomials
from sensor_models.readers.rpc_files import read_rpc, rpc_to_rasterio
from sensor_models.terrain.dem import Dem


class HeightsOnly:
    """The DEM without its slopes: ``image_to_ground`` then takes the bracketed search."""

    def __init__(self, dem):
        self.height_m = dem.height_m
        self.height_range_m = dem.height_range_m


@pytest.fixture(scope="module")
def srtm(shared_data):
    d = shared_data / "dem"
    return Dem.open(d / "N44E005.hgt", vertical_datum="egm96", geoid=d / "egm96_15.gtx")


@pytest.fixture(scope="module", params=["left_image", "right_image"])
def rpc(request, shared_data):
    return read_rpc(shared_data / "pleiades_ventoux" / f"{request.param}.geom")


def _pixels(rpc, n, margin=300.0, seed=5):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-margin, rpc.image_shape[0] + margin, n),
            rng.uniform(-margin, rpc.image_shape[1] + margin, n))


def _check_against_bracketed(rpc, dem, rows, cols):
    """Newton's points against the bracketed search's; returns both finite masks."""
    lon, lat, h = rpc.image_to_ground(rows, cols, dem=dem)
    blon, blat, bh = rpc.image_to_ground(rows, cols, dem=HeightsOnly(dem))
    found, bfound = np.isfinite(lon), np.isfinite(blon)
    # every point the bracketed search finds, Newton finds (it may find more: the bracketed
    # search needs both ends of the DEM's height range on the DEM)
    assert not np.any(bfound & ~found)
    for x, y, z, f in ((lon, lat, h, found), (blon, blat, bh, bfound)):
        r, c = rpc.ground_to_image(x[f], y[f], z[f])
        assert np.max(np.maximum(abs(r - rows[f]), abs(c - cols[f]))) <= 1.0001e-4
        assert np.max(np.abs(dem.height_m(x[f], y[f]) - z[f])) <= 1.0001e-3
    both = found & bfound
    d_m = np.hypot((lon - blon)[both] * np.cos(np.radians(lat[both])), (lat - blat)[both]) * 111_320.0
    assert d_m.max() < 5e-3 and np.max(np.abs(h - bh)[both]) < 5e-3
    return found, bfound


def test_real_terrain_matches_the_bracketed_search(rpc, srtm):
    rows, cols = _pixels(rpc, 20000)
    found, bfound = _check_against_bracketed(rpc, srtm, rows, cols)
    assert found.all() and bfound.all()  # the scenes lie inside the tile


def test_steep_terrain_voids_and_edges(rpc, srtm):
    z = np.asarray(srtm.heights_m)
    rows, cols = _pixels(rpc, 20000)
    # relief multiplied by 4 (slopes up to about 4 x 45 degrees): still one crossing per ray
    steep = Dem.from_array(400.0 + 4.0 * (z - 400.0), srtm.transform, "EPSG:4326")
    found, _ = _check_against_bracketed(rpc, steep, rows, cols)
    assert found.all()
    # voids punched in and a DEM whose edge cuts the scene
    rng = np.random.default_rng(3)
    zv = z.copy()
    for _ in range(300):
        i, j = rng.integers(0, 1200, 2)
        zv[i:i + rng.integers(1, 15), j:j + rng.integers(1, 15)] = np.nan
    part = Dem.from_array(zv[700:1000, 250:450], srtm.transform @ Affine.translation(250, 700), "EPSG:4326")
    found, bfound = _check_against_bracketed(rpc, part, rows, cols)
    assert 0.05 < bfound.mean() <= found.mean() < 0.6


def test_agrees_with_gdal_rpc_transformer(rpc, srtm, tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import RPCTransformer

    z = np.asarray(srtm.heights_m, dtype=np.float32)
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs="EPSG:4326", transform=srtm.transform, nodata=np.nan) as ds:
        ds.write(z, 1)
    dem = Dem.open(path, vertical_datum="ellipsoid")  # the heights GDAL reads
    rows, cols = _pixels(rpc, 5000, margin=0.0)
    lon, lat, h = rpc.image_to_ground(rows, cols, dem=dem)
    with RPCTransformer(rpc_to_rasterio(rpc), RPC_DEM=str(path), RPC_DEMINTERPOLATION="bilinear",
                        RPC_PIXEL_ERROR_THRESHOLD=1e-4) as gdal:
        glon, glat = (np.asarray(v, dtype=np.float64) for v in gdal.xy(rows, cols, offset="ul"))
    assert np.isfinite(lon).all() and np.isfinite(glon).all()
    d_m = np.hypot((lon - glon) * np.cos(np.radians(lat)), lat - glat) * 111_320.0
    assert d_m.max() < 2e-3  # GDAL stops its height search at its own tolerance


def test_one_matrix_product_gives_the_derivatives(rpc):
    rng = np.random.default_rng(0)
    L, P, H = (rng.uniform(-1.0, 1.0, 50) for _ in range(3))
    coef = np.stack([rpc.line_num, rpc.line_den, rpc.samp_num, rpc.samp_den], axis=1)
    V = derivative_coefficients(coef).T @ rpc00b_monomials(L, P, H)
    eps = 1e-6
    for axis in range(3):
        hi, lo = [L, P, H], [L, P, H]
        hi[axis], lo[axis] = [L, P, H][axis] + eps, [L, P, H][axis] - eps
        numeric = coef.T @ (rpc00b_monomials(*hi) - rpc00b_monomials(*lo)) / (2 * eps)
        np.testing.assert_allclose(V[4 * (axis + 1):4 * (axis + 2)], numeric, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(V[:4], coef.T @ rpc00b_monomials(L, P, H))


@pytest.mark.parametrize("crs", ["EPSG:4326", "EPSG:32631"])
def test_dem_slopes_are_the_derivatives_of_its_heights(crs):
    from rasterio.transform import from_origin

    rng = np.random.default_rng(1)
    z = 300.0 + np.cumsum(np.cumsum(rng.normal(size=(60, 50)), axis=0), axis=1)
    origin = (5.0, 45.0, 1e-3) if crs == "EPSG:4326" else (650_000.0, 4_985_000.0, 30.0)
    dem = Dem.from_array(z, from_origin(origin[0], origin[1], origin[2], origin[2]), crs)
    lon0, lat0, lon1, lat1 = dem.bounds_lonlat
    lon = rng.uniform(lon0, lon1, 400)
    lat = rng.uniform(lat0, lat1, 400)
    h, d_lon, d_lat = dem.height_and_slope_m(lon, lat)
    np.testing.assert_array_equal(np.isfinite(h), np.isfinite(dem.height_m(lon, lat)))
    ok = np.isfinite(h)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(h[ok], dem.height_m(lon, lat)[ok], rtol=0, atol=1e-9)
    eps = 1e-8
    num_lon = (dem.height_m(lon + eps, lat) - dem.height_m(lon - eps, lat)) / (2 * eps)
    num_lat = (dem.height_m(lon, lat + eps) - dem.height_m(lon, lat - eps)) / (2 * eps)
    scale = np.abs(num_lon[ok]).max()
    np.testing.assert_allclose(d_lon[ok], num_lon[ok], rtol=0, atol=1e-3 * scale)
    np.testing.assert_allclose(d_lat[ok], num_lat[ok], rtol=0, atol=1e-3 * scale)
