"""Outputs an analyst opens in QGIS: residual layers, the level-1A GeoTIFF with RPC tags, the GCP GeoTIFF.

Run through the real commands on the embedded HY-1C CZI fixture (four CCDs of 192 detectors,
30 m pixels, the LAB model ~260 px off) and on the shared Pleiades crop (an RPC product).
Everything is read back with rasterio/GDAL and pyogrio, and compared with numbers computed
independently of the writers (the model's own localization, pyproj's geodesic distances, GDAL's
RPC transformer).
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import RPCTransformer

from calibrate.accuracy import check_residuals
from calibrate.cli import main
from calibrate.residual_layer import RESIDUAL_FIELDS, read_residual_layer, residual_layer
from gcpmatch.gcp_files import read_gcps
from gcpmatch.gcps import GcpTable
from sensor_models.readers import open_model
from sensor_models.models.rpc import RpcModel
from sensor_models.readers.rpc_files import read_rpc

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
SCENE = FIXTURE / "manifest.json"
EXAMPLE = ROOT / "fixtures" / "example_pushbroom" / "manifest.json"
GEOD = pyproj.Geod(ellps="WGS84")


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _read_band(path, index=1, window=None):
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path) as ds:
            return ds.read(index, window=window)


@pytest.fixture(scope="module")
def matched(tmp_path_factory):
    """``gcpcal match`` on the fixture's reference band, with the GCP GeoTIFF."""
    out = tmp_path_factory.mktemp("match")
    code = main(["-q", "match", str(SCENE), "--dom", str(FIXTURE / "reference" / "dom.tif"),
                 "--dem", str(FIXTURE / "reference" / "dem.tif"), "--out", str(out / "gcps.csv"),
                 "--geotiff", str(out / "gcps.tif")])
    assert code == 0
    return out


@pytest.fixture(scope="module")
def calibrated(matched, tmp_path_factory):
    """``gcpcal calibrate`` on those GCPs (partial: the other bands are left to ``relative``)."""
    out = tmp_path_factory.mktemp("cal") / "cal"
    code = main(["-q", "calibrate", str(SCENE), "--gcps", str(matched / "gcps.csv"), "--out", str(out), "--no-report"])
    assert code == 4
    return out


def _same_points(layer, table):
    """The layer's points are the table's, in order, with their fields and geometry."""
    assert len(layer["id"]) == len(table)
    assert list(layer["id"]) == list(table.id)
    for k in ("row", "col", "lon", "lat", "h", "sigma_px"):
        np.testing.assert_array_equal(layer[k], getattr(table, k))
    np.testing.assert_array_equal(layer["geom_lon"], table.lon)
    np.testing.assert_array_equal(layer["geom_lat"], table.lat)
    np.testing.assert_array_equal(layer["geom_h"], table.h)
    assert list(layer["band"]) == list(table.band) and list(layer["ccd"]) == list(table.ccd)


# --------------------------------------------------------------------------- residual layers
def test_match_residual_layer_is_the_gcp_table_against_the_input_model(matched):
    table = read_gcps(matched / "gcps.csv")
    layer = read_residual_layer(matched / "gcps_residuals.gpkg")
    assert set(RESIDUAL_FIELDS) <= set(layer)
    _same_points(layer, table)
    assert list(layer["kind"]) == list(table.kind) and {"gcp", "check"} == set(layer["kind"])
    summary = json.loads((matched / "gcps.summary.json").read_text())
    assert summary["residual_layer"] == str(matched / "gcps_residuals.gpkg")
    assert (layer["kind"] == "gcp").sum() == summary["gcps"] and (layer["kind"] == "check").sum() == summary["check_points"]

    model = open_model(SCENE)  # the uncalibrated input model
    idx = np.array([model.detector_index([c], band="B2", array=n)[0] for c, n in zip(table.col, table.ccd)])
    res, _ = check_residuals(model, table.row, table.col, table.lon, table.lat, table.h, band=table.band, ccd=idx)
    np.testing.assert_allclose(layer["resid_along_px"], res[:, 0], atol=1e-9)
    np.testing.assert_allclose(layer["resid_across_px"], res[:, 1], atol=1e-9)
    planar = np.hypot(res[:, 0], res[:, 1])
    lost = np.isnan(layer["resid_along_px"])  # the LAB model projects these outside their CCD
    print(f"\nmatch residual layer: {len(table)} points, median planar {np.nanmedian(planar):.1f} px before "
          f"calibration, {lost.sum()} without a projection")
    assert lost.sum() < 0.2 * len(table) and np.array_equal(lost, np.isnan(layer["resid_along_m"]))
    assert 100.0 < np.nanmedian(planar) < 1000.0  # the LAB model is hundreds of pixels off


