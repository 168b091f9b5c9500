"""Reference data as users have them: tiles and mosaics, Landsat and Sentinel-2 DOMs, QA masks, geoid lookup."""

from __future__ import annotations

import json
import os
import tracemalloc

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from sensor_models.maps.dom_inputs import DomSource, open_dom, resolve_dom, s2_radiometry
from sensor_models.errors import GcpcalError, GeoidGridMissingError, InputError
from sensor_models.maps.mosaic import mosaic_path, raster_inputs, write_vrt
from sensor_models.maps.raster import MapImage
from sensor_models.maps.reference_qa import invalid_from_qa, qa_layout_from_name, qa_layout_of
from sensor_models.terrain.dem import Dem
from sensor_models.terrain.geoid import find_egm96_grid

UTM31 = "EPSG:32631"


def _write(path, values, transform, crs=UTM31, nodata=None):
    profile = {"driver": "GTiff", "width": values.shape[1], "height": values.shape[0], "count": 1,
               "dtype": values.dtype.name, "crs": crs, "transform": transform}
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(values, 1)
    return str(path)


def _split_in_four(values, transform, folder, *, name="tile_{}.tif", rows=37, cols=53, crs=UTM31):
    """Write ``values`` as four tiles cut at (rows, cols); return their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, (r0, r1, c0, c1) in enumerate([(0, rows, 0, cols), (0, rows, cols, None), (rows, None, 0, cols),
                                          (rows, None, cols, None)]):
        part = values[r0:r1, c0:c1]
        paths.append(_write(folder / name.format(k), part, transform * Affine.translation(c0, r0), crs=crs))
    return paths


@pytest.fixture()
def original(tmp_path):
    rng = np.random.default_rng(1)
    values = rng.integers(1, 60000, size=(90, 120)).astype(np.uint16)
    transform = Affine(30.0, 0.0, 600000.0, 0.0, -30.0, 4900000.0)
    return values, transform


# -- tiles and mosaics ------------------------------------------------------------------------


def test_four_tiles_mosaic_back_to_the_original_bytes(tmp_path, original):
    values, transform = original
    _split_in_four(values, transform, tmp_path / "tiles")
    path = mosaic_path(tmp_path / "tiles", what="DOM")
    assert path.endswith(".vrt")
    with rasterio.open(path) as ds:
        assert ds.read(1).tobytes() == values.tobytes()
        assert ds.transform == transform and ds.crs.to_epsg() == 32631


def test_list_comma_folder_glob_and_vrt_forms_read_alike(tmp_path, original):
    values, transform = original
    tiles = _split_in_four(values, transform, tmp_path / "tiles")
    vrt = write_vrt(tiles, tmp_path / "mine.vrt", what="DOM")
    forms = [tiles, ",".join(tiles), str(tmp_path / "tiles"), str(tmp_path / "tiles" / "tile_*.tif"), vrt]
    for form in forms:
        image = MapImage.open(form)
        assert image.grid.shape == values.shape, form
        np.testing.assert_array_equal(image.read(0, 90, 0, 120), values.astype(np.float32))
    assert raster_inputs(str(tmp_path / "tiles")) == sorted(tiles)
    one = MapImage.open(tiles[0])  # one file is opened as itself, not through a VRT
    assert one.path == tiles[0]


def test_tiles_in_two_crs_are_refused_naming_the_file(tmp_path, original):
    values, transform = original
    a = _write(tmp_path / "a.tif", values[:, :60], transform)
    b = _write(tmp_path / "b.tif", values[:, 60:], transform * Affine.translation(60, 0), crs="EPSG:32632")
    with pytest.raises(InputError, match="mix coordinate reference systems") as err:
        mosaic_path([a, b], what="DOM")
    assert "b.tif" in str(err.value) and "\n" not in str(err.value)
    b_ok = _write(tmp_path / "b_ok.tif", values[:, 60:], transform * Affine.translation(60, 0))
    assert mosaic_path([a, b_ok], what="DOM").endswith(".vrt")  # the same tiles in one CRS are accepted


def test_tiles_off_the_grid_and_missing_files_are_refused(tmp_path, original):
    values, transform = original
    a = _write(tmp_path / "a.tif", values[:, :60], transform)
    shifted = _write(tmp_path / "s.tif", values[:, 60:], transform * Affine.translation(60.5, 0))
    with pytest.raises(InputError, match="not aligned"):
        mosaic_path([a, shifted])
    with pytest.raises(InputError, match="not found"):
        mosaic_path([a, str(tmp_path / "nope.tif")])
    with pytest.raises(InputError, match="matches no file"):
        mosaic_path(str(tmp_path / "z*.tif"))


def _write_hgt(folder, name, values):
    path = folder / name
    values.astype(">i2").tofile(path)
    return path


def test_srtm_hgt_tiles_form_one_dem_with_a_void_between(tmp_path):
    n = 1201
    west = np.full((n, n), 100, dtype=np.int16)
    east = np.full((n, n), 300, dtype=np.int16)
    _write_hgt(tmp_path, "N44E005.hgt", west)
    _write_hgt(tmp_path, "N44E007.hgt", east)  # E006 missing: a void between
    box = (5.4, 44.4, 7.6, 44.6)  # a window across the three tile positions (read by window)
    dem = Dem.open(tmp_path, vertical_datum="ellipsoid", bounds=box, margin_deg=0.01)
    h = dem.height_m(np.array([5.5, 7.5, 6.5]), np.array([44.5, 44.5, 44.5]))
    np.testing.assert_allclose(h[:2], [100.0, 300.0])
    assert np.isnan(h[2])
    lon0, lat0, lon1, lat1 = dem.bounds_lonlat
    assert 5.38 < lon0 < 5.4 and 7.6 < lon1 < 7.62 and 44.38 < lat0 < 44.4 and 44.6 < lat1 < 44.62
    same = Dem.open([tmp_path / "N44E005.hgt", tmp_path / "N44E007.hgt"], vertical_datum="ellipsoid", bounds=box,
                    margin_deg=0.01)
    np.testing.assert_array_equal(np.nan_to_num(same.heights_m, nan=-1), np.nan_to_num(dem.heights_m, nan=-1))


def test_copernicus_glo30_tile_names_by_folder_and_glob(tmp_path):
    step = 1.0 / 36  # a coarse stand-in for 1 arc-second: the names and the tiling are what matter
    for lat in (44, 45):
        for lon in (5, 6):
            name = f"Copernicus_DSM_COG_10_N{lat:02d}_00_E{lon:03d}_00_DEM.tif"
            _write(tmp_path / name, np.full((36, 36), 10.0 * lat + lon, np.float32),
                   Affine(step, 0, lon, 0, -step, lat + 1), crs="EPSG:4326")
    for form in (tmp_path, str(tmp_path / "Copernicus_DSM_COG_10_*_DEM.tif")):
        dem = Dem.open(form, vertical_datum="ellipsoid")
        assert dem.heights_m.shape == (72, 72)
        np.testing.assert_allclose(dem.height_m(np.array([5.5, 6.5, 5.5, 6.5]), np.array([44.5, 44.5, 45.5, 45.5])),
                                   [445.0, 446.0, 455.0, 456.0])
    # GLO-30 tiles north of 50 degrees have wider columns: such a mix is refused, naming the tile
    _write(tmp_path / "Copernicus_DSM_COG_10_N50_00_E005_00_DEM.tif", np.zeros((36, 24), np.float32),
           Affine(1.5 * step, 0, 5, 0, -step, 51), crs="EPSG:4326")
    with pytest.raises(InputError, match="N50_00_E005_00_DEM.tif: the DEM tiles differ in pixel width"):
        Dem.open(tmp_path, vertical_datum="ellipsoid")


def test_dem_tiles_keep_the_vertical_datum_they_all_declare(tmp_path):
    heights = np.linspace(200.0, 400.0, 40 * 60, dtype=np.float32).reshape(40, 60)
    tiles = _split_in_four(heights, Affine(30.0, 0, 600000.0, 0, -30.0, 4900000.0), tmp_path / "t", rows=20, cols=30)
    for tile in tiles:
        with rasterio.open(tile, "r+") as ds:
            ds.update_tags(VERTICAL_DATUM="ellipsoid")
    dem = Dem.open(tmp_path / "t")  # no vertical_datum given: the tiles declare it
    np.testing.assert_array_equal(dem.heights_m, heights.astype(np.float64))
    with rasterio.open(tiles[3], "r+") as ds:
        ds.update_tags(VERTICAL_DATUM="egm96")
    with pytest.raises(GcpcalError, match=r"t/tile_0.tif \(and 3 more DEM tiles\): the DEM does not declare"):
        Dem.open(tmp_path / "t")


def test_window_read_of_a_mosaic_does_not_hold_the_mosaic(tmp_path):
    rng = np.random.default_rng(2)
    big = rng.random((1600, 1600), dtype=np.float32)  # 10 MB of float32
    tiles = _split_in_four(big, Affine(10.0, 0, 500000.0, 0, -10.0, 4900000.0), tmp_path / "t", rows=800, cols=800)
    del big
    image = MapImage.open(tiles)
    tracemalloc.start()
    block = image.read(780, 820, 780, 820)  # across all four tiles
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert block.shape == (40, 40) and np.isfinite(block).all()
    assert peak < 1_000_000, peak  # the mosaic is 10 MB


# -- QA layouts -------------------------------------------------------------------------------

# Values of the real pre-Collection BQA crop, decoded by hand (bits 15-14 cloud confidence,
# 13-12 cirrus confidence, 11-10 snow/ice, 5-4 water; 3 = high); masked by default / with cirrus:
#   20480 = 0b01_01_00_00_0000_0000  cloud low,  cirrus low            -> kept   / kept
#   20512 = 0b01_01_00_00_0010_0000  cloud low,  cirrus low, water med -> kept   / kept
#   23552 = 0b01_01_11_00_0000_0000  cloud low,  cirrus low, snow high -> kept   / kept
#   28672 = 0b01_11_00_00_0000_0000  cloud low,  cirrus HIGH           -> kept   / masked
#   36864 = 0b10_01_00_00_0000_0000  cloud med,  cirrus low            -> kept   / kept
#   45056 = 0b10_11_00_00_0000_0000  cloud med,  cirrus HIGH           -> kept   / masked
#   53248 = 0b11_01_00_00_0000_0000  cloud HIGH, cirrus low            -> masked / masked
#   61440 = 0b11_11_00_00_0000_0000  cloud HIGH, cirrus HIGH           -> masked / masked
BQA_BY_HAND = {20480: False, 20512: False, 23552: False, 28672: False, 36864: False, 45056: False, 53248: True,
               61440: True}
BQA_CIRRUS_BY_HAND = {**BQA_BY_HAND, 28672: True, 45056: True}


def test_pre_collection_bqa_bits_by_hand(shared_data):
    path = shared_data / "real_textures" / "landsat8" / "l8_BQA.tif"
    with rasterio.open(path) as ds:
        qa = ds.read(1)
    assert qa_layout_of(path) == "landsat-pre-collection"  # decided from the values: bits 14-15 set
    for value, masked in BQA_BY_HAND.items():
        rows, cols = np.nonzero(qa == value)
        assert rows.size, value
        assert bool(invalid_from_qa(qa[rows[0], cols[0]], "landsat-pre-collection")) is masked, value
        assert bool(invalid_from_qa(value, "landsat-pre-collection", cirrus=True)) is BQA_CIRRUS_BY_HAND[value], value
    assert set(np.unique(qa)) <= set(BQA_BY_HAND) | {28704, 36896, 45088, 53280, 61472}  # + bit 5 (water)
    # the same values read as Collection 2 would say something else: the layouts differ
    assert bool(invalid_from_qa(28672, "landsat-c2")) is False


def test_landsat_band_opened_with_its_bqa_beside(shared_data):
    folder = shared_data / "real_textures" / "landsat8"
    with rasterio.open(folder / "l8_BQA.tif") as ds:
        qa = ds.read(1)
    with rasterio.open(folder / "l8_B4.tif") as ds:
        dn = ds.read(1).astype(np.float32)
    expected = np.vectorize(lambda v: BQA_BY_HAND.get(int(v) & 0xFFDF, True))(qa)  # bit 5 (water) never masks
    image, found = open_dom(folder / "l8_B4.tif")
    assert found.product == "landsat" and found.qa_layout == "landsat-pre-collection"
    values = image.read(0, qa.shape[0], 0, qa.shape[1])
    np.testing.assert_array_equal(np.isnan(values), expected)
    np.testing.assert_array_equal(values[~expected], dn[~expected])
    # counted by hand from the value histogram: 53248 x 2591, 53280 x 41, 61440 x 20140, 61472 x 4
    assert abs(expected.mean() - 22776 / qa.size) < 1e-12
    bare, _ = open_dom(DomSource(items=(str(folder / "l8_B4.tif"),), use_qa=False))
    assert not np.isnan(bare.read(0, 10, 0, 10)).any()


def test_bqa_masks_the_15_m_panchromatic_band_at_its_own_pixels(shared_data):
    folder = shared_data / "real_textures" / "landsat8"
    image, _ = open_dom(DomSource(items=(str(folder / "l8_B8.tif"),), qa=(str(folder / "l8_BQA.tif"),)))
    with rasterio.open(folder / "l8_BQA.tif") as ds:
        qa = ds.read(1)
    flagged = invalid_from_qa(qa, "landsat-pre-collection")
    values = image.read(0, 1207, 0, 1254)
    # B8's grid is shifted by half a B8 pixel from BQA's (both 'Point' rasters): the centre of B8
    # pixel (r, c) lies on a BQA pixel edge for even r or c, and inside BQA pixel ((r - 1) / 2,
    # (c - 1) / 2) for odd r and c.
    odd_r, odd_c = np.arange(1, 1207, 2), np.arange(1, 1254, 2)
    np.testing.assert_array_equal(np.isnan(values[np.ix_(odd_r, odd_c)]),
                                  flagged[np.ix_((odd_r - 1) // 2, (odd_c - 1) // 2)])
    assert not np.isnan(values[np.ix_(odd_r, odd_c)]).all() and np.isnan(values[np.ix_(odd_r, odd_c)]).any()
    assert 0.05 < np.isnan(values).mean() < 0.08  # high cloud: 6.0 % of the 30 m QA, plus the edge row


def test_landsat_bqa_masks_cloud_not_cirrus_and_says_how_much(shared_data, tmp_path):
    """The real pre-Collection BQA: cloud (high) masks 6.0 % of the crop, cirrus (high) 31 % more
    only with --dom-mask-cirrus; a user's mask (nonzero = unusable) adds to the QA."""
    folder = shared_data / "real_textures" / "landsat8"
    with rasterio.open(folder / "l8_BQA.tif") as ds:
        qa, profile = ds.read(1), ds.profile
    image, found = open_dom(folder / "l8_B4.tif")
    share = np.isnan(image.read(0, qa.shape[0], 0, qa.shape[1])).mean()
    assert not found.qa_cirrus and abs(share - np.mean((qa >> 14) == 3)) < 1e-12
    assert 0.05 < share < 0.07
    image, _ = open_dom(DomSource(items=(str(folder / "l8_B4.tif"),), qa_cirrus=True))
    with_cirrus = np.isnan(image.read(0, qa.shape[0], 0, qa.shape[1])).mean()
    assert abs(with_cirrus - np.mean(((qa >> 14) == 3) | (((qa >> 12) & 3) == 3))) < 1e-12 and with_cirrus > 0.3
    user = np.zeros(qa.shape, dtype=np.uint8)
    user[:100, :] = 7
    profile.update(dtype="uint8", nodata=None)
    with rasterio.open(tmp_path / "mine.tif", "w", **profile) as ds:
        ds.write(user, 1)
    image, found = open_dom(DomSource(items=(str(folder / "l8_B4.tif"),), mask=(str(tmp_path / "mine.tif"),)))
    masked = np.isnan(image.read(0, qa.shape[0], 0, qa.shape[1]))
    np.testing.assert_array_equal(masked, ((qa >> 14) == 3) | (user != 0))
    assert found.mask_files == [str(tmp_path / "mine.tif")]
    # the mask alone, without any QA
    image, _ = open_dom(DomSource(items=(str(folder / "l8_B4.tif"),), use_qa=False, mask=(str(tmp_path / "mine.tif"),)))
    np.testing.assert_array_equal(np.isnan(image.read(0, qa.shape[0], 0, qa.shape[1])), user != 0)


