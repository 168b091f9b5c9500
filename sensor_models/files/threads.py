"""How many threads the parallel stages use, and an ordered, bounded map over a thread pool.

Phase correlation, reference chips, orthorectification and the simulator's renderers split their
work into independent blocks (batches of windows, output blocks, lines of a scene) and run the
blocks on threads: numpy's array operations, ``scipy.fft``, OpenCV and GDAL release the GIL
while they work, so the threads run on separate cores. The blocks are the same whatever the
thread count and each block's result goes to its own place, so the results do not depend on it.

The count (:func:`thread_count`): an explicit ``threads >= 1``; else the environment variable
``GCPCAL_THREADS`` (an integer >= 0); else every core this process may run on
(``os.sched_getaffinity``, which honours ``taskset`` and container CPU sets, where
``os.cpu_count`` gives the machine's). 0 means every core. One thread runs the blocks one after
the other in the calling thread.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

from sensor_models.errors import InputError

__all__ = ["BLAS_THREAD_ENVS", "THREADS_ENV", "PerThread", "available_cores", "blas_threads", "command_blas_single_threaded",
           "libraries_single_threaded", "map_ordered", "opencv_threads", "parse_threads", "thread_count"]

#: Environment variable capping the threads of every parallel stage (0 or unset: every core).
THREADS_ENV = "GCPCAL_THREADS"


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity set; ``os.cpu_count()`` where unknown), >= 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity call on this platform
        return max(1, os.cpu_count() or 1)


def parse_threads(text, *, field: str = "threads") -> int:
    """A thread count from text or a number: an integer >= 0 (0: every core).

    Parameters
    ----------
    text : str or int
        What the user gave (``--threads``, ``GCPCAL_THREADS``).
    field : str
        The option's name, for the error.

    Returns
    -------
    int
        The count, >= 0.

    Raises
    ------
    InputError
        Not an integer, or negative.
    """
    try:
        value = int(str(text).strip())
    except ValueError:
        value = -1
    if isinstance(text, bool) or value < 0 or (isinstance(text, float) and text != value):
        raise InputError(f"must be an integer >= 0 (0: every core), got {text!r}", field=field)
    return value


def thread_count(threads: int | None = None) -> int:
    """Threads to use: ``threads`` when >= 1, else ``GCPCAL_THREADS`` when set and >= 1, else every core.

    Parameters
    ----------
    threads : int or None
        An explicit count; None or 0 for the default.

    Returns
    -------
    int
        >= 1.

    Raises
    ------
    InputError
        ``threads`` negative or not an integer, or ``GCPCAL_THREADS`` not an integer >= 0.
    """
    if threads is not None:
        threads = parse_threads(threads)
        if threads >= 1:
            return threads
    env = os.environ.get(THREADS_ENV, "").strip()
    if env:
        capped = parse_threads(env, field=THREADS_ENV)
        if capped >= 1:
            return capped
    return available_cores()


def map_ordered(function, items, threads: int, *, in_flight: int | None = None):
    """``function(item)`` for every item, results yielded in the items' order, on ``threads`` threads.

    At most ``in_flight`` items (default ``2 * threads``) are submitted and not yet yielded, so
    the memory is bounded by that many blocks' results whatever the number of items. With one
    thread the items run one after the other in the calling thread (no pool).

    Parameters
    ----------
    function : callable(item) -> object
        The work of one block; must not depend on which thread runs it.
    items : iterable
        The blocks.
    threads : int
        Worker threads, >= 1.
    in_flight : int, optional
        Items submitted ahead of the one being yielded, >= ``threads``.

    Yields
    ------
    object
        ``function(item)``, in the order of ``items``. An exception in a block is raised here, at
        that block's turn (the pool then stops taking new blocks).
    """
    if threads <= 1:
        for item in items:
            yield function(item)
        return
    limit = max(threads, in_flight or 2 * threads)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = deque()
        try:
            for item in items:
                pending.append(pool.submit(function, item))
                if len(pending) >= limit:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:
                future.cancel()


class PerThread:
    """One object per thread (a GDAL dataset is not thread-safe): made by ``factory()`` on a thread's
    first :meth:`get`; :meth:`close` closes every one made.

    Parameters
    ----------
    factory : callable() -> object with close()
        Opens a new object (e.g. ``lambda: rasterio.open(path)``).
    first : object, optional
        The calling thread's object, already open.
    """

    def __init__(self, factory, first=None):
        self._factory = factory
        self._local = threading.local()
        self._lock = threading.Lock()
        self._made = []
        if first is not None:
            self._local.value = first
            self._made.append(first)

    def get(self):
        """This thread's object (opened now on the thread's first call)."""
        value = getattr(self._local, "value", None)
        if value is None:
            value = self._local.value = self._factory()
            with self._lock:
                self._made.append(value)
        return value

    def close(self) -> None:
        """Close every object made (the threads that used them have finished)."""
        with self._lock:
            made, self._made = self._made, []
        for value in made:
            value.close()


class _ProcessSetting:
    """A process-wide library setting held while any thread is inside one of its blocks.

    The first block to enter applies it, the last to leave restores what was there before: blocks
    entered by several threads at once, or nested, neither restore early nor leave the setting
    behind. The first entrant's value holds until the last leaves (every caller asks for 1).
    ``apply(n)`` sets the value and returns the function that restores the previous one.
    """

    def __init__(self, apply):
        self._apply, self._lock, self._depth, self._restore = apply, threading.Lock(), 0, None

    @contextmanager
    def __call__(self, n: int):
        with self._lock:
            if self._depth == 0:
                self._restore = self._apply(int(n))
            self._depth += 1
        try:
            yield
        finally:
            with self._lock:
                self._depth -= 1
                if self._depth == 0:
                    restore, self._restore = self._restore, None
                    restore()


def _set_opencv_threads(n: int):
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(n)
    return lambda: cv2.setNumThreads(before)


_controller_cache: list = [None, -1]  # [ThreadpoolController, len(sys.modules) when it scanned]


def _set_blas_threads(n: int):
    import sys

    from threadpoolctl import ThreadpoolController

    # A controller scans the shared libraries loaded (4 ms: more than a small solve it guards).
    # BLAS libraries arrive with the extension modules that link them (NumPy's, SciPy's), so the
    # scan is redone only when a module was imported since the last one.
    if _controller_cache[1] != len(sys.modules):
        _controller_cache[:] = [ThreadpoolController(), len(sys.modules)]
    return _controller_cache[0].limit(limits=n, user_api="blas").restore_original_limits


#: OpenCV's own thread count set to ``n`` inside the block, restored after (a process-wide
#: setting, :class:`_ProcessSetting`). Stages that already run blocks on ``threads`` threads set
#: it to 1, so that each OpenCV call does not start another ``threads`` workers (``threads**2``
#: busy threads on ``threads`` cores).
opencv_threads = _ProcessSetting(_set_opencv_threads)

#: The BLAS libraries' thread count (OpenBLAS, MKL, BLIS) set to ``n`` inside the block, restored
#: after, through ``threadpoolctl`` (a process-wide setting, :class:`_ProcessSetting`). The phase
#: correlation's matrix-vector products are small (a few hundred rows of a few thousand): split
#: over OpenBLAS's threads they cost more in the threads' busy waiting than they gain (measured in
#: docs/speed.md, "Every core"), and stages that run blocks on threads of their own need one BLAS
#: thread per block.
blas_threads = _ProcessSetting(_set_blas_threads)


@contextmanager
def libraries_single_threaded():
    """OpenCV and BLAS on one thread each inside the block (process-wide settings, restored after).

    For the stages that run their own blocks on threads: the blocks are the parallelism, a
    library's own threads on top would only compete for the same cores (measured: OpenBLAS's
    waiting threads tripled the orthorectification's CPU time on 2 threads), and one thread per
    call gives the same numbers whatever the count.
    """
    with opencv_threads(1), blas_threads(1):
        yield


#: Environment variables naming the BLAS libraries' thread counts, read when a library loads.
BLAS_THREAD_ENVS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


@contextmanager
def command_blas_single_threaded():
    """BLAS on one thread for a whole gcpcal command, unless the user chose a count.

    gcpcal's matrix products are small (normal equations of a few hundred unknowns, per-pair sums
    of a few thousand terms) and its stages run their blocks on threads of their own. OpenBLAS
    splits such products over its threads anyway, and the threads then busy-wait for the next
    one: on 2 cores ``gcpcal demo`` used 25.9 CPU-s for 18.0 s of wall time with OpenBLAS's
    default count and 18.0 CPU-s for 17.7 s on one thread, the same summary to the last digit
    (docs/speed.md, "Every core"). Inside the block the BLAS libraries already loaded run one
    thread (:data:`blas_threads`) and the ``*_NUM_THREADS`` variables of
    :data:`BLAS_THREAD_ENVS` say 1, for libraries loaded later and for the processes started
    meanwhile (Dask's local workers); both are restored after. When any of those variables is
    set already, nothing changes.
    """
    if any(name in os.environ for name in BLAS_THREAD_ENVS):
        yield
        return
    os.environ.update(dict.fromkeys(BLAS_THREAD_ENVS, "1"))
    try:
        with blas_threads(1):
            yield
    finally:
        for name in BLAS_THREAD_ENVS:
            os.environ.pop(name, None)
