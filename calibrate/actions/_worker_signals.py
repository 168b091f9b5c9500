"""Dask worker preload of validate and campaign: worker processes ignore Ctrl-C and a closed terminal.

A Ctrl-C (SIGINT) or a closed terminal (SIGHUP) reaches every process of the foreground group,
the Dask workers too, and each would print a traceback. The workers ignore both instead; the
``gcpcal`` process handles them, closes the cluster (which ends its workers) and prints one
line. A worker whose ``gcpcal`` process was killed outright ends too: Dask's worker processes
exit when the pipe from their parent closes.
"""

from __future__ import annotations

import signal
import threading

__all__ = ["dask_setup"]


def dask_setup(worker) -> None:
    """Make this worker process ignore SIGINT and SIGHUP (called by Dask when the worker starts).

    Parameters
    ----------
    worker : distributed.Worker
        The starting worker (unused).
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if hasattr(signal, "SIGHUP"):
            signal.signal(signal.SIGHUP, signal.SIG_IGN)
