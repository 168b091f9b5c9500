"""Orthorectification to Cloud-Optimized GeoTIFFs (sensor_models.imaging.ortho, ``gcpcal ortho``).

Geometry: the node-grid positions against exact inverse localization; resampling convention on
a linear ramp; COG layout, atomic output; the CLI; and the acceptance test on the HY-1C-like
fixture: the orthoimage made with the demo's calibrated model agrees with the reference DOM to
a small fraction of a pixel, the LAB model's does not, and the GCP GeoTIFF of the demo warps
with GDAL onto the DOM within a few pixels.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.warp import Resampling, calculate_default_transform, reproject

from calibrate.cli import main
from gcpmatch.phase import phase_correlate
from sensor_models import open_model
from sensor_models.errors import InputError
from sensor_models.imaging.ortho import orthorectify, orthorectify_to_file
from sensor_models.imaging.ortho_geometry import OrthoGeometry
from sensor_models.imaging.ortho_grid import ortho_grid, utm_crs
from sensor_models.terrain.dem import Dem

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "fixtures" / "hy1c_czi"
LAB = FIX / "manifest.json"
TRUTH = FIX / "truth_manifest.json"
DEM = FIX / "reference" / "dem.tif"
DOM = FIX / "reference" / "dom.tif"
B2 = FIX / "B2.tif"


@pytest.fixture(scope="module")
def dem():
    return Dem.open(DEM)


@pytest.fixture(scope="module")
def lab():
    return open_model(LAB)


@pytest.fixture(scope="module")
def truth():
    return open_model(TRUTH)


def _pixel_lonlat(geometry, rows, cols):
    t = geometry.grid.transform
    return geometry._lonlat(t.a * cols + t.b * rows + t.c, t.d * cols + t.e * rows + t.f)


def _sample(geometry, n, seed, *, indices=False):
    """Random valid output pixels of the whole grid: lon, lat, h, ccd, image row and col
    (and the output pixel indices with ``indices=True``)."""
    g = geometry.block(0, geometry.grid.shape[0], 0, geometry.grid.shape[1])
    idx = np.random.default_rng(seed).choice(np.flatnonzero(g.valid), n, replace=False)
    j, i = np.unravel_index(idx, g.valid.shape)
    lon, lat = _pixel_lonlat(geometry, j + 0.5, i + 0.5)
    out = (lon, lat, g.h_m.flat[idx], g.ccd.flat[idx], g.row.flat[idx], g.col.flat[idx])
    return out + (j, i) if indices else out


# ---------------------------------------------------------------- geometry
def test_blocks_together_equal_blocks_alone(lab, dem, monkeypatch):
    """``OrthoGeometry.blocks`` solves the blocks' inverse localizations in one call per CCD: the
    same arrays, to the bit, as each block alone, in fewer model calls (and a block wholly off
    the DEM or the image among them changes nothing)."""
    import sensor_models.models.pushbroom_inverse as inverse

    grid = ortho_grid(lab, dem, band="B2")
    geometry = OrthoGeometry(lab, dem, grid, band="B2")
    n_rows, n_cols = grid.shape
    step = max(32, min(n_rows, n_cols) // 3)
    windows = [(a, min(a + step, n_rows), b, min(b + step, n_cols))
               for a in range(0, n_rows, step) for b in range(0, n_cols, step)]
    steps = []
    solve = inverse.solve_ccd

    def counted(*args, **kwargs):
        steps.append(1)
        return solve(*args, **kwargs)

    monkeypatch.setattr(inverse, "solve_ccd", counted)
    alone = [geometry.block(*w) for w in windows]
    n_alone, steps[:] = len(steps), []
    together = geometry.blocks(windows)
    assert len(steps) < n_alone
    for a, b in zip(alone, together):
        for name in ("row", "col", "h_m", "ccd", "valid"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.mark.parametrize("which", ["lab", "truth"])
def test_node_grid_matches_exact_inverse_localization(which, request, dem):
    model = request.getfixturevalue(which)
    grid = ortho_grid(model, dem, band="B2")
    geometry = OrthoGeometry(model, dem, grid, band="B2")
    lon, lat, h, ccd, row, col = _sample(geometry, 3000, seed=1)
    # the per-pixel height is the DEM's bilinear height
    np.testing.assert_allclose(h, dem.height_m(lon, lat), atol=1e-6)
    r, c = model.ground_to_image(lon, lat, h, band="B2", array=ccd)
    err = np.hypot(r - row, c - col)
    # interpolation, not a copy of the exact values; and far below a hundredth of a pixel
    assert 1e-7 < np.max(err) <= 0.01
    assert np.sqrt(np.mean(err**2)) < 0.002
    # CCD choice: the exact model's own rule agrees except within a pixel of a seam
    r_free, c_free = model.ground_to_image(lon, lat, h, band="B2")
    differ = np.hypot(r_free - row, c_free - col) > 0.01
    assert np.count_nonzero(differ) <= 0.01 * lon.size
    seams = np.array([ccd.first_col for ccd in model.band_ccds("B2")][1:], dtype=float)
    if differ.any():
        assert np.min(np.abs(col[differ, None] - seams[None, :]), axis=1).max() < 1.0


def test_coarser_nodes_larger_error(truth, dem):
    grid = ortho_grid(truth, dem, band="B2")
    errors = []
    for step in (8, 32):
        geometry = OrthoGeometry(truth, dem, grid, band="B2", node_step_px=step)
        lon, lat, h, ccd, row, col = _sample(geometry, 1500, seed=2)
        r, c = truth.ground_to_image(lon, lat, h, band="B2", array=ccd)
        errors.append(np.max(np.hypot(r - row, c - col)))
    assert 3.0 * errors[0] < errors[1] < 0.05


def test_model_without_ccds_uses_one_field(truth, dem):
    view = truth.detector_view("B2", 1)  # a generic SensorModel: columns 0..192 of one CCD
    grid = ortho_grid(view, dem)
    geometry = OrthoGeometry(view, dem, grid)
    assert len(geometry.solvers) == 1
    lon, lat, h, ccd, row, col = _sample(geometry, 1000, seed=3)
    r, c = view.ground_to_image(lon, lat, h)
    assert np.max(np.hypot(r - row, c - col)) <= 0.01
    assert np.all((col >= 0) & (col <= 192) & (ccd == 0))


def test_grid_defaults(lab, dem):
    grid = ortho_grid(lab, dem)
    assert grid.crs.to_epsg() == 32631 == utm_crs(5.4, 44.4).to_epsg()
    assert utm_crs(-70.0, -33.0).to_epsg() == 32719
    assert grid.transform.a == pytest.approx(30.3) and grid.transform.e == pytest.approx(-30.3)
    # corners on multiples of the resolution; the box holds the whole footprint (~23 x 15.5 km)
    assert grid.transform.c / 30.3 == pytest.approx(round(grid.transform.c / 30.3), abs=1e-6)
    assert 760 < grid.shape[1] < 1000 and 512 < grid.shape[0] < 800
    fine = ortho_grid(lab, dem, resolution_m=10.0, crs="EPSG:32631")
    assert fine.transform.a == 10.0 and abs(fine.shape[1] - 3.03 * grid.shape[1]) < 6
    with pytest.raises(InputError, match="geographic"):
        ortho_grid(lab, dem, crs="EPSG:4326")
    with pytest.raises(InputError, match="positive"):
        ortho_grid(lab, dem, resolution_m=-5)


# ---------------------------------------------------------------- pixels and file
@pytest.mark.parametrize("resampling", ["bilinear", "cubic"])
def test_pixel_convention_on_a_ramp(resampling, tmp_path, truth, dem):
    """Pixel (i, j) holds 1000 + 3 i + 2 j: bilinear and cubic interpolation reproduce the ramp,
    1000 + 3 (row - 0.5) + 2 (col - 0.5) at continuous image coordinates (row, col)."""
    n_rows, n_cols = truth.image_shape
    ii, jj = np.meshgrid(np.arange(n_rows), np.arange(n_cols), indexing="ij")
    ramp = (1000.0 + 3.0 * ii + 2.0 * jj).astype(np.float32)
    out = tmp_path / "ramp.tif"
    summary = orthorectify_to_file(truth, ramp, dem, out, band="B2", nodata=-9999.0, block=512, resampling=resampling)
    assert summary["dtype"] == "float32" and summary["geometry_check_max_px"] < 0.01
    with rasterio.open(out) as ds:
        values = ds.read(1)
        transform = ds.transform
    grid = ortho_grid(truth, dem, band="B2")
    geometry = OrthoGeometry(truth, dem, grid, band="B2")
    assert transform.almost_equals(grid.transform)
    lon, lat, h, ccd, row, col, j, i = _sample(geometry, 2000, seed=4, indices=True)
    r, c = truth.ground_to_image(lon, lat, h, band="B2", array=ccd)
    inside = (r > 2) & (r < n_rows - 2) & (c > 2) & (c < n_cols - 2)
    got = values[j, i]
    expected = 1000.0 + 3.0 * (r - 0.5) + 2.0 * (c - 0.5)
    err = (got - expected)[inside]
    if resampling == "bilinear":
        # exact on a ramp; OpenCV quantizes positions to 1/32 px: |error| <= (3 + 2) / 64
        assert np.max(np.abs(err)) < 5.0 / 64 + 1e-3
    else:
        # OpenCV's cubic (Keys, a = -0.75) reproduces a ramp only to a periodic, zero-mean error
        # (measured 0.24 of the 5 DN/px slope sum, i.e. < 0.05 px; mean 0)
        assert 5.0 / 64 < np.max(np.abs(err)) < 0.35 and abs(np.mean(err)) < 0.01, (np.max(np.abs(err)), np.mean(err))
    assert np.all(values[values != -9999.0] > 900)


def test_cog_layout_and_block_independence(tmp_path, truth, dem):
    a, b = tmp_path / "a.tif", tmp_path / "b.tif"
    sa = orthorectify_to_file(truth, B2, dem, a, block=1024)
    sb = orthorectify_to_file(truth, B2, dem, b, block=128, resampling="bilinear")
    with rasterio.open(a) as ds:
        assert ds.driver == "GTiff" and ds.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert ds.tags(ns="IMAGE_STRUCTURE")["COMPRESSION"] == "DEFLATE"
        assert ds.profile["tiled"] and ds.overviews(1) == [2]
        assert ds.crs.to_epsg() == 32631 and ds.nodata == 0 and ds.dtypes[0] == "uint16"
        assert ds.descriptions[0] == "B2"
        va = ds.read(1)
    with rasterio.open(b) as ds:
        vb = ds.read(1)
    # blocks of 128 and 1024 pixels give the same image: node grids anchored on other blocks move
    # positions by ~1e-4 px, which flips a few roundings to integers (measured 0.5 % of pixels)
    assert np.count_nonzero((va == 0) != (vb == 0)) <= 1e-4 * va.size
    both = (va > 0) & (vb > 0)
    assert np.count_nonzero(va != vb) < 0.02 * va.size
    assert np.max(np.abs(va.astype(int) - vb.astype(int))[both]) <= 1
    assert 0.6 < sa["valid_fraction"] == pytest.approx(sb["valid_fraction"], rel=1e-3)
    assert sa["geometry_check_points"] >= 200 and sa["geometry_check_max_px"] < 0.01
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != ".gcpcal-outputs.json") == ["a.tif", "b.tif"]  # no temporary left


def test_thread_count_does_not_change_the_output(tmp_path, truth, dem):
    """Blocks computed on 1, 2 or 3 threads (the raster read through one handle per thread, the
    DEM by windows from threads too): the same pixels, check points and summary, bit for bit."""
    from sensor_models.terrain.dem_windows import open_ortho_dem

    coarse, windows = open_ortho_dem(DEM, max_nodes=60_000)
    pixels, summaries = [], []
    for threads in (1, 2, 3):
        out = tmp_path / f"t{threads}.tif"
        summary = orthorectify_to_file(truth, B2, coarse, out, block=128, threads=threads, dem_windows=windows)
        assert summary["threads"] == threads
        with rasterio.open(out) as ds:
            pixels.append(ds.read(1))
        summaries.append({k: v for k, v in summary.items() if k not in ("seconds", "cog_seconds", "pixels_per_s",
                                                                        "output", "threads")})
    windows.close()
    assert summaries[0]["valid_fraction"] > 0.6
    for values, summary in zip(pixels[1:], summaries[1:]):
        np.testing.assert_array_equal(values, pixels[0])
        assert summary == summaries[0]
    t = rasterio.open(tmp_path / "t1.tif").transform
    shape = (300, 280)
    memory = [orthorectify(truth, rasterio.open(B2).read(1), dem, t, "EPSG:32631", shape, band="B2", block_rows=64,
                           threads=n) for n in (1, 3)]
    np.testing.assert_array_equal(memory[0], memory[1])
    assert np.isfinite(memory[0]).mean() > 0.5


@pytest.mark.parametrize("threads", [1, 3])
def test_atomic_no_partial_output_threads(tmp_path, truth, dem, threads):
    """An error while blocks run on threads: no output, no temporary, the source closed after the blocks."""
    out = tmp_path / "ortho.tif"
    out.write_bytes(b"previous")

    def fail(done, total):
        if done == 2:
            raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError, match="interrupted"):
        orthorectify_to_file(truth, B2, dem, out, block=128, progress=fail, threads=threads)
    assert out.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir() if p.name != ".gcpcal-outputs.json"] == ["ortho.tif"]


def test_atomic_no_partial_output(tmp_path, truth, dem):
    out = tmp_path / "ortho.tif"
    out.write_bytes(b"previous")

    def fail(done, total):
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError, match="interrupted"):
        orthorectify_to_file(truth, B2, dem, out, block=128, progress=fail)
    assert out.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir() if p.name != ".gcpcal-outputs.json"] == ["ortho.tif"]


def test_bad_inputs(tmp_path, truth, dem):
    with pytest.raises(InputError, match="512 x 768"):
        orthorectify_to_file(truth, np.zeros((10, 10), np.uint16), dem, tmp_path / "x.tif")
    with pytest.raises(InputError, match="resampling"):
        orthorectify_to_file(truth, B2, dem, tmp_path / "x.tif", resampling="lanczos")
    with pytest.raises(InputError, match="not a uint16 value"):
        orthorectify_to_file(truth, B2, dem, tmp_path / "x.tif", nodata=-1)
    with pytest.raises(InputError, match="not found"):
        orthorectify_to_file(truth, tmp_path / "missing.tif", dem, tmp_path / "x.tif")
    far = Dem.from_array(np.full((4, 4), 100.0), (0.01, 0, 20.0, 0, -0.01, 10.0), "EPSG:4326")
    with pytest.raises(InputError, match="no output pixel"):
        orthorectify_to_file(truth, B2, far, tmp_path / "x.tif", crs="EPSG:32631")
    assert not list(tmp_path.iterdir())


def test_a_band_name_is_looked_up_in_the_rasters_given():
    """``image`` as a band name or None: the raster comes from the ``rasters`` passed (a Scene's), not the model."""
    from sensor_models.imaging.ortho_resample import resolve_source
    from sensor_models.readers import open_scene

    scene = open_scene(LAB)
    for image, band, want in (("B3", None, "B3"), (None, "B3", "B3"), (None, None, scene.model.reference_band)):
        source, got = resolve_source(scene.model, image, band, scene.rasters)
        try:
            assert got == want and (source.path, source.index) == scene.raster_of(want)
        finally:
            source.close()
    with pytest.raises(InputError, match="no raster listed for band 'B2'"):
        resolve_source(scene.model, None, "B2")
    with pytest.raises(InputError, match="names band 'B3' but band='B2'"):
        resolve_source(scene.model, "B3", "B2", scene.rasters)


def test_in_memory_orthorectify_agrees_with_file(tmp_path, truth, dem):
    out = tmp_path / "o.tif"
    orthorectify_to_file(truth, B2, dem, out, dtype="float32", nodata=-1.0)
    with rasterio.open(out) as ds:
        on_disk = ds.read(1)
        transform, crs, shape = ds.transform, ds.crs.to_wkt(), ds.shape
    with rasterio.open(B2) as ds:
        image = ds.read(1)
    mem = orthorectify(truth, image, dem, transform, crs, shape, band="B2", block_rows=1024)
    ok = np.isfinite(mem)
    np.testing.assert_array_equal(ok, on_disk != -1.0)
    assert np.max(np.abs(mem[ok] - on_disk[ok])) < 1e-3


# ---------------------------------------------------------------- acceptance on the fixture
@pytest.fixture(scope="module")
def demo(demo_folder):
    return demo_folder


def _dom_on(path):
    """The ortho (NaN = no data) and the DOM averaged onto its grid."""
    with rasterio.open(path) as ds:
        ortho = np.ma.filled(ds.read(1, masked=True).astype(np.float32), np.nan)
        transform, crs = ds.transform, ds.crs
    dom = np.full(ortho.shape, np.nan, np.float32)
    with rasterio.open(DOM) as src:
        reproject(rasterio.band(src, 1), dom, dst_transform=transform, dst_crs=crs, resampling=Resampling.average,
                  dst_nodata=np.nan)
    return ortho, dom, transform, crs


def _shifts(image, dom, window=64, step=32):
    """Phase-correlation shifts (px) of ``image`` against the DOM over every full window."""
    refs, movs = [], []
    for r in range(0, image.shape[0] - window + 1, step):
        for c in range(0, image.shape[1] - window + 1, step):
            a, b = image[r:r + window, c:c + window], dom[r:r + window, c:c + window]
            if np.isfinite(a).all() and np.isfinite(b).all():
                refs.append(b)
                movs.append(a)
    m = phase_correlate(np.array(refs), np.array(movs))
    return m.shift_px[m.valid], len(refs)


@pytest.mark.slow  # the demo's calibration: 6 s on an idle machine, 25 s on a busy one
def test_calibrated_ortho_matches_dom(demo, tmp_path, capsys):
    out = tmp_path / "b2_ortho.tif"
    code = main(["ortho", str(LAB), "--calibration", str(demo / "relative"), "--dem", str(DEM), "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    summary = json.loads(captured.out)
    # stdout carries the written summary less its provenance block (docs/cli.md, "--json")
    written = json.loads(out.with_suffix(".summary.json").read_text())
    assert written.pop("provenance")["inputs"] and "provenance" not in summary
    assert summary == written
    assert summary["calibration"] == str(demo / "relative" / "manifest.json") and summary["band"] == "B2"
    assert summary["image"] == str(B2) and summary["geometry_check_max_px"] < 0.01
    ortho, dom, _, _ = _dom_on(out)
    shifts, windows = _shifts(ortho, dom)
    assert windows > 200 and len(shifts) > 0.9 * windows  # the whole scene, not a corner
    rms = float(np.sqrt(np.mean(np.sum(shifts**2, axis=1))))
    # measured 0.075 px (the calibrated model is 0.09 px RMS off the TRUE model)
    assert 0.02 < rms <= 0.2
    assert np.all(np.abs(np.median(shifts, axis=0)) < 0.05)

    # control: the TRUE model's orthoimage shows only the measurement's own noise (0.02 px)
    t_out = tmp_path / "truth.tif"
    orthorectify_to_file(open_model(TRUTH), B2, Dem.open(DEM), t_out)
    t_shifts, _ = _shifts(*_dom_on(t_out)[:2])
    t_rms = float(np.sqrt(np.mean(np.sum(t_shifts**2, axis=1))))
    # (with --attitude auto the calibrated model is 0.03 px off the truth: close to that noise)
    assert 0.002 < t_rms < 0.05 and t_rms < rms

    # the LAB model (260 px off) gives an orthoimage that does not correlate with the DOM
    lab_out = tmp_path / "lab.tif"
    code = main(["ortho", str(LAB), "--dem", str(DEM), "--out", str(lab_out), "--json"])
    capsys.readouterr()
    assert code == 0
    lab_ortho, lab_dom, _, _ = _dom_on(lab_out)
    lab_shifts, lab_windows = _shifts(lab_ortho, lab_dom)
    assert lab_windows > 100
    close = np.hypot(*lab_shifts.T) < 2.0 if len(lab_shifts) else np.zeros(0, bool)
    assert np.count_nonzero(close) < 0.05 * lab_windows


@pytest.mark.slow  # shares the demo's calibration
def test_gcp_geotiff_warps_with_gdal(demo, tmp_path):
    from gcpmatch.gcp_files import read_gcps
    from gcpmatch.gcp_geotiff import write_gcps_geotiff

    table = read_gcps(demo / "gcps.csv")
    table = table.select(table.band == "B2")
    path = write_gcps_geotiff(table, tmp_path / "gcps.tif", image_shape=(512, 768), source_raster=B2)
    dst_crs = "EPSG:32631"
    with rasterio.open(path) as src:
        gcps, gcp_crs = src.gcps
        # the points of kind gcp become GDAL GCPs; check points stay in the CSV metadata only
        assert len(gcps) == np.count_nonzero(table.kind == "gcp") > 500 and gcp_crs.to_epsg() == 4326
        transform, width, height = calculate_default_transform(gcp_crs, dst_crs, src.width, src.height, gcps=gcps)
        assert 20.0 < transform.a < 40.0 and 600 < width < 1100 and 450 < height < 900
        ortho = tmp_path / "calibrated.tif"
        orthorectify_to_file(open_model(demo / "relative" / "manifest.json"), B2, Dem.open(DEM), ortho)
        _, dom, grid_transform, grid_crs = _dom_on(ortho)
        rms = {}
        for method, options in (("polynomial", {}), ("tps", {"SRC_METHOD": "GCP_TPS"})):
            warped = np.full(dom.shape, np.nan, np.float32)
            reproject(rasterio.band(src, 1), warped, gcps=gcps, src_crs=gcp_crs, src_nodata=0, dst_transform=grid_transform,
                      dst_crs=grid_crs, resampling=Resampling.bilinear, dst_nodata=np.nan, **options)
            shifts, windows = _shifts(warped, dom)
            assert len(shifts) > 0.8 * windows > 150
            rms[method] = float(np.sqrt(np.mean(np.sum(shifts**2, axis=1))))
    # GDAL's default GCP polynomial ignores the relief (1.5 km): measured 3.9 px RMS (max 9 px);
    # a thin-plate spline through the 983 GCPs follows it: 0.54 px RMS
    assert 1.0 < rms["polynomial"] < 6.0
    assert 0.1 < rms["tps"] < 1.0


# ---------------------------------------------------------------- CLI errors
def test_missing_dem_is_a_usage_error_marked_in_the_help(tmp_path, capsys):
    """--dem is required (the help says so) and a missing one is a usage error (exit 2)."""
    assert main(["ortho", str(LAB), "--out", str(tmp_path / "o.tif")]) == 2
    assert "Missing option '--dem'" in capsys.readouterr().err
    assert main(["ortho", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "--dem PATH" in out and "[required]" in out.split("--dem PATH", 1)[1].split("--dem-datum", 1)[0]
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, message", [
    (["--dem", str(DEM), "--out", "{tmp}/o.tif", "--band", "B9"], "unknown band 'B9'"),
    (["--dem", str(DEM), "--out", "{tmp}/o.tif", "--crs", "EPSG:4326"], "geographic"),
    (["--dem", str(DEM), "--out", "{tmp}/o.tif", "--crs", "EPSG:99999999"], "unknown CRS"),
    (["--dem", str(DEM), "--out", "{tmp}/o.tif", "--image", str(DOM)], "1441 x 1862 px"),
    (["--dem", str(DEM), "--out", "{tmp}/o.tif", "--calibration", "{tmp}"], "no manifest.json"),
    (["--dem", str(DEM), "--out", "{tmp}/o.png"], "give a .tif name"),
])
def test_cli_errors_one_line(args, message, tmp_path, capsys):
    code = main(["ortho", str(LAB)] + [a.format(tmp=tmp_path) for a in args])
    err = capsys.readouterr().err
    assert code == 1
    assert message in err and err.startswith("gcpcal: error:") and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())