def test_metres_are_the_models_local_gsd(matched):
    """metres / px = the ground length of a one-pixel step at the point, from pyproj's geodesic."""
    table = read_gcps(matched / "gcps.csv")
    layer = read_residual_layer(matched / "gcps_residuals.gpkg")
    model = open_model(SCENE)
    sel = np.arange(0, len(table), 7)
    sel = sel[np.isfinite(layer["resid_along_px"][sel])]
    for axis, (dr, dc) in (("along", (0.5, 0.0)), ("across", (0.0, 0.5))):
        gsd = []
        for i in sel:
            kw = {"height": [table.h[i]], "band": "B2", "array": table.ccd[i]}
            lo = model.image_to_ground([table.row[i] - dr], [table.col[i] - dc], **kw)
            hi = model.image_to_ground([table.row[i] + dr], [table.col[i] + dc], **kw)
            gsd.append(GEOD.inv(lo[0][0], lo[1][0], hi[0][0], hi[1][0])[2])
        gsd = np.array(gsd)
        ratio = layer[f"resid_{axis}_m"][sel] / layer[f"resid_{axis}_px"][sel]
        np.testing.assert_allclose(ratio, gsd, rtol=0.01)
        np.testing.assert_allclose(layer[f"gsd_{axis}_m"][sel], gsd, rtol=0.01)
        assert 25.0 < gsd.min() and gsd.max() < 40.0  # the fixture's ~30 m pixels
    planar_m = np.hypot(layer["resid_along_m"], layer["resid_across_m"])
    np.testing.assert_allclose(layer["resid_planar_m"], planar_m, rtol=0.05)  # rows and columns nearly perpendicular


def test_calibrate_residual_layer_is_the_calibrations_own_residuals(calibrated, matched):
    table = read_gcps(matched / "gcps.csv")
    layer = read_residual_layer(calibrated / "residuals.gpkg")
    summary = json.loads((calibrated / "calibrate.summary.json").read_text())
    doc = json.loads((calibrated / "calibration.json").read_text())
    assert summary["residual_layer"] == "residuals.gpkg"
    fitted = np.isin(layer["kind"], ["gcp", "outlier"])
    assert fitted.sum() == summary["gcps"] == len(table.gcps())
    assert (layer["kind"] == "check").sum() == summary["check_points"] == len(table.checks())
    _same_points({k: v[fitted] for k, v in layer.items()}, table.gcps())
    _same_points({k: v[~fitted] for k, v in layer.items()}, table.checks())

    pts = doc["points"]  # the fit's own arrays, in the order of the table's GCPs
    np.testing.assert_array_equal(layer["resid_along_px"][fitted], np.asarray(pts["row_residual_after_px"], float))
    np.testing.assert_array_equal(layer["resid_across_px"][fitted], np.asarray(pts["col_residual_after_px"], float))
    assert list(layer["kind"][fitted] == "gcp") == list(pts["inlier"])
    # the fit rejected a few, not many: with the time-varying attitude the ideal fixture's fit
    # leaves 0.019 px rms, and about 9 % of its GCPs (matching errors of a few hundredths of a
    # pixel) fall outside its robust threshold, while the check points improve (0.031 px against
    # 0.067 px with a static attitude)
    assert 0 < (layer["kind"] == "outlier").sum() < 0.12 * fitted.sum()

    checks = ~fitted
    rmse = math.sqrt(np.mean(layer["resid_along_px"][checks] ** 2 + layer["resid_across_px"][checks] ** 2))
    print(f"\ncalibrate residual layer: check RMSE {rmse:.4f} px, summary {summary['check_rmse_px']['after']:.4f} px")
    assert rmse == pytest.approx(summary["check_rmse_px"]["after"], rel=1e-9)
    assert 0.01 < rmse < 0.3


