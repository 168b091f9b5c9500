"""The one error boundary of ``gcpcal``: every exception becomes one stderr line and an exit code.

=====  ==========================================================================================
code   meaning
=====  ==========================================================================================
0      success
1      input or I/O error (bad or missing file, unwritable folder, full disk, unreadable raster,
       unreachable Dask scheduler), memory exhausted (the command and step named), or an
       internal error
2      usage error (bad option or argument): one line ``gcpcal: error: <message> (gcpcal <command>
       --help)``; with ``-v`` click's usage and hint too
3      the stage ran but failed (no convergence, every validation scene failed, ...)
4      partial success (some validation scenes failed, their rows say why)
129    hung up (SIGHUP: the terminal closed)
130    interrupted (Ctrl-C, SIGINT)
143    terminated (SIGTERM: ``kill``, ``timeout``, a batch scheduler)
=====  ==========================================================================================

On SIGINT, SIGTERM and SIGHUP the command stops, removes its staging (nothing new, nothing
stale is left) and exits ``128 + the signal number``.

Nothing a user or the machine can cause prints a traceback; an unexpected exception (a bug)
prints ``gcpcal: internal error: <type>: <message>`` and, with ``-v``, its traceback.
"""

from __future__ import annotations

import logging
import traceback

import click

from sensor_models.errors import GcpcalError

__all__ = ["EXIT_FAILED", "EXIT_HANGUP", "EXIT_INPUT", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_PARTIAL",
           "EXIT_TERMINATED", "EXIT_USAGE", "Interrupted", "note_signal", "quiet_cluster_logs", "run_guarded"]

EXIT_OK = 0
EXIT_INPUT = 1
EXIT_USAGE = 2
EXIT_FAILED = 3
EXIT_PARTIAL = 4
EXIT_INTERRUPTED = 130
EXIT_HANGUP = 129
EXIT_TERMINATED = 143

#: What each handled signal makes the command say, and its exit code (128 + the signal number).
_SIGNAL_WORDS = {2: "interrupted", 1: "hung up (SIGHUP)", 15: "terminated (SIGTERM)"}
_received: list[int] = []


class Interrupted(KeyboardInterrupt):
    """A handled signal (SIGINT, SIGTERM, SIGHUP) stopping the command; ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)


def note_signal(signum: int) -> None:
    """Record that signal ``signum`` arrived: :func:`run_guarded` then exits ``128 + signum``.

    Parameters
    ----------
    signum : int
    """
    _received.append(int(signum))


#: Loggers silenced once Ctrl-C arrives: a closing Dask cluster logs each worker's end.
_CLUSTER_LOGGERS = ("distributed", "dask", "tornado", "asyncio")


def quiet_cluster_logs() -> None:
    """Disable the Dask cluster's loggers (and their children) for the rest of the process.

    Called when the user interrupts: the cluster then closes without a line per worker.
    """
    names = list(logging.root.manager.loggerDict) + list(_CLUSTER_LOGGERS)
    for name in names:
        if name.split(".")[0] in _CLUSTER_LOGGERS:
            logging.getLogger(name).disabled = True


def _say(message: str) -> None:
    try:
        click.echo(f"gcpcal: {message}", err=True)
    except OSError:  # stderr gone (a closed terminal after SIGHUP): the exit code says it
        pass


def _one_line(text: str) -> str:
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    return lines[0] if lines else ""


#: Longest error line printed, characters: a message quoting a user's malformed file (a header of
#: megabytes) is cut there.
_MAX_LINE_CHARS = 1000


def _escape_breaks(text: str) -> str:
    """``text`` as one bounded line: line breaks it quotes from a user's file shown as ``\\n``,
    cut after :data:`_MAX_LINE_CHARS` characters."""
    text = str(text).replace("\r", "\\r").replace("\n", "\\n")
    if len(text) > _MAX_LINE_CHARS:
        text = f"{text[:_MAX_LINE_CHARS]}... ({len(text) - _MAX_LINE_CHARS} more characters)"
    return text


def _os_error_message(exc: OSError) -> str:
    """``/x/y: Permission denied`` (the file first, as the shell says it)."""
    what = exc.strerror or _one_line(exc) or type(exc).__name__
    if exc.filename is not None and exc.filename2 is not None:
        return f"{exc.filename} -> {exc.filename2}: {what}"
    if exc.filename is not None:
        return f"{exc.filename}: {what}"
    return what


def _rasterio_message(exc: BaseException) -> str:
    """``Read failed: <file>, band 1: IReadBlock failed ...``: rasterio's line, with GDAL's cause.

    rasterio's ``Read failed. See previous exception for details.`` names no file; the GDAL
    error it chains from does (``scene.tif, band 1: ...``), so the two are joined.
    """
    text = _one_line(exc) or type(exc).__name__
    cause = exc.__cause__ or exc.__context__
    if cause is None or not text.endswith("See previous exception for details."):
        return text
    head = text[: -len("See previous exception for details.")].strip().rstrip(".")
    detail = _one_line(cause)
    hint = " (truncated or corrupt raster?)" if head.lower().startswith("read failed") else ""
    return f"{head}: {detail}{hint}" if detail else head


def _usage_error_line(exc: click.UsageError) -> str:
    """``error: <message> (gcpcal <command> --help)``: click's usage, hint and error in one line."""
    message = _one_line(exc.format_message()) or "bad usage"
    ctx = exc.ctx
    command = ctx.command_path if ctx is not None else "gcpcal"
    return f"error: {message} ({command} --help)"


