"""The fast paths of the matcher against the slow ones they replace, with accuracy bounds.

* The adaptive DEM intersection (:mod:`sensor_models.terrain.intersect`: coarse-grid start, one
  chord step everywhere, Newton steps only where the convergence mask says so) against the fixed
  four-step solver, on the embedded fixture (``fixtures/hy1c_czi``, heights 0..1500 m).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sensor_models.terrain.intersect import intersect_dem_fixed
from sensor_models.imaging.locate import HEIGHT_TOLERANCE_M, _pixel_layers, dem_planes, locate_block
from sensor_models.maps.grid import MapGrid, MapProjector
from sensor_models.terrain.intersect import intersect_dem_adaptive
from sensor_models.maps.raster import MapImage
from sensor_models.readers import open_model, open_scene
from sensor_models.terrain.dem import Dem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "hy1c_czi"
BAND = "B2"


@pytest.fixture(scope="module")
def scene():
    model = open_model(FIXTURE / "truth_manifest.json")
    dem = Dem.open(FIXTURE / "reference" / "dem.tif")
    dom = MapImage.open(FIXTURE / "reference" / "dom.tif")
    dem_planes(dem)
    return model, dem, dom


@pytest.fixture(scope="module")
def layers(scene):
    """Straight-ray layers of CCD 2's first 400 lines in the DEM grid, and their lower height."""
    model, dem, _ = scene
    look = model.detector_arrays(BAND)[2]
    h_lo, h_hi = dem.height_range_m[0] - 50.0, dem.height_range_m[1] + 50.0
    lay = _pixel_layers(model, {"band": BAND, "array": 2}, [MapProjector(MapGrid.of_dem(dem))], 0, 400,
                        look.first_col, look.first_col + look.n_detectors, 16.0, h_lo, h_hi)[0]
    return lay, np.float32(h_lo)


def test_adaptive_locate_block_agrees_with_the_fixed_solver_everywhere(scene):
    """Every pixel of the fixture's four CCDs (512 x 768): same NaN pixels, heights within
    1 cm RMS and 5 cm at worst (the fixed solver's own error against the exact model is up to
    9 mm: tests/test_locate.py), DOM positions within 2e-3 DOM px."""
    model, dem, dom = scene
    n_rows = model.image_shape[0]
    d_h, d_uv, n = [], [], 0
    for ccd in range(len(model.detector_arrays(BAND))):
        a = locate_block(model, dem, [dom.grid], band=BAND, ccd=ccd, row0=0, row1=n_rows)
        b = locate_block(model, dem, [dom.grid], band=BAND, ccd=ccd, row0=0, row1=n_rows,
                         tolerance_m=HEIGHT_TOLERANCE_M)
        assert np.array_equal(np.isnan(a.h_m), np.isnan(b.h_m))
        d_h.append((a.h_m - b.h_m).ravel())
        d_uv.append(np.hypot(a.uv[0][0] - b.uv[0][0], a.uv[0][1] - b.uv[0][1]).ravel())
        n += a.h_m.size
    d_h, d_uv = np.concatenate(d_h), np.concatenate(d_uv)
    ok = np.isfinite(d_h)
    assert n == n_rows * 768 and ok.mean() > 0.8
    assert np.sqrt(np.mean(d_h[ok] ** 2)) < 0.01 and np.abs(d_h[ok]).max() < 0.05
    assert d_uv[ok].max() < 2e-3


def test_convergence_mask_refines_the_pixels_that_need_it(layers, scene):
    """Against a converged solution (12 fixed steps): without the refinement steps (one chord
    step from the coarse start) heights are off by more than 1 cm somewhere; with the mask's
    Newton steps every pixel is within 1 cm. A start the coarse grid cannot give (coarse step 1:
    mid-height everywhere) converges through the mask too."""
    _, dem, _ = scene
    lay, h_lo = layers
    exact = intersect_dem_fixed(dem, *lay, h_lo, 12)[0]
    ok = np.isfinite(exact)
    assert ok.mean() > 0.9
    rough = intersect_dem_adaptive(dem, *lay, h_lo, chord_steps=1, max_refine_steps=0)[0]
    assert np.nanmax(np.abs(rough - exact)) > 0.01
    for kw in ({}, {"coarse_step": 1, "max_refine_steps": 8}):
        h = intersect_dem_adaptive(dem, *lay, h_lo, tolerance_m=HEIGHT_TOLERANCE_M, **kw)[0]
        assert np.array_equal(np.isnan(h), ~ok)
        assert np.abs(h[ok] - exact[ok]).max() < 0.01