def test_validate_scene_residuals_gather_into_one_layer(calibrated, tmp_path):
    """The task's residual layer (on the worker) and the gathering step, without a Dask cluster."""
    from functools import partial

    from calibrate.actions.validate import merge_residual_layers, write_scene_points
    from calibrate.batch import Site, validate_scene

    site = Site(name="hy1c one", scene=SCENE, dom=FIXTURE / "reference" / "dom.tif", dem=FIXTURE / "reference" / "dem.tif")
    row = validate_scene(site, calibrated / "manifest.json", write_points=partial(write_scene_points, tmp_path / "points"))
    assert row["status"] == "ok", row["reason"]
    assert (tmp_path / "points" / "hy1c_one_residuals.gpkg").is_file()
    assert merge_residual_layers(tmp_path, [row, {**row, "name": "failed scene"}]) == "residuals.gpkg"
    layer = read_residual_layer(tmp_path / "residuals.gpkg")
    assert len(layer["id"]) == row["points"] > 100
    assert set(layer["site"]) == {"hy1c one"} and set(layer["kind"]) == {"check"}
    _same_points(layer, read_gcps(tmp_path / "points" / "hy1c_one.csv"))
    rmse = math.sqrt(np.mean(layer["resid_along_px"] ** 2 + layer["resid_across_px"] ** 2))
    assert rmse == pytest.approx(row["rmse_planar_px"], rel=1e-9) and 0.01 < rmse < 0.3
    rmse_m = math.sqrt(np.mean(layer["resid_planar_m"] ** 2))
    assert rmse_m == pytest.approx(row["rmse_planar_m"], rel=1e-9)
    assert not list((tmp_path / "points").glob("*.gpkg"))  # gathered into the one layer


@pytest.mark.slow
def test_validate_residual_layer_has_one_site_field(calibrated, tmp_path, capsys):
    sites = tmp_path / "sites.csv"
    sites.write_text(f"name,scene,dom,dem\nhy1c,{SCENE},{FIXTURE / 'reference/dom.tif'},"
                     f"{FIXTURE / 'reference/dem.tif'}\n")
    code, out, err = _run(capsys, "validate", sites, "--calibration", calibrated, "--out", tmp_path / "val",
                          "--workers", "1", "--json")
    assert code == 0, err
    doc = json.loads(out)
    row = doc["rows"][0]
    layer = read_residual_layer(tmp_path / "val" / "residuals.gpkg")
    assert len(layer["id"]) == row["points"] > 100
    assert set(layer["site"]) == {"hy1c"} and set(layer["kind"]) == {"check"}
    points = read_gcps(tmp_path / "val" / "points" / "hy1c.csv")
    _same_points(layer, points)
    rmse = math.sqrt(np.mean(layer["resid_along_px"] ** 2 + layer["resid_across_px"] ** 2))
    assert rmse == pytest.approx(row["rmse_planar_px"], rel=1e-9)
    assert not list((tmp_path / "val" / "points").glob("*.gpkg"))  # gathered into the one layer


# --------------------------------------------------------------------------- the GCP GeoTIFF
def test_gcp_geotiff_holds_the_scene_pixels_and_the_gcps(matched):
    table = read_gcps(matched / "gcps.csv")
    with rasterio.open(matched / "gcps.tif") as ds:
        gcps, crs = ds.gcps
        pixels = ds.read(1)
        assert ds.count == 1 and crs.to_epsg() == 4326
    fit = table.kind == "gcp"  # a warp uses every GDAL GCP: the check points are not among them
    assert len(gcps) == fit.sum() < len(table)
    np.testing.assert_array_equal([g.row for g in gcps], table.row[fit])
    np.testing.assert_array_equal([g.col for g in gcps], table.col[fit])
    np.testing.assert_array_equal([g.x for g in gcps], table.lon[fit])
    scene = _read_band(FIXTURE / "B2.tif")
    assert pixels.dtype == scene.dtype and np.array_equal(pixels, scene)
    assert np.ptp(scene) > 0  # not a blank raster
    back = read_gcps(matched / "gcps.tif")  # our reader takes the whole table back, checks included
    assert len(back) == len(table) and list(back.kind) == list(table.kind)


def test_gcp_csv_opens_typed_as_wgs84_points_and_the_qc_figure_is_written(matched):
    """The .csvt and .prj beside the CSV: GDAL's CSV driver (QGIS's too) reads lon/lat as the
    point geometry in WGS84 and the numbers as reals; the QC figure is a PNG."""
    import pyogrio

    info = pyogrio.read_info(matched / "gcps.csv")
    assert info["geometry_type"] == "Point" and "WGS" in info["crs"] or "4326" in info["crs"]
    dtypes = dict(zip(info["fields"], info["dtypes"]))
    assert dtypes["row"] == dtypes["sigma_px"] == "float64" and dtypes["id"] == "object"
    _, _, geometry, values = pyogrio.raw.read(matched / "gcps.csv")
    table = read_gcps(matched / "gcps.csv")
    xy = np.array([struct.unpack("<bIdd", bytes(g)[:21])[2:] for g in geometry])
    np.testing.assert_allclose(xy[:, 0], table.lon, rtol=0, atol=1e-12)
    np.testing.assert_allclose(xy[:, 1], table.lat, rtol=0, atol=1e-12)
    png = matched / "gcps_qc.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 50_000
    summary = json.loads((matched / "gcps.summary.json").read_text())
    assert summary["qc_figure"] == str(png)