def test_collection_2_qa_pixel_bits():
    for bit in (0, 1, 3, 4):  # fill, dilated cloud, cloud, cloud shadow
        assert invalid_from_qa(1 << bit, "landsat-c2"), bit
    assert not invalid_from_qa(1 << 2, "landsat-c2") and invalid_from_qa(1 << 2, "landsat-c2", cirrus=True)
    for bit in range(5, 16):  # snow, clear, water, confidences: not masks by themselves
        assert not invalid_from_qa(1 << bit, "landsat-c2"), bit
    assert not invalid_from_qa(21824, "landsat-c2")  # clear land, low cloud confidence
    assert invalid_from_qa(22280, "landsat-c2")  # bit 3 cloud with high confidence
    assert qa_layout_from_name("LC08_L1TP_044034_20210508_20210518_02_T1_QA_PIXEL.TIF") == "landsat-c2"
    assert qa_layout_from_name("LC08_L1TP_044034_20170508_20170518_01_T1_BQA.TIF") == "landsat-c1"
    assert qa_layout_from_name("LC80440342015128LGN00_BQA.TIF") == "landsat-pre-collection"
    assert qa_layout_from_name("T18SUJ_20220301T000000_SCL_20m.jp2") == "s2-scl"
    assert qa_layout_from_name("mask.tif") is None


