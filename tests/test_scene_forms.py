"""SCENE as the user has it: every form x every command, without ``--image``.

Each form of a scene (a raster with GeoTIFF RPC tags, a raster with an ``.RPB`` / ``_RPC.TXT`` /
``.geom`` sidecar, the model file with its raster beside it, a crop with a pixel geotransform)
must give a command the same result as the bare model file given with ``--image`` (the reference
form, which worked before :func:`sensor_models.readers.open_scene`). Generated scenes are small
(240 x 240 px, a synthetic RPC near Mont Ventoux over a flat DEM); the real Pleiades crops and the
SPOT 1-5 DIMAP metadata of ``../shared/data`` are used in place and skip when absent.

The form x command table in ``docs/inputs.md`` ("SCENE forms") is what these tests prove.
"""

from __future__ import annotations

import json
import os
import sys
import types

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.errors import NotGeoreferencedWarning
from scipy.ndimage import gaussian_filter

from calibrate.cli import main
from sensor_models.readers import open_model, open_scene
from sensor_models.models.rpc import RpcModel
from sensor_models.readers.rpc_files import read_rpc, rpc_to_gdal_metadata, rpc_to_rasterio, write_rpc

pytestmark = pytest.mark.filterwarnings("ignore", category=NotGeoreferencedWarning)

FULL = (240, 240)  # generated full scene, rows x cols
CROP_OFF, CROP = (40, 60), (150, 170)  # crop of it: first pixel (row, col) and shape
SHIFT_PX = (3.0, -2.0)  # the DOM's geometry against the scene's RPC, rows and columns
HEIGHT_M = 300.0  # the flat DEM, above the ellipsoid
MATCH = ["--window", "32", "--spacing", "16", "--max-offset", "20"]

# ----------------------------------------------------------------- generated scene


def _rpc() -> RpcModel:
    """A 240 x 240 px RPC of about 8 m pixels near (5.2 E, 44.2 N), with some relief parallax."""
    zeros = np.zeros(20)
    line_num, samp_num, den = zeros.copy(), zeros.copy(), zeros.copy()
    den[0] = 1.0
    line_num[2], line_num[3], line_num[1] = -1.0, 0.02, 0.03  # -P (north up), relief, skew
    samp_num[1], samp_num[3], samp_num[2] = 1.0, 0.01, -0.02
    return RpcModel(line_num=line_num, line_den=den, samp_num=samp_num, samp_den=den, line_off=119.5, samp_off=119.5,
                    lat_off=44.2, lon_off=5.2, height_off=300.0, line_scale=120.0, samp_scale=120.0,
                    lat_scale=120 * 8 / 111_000, lon_scale=120 * 8 / (111_000 * np.cos(np.radians(44.2))),
                    height_scale=500.0, image_shape=FULL)


def _texture(shape, seed) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.normal(size=shape), 2.0) + 0.3 * gaussian_filter(rng.normal(size=shape), 0.7)
    return (1000 + 400 * t / t.std()).clip(1, 4000).astype(np.uint16)


def _write_raster(path, pixels, *, transform=None, rpcs=None) -> None:
    kw = {} if transform is None else {"transform": transform}
    with rasterio.open(path, "w", driver="GTiff", width=pixels.shape[1], height=pixels.shape[0], count=1,
                       dtype=pixels.dtype, rpcs=rpcs, **kw) as ds:
        ds.write(pixels, 1)


def _write_geom(model: RpcModel, path) -> None:
    """An OSSIM keyword list (``polynomial_format: B``) from the GDAL metadata of ``model``."""
    md = rpc_to_gdal_metadata(model)
    lines = ["type: ossimRpcModel", "polynomial_format: B",
             f"number_lines: {model.image_shape[0]}", f"number_samples: {model.image_shape[1]}"]
    for key in ("LINE_OFF", "SAMP_OFF", "LAT_OFF", "LONG_OFF", "HEIGHT_OFF", "LINE_SCALE", "SAMP_SCALE", "LAT_SCALE",
                "LONG_SCALE", "HEIGHT_SCALE"):
        lines.append(f"{key.lower()}: {md[key]}")
    for key in ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF"):
        lines += [f"{key.lower()}_{i:02d}: {v}" for i, v in enumerate(md[key].split())]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def _write_dem(path) -> None:
    heights = np.full((60, 60), HEIGHT_M, dtype=np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=60, height=60, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(0.002, 0, 5.14, 0, -0.002, 44.26)) as ds:
        ds.write(heights, 1)


