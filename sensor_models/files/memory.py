"""The memory this machine can give a process now, for the stages that size their work by it."""

from __future__ import annotations

import os

__all__ = ["available_memory_bytes"]


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
