"""How many window pairs the torch phase kernel takes at once: sized from the device's free memory.

The torch backend of :func:`gcpmatch.phase.phase_correlate` holds, for each pair of ``H x W``
windows in the working precision of ``s`` bytes per real number (4 for float32):

* the two windows on the device: ``2 s H W``;
* the reference's half spectrum (kept for every pass) and the moving window's: ``2 x 2 s H W``
  (``H (W/2 + 1)`` complex numbers of ``2 s`` bytes each, rounded up to ``H W``);
* the cross-power and its reweighted copy while the normalization runs (``2 x 2 s H W``), their
  magnitude, the floored magnitude and the factor (``3 x s H W / 2``), and the apodized window
  being transformed with one temporary (``2 s H W``).

That is at most about ``13.5 s H W`` bytes at the peak, before the FFT library's work area. The
planner budgets :data:`BYTES_PER_PIXEL_PER_ITEM` ``= 16`` times ``s`` per pixel and pair
(``16 s H W``: 256 KiB for a 64 x 64 px pair in float32), which leaves room for a work area as
large as a spectrum. Measured on the CPU (torch, peak resident memory over 1024 and 4096 pairs
of 64 x 64 px in float32, the inputs already resident): 14 to 17 bytes per pixel with the
half-resolution first pass, 18 to 21 with the full one, under the budgeted 64 (``16 x 4``);
``bench/gpu_check.py`` reads the peak on a CUDA device (``torch.cuda.max_memory_allocated``)
and reports it beside the budget.

The batch is then ``floor(fraction x free / window_bytes)``, at least 1 and at most
``max_batch``:

* CUDA: ``free`` = the driver's free memory (``torch.cuda.mem_get_info``) plus what torch's
  caching allocator holds unused; ``fraction`` = :data:`DEVICE_FRACTION`, ``max_batch`` =
  :data:`MAX_DEVICE_BATCH` (past a few thousand pairs the kernel launches are amortized);
* CPU: ``free`` = the memory the kernel reports available (``MemAvailable`` of
  ``/proc/meminfo``, else the physical pages free); the batch is also bounded by the CPU
  kernel's measured best size, :data:`BATCH_PIXELS` worth of windows (a batch
  that fits the caches is faster there: 256 pairs of 64 x 64 px).

The batch changes how many pairs share one call, not what is computed for a pair: every
operation of the kernel is per pair (no sum runs across pairs), so the shifts agree across batch
sizes to the last bits the FFT library's plan for a batch size may change
(``tests/test_phase.py`` bounds the difference at 1e-4 px). Measured: batches of 64, 100, 256
and 1 024 pairs give the same bits on 6 000 pairs; the FFT library transforms a few pairs at
once in vector lanes and the last ``n mod L`` pairs of a call one at a time (``L`` lanes: 4 on
the development machine; 16 is a multiple of the widths in use), so a pair that falls in that
remainder of one split of the pairs and not of another can move by ~3e-8 px.
"""

from __future__ import annotations


import numpy as np

__all__ = ["BATCH_PIXELS", "BYTES_PER_PIXEL_PER_ITEM", "DEVICE_FRACTION", "MAX_DEVICE_BATCH", "THREADS_PER_BATCH",
           "cpu_batch", "device_batch", "free_memory_bytes", "match_batch", "window_bytes"]

#: Default batch of the CPU backend: 256 windows of 64 x 64 px (~20 MB of scratch). Fewer Python
#: calls per pair than 128 (measured, ``first_pass="half"``, 1 thread: 72.0 % of the FFT floor
#: against 66.4 %); the floor itself is fastest at 32 pairs, where the kernel's per-call overhead
#: dominates.
BATCH_PIXELS = 1 << 20
#: Threads per :data:`BATCH_PIXELS` of the CPU backend's default batch beyond four threads: the
#: batch grows with the threads (1 024 pairs of 64 x 64 px at 16), so that each thread spends
#: less of its time in the kernel's small per-call steps, which hold the interpreter lock.
#: Measured on a 16-core CPU (``bench/bench_cores.py``, 60 000 pairs, one run each, docs/speed.md
#: "Every core"): at 16 threads 64 / 256 / 1 024 pairs a batch gave 14.6 k / 37.5 k / 65.2 k
#: pairs/s; at one thread 256 is the fastest (15.3 k against 10.0 k at 1 024: the caches).
THREADS_PER_BATCH = 4
#: Budgeted device bytes per pixel of one window pair, per byte of the working real type.
BYTES_PER_PIXEL_PER_ITEM = 16
#: Share of the free memory a batch may take (the rest: the caller's arrays, other processes).
DEVICE_FRACTION = 0.5
#: Most pairs per batch on a CUDA device.
MAX_DEVICE_BATCH = 65536


