"""GDAL virtual paths as inputs: a scene raster, DOM and DEM read from inside a zip archive
(``/vsizip/``) give the same GCPs as the plain files; a missing member is one line naming it."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import pytest

from calibrate.cli import main
from sensor_models.files.gdal_paths import is_gdal_virtual, virtual_exists

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vsi")
    with zipfile.ZipFile(folder / "inputs.zip", "w") as z:  # stored and deflated members both
        z.write(FIXTURE / "reference" / "dom.tif", "ref/dom.tif", compress_type=zipfile.ZIP_DEFLATED)
        z.write(FIXTURE / "reference" / "dem.tif", "ref/dem.tif", compress_type=zipfile.ZIP_STORED)
        z.write(FIXTURE / "B2.tif", "scene/B2.tif", compress_type=zipfile.ZIP_DEFLATED)
    return folder


def test_recognised_and_asked_of_gdal(archive):
    inside = f"/vsizip/{archive / 'inputs.zip'}/ref/dem.tif"
    assert is_gdal_virtual(inside) and not is_gdal_virtual(str(FIXTURE / "B2.tif")) and not is_gdal_virtual(None)
    assert virtual_exists(inside) and not virtual_exists(f"/vsizip/{archive / 'inputs.zip'}/ref/none.tif")


def test_match_reads_scene_dom_and_dem_inside_a_zip_as_the_plain_files(archive, capsys):
    zip_path = archive / "inputs.zip"
    plain, zipped = archive / "plain.csv", archive / "zipped.csv"
    common = ["--spacing", "48"]
    assert main(["-q", "match", str(SCENE), "--dom", str(FIXTURE / "reference" / "dom.tif"), "--dem",
                 str(FIXTURE / "reference" / "dem.tif"), "--out", str(plain), *common]) == 0
    assert main(["-q", "match", str(SCENE), "--image", f"/vsizip/{zip_path}/scene/B2.tif",
                 "--dom", f"/vsizip/{zip_path}/ref/dom.tif", "--dem", f"/vsizip/{zip_path}/ref/dem.tif",
                 "--out", str(zipped), *common]) == 0
    capsys.readouterr()
    assert zipped.read_text() == plain.read_text()
    prov = json.loads(zipped.with_suffix(".summary.json").read_text())["provenance"]
    assert len(prov["virtual_inputs"]) == 3 and prov["terrain"]["dem"].startswith("/vsizip/")


def test_a_missing_member_is_one_line_naming_it(archive, capsys):
    missing = f"/vsizip/{archive / 'inputs.zip'}/ref/nothing.tif"
    code = main(["-q", "match", str(SCENE), "--dom", missing, "--dem", str(FIXTURE / "reference" / "dem.tif"),
                 "--out", str(archive / "x.csv")])
    err = capsys.readouterr().err
    assert code == 1 and missing in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (archive / "x.csv").exists()