def test_collection_1_bqa_bits():
    assert invalid_from_qa(1, "landsat-c1") and invalid_from_qa(1 << 4, "landsat-c1")
    assert invalid_from_qa(3 << 7, "landsat-c1") and not invalid_from_qa(3 << 11, "landsat-c1")
    assert invalid_from_qa(3 << 11, "landsat-c1", cirrus=True)
    assert not invalid_from_qa(2 << 7, "landsat-c1") and not invalid_from_qa(2 << 11, "landsat-c1")
    assert not invalid_from_qa(2720, "landsat-c1")  # clear: cloud, shadow, snow, cirrus confidence low


def test_sentinel2_scl_classes():
    classes = np.arange(12)
    np.testing.assert_array_equal(invalid_from_qa(classes, "s2-scl"), np.isin(classes, [0, 1, 3, 8, 9]))
    np.testing.assert_array_equal(invalid_from_qa(classes, "s2-scl", cirrus=True),
                                  np.isin(classes, [0, 1, 3, 8, 9, 10]))
    np.testing.assert_array_equal(invalid_from_qa(np.array([0, 1, 255, -3]), "mask"), [False, True, True, True])
    np.testing.assert_array_equal(invalid_from_qa(np.array([0.0, np.nan, 0.5]), "mask"), [False, False, True])
    with pytest.raises(InputError, match="unknown QA layout"):
        invalid_from_qa(classes, "landsat-c3")


