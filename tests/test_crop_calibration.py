"""A crop of an RPC product, calibrated: each RPC file is named for the raster it describes.

An RPC product delivered as a crop (a raster with a pixel geotransform ``(1, 0, c0, 0, 1, r0)``
and the full scene's RPC beside it, as the real Pleiades crops of ``../shared/data``) is
calibrated in the crop's pixels. ``calibrate`` writes ``<crop>_RPC.TXT`` in the crop's pixels,
the sidecar GDAL pairs with the crop raster, and the full scene's RPC as
``<product>_full_scene_RPC.TXT``, a name no raster of the product pairs with: the model the other
commands open (``ortho --calibration`` and ``rpc --image`` crop it through the raster's
geotransform exactly once). Generated data (a 240 x 240 px RPC near Mont
Ventoux, flat terrain, GCPs localized through a known true model), a few seconds.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import RPCTransformer

from calibrate.cli import main
from gcpmatch.gcp_csv import write_gcps_csv
from gcpmatch.gcps import GcpTable
from sensor_models.models.rpc import RpcModel
from sensor_models.readers.rpc_files import read_rpc, rpc_to_gdal_metadata

pytestmark = pytest.mark.filterwarnings("ignore", category=NotGeoreferencedWarning)

FULL = (240, 240)  # the full scene, rows x cols
ORIGIN, CROP = (70, 50), (120, 150)  # the crop's first pixel in the full scene (row, col), its shape
BIAS_PX = (3.0, -2.0)  # the product's RPC error, rows and columns
HEIGHT_M = 300.0


def _full_rpc(line_shift=0.0, samp_shift=0.0) -> RpcModel:
    """About 8 m pixels near (5.2 E, 44.2 N), north up, with a little skew and relief parallax."""
    den = np.zeros(20)
    den[0] = 1.0
    line_num, samp_num = np.zeros(20), np.zeros(20)
    line_num[2], line_num[1], line_num[3] = -1.0, 0.02, 0.03
    samp_num[1], samp_num[2], samp_num[3] = 1.0, 0.01, -0.01
    return RpcModel(line_num=line_num, line_den=den, samp_num=samp_num, samp_den=den.copy(),
                    line_off=119.5 + line_shift, samp_off=119.5 + samp_shift, lat_off=44.2, lon_off=5.2,
                    height_off=300.0, line_scale=120.0, samp_scale=120.0, lat_scale=120 * 8 / 111_000,
                    lon_scale=120 * 8 / (111_000 * np.cos(np.radians(44.2))), height_scale=500.0, image_shape=FULL)


def _crop_raster(path) -> None:
    rng = np.random.default_rng(11)
    pixels = (1000 + 300 * rng.standard_normal(CROP)).clip(1, 4000).astype(np.uint16)
    with rasterio.open(path, "w", driver="GTiff", width=CROP[1], height=CROP[0], count=1, dtype="uint16",
                       transform=Affine(1, 0, ORIGIN[1], 0, 1, ORIGIN[0])) as ds:
        ds.write(pixels, 1)


def _write_geom(model: RpcModel, path) -> None:
    """The model as an OSSIM keyword list (``polynomial_format: B``, as the shareloc ``.geom`` files)."""
    md = rpc_to_gdal_metadata(model)
    text = ["type: ossimRpcModel", "polynomial_format: B", f"number_lines: {FULL[0]}", f"number_samples: {FULL[1]}"]
    text += [f"{k.lower()}: {md[k]}" for k in ("LINE_OFF", "SAMP_OFF", "LAT_OFF", "LONG_OFF", "HEIGHT_OFF",
                                               "LINE_SCALE", "SAMP_SCALE", "LAT_SCALE", "LONG_SCALE", "HEIGHT_SCALE")]
    for k in ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF"):
        text += [f"{k.lower()}_{i:02d}: {v}" for i, v in enumerate(md[k].split())]
    Path(path).write_text("\n".join(text) + "\n", encoding="ascii")


@pytest.fixture(scope="module")
def product(tmp_path_factory):
    """The crop with the product's (biased) RPC beside it, GCPs from the true model, a flat DEM."""
    d = tmp_path_factory.mktemp("crop")
    _crop_raster(d / "crop.tif")
    _write_geom(_full_rpc(), d / "crop.geom")  # the product's RPC beside the crop, describing the full scene
    truth = _full_rpc(*BIAS_PX)
    rows, cols = np.meshgrid(np.arange(5.5, CROP[0], 10.0), np.arange(5.5, CROP[1], 10.0), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    lon, lat, h = truth.image_to_ground(rows + ORIGIN[0], cols + ORIGIN[1], height=HEIGHT_M)
    kind = np.where(np.arange(rows.size) % 5 == 0, "check", "gcp")
    write_gcps_csv(GcpTable.from_arrays(rows, cols, lon, lat, h, sigma_px=0.1, kind=kind), d / "gcps.csv")
    with rasterio.open(d / "dem.tif", "w", driver="GTiff", width=40, height=40, count=1, dtype="float32",
                       crs="EPSG:4326", transform=Affine(0.0025, 0, 5.15, 0, -0.0025, 44.25)) as ds:
        ds.write(np.full((40, 40), HEIGHT_M, dtype=np.float32), 1)
    # the same crop with the true RPC beside it: what the calibrated geometry must reproduce
    _crop_raster(d / "truth.tif")
    _write_geom(truth, d / "truth.geom")
    code = main(["-q", "calibrate", str(d / "crop.tif"), "--gcps", str(d / "gcps.csv"), "--out", str(d / "cal"),
                 "--no-report"])
    assert code == 0
    return d, (rows, cols, lon, lat, h)


def test_calibrated_rpcs_are_written_in_the_pixels_their_names_pair_with(product):
    d, (rows, cols, lon, lat, h) = product
    crop_rpc = read_rpc(d / "cal" / "crop_RPC.TXT")  # GDAL pairs it with crop.tif: the crop's pixels
    r, c = crop_rpc.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(r, rows, atol=1e-4)
    np.testing.assert_allclose(c, cols, atol=1e-4)
    full = read_rpc(d / "cal" / "crop_full_scene_RPC.TXT")
    r, c = full.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(r, rows + ORIGIN[0], atol=1e-4)  # full-scene rows
    np.testing.assert_allclose(c, cols + ORIGIN[1], atol=1e-4)
    assert full.line_off == pytest.approx(119.5 + BIAS_PX[0], abs=1e-4)  # the bias, not the crop offset


def test_the_sidecar_copied_beside_the_crop_is_what_gdal_uses_and_agrees_with_localize(product, tmp_path):
    """As an analyst does: the crop raster alone in a folder with the calibrated sidecar copied
    beside it. GDAL's RPC transformer (reading the sidecar) and ``gcpcal localize`` of the
    calibration agree within 1e-3 px (the requirement is 1 px), and the full-scene file,
    copied too, is not what GDAL pairs with the crop."""
    import shutil

    d, (rows, cols, lon, lat, h) = product
    shutil.copy(d / "crop.tif", tmp_path / "crop.tif")
    for name in ("crop_RPC.TXT", "crop_full_scene_RPC.TXT"):
        shutil.copy(d / "cal" / name, tmp_path / name)
    with rasterio.open(tmp_path / "crop.tif") as ds:
        rpcs = ds.rpcs
    assert rpcs is not None
    with RPCTransformer(rpcs) as tr:
        r, c = tr.rowcol(lon, lat, h, op=np.positive)
    out = tmp_path / "ours.csv"
    points = tmp_path / "points.csv"
    points.write_text("lon,lat,h\n" + "".join(f"{x:.12f},{y:.12f},{z:.6f}\n" for x, y, z in zip(lon, lat, h)))
    assert main(["-q", "localize", str(tmp_path / "crop.tif"), "--csv", str(points), "--inverse", "--out",
                 str(out)]) == 0  # the crop raster with its copied sidecar, as GDAL sees it
    ours = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(np.asarray(r, float), ours[:, 0], atol=1e-3)
    np.testing.assert_allclose(np.asarray(c, float), ours[:, 1], atol=1e-3)
    np.testing.assert_allclose(ours[:, 0], rows, atol=1e-3)  # and both are the crop's true pixels
    np.testing.assert_allclose(ours[:, 1], cols, atol=1e-3)


def test_calibrated_rpc_states_its_errors_from_the_check_points(product):
    """ERR_BIAS / ERR_RAND (GDAL RFC 22) are filled, not -1: the check points' scatter in metres
    (GCPs from the true model: millimetres) and the reference's accuracy (none stated: 0)."""
    d, _ = product
    text = (d / "cal" / "crop_RPC.TXT").read_text()
    fields = dict(line.split(":", 1) for line in text.splitlines() if line.startswith("ERR_"))
    err_bias, err_rand = (float(fields[k].split()[0]) for k in ("ERR_BIAS", "ERR_RAND"))
    assert 0.0 <= err_bias < 0.05 and 0.0 <= err_rand < 0.05, (err_bias, err_rand)
    assert read_rpc(d / "cal" / "crop_RPC.TXT").err_rand == pytest.approx(err_rand)


def test_ortho_with_the_calibration_crops_it_like_the_scene(product):
    d, _ = product
    dem = ["--dem", str(d / "dem.tif"), "--dem-datum", "ellipsoid"]
    assert main(["-q", "ortho", str(d / "crop.tif"), "--calibration", str(d / "cal"), *dem,
                 "--out", str(d / "cal_ortho.tif")]) == 0
    assert main(["-q", "ortho", str(d / "truth.tif"), *dem, "--out", str(d / "truth_ortho.tif")]) == 0
    assert main(["-q", "ortho", str(d / "crop.tif"), *dem, "--out", str(d / "raw_ortho.tif")]) == 0
    with rasterio.open(d / "cal_ortho.tif") as a, rasterio.open(d / "truth_ortho.tif") as b:
        assert a.transform == b.transform
        pa, pb = a.read(1).astype(int), b.read(1).astype(int)
    assert np.count_nonzero(pa) > 0.5 * pa.size and np.abs(pa - pb).max() <= 1
    with rasterio.open(d / "raw_ortho.tif") as raw:  # the uncalibrated product lands elsewhere
        assert raw.transform != a.transform or np.abs(raw.read(1).astype(int) - pa).max() > 100


def test_rpc_of_the_calibration_with_the_crop_raster_is_the_crops(product):
    d, (rows, cols, lon, lat, h) = product
    assert main(["-q", "rpc", str(d / "cal" / "crop_full_scene_RPC.TXT"), "--image", str(d / "crop.tif"),
                 "--height-range", "0", "600", "--out", str(d / "l1a.tif")]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(d / "l1a.tif") as ds:
            assert (ds.height, ds.width) == CROP
            rpcs = ds.rpcs
            tags = ds.tags()
    with RPCTransformer(rpcs) as tr:
        r, c = tr.rowcol(lon, lat, h, op=np.positive)
    np.testing.assert_allclose(np.asarray(r, float), rows, atol=1e-3)  # the crop's own pixels, cropped once
    np.testing.assert_allclose(np.asarray(c, float), cols, atol=1e-3)
    # the height hint equals HEIGHT_OFF, and the warning's distance is GDAL's own at 0 m vs the hint
    hint = float(tags["GCPCAL_RPC_HEIGHT_HINT_M"])
    assert hint == pytest.approx(float(rpcs.height_off), abs=0.05) and hint == pytest.approx(300.0, abs=1.0)
    with RPCTransformer(rpcs) as tr:
        xs, ys = tr.xy([CROP[0] / 2] * 2, [CROP[1] / 2] * 2, zs=[hint, 0.0], offset="ul")
    import pyproj

    gdal_m = pyproj.Geod(ellps="WGS84").inv(xs[0], ys[0], xs[1], ys[1])[2]
    stated_m = float(tags["GCPCAL_WARNING"].split(" lands ", 1)[1].split(" m ", 1)[0])
    assert abs(stated_m - gdal_m) <= 1.0 and gdal_m > 10.0, (stated_m, gdal_m)
    assert f"RPC_HEIGHT={hint:.0f}" in tags["GCPCAL_WARNING"]