def test_gcp_geotiff_copies_only_the_matched_band(tmp_path):
    from gcpmatch.gcp_geotiff import write_gcps_geotiff
    from sensor_models.errors import InputError

    rng = np.random.default_rng(6)
    stack = rng.integers(0, 4000, size=(3, 30, 40)).astype("uint16")
    src = tmp_path / "stack.tif"
    with rasterio.open(src, "w", driver="GTiff", width=40, height=30, count=3, dtype="uint16") as ds:
        ds.write(stack)
    table = GcpTable.from_arrays([1.5, 20.5], [2.5, 35.5], [5.0, 5.1], [44.0, 44.1], [10.0, 20.0])
    write_gcps_geotiff(table, tmp_path / "g.tif", image_shape=(30, 40), source_raster=src, source_band=2)
    with rasterio.open(tmp_path / "g.tif") as ds:
        assert ds.count == 1 and len(ds.gcps[0]) == 2
        assert np.array_equal(ds.read(1), stack[1])
    for bad in (0, 4, "2"):
        with pytest.raises(InputError, match="source_band"):
            write_gcps_geotiff(table, tmp_path / "h.tif", image_shape=(30, 40), source_raster=src, source_band=bad)
    assert not (tmp_path / "h.tif").exists()


# --------------------------------------------------------------------------- rpc: L1A + exact path
def _gdal_round_trip(tif, ours: RpcModel, lon, lat, h):
    """Ground -> image by GDAL's RPC transformer (no RPC_DEM: the given heights) and by ours."""
    with rasterio.open(tif) as ds:
        rpcs = ds.rpcs
    assert rpcs is not None
    with RPCTransformer(rpcs) as tr:
        rows, cols = tr.rowcol(lon, lat, h, op=np.positive)
    r, c = ours.ground_to_image(lon, lat, h)
    return np.hypot(np.asarray(rows, float) - r, np.asarray(cols, float) - c)


def test_rpc_per_ccd_level1a_round_trips_through_gdal(tmp_path, capsys):
    """One RPC per CCD misses 0.01 px on this scene (its attitude and orbit samples vary faster
    than a cubic over the scene), so each CCD is split into row tiles: each tile's GeoTIFF holds
    exactly its pixels, GDAL reads its RPC, and it lands within 0.01 px of the rigorous model."""
    out = tmp_path / "l1a"
    code, _, err = _run(capsys, "rpc", SCENE, "--out", out, "--height-range", "0", "500", "--json")
    assert code == 0, err
    summary = json.loads((out / "rpc.summary.json").read_text())
    model = open_model(SCENE)
    arrays = {a.name: (i, a) for i, a in enumerate(model.detector_arrays("B2"))}
    entries = summary["rpcs"]
    assert {e["ccd"] for e in entries} == set(arrays) and len(entries) > len(arrays)  # tiled
    assert summary["check_max_px"] <= 0.01 and summary["max_error_px"] == 0.01
    stems = [Path(e["output"]).name[: -len("_RPC.TXT")] for e in entries]
    assert sorted(p.name for p in out.iterdir() if p.name != ".gcpcal-outputs.json") == sorted(
        ["rpc.summary.json"] + [f"{n}_RPC.TXT" for n in stems] + [f"{n}.tif" for n in stems])
    scene = _read_band(FIXTURE / "B2.tif")
    rng = np.random.default_rng(3)
    covered = {name: np.zeros(model.image_shape[0], int) for name in arrays}
    for entry, stem in zip(entries, stems):
        i, array = arrays[entry["ccd"]]
        r0, c0, (n_r, n_c) = entry["first_row"], entry["first_col"], entry["shape"]
        assert c0 == array.first_col and n_c == array.n_detectors  # rows split, not columns
        assert stem == f"{array.name}_r{r0}_c0" and entry["fit"]["form"] == "rational"
        covered[array.name][r0:r0 + n_r] += 1
        tif = out / f"{stem}.tif"
        with rasterio.open(tif) as ds:
            pixels, tags = ds.read(1), ds.tags()
        assert np.array_equal(pixels, scene[r0:r0 + n_r, c0:c0 + n_c])
        assert float(tags["GCPCAL_RPC_CHECK_MAX_PX"]) == entry["fit"]["check_max_px"]
        assert int(tags["GCPCAL_FIRST_ROW"]) == r0
        view = model.detector_view("B2", i)
        r = rng.uniform(0.5, n_r - 0.5, 40)  # tile pixels, not the check grid's
        c = rng.uniform(0.5, n_c - 0.5, 40)
        h = rng.uniform(0.0, 500.0, 40)
        lon, lat, _ = view.image_to_ground(r + r0, c, height=h)
        ours = read_rpc(out / f"{stem}_RPC.TXT")
        assert _gdal_round_trip(tif, ours, lon, lat, h).max() < 1e-3  # GDAL reads the same RPC
        with rasterio.open(tif) as ds, RPCTransformer(ds.rpcs) as tr:
            rows, cols = tr.rowcol(lon, lat, h, op=np.positive)
        err_px = np.hypot(np.asarray(rows) - r, np.asarray(cols) - c)
        # against the rigorous CCD model, at points no fit or check grid used
        assert err_px.max() <= 0.01 and entry["fit"]["check_max_px"] <= 0.01
    assert all(np.all(v == 1) for v in covered.values())  # the tiles cover every row once


