"""Warnings of a stage on stderr: one line each, ``gcpcal: warning: ...``."""

from __future__ import annotations

import click

__all__ = ["echo_warnings"]


def echo_warnings(summary: dict) -> None:
    """Print the ``warnings`` of an action's summary on stderr (whatever ``--json`` or ``-q`` say).

    Parameters
    ----------
    summary : dict
        The action's summary; its ``warnings`` (list of str, optional) are printed.

    Returns
    -------
    None
    """
    for warning in summary.get("warnings") or ():
        click.echo(f"gcpcal: warning: {warning}", err=True)
