"""Stage action of ``gcpcal validate``: a calibration checked on validation scenes, one Dask task each.

The work is :func:`calibrate.batch.validate_sites` (which writes ``validation.csv``,
``validation.json`` and ``validation.html`` into the output folder); this action reads the sites
file, checks the scheduler address the user gave and hands the sites over.
"""

from __future__ import annotations

from calibrate.actions._io import final_paths, staged_folder
from sensor_models.errors import InputError

__all__ = ["check_scheduler_address", "validate_calibration"]


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


def validate_calibration(sites_path, calibration, out_dir, *, scheduler=None, workers: int = 2, spacing_px: int = 32,
                         timeout_s: float = 10.0, progress=None) -> dict:
    """Validate ``calibration`` on every scene of the sites file.

    Parameters
    ----------
    sites_path : str or Path
        Sites file (YAML or CSV: name, scene, dom, dem; :func:`calibrate.batch.read_sites`).
    calibration : str or Path
        Calibrated ``manifest.json`` or the folder holding it.
    out_dir : str or Path
        Output folder.
    scheduler : str, optional
        Dask scheduler address; default: a local cluster of ``workers`` processes.
    workers : int
        Worker processes of the local cluster.
    spacing_px : int
        Matching window spacing, pixels.
    timeout_s : float
        Seconds allowed to connect to ``scheduler``.
    progress : callable(done, total, row), optional
        Called once with ``(0, n_sites, None)`` before the work starts, then as each scene
        finishes.

    Returns
    -------
    dict
        The summary of :func:`calibrate.batch.validate_sites` with ``sites_file`` and ``rows``
        (one per scene; a failed scene says why).
    """
    from pathlib import Path

    from calibrate.batch import read_sites, validate_sites

    if scheduler is not None:
        check_scheduler_address(scheduler)
    sites = read_sites(sites_path)
    with staged_folder(out_dir, ".validate-", inputs=[sites_path, calibration]) as stage:
        if progress is not None:
            progress(0, len(sites), None)
        rows, summary = validate_sites(sites, calibration, stage, scheduler=scheduler, workers=workers,
                                       progress=progress, spacing_px=spacing_px, timeout_s=timeout_s)
    rows, summary = final_paths(rows, stage, out_dir), final_paths(summary, stage, out_dir)
    summary["sites_file"] = str(sites_path)
    return {**summary, "rows": rows}
