"""Idle :class:`~gcpmatch.phase_numpy.NumpyKernel` objects kept between calls of
:func:`gcpmatch.phase.phase_correlate`.

A kernel's constants (grid tables, window spectra) take about 1 ms to build and its scratch
buffers (about 8 MB for a batch of 256 pairs of 64 x 64 px) are fresh pages the first time a
batch writes them: on a call of 2 048 such pairs with a new kernel the page faults alone cost
5-10 us a pair of system time (docs/speed.md, "Phase kernel against the FFT floor"). The match
calls ``phase_correlate`` once per task of a few hundred windows; kept here, a kernel is built
and its pages touched once per window shape and thread, not once per call.

Kernels are keyed by everything their plan and thread count depend on; a kernel handed out is
used by one thread at a time and put back after. The idle kernels' scratch stays within
``KERNEL_POOL_BYTES``; :func:`release_kernels` drops them all (the match does after each CCD's
window stage, before handing freed memory back to the system). A kernel's numbers do not depend
on the batches it ran before: every buffer is written before it is read
(``tests/test_phase_pool.py``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable

from gcpmatch.phase_numpy import NumpyKernel

__all__ = ["KERNEL_POOL_BYTES", "KernelPool", "KERNEL_POOL", "release_kernels"]

#: Most scratch bytes the idle kernels keep between calls (a kernel put back beyond it is
#: dropped): 16 kernels of a 256-pair batch of 64 x 64 px windows, one per thread of a 16-thread
#: window stage.
KERNEL_POOL_BYTES = 128 << 20


def kernel_bytes(kernel: NumpyKernel) -> int:
    """Scratch bytes a kernel keeps (its buffers and its half-resolution kernel's)."""
    total = sum(b.nbytes for b in kernel._buffers.values())
    return total + (0 if kernel.coarse is None else kernel_bytes(kernel.coarse))


class KernelPool:
    """Idle kernels by key, within a byte budget; safe to use from several threads.

    Parameters
    ----------
    budget_bytes : int
        Most scratch bytes kept by the idle kernels (:func:`kernel_bytes`).
    """

    def __init__(self, budget_bytes: int = KERNEL_POOL_BYTES):
        self.budget_bytes = int(budget_bytes)
        self._lock = threading.Lock()
        self._idle: dict[Hashable, list[NumpyKernel]] = {}
        self._bytes = 0

    def take(self, key: Hashable, build: Callable[[], NumpyKernel]) -> NumpyKernel:
        """An idle kernel of ``key``, or ``build()`` when none is."""
        with self._lock:
            idle = self._idle.get(key)
            if idle:
                kernel = idle.pop()
                self._bytes -= kernel_bytes(kernel)
                return kernel
        return build()

    def give_back(self, key: Hashable, kernel: NumpyKernel) -> None:
        """Keep ``kernel`` for the next caller of ``key`` if the budget allows, else drop it."""
        size = kernel_bytes(kernel)
        with self._lock:
            if self._bytes + size > self.budget_bytes:
                return
            self._idle.setdefault(key, []).append(kernel)
            self._bytes += size

    def release(self) -> int:
        """Drop every idle kernel; returns the scratch bytes they held."""
        with self._lock:
            freed, self._bytes, self._idle = self._bytes, 0, {}
        return freed

    @property
    def idle_bytes(self) -> int:
        """Scratch bytes held by the idle kernels now."""
        return self._bytes


#: The process's pool, used by :func:`gcpmatch.phase.phase_correlate` on the CPU backend.
KERNEL_POOL = KernelPool()


def release_kernels() -> int:
    """Drop the idle kernels of :data:`KERNEL_POOL`; returns the scratch bytes they held."""
    return KERNEL_POOL.release()
