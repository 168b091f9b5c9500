"""Real imagery: match a Pleiades crop against an orthoimage of its stereo mate (shareloc data).

The DOM is the left crop orthorectified through its RPC over SRTM (EGM96 heights converted to
ellipsoidal with the geoid grid); the right crop is matched once with its RPC and once with the
RPC whose ``line_off`` was moved by 60 lines. Matching must not depend on the starting model,
so the two runs give the same GCPs and their residuals differ by the 60-line bias; the
residuals against the unbiased RPC show the floor that SRTM's disagreement with the canopy
allows on this slope (several lines along track at a base-to-height ratio of 0.35).
"""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from calibrate.rpc_bias import compensate_rpc_bias
from gcpmatch.extract import extract_gcps
from gcpmatch.options import MatchOptions
from sensor_models.imaging.ortho import orthorectify
from sensor_models.readers.rpc_files import read_rpc
from sensor_models.maps.raster import MapImage
from sensor_models.terrain.dem import Dem

pytestmark = pytest.mark.shared_data


def _crop(folder, geom, tif):
    with rasterio.open(folder / tif) as ds:
        t, img, shape = ds.transform, ds.read(1).astype(np.float32), (ds.height, ds.width)
    return read_rpc(folder / geom).cropped(t.f, t.c, shape), img


@pytest.fixture(scope="module")
def ventoux(shared_data):
    folder = shared_data / "pleiades_ventoux"
    left, limg = _crop(folder, "left_image.geom", "left_image.tif")
    right, rimg = _crop(folder, "right_image.geom", "right_image.tif")
    biased, _ = _crop(folder, "right_image_bias.geom", "right_image.tif")
    dem = Dem.open(shared_data / "dem" / "N44E005.hgt", vertical_datum="egm96",
                   geoid=shared_data / "dem" / "egm96_15.gtx")
    lon, lat, _ = left.image_to_ground(np.array([0.5, 0.5, 499.5, 499.5]), np.array([0.5, 499.5, 0.5, 499.5]), dem=dem)
    crs = pyproj.CRS.from_epsg(32631)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
    res = 0.5
    transform = Affine(res, 0, min(x) - 10, 0, -res, max(y) + 10)
    shape = (int((max(y) - min(y) + 20) / res), int((max(x) - min(x) + 20) / res))
    dom = MapImage.from_array(orthorectify(left, limg, dem, transform, crs, shape), transform, crs)
    options = MatchOptions(window_px=32, spacing_px=8, max_offset_px=150, check_fraction=0.0)
    runs = {}
    for name, model in (("geom", right), ("bias", biased)):
        table, summary = extract_gcps(model, rimg, dem, dom, band=None, options=options)
        runs[name] = (model, table, summary)
    return right, runs


def test_sixty_line_bias_comes_back_from_matched_gcps(ventoux):
    right, runs = ventoux
    own = {}
    for name, (model, table, _) in runs.items():
        r, c = model.ground_to_image(table.lon, table.lat, table.h)
        own[name] = (np.median(table.row - r), np.median(table.col - c))
        assert len(table) > 200
    d_row = own["geom"][0] - own["bias"][0]
    d_col = own["geom"][1] - own["bias"][1]
    print(f"bias recovered from the residual difference: {d_row:.3f} lines, {d_col:.3f} samples")
    assert abs(d_row - 60.0) < 0.5 and abs(d_col) < 0.5


def test_floor_against_the_unbiased_rpc_is_srtm_parallax(ventoux):
    right, runs = ventoux
    _, table, _ = runs["geom"]
    r, c = right.ground_to_image(table.lon, table.lat, table.h)
    dr, dc = table.row - r, table.col - c
    print(f"floor: mean row {dr.mean():.2f} col {dc.mean():.2f}, std row {dr.std():.2f} col {dc.std():.2f} px")
    # several lines along track (parallax of SRTM against the canopy), about a pixel across
    assert 1.0 < np.sqrt(np.mean(dr**2)) < 10.0
    assert np.std(dc) < 3.0


def test_rpc_bias_compensation_recovers_sixty_lines(ventoux):
    right, runs = ventoux
    fits = {}
    for name, (model, table, _) in runs.items():
        res = compensate_rpc_bias(model, table.row, table.col, table.lon, table.lat, table.h, terms="offset")
        assert res.success
        fits[name] = res.bias
    # the biased RPC needs 60 lines more correction than the unbiased one, to a fraction of a pixel
    delta = fits["bias"]["bias.row.a0"] - fits["geom"]["bias.row.a0"]
    print(f"compensation: unbiased a0 {fits['geom']['bias.row.a0']:.2f}, biased a0 {fits['bias']['bias.row.a0']:.2f}, "
          f"difference {delta:.3f} lines")
    assert abs(abs(delta) - 60.0) < 0.5


def test_match_and_calibrate_commands_on_the_biased_crop(shared_data, tmp_path):
    """The analyst's path on a real RPC product crop: match, then calibrate the RPC bias."""
    from calibrate.cli import main

    folder = shared_data / "pleiades_ventoux"
    left, limg = _crop(folder, "left_image.geom", "left_image.tif")
    dem_args = ["--dem", str(shared_data / "dem" / "N44E005.hgt"), "--dem-datum", "egm96",
                "--geoid", str(shared_data / "dem" / "egm96_15.gtx")]
    dem = Dem.open(shared_data / "dem" / "N44E005.hgt", vertical_datum="egm96", geoid=shared_data / "dem" / "egm96_15.gtx")
    lon, lat, _ = left.image_to_ground(np.array([0.5, 0.5, 499.5, 499.5]), np.array([0.5, 499.5, 0.5, 499.5]), dem=dem)
    crs = pyproj.CRS.from_epsg(32631)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
    transform = Affine(0.5, 0, min(x) - 10, 0, -0.5, max(y) + 10)
    shape = (int((max(y) - min(y) + 20) / 0.5), int((max(x) - min(x) + 20) / 0.5))
    ortho = orthorectify(left, limg, dem, transform, crs, shape)
    dom = tmp_path / "left_dom.tif"
    with rasterio.open(dom, "w", driver="GTiff", width=shape[1], height=shape[0], count=1, dtype="float32",
                       crs=crs.to_wkt(), transform=transform, nodata=np.nan) as ds:
        ds.write(ortho, 1)
    geom, image = str(folder / "right_image_bias.geom"), str(folder / "right_image.tif")
    assert main(["-q", "match", geom, "--image", image, "--dom", str(dom), *dem_args, "--out", str(tmp_path / "g.csv"),
                 "--window", "32", "--spacing", "8", "--max-offset", "150"]) == 0
    assert main(["-q", "calibrate", geom, "--image", image, "--gcps", str(tmp_path / "g.csv"),
                 "--out", str(tmp_path / "cal"), "--no-report"]) == 0
    import json

    doc = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    a0 = doc["bias"]["bias.row.a0"]
    print(f"CLI: RPC bias a0 {a0:.2f} lines (60 + the SRTM parallax floor)")
    assert -66.0 < a0 < -60.0  # 60 lines plus the few-line floor against the left image's RPC and SRTM
    # the crop's sidecar under the raster's name (what GDAL pairs with right_image.tif), and the full
    # scene's RPC under the product's name with a suffix no raster pairs with
    assert (tmp_path / "cal" / "right_image_RPC.TXT").exists()
    assert (tmp_path / "cal" / "right_image_bias_full_scene_RPC.TXT").exists()
    summary = json.loads((tmp_path / "cal" / "calibrate.summary.json").read_text())
    assert summary["model"] == "right_image_bias_full_scene_RPC.TXT"