def test_rpc_out_is_written_exactly(tmp_path, capsys):
    # several CCDs and a file name: one line, exit 2, nothing written
    code, out, err = _run(capsys, "rpc", SCENE, "--out", tmp_path / "x_RPC.TXT")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "4 CCDs" in err and "--out a folder" in err and "--ccd" in err
    assert list(tmp_path.iterdir()) == []
    code, out, err = _run(capsys, "rpc", SCENE, "--ccd", "cam2_ccd1", "--out", tmp_path / "x.txt")
    assert code == 2 and "*_RPC.TXT, *.RPB, *.tif or a folder" in err and list(tmp_path.iterdir()) == []
    # one CCD: exactly the file given, and its summary
    for name in ("one.tif", "one_RPC.TXT", "one.RPB"):
        code, out, err = _run(capsys, "rpc", SCENE, "--ccd", "cam2_ccd1", "--out", tmp_path / name,
                              "--height-range", "0", "500")
        assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != ".gcpcal-outputs.json") == sorted(
        ["one.tif", "one.tif.summary.json", "one_RPC.TXT", "one_RPC.TXT.summary.json", "one.RPB",
         "one.RPB.summary.json"])
    with rasterio.open(tmp_path / "one.tif") as ds:
        assert ds.shape == (512, 192) and ds.rpcs is not None
    # a *.tif is a copy of the scene raster: a model with no raster needs --image
    code, out, err = _run(capsys, "rpc", EXAMPLE, "--ccd", "ccd1", "--out", tmp_path / "ex.tif")
    assert code == 1 and "give --image" in err and not (tmp_path / "ex.tif").exists()
    # ... while a folder gets the text RPCs, and says why there is no raster (one RPC per CCD
    # within the tolerance asked for)
    code, out, err = _run(capsys, "rpc", EXAMPLE, "--out", tmp_path / "ex", "--height-range", "0", "100",
                          "--max-error-px", "1")
    assert code == 0 and "no raster" in err
    assert sorted(p.name for p in (tmp_path / "ex").iterdir() if p.name != ".gcpcal-outputs.json") == ["ccd1_RPC.TXT", "ccd2_RPC.TXT", "rpc.summary.json"]


# --------------------------------------------------------------------------- the Pleiades crop
@pytest.fixture(scope="module")
def ventoux(shared_data):
    return shared_data / "pleiades_ventoux"


