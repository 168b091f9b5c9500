"""A crop of an RPC product, calibrated: the calibrated RPC is the full scene's, and it crops again.

An RPC product delivered as a crop (a raster with a pixel geotransform ``(1, 0, c0, 0, 1, r0)``
and the full scene's RPC beside it, as the real Pleiades crops of ``../shared/data``) is
calibrated in the crop's pixels. ``calibrate`` writes the calibrated RPC in the full scene's
pixels, as the product's own RPC file, so that ``ortho --calibration`` and ``rpc --image`` crop it
through the raster's geotransform exactly once. Generated data (a 240 x 240 px RPC near Mont
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
    md = model.to_gdal_metadata()
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


def test_calibrated_rpc_is_written_in_the_full_scenes_pixels(product):
    d, (rows, cols, lon, lat, h) = product
    calibrated = RpcModel.read(d / "cal" / "crop_RPC.TXT")
    r, c = calibrated.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(r, rows + ORIGIN[0], atol=1e-4)  # full-scene rows, not the crop's
    np.testing.assert_allclose(c, cols + ORIGIN[1], atol=1e-4)
    assert calibrated.line_off == pytest.approx(119.5 + BIAS_PX[0], abs=1e-4)  # the bias, not the crop offset


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
    assert main(["-q", "rpc", str(d / "cal" / "crop_RPC.TXT"), "--image", str(d / "crop.tif"),
                 "--height-range", "0", "600", "--out", str(d / "l1a.tif")]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(d / "l1a.tif") as ds:
            assert (ds.height, ds.width) == CROP
            rpcs = ds.rpcs
    with RPCTransformer(rpcs) as tr:
        r, c = tr.rowcol(lon, lat, h, op=np.positive)
    np.testing.assert_allclose(np.asarray(r, float), rows, atol=1e-3)  # the crop's own pixels, cropped once
    np.testing.assert_allclose(np.asarray(c, float), cols, atol=1e-3)