def _is_dask_error(exc: BaseException) -> bool:
    module = type(exc).__module__ or ""
    return module.split(".")[0] in ("dask", "distributed")


#: What the libraries say when an allocation fails (OpenCV's ``cv::OutOfMemoryError``, GDAL's
#: ``CPLE_OutOfMemory``, the loader mapping a library under an address-space limit, torch on a
#: GPU, errno ENOMEM).
_MEMORY_TEXTS = ("insufficient memory", "failed to allocate", "out of memory", "cannot allocate",
                 "failed to map segment")

#: Top-level packages of gcpcal, whose frames name the step that ran out of memory.
_OWN_PACKAGES = ("calibrate", "gcpmatch", "sensor_models")


def _memory_exhaustion(exc: BaseException) -> BaseException | None:
    """The exception (``exc`` or one it chains from) that says memory ran out; None otherwise."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, MemoryError) or "OutOfMemory" in type(exc).__name__:
            return exc
        if not isinstance(exc, GcpcalError) and any(text in str(exc).lower() for text in _MEMORY_TEXTS):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def _failing_step(exc: BaseException) -> str:
    """``gcpcal <command>, at <module>.<function>``: where an exception was raised, in gcpcal's code."""
    command, step = None, None
    for frame, _ in traceback.walk_tb(exc.__traceback__):
        module = frame.f_globals.get("__name__", "")
        if module.split(".")[0] not in _OWN_PACKAGES:
            continue
        if module.startswith("calibrate.cli."):
            name = module.rsplit(".", 1)[-1]
            if not name.startswith("_") and name != "options":
                command = name
            continue
        step = f"{module}.{frame.f_code.co_name}"
    where = f"gcpcal {command}" if command else "gcpcal"
    return f"{where}, at {step}" if step else where


def _memory_message(exc: BaseException, cause: BaseException) -> str:
    """One line: out of memory, in which command and step, what the library said, what to do."""
    detail = _one_line(cause) or type(cause).__name__
    if "Failed to allocate" in detail:  # OpenCV: "OpenCV(5.0.0) <file>:73: error: (-4:Insufficient memory) ..."
        detail = detail[detail.index("Failed to allocate"):].split(" in function")[0]
    module = type(cause).__module__
    kind = type(cause).__name__ if module == "builtins" else f"{module.split('.')[0]}.{type(cause).__name__}"
    return (f"out of memory in {_failing_step(exc)} ({kind}: {detail}): free memory or raise the "
            "limit (ulimit -v), or work in smaller pieces (--block, --spacing, --workers, a crop)")


def _user_error_message(exc: BaseException) -> str | None:
    """The message of an error a user or the machine caused; None for anything else (a bug)."""
    memory = _memory_exhaustion(exc)
    if memory is not None:  # first: under the limit, even importing rasterio below may fail
        return _memory_message(exc, memory)
    try:
        from rasterio.errors import RasterioError
    except ImportError:  # rasterio cannot load here: no error can be one of its own
        RasterioError = ()  # noqa: N806

    if isinstance(exc, GcpcalError):
        return str(exc)
    if isinstance(exc, OSError) and exc.filename is not None:  # a file named by gcpcal (e.g. a failed write)
        return _os_error_message(exc)
    if isinstance(exc, RasterioError):  # before OSError: RasterioIOError is both
        return _rasterio_message(exc)
    if isinstance(exc, OSError):
        return _os_error_message(exc)
    if _is_dask_error(exc):
        return f"dask: {type(exc).__name__}: {_one_line(exc)}"
    return None


def run_guarded(invoke, *, verbose: int = 0) -> int:
    """Call ``invoke()`` and map what it returns or raises to an exit code.

    Parameters
    ----------
    invoke : callable
        Runs the click group in non-standalone mode (``group.main(..., standalone_mode=False)``);
        an int it returns is the exit code (``ctx.exit(code)``).
    verbose : int
        ``-v`` count: 1 or more prints the traceback of an internal error, 2 or more that of
        any error.

    Returns
    -------
    int
        The exit code (see the module docstring).
    """
    _received.clear()
    try:
        rv = invoke()
    except (KeyboardInterrupt, click.exceptions.Abort) as exc:
        quiet_cluster_logs()
        signum = getattr(exc, "signum", None) or (_received[0] if _received else 2)
        _say(_SIGNAL_WORDS.get(signum, f"stopped by signal {signum}"))
        return 128 + signum
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.UsageError as exc:
        if verbose >= 1:
            exc.show()
        else:
            _say(_usage_error_line(exc))
        return exc.exit_code
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except Exception as exc:  # the boundary: every error ends here as one line
        message = _user_error_message(exc)
        if message is None:
            if verbose >= 1:
                traceback.print_exc()
            _say(f"internal error: {type(exc).__name__}: {_one_line(exc)} (run with -v for the traceback)")
            return EXIT_INPUT
        if verbose >= 2:
            traceback.print_exc()
        _say(f"error: {_escape_breaks(message)}")
        return EXIT_INPUT
    if isinstance(rv, int) and not isinstance(rv, bool):
        return rv
    return EXIT_OK
