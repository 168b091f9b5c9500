"""RPC00B fitting: the denominator bound, rational fits of push-broom models, tiles, real products.

Truth is always the rigorous model the RPC stands in for, sampled at random pixels and heights
that no fit, validation or check grid used.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensor_models.geometry.ephemeris import Attitude
from sensor_models.errors import InputError
from sensor_models.models.pushbroom import PushbroomModel
from sensor_models.readers import open_model
from sensor_models.models.rpc_dem import rpc00b_monomials
from sensor_models.models.rpc_fit import denominator_lower_bound, fit_rpc, fit_rpc_tiles

PROJECT_ROOT = Path(__file__).resolve().parents[1]

IDEAL = PROJECT_ROOT / "fixtures" / "hy1c_czi" / "manifest.json"
REALISTIC = PROJECT_ROOT / "fixtures" / "hy1c_czi_realistic" / "manifest.json"
HEIGHTS = (-100.0, 3000.0)


def _cube_min(den, n=41):
    """Min of the cubic over a dense sample of [-1, 1]^3 (an upper bound of the true minimum)."""
    a = np.linspace(-1.0, 1.0, n)
    L, P, H = (x.reshape(-1) for x in np.meshgrid(a, a, a, indexing="ij"))
    return float(np.min(np.asarray(den) @ rpc00b_monomials(L, P, H)))


def _max_error_px(model, rpc, n, *, rows=None, seed=0):
    """Max image distance between ``rpc`` and ``model`` at ``n`` random pixels and heights."""
    rng = np.random.default_rng(seed)
    n_rows, n_cols = rpc.image_shape
    r0 = 0 if rows is None else rows
    r = rng.uniform(0.5, n_rows - 0.5, n)
    c = rng.uniform(0.5, n_cols - 0.5, n)
    lon, lat, h = model.image_to_ground(r + r0, c, height=rng.uniform(*HEIGHTS, n))
    r2, c2 = rpc.ground_to_image(lon, lat, h)
    return float(np.max(np.hypot(r2 - r, c2 - c)))


def _with_cubic_attitude(model):
    """The model with its attitude replaced by the least-squares cubic in time of its rotation
    vector (relative to mid-scene) over the scene: what is left beyond a cubic is removed."""
    lt = model.line_timing
    t0, t1 = sorted((float(lt.seconds(-64.0)), float(lt.seconds(model.n_rows + 64.0))))
    t = np.linspace(t0, t1, 200)
    mid = model.attitude.rotation([(t0 + t1) / 2.0])[0]
    rv = (mid.inv() * model.attitude.rotation(t)).as_rotvec()
    V = np.vander((t - t.mean()) / (t1 - t0), 4)
    smooth = mid * Rotation.from_rotvec(V @ np.linalg.lstsq(V, rv, rcond=None)[0])
    att = Attitude(t, smooth.as_quat(), frame=model.attitude.frame)
    return PushbroomModel(orbit=model.orbit, attitude=att, line_timing=lt, bands=model.bands,
                          installation=model.installation, n_rows=model.n_rows, reference_band=model.reference_band)


# ---------------------------------------------------------------------------------------------
# the denominator bound
# ---------------------------------------------------------------------------------------------
def _den(**terms):
    names = {"1": 0, "L": 1, "P": 2, "H": 3, "L2": 7, "P2": 8, "H2": 9, "L3": 11, "LPH": 10}
    d = np.zeros(20)
    for k, v in terms.items():
        d[names[k.removeprefix("c")]] = v
    return d


def test_denominator_bound_is_exact_on_a_linear_and_tight_on_a_curved_denominator():
    assert denominator_lower_bound(_den(c1=1.0, L=0.5)) == pytest.approx(0.5, abs=1e-12)  # at L = -1
    # min 0.05 at L = 0, where the Bernstein net of L^2 dips to -1/3: subdivision must lift it
    bound = denominator_lower_bound(_den(c1=0.05, L2=1.0))
    assert 0.04 < bound <= 0.05 + 1e-12


def test_denominator_bound_finds_interior_and_corner_zeros():
    assert denominator_lower_bound(_den(c1=-0.1, L2=1.0)) <= -0.1 + 1e-12  # corners 0.9, zero inside
    assert denominator_lower_bound(_den(c1=1.0, L3=-0.6, LPH=-0.6)) < 0.0  # D(1, 1, 1) = -0.2


def test_denominator_bound_never_exceeds_the_sampled_minimum():
    rng = np.random.default_rng(42)
    proved = 0
    for _ in range(40):
        den = np.r_[1.0, rng.normal(0.0, 0.15, 19)]
        bound, sampled = denominator_lower_bound(den), _cube_min(den)
        assert bound <= sampled + 1e-12  # sound: never above the true minimum
        proved += bound > 0.0
        if sampled < 0.0:
            assert bound < 0.0  # a real zero is never certified away
    assert 5 < proved < 40  # both cases occur


# ---------------------------------------------------------------------------------------------
# push-broom fixtures
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def realistic():
    model = open_model(REALISTIC)
    return model, model.detector_view(model.reference_band, 0)


def test_rational_fit_follows_a_push_broom_ccd_whose_attitude_is_a_cubic(realistic):
    """The fit reaches 0.01 px with room to spare once the model is smooth: the realistic scene's
    CCD with its attitude reduced to a cubic in time; the polynomial form stays coarser."""
    model, _ = realistic
    view = _with_cubic_attitude(model).detector_view(model.reference_band, 0)
    rpc, report = fit_rpc(view, height_range_m=HEIGHTS)
    assert report["form"] == "rational" and report["check_max_px"] < 1e-4
    assert report["denominator_lower_bound"] > 0.5
    assert 1e-7 < _max_error_px(view, rpc, 3000) < 1e-4  # at pixels no grid used; not exact either
    poly, poly_report = fit_rpc(view, height_range_m=HEIGHTS, form="polynomial")
    assert np.array_equal(poly.line_den, np.eye(20)[0]) and np.array_equal(poly.samp_den, np.eye(20)[0])
    assert poly_report["check_max_px"] > 10 * report["check_max_px"]


def test_one_rpc_cannot_follow_the_scene_s_attitude_so_tiles_do(realistic):
    """The attitude samples of the realistic scene (jitter, 4 Hz samples) vary faster than a cubic
    over its 2.3 s: one RPC misses 0.01 px by far, row tiles reach it."""
    model, view = realistic
    rpc, report = fit_rpc(view, height_range_m=HEIGHTS)
    assert 0.1 < report["check_max_px"] < 0.3
    assert report["denominator_lower_bound"] > 0.0
    tiles = fit_rpc_tiles(view, height_range_m=HEIGHTS, max_error_px=0.01, min_tile_px=32)
    assert 2 < len(tiles) <= 16
    assert sum(t.rpc.image_shape[0] for t in tiles) == view.image_shape[0]
    assert {t.first_col for t in tiles} == {0} and {t.rpc.image_shape[1] for t in tiles} == {view.image_shape[1]}
    rows = 0
    for k, tile in enumerate(tiles):
        assert tile.first_row == rows
        rows += tile.rpc.image_shape[0]
        assert tile.report["form"] == "rational" and tile.report["check_max_px"] <= 0.01
        assert tile.report["denominator_lower_bound"] > 0.0
        assert _max_error_px(view, tile.rpc, 500, rows=tile.first_row, seed=k) <= 0.012


def test_tiles_options_are_checked(realistic):
    _, view = realistic
    with pytest.raises(InputError, match="max_error_px"):
        fit_rpc_tiles(view, height_range_m=HEIGHTS, max_error_px=0.0)
    with pytest.raises(InputError, match="min_tile_px"):
        fit_rpc_tiles(view, height_range_m=HEIGHTS, max_error_px=0.01, min_tile_px=4)
    with pytest.raises(InputError, match="form"):
        fit_rpc(view, height_range_m=HEIGHTS, form="cubic")


# ---------------------------------------------------------------------------------------------
# real products
# ---------------------------------------------------------------------------------------------
REAL = ["spot_dimap/SPOT1.DIM", "spot_dimap/SPOT2.DIM", "spot_dimap/SPOT3.DIM", "spot_dimap/SPOT4.DIM",
        "spot_dimap/SPOT5.DIM", "products/WV2.XML", "products/WV3.XML"]


def test_spot6_rigorous_model_is_one_rational_rpc(shared_data):
    model = open_model(shared_data / "products" / "SPOT6.XML")
    rpc, report = fit_rpc(model, height_range_m=HEIGHTS)
    assert report["form"] == "rational" and report["check_max_px"] <= 0.01
    assert report["denominator_lower_bound"] > 0.5
    assert _max_error_px(model, rpc, 2000) <= 0.01


@pytest.mark.slow
@pytest.mark.parametrize("name", REAL)
def test_real_product_rpc_tiles_reach_a_hundredth_of_a_pixel(shared_data, name):
    model = open_model(shared_data / name)
    view = model.detector_view(model.reference_band, 0)
    tiles = fit_rpc_tiles(view, height_range_m=HEIGHTS, max_error_px=0.01, min_tile_px=32)
    assert len(tiles) > 1  # their attitude (and SPOT 5's look table) is beyond one RPC
    for k, tile in enumerate(tiles):
        assert tile.report["form"] == "rational" and tile.report["check_max_px"] <= 0.01
        assert tile.report["denominator_lower_bound"] > 0.0
    worst = max(range(len(tiles)), key=lambda k: tiles[k].report["check_max_px"])
    tile = tiles[worst]
    from sensor_models.models.rpc_fit import _Window

    window = _Window(view, tile.first_row, tile.first_col, tile.rpc.image_shape)
    assert _max_error_px(window, tile.rpc, 1000, seed=worst) <= 0.015


def test_cli_writes_the_polynomial_form_only_when_asked_and_warns_when_one_rpc_misses(tmp_path, capsys):
    from calibrate.cli import main
    from sensor_models.readers.rpc_files import read_rpc

    forms = {}
    for form in ("rational", "polynomial"):
        out = tmp_path / f"{form}_RPC.TXT"
        args = ["rpc", str(IDEAL), "--ccd", "cam1_ccd2", "--out", str(out), "--height-range", "0", "500", "--json"]
        code = main(args + (["--form", form] if form == "polynomial" else []))
        captured = capsys.readouterr()
        assert code == 0, captured.err
        summary = json.loads(captured.out)
        (entry,) = summary["rpcs"]
        forms[form] = (entry["fit"], read_rpc(out))
        # one RPC in a file: written, and the miss of 0.01 px is said (the scene's attitude)
        assert summary["check_max_px"] > 0.01 and "miss 0.01 px" in " ".join(summary["warnings"])
    (fit_r, rpc_r), (fit_p, rpc_p) = forms["rational"], forms["polynomial"]
    assert fit_r["form"] == "rational" and np.count_nonzero(rpc_r.line_den[1:]) > 0
    assert fit_p["form"] == "polynomial" and np.array_equal(rpc_p.line_den, np.eye(20)[0])
    assert fit_r["check_max_px"] < fit_p["check_max_px"]
