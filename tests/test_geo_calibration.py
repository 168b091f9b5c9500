"""Absolute calibration of the geostationary staring camera from Earth-view GCPs (seed 000/002)."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.absolute import calibrate_model
from calibrate.config import CalibrationOptions
from gcpmatch.gcps import GcpTable
from sensor_models.errors import InputError
from sensor_models.models.synthetic import example_geo_staring_model
from sensor_models.models.staring_camera import StaringLab
from sensor_models.models.pushbroom_types import Installation

ARCSEC = np.pi / 180.0 / 3600.0


@pytest.fixture(scope="module")
def case():
    # seed 002 table 2: installation errors of 72, -72, 72 arcsec; a distorted, shifted lens
    true_lab = StaringLab(focal_length_mm=1250.0 * 1.0005, pixel_size_mm=0.025, principal_point_px=(515.0, 508.0),
                          radial_k=(2e-9, 0.0), decentering_p=(1e-7, -1e-7))
    truth = example_geo_staring_model(camera=true_lab, image_shape=(1024, 1024),
                                      installation=Installation(72 * ARCSEC, -72 * ARCSEC, 72 * ARCSEC))
    lab = example_geo_staring_model()
    rng = np.random.default_rng(0)
    r, c = rng.uniform(0, 1024, 2000), rng.uniform(0, 1024, 2000)
    lon, lat, h = truth.image_to_ground(r, c, height=0.0)
    noisy = (r + rng.normal(0, 0.1, r.size), c + rng.normal(0, 0.1, c.size))
    gr, gc = np.meshgrid(np.linspace(5, 1019, 30), np.linspace(5, 1019, 30), indexing="ij")
    grid = truth.image_to_ground(gr.ravel(), gc.ravel(), height=0.0)
    return truth, lab, noisy, (lon, lat, h), (gr.ravel(), gc.ravel(), grid)


def fit(model, row, col, lon, lat, h, *, ccd=None, **options):
    """``calibrate_model`` on a table of these columns with these options."""
    table = GcpTable.from_arrays(row, col, lon, lat, h, ccd=ccd)
    return calibrate_model(model, table, options=CalibrationOptions(**options))


def _truth_rms(model, grid):
    rows, cols, (lon, lat, h) = grid
    r, c = model.ground_to_image(lon, lat, h)
    return float(np.sqrt(np.mean((r - rows) ** 2 + (c - cols) ** 2)))


@pytest.mark.parametrize("scheme", ["exterior-interior", "interior-exterior", "interior", "joint"])
def test_full_schemes_reach_a_hundredth_of_a_pixel(case, scheme):
    truth, lab, (r, c), (lon, lat, h), grid = case
    before = _truth_rms(lab, grid)
    res = fit(lab, r, c, lon, lat, h, scheme=scheme)
    after = _truth_rms(res.model, grid)
    print(f"{scheme}: {before:.2f} -> {after:.4f} px")
    assert res.success
    assert before > 10.0
    assert 0.001 < after < 0.05


def test_exterior_only_leaves_the_lens_distortion(case):
    truth, lab, (r, c), (lon, lat, h), grid = case
    res = fit(lab, r, c, lon, lat, h, scheme="exterior")
    assert 0.1 < _truth_rms(res.model, grid) < 2.0


def test_points_in_one_corner_do_not_estimate_the_interior(case):
    truth, lab, (r, c), (lon, lat, h), grid = case
    corner = (r < 200) & (c < 200)
    res = fit(lab, r[corner], c[corner], lon[corner], lat[corner], h[corner], scheme="exterior-interior")
    assert res.skipped and "span" in res.skipped[0]["reason"]
    with pytest.raises(InputError):
        fit(lab, r, c, lon, lat, h, ccd="ccd1")
