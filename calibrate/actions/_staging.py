"""Staging names gcpcal can recognise as its own, their cleanup after a crash, and signal-safe commits.

Every staging folder or temporary file gcpcal makes beside an output is named

    ``.<output name>.gcpcal-stage.<host>.<pid>.<random>``   (``gcpcal-old`` for a folder set aside)

so that a later run can tell that it is gcpcal's, which host and process made it, and whether
that process still runs. A process killed outright (SIGKILL, a power cut) cannot clean up; the
next run of any command that writes into the same folder removes the staging of dead processes
of this host (:func:`clean_stale`) and says so on stderr. A staging folder holding a commit
journal (:data:`JOURNAL_NAME`: the process was killed while moving its complete outputs into
place) is rolled forward first: the moves it lists are finished, so the outputs end whole. A
folder set aside during a swap whose new folder never arrived is put back, not deleted. Staging of a live process, of another host
(a shared filesystem) or of any other name is never touched.

:func:`signals_deferred` holds SIGINT, SIGTERM and SIGHUP back while outputs are moved into
place (a handful of renames), so a handled signal ends a command before or after the move,
never in the middle of it.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

__all__ = ["ASIDE_TAG", "FAULT_ENV", "JOURNAL_NAME", "STAGE_TAG", "write_journal", "clean_stale", "fault_point", "make_stage_dir", "make_temp_file",
           "pid_alive", "say", "signals_deferred", "stage_prefix"]

STAGE_TAG = "gcpcal-stage"
#: Journal of a commit in progress, inside its staging folder: ``{"moves": [[staged, final], ...],
#: "remove": [final, ...]}`` (absolute paths), written before the first move (:func:`write_journal`).
JOURNAL_NAME = ".gcpcal-commit.json"
ASIDE_TAG = "gcpcal-old"
_STAGE_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<tag>gcpcal-stage|gcpcal-old)\.(?P<host>[A-Za-z0-9_-]+)\."
                         r"(?P<pid>\d+)\.[^.]*$")
#: The temporary folder of a staged write whose target is itself a run's staging folder
#: (``sensor_models.files.atomic.staged``: ``.<target name>.stage-XXXX`` beside the target).
_NESTED_STAGE_NAME = re.compile(r"^\.(?P<inner>\..+)\.stage-[^.]*$")
_DEFERRED = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


#: Fault-injection hook of the test suite (tests/test_fault_injection.py): ``<point>:<SIGNAME>``
#: makes the process send itself that signal the first time it reaches ``<point>``
#: (:func:`fault_point`), so that the real signal path runs at a chosen moment.
FAULT_ENV = "GCPCAL_TEST_SIGNAL"


def fault_point(name: str) -> None:
    """Send the signal named by :data:`FAULT_ENV` to this process if ``name`` is its point (once).

    Points: ``guarded`` (outputs checked, no work done), ``staging`` (a staging folder exists),
    ``written`` (every output staged, none moved), ``moving`` (between two moves of a commit).

    Parameters
    ----------
    name : str
    """
    spec = os.environ.get(FAULT_ENV)
    if not spec or spec.partition(":")[0] != name:
        return
    del os.environ[FAULT_ENV]
    os.kill(os.getpid(), getattr(signal, spec.partition(":")[2]))


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9_-]", "-", socket.gethostname() or "host")[:64] or "host"


def say(message: str) -> None:
    """Print one ``gcpcal: <message>`` line on stderr (whatever ``-q`` says: it reports a change on disk).

    Parameters
    ----------
    message : str
    """
    print(f"gcpcal: {message}", file=sys.stderr, flush=True)


def stage_prefix(name: str, tag: str = STAGE_TAG) -> str:
    """``.<name>.<tag>.<host>.<pid>.``: the start of a staging name of this process.

    Parameters
    ----------
    name : str
        The output's file or folder name.
    tag : str
        :data:`STAGE_TAG` or :data:`ASIDE_TAG`.

    Returns
    -------
    str
    """
    return f".{name}.{tag}.{_host()}.{os.getpid()}."


def make_stage_dir(parent, name: str, tag: str = STAGE_TAG) -> Path:
    """A new, empty staging folder of this process in ``parent`` for output ``name``.

    Parameters
    ----------
    parent : str or Path
        Existing folder (the output's, so that renames stay on one filesystem).
    name : str
        The output's name.
    tag : str
        :data:`STAGE_TAG` or :data:`ASIDE_TAG`.

    Returns
    -------
    Path
    """
    return Path(tempfile.mkdtemp(prefix=stage_prefix(name, tag), dir=parent))


def make_temp_file(parent, name: str) -> Path:
    """A new, empty temporary file of this process in ``parent`` for output ``name`` (mode 0644).

    Parameters
    ----------
    parent : str or Path
        Existing folder.
    name : str
        The output's name.

    Returns
    -------
    Path
    """
    fd, tmp = tempfile.mkstemp(prefix=stage_prefix(name), dir=parent)
    os.close(fd)
    os.chmod(tmp, 0o644)
    return Path(tmp)


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host runs (a zombie counts as dead).

    Parameters
    ----------
    pid : int

    Returns
    -------
    bool
    """
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return True
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            return fh.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:
        return True


def write_journal(stage, moves, remove=()) -> Path:
    """Write the commit journal of staging folder ``stage`` (before its first move).

    Parameters
    ----------
    stage : Path
        The staging folder (the journal goes inside it).
    moves : iterable of (Path, Path)
        ``(staged file, final file)`` pairs.
    remove : iterable of Path
        Final files to remove (gcpcal's stale outputs).

    Returns
    -------
    Path
        The journal.
    """
    import json

    doc = {"moves": [[str(a), str(b)] for a, b in moves], "remove": [str(p) for p in remove]}
    path = Path(stage) / JOURNAL_NAME
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(doc), encoding="utf-8")
    os.replace(tmp, path)
    return path