def test_pleiades_crop_level1a_matches_its_rpc_through_gdal(ventoux, tmp_path, capsys):
    tif = tmp_path / "left_l1a.tif"
    code, _, err = _run(capsys, "rpc", ventoux / "left_image.geom", "--image", ventoux / "left_image.tif",
                        "--out", tif, "--height-range", "0", "2000")
    assert code == 0, err
    summary = json.loads((tmp_path / "left_l1a.tif.summary.json").read_text())
    assert summary["check_max_px"] < 1e-3  # an RPC refitted to an RPC
    with rasterio.open(tif) as ds:
        assert ds.shape == (500, 500) and float(ds.tags()["GCPCAL_RPC_CHECK_MAX_PX"]) == summary["check_max_px"]
        pixels = ds.read(1)
    assert np.array_equal(pixels, _read_band(ventoux / "left_image.tif"))
    with rasterio.open(ventoux / "left_image.tif") as ds:
        t = ds.transform
    crop = read_rpc(ventoux / "left_image.geom").cropped(int(t.f), int(t.c), (500, 500))
    rng = np.random.default_rng(4)
    r, c, h = rng.uniform(0.5, 499.5, 50), rng.uniform(0.5, 499.5, 50), rng.uniform(0.0, 2000.0, 50)
    lon, lat, _ = crop.image_to_ground(r, c, height=h)
    err_px = _gdal_round_trip(tif, crop, lon, lat, h)
    print(f"\nPleiades crop L1A: GDAL RPC transformer vs the product's RPC: max {err_px.max():.2e} px")
    assert err_px.max() < 0.01


def test_pleiades_residual_metres_follow_its_half_metre_pixels(ventoux):
    """The layer of an RPC model (no band, no CCD): a known image shift in px and in m."""
    with rasterio.open(ventoux / "left_image.tif") as ds:
        t = ds.transform
    crop = read_rpc(ventoux / "left_image.geom").cropped(int(t.f), int(t.c), (500, 500))
    rng = np.random.default_rng(5)
    r, c, h = rng.uniform(20, 480, 30), rng.uniform(20, 480, 30), rng.uniform(300.0, 1500.0, 30)
    lon, lat, _ = crop.image_to_ground(r, c, height=h)
    shift = np.array([1.5, -2.0])  # observed = modelled + shift
    table = GcpTable.from_arrays(r + shift[0], c + shift[1], lon, lat, h, sigma_px=0.1)
    res, _ = check_residuals(crop, table.row, table.col, lon, lat, h)
    np.testing.assert_allclose(res, np.broadcast_to(shift, res.shape), atol=1e-6)
    layer = residual_layer(crop, table, res, "check")
    assert set(layer["ccd"]) == {""} and set(layer["band"]) == {""}
    gsd = []
    for i in range(len(r)):
        lo = crop.image_to_ground([table.row[i] - 0.5], [table.col[i]], height=[h[i]])
        hi = crop.image_to_ground([table.row[i] + 0.5], [table.col[i]], height=[h[i]])
        gsd.append(GEOD.inv(lo[0][0], lo[1][0], hi[0][0], hi[1][0])[2])
    np.testing.assert_allclose(layer["resid_along_m"] / shift[0], gsd, rtol=0.01)
    assert 0.4 < np.median(layer["gsd_along_m"]) < 1.0 and 0.4 < np.median(layer["gsd_across_m"]) < 1.0