def cpu_batch(height: int, width: int, threads: int) -> int:
    """Default pairs per batch of the CPU backend for ``threads`` threads.

    ``BATCH_PIXELS * max(1, threads // THREADS_PER_BATCH)`` pixels worth of windows, rounded
    down to a multiple of 16 pairs when that leaves any (a pair's numbers do not depend on the
    batch while batches are multiples of the FFT library's vector width: module docstring).

    Parameters
    ----------
    height, width : int
        Window size, pixels.
    threads : int
        Threads the batches run on.

    Returns
    -------
    int
        Pairs per batch, >= 1.
    """
    pairs = BATCH_PIXELS * max(1, int(threads) // THREADS_PER_BATCH) // (height * width)
    return max(1, pairs - pairs % 16 if pairs >= 16 else pairs)


def window_bytes(height: int, width: int, itemsize: int) -> int:
    """Budgeted device memory of one window pair in the torch kernel, bytes.

    Parameters
    ----------
    height, width : int
        Window size, pixels.
    itemsize : int
        Bytes per real number of the working precision (4 for float32, 8 for float64).

    Returns
    -------
    int
        ``BYTES_PER_PIXEL_PER_ITEM * itemsize * height * width``.
    """
    return int(BYTES_PER_PIXEL_PER_ITEM * itemsize * height * width)


def free_memory_bytes(device) -> int:
    """Free memory of a torch device, bytes (module docstring).

    Parameters
    ----------
    device : str or torch.device
        ``"cpu"``, ``"cuda"``, ``"cuda:1"``, ...

    Returns
    -------
    int
        CUDA: driver-free memory plus torch's cached but unused blocks; CPU: the memory
        available to new allocations.
    """
    import torch

    device = torch.device(device)
    if device.type == "cuda":
        free, _total = torch.cuda.mem_get_info(device)
        cached = torch.cuda.memory_reserved(device) - torch.cuda.memory_allocated(device)
        return int(free + max(cached, 0))
    from sensor_models.files.memory import available_memory_bytes

    free = available_memory_bytes()
    return 0 if free is None else free


def device_batch(shape: tuple[int, int], dtype, device, *, budget_bytes: int | None = None,
                 cpu_max_pixels: int | None = None) -> int:
    """Pairs of ``shape`` windows per torch batch on ``device`` (module docstring).

    Parameters
    ----------
    shape : (int, int)
        Window ``(height, width)``, pixels.
    dtype : numpy dtype
        Working precision (float32 or float64).
    device : str or torch.device
        Torch device.
    budget_bytes : int, optional
        Memory the batch may take, bytes; default ``DEVICE_FRACTION`` of
        :func:`free_memory_bytes`.
    cpu_max_pixels : int, optional
        On the CPU, the most pixels per batch (default :data:`BATCH_PIXELS`).

    Returns
    -------
    int
        ``max(1, min(budget // window_bytes, cap))``, ``cap`` = ``MAX_DEVICE_BATCH`` on CUDA, the
        CPU bound on the CPU.
    """
    import torch

    height, width = shape
    device = torch.device(device)
    if budget_bytes is None:
        budget_bytes = int(DEVICE_FRACTION * free_memory_bytes(device))
    per_pair = window_bytes(height, width, np.dtype(dtype).itemsize)
    if device.type == "cuda":
        cap = MAX_DEVICE_BATCH
    else:
        cap = max(1, (BATCH_PIXELS if cpu_max_pixels is None else cpu_max_pixels) // (height * width))
    return int(max(1, min(int(budget_bytes) // per_pair, cap)))


def match_batch(window_px: int, backend: str, batch: int) -> int:
    """Windows per batch of the matcher (:func:`gcpmatch.extract.extract_gcps`).

    The CPU and torch-on-CPU backends take ``batch`` (:class:`gcpmatch.options.MatchOptions`).
    On CUDA (``backend="gpu"``) a batch of that size would leave the device mostly idle, so the
    matcher gathers at least what :func:`device_batch` gives for float32 windows within
    ``DEVICE_FRACTION`` of the smaller of the device's and the host's free memory (the host holds
    the gathered windows of a batch, and the per-pair budget bounds them too).

    Parameters
    ----------
    window_px : int
        Window side, pixels.
    backend : {"cpu", "torch", "gpu"}
        The matcher's backend.
    batch : int
        The options' batch, windows.

    Returns
    -------
    int
        Windows per batch, >= ``batch``.
    """
    if backend != "gpu":
        return int(batch)
    free = min(free_memory_bytes("cuda"), free_memory_bytes("cpu"))
    planned = device_batch((window_px, window_px), np.float32, "cuda", budget_bytes=int(DEVICE_FRACTION * free))
    return int(max(batch, planned))