@pytest.fixture(scope="module")
def gen(tmp_path_factory):
    """Every form of one generated scene, its reference model file, a DEM and a DOM (its ortho)."""
    d = tmp_path_factory.mktemp("forms")
    model, pixels = _rpc(), _texture(FULL, 7)
    (d / "ref").mkdir()
    write_rpc(model, d / "ref" / "scene_RPC.TXT")  # no raster beside it: the reference is this + --image
    _write_raster(d / "tags.tif", pixels, rpcs=rpc_to_rasterio(model))
    for stem in ("rpb", "txt", "geom"):
        _write_raster(d / f"{stem}.tif", pixels)
    write_rpc(model, d / "rpb.RPB")
    write_rpc(model, d / "txt_RPC.TXT")
    _write_geom(model, d / "geom.geom")
    (r0, c0), (nr, nc) = CROP_OFF, CROP
    _write_raster(d / "crop.tif", pixels[r0:r0 + nr, c0:c0 + nc], transform=Affine(1, 0, c0, 0, 1, r0))
    _write_geom(model, d / "crop.geom")  # the full scene's RPC beside the crop
    _write_dem(d / "dem.tif")
    dem = ["--dem", str(d / "dem.tif"), "--dem-datum", "ellipsoid"]
    # the DOM: the scene orthorectified through its RPC moved by SHIFT_PX (what calibrate must find)
    kw = model.init_kwargs()
    kw.update(line_off=model.line_off + SHIFT_PX[0], samp_off=model.samp_off + SHIFT_PX[1])
    write_rpc(RpcModel(**kw), d / "ref" / "shifted_RPC.TXT")
    assert main(["-q", "ortho", str(d / "ref" / "shifted_RPC.TXT"), "--image", str(d / "tags.tif"), *dem,
                 "--out", str(d / "dom.tif")]) == 0
    return types.SimpleNamespace(dir=d, dem=dem, dom=str(d / "dom.tif"), ref=str(d / "ref" / "scene_RPC.TXT"))


#: form -> (SCENE file, raster of the pixels, crop offset (row, col) of the raster in the full scene)
FORMS = {
    "raster with RPC tags": ("tags.tif", "tags.tif", (0, 0)),
    "raster + .RPB": ("rpb.tif", "rpb.tif", (0, 0)),
    "raster + _RPC.TXT": ("txt.tif", "txt.tif", (0, 0)),
    "raster + .geom": ("geom.tif", "geom.tif", (0, 0)),
    ".geom + raster": ("geom.geom", "geom.tif", (0, 0)),
    ".RPB + raster": ("rpb.RPB", "rpb.tif", (0, 0)),
    "_RPC.TXT + raster": ("txt_RPC.TXT", "txt.tif", (0, 0)),
    "crop raster + .geom": ("crop.tif", "crop.tif", CROP_OFF),
    "crop .geom + raster": ("crop.geom", "crop.tif", CROP_OFF),
}


def _read(path) -> np.ndarray:
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform, ds.crs


def _same_gcps(a, b, *, minimum: int) -> None:
    """Two GCP tables with the same points; GeoTIFF RPC tags round coefficients (GDAL prints them
    with 15 digits), so numbers agree to 1e-6 px and 1e-10 degrees, not bit for bit."""
    ta, tb = (np.genfromtxt(p, delimiter=",", names=True, dtype=None, encoding="ascii") for p in (a, b))
    assert ta.size == tb.size >= minimum
    assert list(ta["id"]) == list(tb["id"]) and list(ta["kind"]) == list(tb["kind"])
    for name, tol in (("row", 1e-6), ("col", 1e-6), ("lon", 1e-10), ("lat", 1e-10), ("h", 1e-6)):
        np.testing.assert_allclose(ta[name], tb[name], rtol=0, atol=tol, err_msg=name)


def _localize_json(capsys, model, rows, cols) -> dict:
    capsys.readouterr()
    assert main(["localize", model, "--height", str(HEIGHT_M), "--rows", ",".join(map(str, rows)),
                 "--cols", ",".join(map(str, cols)), "--json"]) == 0
    return json.loads(capsys.readouterr().out)["results"]


