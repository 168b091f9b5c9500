"""Options shared by several ``gcpcal`` commands, and the small helpers every command uses.

Stack a list of options on a command with :func:`add_options`; defaults that mirror an option
value of :mod:`calibrate.config` are read from there.
"""

from __future__ import annotations

import json

import click
import numpy as np

from calibrate._json import json_default
from sensor_models.errors import InputError

__all__ = ["add_options", "dem_options", "echo_json", "echo_warnings", "float_list", "json_option", "out_dir_option",
           "progress_printer", "quiet_of", "verbosity_options"]

#: ``--dem``, ``--dem-datum``, ``--geoid`` (keywords ``dem_path``, ``dem_datum``, ``geoid``).
dem_options = [
    click.option("--dem", "dem_path", type=click.Path(dir_okay=False), help="DEM raster (any CRS rasterio reads)."),
    click.option(
        "--dem-datum",
        type=click.Choice(["ellipsoid", "egm96"]),
        default=None,
        help="Vertical datum of the DEM heights when the file does not declare it.",
    ),
    click.option("--geoid", type=click.Path(dir_okay=False), help="Geoid grid (e.g. egm96_15.gtx) for egm96 heights."),
]

#: ``-v/--verbose`` (count) and ``-q/--quiet`` of the group.
verbosity_options = [
    click.option("-v", "--verbose", count=True, help="More log output (repeatable); -v shows the traceback of an "
                                                     "internal error, -vv of any error."),
    click.option("-q", "--quiet", is_flag=True, help="Only errors."),
]

#: ``--json`` (keyword ``as_json``).
json_option = click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")


def out_dir_option(required: bool = True, default=None, help: str = "Output folder."):
    """The ``--out`` option of a command that writes a folder (keyword ``out_dir``).

    Parameters
    ----------
    required : bool
        Whether ``--out`` must be given.
    default : str, optional
        Default folder when not required.
    help : str
        Help text.

    Returns
    -------
    callable
        The click decorator.
    """
    extra = {} if default is None else {"default": default, "show_default": True}
    return click.option("--out", "out_dir", required=required, type=click.Path(file_okay=False), help=help, **extra)


def add_options(options):
    """Decorator stacking a list of click options on a command, in the list's order.

    Parameters
    ----------
    options : list of callable
        click option decorators.

    Returns
    -------
    callable
        The decorator.
    """
    def wrap(func):
        for opt in reversed(options):
            func = opt(func)
        return func

    return wrap


def float_list(text: str, what: str) -> np.ndarray:
    """Comma-separated numbers of option ``--what``.

    Parameters
    ----------
    text : str
        E.g. ``"10.5,1000"`` (empty items are skipped).
    what : str
        The option name, without dashes, for the error message.

    Returns
    -------
    ndarray of float64, shape (N,)
    """
    try:
        return np.array([float(v) for v in text.split(",") if v.strip() != ""], dtype=np.float64)
    except ValueError:
        raise InputError(f"--{what} must be comma-separated numbers, got {text!r}") from None


def quiet_of(ctx: click.Context, as_json: bool = False) -> bool:
    """Whether progress output is off (``-q`` on the group, or JSON on stdout).

    Parameters
    ----------
    ctx : click.Context
        The command's context.
    as_json : bool
        The command's ``--json`` flag.

    Returns
    -------
    bool
    """
    return bool((ctx.obj or {}).get("quiet", False)) or bool(as_json)


def progress_printer(ctx: click.Context, as_json: bool = False):
    """A progress callback printing each message on stderr, or None when quiet.

    Parameters
    ----------
    ctx : click.Context
        The command's context.
    as_json : bool
        The command's ``--json`` flag.

    Returns
    -------
    callable(str) or None
    """
    return None if quiet_of(ctx, as_json) else (lambda message: click.echo(message, err=True))


def echo_json(doc: dict) -> None:
    """Print ``doc`` as one JSON line on stdout (numpy values and paths converted).

    Parameters
    ----------
    doc : dict
        The summary.
    """
    click.echo(json.dumps(doc, default=json_default))


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