# -- Sentinel-2 products ----------------------------------------------------------------------

_MTD_L1C = """<?xml version="1.0" encoding="UTF-8"?>
<n1:Level-1C_User_Product xmlns:n1="https://psd-14.sentinel2.eo.esa.int/PSD/User_Product_Level-1C.xsd">
 <n1:General_Info><Product_Info><PROCESSING_BASELINE>04.00</PROCESSING_BASELINE></Product_Info>
  <Product_Image_Characteristics>
   <QUANTIFICATION_VALUE unit="none">10000</QUANTIFICATION_VALUE>
   <Radiometric_Offset_List>
    <RADIO_ADD_OFFSET band_id="2">-1000</RADIO_ADD_OFFSET>
    <RADIO_ADD_OFFSET band_id="1">-1000</RADIO_ADD_OFFSET>
    <RADIO_ADD_OFFSET band_id="3">-1000</RADIO_ADD_OFFSET>
   </Radiometric_Offset_List>
  </Product_Image_Characteristics>
 </n1:General_Info>
</n1:Level-1C_User_Product>
"""

_MTD_L2A = """<?xml version="1.0" encoding="UTF-8"?>
<n1:Level-2A_User_Product xmlns:n1="https://psd-14.sentinel2.eo.esa.int/PSD/User_Product_Level-2A.xsd">
 <n1:General_Info><Product_Image_Characteristics>
  <QUANTIFICATION_VALUES_LIST><BOA_QUANTIFICATION_VALUE unit="none">10000</BOA_QUANTIFICATION_VALUE>
  </QUANTIFICATION_VALUES_LIST>
  <BOA_ADD_OFFSET_VALUES_LIST><BOA_ADD_OFFSET band_id="3">-1000</BOA_ADD_OFFSET></BOA_ADD_OFFSET_VALUES_LIST>
 </Product_Image_Characteristics></n1:General_Info>
</n1:Level-2A_User_Product>
"""

