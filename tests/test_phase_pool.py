"""Tests of gcpmatch.phase_pool: kernels kept between phase_correlate calls change no number,
stay within their byte budget and are dropped on release; the CPU path's input checks run per
batch and BLAS stays on one thread for the whole call."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gcpmatch.phase import phase_correlate
from gcpmatch.phase_numpy import NumpyKernel
from gcpmatch.phase_plan import make_plan
from gcpmatch.phase_pool import KERNEL_POOL, KernelPool, kernel_bytes, release_kernels
from sensor_models.errors import InputError

FIELDS = ("shift_row_px", "shift_col_px", "score", "peak_ratio", "valid", "reason")


def _pairs(n, size=32, seed=0):
    """``n`` pairs of smooth random texture, the moving one shifted by whole and fractional px."""
    rng = np.random.default_rng(seed)
    field = np.cumsum(np.cumsum(rng.normal(size=(n, size + 8, size + 8)), axis=1), axis=2)
    ref = field[:, 4:4 + size, 4:4 + size]
    mov = 0.6 * field[:, 3:3 + size, 5:5 + size] + 0.4 * field[:, 4:4 + size, 5:5 + size]
    return ref.astype(np.float32), mov.astype(np.float32)


def _same(a, b):
    return all(np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True) for f in FIELDS)


def test_pooled_kernels_give_the_numbers_of_fresh_ones():
    release_kernels()
    ref, mov = _pairs(40)
    fresh = phase_correlate(ref, mov, workers=1, batch=16)
    assert KERNEL_POOL.idle_bytes > 0  # the call's kernel was kept
    # a kept kernel that last ran other pairs, a smaller batch and a larger one
    other_ref, other_mov = _pairs(7, seed=3)
    phase_correlate(other_ref[::-1].copy(), other_mov, workers=1, batch=5)
    again = phase_correlate(ref, mov, workers=1, batch=16)
    assert _same(fresh, again)
    assert np.isfinite(fresh.shift_row_px).all() and fresh.valid.mean() > 0.9


def test_pooled_kernel_is_reused_not_rebuilt(monkeypatch):
    release_kernels()
    ref, mov = _pairs(8)
    phase_correlate(ref, mov, workers=1)
    built = []
    original = NumpyKernel.__init__

    def counting_init(self, *args, **kwargs):
        built.append(1)
        original(self, *args, **kwargs)

    monkeypatch.setattr(NumpyKernel, "__init__", counting_init)
    phase_correlate(ref, mov, workers=1)
    assert built == []
    phase_correlate(ref, mov, workers=1, window="tukey")  # another plan: a kernel of its own
    assert len(built) == 2  # itself and its half-resolution kernel
    assert release_kernels() > 0 and KERNEL_POOL.idle_bytes == 0


def test_array_windows_are_not_pooled():
    release_kernels()
    ref, mov = _pairs(6)
    phase_correlate(ref, mov, workers=1, window=np.ones((32, 32)), follow=0)
    assert KERNEL_POOL.idle_bytes == 0


def test_budget_bounds_the_idle_kernels():
    plan = make_plan((32, 32))
    kernels = []
    ref, mov = _pairs(8)
    for _ in range(3):
        kernel = NumpyKernel(plan, workers=1)
        kernel(ref, mov)
        kernels.append(kernel)
    size = kernel_bytes(kernels[0])
    assert size > 0
    pool = KernelPool(budget_bytes=2 * size)
    for kernel in kernels:
        pool.give_back("k", kernel)
    assert pool.idle_bytes == 2 * size  # the third did not fit
    taken = pool.take("k", lambda: None)
    assert taken is kernels[1] and pool.idle_bytes == size
    assert pool.take("other", lambda: "built") == "built"
    assert pool.release() == size and pool.idle_bytes == 0
    assert KernelPool(budget_bytes=0).take("k", lambda: "built") == "built"


def test_non_finite_window_in_a_later_batch_is_named():
    ref, mov = _pairs(20)
    ref[13, 2, 2] = np.inf
    with pytest.raises(InputError, match="pair 13") as info:
        phase_correlate(ref, mov, workers=2, batch=4)
    assert info.value.field == "reference" and "pairs 12-15" in str(info.value)


def test_torch_path_checks_the_whole_arrays_first():
    pytest.importorskip("torch")
    ref, mov = _pairs(20)
    mov[17, 0, 5] = np.nan
    with pytest.raises(InputError, match="pair 17") as info:
        phase_correlate(ref, mov, backend="torch", batch=4)
    assert info.value.field == "moving" and "pairs 0-19" in str(info.value)


def test_blas_stays_on_one_thread_for_the_whole_call():
    """OpenBLAS's threads, once woken by a product, spin for a while: a call that woke them used
    about twice its wall time in CPU on 2 cores (docs/speed.md, "Phase correlation")."""
    threadpoolctl = pytest.importorskip("threadpoolctl")
    blas = [i for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    if not blas or max(i["num_threads"] for i in blas) < 2:
        pytest.skip("BLAS runs one thread here: nothing to wake")
    ref, mov = _pairs(2048, seed=1)
    phase_correlate(ref, mov, workers=1)
    ratios = []
    for _ in range(3):
        w0, c0 = time.perf_counter(), time.process_time()
        phase_correlate(ref, mov, workers=1)
        ratios.append((time.process_time() - c0) / (time.perf_counter() - w0))
    assert min(ratios) < 1.3, ratios


def test_concurrent_callers_share_the_pool_and_get_their_own_numbers():
    from concurrent.futures import ThreadPoolExecutor

    release_kernels()
    jobs = [_pairs(24, seed=s) for s in range(8)]
    alone = [phase_correlate(r, m, workers=1, batch=8) for r, m in jobs]
    release_kernels()
    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(lambda job: phase_correlate(*job, workers=2, batch=8), jobs * 3))
    assert all(_same(a, b) for a, b in zip(alone * 3, together))
    assert 0 < KERNEL_POOL.idle_bytes <= KERNEL_POOL.budget_bytes
    release_kernels()