@pytest.mark.parametrize("form", list(FORMS))
def test_open_scene_finds_the_raster_and_crops(gen, form):
    scene, raster, (r0, c0) = FORMS[form]
    opened = open_scene(gen.dir / scene)
    model = opened.model
    assert opened.rasters == {None: {"path": str((gen.dir / raster).resolve()), "index": 1}}
    assert opened.raster_candidates == ()
    with rasterio.open(gen.dir / raster) as ds:
        assert model.image_shape == (ds.height, ds.width)
    full = open_model(gen.ref)
    lon, lat, h = full.image_to_ground(np.array([r0 + 10.5, r0 + 100.25]), np.array([c0 + 20.5, c0 + 3.75]),
                                       height=HEIGHT_M)
    row, col = model.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(row, [10.5, 100.25], atol=1e-7)
    np.testing.assert_allclose(col, [20.5, 3.75], atol=1e-7)


@pytest.mark.parametrize("form", list(FORMS))
def test_every_command_without_image_equals_with_image(gen, form, tmp_path, capsys):
    """ortho, match, calibrate, localize and rpc on the form == the reference model file + --image."""
    scene, raster, (r0, c0) = FORMS[form]
    scene, raster = str(gen.dir / scene), str(gen.dir / raster)
    # ortho: the same pixels on the same grid
    assert main(["-q", "ortho", scene, *gen.dem, "--out", str(tmp_path / "a.tif")]) == 0
    assert main(["-q", "ortho", gen.ref, "--image", raster, *gen.dem, "--out", str(tmp_path / "b.tif")]) == 0
    (a, ta, ca), (b, tb, cb) = _read(tmp_path / "a.tif"), _read(tmp_path / "b.tif")
    assert ta == tb and ca == cb and np.array_equal(a, b) and np.count_nonzero(a) > 0.3 * a.size
    # match: the same GCP table; calibrate: the same bias
    common = ["--dom", gen.dom, *gen.dem, *MATCH]
    assert main(["-q", "match", scene, *common, "--out", str(tmp_path / "a.csv")]) == 0
    assert main(["-q", "match", gen.ref, "--image", raster, *common, "--out", str(tmp_path / "b.csv")]) == 0
    _same_gcps(tmp_path / "a.csv", tmp_path / "b.csv", minimum=20)
    assert main(["-q", "calibrate", scene, "--gcps", str(tmp_path / "a.csv"), "--out", str(tmp_path / "ca"),
                 "--no-report"]) == 0
    assert main(["-q", "calibrate", gen.ref, "--image", raster, "--gcps", str(tmp_path / "a.csv"),
                 "--out", str(tmp_path / "cb"), "--no-report"]) == 0
    bias_a = json.loads((tmp_path / "ca" / "calibration.json").read_text())["bias"]
    bias_b = json.loads((tmp_path / "cb" / "calibration.json").read_text())["bias"]
    np.testing.assert_allclose(list(bias_a.values()), list(bias_b.values()), rtol=0, atol=1e-6)
    assert abs(bias_a["bias.row.a0"] - SHIFT_PX[0]) < 0.1 and abs(bias_a["bias.col.b0"] - SHIFT_PX[1]) < 0.1
    # localize: pixels of the raster, i.e. full-scene pixels shifted by the crop offset
    rows, cols = [0.5, 75.25, 149.5], [0.5, 160.75, 33.0]
    got = _localize_json(capsys, scene, rows, cols)
    ref = _localize_json(capsys, gen.ref, [r + r0 for r in rows], [c + c0 for c in cols])
    np.testing.assert_allclose(got["lon"], ref["lon"], rtol=0, atol=1e-11)
    np.testing.assert_allclose(got["lat"], ref["lat"], rtol=0, atol=1e-11)
    # rpc: the fitted RPC describes the raster's pixels
    assert main(["-q", "rpc", scene, "--height-range", "0", "600", "--out", str(tmp_path / "fit_RPC.TXT")]) == 0
    fitted, full = read_rpc(tmp_path / "fit_RPC.TXT"), open_model(gen.ref)
    lon, lat, h = full.image_to_ground(np.array([r0 + 5.5, r0 + 140.5]), np.array([c0 + 7.5, c0 + 150.5]),
                                       height=250.0)
    row, col = fitted.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(np.r_[row, col], [5.5, 140.5, 7.5, 150.5], atol=1e-3)


