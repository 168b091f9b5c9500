"""The Dask cluster that runs many scenes: a LocalCluster, or a scheduler's address.

``gcpcal validate`` (:mod:`calibrate.batch`) and ``gcpcal campaign``
(:mod:`calibrate.pipelines.campaign`) run one Dask task per scene. Without an address they start
a :class:`distributed.LocalCluster` of single-threaded worker processes on this machine
(:func:`connect`); with one (``tcp://host:8786``: a ``dask scheduler`` started by hand, or the
scheduler of a ``dask_jobqueue`` cluster on an HPC batch system) they submit to it, and its
workers must read the scenes' files at the same paths (a shared filesystem).

Workers started by ``gcpcal`` ignore Ctrl-C (:mod:`calibrate.actions._worker_signals`, preloaded
by the CLI for the commands of ``calibrate.cli._CLUSTER_COMMANDS``): the ``gcpcal`` process
handles it and closes the cluster.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os

from sensor_models.errors import InputError

__all__ = ["available_cores", "check_scheduler_address", "connect", "dask_log_level", "worker_count"]


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform says, else the count).

    Returns
    -------
    int
        At least 1.
    """
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def check_scheduler_address(address: str) -> str:
    """Refuse a Dask scheduler address that cannot be parsed, before any connection.

    Parameters
    ----------
    address : str
        ``scheme://host:port`` or ``host:port`` (TCP).

    Returns
    -------
    str
        ``address``, unchanged.

    Raises
    ------
    InputError
        Naming the address, when its scheme is unknown or its host/port cannot be parsed.
    """
    from distributed.comm import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme in ("tcp", "tls"):
            parse_host_port(location)
    except ValueError as exc:
        raise InputError(f"not a Dask scheduler address ({exc})", path=str(address), field="scheduler") from None
    return address


@contextlib.contextmanager
def dask_log_level():
    """Keep Dask's INFO chatter (scheduler start, workers joining) out of a non-verbose run."""
    importlib.import_module("distributed")  # importing it configures its logger: do that first

    logger = logging.getLogger("distributed")
    old = logger.level
    if logging.getLogger().getEffectiveLevel() > logging.INFO:
        logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(old)


def connect(scheduler, workers: int, timeout_s: float, *, processes: bool = True):
    """A Dask client: on a new LocalCluster (``scheduler`` None) or at the given address.

    The LocalCluster's HTTP server takes a free port (``:0``), so concurrent runs never
    compete for the dashboard's default port.

    Parameters
    ----------
    scheduler : str or None
        Scheduler address (``tcp://host:8786``); None: a new LocalCluster.
    workers : int
        Workers of the LocalCluster, one thread each.
    timeout_s : float
        Seconds allowed to reach ``scheduler``.
    processes : bool
        LocalCluster workers are processes (True) or threads of this process (False).

    Returns
    -------
    client : distributed.Client
    cluster : distributed.LocalCluster or None
        The cluster started here (the caller closes it), None at an address.

    Raises
    ------
    InputError
        ``scheduler`` cannot be reached within ``timeout_s``.
    """
    from distributed import Client, LocalCluster

    if scheduler is None:
        # workers log at CRITICAL only: a task's error reaches the client as its exception, and
        # on Ctrl-C a loaded machine can stop the scheduler before a worker's heartbeat, which
        # the worker would log at ERROR with a traceback (tests/test_bad_inputs.py, validate)
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=bool(processes),
                               dashboard_address=":0", silence_logs=logging.CRITICAL)
        try:
            return Client(cluster), cluster
        except BaseException:
            cluster.close()
            raise
    try:
        return Client(str(scheduler), timeout=f"{float(timeout_s)}s"), None
    except (OSError, TimeoutError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot reach the Dask scheduler within {timeout_s:g} s ({why})", path=str(scheduler),
                         field="scheduler") from None


def worker_count(client, cluster, scheduler, timeout_s: float) -> int:
    """Workers the client can use; at an address, waits up to ``timeout_s`` for the first one.

    Parameters
    ----------
    client : distributed.Client
    cluster : distributed.LocalCluster or None
        As :func:`connect` returned.
    scheduler : str or None
        The address (for the message).
    timeout_s : float

    Returns
    -------
    int

    Raises
    ------
    InputError
        No worker joined the scheduler within ``timeout_s``.
    """
    if cluster is not None:
        return len(cluster.workers)
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except TimeoutError:
        raise InputError(f"the Dask scheduler has no worker (none joined within {timeout_s:g} s)",
                         path=str(scheduler), field="scheduler") from None
    return len(client.scheduler_info(n_workers=-1).get("workers", {}))
