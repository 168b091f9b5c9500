"""The plausibility checks pass what real inputs are and refuse what they cannot be, from both sides.

Legitimate inputs: the two demo fixtures (ideal and realistic HY-1C CZI scenes with their DOM
and DEM) and the Pleiades tutorial pair on SRTM (``../shared/data``). Each check is bracketed:
the same input moved just inside its limit passes, moved past it is refused
(:mod:`calibrate.plausibility`). The bad-input matrix (``test_bad_inputs.py``) proves
the refusals through every command.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from calibrate.plausibility import (MAX_DOM_GSD_RATIO, accepting_implausible, check_dem_heights,
                                             check_dom_resolution, check_gcps_on_scene, check_scene_raster)
from calibrate.cli import main
from sensor_models.errors import ImplausibleInputError
from sensor_models.imaging.ortho_grid import scene_gsd_m
from sensor_models.maps.raster import MapImage
from sensor_models.readers import open_scene
from sensor_models.terrain.dem import Dem
from tests.conftest import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = [ROOT / "fixtures" / "hy1c_czi", ROOT / "fixtures" / "hy1c_czi_realistic"]
DATA = SHARED_DATA  # ../shared/data beside the project, or GCPCAL_SHARED_DATA
needs_data = pytest.mark.skipif(not (DATA / "pleiades_ventoux").is_dir(), reason=f"no real test data at {DATA}")


def _grid_gcps(model, dem, n=12):
    """Ground points of an n x n pixel grid localized on the DEM: a GCP table of this very scene."""
    rows, cols = model.image_shape
    r, c = np.meshgrid(np.linspace(5.5, rows - 5.5, n), np.linspace(5.5, cols - 5.5, n), indexing="ij")
    lon, lat, h = (np.asarray(v) for v in model.image_to_ground(r.ravel(), c.ravel(), dem=dem))
    ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)  # rays that meet the DEM
    return lon[ok], lat[ok], h[ok]


def _scaled_dem(src: Path, dst: Path, factor: float) -> Path:
    with rasterio.open(src) as ds:
        profile, data, tags = ds.profile, ds.read().astype("float32") * factor, ds.tags()
    with rasterio.open(dst, "w", **(profile | {"dtype": "float32"})) as out:
        out.write(data)
        out.update_tags(**tags)
    return dst


def _coarse(src: Path, dst: Path, factor: int) -> Path:
    from rasterio.enums import Resampling

    with rasterio.open(src) as ds:
        h, w = ds.height // factor, ds.width // factor
        data = ds.read(out_shape=(ds.count, h, w), resampling=Resampling.average)
        profile = ds.profile | {"height": h, "width": w,
                                "transform": ds.transform * Affine.scale(ds.width / w, ds.height / h)}
        tags = ds.tags()
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
        out.update_tags(**tags)
    return dst


@pytest.mark.parametrize("fixture", FIXTURES, ids=lambda p: p.name)
def test_demo_fixtures_are_plausible(fixture):
    scene = open_scene(fixture / "manifest.json")
    model = scene.model
    dem = Dem.open(fixture / "reference" / "dem.tif")
    dom = MapImage.open(fixture / "reference" / "dom.tif")
    assert check_dem_heights(dem, model) == []
    assert check_dom_resolution(dom, model) == []
    for band in model.bands:
        assert check_scene_raster(scene, band, None) == []
        assert check_scene_raster(scene, band, scene.rasters[band]["path"]) == []  # its own raster as --image
    lon, lat, h = _grid_gcps(model, dem)
    assert check_gcps_on_scene(model, lon, lat, h, source="grid.csv") == []


def test_dem_heights_bracketed(tmp_path):
    fixture = FIXTURES[0]
    model = open_scene(fixture / "manifest.json").model
    # the file spans 0..1500 m, the footprint 0..1250 m: x6 reaches 7500 m there, x8 10 000 m
    inside = _scaled_dem(fixture / "reference" / "dem.tif", tmp_path / "x6.tif", 6.0)
    assert check_dem_heights(Dem.open(inside), model) == []
    beyond = _scaled_dem(fixture / "reference" / "dem.tif", tmp_path / "x8.tif", 8.0)
    with pytest.raises(ImplausibleInputError, match=r"x8\.tif: DEM heights \d+\.\.\d{5} m .*--allow-implausible"):
        check_dem_heights(Dem.open(beyond), model)
    with accepting_implausible():
        assert len(check_dem_heights(Dem.open(beyond), model)) == 1


def test_dom_resolution_bracketed(tmp_path):
    fixture = FIXTURES[0]
    model = open_scene(fixture / "manifest.json").model
    gsd = scene_gsd_m(model)
    native = MapImage.open(fixture / "reference" / "dom.tif").grid.resolution_m
    ok_factor = int(MAX_DOM_GSD_RATIO * gsd // native)  # just under the limit
    ok = MapImage.open(_coarse(fixture / "reference" / "dom.tif", tmp_path / "ok.tif", ok_factor))
    assert ok.grid.resolution_m / gsd <= MAX_DOM_GSD_RATIO
    assert check_dom_resolution(ok, model) == []
    coarse = MapImage.open(_coarse(fixture / "reference" / "dom.tif", tmp_path / "coarse.tif", ok_factor + 1))
    assert coarse.grid.resolution_m / gsd > MAX_DOM_GSD_RATIO
    with pytest.raises(ImplausibleInputError, match=r"times the scene's ground sampling distance"):
        check_dom_resolution(coarse, model, source=tmp_path / "coarse.tif")


def test_gcps_of_another_scene_bracketed():
    fixture = FIXTURES[0]
    model = open_scene(fixture / "manifest.json").model
    lon, lat, h = _grid_gcps(model, Dem.open(fixture / "reference" / "dem.tif"))
    per_km = 1.0 / (111.32 * np.cos(np.radians(np.mean(lat))))
    assert check_gcps_on_scene(model, lon + 8.0 * per_km, lat, h, source="g.csv") == []  # a model 8 km off
    with pytest.raises(ImplausibleInputError, match=rf"{lon.size} of {lon.size} GCPs lie outside the scene's footprint"):
        check_gcps_on_scene(model, lon + 55.0 * per_km, lat, h, source="g.csv")
    with pytest.raises(ImplausibleInputError, match=r"GCP heights outside -500\.\.9000 m"):
        check_gcps_on_scene(model, lon, lat, h * 100.0, source="g.csv")


def test_raster_named_for_another_band_is_refused(tmp_path):
    fixture = FIXTURES[0]
    scene = open_scene(fixture / "manifest.json", image=fixture / "B4.tif", band="B2")
    with pytest.raises(ImplausibleInputError, match=r"manifest lists this file as band B4's raster"):
        check_scene_raster(scene, "B2", fixture / "B4.tif")
    renamed = tmp_path / "scene_B4.tif"
    renamed.write_bytes((fixture / "B4.tif").read_bytes())
    with pytest.raises(ImplausibleInputError, match=r"its name says band B4"):
        check_scene_raster(scene, "B2", renamed)
    described = tmp_path / "pan.tif"
    described.write_bytes((fixture / "B4.tif").read_bytes())
    with rasterio.open(described, "r+") as ds:
        ds.set_band_description(1, "B4")
    with pytest.raises(ImplausibleInputError, match=r"its band 1 says 'B4'"):
        check_scene_raster(scene, "B2", described)
    with rasterio.open(described, "r+") as ds:
        ds.set_band_description(1, "B2")
    assert check_scene_raster(scene, "B2", described) == []


@needs_data
def test_pleiades_tutorial_inputs_are_plausible_and_landsat_is_not(tmp_path, capsys):
    pair = DATA / "pleiades_ventoux"
    srtm = ["--dem", str(DATA / "dem" / "N44E005.hgt"), "--dem-datum", "egm96", "--geoid",
            str(DATA / "dem" / "egm96_15.gtx")]
    ref = tmp_path / "left_ortho.tif"
    assert main(["-q", "ortho", str(pair / "left_image.tif"), *srtm, "--resolution", "0.5", "--out", str(ref)]) == 0
    right = open_scene(pair / "right_image.tif").model
    dem = Dem.open(DATA / "dem" / "N44E005.hgt", vertical_datum="egm96", geoid=DATA / "dem" / "egm96_15.gtx")
    assert check_dem_heights(dem, right) == []
    assert check_dom_resolution(MapImage.open(ref), right) == []
    lon, lat, h = _grid_gcps(right, dem, n=6)
    assert check_gcps_on_scene(right, lon, lat, h, source="gcps.csv") == []
    landsat = MapImage.open(DATA / "real_textures" / "landsat8" / "l8_B8.tif")
    with pytest.raises(ImplausibleInputError, match=r"the DOM's pixel is 15\.0 m, \d\d\.\d times"):
        check_dom_resolution(landsat, right, source="l8_B8.tif")
