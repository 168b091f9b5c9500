"""Procedural reference data (DOM + DEM): determinism, geometry, content, files, errors."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest
from scipy import ndimage

from sensor_models.errors import InputError
from sensor_models.simulate.procedural import ReferenceData, generate_reference
from sensor_models.simulate.procedural_cover import LandCover, illumination
from sensor_models.terrain.dem import Dem

LON, LAT = 5.3, 44.2  # Provence: UTM zone 31N

# Small scenes shared by several tests (each takes well under a second).
SMALL = dict(seed=5, relief_m=600.0)


@pytest.fixture(scope="module")
def small() -> ReferenceData:
    """12 km x 9 km at 15 m (800 x 600 DOM, 400 x 300 DEM), sea on one side."""
    return generate_reference(LON, LAT, 12_000.0, 9_000.0, **SMALL)


@pytest.fixture(scope="module")
def mountains() -> ReferenceData:
    """30 km x 22.5 km, default relief, no sea; DOM and DEM both at 30 m (aligned grids)."""
    return generate_reference(LON, LAT, 30_000.0, 22_500.0, seed=2, dom_resolution_m=30.0,
                              sea_fraction=0.0)


# ---------------------------------------------------------------------------------------------
# Determinism
# ---------------------------------------------------------------------------------------------


def test_same_seed_same_arrays_other_seed_differs(small):
    calls = []
    again = generate_reference(LON, LAT, 12_000.0, 9_000.0, **SMALL, progress=lambda d, t: calls.append((d, t)))
    # counted progress (phases, then every strip of DOM rows) does not touch the result
    total = calls[0][1]
    assert [d for d, _ in calls] == list(range(total + 1)) and {t for _, t in calls} == {total}
    assert total == 6 + -(-small.dom.shape[0] // 256) + 1
    for name in ("dom", "dem_m", "water_mask", "land_cover"):
        a, b = getattr(small, name), getattr(again, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    assert small.dom_transform == again.dom_transform
    other = generate_reference(LON, LAT, 12_000.0, 9_000.0, **{**SMALL, "seed": 6})
    assert np.mean(other.dom != small.dom) > 0.9
    assert np.mean(other.dem_m != small.dem_m) > 0.9


def test_same_seed_same_file_bytes(small, tmp_path):
    first = small.write(tmp_path / "a")
    again = generate_reference(LON, LAT, 12_000.0, 9_000.0, **SMALL)
    second = again.write(tmp_path / "b")
    for p, q in zip(first, second):
        assert p.read_bytes() == q.read_bytes(), p.name
    other = generate_reference(LON, LAT, 12_000.0, 9_000.0, **{**SMALL, "seed": 6})
    third = other.write(tmp_path / "c")
    assert first[0].read_bytes() != third[0].read_bytes()


# ---------------------------------------------------------------------------------------------
# Grids
# ---------------------------------------------------------------------------------------------


def _centre_of(transform, shape):
    return transform @ (shape[1] / 2.0, shape[0] / 2.0)


@pytest.mark.parametrize(
    "lon, lat, epsg",
    [(5.3, 44.2, 32631), (-70.6, -33.4, 32719), (179.9, 10.0, 32660), (-180.0, 0.5, 32601)],
)
def test_utm_zone_and_centre(lon, lat, epsg):
    ref = generate_reference(lon, lat, 3000.0, 2400.0, seed=1, sea_fraction=0.0, relief_m=100.0)
    assert ref.crs.to_epsg() == epsg
    x, y = pyproj.Transformer.from_crs("EPSG:4326", ref.crs, always_xy=True).transform(lon, lat)
    grids = ((ref.dom_transform, ref.dom.shape), (ref.dem_transform, ref.dem_m.shape))
    for transform, shape in grids:
        cx, cy = _centre_of(transform, shape)
        assert abs(cx - x) < 1e-6 and abs(cy - y) < 1e-6
        assert transform.b == 0.0 and transform.d == 0.0 and transform.e == -transform.a


def test_extent_exact_for_multiples_and_snapped_outwards_otherwise():
    ref = generate_reference(LON, LAT, 6000.0, 4500.0, seed=0, relief_m=200.0)
    assert ref.dom.shape == (300, 400) and ref.dem_m.shape == (150, 200)
    assert ref.water_mask.shape == ref.dom.shape == ref.land_cover.shape
    assert ref.dom_transform.a == 15.0 and ref.dem_transform.a == 30.0
    # Same corners for both grids when the size is a multiple of both resolutions.
    assert ref.dom_transform.c == pytest.approx(ref.dem_transform.c, abs=1e-6)
    assert ref.dom_transform.f == pytest.approx(ref.dem_transform.f, abs=1e-6)
    # 6010 m is not a multiple: ceil to whole pixels, overhang shared on both sides.
    odd = generate_reference(LON, LAT, 6010.0, 4490.0, seed=0, relief_m=200.0)
    assert odd.dom.shape == (300, 401) and odd.dem_m.shape == (150, 201)
    width_dom = odd.dom.shape[1] * 15.0
    assert 6010.0 <= width_dom < 6010.0 + 15.0
    assert _centre_of(odd.dom_transform, odd.dom.shape) == pytest.approx(
        _centre_of(odd.dem_transform, odd.dem_m.shape), abs=1e-6)


# ---------------------------------------------------------------------------------------------
# Terrain
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("relief, sea", [(300.0, 0.0), (600.0, 0.15), (1500.0, 0.3)])
def test_relief_and_mean_height(relief, sea):
    ref = generate_reference(LON, LAT, 12_000.0, 9_000.0, seed=3, relief_m=relief,
                             mean_height_m=relief / 3.0, sea_fraction=sea)
    dem = ref.dem_m
    assert dem.dtype == np.float32 and np.isfinite(dem).all()
    span = float(dem.max() - dem.min())
    assert 0.5 * relief < span <= 1.2 * relief
    assert np.all(dem * 16.0 == np.round(dem * 16.0))  # 1/16 m quantum
    sea_px = ref.land_cover == LandCover.SEA
    if sea > 0.0:
        # The sea is flat at sea level (0 m above the ellipsoid) and the coast at sea level.
        assert dem.min() == 0.0
    else:
        assert not sea_px.any()
    land = _dem_land(ref)
    assert abs(float(dem[land].mean()) - relief / 3.0) < 0.1 * relief


def _dem_land(ref):
    """DEM nodes whose four DOM pixels are land (DOM at 15 m, DEM at 30 m, aligned)."""
    water = ref.water_mask.reshape(ref.dem_m.shape[0], 2, ref.dem_m.shape[1], 2)
    return ~water.any(axis=(1, 3))


def test_slopes_mostly_below_35_degrees(mountains):
    dem = mountains.dem_m.astype(np.float64)
    assert 1300.0 < dem.max() - dem.min() <= 1500.0
    d_row, d_col = np.gradient(dem, 30.0)
    slope_deg = np.degrees(np.arctan(np.hypot(d_row, d_col)))
    assert np.mean(slope_deg > 35.0) < 0.08
    assert 2.0 < np.median(slope_deg) < 20.0
    # Smooth at the node scale: second differences are a small part of the first ones.
    curvature = np.abs(np.diff(dem, 2, axis=1)).mean()
    assert curvature < 0.5 * np.abs(np.diff(dem, axis=1)).mean()


def test_lakes_are_flat_basins_in_the_dem():
    ref = generate_reference(LON, LAT, 30_000.0, 22_500.0, seed=4, dom_resolution_m=30.0,
                             n_lakes=3, sea_fraction=0.0)
    lakes = ref.land_cover == LandCover.LAKE  # DOM and DEM grids coincide at 30 m
    assert lakes.sum() > 50
    whole, _ = ndimage.label(lakes, structure=np.ones((3, 3)))
    labels, n = ndimage.label(ndimage.binary_erosion(lakes))
    assert n >= 1
    valleys = ndimage.binary_dilation(ref.land_cover == LandCover.RIVER, iterations=6)
    for i in range(1, n + 1):
        heights = ref.dem_m[labels == i]
        level = heights.min()
        assert heights.max() - level < 0.5  # a flat water surface
        # A filled basin: no node next to the water is below it (away from the river valleys
        # carved into the DEM), and the shore rises around it.
        surface = np.isin(whole, np.unique(whole[labels == i]))
        assert np.all(ref.dem_m[surface] == level)
        rim = ndimage.binary_dilation(surface, structure=np.ones((3, 3))) & ~surface & ~valleys
        assert rim.sum() > 10 and ref.dem_m[rim].min() >= level
        shore = ndimage.binary_dilation(surface, iterations=4) & ~surface & ~valleys
        assert np.median(ref.dem_m[shore]) > level + 1.0


# ---------------------------------------------------------------------------------------------
# Image content
# ---------------------------------------------------------------------------------------------


def test_dynamic_range_and_values(small):
    dom = small.dom
    assert dom.dtype == np.uint16 and dom.min() >= 1 and dom.max() <= 4095
    lo, hi = np.percentile(dom, [0.5, 99.5])
    assert hi - lo > 2000.0
    assert lo < 600.0  # dark water and forest
    assert np.mean(dom == 4095) < 0.001  # hardly any saturation


@pytest.mark.parametrize("sea_fraction", [0.0, 0.15, 0.4])
def test_water_fraction_follows_sea_fraction(sea_fraction):
    ref = generate_reference(LON, LAT, 12_000.0, 9_000.0, seed=8, sea_fraction=sea_fraction,
                             relief_m=600.0)
    sea = np.mean(ref.land_cover == LandCover.SEA)
    assert abs(sea - sea_fraction) < 0.02
    water = ref.water_mask.mean()
    assert sea_fraction - 0.01 < water < sea_fraction + 0.06
    classes = np.isin(ref.land_cover, [LandCover.SEA, LandCover.LAKE, LandCover.RIVER])
    assert np.array_equal(ref.water_mask, classes)


def test_land_cover_classes_present():
    ref = generate_reference(LON, LAT, 30_000.0, 22_500.0, seed=1, dom_resolution_m=30.0,
                             n_lakes=2, n_rivers=3, n_roads=3)
    fractions = np.bincount(ref.land_cover.ravel(), minlength=11) / ref.land_cover.size
    assert fractions[0] == 0.0  # every pixel classified
    for cls in (LandCover.SEA, LandCover.LAKE, LandCover.RIVER, LandCover.FIELD,
                LandCover.FOREST, LandCover.URBAN, LandCover.GRASS, LandCover.ROAD):
        assert fractions[cls] > 0.0005, cls.name
    land = 1.0 - fractions[[LandCover.SEA, LandCover.LAKE, LandCover.RIVER]].sum()
    assert 0.15 < fractions[LandCover.FOREST] / land < 0.45
    assert 0.01 < fractions[LandCover.URBAN] / land < 0.1


def _local_std(img, size=7):
    img = img.astype(np.float64)
    m = ndimage.uniform_filter(img, size)
    return np.sqrt(np.maximum(ndimage.uniform_filter(img * img, size) - m * m, 0.0))


def test_land_is_textured_water_is_not(small):
    std = _local_std(small.dom)
    land = ndimage.binary_erosion(~small.water_mask, iterations=4)
    water = ndimage.binary_erosion(small.water_mask, iterations=4)
    assert land.mean() > 0.5 and water.mean() > 0.05
    assert np.median(std[water]) < 5.0  # sensor noise (2.5 DN) and a faint gradient only
    assert np.median(std[land]) > 20.0 * np.median(std[water])


def _chip_origin(mask, size, want, margin=8):
    """Top-left corner of the first chip (coarse scan) whose mask, plus a margin, is ``want``."""
    for r in range(margin, mask.shape[0] - size - margin, size // 2):
        for c in range(margin, mask.shape[1] - size - margin, size // 2):
            if np.all(mask[r - margin:r + size + margin, c - margin:c + size + margin] == want):
                return r, c
    raise AssertionError("no suitable chip")


def _phase_correlation(a, b):
    """Integer shift of ``b`` relative to ``a``, the peak value and its ratio to the runner-up."""
    window = np.outer(np.hanning(a.shape[0]), np.hanning(a.shape[1]))
    fa = np.fft.fft2((a - a.mean()) * window)
    fb = np.fft.fft2((b - b.mean()) * window)
    cross = fb * np.conj(fa)
    surface = np.real(np.fft.ifft2(cross / (np.abs(cross) + 1e-12)))
    peak = np.unravel_index(np.argmax(surface), surface.shape)
    shift = tuple(int(p if p <= n // 2 else p - n) for p, n in zip(peak, surface.shape))
    rest = surface.copy()
    rows = [(peak[0] + d) % surface.shape[0] for d in (-1, 0, 1)]
    cols = [(peak[1] + d) % surface.shape[1] for d in (-1, 0, 1)]
    rest[np.ix_(rows, cols)] = -np.inf
    return shift, surface[peak], surface[peak] / rest.max()


def test_land_is_matchable_water_is_not(small):
    """A chip and its shifted copy, each with independent noise (another acquisition)."""
    rng = np.random.default_rng(0)
    size, shift = 64, (3, -5)
    dom = small.dom.astype(np.float64)
    results = {}
    for name, want in (("land", False), ("water", True)):
        r, c = _chip_origin(small.water_mask, size, want)
        a = dom[r:r + size, c:c + size]
        b = dom[r - shift[0]:r - shift[0] + size, c - shift[1]:c - shift[1] + size]  # a(x - s)
        a = a + rng.normal(0.0, 10.0, a.shape)
        b = b + rng.normal(0.0, 10.0, b.shape)
        results[name] = _phase_correlation(a, b)
    found, peak, ratio = results["land"]
    assert found == shift and peak > 0.2 and ratio > 3.0
    found, peak, ratio = results["water"]
    assert found != shift or ratio < 1.5
    # Land has energy at high spatial frequencies (above 0.2 cycles per pixel).
    r, c = _chip_origin(small.water_mask, size, False)
    chip = dom[r:r + size, c:c + size]
    power = np.abs(np.fft.fft2(chip - chip.mean())) ** 2
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(size), np.fft.fftfreq(size), indexing="ij"))
    assert power[f > 0.2].sum() / power.sum() > 0.03


def test_dom_correlates_with_terrain_shading(mountains):
    sun = dict(sun_azimuth_deg=135.0, sun_elevation_deg=45.0)
    cos_i = illumination(mountains.dem_m, 30.0, **sun)
    opposite = generate_reference(LON, LAT, 30_000.0, 22_500.0, seed=2, dom_resolution_m=30.0,
                                  sea_fraction=0.0, sun_azimuth_deg=315.0)
    assert np.array_equal(opposite.dem_m, mountains.dem_m)
    for ref, sign in ((mountains, 1.0), (opposite, -1.0)):
        vegetation = np.isin(ref.land_cover, [LandCover.FOREST, LandCover.GRASS])
        corr = np.corrcoef(ref.dom[vegetation].astype(np.float64), cos_i[vegetation])[0, 1]
        assert sign * corr > 0.2


def test_illumination_of_a_plane():
    # A plane rising to the east by 10 %: lit by a western sun, shadowed by an eastern one.
    x = np.arange(50) * 30.0
    heights = np.tile(0.1 * x, (40, 1))
    for azimuth, expected_sign in ((270.0, 1.0), (90.0, -1.0)):
        cos_i = illumination(heights, 30.0, sun_azimuth_deg=azimuth, sun_elevation_deg=30.0)
        normal = np.array([-0.1, 0.0, 1.0]) / math.sqrt(1.01)
        az, el = math.radians(azimuth), math.radians(30.0)
        sun = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
        np.testing.assert_allclose(cos_i, normal @ sun, rtol=1e-6)
        assert expected_sign * (cos_i[0, 0] - math.sin(el)) > 0.0


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------


def test_files_geotiff_layout_and_dem_open(small, tmp_path):
    import rasterio

    dom_path, dem_path = small.write(tmp_path / "out", dom_name="ref.tif", dem_name="h.tif")
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if p.name != ".gcpcal-outputs.json") == ["h.tif", "ref.tif"]
    for path, data, transform, predictor in (
        (dom_path, small.dom, small.dom_transform, "2"),
        (dem_path, small.dem_m, small.dem_transform, "3"),
    ):
        with rasterio.open(path) as ds:
            assert ds.crs.to_epsg() == 32631
            assert ds.transform == transform
            assert ds.nodata is None and ds.count == 1
            assert ds.block_shapes == [(256, 256)]
            structure = ds.tags(ns="IMAGE_STRUCTURE")
            assert structure["COMPRESSION"] == "DEFLATE" and structure["PREDICTOR"] == predictor
            assert "TIFFTAG_DATETIME" not in ds.tags()
            assert '"seed": 5' in ds.tags()["GCPCAL_PROCEDURAL"]
            assert np.array_equal(ds.read(1), data)
    with rasterio.open(dem_path) as ds:
        assert ds.tags()["VERTICAL_DATUM"] == "ellipsoid"
    dem = Dem.open(dem_path)  # no arguments: the datum comes from the tag
    np.testing.assert_array_equal(dem.heights_m, small.dem_m.astype(np.float64))
    assert dem.height_range_m == (float(small.dem_m.min()), float(small.dem_m.max()))


def test_failed_write_leaves_no_partial_file(small, tmp_path):
    (tmp_path / "dem.tif").mkdir()  # the DEM cannot replace a folder
    with pytest.raises(InputError, match="dem.tif"):
        small.write(tmp_path)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != ".gcpcal-outputs.json" and p.name not in ("dem.tif", "dom.tif")]
    assert leftovers == []
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError):
        small.write(blocker)  # out_dir is a file


# ---------------------------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, field",
    [
        ({"width_m": 0.0}, "width_m"),
        ({"height_m": -10.0}, "height_m"),
        ({"width_m": float("nan")}, "width_m"),
        ({"width_m": 50.0}, "width_m"),  # fewer than 8 DEM pixels
        ({"dom_resolution_m": 0.0}, "dom_resolution_m"),
        ({"dem_resolution_m": -30.0}, "dem_resolution_m"),
        ({"center_lat_deg": 84.5}, "center_lat_deg"),
        ({"center_lat_deg": -85.0}, "center_lat_deg"),
        ({"center_lon_deg": 181.0}, "center_lon_deg"),
        ({"sea_fraction": 0.95}, "sea_fraction"),
        ({"sea_fraction": -0.1}, "sea_fraction"),
        ({"relief_m": -1.0}, "relief_m"),
        ({"seed": -1}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"sun_elevation_deg": 0.0}, "sun_elevation_deg"),
        ({"n_lakes": -2}, "n_lakes"),
        ({"urban_fraction": 0.5, "forest_fraction": 0.6}, "forest_fraction"),
        ({"width_m": 500_000.0, "height_m": 500_000.0}, "width_m"),  # too many pixels
        ({"relief_m": "high"}, "relief_m"),
    ],
)
def test_bad_arguments_raise_input_error_naming_them(change, field):
    args = dict(center_lon_deg=LON, center_lat_deg=LAT, width_m=3000.0, height_m=3000.0)
    args.update(change)
    with pytest.raises(InputError) as info:
        generate_reference(**args)
    assert info.value.field == field
    assert f"'{field}'" in str(info.value)
