"""The one progress display of ``gcpcal``: a rich bar on stderr, shown only where a person watches.

Every long stage (demo, simulate, match, calibrate, ortho, validate, ...) reports through one
:class:`StageProgress`. Its two callbacks fit the two kinds the stage actions take:

- :meth:`StageProgress.message` (``progress(str)``): a step, e.g. ``"coarse stage: 412 SIFT matches"``;
- :meth:`StageProgress.count` (``progress(done, total)``): work units done, e.g. ortho blocks.

Where it shows:

=============================  ==================================================================
stderr                         what appears
=============================  ==================================================================
a terminal                     a live rich display (spinner, bar, count, elapsed time, time left,
                               last step), removed when the stage ends
not a terminal (file, pipe)    the step messages, one plain line each (a log), and for counted
                               work a line at each further tenth once the stage has run 2 s
                               (``gcpcal match: windows 30 % (1122/3740), 12 s, about 28 s
                               left``), as GDAL's ``0...10...20``; no live display
``-q`` or ``--json``           nothing
=============================  ==================================================================

stdout is never touched, so ``--json`` output stays pure JSON.
"""

from __future__ import annotations

import time

import click

__all__ = ["PLAIN_AFTER_S", "StageProgress", "format_seconds", "stage_progress"]

#: Off a terminal, counted progress is printed only once a stage has run this long (seconds).
PLAIN_AFTER_S = 2.0


def format_seconds(seconds: float) -> str:
    """``"45 s"``, ``"3 min 20 s"`` or ``"1 h 05 min"``.

    Parameters
    ----------
    seconds : float

    Returns
    -------
    str
    """
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


class StageProgress:
    """Progress of one stage on stderr (see the module docstring); use it as a context manager.

    Parameters
    ----------
    label : str
        Shown before the bar, e.g. ``"gcpcal match"``.
    quiet : bool
        ``-q`` or ``--json``: show nothing.
    console : rich.console.Console, optional
        The stderr console (default: a new one on ``sys.stderr``); pass one with
        ``force_terminal=True`` to show the live display whatever stderr is.
    """

    def __init__(self, label: str, *, quiet: bool, console=None):
        from rich.console import Console

        self.label = label
        self.quiet = bool(quiet)
        self.console = console if console is not None else Console(stderr=True)
        self.live = not self.quiet and self.console.is_terminal
        self._bar = None
        self._task = None
        self._t0 = time.perf_counter()
        self._first = None  # (time, done) of the first count: the rate's origin
        self._tenth = -1  # last tenth printed off a terminal

    def __enter__(self) -> "StageProgress":
        self._t0 = time.perf_counter()
        if self.live:
            from rich.markup import escape
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self._bar = Progress(SpinnerColumn(), TextColumn(escape(self.label)), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.description}"),
                                 console=self.console, transient=True)
            self._task = self._bar.add_task("", total=None)
            self._bar.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def message(self, text: str) -> None:
        """A step of the stage: the live display's last-step text, or one plain stderr line.

        Parameters
        ----------
        text : str
            The step, plain text (no rich markup is interpreted).
        """
        if self.quiet:
            return
        if self._bar is not None:
            from rich.markup import escape

            self._bar.update(self._task, description=escape(str(text)))
        else:
            click.echo(str(text), err=True)

    def status(self, text: str) -> None:
        """The live display's last-step text only (no plain line where stderr is not a terminal).

        Parameters
        ----------
        text : str
            Plain text.
        """
        if self._bar is not None:
            from rich.markup import escape

            self._bar.update(self._task, description=escape(str(text)))

    def count(self, done: int, total: int | None) -> None:
        """Work units done out of ``total`` (None: unknown): the live bar, or off a terminal a
        plain line at each further tenth once the stage has run :data:`PLAIN_AFTER_S`.

        Parameters
        ----------
        done : int
            Units done so far.
        total : int or None
            Units in all.
        """
        now = time.perf_counter()
        if self._first is None:
            self._first = (now, done)
        if self._bar is not None:
            self._bar.update(self._task, completed=done, total=total)
            return
        if self.quiet or not total or done <= 0:
            return
        tenth = min(10, int(10 * done / total))
        if tenth <= self._tenth or now - self._t0 < PLAIN_AFTER_S:
            return
        self._tenth = tenth
        line = f"{self.label} {100 * done / total:.0f} % ({done}/{total}), {format_seconds(now - self._t0)}"
        t1, d1 = self._first
        if done < total and done > d1 and now > t1:
            line += f", about {format_seconds((total - done) * (now - t1) / (done - d1))} left"
        click.echo(line, err=True)

    def note(self, text: str, *, markup: bool = False) -> None:
        """A line kept on stderr above the live display (e.g. one validated scene), unless quiet.

        Parameters
        ----------
        text : str
            The line.
        markup : bool
            Interpret rich markup in ``text`` (escape user strings first).
        """
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.console.print(text, markup=markup, highlight=False)
        elif markup:
            self.console.print(text, markup=True, highlight=False)
        else:
            click.echo(text, err=True)


def stage_progress(ctx: click.Context, label: str, as_json: bool = False, console=None) -> StageProgress:
    """The progress display of a command: quiet under ``-q`` or ``--json``, live on a terminal.

    Parameters
    ----------
    ctx : click.Context
        The command's context (``ctx.obj["quiet"]`` holds ``-q``).
    label : str
        Shown before the bar, e.g. ``"gcpcal ortho"``.
    as_json : bool
        The command's ``--json`` flag.
    console : rich.console.Console, optional
        The stderr console (tests force a terminal with it).

    Returns
    -------
    StageProgress
        Not yet started: use it in a ``with`` block.
    """
    from calibrate.cli.options import quiet_of

    return StageProgress(label, quiet=quiet_of(ctx, as_json), console=console)


def scene_lines(bar: StageProgress, ok_text):
    """The ``progress(done, total, row)`` callback of a many-scene command: one stderr line per scene.

    Parameters
    ----------
    bar : StageProgress
        The command's progress.
    ok_text : callable(row) -> str
        The line of a scene that succeeded, after its name (rich markup allowed; escape values).

    Returns
    -------
    callable(done, total, row)
        ``row`` None when the work starts (the workers are starting); else a finished scene's row
        (``name``, ``status``, ``reason`` and what ``ok_text`` reads).
    """
    from rich.markup import escape

    def progress(done, total, row):
        if row is None:
            bar.count(0, total)
            bar.status("starting the workers")
            return
        if row["status"] == "ok":
            text = f"{escape(row['name'])}: {ok_text(row)}"
        else:
            text = f"{escape(row['name'])}: [red]failed[/red] ({escape(row['reason'] or '')})"
        bar.note(text, markup=True)
        bar.count(done, total)
        bar.status(row["name"])

    return progress

