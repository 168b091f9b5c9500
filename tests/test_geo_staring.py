"""Geostationary staring camera (seed 000 eq. 3-11, seed 002): geometry, Jacobians, lab fit, manifest."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from affine import Affine

from sensor_models.errors import InputError, ManifestError
from sensor_models.models.geo_staring import GeoStaringModel
from sensor_models.models.synthetic import GF4_LIKE_CAMERA, GF4_LIKE_SHAPE, SEED000_CAMERA, example_geo_staring_model
from sensor_models.models.star_directions import radec_to_vectors
from sensor_models.models.staring_camera import PointingMirror, StaringInterior, StaringLab, fit_interior
from sensor_models.geometry.geodesy import geodetic_to_ecef
from sensor_models.models.pushbroom_types import Installation
from sensor_models.readers.geo_manifest import (geo_manifest_to_dict, read_geo_manifest, read_geo_manifest_and_rasters,
                                                write_geo_manifest)
from sensor_models.terrain.dem import Dem

ARCSEC = np.radians(1.0 / 3600.0)
#: a laboratory camera with every term of seed 002 table 1, on seed 000's array (larger
#: distortion than the table so that it shows on 1024 pixels)
LAB = StaringLab(
    focal_length_mm=1251.0,
    pixel_size_mm=0.025,
    principal_point_px=(512.0 - 0.0015, 512.0 - 0.0015),
    radial_k=(4e-8, 0.0),
    decentering_p=(6e-7, -3e-7),
    tilt_rad=(-8 * ARCSEC, -8 * ARCSEC),
    rotation_rad=-8 * ARCSEC,
)
ATTITUDE = dict(bias_rad=(-0.04, 0.02, 0.003), drift_rad_s=(1e-7, -1e-7, 2e-7), jitter_amplitude_rad=(1e-6, 1e-6, 1e-6), jitter_frequency_hz=0.1, seed=5)
INSTALL = Installation(72 * ARCSEC, -72 * ARCSEC, 72 * ARCSEC)  # seed 002 table 2
FOLD = PointingMirror((0.0, 1.0, -1.0))  # 45 degrees: camera +Z folded onto +Y


@pytest.fixture(scope="module")
def pointed():
    """Seed 000 camera with lab distortion, installation error, looking at about 13 S, 112 E."""
    return example_geo_staring_model(camera=LAB, image_shape=(1024, 1024), installation=INSTALL, attitude_kwargs=ATTITUDE)


@pytest.fixture(scope="module")
def mirrored():
    """A fold mirror (roll 90 degrees brings the folded view back to nadir), frame at 30 s."""
    model = example_geo_staring_model(camera=LAB, image_shape=(1024, 1024), installation=Installation(np.pi / 2 + 1e-3, -2e-3, 5e-3), mirror=FOLD, attitude_kwargs=ATTITUDE)
    return model.at_frame(30.0, mirror_angles=(0.01, -0.02))


def _grid(model, n=48):
    rows = np.linspace(0.5, model.n_rows - 0.5, n)
    cols = np.linspace(0.5, model.n_cols - 0.5, n)
    r, c = np.meshgrid(rows, cols, indexing="ij")
    return r.ravel(), c.ravel()


# --------------------------------------------------------------------------- geometry
def test_nadir_sub_satellite_point_and_sampling():
    model = example_geo_staring_model()  # zero attitude and installation, pinhole
    lon, lat, h = model.image_to_ground([512.0], [512.0], height=0.0)
    xyz = geodetic_to_ecef(lon, lat, h)[0]
    assert np.linalg.norm(xyz - geodetic_to_ecef(105.0, 0.0, 0.0)) < 1e-3  # metres
    row, col = model.ground_to_image([105.0], [0.0], [0.0])
    assert abs(row[0] - 512.0) < 1e-6 and abs(col[0] - 512.0) < 1e-6
    # the boresight object vector points from the satellite to the Earth's centre (GCRF)
    centre = -model.position_gcrf_m / np.linalg.norm(model.position_gcrf_m)
    assert np.linalg.norm(model.object_vector_gcrf([512.0], [512.0])[0] - centre) < 1e-12
    # seed 000 table 1: 25 um / 1250 mm = 20 urad, ~716 m from 35 786 km; north up, east right
    lon, lat, h = model.image_to_ground([512.0, 512.0, 612.0], [512.0, 612.0, 512.0], height=0.0)
    step = np.linalg.norm(np.diff(geodetic_to_ecef(lon, lat, h)[[0, 1]], axis=0)) / 100.0
    assert 715.0 < step < 717.0
    assert lon[1] > lon[0] and lat[2] < lat[0]
    gf4 = example_geo_staring_model(camera="gf4")
    lon, lat, h = gf4.image_to_ground([5120.0, 5120.0], [5120.0, 5130.0], height=0.0)
    step = np.linalg.norm(np.diff(geodetic_to_ecef(lon, lat, h), axis=0)) / 10.0
    assert 49.9 < step < 50.1


@pytest.mark.parametrize("height", [-400.0, 0.0, 3000.0, 8848.0])
def test_round_trip_over_the_frame(pointed, height):
    r, c = _grid(pointed)
    lon, lat, h = pointed.image_to_ground(r, c, height=height)
    assert np.all(np.isfinite(lon))
    np.testing.assert_allclose(h, height, atol=1e-5)
    r2, c2 = pointed.ground_to_image(lon, lat, h)
    assert np.hypot(r2 - r, c2 - c).max() <= 1e-6


def test_round_trip_gf4_like_and_mirror(mirrored):
    gf4 = example_geo_staring_model(camera="gf4", attitude_kwargs=ATTITUDE, installation=INSTALL)
    for model in (gf4, mirrored):
        r, c = _grid(model, 40)
        lon, lat, h = model.image_to_ground(r, c, height=500.0)
        r2, c2 = model.ground_to_image(lon, lat, h)
        assert np.hypot(r2 - r, c2 - c).max() <= 1e-6


def test_round_trip_on_a_dem(pointed):
    lon0, lat0, _ = pointed.image_to_ground([512.0], [512.0], height=0.0)
    step = 0.01
    n = 600
    west, north = float(lon0[0]) - 3.0, float(lat0[0]) + 3.0
    lon_n, lat_n = np.meshgrid(west + step * (np.arange(n) + 0.5), north - step * (np.arange(n) + 0.5))
    z = 1500.0 + 1200.0 * np.sin(3.1 * lon_n) * np.cos(2.3 * lat_n) + 300.0 * np.sin(17 * lon_n) * np.sin(13 * lat_n)
    dem = Dem.from_array(z, Affine(step, 0.0, west, 0.0, -step, north), "EPSG:4326")
    r, c = _grid(pointed, 60)
    inner = (r > 100) & (r < 924) & (c > 100) & (c < 924)  # the DEM covers about 3 degrees around
    r, c = r[inner], c[inner]
    lon, lat, h = pointed.image_to_ground(r, c, dem=dem)
    assert np.all(np.isfinite(lon))
    assert h.max() - h.min() > 2000.0  # the rays met the relief
    np.testing.assert_allclose(h, dem.height_m(lon, lat), atol=1e-3)
    r2, c2 = pointed.ground_to_image(lon, lat, h)
    assert np.hypot(r2 - r, c2 - c).max() <= 1e-6


def test_star_vectors_round_trip(mirrored):
    r, c = _grid(mirrored, 40)
    w = mirrored.object_vector_gcrf(r, c)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-15)
    r2, c2 = mirrored.star_to_image(w)
    assert np.hypot(r2 - r, c2 - c).max() <= 1e-6
    ra, dec = mirrored.object_radec(r, c)
    r3, c3 = mirrored.star_to_image(ra_deg=ra, dec_deg=dec)
    assert np.hypot(r3 - r, c3 - c).max() <= 1e-6
    # a star behind the camera has no image
    assert np.isnan(mirrored.star_to_image(-w[:1])[0]).all()
    with pytest.raises(InputError, match="either"):
        mirrored.star_to_image(w, ra_deg=ra)
    with pytest.raises(InputError, match="either"):
        mirrored.star_to_image(ra_deg=ra)


def test_stars_drift_at_the_earth_rotation_rate():
    """Seed 000 relies on it: an Earth-pointing GEO camera sees the stars move east to west."""
    model = example_geo_staring_model()
    w = model.object_vector_gcrf([512.0], [512.0])
    later = model.at_frame(10.0)
    row, col = later.star_to_image(w)
    expected = 10.0 * 7.2921e-5 / 2e-5  # 36.46 px of 20 urad in 10 s
    assert expected - 0.2 < abs(col[0] - 512.0) < expected + 0.2
    assert abs(row[0] - 512.0) < 0.5
    # the ground does not move
    r2, c2 = later.ground_to_image(*model.image_to_ground([512.0], [512.0], height=0.0))
    assert abs(r2[0] - 512.0) < 1e-6 and abs(c2[0] - 512.0) < 1e-6


def test_mirror_turns_the_view_by_twice_its_rotation():
    model = example_geo_staring_model(installation=Installation(np.pi / 2, 0.0, 0.0), mirror=FOLD)
    # the fold and the 90 degree roll look at the sub-satellite point again (image flipped)
    lon, lat, _ = model.image_to_ground([512.0, 0.5], [512.0, 512.0], height=0.0)
    assert abs(lon[0] - 105.0) < 1e-9 and abs(lat[0]) < 1e-9 and lat[1] < -3.0
    v0 = model.object_vector_gcrf([512.0], [512.0])[0]
    for delta in (1e-4, 1e-2, 0.05):
        # about camera X: in the mirror plane, normal to the plane of incidence -> 2 delta
        v1 = model.at_frame(0.0, mirror_angles=(delta, 0.0)).object_vector_gcrf([512.0], [512.0])[0]
        assert np.arccos(np.clip(v0 @ v1, -1, 1)) == pytest.approx(2 * delta, rel=1e-8)
    # a normal-incidence mirror turned about either axis: 2 delta as well
    normal = example_geo_staring_model(installation=Installation(np.pi, 0.0, 0.0), mirror=PointingMirror())
    u0 = normal.object_vector_gcrf([512.0], [512.0])[0]
    for angles in ((0.01, 0.0), (0.0, 0.01)):
        u1 = normal.at_frame(0.0, mirror_angles=angles).object_vector_gcrf([512.0], [512.0])[0]
        assert np.arccos(np.clip(u0 @ u1, -1, 1)) == pytest.approx(0.02, rel=1e-8)
    with pytest.raises(InputError, match="no pointing mirror"):
        example_geo_staring_model().at_frame(0.0, mirror_angles=(0.1, 0.0))


def test_points_beyond_the_limb_are_nan(pointed):
    r, c = pointed.ground_to_image([112.0 + 100.0, 112.0], [0.0, -13.0], [0.0, 0.0])
    assert np.isnan(r[0]) and np.isnan(c[0])
    assert np.isfinite(r[1])
    # a pixel looking past the Earth has no ground point
    off = example_geo_staring_model(attitude_kwargs=dict(bias_rad=(0.3, 0.0, 0.0)))
    lon, _, _ = off.image_to_ground([512.0], [512.0], height=0.0)
    assert np.isnan(lon).all()


# --------------------------------------------------------------------------- Jacobians
def _fd(model, project, jac):
    p = model.parameters()
    fd = np.zeros_like(jac)
    for k in range(len(p)):
        step = 1e-3 / np.abs(jac[:, :, k]).max()  # moves the image by about 1e-3 px
        v1, v2 = p.values.copy(), p.values.copy()
        v1[k] += step
        v2[k] -= step
        fd[:, :, k] = (np.stack(project(model.with_parameters(v1)), -1) - np.stack(project(model.with_parameters(v2)), -1)) / (2 * step)
    return fd


@pytest.mark.parametrize("which", ["pointed", "mirrored"])
def test_image_jacobian_matches_central_differences(which, request):
    model = request.getfixturevalue(which)
    rng = np.random.default_rng(11)
    r, c = rng.uniform(0, 1024, 40), rng.uniform(0, 1024, 40)
    lon, lat, h = model.image_to_ground(r, c, height=rng.uniform(0, 3000, 40))
    row, col, jac = model.image_jacobian(lon, lat, h)
    np.testing.assert_allclose(row, r, atol=1e-6)
    assert jac.shape == (40, 2, 23)
    fd = _fd(model, lambda m: m.ground_to_image(lon, lat, h), jac)
    rel = np.abs(jac - fd).max(axis=(0, 1)) / np.abs(jac).max(axis=(0, 1))
    assert rel.max() <= 1e-6, dict(zip(model.parameter_names(), rel))
    # a subset, in the order asked
    names = ["interior.tan_psi_y.b03", "installation.yaw"]
    _, _, sub = model.image_jacobian(lon, lat, h, names=names)
    idx = model.parameters().index(names)
    np.testing.assert_array_equal(sub, jac[:, :, idx])


def test_star_jacobian_matches_central_differences(mirrored):
    rng = np.random.default_rng(12)
    w = mirrored.object_vector_gcrf(rng.uniform(0, 1024, 30), rng.uniform(0, 1024, 30))
    _, _, jac = mirrored.star_jacobian(w)
    fd = _fd(mirrored, lambda m: m.star_to_image(w), jac)
    rel = np.abs(jac - fd).max(axis=(0, 1)) / np.abs(jac).max(axis=(0, 1))
    assert rel.max() <= 1e-6, dict(zip(mirrored.parameter_names(), rel))


def test_jacobian_magnitudes():
    """Roll moves rows and pitch columns by one pixel per IFOV; a00 moves columns by n/2."""
    model = example_geo_staring_model()
    _, _, jac = model.image_jacobian([105.0], [0.0], [0.0], names=["installation.roll", "installation.pitch", "interior.tan_psi_x.a00"])
    assert abs(jac[0, 0, 0]) == pytest.approx(1 / 2e-5, rel=1e-3) and abs(jac[0, 1, 0]) < 1e-6
    assert abs(jac[0, 1, 1]) == pytest.approx(1 / 2e-5, rel=1e-3) and abs(jac[0, 0, 1]) < 1e-6
    assert jac[0, 1, 2] == pytest.approx(-512.0 / (2e-5 * 512.0), rel=1e-9)


def test_parameters_and_gauge(pointed):
    p = pointed.parameters()
    assert p.names[:3] == ("installation.roll", "installation.pitch", "installation.yaw")
    assert p.names[3] == "interior.tan_psi_x.a00" and p.names[-1] == "interior.tan_psi_y.b03"
    same = pointed.with_parameters(p.values)
    lon, lat, h = pointed.image_to_ground([10.5, 900.5], [1000.5, 3.5], height=100.0)
    np.testing.assert_array_equal(np.stack(same.ground_to_image(lon, lat, h)), np.stack(pointed.ground_to_image(lon, lat, h)))
    assert pointed.interior_parameter_names(1) == (
        "interior.tan_psi_x.a00", "interior.tan_psi_x.a10", "interior.tan_psi_x.a01",
        "interior.tan_psi_y.b00", "interior.tan_psi_y.b10", "interior.tan_psi_y.b01",
    )  # fmt: skip
    # the gauge functionals see the rotations: a roll (rows) and the matching b00 shift agree
    rows, scale = pointed.gauge_rows()
    v = p.values.copy()
    v[pointed.parameters().index(["interior.tan_psi_y.b00"])] += scale[1]
    assert (rows @ v - rows @ p.values) == pytest.approx([0.0, scale[1], 0.0])
    with pytest.raises(InputError, match="23"):
        pointed.with_parameters(v[:-1])
    with pytest.raises(InputError, match="unknown parameters"):
        pointed.image_jacobian(lon, lat, h, names=["installation.spin"])
    with pytest.raises(InputError, match="unknown band"):
        pointed.ground_to_image(lon, lat, h, band="B9")
    with pytest.raises(InputError, match="exactly one"):
        pointed.image_to_ground([1.0], [1.0])
    with pytest.raises(InputError, match="NaN"):
        pointed.ground_to_image([np.nan], [0.0], [0.0])


# --------------------------------------------------------------------------- lab fit
def test_lab_fit_of_seed002_table1_on_a_gf4_like_array():
    """Seed 002 table 1 distorts the 10240-pixel array by ~29 px; the cubic follows it to 1e-4 px."""
    g = GF4_LIKE_CAMERA
    lab = StaringLab(
        focal_length_mm=g.focal_length_mm + 1.0,  # delta f = 1 mm
        pixel_size_mm=g.pixel_size_mm,
        principal_point_px=(5120 - 0.0015, 5120 - 0.0015),
        radial_k=(5e-11, 0.0),
        decentering_p=(6e-8, -3e-8),
        tilt_rad=(-8 * ARCSEC, -8 * ARCSEC),
        rotation_rad=-8 * ARCSEC,
    )
    interior, residual = fit_interior(lab, GF4_LIKE_SHAPE)
    assert 1e-7 < residual["max_px"] < 1e-4
    rng = np.random.default_rng(2)
    r, c = rng.uniform(0, 10240, 5000), rng.uniform(0, 10240, 5000)
    u, v = (c - 5120) / 5120, (r - 5120) / 5120
    tx, ty = lab.tangents(r, c, GF4_LIKE_SHAPE)
    fx, fy = interior.tangents(u, v)
    assert np.hypot(fx - tx, fy - ty).max() / g.ifov_rad < 2 * residual["max_px"]
    px, py = StaringInterior.pinhole(g.focal_length_mm, g.pixel_size_mm, GF4_LIKE_SHAPE).tangents(u, v)
    assert 20.0 < np.hypot(px - tx, py - ty).max() / g.ifov_rad < 40.0  # what the fit absorbed


def test_lab_fit_reports_what_the_cubic_cannot_follow():
    # k2 r^4 is a quintic: about 2.1 px at the corners of the 1024 array, partly absorbed
    lab = StaringLab(focal_length_mm=1250.0, pixel_size_mm=0.025, radial_k=(0.0, 1e-14))
    _, residual = fit_interior(lab, (1024, 1024))
    assert 0.1 < residual["max_px"] < 2.0
    assert 0.01 < residual["rms_px"] < residual["max_px"]
    model = GeoStaringModel.from_lab(LAB, image_shape=(1024, 1024), **_exterior())
    assert model.lab is LAB and 1e-7 < model.lab_fit_residual["max_px"] < 1e-4


def _exterior():
    base = example_geo_staring_model()
    return dict(orbit=base.orbit, attitude=base.attitude, frame_seconds=0.0)


def test_constructor_checks():
    ext = _exterior()
    with pytest.raises(InputError, match="10 coefficients"):
        StaringInterior(np.zeros(9), np.zeros(10))
    with pytest.raises(InputError, match="singular"):
        StaringInterior(np.zeros(10), np.zeros(10))
    with pytest.raises(InputError, match=r"\(2, 10\)"):
        GeoStaringModel(interior=np.zeros(20), image_shape=(8, 8), **ext)
    with pytest.raises(InputError, match="positive"):
        StaringLab(focal_length_mm=-1.0, pixel_size_mm=0.01)
    from sensor_models.errors import OutOfRangeError

    with pytest.raises(OutOfRangeError, match="outside"):
        GeoStaringModel(interior=StaringInterior.pinhole(1250, 0.025, (8, 8)), image_shape=(8, 8), **{**ext, "frame_seconds": 1e4})
    assert SEED000_CAMERA.ifov_rad == pytest.approx(2e-5)


# --------------------------------------------------------------------------- manifest
@pytest.fixture(scope="module")
def doc(mirrored, tmp_path_factory):
    path = write_geo_manifest(mirrored, tmp_path_factory.mktemp("geo") / "frame.json", raster="/data/frame.tif")
    return json.loads(path.read_text())


def _write(tmp_path, d, name="frame.json"):
    p = tmp_path / name
    p.write_text(json.dumps(d), encoding="utf-8")
    return p


def _expect_error(path, field, *words):
    with pytest.raises(ManifestError) as info:
        read_geo_manifest(path)
    msg = str(info.value)
    assert str(path) in msg and field in msg and "\n" not in msg, msg
    for w in words:
        assert w in msg, msg


def test_manifest_round_trip(mirrored, tmp_path):
    path = write_geo_manifest(mirrored, tmp_path / "sub" / "frame.json", raster=tmp_path / "frame.tif")
    assert not list(path.parent.glob(".*tmp"))  # atomic: nothing left beside it
    again, rasters = read_geo_manifest_and_rasters(path)
    assert rasters["B1"]["path"] == str((tmp_path / "frame.tif").resolve())
    np.testing.assert_array_equal(again.parameters().values, mirrored.parameters().values)
    r, c = _grid(mirrored, 20)
    for x, y in zip(again.image_to_ground(r, c, height=250.0), mirrored.image_to_ground(r, c, height=250.0)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(again.object_vector_gcrf(r, c), mirrored.object_vector_gcrf(r, c))
    d1 = json.loads(path.read_text())
    d2 = geo_manifest_to_dict(again, raster=rasters["B1"], base_dir=path.parent.resolve())
    # quaternions are normalized again on reading: equal to the last bits
    q1, q2 = (np.array(d.pop("attitude").pop("quaternions_xyzw")) for d in (d1, d2))
    np.testing.assert_allclose(q1, q2, rtol=0, atol=1e-15)
    assert d1 == d2


def test_manifest_lab_interior(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["interior"] = {
        "model": "lab",
        "focal_length_mm": LAB.focal_length_mm,
        "pixel_size_mm": LAB.pixel_size_mm,
        "principal_point_px": list(LAB.principal_point_px),
        "radial_k": list(LAB.radial_k),
        "decentering_p": list(LAB.decentering_p),
        "tilt_rad": list(LAB.tilt_rad),
        "rotation_rad": LAB.rotation_rad,
    }
    model = read_geo_manifest(_write(tmp_path, d))
    assert model.lab == LAB and 1e-7 < model.lab_fit_residual["max_px"] < 1e-4
    expected, _ = fit_interior(LAB, (1024, 1024))
    np.testing.assert_array_equal(model.interior.tan_psi_x, expected.tan_psi_x)
    d["interior"] = {"model": "lab", "focal_length_mm": 1250.0, "pixel_size_mm": 0.025}  # defaults
    assert read_geo_manifest(_write(tmp_path, d)).lab_fit_residual["max_px"] < 1e-9
    d["interior"]["k3"] = 1.0
    _expect_error(_write(tmp_path, d), "'interior'", "unknown key", "'k3'")


def test_manifest_strict_errors(doc, tmp_path):
    d = copy.deepcopy(doc)
    d["comment"] = "x"
    _expect_error(_write(tmp_path, d), "(root)", "unknown key", "'comment'")
    d = copy.deepcopy(doc)
    d["mirror"]["speed"] = 1.0
    _expect_error(_write(tmp_path, d), "'mirror'", "unknown key", "'speed'")
    d = copy.deepcopy(doc)
    del d["frame"]["seconds"]
    _expect_error(_write(tmp_path, d), "frame.seconds", "is missing")
    d = copy.deepcopy(doc)
    del d["image"]["n_cols"]
    _expect_error(_write(tmp_path, d), "image.n_cols", "is missing")
    d = copy.deepcopy(doc)
    d["interior"]["tan_psi_y"][4] = float("nan")
    p = _write(tmp_path, d)
    assert "NaN" in p.read_text()
    _expect_error(p, "interior.tan_psi_y", "NaN")
    d = copy.deepcopy(doc)
    d["interior"]["tan_psi_x"] = d["interior"]["tan_psi_x"][:9]
    _expect_error(_write(tmp_path, d), "interior.tan_psi_x", "shape 10")
    d = copy.deepcopy(doc)
    d["frame"]["seconds"] = 5000.0
    _expect_error(_write(tmp_path, d), "frame.seconds", "outside")
    d = copy.deepcopy(doc)
    d["sensor"] = "pushbroom"
    _expect_error(_write(tmp_path, d), "sensor", "'geo_staring'")
    d = copy.deepcopy(doc)
    d["mirror"]["normal_cam"] = [0.0, 0.0, 0.0]
    _expect_error(_write(tmp_path, d), "mirror.normal_cam", "zero")
    d = copy.deepcopy(doc)
    d["attitude"]["seconds"][5] = d["attitude"]["seconds"][4]
    _expect_error(_write(tmp_path, d), "attitude.seconds", "increase strictly")


def test_radec_vectors_are_unit_and_consistent():
    w = radec_to_vectors([0.0, 90.0, 180.0], [0.0, 0.0, 90.0])
    np.testing.assert_allclose(w, [[1, 0, 0], [0, 1, 0], [0, 0, 1]], atol=1e-15)