S2_T = Affine(10.0, 0.0, 399960.0, 0.0, -10.0, 4200000.0)


def _s2_band(values):
    return values.astype(np.uint16)


def test_sentinel2_l1c_safe_band_scale_offset_and_nodata(tmp_path):
    safe = tmp_path / "S2A_MSIL1C_20220301T000000_N0400_R000_T18SUJ_20220301T000000.SAFE"
    img = safe / "GRANULE" / "L1C_T18SUJ_A000000_20220301T000000" / "IMG_DATA"
    img.mkdir(parents=True)
    (safe / "MTD_MSIL1C.xml").write_text(_MTD_L1C)
    dn = np.array([[0, 1000, 2500], [11000, 1500, 0]], dtype=np.uint16)
    for band in ("B04", "B08"):
        _write(img / f"T18SUJ_20220301T000000_{band}.jp2", _s2_band(dn), S2_T, crs="EPSG:32618")
    assert s2_radiometry(str(safe / "MTD_MSIL1C.xml"), "B04") == (10000.0, -1000.0)
    assert s2_radiometry(str(safe / "MTD_MSIL1C.xml"), "B08") == (10000.0, 0.0)  # no offset listed for band 7
    for item in (safe, img):  # the SAFE folder or the granule's IMG_DATA folder, with the band
        image, found = open_dom(DomSource(items=(str(item),), band="B04"))
        assert found.files[0].endswith("_B04.jp2") and found.product == "sentinel-2"
        values = image.read(0, 2, 0, 3)
        expected = np.where(dn == 0, np.nan, (dn.astype(np.float64) - 1000.0) / 10000.0)
        np.testing.assert_allclose(values, expected, rtol=1e-6, atol=1e-7)
    # a decimated read (the coarse matcher's) averages only pixels with data: DN 0 is no data
    zeros = np.full((4, 4), 3000, dtype=np.uint16)
    zeros[0, 0] = zeros[2:, 2:] = 0
    _write(img / "T18SUJ_20220301T000000_B03.jp2", zeros, S2_T, crs="EPSG:32618")
    image, _ = open_dom(DomSource(items=(str(img),), band="B03"))
    np.testing.assert_allclose(image.read_decimated(0, 4, 0, 4, (2, 2)), [[0.2, 0.2], [0.2, np.nan]], rtol=1e-6)
    with pytest.raises(InputError, match="several bands"):
        resolve_dom(DomSource(items=(str(img),)))
    glob_b08 = resolve_dom(DomSource(items=(str(img / "*.jp2"),), band="B08"))  # a glob, filtered by the band
    assert [os.path.basename(f) for f in glob_b08.files] == ["T18SUJ_20220301T000000_B08.jp2"]
    with pytest.raises(InputError, match="names no file of band B08"):
        resolve_dom(DomSource(items=(str(img / "T18SUJ_20220301T000000_B04.jp2"),), band="B08"))
    with pytest.raises(InputError, match="no file of band B02"):
        resolve_dom(DomSource(items=(str(safe),), band="B02"))


