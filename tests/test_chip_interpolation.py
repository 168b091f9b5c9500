"""Resampling kernels of ``sensor_models.maps.raster.sample_map_image`` and the matcher's chips.

A DOM coarser than the scene is upsampled into the scene's geometry. The tests sample a smooth,
band-limited map (a sum of plane waves below 0.3 cycles per DOM pixel, known exactly everywhere)
at a dense scan of sub-pixel positions, and check that Lanczos taps follow it far better than
bilinear ones (whose error depends on the sub-pixel phase), that the no-data footprint stays the
bilinear one, and that the default, which the simulator uses, is still bilinear to the bit.
"""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from gcpmatch.reference import CHIP_INTERPOLATION
from sensor_models.errors import InputError
from sensor_models.maps.raster import INTERPOLATIONS, MapImage, sample_map_image

N = 96
WAVES = [(0.11, 0.05, 0.3, 40.0), (-0.07, 0.19, 1.1, 25.0), (0.23, -0.13, 2.0, 15.0), (0.02, 0.27, 0.7, 10.0)]


def _field(u, v):
    """The map's value at node-index position (u, v): plane waves, cycles per pixel."""
    return 1000.0 + sum(a * np.cos(2 * np.pi * (fu * u + fv * v) + ph) for fu, fv, ph, a in WAVES)


@pytest.fixture(scope="module")
def dom():
    j, i = np.mgrid[0:N, 0:N].astype(float)
    values = _field(i, j).astype(np.float32)
    return MapImage.from_array(values, Affine(30.0, 0, 500000.0, 0, -30.0, 4900000.0), "EPSG:32631")


def _scan(rng, n=20000):
    """Dense random sub-pixel positions well inside the map (not a grid), as a (n // 100, 100) image."""
    shape = (max(1, n // 100), min(n, 100))
    return (rng.uniform(10, N - 10, shape).astype(np.float32), rng.uniform(10, N - 10, shape).astype(np.float32))


def test_lanczos_follows_a_band_limited_map_far_better_than_bilinear(dom):
    u, v = _scan(np.random.default_rng(5))
    truth = _field(u.astype(float), v.astype(float))
    err = {k: sample_map_image(dom, u, v, interpolation=k) - truth for k in INTERPOLATIONS}
    rms = {k: float(np.sqrt(np.mean(e**2))) for k, e in err.items()}
    signal = float(np.std(truth))
    assert rms["linear"] > 0.02 * signal  # bilinear smooths the upper waves
    assert rms["lanczos"] < 0.25 * rms["linear"]
    assert rms["cubic"] < rms["linear"]
    # OpenCV quantizes positions to 1/32 px: the floor any kernel meets here
    assert rms["lanczos"] > 1e-4 * signal


def test_bilinear_error_depends_on_the_sub_pixel_phase_lanczos_much_less(dom):
    """The structured error the chips had: bilinear loses most amplitude half-way between nodes."""
    u, v = _scan(np.random.default_rng(6))
    truth = _field(u.astype(float), v.astype(float))
    pu, pv = (np.minimum(x % 1.0, 1.0 - x % 1.0) for x in (u, v))  # distance to the nearest node, 0-0.5
    near, mid = (pu < 0.1) & (pv < 0.1), (pu > 0.4) & (pv > 0.4)
    assert near.sum() > 300 and mid.sum() > 300
    e_b = np.abs(sample_map_image(dom, u, v, interpolation="linear") - truth)
    assert e_b[mid].mean() > 3.0 * e_b[near].mean()  # exact at the nodes, worst between them
    e_l = np.abs(sample_map_image(dom, u, v, interpolation="lanczos") - truth)
    assert e_l[mid].mean() < 0.25 * e_b[mid].mean()


def test_no_data_footprint_is_the_bilinear_one(dom):
    values = dom.read(0, N, 0, N)
    values[40:46, 50:53] = np.nan
    holed = MapImage.from_array(values, dom.grid.transform, dom.grid.crs)
    u, v = _scan(np.random.default_rng(7))
    lin = sample_map_image(holed, u, v, interpolation="linear")
    for kind in ("cubic", "lanczos"):
        out = sample_map_image(holed, u, v, interpolation=kind)
        np.testing.assert_array_equal(np.isnan(out), np.isnan(lin))
        assert np.isnan(lin).sum() > 50
        # away from the hole the wide taps are used, next to it the bilinear sample
        far = (np.abs(v - 43) > 8) | (np.abs(u - 51) > 8)
        assert not np.array_equal(out[far], lin[far])


def test_default_is_bilinear_and_the_chips_use_lanczos(dom):
    u, v = _scan(np.random.default_rng(8), 500)
    np.testing.assert_array_equal(sample_map_image(dom, u, v, sigma_px=0.7),
                                  sample_map_image(dom, u, v, sigma_px=0.7, interpolation="linear"))
    assert CHIP_INTERPOLATION == "lanczos"


def test_unknown_interpolation_is_one_input_error(dom):
    u, v = _scan(np.random.default_rng(9), 10)
    with pytest.raises(InputError) as info:
        sample_map_image(dom, u, v, interpolation="nearest")
    assert info.value.field == "interpolation" and "\n" not in str(info.value)


def test_many_samples_near_no_data_take_the_bilinear_values(dom):
    """More samples next to no-data than one OpenCV map row holds (rows of 4096, padded): each
    gets exactly the bilinear value, in its own place."""
    values = dom.read(0, N, 0, N)
    values[:, 48:] = np.nan  # half the map is no-data
    holed = MapImage.from_array(values, dom.grid.transform, dom.grid.crs)
    rng = np.random.default_rng(10)
    shape = (120, 250)  # 30 000 samples around the edge
    u = rng.uniform(42, 50, shape).astype(np.float32)
    v = rng.uniform(10, N - 10, shape).astype(np.float32)
    lin = sample_map_image(holed, u, v, interpolation="linear")
    out = sample_map_image(holed, u, v, interpolation="lanczos")
    wide_nan = ~np.isnan(lin) & (u > 44.0)  # within reach of the Lanczos taps, not of the bilinear ones
    assert wide_nan.sum() > 5000
    np.testing.assert_array_equal(np.isnan(out), np.isnan(lin))
    np.testing.assert_array_equal(out[wide_nan], lin[wide_nan])
    far = u < 42.5  # out of the Lanczos reach: its own values
    assert far.any() and not np.array_equal(out[far], lin[far])
