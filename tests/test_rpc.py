"""Tests of the RPC00B model: reading, conventions, bias, Jacobian, DEM intersection, writing
through GDAL, and fitting an RPC to other sensor models.

Real data: the Pleiades Ventoux crops and their OSSIM ``.geom`` RPCs in ``../shared/data``
(see its README); tests needing them use the ``shared_data`` fixture and skip without it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import RPCTransformer

from sensor_models.base import SensorModel
from sensor_models.errors import InputError, RpcError
from sensor_models.geometry.geodesy import ecef_to_geodetic, enu_basis, geodetic_to_ecef
from sensor_models.models.rpc import BIAS_NAMES
from sensor_models.readers.rpc_files import read_rpc, rpc_from_rasterio, write_rpc
from sensor_models.models.rpc_fit import fit_rpc

HEIGHTS_M = (0.0, 450.0, 1075.0, 1900.0)


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ventoux(shared_data):
    return shared_data / "pleiades_ventoux"


@pytest.fixture(scope="module")
def left(ventoux):
    return read_rpc(ventoux / "left_image.geom")


def image_grid(model, n=15, margin=0.5):
    n_rows, n_cols = model.image_shape
    r, c = np.meshgrid(
        np.linspace(margin, n_rows - margin, n), np.linspace(margin, n_cols - margin, n),
        indexing="ij",
    )
    return r.ravel(), c.ravel()


def ground_grid(model, n=15, heights=HEIGHTS_M):
    """Ground points covering the image at several heights (localized with ``model``)."""
    r, c = image_grid(model, n)
    lons, lats, hs = [], [], []
    for h in heights:
        lon, lat, hh = model.image_to_ground(r, c, height=h)
        lons.append(lon), lats.append(lat), hs.append(hh)
    return np.concatenate(lons), np.concatenate(lats), np.concatenate(hs)


def gdal_rowcol(rpcs, lon, lat, h):
    """GDAL's RPC transformer, ground -> continuous (row, col), no rounding."""
    with RPCTransformer(rpcs) as tr:
        rows, cols = tr.rowcol(lon, lat, h, op=np.positive)
    return np.asarray(rows, dtype=float), np.asarray(cols, dtype=float)