def test_sentinel2_l2a_finest_band_and_scl_at_20_m(tmp_path):
    granule = tmp_path / "S2B_MSIL2A_X.SAFE" / "GRANULE" / "L2A_T18SUJ_X" / "IMG_DATA"
    (granule / "R10m").mkdir(parents=True)
    (granule / "R20m").mkdir()
    (tmp_path / "S2B_MSIL2A_X.SAFE" / "MTD_MSIL2A.xml").write_text(_MTD_L2A)
    dn10 = np.full((4, 6), 3000, dtype=np.uint16)
    _write(granule / "R10m" / "T18SUJ_X_B04_10m.jp2", dn10, S2_T, crs="EPSG:32618")
    _write(granule / "R20m" / "T18SUJ_X_B04_20m.jp2", dn10[:2, :3], S2_T * Affine.scale(2), crs="EPSG:32618")
    scl = np.array([[4, 9, 5], [3, 6, 10]], dtype=np.uint8)
    _write(granule / "R20m" / "T18SUJ_X_SCL_20m.jp2", scl, S2_T * Affine.scale(2), crs="EPSG:32618")
    image, found = open_dom(DomSource(items=(str(tmp_path / "S2B_MSIL2A_X.SAFE"),), band="4"))
    assert found.files[0].endswith("_B04_10m.jp2") and found.qa_layout == "s2-scl"
    values = image.read(0, 4, 0, 6)
    masked = np.kron(np.isin(scl, [3, 9]), np.ones((2, 2), dtype=bool))  # 10 (thin cirrus) kept; each 20 m class covers 2 x 2
    np.testing.assert_array_equal(np.isnan(values), masked)
    np.testing.assert_allclose(values[~masked], 0.2, rtol=1e-6)  # (3000 - 1000) / 10000


def test_real_sentinel2_crop_is_reflectance_with_zero_as_nodata(shared_data):
    path = shared_data / "real_textures" / "sentinel2" / "s2_B04.jp2"
    image, found = open_dom(path)
    assert found.product == "sentinel-2" and found.nodata == 0 and "DN / 10000" in found.notes[0]
    with rasterio.open(path) as ds:
        dn = ds.read(1, window=((100, 140), (200, 260))).astype(np.float64)
    np.testing.assert_allclose(image.read(100, 140, 200, 260), dn / 10000.0, rtol=1e-6)
    assert 0.01 < np.nanmean(image.read(0, 200, 0, 200)) < 0.5


# -- geoid lookup in PROJ's data directories --------------------------------------------------


def test_egm96_grid_found_in_a_proj_data_directory(shared_data, tmp_path):
    from pyproj import datadir

    hgt = shared_data / "dem" / "N44E005.hgt"
    bounds = (5.1, 44.1, 5.3, 44.3)
    explicit = Dem.open(hgt, vertical_datum="egm96", geoid=shared_data / "dem" / "egm96_15.gtx", bounds=bounds)
    proj_dir = tmp_path / "proj"
    proj_dir.mkdir()
    assert find_egm96_grid([str(proj_dir)]) is None
    os.symlink(shared_data / "dem" / "egm96_15.gtx", proj_dir / "egm96_15.gtx")
    assert find_egm96_grid([str(proj_dir)]) == str(proj_dir / "egm96_15.gtx")
    before = datadir.get_data_dir()
    datadir.append_data_dir(str(proj_dir))
    try:
        found = Dem.open(hgt, vertical_datum="egm96", bounds=bounds)
    finally:
        datadir.set_data_dir(before)
    np.testing.assert_array_equal(found.heights_m, explicit.heights_m)


def test_missing_geoid_error_says_where_it_looked(shared_data):
    if find_egm96_grid() is not None:
        pytest.skip(f"an EGM96 grid is installed in PROJ's data directories: {find_egm96_grid()}")
    with pytest.raises(GeoidGridMissingError) as err:
        Dem.open(shared_data / "dem" / "N44E005.hgt", vertical_datum="egm96", bounds=(5.1, 44.1, 5.2, 44.2))
    text = str(err.value)
    assert "--geoid" in text and pyproj.datadir.get_user_data_dir() in text and "egm96_15.gtx" in text


# -- the command line -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from tests.test_match import _config
    from sensor_models.simulate.pushbroom_sim import simulate_pushbroom

    d = tmp_path_factory.mktemp("scene")
    simulate_pushbroom(d, config=_config())
    return d


def _landsat_tiles(scene, folder, *, cloudy_tile: int):
    """The scene's DOM as four Landsat C2 tiles (B4 + QA_PIXEL); ``cloudy_tile`` flagged as cloud."""
    with rasterio.open(scene / "reference" / "dom.tif") as ds:
        dom, transform, crs = ds.read(1), ds.transform, ds.crs
    rows, cols = dom.shape[0] // 2, dom.shape[1] // 2
    ids = [f"LC08_L1TP_19703{k}_20210508_20210518_02_T1" for k in range(4)]
    _split_in_four(dom, transform, folder, name="{}_B4.TIF", rows=rows, cols=cols, crs=crs)
    for k in range(4):
        os.rename(folder / f"{k}_B4.TIF", folder / f"{ids[k]}_B4.TIF")
    qa = np.full(dom.shape, 21824, dtype=np.uint16)
    qa_tiles = _split_in_four(qa, transform, folder, name="{}_QA_PIXEL.TIF", rows=rows, cols=cols, crs=crs)
    with rasterio.open(qa_tiles[cloudy_tile], "r+") as ds:
        ds.write(np.full((ds.height, ds.width), 22280, dtype=np.uint16), 1)
        cloudy_bounds = ds.bounds
    for k in range(4):
        os.rename(folder / f"{k}_QA_PIXEL.TIF", folder / f"{ids[k]}_QA_PIXEL.TIF")
    return cloudy_bounds, crs


