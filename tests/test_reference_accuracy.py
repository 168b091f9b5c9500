"""The reference DOM's stated geolocation accuracy: option, GDAL tags, Landsat MTL, assumed.

``sensor_models.maps.dom_inputs.reference_accuracy`` feeds the reference term of the window sigma
model (docs/matching.md, "sigma_px"); ``gcpmatch.uncertainty.reference_sigma_px`` projects it
into image rows and columns. Rasters are real GeoTIFFs written with rasterio.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from sensor_models.maps.dom_inputs import (ACCURACY_TAG, ACCURACY_TAG_X, ACCURACY_TAG_Y,
                                      reference_accuracy, stated_accuracy)
from sensor_models.errors import InputError

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"

#: the structure of a Landsat Collection 2 L1 MTL (LSDS-1822), reduced to what is read here
MTL = """GROUP = LANDSAT_METADATA_FILE
  GROUP = LEVEL1_PROCESSING_RECORD
    GROUND_CONTROL_POINTS_MODEL = 412
    GEOMETRIC_RMSE_MODEL = 6.211
    GEOMETRIC_RMSE_MODEL_Y = 4.420
    GEOMETRIC_RMSE_MODEL_X = 4.364
  END_GROUP = LEVEL1_PROCESSING_RECORD
END_GROUP = LANDSAT_METADATA_FILE
END
"""


def _raster(path: Path, tags: dict | None = None) -> str:
    """A small UTM GeoTIFF with ``tags`` in the default metadata domain."""
    with rasterio.open(path, "w", driver="GTiff", width=8, height=8, count=1, dtype="uint16", crs="EPSG:32618",
                       transform=from_origin(500000.0, 4200000.0, 30.0, 30.0)) as ds:
        ds.write(np.full((1, 8, 8), 100, dtype=np.uint16))
        if tags:
            ds.update_tags(**tags)
    return str(path)


def test_isotropic_tag(tmp_path):
    acc = reference_accuracy([_raster(tmp_path / "dom.tif", {ACCURACY_TAG: "2.5"})])
    assert (acc.east_m, acc.north_m, acc.assumed) == (2.5, 2.5, False)
    assert acc.source == f"tag {tmp_path / 'dom.tif'}" and acc.note is None


def test_per_axis_tags(tmp_path):
    acc = reference_accuracy([_raster(tmp_path / "dom.tif", {ACCURACY_TAG_X: "3.0", ACCURACY_TAG_Y: "4.0"})])
    assert (acc.east_m, acc.north_m) == (3.0, 4.0)
    assert acc.per_axis_m == pytest.approx(np.sqrt(12.5))


@pytest.mark.parametrize("tags, field", [({ACCURACY_TAG_X: "3.0"}, ACCURACY_TAG_X),
                                         ({ACCURACY_TAG: "about 2 m"}, ACCURACY_TAG),
                                         ({ACCURACY_TAG: "-1"}, ACCURACY_TAG),
                                         ({ACCURACY_TAG_X: "nan", ACCURACY_TAG_Y: "1"}, ACCURACY_TAG_X)])
def test_bad_tags_are_input_errors(tmp_path, tags, field):
    path = _raster(tmp_path / "dom.tif", tags)
    with pytest.raises(InputError) as exc:
        reference_accuracy([path])
    assert exc.value.field == field and exc.value.path == path


def test_landsat_mtl_beside_the_band(tmp_path):
    band = _raster(tmp_path / "LC08_L1TP_015034_20230615_20230620_02_T1_B4.TIF")
    (tmp_path / "LC08_L1TP_015034_20230615_20230620_02_T1_MTL.txt").write_text(MTL)
    acc = reference_accuracy([band])
    assert (acc.east_m, acc.north_m, acc.assumed) == (4.364, 4.420, False)
    assert acc.source.startswith("mtl ") and acc.source.endswith("_MTL.txt")
    # an MTL without the model RMSE (an L1GT product) states nothing
    (tmp_path / "LC08_L1TP_015034_20230615_20230620_02_T1_MTL.txt").write_text(MTL.replace("GEOMETRIC_RMSE_MODEL_X",
                                                                                         "OTHER"))
    assert stated_accuracy([band]) is None


def test_precedence_option_then_tag_then_mtl(tmp_path):
    band = _raster(tmp_path / "LC08_X_B4.TIF", {ACCURACY_TAG: "2.0"})
    (tmp_path / "LC08_X_MTL.txt").write_text(MTL)
    assert reference_accuracy([band]).east_m == 2.0  # the band's own tag before the MTL
    acc = reference_accuracy([band], given_m=0.7)
    assert (acc.east_m, acc.north_m, acc.source) == (0.7, 0.7, "option")
    assert reference_accuracy([band], given_m=0.0).east_m == 0.0  # 0 is a statement, not "unknown"


def test_tiles_keep_the_largest_statement(tmp_path):
    a = _raster(tmp_path / "a.tif", {ACCURACY_TAG_X: "1.0", ACCURACY_TAG_Y: "5.0"})
    b = _raster(tmp_path / "b.tif", {ACCURACY_TAG: "3.0"})
    acc = reference_accuracy([a, b])
    assert (acc.east_m, acc.north_m) == (3.0, 5.0)


def test_unknown_is_assumed_and_said(tmp_path, shared_data):
    acc = reference_accuracy([_raster(tmp_path / "dom.tif")])
    assert acc.assumed and acc.source == "assumed"
    assert acc.east_m == acc.north_m == pytest.approx(5.59, abs=0.01)  # 12 m CE90 / 2.146
    assert "assumed 5.6 m" in acc.note and "--reference-sigma-m" in acc.note
    # the real Landsat 8 and Sentinel-2 crops carry neither tags nor an MTL
    for path in (shared_data / "real_textures" / "landsat8" / "l8_B4.tif",
                 shared_data / "real_textures" / "sentinel2" / "s2_B04.jp2"):
        if path.exists():
            assert reference_accuracy([str(path)]).assumed, path


def test_reference_sigma_px_projects_east_and_north():
    """On a near-polar orbit rows run about north-south: a north error lands in rows, an east one in columns."""
    from gcpmatch.reference import scene_gsd_m
    from gcpmatch.uncertainty import reference_sigma_px
    from sensor_models.readers import open_model

    model = open_model(FIXTURE / "manifest.json")
    band = model.reference_band
    look = model.detector_arrays(band)[0]
    gsd = scene_gsd_m(model, band=band)
    kw = dict(band=band, first_col=look.first_col, n_detectors=look.n_detectors, array=0)
    row_n, col_n = reference_sigma_px(model, 0.0, 10.0, **kw)
    row_e, col_e = reference_sigma_px(model, 10.0, 0.0, **kw)
    assert row_n > 3 * col_n and col_e > 3 * row_e, (row_n, col_n, row_e, col_e)
    # the trace is invariant to the orientation: (row^2 + col^2) = (east^2 + north^2) / gsd^2 for square pixels
    row, col = reference_sigma_px(model, 10.0, 10.0, **kw)
    assert np.hypot(row, col) == pytest.approx(np.hypot(10.0, 10.0) / gsd, rel=0.1)
    assert row == pytest.approx(np.hypot(row_n, row_e), rel=1e-6)


def test_match_reads_the_dom_tag_and_the_option_wins(tmp_path, capsys):
    """``gcpcal match`` on the ideal fixture with a tagged copy of its DOM: the summary names the tag;
    ``--reference-sigma-m`` overrides it."""
    from calibrate.cli import main

    dom = tmp_path / "dom.tif"
    shutil.copy(FIXTURE / "reference" / "dom.tif", dom)
    with rasterio.open(dom, "r+") as ds:
        ds.update_tags(**{ACCURACY_TAG_X: "3.0", ACCURACY_TAG_Y: "9.0"})
    base = ["match", str(FIXTURE / "manifest.json"), "--dom", str(dom), "--dem",
            str(FIXTURE / "reference" / "dem.tif"), "--spacing", "96"]
    assert main([*base, "--out", str(tmp_path / "tag.csv")]) == 0
    assert f"reference accuracy: 3 m east, 9 m north (1 sigma, from tag {dom})" in capsys.readouterr().out
    tag = json.loads((tmp_path / "tag.summary.json").read_text())
    assert tag["reference_accuracy"] == {"east_m": 3.0, "north_m": 9.0, "source": f"tag {dom}", "assumed": False}
    assert "reference_note" not in tag
    ref = np.array([c["reference_sigma_px"] for c in tag["per_ccd"]])  # (row, col) per CCD
    assert np.all(ref[:, 0] > 2 * ref[:, 1]), ref  # the 9 m north error lands in rows (near-polar orbit)
    assert main(["-q", *base, "--reference-sigma-m", "0", "--out", str(tmp_path / "opt.csv")]) == 0
    opt = json.loads((tmp_path / "opt.summary.json").read_text())
    assert opt["reference_accuracy"]["source"] == "option" and opt["reference_accuracy"]["east_m"] == 0.0
    assert np.all(np.array([c["reference_sigma_px"] for c in opt["per_ccd"]]) == 0.0)