def test_pleiades_residual_east_north_and_azimuth_are_the_ground_displacement(ventoux):
    """East, north and azimuth of the residual against pyproj's geodesic between the modelled and
    the observed positions localized at the point's height (an independent computation: no GSD,
    no linearization); shifts in four directions so that every quadrant of the azimuth is hit."""
    with rasterio.open(ventoux / "left_image.tif") as ds:
        t = ds.transform
    crop = read_rpc(ventoux / "left_image.geom").cropped(int(t.f), int(t.c), (500, 500))
    rng = np.random.default_rng(11)
    n = 40
    r, c, h = rng.uniform(20, 480, n), rng.uniform(20, 480, n), rng.uniform(300.0, 1500.0, n)
    lon, lat, _ = crop.image_to_ground(r, c, height=h)
    shift = np.array([[1.5, -2.0], [-0.7, 0.4], [2.2, 1.1], [-1.3, -0.9]])[np.arange(n) % 4]
    table = GcpTable.from_arrays(r + shift[:, 0], c + shift[:, 1], lon, lat, h, sigma_px=0.1)
    res, _ = check_residuals(crop, table.row, table.col, lon, lat, h)
    layer = residual_layer(crop, table, res, "check")
    olon, olat, _ = crop.image_to_ground(table.row, table.col, height=h)
    az, _, dist = GEOD.inv(lon, lat, olon, olat)
    east, north = dist * np.sin(np.radians(az)), dist * np.cos(np.radians(az))
    np.testing.assert_allclose(layer["resid_east_m"], east, atol=0.01 * np.abs(dist).max())
    np.testing.assert_allclose(layer["resid_north_m"], north, atol=0.01 * np.abs(dist).max())
    d_az = (layer["resid_azimuth_deg"] - np.mod(az, 360.0) + 180.0) % 360.0 - 180.0
    assert np.abs(d_az).max() < 1.0 and (layer["resid_azimuth_deg"] >= 0).all() and (layer["resid_azimuth_deg"] < 360).all()
    np.testing.assert_allclose(np.hypot(layer["resid_east_m"], layer["resid_north_m"]), layer["resid_planar_m"], rtol=1e-12)
    assert len({int(a // 90) for a in layer["resid_azimuth_deg"]}) >= 3


def test_each_stage_names_its_residual_layer(matched, calibrated):
    """Loaded together in a GIS, the match and calibration layers keep distinct names."""
    import pyogrio

    def point_layers(path):
        return [name for name, geometry in pyogrio.list_layers(path) if geometry is not None]

    assert point_layers(matched / "gcps_residuals.gpkg") == ["match_residuals"]
    assert point_layers(calibrated / "residuals.gpkg") == ["calibration_residuals"]


def test_residual_layer_carries_its_qgis_style(matched):
    """QGIS's default-style table holds an arrow style for the layer: well-formed QML, rotation
    from the azimuth field, size from the planar residual, one category per kind."""
    import sqlite3
    import xml.etree.ElementTree as ET

    con = sqlite3.connect(matched / "gcps_residuals.gpkg")
    try:
        rows = con.execute("SELECT f_table_name, f_geometry_column, useAsDefault, styleQML FROM layer_styles").fetchall()
    finally:
        con.close()
    assert len(rows) == 1 and rows[0][:3] == ("match_residuals", "geom", 1)
    root = ET.fromstring(rows[0][3].split("\n", 1)[1])  # after the DOCTYPE line
    renderer = root.find("renderer-v2")
    assert renderer.get("attr") == "kind"
    assert {c.get("value") for c in renderer.iter("category")} == {"gcp", "check", "outlier"}
    fields = {o.get("value") for o in renderer.iter("Option") if o.get("name") == "field"}
    expressions = " ".join(o.get("value") for o in renderer.iter("Option") if o.get("name") == "expression")
    assert fields == {"resid_azimuth_deg"} and "resid_planar_px" in expressions
    assert len(read_residual_layer(matched / "gcps_residuals.gpkg")["id"]) > 0  # the style table is no layer


def test_layer_names_each_point_s_ccd_when_the_table_names_none(tmp_path):
    """A GCP table without a ``ccd`` column: the layer finds each point's CCD from its column."""
    truth = open_model(FIXTURE / "truth_manifest.json")
    rows, cols = np.meshgrid(np.linspace(20.5, 492.5, 12), np.linspace(20.5, 748.5, 24), indexing="ij")
    lon, lat, h = truth.image_to_ground(rows.ravel(), cols.ravel(), height=np.full(rows.size, 200.0), band="B2")
    lines = ["id,row,col,lon,lat,h,kind"] + [
        f"p{i},{float(r)!r},{float(c)!r},{float(x)!r},{float(y)!r},{float(z)!r},{'check' if i % 4 == 0 else 'gcp'}"
        for i, (r, c, x, y, z) in enumerate(zip(rows.ravel(), cols.ravel(), lon, lat, h))]
    (tmp_path / "gcps.csv").write_text("\n".join(lines) + "\n")
    assert main(["-q", "calibrate", str(SCENE), "--gcps", str(tmp_path / "gcps.csv"), "--out", str(tmp_path / "cal"),
                 "--no-report"]) == 4  # partial: the other bands are left to relative
    layer = read_residual_layer(tmp_path / "cal" / "residuals.gpkg")
    names = [a.name for a in truth.detector_arrays("B2")]
    want = np.array(names, dtype=object)[truth.detector_index(cols.ravel(), band="B2")]
    assert sorted(set(layer["ccd"])) == sorted(names)
    order = np.argsort([int(i[1:]) for i in layer["id"]])
    assert list(np.asarray(layer["ccd"])[order]) == list(want)


def test_rpc_of_a_calibrated_manifest_carries_its_check_point_accuracy(calibrated, tmp_path, capsys):
    """ERR_BIAS / ERR_RAND of ``gcpcal rpc`` on ``gcpcal calibrate``'s manifest: the check points'
    accuracy after calibration (as ``gcpcal calibrate`` writes for an RPC product), the RPC's own
    check-grid RMS added to ERR_RAND; in the text RPC and the GeoTIFF tags alike. Without a
    calibration beside the model they stay -1 (unknown), and the summary says why."""
    import shutil
    from types import SimpleNamespace

    from calibrate.actions.calibrate import rpc_error_estimates
    from calibrate.actions.rpc import calibration_errors

    layer = read_residual_layer(calibrated / "residuals.gpkg")
    check = np.asarray(layer["kind"]).astype(str) == "check"
    res = np.stack([layer["resid_along_m"][check], layer["resid_across_m"][check], layer["resid_planar_m"][check]], 1)
    doc = json.loads((calibrated / "calibration.json").read_text())
    sigma = (doc["reference_accuracy"]["east_m"], doc["reference_accuracy"]["north_m"])
    bias, rand = rpc_error_estimates(SimpleNamespace(residuals_m=res), sigma)
    for name in ("cal_RPC.TXT", "cal.tif"):
        code, out, err = _run(capsys, "rpc", calibrated / "manifest.json", "--ccd", "cam2_ccd1", "--out",
                              tmp_path / name, "--height-range", "0", "500")
        assert code == 0, err
        assert f"ERR_BIAS {bias:.3f} m" in out and f"from {int(check.sum())} check points" in out
    summary = json.loads((tmp_path / "cal_RPC.TXT.summary.json").read_text())
    errors, entry = summary["rpc_errors"], summary["rpcs"][0]
    assert errors["err_bias_m"] == pytest.approx(bias, rel=1e-12) and errors["err_rand_m"] == pytest.approx(rand)
    assert "residuals.gpkg" in errors["source"] and errors["check_points"] == int(check.sum()) == 56
    text = read_rpc(tmp_path / "cal_RPC.TXT")
    gsd = 30.0  # the fixture's ~30 m pixels: the fit's RMS adds a few tenths of a metre at most
    assert text.err_bias == pytest.approx(bias, rel=1e-12)
    assert rand < text.err_rand <= np.hypot(rand, entry["fit"]["check_rms_px"] * 1.2 * gsd)
    with rasterio.open(tmp_path / "cal.tif") as ds:
        assert float(ds.rpcs.err_bias) == pytest.approx(bias, rel=1e-9)
        assert float(ds.rpcs.err_rand) == pytest.approx(text.err_rand, rel=1e-6)
    print(f"\nrpc of the calibrated fixture: ERR_BIAS {text.err_bias:.3f} m, ERR_RAND {text.err_rand:.3f} m "
          f"(check points {rand:.3f} m, fit rms {entry['fit']['check_rms_px']:.3g} px)")
    # without the residual layer: the same formula on calibration.json's mean and RMS per axis
    copy = tmp_path / "copy"
    shutil.copytree(calibrated, copy, ignore=shutil.ignore_patterns("residuals.gpkg"))
    summed = calibration_errors(copy / "manifest.json")
    assert "check_accuracy.after" in summed["source"]
    assert summed["err_bias_m"] == pytest.approx(bias, rel=0.02)
    assert summed["err_rand_m"] == pytest.approx(rand, rel=0.02)
    # the input scene has no calibration beside it: -1, and why
    code, out, err = _run(capsys, "rpc", SCENE, "--ccd", "cam2_ccd1", "--out", tmp_path / "lab_RPC.TXT",
                          "--height-range", "0", "500")
    assert code == 0, err
    assert read_rpc(tmp_path / "lab_RPC.TXT").err_bias in (None, -1.0) and "no calibration.json beside" in out
    lab = json.loads((tmp_path / "lab_RPC.TXT.summary.json").read_text())
    assert lab["rpc_errors"]["err_bias_m"] is None and "-1 (unknown)" in lab["rpc_errors"]["source"]
    assert lab["rpcs"][0]["err_bias_m"] is None


def test_rpc_errors_of_a_relative_manifest_are_its_calibrations(demo_folder):
    """``gcpcal relative``'s folder has no calibration.json: the one its relative.json names gives the figures."""
    from calibrate.actions.rpc import calibration_errors

    rel = calibration_errors(demo_folder / "relative" / "manifest.json")
    cal = calibration_errors(demo_folder / "calibration" / "manifest.json")
    assert rel["source"].startswith("gcpcal relative") and cal["source"].startswith("gcpcal calibrate")
    assert rel["err_bias_m"] == cal["err_bias_m"] and rel["err_rand_m"] == cal["err_rand_m"] is not None