def test_match_against_landsat_tiles_with_qa_pixel(scene, tmp_path):
    from calibrate.cli import main
    from gcpmatch.gcp_files import read_gcps

    cloudy, crs = _landsat_tiles(scene, tmp_path / "landsat", cloudy_tile=1)
    dem = str(scene / "reference" / "dem.tif")
    out = tmp_path / "gcps.csv"
    rc = main(["-q", "match", str(scene / "manifest.json"), "--dom", str(tmp_path / "landsat"), "--dom-band", "B4",
               "--dem", dem, "--out", str(out), "--spacing", "48"])
    assert rc == 0
    summary = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary["dom_product"] == "landsat" and summary["dom_qa_layout"] == "landsat-c2"
    assert len(summary["dom_files"]) == 4 and len(summary["dom_qa_files"]) == 4
    assert 0.05 < summary["dom_masked_fraction"] < 0.95
    table = read_gcps(out)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs.to_wkt(), always_xy=True).transform(table.lon, table.lat)
    inside = (x > cloudy.left) & (x < cloudy.right) & (y > cloudy.bottom) & (y < cloudy.top)
    assert len(table) > 20 and not inside.any()
    out2 = tmp_path / "gcps_noqa.csv"
    rc = main(["-q", "match", str(scene / "manifest.json"), "--dom", str(tmp_path / "landsat"), "--dom-band", "B4",
               "--no-dom-qa", "--dem", dem, "--out", str(out2), "--spacing", "48"])
    assert rc == 0
    bare = read_gcps(out2)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs.to_wkt(), always_xy=True).transform(bare.lon, bare.lat)
    assert ((x > cloudy.left) & (x < cloudy.right) & (y > cloudy.bottom) & (y < cloudy.top)).any()
    assert json.loads(out2.with_suffix(".summary.json").read_text())["dom_masked_fraction"] is None


def test_match_cli_dom_and_dem_errors_are_one_line(scene, tmp_path, capsys):
    from calibrate.cli import main

    args = ["match", str(scene / "manifest.json"), "--dem", str(scene / "reference" / "dem.tif"),
            "--out", str(tmp_path / "g.csv")]
    rc = main(args + ["--dom", str(tmp_path / "nothing_*.tif")])
    err = capsys.readouterr().err
    assert rc == 1 and "matches no file" in err and err.count("\n") == 1
    with rasterio.open(scene / "reference" / "dom.tif") as ds:
        qa = _write(tmp_path / "mask.tif", np.zeros((4, 4), np.uint16), ds.transform, crs=ds.crs)
    rc = main(args + ["--dom", str(scene / "reference" / "dom.tif"), "--dom-qa", qa])
    err = capsys.readouterr().err
    assert rc == 1 and "--dom-qa-layout" in err and err.count("\n") == 1
    assert not (tmp_path / "g.csv").exists()


def test_sites_file_names_the_dom_band_and_qa(tmp_path):
    from calibrate.batch import read_sites

    sites = tmp_path / "sites.csv"
    sites.write_text("name,scene,dom,dem,dom_band,dom_qa\n"
                     "a,s.json,S2A.SAFE,dem/,B04,\n"
                     "b,s.json,l8/LC08_B4.TIF,dem.tif,,l8/LC08_QA_PIXEL.TIF\n")
    a, b = read_sites(sites)
    assert a.dom_band == "B04" and a.dom_qa is None and a.dom == tmp_path / "S2A.SAFE"
    assert b.dom_band is None and b.dom_qa == tmp_path / "l8" / "LC08_QA_PIXEL.TIF"
    sites.write_text("name,scene,dom,dem,dom_bands\na,s.json,d.tif,dem.tif,B04\n")
    with pytest.raises(InputError, match="unknown column"):
        read_sites(sites)


def test_dem_and_dom_options_hand_over_tiles_and_a_dom_source():
    import click
    from click.testing import CliRunner

    from calibrate.cli.options import add_options, dem_options, dom_options

    seen = {}

    @click.command()
    @dom_options
    @add_options(dem_options)
    def cmd(dom_path, dem_path, dem_datum, geoid):
        seen.update(dom=dom_path, dem=dem_path)

    runner = CliRunner()
    assert runner.invoke(cmd, ["--dom", "a.TIF", "--dom", "b.TIF", "--dom-band", "B4", "--dom-qa", "q.TIF",
                               "--dom-qa-layout", "landsat-c1", "--dom-scale", "2e-5", "--dom-offset", "-0.1",
                               "--dem", "x.hgt", "--dem", "y.hgt"]).exit_code == 0
    assert seen["dom"] == DomSource(items=("a.TIF", "b.TIF"), band="B4", qa=("q.TIF",), qa_layout="landsat-c1",
                                    scale=2e-5, offset=-0.1, use_qa=True)
    assert seen["dem"] == ("x.hgt", "y.hgt")
    assert runner.invoke(cmd, ["--dom", "a.TIF", "--no-dom-qa", "--dem", "x.hgt"]).exit_code == 0
    assert seen["dom"].use_qa is False and seen["dem"] == "x.hgt"
    assert runner.invoke(cmd, ["--dom", "a.TIF"]).exit_code == 0 and seen["dem"] is None
    assert runner.invoke(cmd, ["--dem", "x.hgt"]).exit_code == 2  # --dom is required
    assert runner.invoke(cmd, ["--dom", "a.TIF", "--dom-qa-layout", "landsat-c9"]).exit_code == 2


