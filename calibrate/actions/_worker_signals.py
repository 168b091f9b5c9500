"""Dask worker preload of the validate stage: worker processes ignore Ctrl-C.

A Ctrl-C in a terminal reaches every process of the foreground group, the Dask workers too, and
each would print a ``KeyboardInterrupt`` traceback. The workers ignore it instead; the ``gcpcal``
process handles it, closes the cluster (which ends its workers) and prints one line.
"""

from __future__ import annotations

import signal
import threading

__all__ = ["dask_setup"]


def dask_setup(worker) -> None:
    """Make this worker process ignore SIGINT (called by Dask when the worker starts).

    Parameters
    ----------
    worker : distributed.Worker
        The starting worker (unused).
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
