"""Options shared by several ``gcpcal`` commands, and the small helpers every command uses.

Stack a list of options on a command with :func:`add_options`; defaults that mirror an option
value of :mod:`calibrate.config` are read from there.
"""

from __future__ import annotations

import functools
import json
import math

import click
import numpy as np

from calibrate._json import json_default
from calibrate.cli._errors import EXIT_FAILED, EXIT_PARTIAL
from sensor_models.errors import InputError

__all__ = ["accept_product_disagreement_option", "add_options", "allow_implausible_option", "apply_verbosity", "constant_height_option", "dem_options", "dom_options", "echo_json", "optional_dom_options",
           "echo_warnings", "exit_for_failed_scenes", "exit_with_status", "float_list", "height_range_option", "json_option", "one_height_source",
           "out_dir_option", "quiet_of", "verbosity_options"]


def _tiles(ctx, param, value):
    """A repeatable path option's value: None when absent, the path when one, a tuple when several."""
    if not value:
        return None
    return value[0] if len(value) == 1 else tuple(value)


_TILE_FORMS = "repeat the option, or give a comma list, a folder, a glob (quoted) or a .vrt"

def _dem_option_list(required: bool) -> list:
    """``--dem`` (required or not), ``--dem-datum``, ``--geoid``."""
    return [
        click.option("--dem", "dem_path", multiple=True, callback=_tiles, type=click.Path(), required=required,
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


#: ``--dem``, ``--dem-datum``, ``--geoid`` (keywords ``dem_path``, ``dem_datum``, ``geoid``), for
#: commands that can work without a DEM (a constant height instead).
dem_options = _dem_option_list(required=False)
#: The same with ``--dem`` required (marked so in the help; a missing one is a usage error, exit 2),
#: for commands that need terrain (match, run, relative, ortho).
required_dem_options = _dem_option_list(required=True)


def parse_window(text: str, *, square: bool = False):
    """The ``--window`` value of every command: ``"64"`` -> 64, ``"64x32"`` -> ``(64, 32)``.

    Parameters
    ----------
    text : str
        ``N`` (square) or ``ROWSxCOLS``; even sizes >= 16 pixels.
    square : bool
        The command matches square windows only (``match``): ``RxC`` must have R == C.

    Returns
    -------
    int or (int, int)
        Window size, pixels (an int for a square window).

    Raises
    ------
    click.BadParameter
        Not of that form (a usage error, exit 2).
    """
    try:
        sizes = [int(v) for v in str(text).lower().split("x")]
        if len(sizes) not in (1, 2) or any(v < 16 or v % 2 for v in sizes):
            raise ValueError
    except ValueError:
        raise click.BadParameter(f"expected N or ROWSxCOLS, even numbers of pixels >= 16, got {text!r}",
                                 param_hint="'--window'") from None
    if len(sizes) == 2 and sizes[0] == sizes[1]:
        sizes = sizes[:1]
    if square and len(sizes) == 2:
        raise click.BadParameter(f"this command matches square windows: give N, got {text!r}", param_hint="'--window'")
    return sizes[0] if len(sizes) == 1 else tuple(sizes)


def window_option(default: int, *, square: bool = False):
    """``--window N|RxC`` (keyword ``window``): the phase-correlation window, one syntax everywhere.

    Parameters
    ----------
    default : int
        Default side, pixels.
    square : bool
        Only square windows (``RxC`` with R != C is refused).

    Returns
    -------
    callable
        A click option decorator; the command receives an int or ``(rows, cols)``.
    """
    shape = "N (square)" if square else "N (square) or ROWSxCOLS (e.g. 64x32)"
    return click.option("--window", "window", default=str(default), show_default=True, metavar="N|RxC",
                        callback=lambda ctx, param, value: parse_window(value, square=square),
                        help=f"Phase-correlation window, pixels: {shape}; even, >= 16.")


def east_north_metres(text, hint: str, sizes=(1, 2)):
    """None, or a pair of metres >= 0 from ``A`` (both) or ``A,B`` (east, north).

    Parameters
    ----------
    text : str or None
        The option's value.
    hint : str
        The option's name, for the message.
    sizes : tuple of int
        How many values are accepted.

    Returns
    -------
    (float, float) or None

    Raises
    ------
    click.BadParameter
        Not of that form.
    """
    if text is None:
        return None
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) not in sizes or not all(math.isfinite(v) and v >= 0.0 for v in values):
        form = "A,B" if sizes == (2,) else "A or A,B"
        raise click.BadParameter(f"expected {form} (metres >= 0), got {text!r}", param_hint=hint)
    return (values[0], values[-1])


def reference_sigma_option(help_text: str):
    """``--reference-sigma-m E[,N]`` (keyword ``reference_sigma_m``): one spelling and one form in
    every command: the reference's geolocation accuracy, metres, 1 sigma east[,north].

    Parameters
    ----------
    help_text : str
        What the command does with it and its default.

    Returns
    -------
    callable
        A click option decorator; the command receives None or ``(east, north)`` metres.
    """
    return click.option("--reference-sigma-m", "reference_sigma_m", metavar="E[,N]", default=None,
                        callback=lambda ctx, param, value: east_north_metres(value, "'--reference-sigma-m'"),
                        help="Geolocation accuracy of the reference, m (1 sigma east[,north]); " + help_text)


# The height family (docs/cli.md, "Terrain heights"): one spelling and one meaning in every command
# that localizes on the ground (localize, rpc, ortho, truth error, relative):
#   --height M              one constant ellipsoidal height, metres;
#   --height-range MIN MAX  ellipsoidal heights spanned, metres (RPC fit, truth comparison);
#   --dem PATH [--dem-datum ellipsoid|egm96] [--geoid GRID]   terrain from a DEM (``dem_options``).
# A command offers the members it can use; the others are not among its options.

#: ``--height M`` (keyword ``height``).
constant_height_option = click.option(
    "--height", "height", type=float, metavar="M",
    help="Constant ground height, m above the WGS84 ellipsoid (instead of --dem).")

#: ``--height-range MIN MAX`` (keyword ``height_range``).
height_range_option = click.option(
    "--height-range", "height_range", nargs=2, type=float, metavar="MIN MAX",
    help="Lowest and highest ground heights, m above the WGS84 ellipsoid (instead of --dem).")

def one_height_source(**given) -> str | None:
    """The one member of the height family given (``--height``, ``--height-range``, ``--dem``), or None.

    Parameters
    ----------
    **given
        Option name (without dashes, ``_`` for ``-``) -> its value (None when not given).

    Returns
    -------
    str or None
        The option name given, e.g. ``"dem"``.

    Raises
    ------
    click.UsageError
        When more than one is given.
    """
    named = [name for name, value in given.items() if value is not None and value != ()]
    if len(named) > 1:
        raise click.UsageError("give one of " + ", ".join("--" + n.replace("_", "-") for n in given) + ", not "
                               + " and ".join("--" + n.replace("_", "-") for n in named))
    return named[0] if named else None



def _dom_option_list(required: bool = True):
    from sensor_models.maps.reference_qa import QA_LAYOUTS

    return [
        click.option("--dom", "dom_items", multiple=True, required=required, type=click.Path(),
                     help="Reference orthoimage: a raster, a Landsat band GeoTIFF, a Sentinel-2 JP2, a .SAFE or "
                          f"IMG_DATA folder (with --dom-band), or tiles: {_TILE_FORMS}."),
        click.option("--dom-band", help="Band of a product folder or of tiles, e.g. B04 (Sentinel-2) or B4 (Landsat)."),
        click.option("--dom-qa", multiple=True, type=click.Path(),
                     help="QA raster(s) masking the DOM (Landsat QA_PIXEL or BQA, Sentinel-2 SCL); default: the one "
                          "beside the band, when found."),
        click.option("--dom-qa-layout", type=click.Choice(QA_LAYOUTS),
                     help="Bit layout of --dom-qa when its name does not tell (QA_PIXEL, BQA, SCL)."),
        click.option("--no-dom-qa", is_flag=True, help="Use no QA mask, not even one found beside the band."),
        click.option("--dom-mask-cirrus", is_flag=True,
                     help="Mask the QA's cirrus pixels too (by default only fill, cloud and cloud shadow are masked)."),
        click.option("--dom-mask", "dom_mask", multiple=True, type=click.Path(),
                     help="Your own mask of the DOM (any raster in the DOM's CRS, nonzero = do not use), with the QA."),
        click.option("--dom-scale", type=float,
                     help="DOM value = DN * scale + offset (overrides the product's metadata)."),
        click.option("--dom-offset", type=float, help="See --dom-scale."),
    ]


def dom_options(func, *, required: bool = True):
    """Decorator: the reference-orthoimage options, handed to the command as ``dom_path``.

    Adds ``--dom`` (repeatable), ``--dom-band``, ``--dom-qa`` (repeatable), ``--dom-qa-layout``,
    ``--no-dom-qa``, ``--dom-mask-cirrus``, ``--dom-mask`` (repeatable), ``--dom-scale`` and ``--dom-offset``; the command receives them as one
    :class:`sensor_models.maps.dom_inputs.DomSource` in its ``dom_path`` argument.

    Parameters
    ----------
    func : callable
        The command's callback.
    required : bool
        Whether ``--dom`` must be given (:func:`optional_dom_options`: it may not; the
        ``DomSource`` then has no items).

    Returns
    -------
    callable
        The callback with the options attached.
    """
    from sensor_models.maps.dom_inputs import DomSource

    @functools.wraps(func)
    def wrapper(*args, dom_items, dom_band, dom_qa, dom_qa_layout, no_dom_qa, dom_mask_cirrus, dom_mask, dom_scale,
                dom_offset, **kwargs):
        kwargs["dom_path"] = DomSource(items=tuple(dom_items), band=dom_band, qa=tuple(dom_qa),
                                       qa_layout=dom_qa_layout, scale=dom_scale, offset=dom_offset,
                                       use_qa=not no_dom_qa, qa_cirrus=dom_mask_cirrus, mask=tuple(dom_mask))
        return func(*args, **kwargs)

    return add_options(_dom_option_list(required))(wrapper)


def optional_dom_options(func):
    """:func:`dom_options` with ``--dom`` optional (``gcpcal campaign``: a folder's scenes have their own)."""
    return dom_options(func, required=False)


def accept_product_disagreement_option(func):
    """Decorator: ``--accept-product-disagreement``, handed to the command as ``self_check``.

    A vendor product (SPOT 1-5 DIMAP, DIMAP v2, DigitalGlobe XML) whose rigorous model
    disagrees with the product's own corners or RPC beyond its reader's tolerance is refused
    (exit 1, one line naming the product and the disagreement); with the flag the command goes
    on and records the disagreement in its summary (``product_check``, ``warnings``). The
    command receives ``self_check="warn"`` with the flag, ``"refuse"`` without.

    Parameters
    ----------
    func : callable
        The command's callback (taking ``self_check``).

    Returns
    -------
    callable
        The callback with the option attached.
    """
    @functools.wraps(func)
    def wrapper(*args, accept_product_disagreement, **kwargs):
        kwargs["self_check"] = "warn" if accept_product_disagreement else "refuse"
        return func(*args, **kwargs)

    return click.option(
        "--accept-product-disagreement", is_flag=True,
        help="Open a vendor product (.DIM, DIMAP v2 or DigitalGlobe .XML) even when its model disagrees with the "
             "product's own corners or RPC beyond the reader's tolerance; the summary records the disagreement "
             "(docs/dimap.md, docs/worldview.md).")(wrapper)


def allow_implausible_option(func):
    """Decorator: ``--allow-implausible``, under which the stage's plausibility checks warn instead of refusing.

    The checks (:mod:`calibrate.plausibility`: DEM heights, DOM resolution, the raster of
    another band, GCPs off the scene) run inside the command; the flag is not passed to it.

    Parameters
    ----------
    func : callable
        The command's callback.

    Returns
    -------
    callable
        The callback with the option attached.
    """
    from calibrate.plausibility import accepting_implausible

    @functools.wraps(func)
    def wrapper(*args, allow_implausible, **kwargs):
        with accepting_implausible(allow_implausible) as accepted:
            try:
                return func(*args, **kwargs)
            finally:  # also before an exit 1, 3 or 4: the user said yes to these inputs
                for line in accepted:
                    click.echo(f"gcpcal: warning: {line}", err=True)

    return click.option("--allow-implausible", "allow_implausible", is_flag=True,
                        help="Accept inputs whose figures a real one cannot have (DEM heights outside -500..9000 m, "
                             "a DOM over 4x coarser than the scene, another band's raster, GCPs off the scene) "
                             "with a warning instead of refusing them.")(wrapper)


#: ``-v/--verbose`` (count) and ``-q/--quiet``: on the group and, the same, on every command.
verbosity_options = [
    click.option("-v", "--verbose", count=True, help="More log output (repeatable); -v shows the traceback of an "
                                                     "internal error, -vv of any error."),
    click.option("-q", "--quiet", is_flag=True, help="Results on stdout as usual; on stderr only warnings, errors "
                                                     "and the reason of an exit 3 or 4 (no step messages, no "
                                                     "progress)."),
]


def apply_verbosity(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """Record ``-v``/``-q`` in ``ctx.obj`` (added to those before the command name) and set the log level.

    Parameters
    ----------
    ctx : click.Context
        The group's or the command's context; ``ctx.obj`` is the dict shared by all of them.
    verbose : int
        ``-v`` count given here.
    quiet : bool
        ``-q`` given here.
    """
    import logging

    ctx.ensure_object(dict)
    ctx.obj["verbose"] = int(ctx.obj.get("verbose", 0)) + int(verbose)
    ctx.obj["quiet"] = bool(ctx.obj.get("quiet", False)) or bool(quiet)
    levels = (logging.WARNING, logging.INFO, logging.DEBUG)
    level = logging.ERROR if ctx.obj["quiet"] else levels[min(ctx.obj["verbose"], 2)]
    logging.getLogger().setLevel(level)


def exit_with_status(ctx: click.Context, code: int, reason: str) -> None:
    """End a command with exit 3 (failed) or 4 (partial), saying why on stderr in one line.

    The line is printed whatever ``-q`` or ``--json`` say (stdout keeps the summary).

    Parameters
    ----------
    ctx : click.Context
        The command's context.
    code : int
        3 or 4 (:mod:`calibrate.cli._errors`).
    reason : str
        Why, in one line, e.g. ``"B2.ccd2: 0 GCPs"``.
    """
    what = {3: "failed", 4: "partial"}.get(code, f"exit {code}")
    text = " ".join(str(reason).split()) or "(no reason given)"
    click.echo(f"gcpcal: {what}: {text}", err=True)
    ctx.exit(code)


def exit_for_failed_scenes(ctx: click.Context, summary: dict) -> None:
    """A many-scene command (``validate``, ``campaign``) ends with exit 3 when every scene failed,
    4 when some did, naming each failed scene and its reason; nothing when none failed.

    Parameters
    ----------
    ctx : click.Context
        The command's context.
    summary : dict
        ``failed``, ``ok``, ``scenes`` counts and ``failures`` (scene name -> reason).
    """
    if not summary["failed"]:
        return
    reasons = "; ".join(f"{name}: {reason}" for name, reason in summary["failures"].items())
    exit_with_status(ctx, EXIT_PARTIAL if summary["ok"] else EXIT_FAILED,
                     f"{summary['failed']} of {summary['scenes']} scene(s) failed ({reasons})")

#: ``--json`` (keyword ``as_json``).
json_option = click.option("--json", "as_json", is_flag=True,
                           help="Print the summary as JSON on stdout, and nothing else there; no progress.")


def threads_option(what: str, *aliases: str):
    """``--threads N`` (and ``aliases``): threads of a command's parallel stages, 0 for the default.

    Parameters
    ----------
    what : str
        What the threads run, for the help.
    aliases : str
        Other names of the option (an older ``--workers``).

    Returns
    -------
    click decorator
        The option, passed as ``threads`` (an integer >= 0).
    """
    return click.option("--threads", *aliases, "threads", type=click.IntRange(min=0), default=0, show_default=True,
                        help=f"Threads for {what}; 0: GCPCAL_THREADS when set, else every core. "
                             "The outputs do not depend on it.")


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