def write_sparse_raster(path, shape):
    """An empty, sparse GeoTIFF without georeferencing (GDAL then looks for RPC side-cars)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        _write_sparse(path, shape)


def _write_sparse(path, shape):
    with rasterio.open(path, "w", driver="GTiff", width=shape[1], height=shape[0], count=1,
                       dtype="uint8", tiled=True, sparse_ok=True):  # fmt: skip
        pass


class FrameCamera(SensorModel):
    """A synthetic oblique frame camera over Ventoux: smooth, non-polynomial in (lon, lat, h).

    Central projection from 694 km, about 25 degrees off nadir, through an equidistant
    (``r = f * theta``) lens; heights are ellipsoidal. Only for tests.
    """

    kind = "test_frame"

    def __init__(self, shape=(6000, 5000), gsd_m=0.5):
        self._shape = shape
        target = geodetic_to_ecef(5.28, 44.14, 1000.0)
        self.centre = geodetic_to_ecef(5.28, 44.14 - 2.9, 694e3)  # to the south, looks north
        z = target - self.centre
        z /= np.linalg.norm(z)
        east, _, _ = enu_basis(5.28, 44.14)
        x = east - z * np.dot(east, z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        self.rot = np.stack([y, x, z])  # rows: image row axis, image col axis, boresight
        self.f_px = np.linalg.norm(target - self.centre) / gsd_m

    @property
    def image_shape(self):
        return self._shape

    def _to_angles(self, row, col):
        u = (row - self._shape[0] / 2.0) / self.f_px
        v = (col - self._shape[1] / 2.0) / self.f_px
        return u, v

    def ground_to_image(self, lon, lat, h, *, band=None):
        xyz = geodetic_to_ecef(lon, lat, h) - self.centre
        cam = xyz @ self.rot.T
        t = np.hypot(cam[..., 0], cam[..., 1]) / cam[..., 2]
        ratio = np.where(t > 0, np.arctan(t) / np.where(t > 0, t, 1.0), 1.0)  # theta / tan(theta)
        u = cam[..., 0] / cam[..., 2] * ratio
        v = cam[..., 1] / cam[..., 2] * ratio
        return u * self.f_px + self._shape[0] / 2.0, v * self.f_px + self._shape[1] / 2.0

    def image_to_ground(self, row, col, *, height=None, dem=None, band=None):
        row, col, height = np.broadcast_arrays(*(np.asarray(a, float) for a in (row, col, height)))
        u, v = self._to_angles(row, col)
        theta = np.hypot(u, v)
        s = np.where(theta > 0, np.sin(theta) / np.where(theta > 0, theta, 1.0), 1.0)
        d_cam = np.stack([u * s, v * s, np.cos(theta)], axis=-1)
        d = d_cam @ self.rot  # camera -> ECEF
        t = np.full(row.shape, 694e3 / 0.9)
        for _ in range(8):  # Newton on the ellipsoidal height along the ray
            p = self.centre + t[..., None] * d
            lon, lat, hh = ecef_to_geodetic(p)
            _, _, up = enu_basis(lon, lat)
            t = t - (hh - height) / np.sum(d * up, axis=-1)
        lon, lat, hh = ecef_to_geodetic(self.centre + t[..., None] * d)
        return lon, lat, hh

    def parameters(self):
        raise NotImplementedError

    def with_parameters(self, values):
        raise NotImplementedError

    def image_jacobian(self, lon, lat, h, *, band=None, names=None):
        raise NotImplementedError


class SteepDem:
    """A synthetic DEM: a plane rising 3 m per metre northwards (72 degrees), clipped to
    [0, 2000] m, plus 100 m east-west waves; NaN outside a 0.2-degree box."""

    height_range_m = (-100.0, 2100.0)

    def __init__(self, lon0, lat0):
        self.lon0, self.lat0 = lon0, lat0

    def height_m(self, lon_deg, lat_deg):
        lon_deg, lat_deg = np.asarray(lon_deg, float), np.asarray(lat_deg, float)
        north_m = (lat_deg - self.lat0) * 111_000.0
        east_m = (lon_deg - self.lon0) * 111_000.0 * np.cos(np.radians(self.lat0))
        h = np.clip(1000.0 + 3.0 * north_m, 0.0, 2000.0) + 100.0 * np.sin(east_m / 300.0)
        outside = (np.abs(lon_deg - self.lon0) > 0.1) | (np.abs(lat_deg - self.lat0) > 0.1)
        return np.where(outside, np.nan, h)


@pytest.fixture(scope="module")
def frame_fit():
    cam = FrameCamera()
    rpc, report = fit_rpc(cam, height_range_m=(-100.0, 2100.0))
    return cam, rpc, report


# ---------------------------------------------------------------------------------------------
# (a) reading the .geom files; round trips
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["left_image", "right_image", "right_image_bias"])
def test_geom_reads_and_round_trips(ventoux, name):
    model = read_rpc(ventoux / f"{name}.geom")
    assert model.kind == "rpc"
    assert model.image_shape[0] > 40_000 and model.image_shape[1] > 38_000  # full scene
    r, c = image_grid(model, 21)
    for h in HEIGHTS_M:
        lon, lat, hh = model.image_to_ground(r, c, height=h)
        assert np.all(np.isfinite(lon)) and np.all(hh == h)
        r2, c2 = model.ground_to_image(lon, lat, hh)
        assert np.max(np.abs(r2 - r)) <= 1e-6
        assert np.max(np.abs(c2 - c)) <= 1e-6
        lon2, lat2, _ = model.image_to_ground(r2, c2, height=h)
        assert np.max(np.abs(lon2 - lon)) < 1e-10 and np.max(np.abs(lat2 - lat)) < 1e-10


def test_left_geom_values(left):
    """Spot values read from left_image.geom, and the documented pixel convention."""
    assert left.image_shape == (41801, 39182)
    assert left.line_off == 21109.5 and left.samp_scale == 19999.5
    assert left.line_num[2] == pytest.approx(-1.03205102244059, rel=0, abs=0)
    # at the normalized origin only the constant terms act: row = line_off + c0 * scale + 0.5
    row, col = left.ground_to_image(left.lon_off, left.lat_off, left.height_off)
    assert row == pytest.approx(left.line_off + 0.5 + left.line_num[0] * left.line_scale, abs=1e-9)
    assert col == pytest.approx(left.samp_off + 0.5 + left.samp_num[0] * left.samp_scale, abs=1e-9)


def test_band_and_height_arguments(left):
    with pytest.raises(InputError, match="band"):
        left.ground_to_image(5.28, 44.13, 500.0, band="P")
    with pytest.raises(InputError, match="exactly one"):
        left.image_to_ground(100.0, 100.0)
    with pytest.raises(InputError, match="exactly one"):
        left.image_to_ground(100.0, 100.0, height=0.0, dem=SteepDem(5.28, 44.14))
    with pytest.raises(InputError, match="NaN"):
        left.ground_to_image([5.28, np.nan], 44.13, 500.0)


# ---------------------------------------------------------------------------------------------
# (b) written through GDAL and read back
# ---------------------------------------------------------------------------------------------
def test_written_rpc_agrees_through_gdal(left, tmp_path):
    lon, lat, h = ground_grid(left)
    r_ref, c_ref = left.ground_to_image(lon, lat, h)

    # GeoTIFF RPC tag, written by GDAL (through rasterio)
    tif = write_rpc(left, tmp_path / "left_rpc.tif")
    with rasterio.open(tif) as src:
        assert (src.height, src.width) == left.image_shape
        gdal_rpcs = src.rpcs
    # side-cars beside rasters that have no RPC of their own: GDAL must find and use them
    write_sparse_raster(tmp_path / "a.tif", left.image_shape)
    txt = write_rpc(left, tmp_path / "a_RPC.TXT")
    write_sparse_raster(tmp_path / "b.tif", left.image_shape)
    rpb = write_rpc(left, tmp_path / "b.RPB")
    with rasterio.open(tmp_path / "a.tif") as src:
        txt_rpcs = src.rpcs
    with rasterio.open(tmp_path / "b.tif") as src:
        rpb_rpcs = src.rpcs
    assert txt_rpcs is not None and rpb_rpcs is not None

    candidates = {
        "geotiff, our reader": read_rpc(tif),
        "_RPC.TXT, our reader": read_rpc(txt),
        ".RPB, our reader": read_rpc(rpb),
        "_RPC.TXT side-car via GDAL": read_rpc(tmp_path / "a.tif"),
        ".RPB side-car via GDAL": rpc_from_rasterio(rpb_rpcs),
    }
    for label, model in candidates.items():
        r, c = model.ground_to_image(lon, lat, h)
        assert np.max(np.abs(r - r_ref)) <= 1e-6, label
        assert np.max(np.abs(c - c_ref)) <= 1e-6, label
    # GDAL's own transformer on what GDAL read: the same coordinates (see the convention test)
    for label, rpcs in (("geotiff", gdal_rpcs), ("txt", txt_rpcs), ("rpb", rpb_rpcs)):
        r, c = gdal_rowcol(rpcs, lon, lat, h)
        assert np.max(np.abs(r - r_ref)) <= 1e-6, label
        assert np.max(np.abs(c - c_ref)) <= 1e-6, label
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["left_rpc.tif", "a.tif", "a_RPC.TXT", "b.tif", "b.RPB"]
    ), "temporary files left behind"


def test_write_refuses_cross_terms_and_leaves_nothing(left, tmp_path):
    biased = left.with_parameters([1.0, 0.0, 1e-6, 0.0, 0.0, 0.0])
    with pytest.raises(RpcError, match="fit_rpc"):
        write_rpc(biased, tmp_path / "x_RPC.TXT")
    with pytest.raises(RpcError, match="format"):
        write_rpc(left, tmp_path / "x.dat")
    assert list(tmp_path.iterdir()) == []


def test_raster_without_rpc_is_an_error(ventoux):
    with pytest.raises(RpcError, match="no RPC"):
        read_rpc(ventoux / "left_image.tif")


# ---------------------------------------------------------------------------------------------
# (c) pixel conventions: OSSIM .geom, GDAL metadata, GDAL's transformer, crop geotransform
# ---------------------------------------------------------------------------------------------
def test_pixel_convention_against_gdal(ventoux, left, tmp_path):
    with rasterio.open(ventoux / "left_image.tif") as src:
        gt = src.transform
        crop_shape = (src.height, src.width)
        assert src.crs is None and (gt.a, gt.b, gt.d, gt.e) == (1.0, 0.0, 0.0, 1.0)
    col0, row0 = gt.c, gt.f  # full-scene column and row of the crop's first pixel (corner)
    assert (row0, col0) == (5000.0, 5000.0)

    crop = left.cropped(int(row0), int(col0), crop_shape)
    out = write_rpc(crop, tmp_path / "left_crop.tif", template=ventoux / "left_image.tif")
    with rasterio.open(out) as src:
        assert src.transform == gt  # the pixels and geotransform came through
        rpcs = src.rpcs
    from_gdal = read_rpc(out)
    assert from_gdal.image_shape == crop_shape

    # ground points under the crop, at several heights
    lon, lat, h = ground_grid(crop, n=9)
    r_geom, c_geom = left.ground_to_image(lon, lat, h)  # full scene, from the .geom
    r_ours, c_ours = from_gdal.ground_to_image(lon, lat, h)  # crop, from GDAL's metadata
    assert np.max(np.abs(r_ours + row0 - r_geom)) <= 1e-6
    assert np.max(np.abs(c_ours + col0 - c_geom)) <= 1e-6

    # GDAL's transformer gives corner-based coordinates (first pixel's centre at 0.5): the same
    # as ours, i.e. GDAL adds 0.5 to the RPC's line/samp (whose first pixel centre is at 0)
    r_gdal, c_gdal = gdal_rowcol(rpcs, lon, lat, h)
    assert np.max(np.abs(r_gdal - r_ours)) <= 1e-6
    assert np.max(np.abs(c_gdal - c_ours)) <= 1e-6

    # the raw RPC equation (RPC space) is exactly 0.5 px less
    L = (lon - crop.lon_off) / crop.lon_scale
    P = (lat - crop.lat_off) / crop.lat_scale
    H = (h - crop.height_off) / crop.height_scale
    t = np.stack([np.ones_like(L), L, P, H, L * P, L * H, P * H, L**2, P**2, H**2, P * L * H,
                  L**3, L * P**2, L * H**2, L**2 * P, P**3, P * H**2, L**2 * H, P**2 * H, H**3])
    line_rpc = (crop.line_num @ t) / (crop.line_den @ t) * crop.line_scale + crop.line_off
    samp_rpc = (crop.samp_num @ t) / (crop.samp_den @ t) * crop.samp_scale + crop.samp_off
    assert np.max(np.abs(r_ours - (line_rpc + 0.5))) <= 1e-6
    assert np.max(np.abs(c_ours - (samp_rpc + 0.5))) <= 1e-6

    # inverse: GDAL's xy(offset="center") of crop pixel (i, j) is our point (i + 0.5, j + 0.5)
    with RPCTransformer(rpcs, RPC_PIXEL_ERROR_THRESHOLD=1e-6) as tr:
        xs, ys = tr.xy([0, 250, 499], [0, 100, 499], zs=[500.0, 500.0, 500.0], offset="center")
    r_back, c_back = crop.ground_to_image(np.asarray(xs), np.asarray(ys), 500.0)
    np.testing.assert_allclose(r_back, [0.5, 250.5, 499.5], atol=1e-3)
    np.testing.assert_allclose(c_back, [0.5, 100.5, 499.5], atol=1e-3)


# ---------------------------------------------------------------------------------------------
# (d) the 60-line bias of right_image_bias.geom
# ---------------------------------------------------------------------------------------------
def test_bias_geom_is_sixty_lines(ventoux, tmp_path):
    right = read_rpc(ventoux / "right_image.geom")
    biased = read_rpc(ventoux / "right_image_bias.geom")
    lon, lat, h = ground_grid(right)
    r0, c0 = right.ground_to_image(lon, lat, h)
    r1, c1 = biased.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(r1 - r0, 60.0, rtol=0, atol=1e-8)
    np.testing.assert_allclose(c1 - c0, 0.0, rtol=0, atol=1e-8)

    # the same shift as a bias parameter, in both directions
    corrected = right.with_parameters([60.0, 0, 0, 0, 0, 0])
    assert corrected.parameters().as_dict()["bias.row.a0"] == 60.0
    r2, c2 = corrected.ground_to_image(lon, lat, h)
    assert np.max(np.abs(r2 - r1)) <= 1e-8 and np.max(np.abs(c2 - c1)) <= 1e-8
    lon2, lat2, _ = corrected.image_to_ground(r1, c1, height=h)
    lon3, lat3, _ = biased.image_to_ground(r1, c1, height=h)
    assert np.max(np.abs(lon2 - lon3)) < 1e-10 and np.max(np.abs(lat2 - lat3)) < 1e-10

    # writing folds a0 into line_off: the biased .geom comes back
    folded = read_rpc(write_rpc(corrected, tmp_path / "right_RPC.TXT"))
    assert folded.line_off == pytest.approx(biased.line_off, abs=1e-9)


def test_general_bias_is_inverted(left):
    bias = [3.5, 2e-5, -1e-5, -7.25, 4e-6, 3e-5]
    model = left.with_parameters(bias)
    r, c = image_grid(model, 11)
    for h in (200.0, 1500.0):
        lon, lat, hh = model.image_to_ground(r, c, height=h)
        r2, c2 = model.ground_to_image(lon, lat, hh)
        assert np.max(np.abs(r2 - r)) <= 1e-6 and np.max(np.abs(c2 - c)) <= 1e-6
    # and the bias is the documented affine form in the RPC's image coordinates
    lon, lat, h = ground_grid(left, n=5)
    rr, cc = left.ground_to_image(lon, lat, h)
    r, c = model.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(r, rr + bias[0] + bias[1] * rr + bias[2] * cc, rtol=0, atol=1e-8)
    np.testing.assert_allclose(c, cc + bias[3] + bias[4] * rr + bias[5] * cc, rtol=0, atol=1e-8)


# ---------------------------------------------------------------------------------------------
# (e) analytic bias Jacobian against central finite differences
# ---------------------------------------------------------------------------------------------
def test_bias_jacobian_matches_finite_differences(left):
    rng = np.random.default_rng(20030101)
    model = left.with_parameters([1.0, 1e-5, -2e-5, -3.0, 5e-6, 1e-5])
    n_rows, n_cols = model.image_shape
    r = rng.uniform(0.5, n_rows - 0.5, 50)
    c = rng.uniform(0.5, n_cols - 0.5, 50)
    lon, lat, h = left.image_to_ground(r, c, height=rng.uniform(200, 1800, 50))
    row, col, jac = model.image_jacobian(lon, lat, h)
    assert jac.shape == (50, 2, 6)
    r0, c0 = model.ground_to_image(lon, lat, h)
    assert np.array_equal(row, r0) and np.array_equal(col, c0)
    values = model.parameters().values
    for k, name in enumerate(BIAS_NAMES):
        step = 1e-3 if name.endswith("0") else 1e-7
        up, down = values.copy(), values.copy()
        up[k] += step
        down[k] -= step
        rp, cp = model.with_parameters(up).ground_to_image(lon, lat, h)
        rm, cm = model.with_parameters(down).ground_to_image(lon, lat, h)
        fd = np.stack([(rp - rm), (cp - cm)], axis=1) / (2 * step)
        scale = np.max(np.abs(jac[:, :, k]))
        assert np.max(np.abs(fd - jac[:, :, k])) <= 1e-6 * scale, name
    # a subset, in the order asked
    _, _, sub = model.image_jacobian(lon, lat, h, names=["bias.col.b2", "bias.row.a0"])
    np.testing.assert_array_equal(sub, jac[:, :, [5, 0]])
    with pytest.raises(InputError, match="unknown"):
        model.image_jacobian(lon, lat, h, names=["bias.row.z9"])


# ---------------------------------------------------------------------------------------------
# (f) fitting an RPC to other models
# ---------------------------------------------------------------------------------------------
def test_fit_reproduces_the_pleiades_rpc(left):
    biased = left.with_parameters([12.0, 3e-5, -2e-5, -4.0, 1e-5, 2e-5])  # cross terms too
    rpc, report = fit_rpc(biased, height_range_m=(200.0, 1900.0))
    assert report["check_max_px"] <= 0.01 and report["fit_max_px"] <= 0.01
    assert report["n_check"] == 42 * 42 * 12 and report["n_fit"] == 21 * 21 * 7
    assert report["min_abs_denominator"] > 0.5
    # independent of the report: random points inside the scene and height range
    rng = np.random.default_rng(7)
    n_rows, n_cols = left.image_shape
    r = rng.uniform(0.5, n_rows - 0.5, 2000)
    c = rng.uniform(0.5, n_cols - 0.5, 2000)
    lon, lat, h = biased.image_to_ground(r, c, height=rng.uniform(200, 1900, 2000))
    r2, c2 = rpc.ground_to_image(lon, lat, h)
    assert np.max(np.hypot(r2 - r, c2 - c)) <= 0.01


def test_fit_reproduces_a_non_polynomial_camera(frame_fit):
    cam, rpc, report = frame_fit
    assert report["check_max_px"] <= 0.01, report
    assert report["fit_max_px"] <= 0.01, report
    assert rpc.image_shape == cam.image_shape
    rng = np.random.default_rng(11)
    r = rng.uniform(0.5, cam.image_shape[0] - 0.5, 3000)
    c = rng.uniform(0.5, cam.image_shape[1] - 0.5, 3000)
    lon, lat, h = cam.image_to_ground(r, c, height=rng.uniform(-100, 2100, 3000))
    r2, c2 = rpc.ground_to_image(lon, lat, h)
    assert np.max(np.hypot(r2 - r, c2 - c)) <= 0.01


def test_fit_rejects_bad_options(frame_fit):
    cam = frame_fit[0]
    with pytest.raises(InputError):
        fit_rpc(cam, height_range_m=(100.0, 0.0))
    with pytest.raises(InputError):
        fit_rpc(cam, height_range_m=(0.0, 100.0), grid_shape=(21, 21, 2))


# ---------------------------------------------------------------------------------------------
# DEM intersection on steep terrain seen obliquely
# ---------------------------------------------------------------------------------------------
def test_dem_intersection_on_steep_slopes(frame_fit):
    _, rpc, _ = frame_fit
    dem = SteepDem(5.28, 44.14)
    r, c = image_grid(rpc, 25, margin=0.5)
    lon, lat, h = rpc.image_to_ground(r, c, dem=dem)
    assert np.all(np.isfinite(h))
    assert np.max(np.abs(dem.height_m(lon, lat) - h)) <= 1e-3
    r2, c2 = rpc.ground_to_image(lon, lat, h)
    # inversions inside the DEM search stop at 1e-4 px (issue 17: converge only as far as needed)
    assert np.max(np.abs(r2 - r)) <= 1e-4 and np.max(np.abs(c2 - c)) <= 1e-4
    # the plain fixed point h <- dem(lon(h), lat(h)) does not converge here (slope x tan(view))
    hh = np.full(r.shape, 1000.0)
    for _ in range(50):
        lo, la, _ = rpc.image_to_ground(r, c, height=hh)
        hh = dem.height_m(lo, la)
    assert np.max(np.abs(hh - h)) > 1.0
    # with a bias, and away from the DEM
    shifted = rpc.with_parameters([5.0, 1e-4, 0, -3.0, 0, 2e-4])
    lon, lat, h = shifted.image_to_ground(r, c, dem=dem)
    r2, c2 = shifted.ground_to_image(lon, lat, h)
    # 1e-4 px in the RPC's own pixels, scaled by the bias (1 + 2e-4 at most here)
    assert np.max(np.abs(r2 - r)) <= 1.001e-4 and np.max(np.abs(c2 - c)) <= 1.001e-4
    lon, lat, h = rpc.image_to_ground(r, c, dem=SteepDem(7.0, 44.14))  # DEM elsewhere
    assert np.all(np.isnan(lon) & np.isnan(lat) & np.isnan(h))


# ---------------------------------------------------------------------------------------------
# (g) malformed files
# ---------------------------------------------------------------------------------------------
def _edit_geom(src, dst, key, value=None):
    lines = []
    for line in src.read_text().splitlines():
        if line.split(":", 1)[0].strip() == key:
            if value is None:
                continue
            line = f"{key}:  {value}"
        lines.append(line)
    dst.write_text("\n".join(lines) + "\n")
    return dst


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("line_num_coeff_07", None, "missing"),
        ("samp_scale", "abc", "not a number"),
        ("lat_off", None, "missing"),
        ("height_scale", "nan", "not a finite number"),
        ("samp_den_coeff_19", "1.0e-3x", "not a number"),
        ("polynomial_format", "A", "unsupported"),
        ("adjustment_0.adj_param_0.parameter", "1.5", "adjustment"),
    ],
)
def test_malformed_geom_names_the_field(ventoux, tmp_path, key, value, message):
    bad = _edit_geom(ventoux / "left_image.geom", tmp_path / "bad.geom", key, value)
    with pytest.raises(RpcError, match=message) as info:
        read_rpc(bad)
    assert info.value.field == key
    assert str(bad) in str(info.value) and key in str(info.value)


def test_malformed_rpb_and_txt_name_the_field(left, tmp_path):
    txt = write_rpc(left, tmp_path / "x_RPC.TXT")
    text = txt.read_text().replace("LINE_DEN_COEFF_5:", "LINE_DEN_COEFF_X:")
    txt.write_text(text)
    with pytest.raises(RpcError, match="LINE_DEN_COEFF_5"):
        read_rpc(txt)
    rpb = write_rpc(left, tmp_path / "x.RPB")
    rpb.write_text(rpb.read_text().replace("sampScale = ", "sampScale = x"))
    with pytest.raises(RpcError, match="sampScale"):
        read_rpc(rpb)
    with pytest.raises(RpcError, match="cannot read"):
        read_rpc(tmp_path / "absent.geom")


def test_image_shape_of_standalone_files(left, tmp_path):
    rpb = write_rpc(left, tmp_path / "x.RPB")
    derived = read_rpc(rpb)  # an .RPB holds no image size: centred on the offsets
    assert derived.image_shape == (2 * 21109 + 2, 2 * 19207 + 2)
    assert read_rpc(rpb, image_shape=left.image_shape).image_shape == left.image_shape
    tif = write_rpc(left, tmp_path / "x.tif")
    with pytest.raises(RpcError, match="contradicts"):
        read_rpc(tif, image_shape=(10, 10))


@pytest.mark.shared_data
def test_rpc_height_range_is_the_terrain_under_the_scene_not_the_whole_tile(shared_data, tmp_path):
    """A 250 m Pleiades crop over a 1-degree SRTM tile (-54..2946 m): the fit spans the heights under the crop."""
    import json

    from calibrate.cli import main

    folder, dem = shared_data / "pleiades_ventoux", shared_data / "dem"
    argv = ["-q", "rpc", str(folder / "left_image.tif"), "--dem", str(dem / "N44E005.hgt"), "--dem-datum", "egm96",
            "--geoid", str(dem / "egm96_15.gtx"), "--out", str(tmp_path / "l_RPC.TXT")]
    assert main(argv) == 0
    lo, hi = json.loads((tmp_path / "l_RPC.TXT.summary.json").read_text())["height_range_m"]
    # SRTM under the crop: 441-505 m above EGM96, about +51 m to the ellipsoid (../shared/data/README.md)
    assert 250.0 < lo < 490.0 and 560.0 < hi < 900.0