def test_match_with_dem_tiles_reads_only_the_footprint_and_equals_the_single_file(scene, tmp_path):
    from calibrate.actions._io import open_dem
    from calibrate.cli import main
    from sensor_models.readers import open_model

    with rasterio.open(scene / "reference" / "dem.tif") as ds:
        heights, transform, crs, tags = ds.read(1), ds.transform, ds.crs, ds.tags()
    tiles = _split_in_four(heights, transform, tmp_path / "dem", rows=300, cols=400, crs=crs)
    far = _write(tmp_path / "dem" / "tile_far.tif", np.full((100, 100), 1234.0, np.float32),
                 transform * Affine.translation(832 + 5000, 0), crs=crs)  # 150 km east, on the same grid
    for tile in tiles + [far]:
        with rasterio.open(tile, "r+") as ds:
            ds.update_tags(VERTICAL_DATUM=tags["VERTICAL_DATUM"])
    lab = open_model(scene / "manifest.json")
    with rasterio.open(mosaic_path(tmp_path / "dem")) as ds:
        mosaic_size, far_x = ds.width * ds.height, ds.bounds.right
    bounded = open_dem(tmp_path / "dem", model=lab)
    assert bounded.heights_m.size < mosaic_size / 4  # the far tile stretches the mosaic; it is not read
    far_lon = pyproj.Transformer.from_crs(crs.to_wkt(), "EPSG:4326", always_xy=True).transform(far_x - 3000.0,
                                                                                              transform.f)[0]
    assert bounded.bounds_lonlat[2] < far_lon - 1.0
    lon = np.linspace(bounded.bounds_lonlat[0] + 0.01, bounded.bounds_lonlat[2] - 0.01, 7)
    lat = np.linspace(bounded.bounds_lonlat[1] + 0.01, bounded.bounds_lonlat[3] - 0.01, 7)
    single = Dem.open(scene / "reference" / "dem.tif")
    np.testing.assert_array_equal(bounded.height_m(lon, lat), single.height_m(lon, lat))
    summaries = []
    for name, dem in (("tiles", str(tmp_path / "dem")), ("single", str(scene / "reference" / "dem.tif"))):
        out = tmp_path / f"{name}.csv"
        assert main(["-q", "match", str(scene / "manifest.json"), "--dom", str(scene / "reference" / "dom.tif"),
                     "--dem", dem, "--out", str(out), "--spacing", "48"]) == 0
        summaries.append((out.read_text(), json.loads(out.with_suffix(".summary.json").read_text())["gcps"]))
    assert summaries[0] == summaries[1]


def test_ortho_localize_and_rpc_on_dem_tiles_equal_the_single_dem(tmp_path):
    """The embedded fixture's DEM cut into two tiles gives the same ortho, localization and RPC range."""
    import json

    from calibrate.cli import main

    from pathlib import Path

    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
    with rasterio.open(fixture / "reference" / "dem.tif") as ds:
        values, transform, crs, nodata = ds.read(1), ds.transform, ds.crs, ds.nodata
    half = values.shape[1] // 2
    _write(tmp_path / "west.tif", values[:, :half], transform, crs=crs, nodata=nodata)
    _write(tmp_path / "east.tif", values[:, half:], transform * Affine.translation(half, 0), crs=crs,
           nodata=nodata)
    single = ["--dem", str(fixture / "reference" / "dem.tif")]
    tiles = ["--dem", str(tmp_path / "west.tif"), "--dem", str(tmp_path / "east.tif"), "--dem-datum", "ellipsoid"]
    scene = str(fixture / "manifest.json")
    for name, dem in (("single", single), ("tiles", tiles)):
        assert main(["-q", "ortho", scene, *dem, "--out", str(tmp_path / f"{name}.tif")]) == 0
        assert main(["-q", "localize", scene, "--rows", "10.5,300.5", "--cols", "20.5,700.5", *dem,
                     "--out", str(tmp_path / f"{name}.csv")]) == 0
        assert main(["-q", "rpc", scene, "--ccd", "cam1_ccd1", *dem, "--out", str(tmp_path / f"{name}_RPC.TXT")]) == 0
    with rasterio.open(tmp_path / "single.tif") as a, rasterio.open(tmp_path / "tiles.tif") as b:
        assert a.transform == b.transform and np.array_equal(a.read(1), b.read(1), equal_nan=True)
    assert (tmp_path / "single.csv").read_text() == (tmp_path / "tiles.csv").read_text()
    ranges = [json.loads((tmp_path / f"{n}_RPC.TXT.summary.json").read_text())["height_range_m"]
              for n in ("single", "tiles")]
    assert np.allclose(ranges[0], ranges[1])