def test_adaptive_intersection_rejects_a_tolerance_of_zero(layers, scene):
    _, dem, _ = scene
    lay, h_lo = layers
    with pytest.raises(ValueError, match="tolerance_m"):
        intersect_dem_adaptive(dem, *lay, h_lo, tolerance_m=0.0)


# ---------------------------------------------------------------- reference chips on steep relief


@pytest.fixture(scope="module")
def steep_scene(tmp_path_factory):
    """The fixture's LAB model rolled by 20 degrees over a steep synthetic DEM (GeoTIFF).

    Rolling the camera makes the view oblique (tan z ~ 0.36: a metre of height moves the
    ground point by 0.36 m, 0.024 DOM px), so the height the intersection stops at matters.
    The DEM (30 m, UTM 31N, ellipsoidal heights 200..2200 m) has triangular ridges: 62 degree
    flanks, sharp crests and valleys (breaks of slope), plus 5 m noise; no flank is steeper
    than the rays, so no terrain hides another (the first crossing is the only one).
    """
    import json

    import pyproj
    import rasterio
    from affine import Affine

    folder = tmp_path_factory.mktemp("steep")
    manifest = json.loads((FIXTURE / "manifest.json").read_text())
    manifest["installation"]["roll_rad"] = 0.35
    for raster in manifest["image"]["rasters"].values():
        raster["path"] = str((FIXTURE / raster["path"]).resolve())
    (folder / "manifest.json").write_text(json.dumps(manifest))
    model = open_model(folder / "manifest.json")
    n_rows, n_cols = model.image_shape
    rr, cc = np.meshgrid([0.5, n_rows - 0.5], [0.5, n_cols - 0.5], indexing="ij")
    to_utm = pyproj.Transformer.from_crs(4326, 32631, always_xy=True)
    xy = [to_utm.transform(*model.image_to_ground(rr.ravel(), cc.ravel(), height=h)[:2]) for h in (0.0, 3000.0)]
    x0, x1 = min(min(p[0]) for p in xy) - 3000.0, max(max(p[0]) for p in xy) + 3000.0
    y0, y1 = min(min(p[1]) for p in xy) - 3000.0, max(max(p[1]) for p in xy) + 3000.0
    res = 30.0
    width, height = int((x1 - x0) / res), int((y1 - y0) / res)
    x, y = np.meshgrid(x0 + res * (np.arange(width) + 0.5), y1 - res * (np.arange(height) + 0.5))

    def triangle(s, period):
        return np.abs((s / period) % 1.0 - 0.5) * 2.0

    z = 200.0 + 1400.0 * triangle(x + 0.3 * y, 3000.0) + 600.0 * triangle(y, 2100.0)
    z += np.random.default_rng(3).normal(0.0, 5.0, z.shape)
    with rasterio.open(folder / "dem.tif", "w", driver="GTiff", width=width, height=height, count=1,
                       dtype="float32", crs=pyproj.CRS.from_epsg(32631).to_wkt(),
                       transform=Affine(res, 0.0, x0, 0.0, -res, y1)) as ds:
        ds.write(z.astype(np.float32), 1)
    dem = Dem.open(folder / "dem.tif", vertical_datum="ellipsoid")
    dem_planes(dem)
    t = dem.transform
    grid = MapGrid(Affine(15.0, 0.0, t.c, 0.0, -15.0, t.f), dem.crs, (2 * dem.shape[0], 2 * dem.shape[1]))
    return model, dem, grid


def _chip_positions(model, dem, grid, **kw):
    """DOM node indices of every pixel of B2 (all CCDs, one block each), stacked: (n, 2)."""
    out = []
    for ccd in range(len(model.detector_arrays(BAND))):
        pg = locate_block(model, dem, [grid], band=BAND, ccd=ccd, row0=0, row1=model.image_shape[0], **kw)
        out.append(np.stack([pg.uv[0][0].ravel(), pg.uv[0][1].ravel()], axis=-1))
    return np.concatenate(out)


