"""The ``gcpcal`` command line: one click group, one module per command.

Each command module (``calibrate/cli/<name>.py``, attribute ``command``) parses its options,
builds the options value and hands off to its stage action in :mod:`calibrate.actions` (or, for a
command that runs several stages, to its composition in :mod:`calibrate.pipelines`); it
prints the action's summary (a line, a table or ``--json``) and maps the outcome to the exit
code. Shared options live in :mod:`calibrate.cli.options`; :func:`main` is the one error
boundary (:mod:`calibrate.cli._errors`). Library code never calls ``sys.exit``.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import logging
import signal
import sys
import threading

import click

from calibrate.actions._guard import allow_overwrite, running_command
from calibrate.actions._provenance import command_line
from calibrate.cli._errors import Interrupted, note_signal, quiet_cluster_logs, run_guarded
from calibrate.cli.options import add_options, apply_verbosity, verbosity_options
from sensor_models import __version__
from sensor_models.files.threads import command_blas_single_threaded, thread_count

__all__ = ["COMMANDS", "cli", "load_all_commands", "main"]

#: Every command, registered explicitly: name -> (its module, the one line ``gcpcal --help``
#: shows, which is the first sentence of the command's own help). A command's module (and the
#: libraries behind it) is imported only when that command runs or prints its help, so that
#: ``gcpcal --help`` and ``gcpcal --version`` answer at once; ``tests/test_cli_structure.py``
#: checks that every line equals the command's own.
COMMANDS = {
    "localize": ("calibrate.cli.localize", "Localize points through MODEL, image -> ground or ground -> image."),
    "rpc": ("calibrate.cli.rpc", "Fit an RPC to MODEL over its image and height range and write it."),
    "demo": ("calibrate.cli.demo", "Run the main job on an embedded fixture and write OUT/summary.json."),
    "match": ("calibrate.cli.match",
              "Extract GCPs of SCENE against a DOM and a DEM (coarse SIFT, dense phase correlation)."),
    "calibrate": ("calibrate.cli.calibrate",
                  "Calibrate SCENE's model from GCPs; write calibration.json, the calibrated model and report.html."),
    "run": ("calibrate.cli.run",
            "Calibrate SCENE from GCPs, or from star frames when clouds leave too few (says which and why)."),
    "relative": ("calibrate.cli.relative",
                 "Calibrate every band of SCENE against its calibrated reference band (band-to-band)."),
    "validate": ("calibrate.cli.validate",
                 "Validate a calibration on the scenes of SITES (YAML or CSV: name, scene, dom, dem)."),
    "campaign": ("calibrate.cli.campaign",
                 "Run gcpcal run on every scene of CAMPAIGN, one Dask task per scene; one table for all."),
    "ortho": ("calibrate.cli.ortho", "Orthorectify a band of SCENE on the DEM into a Cloud-Optimized GeoTIFF."),
    "stars": ("calibrate.cli.stars",
              "Calibrate a staring camera from star tracks in FRAMES (a frames.json or its folder)."),
    "compensate": ("calibrate.cli.compensate",
                   "Seed 002 simulation: ICO, ECO, ECBIC, ICBEC and joint compensation from virtual control points."),
    "thermal": ("calibrate.cli.thermal",
                "Simulate and model the daily thermal drift of a staring camera's installation angles."),
    "oalr": ("calibrate.cli.oalr",
             "Focal-length change and camera rotations from OALR cross marks in MARKS.csv (seed 004)."),
    "truth": ("calibrate.cli.truth", "Compare models with the truth of a simulated scene."),
    "simulate": ("calibrate.cli.simulate", "Simulate scenes with known truth."),
    "experiment": ("calibrate.cli.experiment",
                   "Run seed SEED's experiment (000 stars, 002 staring schemes + thermal, 003 push-broom, 004 OALR)."),
}


def _short(text: str, limit: int) -> str:
    """``text`` cut at a word boundary to at most ``limit`` characters, with "..." when cut."""
    if len(text) <= limit:
        return text
    cut = text[: max(limit - 3, 1)].rsplit(" ", 1)[0]
    return cut.rstrip(" ,;:") + "..."


class _CommandsOnDemand(click.Group):
    """A click group that imports a command's module the first time the command is asked for."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        if name not in self.commands and name in COMMANDS:
            command = importlib.import_module(COMMANDS[name][0]).command
            _accept_verbosity(command)
            self.add_command(command)
        return self.commands.get(name)

    def format_commands(self, ctx, formatter):
        """The command table from :data:`COMMANDS`, without importing any command."""
        width = max(len(name) for name in COMMANDS)
        limit = formatter.width - 6 - width
        rows = [(name, _short(COMMANDS[name][1], limit)) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


def load_all_commands() -> dict[str, click.Command]:
    """Every command, imported and registered: name -> click command (for tests and docs)."""
    return {name: cli.get_command(None, name) for name in COMMANDS}


@click.group(cls=_CommandsOnDemand, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="gcpcal")
@add_options(verbosity_options)
@click.pass_context
def cli(ctx, verbose, quiet):
    """gcpcal: on-orbit geometric calibration of satellite cameras.

    \b
    Exit codes:
      0    success
      1    input or I/O error (bad or missing file, unwritable folder, full disk,
           unreadable raster, unreachable Dask scheduler) or an internal error
      2    usage error (bad option or argument)
      3    the stage ran but failed (e.g. no convergence)
      4    partial success (e.g. some validation or campaign scenes failed)
      129  hung up (SIGHUP)
      130  interrupted (Ctrl-C)
      143  terminated (SIGTERM)
    """
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")
    ctx.ensure_object(dict)
    ctx.obj.update(quiet=False, verbose=0)
    apply_verbosity(ctx, verbose, quiet)
    thread_count()  # a bad GCPCAL_THREADS stops any command before it starts (one line, exit 1)


#: ``--overwrite``, on every command that writes (every command but the groups).
overwrite_option = click.option(
    "--overwrite", is_flag=True,
    help="Replace existing files gcpcal did not write (or that changed since), and write through a symbolic link "
         "given as an output. Without it they are refused; gcpcal's own earlier outputs are replaced anyway. "
         "Inputs and devices are never written.")


def _accept_verbosity(command: click.Command, path: str = "") -> None:
    """Give ``command`` (and, for a group, each subcommand) the group's ``-v``/``-q``, with the same effect.

    ``gcpcal -q match ...``, ``gcpcal match -q ...`` and ``gcpcal match ... -q`` are the same
    command; the counts add up (``gcpcal -v calibrate -v`` is ``-vv``). Every command (not a
    group) also gets ``--overwrite`` (:mod:`calibrate.actions._guard`) and records its name in
    the ledger of what it writes.
    """
    name = f"{path} {command.name}".strip()
    for decorator in reversed(verbosity_options):
        decorator(command)  # click.option on a Command object appends to its params
    group = isinstance(command, click.Group)
    if not group:
        overwrite_option(command)
    callback = command.callback

    @functools.wraps(callback)
    def with_verbosity(*args, verbose=0, quiet=False, overwrite=False, **kwargs):
        apply_verbosity(click.get_current_context(), verbose, quiet)
        if group:
            return callback(*args, **kwargs)
        with allow_overwrite(overwrite), running_command(name):
            return callback(*args, **kwargs)

    command.callback = with_verbosity
    if group:
        for sub in command.commands.values():
            _accept_verbosity(sub, name)


def _verbosity(args: list[str]) -> int:
    """``-v`` count anywhere before a ``--`` (the group's and the command's add up)."""
    count = 0
    for arg in args:
        if arg == "--":
            break
        if arg == "--verbose":
            count += 1
        elif arg.startswith("-") and not arg.startswith("--") and set(arg[1:]) <= {"v", "q"}:
            count += arg.count("v")
    return count


#: Commands that start a Dask cluster: their workers ignore Ctrl-C (calibrate.actions._worker_signals).
_CLUSTER_COMMANDS = ("validate", "campaign")


def _worker_config(args: list[str]):
    """A dask.config context whose workers load :mod:`calibrate.actions._worker_signals`, or a no-op."""
    if not any(command in args for command in _CLUSTER_COMMANDS):
        return contextlib.nullcontext()
    import dask.config
    import distributed.config  # noqa: F401  its defaults first: the context restores a snapshot on exit

    preload = list(dask.config.get("distributed.worker.preload", default=None) or [])
    return dask.config.set({"distributed.worker.preload": preload + ["calibrate.actions._worker_signals"]})


#: Signals that stop a command cleanly (staging removed, exit 128 + the number).
_HANDLED = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


def _after_first(signum, frame):
    """A second signal while the first one's cleanup runs: recorded, the cleanup goes on."""
    note_signal(signum)


#: Code whose exceptions Python prints as "Exception ignored in ..." and then carries on: weakref
#: callbacks (the import system drops its module locks through one), finalizers, ``__del__``.
_SWALLOWING_FILES = ("weakref.py", "_weakrefset.py")


def raising_is_swallowed(frame) -> bool:
    """True when an exception raised in ``frame`` would be printed and dropped, not propagated.

    A signal handler runs in whatever Python frame was executing when the signal arrived. In a
    weakref callback or a ``__del__`` the interpreter reports an exception on stderr with a
    traceback and continues, so the command would neither stop nor stay quiet.
    """
    if frame is None:
        return False
    code = frame.f_code
    filename = code.co_filename.replace("\\", "/")
    return (filename.startswith("<frozen importlib") or code.co_name == "__del__"
            or filename.rsplit("/", 1)[-1] in _SWALLOWING_FILES)


#: Seconds between looks at whether a deferred signal can be raised (:func:`_defer`).
_DEFER_S = 0.002


def _defer(signum):
    """Raise ``signum``'s stop a moment later, from a timer signal that lands in other code.

    ``signal.raise_signal`` or ``os.kill`` would run the handler before they return, still inside
    the swallowing frame; SIGALRM arrives asynchronously, at a later bytecode boundary.
    """
    previous = signal.getsignal(signal.SIGALRM)

    def retry(_alarm, frame):
        if raising_is_swallowed(frame):
            signal.setitimer(signal.ITIMER_REAL, _DEFER_S)
            return
        signal.signal(signal.SIGALRM, previous)
        _on_signal(signum, frame)

    signal.signal(signal.SIGALRM, retry)
    signal.setitimer(signal.ITIMER_REAL, _DEFER_S)


def _on_signal(signum, frame):
    """SIGINT, SIGTERM, SIGHUP: quiet the Dask cluster's loggers, then stop as Ctrl-C does.

    A signal that lands in code whose exceptions are swallowed (:func:`raising_is_swallowed`) is
    deferred (:func:`_defer`): the command stops as soon as it is back in ordinary code.
    """
    if raising_is_swallowed(frame) and hasattr(signal, "setitimer"):
        _defer(signum)
        return
    note_signal(signum)
    for handled in _HANDLED:
        signal.signal(handled, _after_first)
    quiet_cluster_logs()
    raise Interrupted(signum)


def main(argv=None) -> int:
    """Console entry point: run the CLI inside the error boundary.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: 0 ok, 1 input/I/O, 2 usage, 3 failed, 4 partial, 129 hung up, 130
        interrupted, 143 terminated.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {signum: signal.signal(signum, _on_signal) for signum in _HANDLED}
    try:
        with _worker_config(args), command_line(args), command_blas_single_threaded():
            return run_guarded(lambda: cli.main(args=args, prog_name="gcpcal", standalone_mode=False),
                               verbose=_verbosity(args))
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