def test_relative_takes_the_form_and_says_an_rpc_has_no_bands(gen, tmp_path, capsys):
    """relative reads an RPC raster form as a SCENE, and refuses it in one line: it needs bands."""
    cal = tmp_path / "cal"
    assert main(["-q", "match", str(gen.dir / "tags.tif"), "--dom", gen.dom, *gen.dem, *MATCH,
                 "--out", str(tmp_path / "g.csv")]) == 0
    assert main(["-q", "calibrate", str(gen.dir / "tags.tif"), "--gcps", str(tmp_path / "g.csv"), "--out", str(cal),
                 "--no-report"]) == 0
    capsys.readouterr()
    code = main(["relative", str(gen.dir / "tags.tif"), "--calibration", str(cal / "tags_RPC.TXT"), *gen.dem,
                 "--out", str(tmp_path / "rel")])
    err = capsys.readouterr().err.strip()
    assert code == 1 and "push-broom" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "rel").exists()


def test_run_on_a_crop_raster(gen, tmp_path):
    """run (match, then calibrate) on the crop as given: the DOM's shift comes back as the bias."""
    out = tmp_path / "run"
    assert main(["-q", "run", str(gen.dir / "crop.tif"), "--dom", gen.dom, *gen.dem, "--out", str(out),
                 "--min-gcps", "20"]) == 0
    summary = json.loads((out / "run.summary.json").read_text())
    assert summary["path"] == "gcps" and summary["success"]
    bias = json.loads((out / "calibration" / "calibration.json").read_text())["bias"]
    assert abs(bias["bias.row.a0"] - SHIFT_PX[0]) < 0.1 and abs(bias["bias.col.b0"] - SHIFT_PX[1]) < 0.1


def test_image_overrides_the_raster_found(gen, tmp_path):
    """--image wins over the raster beside the model file; its crop crops the model."""
    scene = open_scene(gen.dir / "geom.geom", image=gen.dir / "crop.tif")
    assert scene.model.image_shape == CROP
    assert scene.rasters[None]["path"] == str((gen.dir / "crop.tif").resolve())


# ----------------------------------------------------------------- what is refused, in one line


def _one_line_error(capsys, argv) -> str:
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 1, err
    assert err.startswith("gcpcal: error:") and len(err.splitlines()) == 1
    return err


def test_model_file_without_raster_names_what_it_looked_for(gen, tmp_path, capsys):
    err = _one_line_error(capsys, ["ortho", gen.ref, *gen.dem, "--out", str(tmp_path / "o.tif")])
    assert "looked for scene.tif, scene.TIF" in err and "give --image" in err
    err = _one_line_error(capsys, ["match", gen.ref, "--dom", gen.dom, *gen.dem, "--out", str(tmp_path / "g.csv")])
    assert "looked for scene.tif" in err
    assert not list(tmp_path.iterdir())
    scene = open_scene(gen.ref)  # commands that need no pixels still work
    assert scene.rasters == {} and len(scene.raster_candidates) == 8


def test_raster_without_any_model_says_where_it_looked(gen, tmp_path, capsys):
    _write_raster(tmp_path / "bare.tif", _texture((32, 32), 1))
    err = _one_line_error(capsys, ["localize", str(tmp_path / "bare.tif"), "--height", "0", "--rows", "1",
                                   "--cols", "1"])
    assert "no sensor model found" in err and "bare.RPB" in err and "bare.geom" in err


def test_crop_without_pixel_geotransform_is_refused(gen, tmp_path, capsys):
    _write_raster(tmp_path / "odd.tif", _texture((50, 60), 2), transform=Affine(2, 0, 10, 0, 2, 10))
    _write_geom(_rpc(), tmp_path / "odd.geom")
    err = _one_line_error(capsys, ["ortho", str(tmp_path / "odd.tif"), *gen.dem, "--out", str(tmp_path / "o.tif")])
    assert "50 x 60 px" in err and "240 x 240" in err and "pixel geotransform" in err


def test_manifest_rasters_unchanged():
    """A gcpcal manifest: open_scene gives the manifest's own rasters (the manifest reader's)."""
    from calibrate.pipelines.demo import FIXTURE_DIR
    from sensor_models.readers.scene import read_manifest_and_rasters

    manifest = FIXTURE_DIR / "manifest.json"
    scene, model = open_scene(manifest), open_model(manifest)
    assert scene.rasters == read_manifest_and_rasters(manifest)[1] and len(scene.rasters) == 4
    assert scene.model.image_shape == model.image_shape


