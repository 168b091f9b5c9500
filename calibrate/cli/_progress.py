"""The one progress display of ``gcpcal``: a rich bar on stderr, shown only where a person watches.

Every long stage (demo, simulate, match, calibrate, ortho, validate, ...) reports through one
:class:`StageProgress`. Its two callbacks fit the two kinds the stage actions take:

- :meth:`StageProgress.message` (``progress(str)``): a step, e.g. ``"coarse stage: 412 SIFT matches"``;
- :meth:`StageProgress.count` (``progress(done, total)``): work units done, e.g. ortho blocks.

Where it shows:

=============================  ==================================================================
stderr                         what appears
=============================  ==================================================================
a terminal                     a live rich display (spinner, bar, count, elapsed time, last step),
                               removed when the stage ends
not a terminal (file, pipe)    the step messages, one plain line each (a log); no live display
``-q`` or ``--json``           nothing
=============================  ==================================================================

stdout is never touched, so ``--json`` output stays pure JSON.
"""

from __future__ import annotations

import click

__all__ = ["StageProgress", "stage_progress"]


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

    def __enter__(self) -> "StageProgress":
        if self.live:
            from rich.markup import escape
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn,
                                       TimeElapsedColumn)

            self._bar = Progress(SpinnerColumn(), TextColumn(escape(self.label)), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), TextColumn("{task.description}"), console=self.console,
                                 transient=True)
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
        """Work units done out of ``total`` (None: unknown); shown on the live display only.

        Parameters
        ----------
        done : int
            Units done so far.
        total : int or None
            Units in all.
        """
        if self._bar is not None:
            self._bar.update(self._task, completed=done, total=total)

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
