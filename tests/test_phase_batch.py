"""The torch phase stage's batch planner (gcpmatch.phase_batch): budget respected, results batch-free."""

from __future__ import annotations

import numpy as np
import pytest

from gcpmatch.phase import phase_correlate
from gcpmatch.phase_batch import (BATCH_PIXELS, BYTES_PER_PIXEL_PER_ITEM, MAX_DEVICE_BATCH, device_batch,
                                  free_memory_bytes, match_batch, window_bytes)
from test_phase import add_noise, realistic_pairs, stratified_shifts

torch = pytest.importorskip("torch", reason="torch (optional 'gpu' extra) is not installed")


def test_window_bytes_is_the_documented_formula():
    assert window_bytes(64, 64, 4) == BYTES_PER_PIXEL_PER_ITEM * 4 * 64 * 64 == 256 * 1024
    assert window_bytes(48, 80, 8) == 2 * window_bytes(48, 80, 4)


def test_planned_batch_respects_the_budget():
    """Random window shapes, precisions and budgets (1 window's worth to 1 GiB): the batch fits the
    budget, is the largest that does below the CPU bound, and never drops below one pair."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        shape = (int(rng.integers(8, 257)), int(rng.integers(8, 257)))
        dtype = np.float32 if rng.random() < 0.5 else np.float64
        per_pair = window_bytes(*shape, np.dtype(dtype).itemsize)
        budget = int(per_pair * 10 ** rng.uniform(-1.0, 4.0))
        cap_px = int(rng.choice([BATCH_PIXELS, 1 << 26]))
        batch = device_batch(shape, dtype, "cpu", budget_bytes=budget, cpu_max_pixels=cap_px)
        cap = max(1, cap_px // (shape[0] * shape[1]))
        assert 1 <= batch <= cap
        if budget >= per_pair:
            assert batch * per_pair <= budget
            assert batch == cap or (batch + 1) * per_pair > budget
        else:
            assert batch == 1  # a budget below one pair still runs, one pair at a time


def test_default_cpu_batch_is_bounded_by_ram_and_the_cpu_kernel_size():
    free = free_memory_bytes("cpu")
    assert free > 0
    batch = device_batch((64, 64), np.float32, "cpu")
    assert 1 <= batch <= BATCH_PIXELS // (64 * 64)
    assert batch * window_bytes(64, 64, 4) <= max(free, window_bytes(64, 64, 4))
    assert match_batch(64, "torch", 2048) == 2048 and match_batch(64, "cpu", 100) == 100
    assert MAX_DEVICE_BATCH >= 2048


def test_torch_results_do_not_depend_on_the_batch():
    """Every operation of the kernel is per pair: batches of 1, 7, 64 and the planned one give the
    same shifts within 1e-4 px and the same rejections (module docstring's tolerance)."""
    rng = np.random.default_rng(404)
    shifts = stratified_shifts(rng, 120)
    ref, mov = realistic_pairs(rng, shifts)
    a, b = add_noise(rng, ref, 30.0), add_noise(rng, mov, 30.0)
    planned = phase_correlate(a, b, backend="torch", device="cpu")
    for batch in (1, 7, 64):
        other = phase_correlate(a, b, backend="torch", device="cpu", batch=batch)
        np.testing.assert_array_equal(planned.reason, other.reason)
        ok = planned.valid
        assert ok.mean() > 0.9
        assert np.abs(planned.shift_px[ok] - other.shift_px[ok]).max() < 1e-4
        np.testing.assert_allclose(planned.score, other.score, atol=1e-5)
