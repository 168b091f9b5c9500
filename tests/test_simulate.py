"""Scene simulator: geometric fidelity, determinism, truth tools and configuration errors."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.readers.scene import read_manifest, read_manifest_and_rasters
from sensor_models.simulate.config import SimConfig, config_from_dict, load_config
from sensor_models.simulate.pushbroom_sim import footprint_lonlat, simulate_pushbroom
from sensor_models.simulate.scene import build_models
from sensor_models.simulate.truth import truth_error
from sensor_models.terrain.dem import Dem


def small_config(**radiometry) -> SimConfig:
    cfg = SimConfig()
    cam = replace(cfg.camera, detectors_per_ccd=96, overlap_detectors=8, bands=("B1", "B2"),
                  reference_band="B2", band_offsets_px=(-3.0, 3.0))
    rad = replace(cfg.radiometry, band_gain=(0.9, 1.0), band_offset_dn=(50.0, 40.0), band_gamma=(1.0, 1.0), **radiometry)
    return replace(cfg, scene=replace(cfg.scene, n_rows=192), camera=cam, radiometry=rad).validate()


def write_reference(tmp_path, cfg, *, blobs=False, seed=0):
    """DOM (15 m UTM, uint16) and DEM (30 m, ellipsoidal, tagged) around the TRUE footprint.

    With ``blobs``, the DOM is a flat background with Gaussian spots (sigma 60 m) on a grid;
    returns their UTM centres too.
    """
    model = build_models(cfg).true_model
    lon, lat = footprint_lonlat(model, (0.0, 2000.0))
    crs = pyproj.CRS.from_epsg(32631)
    x, y = pyproj.Transformer.from_crs(4326, crs, always_xy=True).transform(lon, lat)
    x0, x1 = np.min(x) - 3000, np.max(x) + 3000
    y0, y1 = np.min(y) - 3000, np.max(y) + 3000
    nx, ny = int((x1 - x0) / 15), int((y1 - y0) / 15)
    t_dom = Affine(15.0, 0, x0, 0, -15.0, y1)
    yy, xx = np.mgrid[0:ny, 0:nx]
    xm, ym = x0 + (xx + 0.5) * 15.0, y1 - (yy + 0.5) * 15.0
    centres = None
    if blobs:
        gx = np.arange(x0 + 1500, x1 - 1500, 700.0)
        gy = np.arange(y0 + 1500, y1 - 1500, 700.0)
        centres = np.array([(a, b) for a in gx for b in gy])
        dom = np.full((ny, nx), 300.0)
        for cx, cy in centres:
            sl = (slice(max(0, int((y1 - cy) / 15) - 20), int((y1 - cy) / 15) + 20),
                  slice(max(0, int((cx - x0) / 15) - 20), int((cx - x0) / 15) + 20))
            dom[sl] += 3000.0 * np.exp(-((xm[sl] - cx) ** 2 + (ym[sl] - cy) ** 2) / (2 * 60.0**2))
    else:
        rng = np.random.default_rng(seed)
        dom = 1500 + 800 * np.sin(xm / 230.0) * np.cos(ym / 170.0) + rng.normal(0, 200, (ny, nx))
    t_dem = Affine(30.0, 0, x0, 0, -30.0, y1)
    dy, dx = np.mgrid[0 : ny // 2, 0 : nx // 2] * 30.0
    dem = 900 + 500 * np.sin(dx / 5000.0) * np.cos(dy / 6000.0)
    p_dom, p_dem = tmp_path / "dom.tif", tmp_path / "dem.tif"
    for p, arr, t, dt in ((p_dom, dom, t_dom, "uint16"), (p_dem, dem, t_dem, "float32")):
        with rasterio.open(p, "w", driver="GTiff", width=arr.shape[1], height=arr.shape[0], count=1,
                           dtype=dt, crs=crs.to_wkt(), transform=t) as ds:
            ds.write(np.clip(arr, 0, 65535).astype(dt) if dt == "uint16" else arr.astype(dt), 1)
            if p is p_dem:
                ds.update_tags(VERTICAL_DATUM="ellipsoid")
    return p_dom, p_dem, centres, crs


def centroid(img, r, c, radius=6):
    r0, c0 = int(r) - radius, int(c) - radius
    win = img[r0 : r0 + 2 * radius + 1, c0 : c0 + 2 * radius + 1].astype(np.float64)
    win = np.clip(win - np.median(img), 0, None)
    rr, cc = np.mgrid[0 : win.shape[0], 0 : win.shape[1]]
    w = win.sum()
    return r0 + 0.5 + (rr * win).sum() / w, c0 + 0.5 + (cc * win).sum() / w


def test_point_features_land_where_the_true_model_says(tmp_path):
    cfg = small_config(snr=1e5, prnu=0.0, seasonal_change=0.0)
    p_dom, p_dem, centres, crs = write_reference(tmp_path, cfg, blobs=True)
    out = tmp_path / "scene"
    simulate_pushbroom(out, config=cfg, dom=p_dom, dem=p_dem)
    truth = read_manifest(out / "truth_manifest.json")
    dem = Dem.open(p_dem)
    lon, lat = pyproj.Transformer.from_crs(crs, 4326, always_xy=True).transform(centres[:, 0], centres[:, 1])
    h = dem.height_m(lon, lat)
    errors = []
    for band in ("B1", "B2"):
        with rasterio.open(out / f"{band}.tif") as ds:
            img = ds.read(1)
        for i, ccd in enumerate(truth.band_ccds(band)):
            row, col = truth.ground_to_image(lon, lat, h, band=band, array=i)
            inside = ((row > 8) & (row < truth.n_rows - 8) & (col > ccd.first_col + 8)
                      & (col < ccd.first_col + ccd.n_detectors - 8))
            for r, c in zip(row[inside], col[inside]):
                rc, cc = centroid(img, r, c)
                errors.append((rc - r, cc - c, i))
    e = np.array(errors)
    assert len({int(k) for k in e[:, 2]}) == 4  # every CCD has spots
    assert e.shape[0] > 60
    rms = np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))
    worst = np.abs(e[:, :2]).max()
    print(f"fidelity: {e.shape[0]} spots, rms {rms:.4f} px, max {worst:.4f} px")
    assert rms < 0.02 and worst < 0.05


def test_same_seed_same_bytes_and_workers_do_not_matter(tmp_path):
    cfg = small_config()
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    a, b = tmp_path / "a", tmp_path / "b"
    simulate_pushbroom(a, config=cfg, dom=p_dom, dem=p_dem, workers=2, block_lines=64)
    simulate_pushbroom(b, config=cfg, dom=p_dom, dem=p_dem, workers=1, block_lines=64)
    names = ["B1.tif", "B2.tif", "manifest.json", "truth_manifest.json"]
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    ta, tb = (json.loads((d / "truth.json").read_text()) for d in (a, b))
    ta["reference"] = tb["reference"] = None  # absolute paths of the inputs
    assert ta == tb
    c = tmp_path / "c"
    simulate_pushbroom(c, config=cfg.with_seed(7), dom=p_dom, dem=p_dem)
    assert (a / "B1.tif").read_bytes() != (c / "B1.tif").read_bytes()
    # nothing left behind but the outputs
    assert not [p for p in a.iterdir() if p.name.startswith(".")]


def test_scene_content_radiometry_and_manifest(tmp_path):
    cfg = small_config(snr=50.0)
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    out = tmp_path / "s"
    summary = simulate_pushbroom(out, config=cfg, dom=p_dom, dem=p_dem)
    lab, rasters = read_manifest_and_rasters(out / "manifest.json")
    assert lab.image_shape == (192, 4 * 96)
    assert set(rasters) == {"B1", "B2"}
    with rasterio.open(out / "B2.tif") as ds:
        img = ds.read(1)
        assert ds.dtypes[0] == "uint16" and ds.crs is None
    assert 0 < img.min() and img.max() < 4096 and img.std() > 100
    # the initial (LAB) model is hundreds of pixels off, as configured
    assert 100 < summary["lab_truth_error_px"]["rms"] < 1000


def test_truth_error_of_true_model_is_zero_and_brackets_a_known_shift():
    cfg = small_config()
    models = build_models(cfg)
    same = truth_error(models.true_model, models.true_model, step_px=24)
    assert same["max_px"] < 1e-6
    # a pure roll of one IFOV moves every pixel by about one column
    from sensor_models.models.pushbroom_types import Installation

    t = models.true_model
    inst = t.installation
    ifov = cfg.scene.gsd_m / cfg.scene.altitude_m
    shifted = t.with_parameters(np.r_[inst.roll + ifov, inst.pitch, inst.yaw, t.parameters().values[3:]])
    err = truth_error(t, shifted, step_px=24)
    assert 0.9 < abs(err["mean_col_px"]) < 1.1 and abs(err["mean_row_px"]) < 0.1
    assert isinstance(Installation(), Installation)


def test_clouds_and_their_true_mask(tmp_path):
    cfg = small_config()
    cfg = replace(cfg, clouds=replace(cfg.clouds, cover=0.3))
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    out = tmp_path / "cloudy"
    summary = simulate_pushbroom(out, config=cfg, dom=p_dom, dem=p_dem)
    assert 0.1 < summary["cloud_fraction"] < 0.6
    with rasterio.open(out / "cloud_mask.tif") as m, rasterio.open(out / "B2.tif") as b:
        mask, img = m.read(1).astype(bool), b.read(1)
    assert img[mask].mean() > img[~mask].mean() + 500  # clouds are bright


@pytest.mark.parametrize(
    "doc, field",
    [
        ({"scene": {"n_rows": 10}}, "scene.n_rows"),
        ({"scene": {"gsd": 30}}, "scene"),
        ({"colour": 1}, "(root)"),
        ({"camera": {"reference_band": "B9"}}, "camera.reference_band"),
        ({"radiometry": {"snr": -1}}, "radiometry.snr"),
        ({"clouds": {"cover": 1.5}}, "clouds.cover"),
        ({"errors": {"installation_deg": [0, 0]}}, "errors.installation_deg"),
        ({"scene": {"n_rows": "many"}}, "scene.n_rows"),
    ],
)
def test_bad_configuration_names_the_field(tmp_path, doc, field):
    p = tmp_path / "cfg.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(InputError) as exc:
        load_config(p)
    msg = str(exc.value)
    assert str(p) in msg and f"field '{field}'" in msg and "\n" not in msg


def test_config_round_trip():
    cfg = small_config()
    assert config_from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


def test_reference_not_covering_the_footprint_is_an_error(tmp_path):
    cfg = small_config()
    p_dom, p_dem, _, _ = write_reference(tmp_path, cfg)
    far = replace(cfg, scene=replace(cfg.scene, center_lon_deg=cfg.scene.center_lon_deg + 1.0))
    with pytest.raises(InputError, match="does not cover the scene footprint"):
        simulate_pushbroom(tmp_path / "far", config=far, dom=p_dom, dem=p_dem)
    assert not any((tmp_path / "far").iterdir())  # no partial output


def test_thermal_drift_of_the_installation_grows_with_time():
    """A drift of the installation (folded into the true attitude) moves late lines, not early ones."""
    cfg = small_config()
    warm = replace(cfg, errors=replace(cfg.errors, thermal_drift_arcsec_s=(0.0, 2.0, 0.0)))
    a, b = build_models(cfg).true_model, build_models(warm).true_model
    ifov_arcsec = cfg.scene.gsd_m / cfg.scene.altitude_m * 206264.8
    rows = np.array([0.5, a.n_rows - 0.5])
    col = np.full(2, 96 + 48.5)  # middle of the second CCD (away from the overlaps)
    lon, lat, h = a.image_to_ground(rows, col, height=500.0, band="B2", array=1)
    r, c = b.ground_to_image(lon, lat, h, band="B2", array=1)
    shift = np.hypot(r - rows, c - col)
    seconds = (a.n_rows - 1) * a.line_timing.line_period_s
    expected = 2.0 * seconds / ifov_arcsec  # pitch drift in pixels at the last line
    assert shift[0] < 0.02
    assert 0.8 * expected < shift[1] < 1.2 * expected


def test_acquisition_seed_changes_the_pass_not_the_camera():
    cfg = small_config()
    other = replace(cfg, scene=replace(cfg.scene, acquisition_seed=99))
    a, b = build_models(cfg), build_models(other)
    assert a.truth["true_camera"] == b.truth["true_camera"]  # same sensor
    assert a.truth["jitter_phase_rad"] != b.truth["jitter_phase_rad"]  # another pass
    qa = a.lab_model.attitude.quaternions_xyzw
    qb = b.lab_model.attitude.quaternions_xyzw
    assert not np.allclose(qa, qb)  # different measured-attitude noise


def test_procedural_reference_is_counted_in_parts(tmp_path):
    """Without a DOM, the procedural reference's phases and strips show in the progress count.

    ``done`` never goes back, the total grows once by the parts announced and ends reached.
    """
    from sensor_models.simulate.render_io import SETUP_STEPS

    calls = []
    cfg = small_config()
    simulate_pushbroom(tmp_path / "out", config=cfg, block_lines=64,
                       progress=lambda done, total: calls.append((done, total)))
    done = [d for d, _ in calls]
    totals = sorted({t for _, t in calls})
    n_blocks = -(-cfg.scene.n_rows // 64)
    assert done == sorted(done), calls
    assert calls[-1][0] == calls[-1][1], calls
    assert totals[-1] > SETUP_STEPS + n_blocks + 4, totals  # phases and DOM strips counted
    assert len(calls) >= totals[-1] - SETUP_STEPS - n_blocks, calls
