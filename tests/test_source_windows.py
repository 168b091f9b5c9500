"""The realistic renderer's source by windows: a scratch raster read by windows, the optics per window,
the footprint integrated by column tiles, the reference DOM's displacement by windows of columns,
each equal to the whole-grid computation.

Random draws: source grids of 150-400 x 150-400 pixels with NaN holes, PSFs of the realistic
profile's family (disk radius 0.3-1.5 detector pitches, astigmatic edge, halo), 1.5-3 source
pixels a detector, and blocks of lines turned 0-25 degrees against the grid that run off its
edges, so that tiles meet the grid's border, the NaN outside it and each other.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from affine import Affine

from sensor_models.simulate.kernel import footprint_offsets, integrate_footprint, optics_kernel
from sensor_models.simulate.source_windows import FilteredWindows, RowFile


def _source(rng):
    shape = tuple(int(n) for n in rng.integers(150, 400, 2))
    a = cv2.GaussianBlur(rng.random(shape, dtype=np.float32), (0, 0), 2.0) + 0.2 * rng.random(shape, dtype=np.float32)
    a[rng.random(shape) < 0.002] = np.nan
    return a.astype(np.float32)


def _kernels(rng, scale):
    r0 = float(rng.uniform(0.3, 1.5))
    kw = dict(halo_fraction=float(rng.uniform(0.0, 0.1)), halo_sigma_px=float(rng.uniform(1.0, 3.0)),
              source_px_per_px=scale)
    return [optics_kernel(r0, **kw), optics_kernel(r0 + 0.4, defocus_radius_row_px=r0 + 0.2, **kw)]


def _whole(a, kernels):
    filled = np.nan_to_num(a, nan=0.0)
    planes = [cv2.filter2D(filled, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT) for k in kernels]
    return np.stack(planes, axis=-1)


@pytest.mark.parametrize("seed", range(6))
def test_row_file_windows_and_filtered_windows_equal_the_whole_grid(tmp_path, seed):
    rng = np.random.default_rng([seed, 1])
    a = _source(rng)
    rows = RowFile(tmp_path / "a.f32", a.shape)
    step = int(rng.integers(1, 40))
    for r0 in range(0, a.shape[0], step):
        rows.write_rows(r0, a[r0:r0 + step])
    kernels = _kernels(rng, float(rng.uniform(1.5, 3.0)))
    whole = _whole(a, kernels)
    windows = FilteredWindows(rows, kernels)
    for _ in range(20):
        r0, c0 = int(rng.integers(0, a.shape[0] - 1)), int(rng.integers(0, a.shape[1] - 1))
        r1, c1 = int(rng.integers(r0 + 1, a.shape[0] + 1)), int(rng.integers(c0 + 1, a.shape[1] + 1))
        np.testing.assert_array_equal(rows.read(r0, r1, c0, c1), a[r0:r1, c0:c1])
        got = windows.window(r0, r1, c0, c1)
        assert got.shape == (r1 - r0, c1 - c0, 2)
        np.testing.assert_allclose(got, whole[r0:r1, c0:c1], rtol=0, atol=2e-6)
    rows.remove()
    assert not (tmp_path / "a.f32").exists()


@pytest.mark.parametrize("seed", range(6))
def test_footprint_by_column_tiles_equals_the_whole_grid(tmp_path, seed):
    rng = np.random.default_rng([seed, 2])
    a = _source(rng)
    scale = float(rng.uniform(1.5, 3.0))
    kernels = _kernels(rng, scale)
    whole = _whole(a, kernels)
    n_lines, n_det = int(rng.integers(2, 24)), int(1.4 * a.shape[1] / scale)  # wider than the grid
    turn = np.radians(rng.uniform(0.0, 25.0))
    line, det = np.meshgrid(np.arange(n_lines, dtype=np.float64), np.arange(n_det, dtype=np.float64), indexing="ij")
    det_u, det_v = scale * np.cos(turn), scale * np.sin(turn)
    u0 = rng.uniform(-0.3, -0.05) * a.shape[1]  # the block starts off the grid
    v0 = rng.uniform(0.1, 0.4) * a.shape[0]
    u = (u0 + det_u * det - scale * np.sin(turn) * line + 0.3 * np.sin(det / 7.0)).astype(np.float32)
    v = (v0 + det_v * det + scale * np.cos(turn) * line).astype(np.float32)
    offsets = footprint_offsets(3, 0.3)
    ir, ic = rng.normal(0.0, 0.2, n_det), rng.normal(0.0, 0.2, n_det)
    expected = integrate_footprint(whole, u, v, *offsets, irregular_row=ir, irregular_col=ic)
    windows = FilteredWindows(a, kernels)
    for max_px in (1 << 30, 400, 60):  # one tile, a few, one detector per tile where needed
        got = integrate_footprint(windows, u, v, *offsets, irregular_row=ir, irregular_col=ic, max_window_px=max_px)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-6)
    assert np.isnan(expected).any() and np.isfinite(expected).any()  # the block ran off the grid and over it


class _Recorded(FilteredWindows):
    """FilteredWindows that records the size of every window read."""

    def __init__(self, *args):
        super().__init__(*args)
        self.sizes = []

    def window(self, row0, row1, col0, col1):
        self.sizes.append((row1 - row0) * (col1 - col0))
        return super().window(row0, row1, col0, col1)


@pytest.mark.parametrize("seed", range(4))
def test_windows_stay_within_the_budget_whatever_the_grid(seed):
    """A block turned against the grid: its column tiles' windows stay under the budget as the grid and block grow."""
    rng = np.random.default_rng([seed, 3])
    scale, turn = float(rng.uniform(1.5, 3.0)), np.radians(rng.uniform(10.0, 30.0))
    kernels = _kernels(rng, scale)
    budget = 20_000
    for n_det in (100, 400):  # the grid (and the block's box) grows 16 times in area
        side = int(1.2 * scale * n_det) + 120
        a = rng.random((side, side), dtype=np.float32)
        line, det = np.meshgrid(np.arange(16.0), np.arange(float(n_det)), indexing="ij")
        u = (60 + scale * (np.cos(turn) * det - np.sin(turn) * line)).astype(np.float32)
        v = (20 + scale * (np.sin(turn) * det + np.cos(turn) * line)).astype(np.float32)
        windows = _Recorded(a, kernels)
        got = integrate_footprint(windows, u, v, *footprint_offsets(3, 0.3), max_window_px=budget)
        assert np.isfinite(got).all()
        assert max(windows.sizes) <= budget
        assert sum(windows.sizes) < 4 * (scale * n_det) * (scale * 16 + 2 * windows.margin + 10) + 16 * budget