def test_chip_settings_agree_with_the_per_pixel_path_on_steep_oblique_relief(steep_scene, monkeypatch):
    """The chips' settings (stop at 1e-3 DOM px of position, nodes every 32 columns) against
    the per-pixel path they replace (1 mm height tolerance, 16-column nodes), every pixel of
    the rolled scene (393 216): within 0.01 DOM px at worst and 5e-4 DOM px RMS, same NaN
    pixels. Measured: 1.3e-3 px at worst, 1.4e-4 RMS.

    Bracketed: with the convergence mask's Newton steps disabled (two chord steps from the
    coarse start only) pixels at breaks of slope land 3.9 px off (bound: > 0.1); stopping at
    0.1 DOM px of position instead of 1e-3 leaves 0.09 px (> 0.01); nodes every 256 columns
    (one node interval per CCD) 1.3e-3 px RMS (> 5e-4).
    """
    from gcpmatch.reference import NODE_STEP_COLS, POSITION_TOLERANCE_DOM_PX

    import sensor_models.imaging.locate as locate

    model, dem, grid = steep_scene
    chips = {"tolerance_m": HEIGHT_TOLERANCE_M, "position_tolerance_m": POSITION_TOLERANCE_DOM_PX * 15.0,
             "node_step_cols": NODE_STEP_COLS}
    reference = _chip_positions(model, dem, grid, tolerance_m=HEIGHT_TOLERANCE_M)
    ok = np.isfinite(reference).all(axis=1)
    assert reference.shape[0] == 512 * 768 and ok.mean() > 0.99

    def errors(**kw):
        uv = _chip_positions(model, dem, grid, **kw)
        assert np.array_equal(np.isfinite(uv).all(axis=1), ok)
        e = np.hypot(*(uv[ok] - reference[ok]).T)
        return float(e.max()), float(np.sqrt(np.mean(e**2)))

    worst, rms = errors(**chips)
    assert 1e-6 < rms < 5e-4 and worst < 0.01
    assert errors(**{**chips, "position_tolerance_m": 0.1 * 15.0})[0] > 0.01
    assert errors(**{**chips, "node_step_cols": 256})[1] > 5e-4
    monkeypatch.setattr(locate, "MAX_REFINE_STEPS", 0)
    assert errors(**chips)[0] > 0.1


def test_height_tolerance_for_position_follows_the_view_angle(layers, scene):
    """The height tolerance is the position tolerance over the block's largest tan z; a
    vertical ray gets no height bound; a position tolerance of zero, or one without the
    adaptive solver, is refused."""
    from sensor_models.errors import InputError
    from sensor_models.imaging.locate import height_tolerance_for_position

    _, dem, _ = scene
    lay, _ = layers
    tan_z = (np.abs(lay[2]).max() + np.abs(lay[3]).max()) * 30.0  # the fixture's DEM: 30 m nodes
    assert 0.001 < tan_z < 0.1  # near nadir
    assert height_tolerance_for_position(dem, lay[2], lay[3], 0.015) == pytest.approx(0.015 / tan_z, rel=1e-6)
    zero = np.zeros_like(lay[2])
    assert height_tolerance_for_position(dem, zero, zero, 0.015) == np.inf
    with pytest.raises(InputError, match="position_tolerance_m"):
        height_tolerance_for_position(dem, lay[2], lay[3], 0.0)
    model, _, dom = scene
    with pytest.raises(InputError, match="position_tolerance_m"):  # the fixed solver has no tolerance
        locate_block(model, dem, [dom.grid], band=BAND, ccd=0, row0=0, row1=8, position_tolerance_m=0.015)


