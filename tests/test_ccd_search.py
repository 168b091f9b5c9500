"""The coarse stage's own offset search for a CCD its SIFT matches left out (gcpmatch.ccd_search).

The HY-1C CZI fixture (512 x 768 px, 4 CCDs of 192 detectors) with its LAB model, one CCD moved
further by 18-28 px (beyond the fine stage's 16 px capture radius, within the 32 px the search
covers on 192-detector CCDs), drawn at random directions, and SIFT made to find nothing on that
CCD (its matches dropped before the pre-correction, as on texture-poor ground): the search must
bring the CCD within a fraction of the capture radius of the TRUE model. A CCD whose scene is
flat noise (no ground signal) must be reported "not pre-corrected" and left as it was; one
whose scene is flat noise over 60 % of its lines (a coast) is found from the rest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import gcpmatch.coarse as coarse
from gcpmatch.ccd_search import search_radius_px, window_side_px
from gcpmatch.extract import read_band
from sensor_models.maps.raster import MapImage
from sensor_models.readers import open_model, open_scene
from sensor_models.terrain.dem import Dem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
BAND = "B2"
CCD = 1
CAPTURE_PX = 16.0


@pytest.fixture(scope="module")
def inputs():
    truth = open_model(FIXTURE / "truth_manifest.json")
    opened = open_scene(FIXTURE / "manifest.json")
    dem = Dem.open(FIXTURE / "reference" / "dem.tif")
    dom = MapImage.open(FIXTURE / "reference" / "dom.tif")
    return truth, opened.model, dem, dom, read_band(opened, BAND)


def _tan_psi_names(model, ccd):
    look = model.detector_arrays(BAND)[ccd]
    return [n for n in model.parameters().names if n.startswith(f"{BAND}.{look.name}.tan_psi")]


def _moved(model, ccd, d_row, d_col):
    """``model`` with CCD ``ccd`` moved by about ``(d_row, d_col)`` pixels (its c0 terms)."""
    look = model.detector_arrays(BAND)[ccd]
    names = [f"{BAND}.{look.name}.tan_psi_x.c0", f"{BAND}.{look.name}.tan_psi_y.c0"]
    row, col = np.array([256.5]), np.array([look.first_col + 96.5])
    lon, lat, _ = model.image_to_ground(row, col, height=np.array([500.0]), band=BAND, array=np.array([ccd]))
    _, _, jac = model.image_jacobian(lon, lat, np.array([500.0]), band=BAND, names=names, array=ccd)
    pv = model.parameters()
    x = pv.values.copy()
    x[pv.index(names)] += np.linalg.solve(jac[0], np.array([d_row, d_col]))
    return model.with_parameters(x)


def _error_px(model, truth, dem, ccd):
    """RMS distance, pixels, between ``model``'s and the TRUE model's projections on CCD ``ccd``."""
    look = truth.detector_arrays(BAND)[ccd]
    rr, cc = np.meshgrid(np.linspace(20.5, 490.5, 8), look.first_col + np.linspace(10.5, 180.5, 6))
    rr, cc = rr.ravel(), cc.ravel()
    arr = np.full(rr.size, ccd)
    lon, lat, _ = truth.image_to_ground(rr, cc, height=np.full(rr.size, 500.0), band=BAND, array=arr)
    h = dem.height_m(lon, lat)
    lon, lat, _ = truth.image_to_ground(rr, cc, height=h, band=BAND, array=arr)
    r2, c2 = model.ground_to_image(lon, lat, h, band=BAND, array=arr)
    return float(np.sqrt(np.mean((r2 - rr) ** 2 + (c2 - cc) ** 2)))


@pytest.fixture()
def no_sift_on_ccd(monkeypatch):
    """SIFT finds nothing on CCD ``CCD``: its matches lose their DEM height (dropped as outside)."""
    found = coarse._matches_on_ground

    def dropped(*args, **kwargs):
        row, col, lon, lat, h = found(*args, **kwargs)
        on_ccd = (col >= 192 * CCD) & (col < 192 * (CCD + 1))
        return row, col, lon, lat, np.where(on_ccd, np.nan, h)

    monkeypatch.setattr(coarse, "_matches_on_ground", dropped)


def test_the_window_covers_the_radius():
    assert search_radius_px(16.0, {}) == 32.0
    assert search_radius_px(16.0, {0: (3.0, 14.0)}) == pytest.approx(3.0 * np.hypot(3.0, 14.0))
    assert window_side_px(43.0, 5450, 512) == 256  # S / 4 >= 43
    assert window_side_px(43.0, 192, 512) == 128  # capped by the CCD's width
    assert window_side_px(43.0, 20, 512) == 0


@pytest.mark.parametrize("draw", range(3))
def test_a_ccd_without_sift_matches_is_found_by_its_own_search(inputs, no_sift_on_ccd, monkeypatch, draw):
    truth, lab, dem, dom, img = inputs
    rng = np.random.default_rng([2024, draw])
    size, angle = rng.uniform(22.0, 28.0), rng.uniform(0.0, 2.0 * np.pi)
    model = _moved(lab, CCD, size * np.sin(angle), size * np.cos(angle))
    result = coarse.coarse_match(img, model, dem, dom, band=BAND, capture_px=CAPTURE_PX)
    assert CCD not in result.ccd_offsets_px
    report = result.ccd_search[CCD]
    assert report["status"] == "pre-corrected", report
    assert _error_px(result.model, truth, dem, CCD) < 0.2 * CAPTURE_PX
    # the same stage without the search leaves the CCD beyond the capture radius
    monkeypatch.setattr(coarse, "search_missing_ccds", lambda scene, m, *a, **k: (m, {}))
    before = coarse.coarse_match(img, model, dem, dom, band=BAND, capture_px=CAPTURE_PX)
    assert _error_px(before.model, truth, dem, CCD) > CAPTURE_PX
    assert result.summary()["ccd_search"][str(CCD)]["status"] == "pre-corrected"


def test_a_featureless_ccd_is_reported_not_faked(inputs, no_sift_on_ccd):
    truth, lab, dem, dom, img = inputs
    model = _moved(lab, CCD, 5.0, 22.0)
    flat = img.astype(np.float32).copy()
    cols = slice(192 * CCD, 192 * (CCD + 1))
    flat[:, cols] = np.random.default_rng(7).normal(1000.0, 10.0, flat[:, cols].shape)
    result = coarse.coarse_match(flat, model, dem, dom, band=BAND, capture_px=CAPTURE_PX)
    report = result.ccd_search[CCD]
    assert report["status"] == "not pre-corrected" and report["reason"], report
    names = _tan_psi_names(model, CCD)
    pv_in, pv_out = model.parameters(), result.model.parameters()
    assert np.array_equal(pv_in.values[pv_in.index(names)], pv_out.values[pv_out.index(names)])


def test_a_coastal_ccd_is_found_from_its_land(inputs, no_sift_on_ccd, monkeypatch):
    """60 % of the CCD's lines flat noise (sea), the fine stage's capture radius 8 px (32-px
    windows), the CCD moved a further 8.5 px (15 px from the TRUE model after the whole-scene
    fit): the windows over the land decide, those over the sea find no peak and do not veto."""
    truth, lab, dem, dom, img = inputs
    capture = 8.0
    model = _moved(lab, CCD, -3.0, 8.0)
    coastal = img.astype(np.float32).copy()
    cols, sea = slice(192 * CCD, 192 * (CCD + 1)), int(0.6 * img.shape[0])
    coastal[:sea, cols] = np.random.default_rng(8).normal(1000.0, 10.0, coastal[:sea, cols].shape)
    result = coarse.coarse_match(coastal, model, dem, dom, band=BAND, capture_px=capture)
    report = result.ccd_search[CCD]
    assert report["status"] == "pre-corrected", report
    assert report["agree"] < 0.5 * report["windows"]  # most windows are over the sea
    assert _error_px(result.model, truth, dem, CCD) < 0.2 * capture
    monkeypatch.setattr(coarse, "search_missing_ccds", lambda scene, m, *a, **k: (m, {}))
    before = coarse.coarse_match(coastal, model, dem, dom, band=BAND, capture_px=capture)
    assert _error_px(before.model, truth, dem, CCD) > capture