# ----------------------------------------------------------------- vendor XML: the dispatch


def test_xml_dispatch_by_root_element(shared_data, tmp_path, monkeypatch, capsys):
    """DIMAP v2 and WorldView XML go to their readers by root element; a missing reader says so.

    The readers themselves come from other modules (``readers.dimap_v2``, ``readers.worldview``);
    here a stand-in reader module (returning the generated RPC) proves the dispatch and the
    raster the DIMAP v2 file names (``Raster_Data/Data_Access/.../DATA_FILE_PATH@href``).
    """
    products = shared_data / "products"
    for name, module in (("SPOT6.XML", "sensor_models.readers.dimap_v2"), ("WV2.XML", "sensor_models.readers.worldview")):
        try:
            __import__(module)
        except ImportError:
            err = _one_line_error(capsys, ["localize", str(products / name), "--height", "0", "--rows", "1",
                                           "--cols", "1"])
            assert "reader not available" in err
    fake = types.ModuleType("sensor_models.readers.dimap_v2")
    fake.read_dimap_v2_checked = lambda path, **kw: (_rpc(), None, None)
    monkeypatch.setitem(sys.modules, "sensor_models.readers.dimap_v2", fake)
    os.symlink(products / "SPOT6.XML", tmp_path / "DIM_SPOT6.XML")
    scene = open_scene(tmp_path / "DIM_SPOT6.XML")
    tile = "IMG_SPOT6_P_201809151819247_SEN_4555226101_R1C1.TIF"
    assert scene.rasters == {} and scene.raster_candidates == (str(tmp_path / tile),)
    _write_raster(tmp_path / tile, _texture(FULL, 3))
    scene = open_scene(tmp_path / "DIM_SPOT6.XML")
    assert scene.rasters == {None: {"path": str((tmp_path / tile).resolve()), "index": 1}}
    tiled = tmp_path / "DIM_TILED.XML"
    tiled.write_text("<?xml version='1.0'?><Dimap_Document><Raster_Data><Data_Access><Data_Files>"
                     + "".join(f"<Data_File><DATA_FILE_PATH href='R1C{i}.TIF'/></Data_File>" for i in (1, 2))
                     + "</Data_Files></Data_Access></Raster_Data></Dimap_Document>")
    assert open_scene(tiled).rasters == {} and open_scene(tiled).raster_tiles == 2
    err = _one_line_error(capsys, ["ortho", str(tiled), "--dem", str(tmp_path / "none.tif"),
                                   "--out", str(tmp_path / "o.tif")])
    assert "split into 2 tiles (R1C1.TIF, ...)" in err and "--image" in err
    (tmp_path / "other.xml").write_text("<?xml version='1.0'?><kml/>")
    with pytest.raises(Exception, match="unknown XML product"):
        open_model(tmp_path / "other.xml")


# ----------------------------------------------------------------- real data


def test_spot_dimap_finds_its_raster_by_href(shared_data, tmp_path, capsys):
    """SPOT 1-5 METADATA.DIM names IMAGERY.TIF: found beside it; localize needs no raster."""
    os.symlink(shared_data / "spot_dimap" / "SPOT1.DIM", tmp_path / "METADATA.DIM")
    dim = str(tmp_path / "METADATA.DIM")
    scene = open_scene(dim)
    assert scene.rasters == {} and scene.raster_candidates == (str(tmp_path / "IMAGERY.TIF"),)
    err = _one_line_error(capsys, ["ortho", dim, "--dem", "x.tif", "--out", str(tmp_path / "o.tif")])
    assert "looked for IMAGERY.TIF" in err
    with rasterio.open(tmp_path / "IMAGERY.TIF", "w", driver="GTiff", width=6000, height=6000, count=1,
                       dtype="uint8", tiled=True, compress="deflate") as ds:
        pass  # sparse: the header is what open_scene reads
    scene = open_scene(dim)
    assert scene.rasters == {"B1": {"path": str((tmp_path / "IMAGERY.TIF").resolve()), "index": 1}}
    got = _localize_json(capsys, dim, [0.5, 3000.5], [0.5, 5999.5])
    lon, lat, _ = open_model(shared_data / "spot_dimap" / "SPOT1.DIM").image_to_ground(
        np.array([0.5, 3000.5]), np.array([0.5, 5999.5]), height=HEIGHT_M)
    np.testing.assert_array_equal(got["lon"], lon)
    np.testing.assert_array_equal(got["lat"], lat)