def test_blocked_row_interpolation_equals_the_catmull_rom_matrix():
    """The small per-interval products give the dense Catmull-Rom matrix product to float32
    rounding, for node steps that divide the block or not, and for rows wider than one product
    (columns split into chunks)."""
    from sensor_models.imaging.locate import _catmull_rom_taps, _interp_rows_blocked, catmull_rom_matrix

    rng = np.random.default_rng(4)
    for n_out, step, n_cols in ((512, 16.0, 300), (100, 7.0, 5000), (1, 16.0, 3)):
        n_nodes = int(np.ceil((n_out - 1) / step)) + 4
        nodes = rng.standard_normal((2, n_nodes, n_cols)).astype(np.float32) * 100.0
        positions = 1.0 + np.arange(n_out) / step
        got = _interp_rows_blocked(nodes, _catmull_rom_taps(positions, n_nodes))
        want = np.einsum("ij,kjl->kil", catmull_rom_matrix(positions, n_nodes), nodes.astype(np.float64))
        assert got.shape == (2, n_out, n_cols) and got[0].flags.c_contiguous
        assert np.abs(got - want).max() < 1e-4 * 100.0
        assert np.abs(got - want).max() > 0.0 or n_out == 1


# ---------------------------------------------------------------- cloud detector on block means


@pytest.fixture(scope="module")
def ccd_pairs(scene):
    """Scene band B2 of each CCD of the fixture (a real GeoTIFF through the reader) and its
    reference chips rendered through the TRUE model (the coarse stage's stand-in)."""
    from gcpmatch.extract import read_band
    from gcpmatch.reference import reference_for_ccd

    truth, dem, dom = scene
    img = read_band(open_scene(FIXTURE / "manifest.json"), BAND)
    pairs = []
    for c, look in enumerate(truth.detector_arrays(BAND)):
        ref = reference_for_ccd(truth, dem, dom, band=BAND, ccd=c)
        pairs.append((np.ascontiguousarray(img[:, look.first_col : look.first_col + look.n_detectors]), ref))
    return pairs


def _paint_clouds(image, cover: float, seed: int):
    """Opaque bright clouds with soft edges over ``cover`` of the image: (cloudy, true mask)."""
    import cv2

    rng = np.random.default_rng(seed)
    field = cv2.GaussianBlur(rng.standard_normal(image.shape).astype(np.float32), (0, 0), 12.0)
    thr = np.quantile(field, 1.0 - cover)
    alpha = np.clip((field - thr) / (0.1 * field.std()) + 0.5, 0.0, 1.0)
    return (image * (1 - alpha) + 3200.0 * alpha).astype(np.float32), alpha > 0.5


def test_decimated_cloud_detector_agrees_with_the_full_resolution_one(ccd_pairs):
    """Per CCD (512 x 192), on the cloud-free fixture and with 30 % painted clouds: the
    decimated detector's cloud fraction is within 0.005 of the full-resolution detector's
    (measured: 0.0014 at worst over 8 cloudy cases) and within 0.05 of the painted truth, its
    mask overlaps it (IoU > 0.95); on clear ground both flag under 1 %. Not vacuous: the painted
    clouds are found (fraction > 0.2), and blocks of 4 with a 9-block box gave 0.025 here."""
    from gcpmatch.clouds import detect_clouds

    for i, (img, ref) in enumerate(ccd_pairs):
        clear_fast = detect_clouds(img, ref)[1]
        clear_full = detect_clouds(img, ref, decimation=1)[1]
        assert clear_fast is not None and clear_full is not None
        assert clear_fast < 0.01 and clear_full < 0.01
        cloudy, truth = _paint_clouds(img, 0.3, seed=i)
        m_fast, f_fast = detect_clouds(cloudy, ref)
        m_full, f_full = detect_clouds(cloudy, ref, decimation=1)
        valid = np.isfinite(ref) & (img > 0)
        true_fraction = truth[valid].mean()
        assert f_fast > 0.2 and abs(f_fast - f_full) < 0.005 and abs(f_fast - true_fraction) < 0.05
        iou = np.count_nonzero(m_fast & m_full) / np.count_nonzero(m_fast | m_full)
        assert iou > 0.95


