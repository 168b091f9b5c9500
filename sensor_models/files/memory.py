"""The memory this machine can give a process now, for the stages that size their work by it,
the freed heap a process hands back between its stages, and bands of lines that keep a pass's
temporaries small.

glibc's allocator keeps the memory a thread frees in that thread's arena (up to eight arenas a
core) and gives it back to the system only from the top of a heap; arrays of up to 32 MiB come
from those arenas once a larger one was freed (the dynamic mmap threshold). A stage that ran on
many threads therefore leaves its scratch resident after it returns, and the next stage adds its
own on top. :func:`release_free_heap` asks glibc to return every free page of every arena
(``malloc_trim(0)``, glibc >= 2.8; Linux ``madvise(MADV_DONTNEED)`` underneath): the match calls
it between its stages. Measured on the full seed-003 geometry's match with 16 threads
(docs/memory.md, "With many threads"): the resident size after a stage fell by 0.3-0.8 GB.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os

__all__ = ["available_memory_bytes", "line_bands", "release_free_heap"]


def available_memory_bytes() -> int | None:
    """The memory the system can give without swapping.

    Linux's estimate (``MemAvailable`` of ``/proc/meminfo``: free pages plus the caches it can
    drop), else the physical pages free (``sysconf``), else None.

    Returns
    -------
    int or None
        Bytes; None where the system says neither.
    """
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None where the C library has none (musl, macOS, Windows).

    On POSIX the process's own symbols are searched first (``dlopen(NULL)``: libc is loaded, and
    no ``ldconfig`` runs); elsewhere the C library is looked up by name."""
    try:
        libc = ctypes.CDLL(None) if os.name == "posix" else ctypes.CDLL(ctypes.util.find_library("c"))
        trim = libc.malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Return the allocator's free pages to the system (glibc's ``malloc_trim(0)``; module docstring).

    Nothing live moves and no value changes; the pages are faulted in again when used.

    Returns
    -------
    bool
        True where pages were returned, False where none were or the C library cannot.
    """
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False


def line_bands(n_rows: int, n_cols: int, band_px: int, multiple: int = 1) -> list[slice]:
    """Slices of whole lines, about ``band_px`` pixels each, covering ``n_rows`` lines of ``n_cols``.

    A pass over a large image band by band keeps its temporaries at a band's size: fresh
    full-size arrays cost page faults (docs/speed.md, "Coarse stage").

    Parameters
    ----------
    n_rows, n_cols : int
        Image size, pixels.
    band_px : int
        Pixels wanted per band (at least ``multiple`` lines a band).
    multiple : int
        Every band but the last starts and ends on a multiple of this many lines (blocks of a
        reduction must not straddle two bands).

    Returns
    -------
    list of slice
        Consecutive line ranges from 0 to ``n_rows``.
    """
    step = multiple * max(1, int(band_px) // (multiple * max(1, int(n_cols))))
    return [slice(r0, min(n_rows, r0 + step)) for r0 in range(0, n_rows, step)]