def _roll_forward(stage: Path) -> bool:
    """Finish the moves of a killed commit whose journal is in ``stage``; True when there was one."""
    import json

    try:
        doc = json.loads((stage / JOURNAL_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    for src, final in doc.get("moves", ()):
        if stage in Path(src).parents and os.path.lexists(src):  # this staging folder's own files
            Path(final).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, final)
    for final in doc.get("remove", ()):
        Path(final).unlink(missing_ok=True)
    return True


def clean_stale(*folders) -> list[Path]:
    """Remove the staging that dead gcpcal processes of this host left in ``folders``; say so.

    A folder set aside (``gcpcal-old``) whose output is missing is renamed back onto it.

    Parameters
    ----------
    *folders : str or Path
        Folders to look in (missing ones are skipped).

    Returns
    -------
    list of Path
        What was removed or put back.
    """
    host, done = _host(), []
    for folder in dict.fromkeys(Path(f) for f in folders if f is not None):
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            m, nested = _STAGE_NAME.match(entry.name), False
            if m is None:  # a staged write into a run's staging, killed before its rename
                outer = _NESTED_STAGE_NAME.match(entry.name)
                m = None if outer is None else _STAGE_NAME.match(outer["inner"])
                nested = m is not None
            if m is None or m["host"] != host or pid_alive(int(m["pid"])):
                continue
            path = Path(entry.path)
            target = path.parent / m["name"]
            try:
                if nested:
                    shutil.rmtree(path) if entry.is_dir(follow_symlinks=False) else path.unlink()
                    say(f"removed {path}, an unfinished write of an interrupted gcpcal run (pid {m['pid']})")
                elif m["tag"] == ASIDE_TAG and not os.path.lexists(target):
                    os.rename(path, target)
                    say(f"put back {target}, set aside by an interrupted gcpcal run (pid {m['pid']})")
                elif entry.is_dir(follow_symlinks=False):
                    if _roll_forward(path):
                        say(f"finished moving the outputs of an interrupted gcpcal run (pid {m['pid']}) from {path}")
                    shutil.rmtree(path)
                    say(f"removed {path}, staging left by an interrupted gcpcal run (pid {m['pid']})")
                else:
                    path.unlink()
                    say(f"removed {path}, a temporary file left by an interrupted gcpcal run (pid {m['pid']})")
            except OSError:
                continue  # another run got there first, or no permission: leave it
            done.append(path)
    return done


@contextmanager
def signals_deferred():
    """Hold SIGINT, SIGTERM and SIGHUP back for the block (main thread; elsewhere a no-op).

    Their handlers are swapped for one that only notes the signal (a process-directed signal may
    be taken by any thread, so a thread's signal mask is not enough); when the block ends the
    handlers are restored and each signal noted is handed to its handler, as if it arrived then.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []
    previous = {}
    try:
        for signum in _DEFERRED:
            previous[signum] = signal.signal(signum, lambda n, frame: noted.append(n))
    except ValueError:  # not the main interpreter
        previous = {}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(noted):
            handler = previous.get(signum)
            if callable(handler):
                handler(signum, None)  # the handler raises (Ctrl-C, gcpcal's handler) as it would have
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), signum)