def test_opening_by_bands_equals_the_opening_of_the_whole_image():
    """Bright specks, lines and blobs next to band edges and image edges: identical results."""
    from gcpmatch.clouds import _open, _open_where_bright

    rng = np.random.default_rng(4)
    bright = rng.random((700, 300)) > 0.97  # specks (removed by the opening)
    bright[120:140, 50:90] = True  # a blob across the band edge at line 128
    bright[0:6, 200:260] = True  # at the first line
    bright[694:700, 0:40] = True  # at the last line
    bright[380:384, :] = True  # a thin line (removed)
    ref = _open(bright, 5)
    assert ref.any() and np.count_nonzero(ref) < np.count_nonzero(bright)
    for band in (128, 64, 37):
        assert np.array_equal(_open_where_bright(bright, 5, band_lines=band), ref)
    assert not _open_where_bright(np.zeros((50, 40), bool), 5).any()


# ---------------------------------------------------------------- coarse stage skipped when close


@pytest.fixture(scope="module")
def fixture_scene(scene):
    from gcpmatch.extract import read_band

    truth, dem, dom = scene
    opened = open_scene(FIXTURE / "manifest.json")
    return truth, opened.model, dem, dom, read_band(opened, BAND)


@pytest.mark.parametrize("shift_rows, skipped", [(0, True), (3, True), (10, False)])
def test_coarse_stage_is_skipped_only_within_half_the_fine_radius(fixture_scene, shift_rows, skipped):
    """The TRUE model against its scene moved by 0, 3 and 10 lines (radius 16 px): the check
    measures the offset (within 0.3 px) and skips SIFT below 8 px only; the note says so."""
    from gcpmatch.coarse_skip import model_offset_px, within_fine_radius

    truth, _, dem, dom, img = fixture_scene
    moved = np.full_like(img, np.nan)
    moved[shift_rows:] = img[: img.shape[0] - shift_rows]
    shifts, n = model_offset_px(moved, truth, dem, dom, band=BAND, radius_px=16.0)
    assert n >= 12 and shifts.shape[0] >= 6
    assert np.abs(np.median(np.hypot(*shifts.T)) - shift_rows) < 0.3
    note = within_fine_radius(moved, truth, dem, dom, band=BAND, radius_px=16.0)
    assert (note is not None) == skipped
    if skipped:
        assert note.startswith(f"coarse stage skipped: model within {shift_rows}.")


def test_coarse_match_falls_back_to_sift_when_the_model_is_far(fixture_scene):
    """The LAB model (hundreds of pixels off): the check cannot confirm it, SIFT runs and
    corrects it; the skip note is absent."""
    from gcpmatch.coarse import coarse_match

    truth, lab, dem, dom, img = fixture_scene
    result = coarse_match(img, lab, dem, dom, band=BAND, skip_within_px=16.0)
    assert result.n_inliers > 6 and result.model is not lab
    assert "skipped" not in result.note


def test_match_options_reject_a_non_boolean_coarse_skip():
    from gcpmatch.options import MatchOptions
    from sensor_models.errors import InputError

    assert MatchOptions(coarse_skip=True).validate().coarse_skip is True
    with pytest.raises(InputError, match="coarse_skip"):
        MatchOptions(coarse_skip="yes").validate()


def test_coarse_match_keeps_a_model_within_the_radius_and_says_so(fixture_scene):
    """The TRUE model: coarse_match returns it unchanged, with no SIFT counts and the note."""
    from gcpmatch.coarse import coarse_match

    truth, _, dem, dom, img = fixture_scene
    result = coarse_match(img, truth, dem, dom, band=BAND, skip_within_px=16.0)
    assert result.model is truth and result.n_inliers == 0
    assert result.note.startswith("coarse stage skipped: model within 0.")


# --------------------------------------------------------------------------- reference chips: DOM sampling


def _chip_nodes(scene, ccd=1, rows=(0, 160)):
    model, dem, dom = scene
    pg = locate_block(model, dem, [dom.grid], band=BAND, ccd=ccd, row0=rows[0], row1=rows[1],
                      tolerance_m=HEIGHT_TOLERANCE_M)
    return pg.uv[0]


