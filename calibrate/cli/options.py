"""Options shared by several ``gcpcal`` commands, and the small helpers every command uses.

Stack a list of options on a command with :func:`add_options`; defaults that mirror an option
value of :mod:`calibrate.config` are read from there.
"""

from __future__ import annotations

import functools
import json

import click
import numpy as np

from calibrate._json import json_default
from sensor_models.errors import InputError

__all__ = ["add_options", "dem_options", "dom_options", "echo_json", "echo_warnings", "float_list", "json_option",
           "out_dir_option", "progress_printer", "quiet_of", "verbosity_options"]

def _tiles(ctx, param, value):
    """A repeatable path option's value: None when absent, the path when one, a tuple when several."""
    if not value:
        return None
    return value[0] if len(value) == 1 else tuple(value)


_TILE_FORMS = "repeat the option, or give a comma list, a folder, a glob (quoted) or a .vrt"

#: ``--dem``, ``--dem-datum``, ``--geoid`` (keywords ``dem_path``, ``dem_datum``, ``geoid``).
dem_options = [
    click.option("--dem", "dem_path", multiple=True, callback=_tiles, type=click.Path(),
                 help=f"DEM raster (any CRS rasterio reads), or tiles mosaicked on the fly (SRTM .hgt, Copernicus "
                      f"GLO-30): {_TILE_FORMS}."),
    click.option(
        "--dem-datum",
        type=click.Choice(["ellipsoid", "egm96"]),
        default=None,
        help="Vertical datum of the DEM heights when the file does not declare it.",
    ),
    click.option("--geoid", type=click.Path(dir_okay=False),
                 help="Geoid grid (e.g. egm96_15.gtx) for egm96 heights; default: us_nga_egm96_15.tif or "
                      "egm96_15.gtx in PROJ's data directories."),
]


def _dom_option_list():
    from sensor_models.reference_qa import QA_LAYOUTS

    return [
        click.option("--dom", "dom_items", multiple=True, required=True, type=click.Path(),
                     help="Reference orthoimage: a raster, a Landsat band GeoTIFF, a Sentinel-2 JP2, a .SAFE or "
                          f"IMG_DATA folder (with --dom-band), or tiles: {_TILE_FORMS}."),
        click.option("--dom-band", help="Band of a product folder or of tiles, e.g. B04 (Sentinel-2) or B4 (Landsat)."),
        click.option("--dom-qa", multiple=True, type=click.Path(),
                     help="QA raster(s) masking the DOM (Landsat QA_PIXEL or BQA, Sentinel-2 SCL); default: the one "
                          "beside the band, when found."),
        click.option("--dom-qa-layout", type=click.Choice(QA_LAYOUTS),
                     help="Bit layout of --dom-qa when its name does not tell (QA_PIXEL, BQA, SCL)."),
        click.option("--no-dom-qa", is_flag=True, help="Use no QA mask, not even one found beside the band."),
        click.option("--dom-scale", type=float,
                     help="DOM value = DN * scale + offset (overrides the product's metadata)."),
        click.option("--dom-offset", type=float, help="See --dom-scale."),
    ]


def dom_options(func):
    """Decorator: the reference-orthoimage options, handed to the command as ``dom_path``.

    Adds ``--dom`` (repeatable), ``--dom-band``, ``--dom-qa`` (repeatable), ``--dom-qa-layout``,
    ``--no-dom-qa``, ``--dom-scale`` and ``--dom-offset``; the command receives them as one
    :class:`sensor_models.dom_inputs.DomSource` in its ``dom_path`` argument.

    Parameters
    ----------
    func : callable
        The command's callback.

    Returns
    -------
    callable
        The callback with the options attached.
    """
    from sensor_models.dom_inputs import DomSource

    @functools.wraps(func)
    def wrapper(*args, dom_items, dom_band, dom_qa, dom_qa_layout, no_dom_qa, dom_scale, dom_offset, **kwargs):
        kwargs["dom_path"] = DomSource(items=tuple(dom_items), band=dom_band, qa=tuple(dom_qa),
                                       qa_layout=dom_qa_layout, scale=dom_scale, offset=dom_offset,
                                       use_qa=not no_dom_qa)
        return func(*args, **kwargs)

    return add_options(_dom_option_list())(wrapper)


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
