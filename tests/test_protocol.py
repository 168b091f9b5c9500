"""Every sensor model fulfils the one SensorModel protocol (sensor_models.base).

Models: the HY-1C CZI-like push-broom fixture (4 bands x 4 CCDs), one of its CCD views, a
geostationary staring camera, an RPC read from the Pleiades Ventoux data (skipped when
../shared/data is absent) and an RPC fitted to one CCD of the example push-broom fixture.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sensor_models.base import DetectorArray, SensorModel
from sensor_models.errors import InputError
from sensor_models.models.synthetic import example_geo_staring_model
from sensor_models.models.ccd_view import CcdView
from sensor_models.models.pushbroom_types import CcdLook
from sensor_models.readers import open_model
from sensor_models.models.rpc import RpcModel
from sensor_models.readers.rpc_files import read_rpc
from sensor_models.models.rpc_fit import fit_rpc

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
PLEIADES_GEOM = Path(__file__).resolve().parents[2] / "shared" / "data" / "pleiades_ventoux" / "left_image.geom"
MODEL_KINDS = ("pushbroom", "ccd_view", "staring", "rpc_pleiades", "rpc_fitted")
#: heights (m above the ellipsoid) at which image points are localized
HEIGHT_M = 250.0


@pytest.fixture(scope="module")
def hy1c():
    return open_model(FIXTURES / "hy1c_czi" / "manifest.json")


@pytest.fixture(scope="module")
def fitted_rpc():
    example = open_model(FIXTURES / "example_pushbroom" / "manifest.json")
    rpc, _ = fit_rpc(example.detector_view(array=0), height_range_m=(0.0, 1000.0), grid_shape=(11, 11, 5))
    return rpc


@pytest.fixture(params=MODEL_KINDS)
def model(request, hy1c, fitted_rpc) -> SensorModel:
    kind = request.param
    if kind == "pushbroom":
        return hy1c
    if kind == "ccd_view":
        return hy1c.detector_view("B3", "cam1_ccd2")
    if kind == "staring":
        return example_geo_staring_model()
    if kind == "rpc_fitted":
        return fitted_rpc
    if not PLEIADES_GEOM.is_file():
        pytest.skip(f"real test data not found at {PLEIADES_GEOM}")
    return read_rpc(PLEIADES_GEOM)


def _sample_points(model, band, array_index, n=5):
    """Image points spread over one detector array (rows and columns inside the image)."""
    a = model.detector_arrays(band)[array_index]
    rows = np.linspace(0.5, model.image_shape[0] - 0.5, n)
    cols = a.first_col + np.linspace(0.5, a.n_detectors - 0.5, n)
    return rows, cols


# ------------------------------------------------------------------ bands
def test_bands_hold_the_reference_band(model):
    bands = tuple(model.bands)
    assert bands and len(set(bands)) == len(bands)
    assert model.reference_band in bands
    assert bands == tuple(b for b in model.bands)  # iteration order is the order


def test_single_band_conventions(hy1c, fitted_rpc):
    assert fitted_rpc.bands == (None,) and fitted_rpc.reference_band is None
    staring = example_geo_staring_model()
    assert staring.bands == (staring.band,)
    view = hy1c.detector_view("B4", 0)
    assert view.bands == ("B4",) and view.reference_band == "B4"
    assert tuple(hy1c.bands) == ("B1", "B2", "B3", "B4") and hy1c.reference_band == "B2"


def test_unknown_band_is_named(model):
    with pytest.raises(InputError, match="no_such_band"):
        model.detector_arrays("no_such_band")


# ------------------------------------------------------------------ detector arrays
def test_detector_arrays_tile_the_image_columns(model):
    for band in model.bands:
        arrays = model.detector_arrays(band)
        assert arrays and all(isinstance(a, DetectorArray) for a in arrays)
        assert len({a.name for a in arrays}) == len(arrays)
        assert arrays[0].first_col == 0
        for a, b in zip(arrays, arrays[1:]):
            assert b.first_col == a.last_col
        assert arrays[-1].last_col == model.image_shape[1]


def test_detector_index_agrees_with_the_arrays(model):
    for band in model.bands:
        arrays = model.detector_arrays(band)
        for i, a in enumerate(arrays):
            cols = a.first_col + np.array([0.5, 0.5 * a.n_detectors, a.n_detectors - 0.5])
            assert np.array_equal(model.detector_index(cols, band=band), np.full(3, i))
            assert np.array_equal(model.detector_index(cols, band=band, array=a.name), np.full(3, i))
            assert np.array_equal(model.detector_index(cols, band=band, array=i), np.full(3, i))
        # columns beyond the image belong to the nearest array
        outside = np.array([-3.0, model.image_shape[1] + 3.0])
        assert model.detector_index(outside, band=band).tolist() == [0, len(arrays) - 1]


def test_pushbroom_arrays_are_its_ccds(hy1c):
    assert hy1c.detector_arrays("B1") is hy1c.band_ccds("B1")
    assert all(isinstance(c, CcdLook) and isinstance(c, DetectorArray) for c in hy1c.band_ccds("B1"))
    cols = np.linspace(-10.0, hy1c.image_shape[1] + 10.0, 97)
    assert np.array_equal(hy1c.detector_index(cols, band="B3"), hy1c.ccd_index(cols, band="B3"))


def test_unknown_array_is_named(model):
    with pytest.raises(InputError, match="no_such_ccd"):
        model.detector_view(model.reference_band, "no_such_ccd")
    with pytest.raises(InputError, match="no_such_ccd"):
        model.detector_index(np.array([1.0]), array="no_such_ccd")
    with pytest.raises(InputError, match="no_such_ccd"):
        model.ground_to_image(np.array([5.0]), np.array([44.0]), np.array([0.0]), array="no_such_ccd")


def test_a_multi_array_band_needs_a_named_view(hy1c):
    with pytest.raises(InputError, match="name one"):
        hy1c.detector_view("B1")


# ------------------------------------------------------------------ views
def test_detector_view_round_trips(model):
    for band in model.bands:
        for i, a in enumerate(model.detector_arrays(band)):
            view = model.detector_view(band, a.name)
            assert view.image_shape == (model.image_shape[0], a.n_detectors)
            assert tuple(view.parameters().names) == tuple(model.parameters().names)
            rows, cols = _sample_points(model, band, i)
            lon, lat, h = model.image_to_ground(rows, cols, height=HEIGHT_M, band=band, array=i)
            v_lon, v_lat, v_h = view.image_to_ground(rows, cols - a.first_col, height=HEIGHT_M)
            np.testing.assert_allclose(v_lon, lon, rtol=0, atol=1e-11)
            np.testing.assert_allclose(v_lat, lat, rtol=0, atol=1e-11)
            np.testing.assert_allclose(v_h, h, rtol=0, atol=1e-6)
            v_row, v_col = view.ground_to_image(lon, lat, h)
            np.testing.assert_allclose(v_row, rows, rtol=0, atol=1e-6)
            np.testing.assert_allclose(v_col + a.first_col, cols, rtol=0, atol=1e-6)


def test_single_array_models_are_their_own_view(model):
    if len(model.detector_arrays()) > 1:
        assert isinstance(model.detector_view(model.reference_band, 1), CcdView)
        return
    assert model.detector_view() is model
    assert model.detector_view(model.reference_band, 0) is model


def test_array_keyword_forces_the_array(model):
    rows, cols = _sample_points(model, None, 0, n=3)
    lon, lat, h = model.image_to_ground(rows, cols, height=HEIGHT_M)
    forced = model.image_to_ground(rows, cols, height=HEIGHT_M, array=0)
    for a, b in zip((lon, lat, h), forced):
        assert np.array_equal(a, b)
    names = model.parameter_names()[:2]
    r1, c1, j1 = model.image_jacobian(lon, lat, h, names=names)
    r2, c2, j2 = model.image_jacobian(lon, lat, h, names=names, array=model.detector_arrays()[0].name)
    # (the push-broom's unforced inverse solves on another CCD first: equal to rounding)
    np.testing.assert_allclose(r2, r1, rtol=0, atol=1e-8)
    np.testing.assert_allclose(c2, c1, rtol=0, atol=1e-8)
    np.testing.assert_allclose(j2, j1, rtol=1e-6, atol=1e-12)


def test_pushbroom_speaks_the_protocols_array_only(hy1c):
    """One vocabulary: the push-broom model's methods name a CCD with ``array=``, as the protocol
    does; the old ``ccd=`` spelling is refused by Python, not silently taken."""
    rows, cols = _sample_points(hy1c, "B1", 1, n=4)
    g = hy1c.image_to_ground(rows, cols, height=HEIGHT_M, band="B1")
    by_name = hy1c.ground_to_image(*g, band="B1", array="cam2_ccd1")[1]
    index = [a.name for a in hy1c.detector_arrays("B1")].index("cam2_ccd1")
    assert np.array_equal(by_name, hy1c.ground_to_image(*g, band="B1", array=index)[1], equal_nan=True)
    for method, args in ((hy1c.ground_to_image, g), (hy1c.image_to_ground, (rows, cols))):
        with pytest.raises(TypeError, match="ccd"):
            method(*args, band="B1", ccd=0)


# ------------------------------------------------------------------ parameters
def test_parameter_groups_partition_the_parameters(model):
    groups = model.parameter_groups()
    names = tuple(model.parameters().names)
    flat = tuple(n for group in groups.values() for n in group)
    assert flat == names
    assert len(set(flat)) == len(flat)
    assert model.parameter_names() == names


def test_group_names_and_rigour(model):
    groups = model.parameter_groups()
    if isinstance(model, RpcModel):
        assert not model.is_rigorous and list(groups) == ["bias"]
        assert model.interior_group() is None
        return
    assert model.is_rigorous
    assert groups["exterior"] == ("installation.roll", "installation.pitch", "installation.yaw")
    for band in model.bands:
        for a in model.detector_arrays(band):
            group = model.interior_group(band, a.name)
            assert group in groups and group != "exterior"
            assert group == ("interior" if model.kind == "geo_staring" else f"interior.{band}.{a.name}")


def test_pushbroom_interior_groups_hold_one_ccds_coefficients(hy1c):
    group = hy1c.parameter_groups()["interior.B3.cam2_ccd1"]
    assert len(group) == 8
    assert all(n.startswith("B3.cam2_ccd1.tan_psi_") for n in group)
    assert hy1c.interior_group("B3", 2) == "interior.B3.cam2_ccd1"
    view = hy1c.detector_view("B3", "cam2_ccd1")
    assert view.interior_group() == "interior.B3.cam2_ccd1"


def test_parameter_lookup(model):
    params = model.parameters()
    for name, value in zip(params.names, params.values):
        assert model.parameter(name) == value
    with pytest.raises(InputError, match="installation.spin"):
        model.parameter("installation.spin")