def test_chip_sampling_without_weight_division_stays_within_a_thousandth_of_a_dn(scene):
    """The matcher's path (no normalized convolution on a window without no-data, one file
    handle per thread) against the exact path on the fixture's DOM (DN about 200-3000)."""
    from sensor_models.imaging.psf import psf_sigma_dom_px
    from sensor_models.maps.raster import sample_map_image

    _, _, dom = scene
    u, v = _chip_nodes(scene)
    sigma = psf_sigma_dom_px(16.0, dom.grid.resolution_m, 0.45)
    exact = sample_map_image(dom, u, v, sigma_px=sigma)
    with dom.reading():
        fast = sample_map_image(dom, u, v, sigma_px=sigma, exact_weights=False)
    assert np.array_equal(np.isnan(exact), np.isnan(fast))
    diff = np.nanmax(np.abs(fast - exact))
    assert diff < 1e-3  # measured 2.4e-4 DN: float32 rounding of the blurred unit weights
    assert np.nanstd(exact) > 100.0  # a textured DOM, so the bound means something
    # without blur both paths are the same computation
    assert np.array_equal(sample_map_image(dom, u, v), sample_map_image(dom, u, v, exact_weights=False), equal_nan=True)


def test_chip_sampling_keeps_the_no_data_rule_when_the_window_has_holes(scene):
    """A DOM with a no-data hole: the fast path falls back to the normalized convolution, so
    the NaN footprint and the values equal the exact path's bit for bit."""
    from sensor_models.maps.raster import sample_map_image

    _, _, dom = scene
    values = dom.read(0, dom.grid.shape[0], 0, dom.grid.shape[1])
    u, v = _chip_nodes(scene)
    r, c = int(np.nanmedian(v)), int(np.nanmedian(u))
    values[r - 5:r + 5, c - 5:c + 5] = np.nan
    holed = MapImage.from_array(values, dom.grid.transform, dom.grid.crs)
    exact = sample_map_image(holed, u, v, sigma_px=0.8)
    fast = sample_map_image(holed, u, v, sigma_px=0.8, exact_weights=False)
    assert np.isnan(exact).sum() >= 50  # the hole shows (plus its blurred rim)
    assert np.array_equal(exact, fast, equal_nan=True)


def test_reading_session_returns_the_same_windows_and_closes_its_handles(scene, tmp_path):
    """Windows read inside ``MapImage.reading`` (from two threads) equal windows read with a
    file opened per call; nested contexts share one session; the handles close at the end."""
    from concurrent.futures import ThreadPoolExecutor

    _, _, dom = scene
    windows = [(r, r + 90, c, c + 120) for r in (-20, 100, 300) for c in (-10, 150, 400)]
    plain = [dom.read(*w) for w in windows]
    with dom.reading():
        session = dom._session
        with dom.reading():
            assert dom._session is session
        with ThreadPoolExecutor(max_workers=2) as pool:
            inside = list(pool.map(lambda w: dom.read(*w), windows))
        assert len(session._handles) >= 1
    assert dom._session is None and session._handles == []
    for a, b in zip(plain, inside):
        assert np.array_equal(a, b, equal_nan=True)


def test_unmasked_read_only_for_files_without_a_mask(tmp_path):
    """A file with a no-data value is still read masked: its no-data pixels become NaN."""
    import rasterio
    from affine import Affine

    data = np.arange(40 * 50, dtype=np.uint16).reshape(40, 50) % 1000 + 1
    data[10:12, 20:25] = 0
    profile = dict(driver="GTiff", width=50, height=40, count=1, dtype="uint16", crs="EPSG:32631",
                   transform=Affine(15.0, 0, 500000.0, 0, -15.0, 4900000.0), tiled=True, blockxsize=16, blockysize=16,
                   compress="deflate")
    for name, nodata in (("plain.tif", None), ("nodata.tif", 0)):
        with rasterio.open(tmp_path / name, "w", nodata=nodata, **profile) as ds:
            ds.write(data, 1)
    plain, holed = MapImage.open(tmp_path / "plain.tif"), MapImage.open(tmp_path / "nodata.tif")
    for image in (plain, holed):
        with image.reading():
            inside = image.read(5, 30, 15, 45)
        assert np.array_equal(inside, image.read(5, 30, 15, 45), equal_nan=True)
    assert np.array_equal(plain.read(0, 40, 0, 50), data.astype(np.float32))
    got = holed.read(0, 40, 0, 50)
    assert np.isnan(got).sum() == 10 and np.all(np.isnan(got[10:12, 20:25]))
    assert np.array_equal(got[data > 0], data[data > 0].astype(np.float32))