@pytest.mark.parametrize("seed", range(3))
def test_degraded_dom_from_a_row_file_by_column_chunks_equals_the_whole_raster(tmp_path, monkeypatch, seed):
    """The reference DOM's displacement remap reads windows of a scratch file by chunks of columns: same DN."""
    from sensor_models.simulate import reference_pair
    from sensor_models.simulate.profiles import get_profile

    rng = np.random.default_rng([seed, 4])
    a = _source(rng)
    transform = Affine(15.0, 0.0, 500_000.0, 0.0, -15.0, 4_000_000.0)
    profile = get_profile("realistic")
    expected = reference_pair.degrade_dom(a, transform, profile, seed=seed)
    monkeypatch.setattr(reference_pair, "_REMAP_COLS", int(rng.integers(7, 60)))
    got = reference_pair.degrade_dom(RowFile.from_array(tmp_path / "a.f32", a, strip_pixels=3_000), transform, profile,
                                     seed=seed)
    np.testing.assert_array_equal(got.values, expected.values)
    assert got.figures == expected.figures


@pytest.mark.parametrize("seed", range(6))
def test_area_average_without_weights_when_they_are_all_one(monkeypatch, seed):
    """An all-finite source onto a finer or coarser reference grid: the weightless average is the weighted one, to the bit."""
    from sensor_models.simulate import reference_pair

    rng = np.random.default_rng([seed, 7])
    a = rng.random((int(rng.integers(20, 400)), int(rng.integers(20, 400))), dtype=np.float32)
    res = float(rng.uniform(10.0, 60.0))
    transform = Affine(res, 0.0, 5e5, 0.0, -res, 4e6)
    got, got_t = reference_pair._area_average(a, transform, 30.0)
    monkeypatch.setattr(reference_pair, "_ones_stay_ones", lambda *args: False)  # the weighted path
    expected, expected_t = reference_pair._area_average(a, transform, 30.0)
    np.testing.assert_array_equal(got, expected)
    assert got_t == expected_t