@pytest.fixture(scope="module")
def ventoux(shared_data, tmp_path_factory):
    d = tmp_path_factory.mktemp("ventoux")
    folder = shared_data / "pleiades_ventoux"
    dem = ["--dem", str(shared_data / "dem" / "N44E005.hgt"), "--dem-datum", "egm96",
           "--geoid", str(shared_data / "dem" / "egm96_15.gtx")]
    return types.SimpleNamespace(folder=folder, dir=d, dem=dem)


def test_pleiades_crop_ortho_without_image(ventoux, tmp_path):
    """The real crop (500 x 500 px of a 41801 x 39182 px scene) orthorectifies as given."""
    f = ventoux.folder
    runs = {"tif": [str(f / "left_image.tif")], "geom": [str(f / "left_image.geom")],
            "image": [str(f / "left_image.geom"), "--image", str(f / "left_image.tif")]}
    out = {}
    for name, args in runs.items():
        assert main(["-q", "ortho", *args, *ventoux.dem, "--out", str(tmp_path / f"{name}.tif")]) == 0
        out[name] = _read(tmp_path / f"{name}.tif")
    a = out["image"][0]
    assert a.shape == (509, 527) and np.count_nonzero(a) > 0.85 * a.size
    for name in ("tif", "geom"):
        assert out[name][1] == out["image"][1] and np.array_equal(out[name][0], a)


def test_pleiades_match_calibrate_localize_rpc_without_image(ventoux, tmp_path, capsys):
    """right_image.tif (crop + .geom) against the left crop's ortho: as with --image, and localize/rpc of the crop."""
    f, dem = ventoux.folder, ventoux.dem
    dom = str(tmp_path / "dom.tif")
    assert main(["-q", "ortho", str(f / "left_image.tif"), *dem, "--out", dom]) == 0
    common = ["--dom", dom, *dem, "--window", "32", "--spacing", "8", "--max-offset", "150"]
    assert main(["-q", "match", str(f / "right_image.tif"), *common, "--out", str(tmp_path / "a.csv")]) == 0
    assert main(["-q", "match", str(f / "right_image.geom"), "--image", str(f / "right_image.tif"), *common,
                 "--out", str(tmp_path / "c.csv")]) == 0
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "c.csv").read_text()  # same .geom: bit for bit
    _same_gcps(tmp_path / "a.csv", tmp_path / "c.csv", minimum=300)
    assert main(["-q", "calibrate", str(f / "right_image.tif"), "--gcps", str(tmp_path / "a.csv"),
                 "--out", str(tmp_path / "ca"), "--no-report"]) == 0
    assert main(["-q", "calibrate", str(f / "right_image.geom"), "--image", str(f / "right_image.tif"),
                 "--gcps", str(tmp_path / "a.csv"), "--out", str(tmp_path / "cb"), "--no-report"]) == 0
    bias = [json.loads((tmp_path / c / "calibration.json").read_text())["bias"] for c in ("ca", "cb")]
    assert bias[0] == bias[1] and 1.0 < abs(bias[0]["bias.row.a0"]) < 10.0  # the SRTM parallax floor
    # localize: crop pixel (r, c) is full-scene pixel (r + 5162, c + 4915)
    got = _localize_json(capsys, str(f / "right_image.tif"), [0.5, 250.0], [0.5, 400.0])
    full = open_model(f / "right_image.geom")
    lon, lat, _ = full.image_to_ground(np.array([5162.5, 5412.0]), np.array([4915.5, 5315.0]), height=HEIGHT_M)
    np.testing.assert_allclose(got["lon"], lon, rtol=0, atol=1e-10)
    np.testing.assert_allclose(got["lat"], lat, rtol=0, atol=1e-10)
    assert main(["-q", "rpc", str(f / "right_image.tif"), "--height-range", "300", "800",
                 "--out", str(tmp_path / "crop_RPC.TXT")]) == 0
    fitted = read_rpc(tmp_path / "crop_RPC.TXT")
    row, col = fitted.ground_to_image(lon, lat, np.full(2, HEIGHT_M))
    np.testing.assert_allclose(np.r_[row, col], [0.5, 250.0, 0.5, 400.0], atol=1e-3)
