"""Fault injection: every writing command under signals, a full disk, a failing read and a read-only target.

Modelled on SQLite's crash and I/O-error tests: each case runs one command with one fault, then
reruns it without the fault, and checks four invariants:

* inputs byte-identical: the SHA-256 of every input file is the same before and after both runs;
* outputs complete or absent: after the faulted run the output is absent, or it has exactly the
  files a clean run writes, each listed in gcpcal's ledger with its checksum (gcpcal's, whole);
* no residue after the rerun: no staging, no temporary file, nothing but the outputs and the
  inputs; a staging left by a killed run is removed by the rerun, which says so on stderr;
* exit codes as documented: 130 SIGINT, 143 SIGTERM, 129 SIGHUP (-9 for SIGKILL, which cannot be
  handled), 1 for a full disk, a failing read or a read-only target, and one stderr line without
  a traceback; the rerun ends as a clean run does.

Faults:

* ``<point>:<SIG>``: the command sends itself the signal at a named point of its output path
  (``guarded``: outputs checked, no work done; ``staging``: a staging folder exists; ``written``:
  every output staged, none moved; ``moving``: between two moves of the commit), through the hook
  :data:`calibrate.actions._staging.FAULT_ENV`: the real signal and its real handler;
* ``delay:<SIG>``: the signal arrives from outside after a seeded delay within the command's run;
* ``enospc``: the output folder is a 4 KiB tmpfs (as root where ``mount`` works); elsewhere the
  process's file-size limit (``RLIMIT_FSIZE``) makes the write fail (EFBIG) in the same way;
* ``eio``: an input whose ``read`` fails with EIO (a link to ``/proc/self/mem``, whose first page
  is never mapped);
* ``readonly``: the output folder is a read-only mount (root) or a folder without write permission.

SIGINT, SIGTERM and SIGHUP cases run in-process (``calibrate.cli.main``, which installs the
handlers); SIGKILL, delays and the file-size limit run a subprocess. A sample runs by default
(``SAMPLE``, a few minutes); the full matrix is marked slow.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from calibrate.actions._ledger import LEDGER_NAME, owned
from calibrate.actions._staging import FAULT_ENV
from calibrate.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "hy1c_czi"
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
CODES = {"SIGINT": 130, "SIGTERM": 143, "SIGHUP": 129, "SIGKILL": -9}
#: Where a table of outcomes is appended (one JSON line per case) when set.
TABLE_ENV = "GCPCAL_FAULT_TABLE"


# --------------------------------------------------------------------------- inputs
@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Inputs of every command, copied into a folder of their own (their checksums are watched)."""
    from dataclasses import replace

    from sensor_models.simulate.star_sky import GeoStarsConfig, simulate_geo_stars

    root = tmp_path_factory.mktemp("fault_inputs")
    shutil.copytree(FIXTURE, root / "s")
    (root / "pts.csv").write_text("row,col\n10.5,10.5\n200.5,300.5\n")
    shutil.copytree(ROOT / "fixtures" / "oalr_marks", root / "oalr")
    s = root / "s"
    assert main(["-q", "match", str(s / "manifest.json"), "--dom", str(s / "reference" / "dom.tif"), "--dem",
                 str(s / "reference" / "dem.tif"), "--out", str(root / "gcps.csv"), "--spacing", "48"]) == 0
    simulate_geo_stars(root / "stars", config=replace(GeoStarsConfig(), n_frames=12))
    (root / "eio").mkdir()
    (root / "eio" / "manifest.json").symlink_to("/proc/self/mem")
    (root / "eio" / "pts.csv").symlink_to("/proc/self/mem")
    return root


def _s(d: Path, name: str) -> str:
    return str(d / "s" / name)


@dataclass(frozen=True)
class Command:
    """A writing command: its argv (inputs under ``d``, output under ``o``), output name, clean exit code."""

    name: str
    argv: object
    out: str
    code: int = 0
    eio: object = None  # argv with one input replaced by a failing one

    def args(self, d: Path, o: Path, *, eio=False) -> list[str]:
        build = self.eio if eio else self.argv
        return ["-q", *map(str, build(d, o))]


def _match(d, o, scene=None):
    return ["match", scene or _s(d, "manifest.json"), "--dom", _s(d, "reference/dom.tif"), "--dem",
            _s(d, "reference/dem.tif"), "--out", o / "gcps.csv", "--spacing", "96"]


COMMANDS = {c.name: c for c in [
    Command("match", _match, "gcps.csv", eio=lambda d, o: _match(d, o, d / "eio" / "manifest.json")),
    Command("calibrate", lambda d, o: ["calibrate", _s(d, "manifest.json"), "--gcps", d / "gcps.csv", "--out",
                                       o / "cal", "--no-report"], "cal", 4,
            eio=lambda d, o: ["calibrate", d / "eio" / "manifest.json", "--gcps", d / "gcps.csv", "--out", o / "cal",
                              "--no-report"]),
    Command("ortho", lambda d, o: ["ortho", _s(d, "manifest.json"), "--dem", _s(d, "reference/dem.tif"), "--band",
                                   "B2", "--resolution", "120", "--out", o / "o.tif"], "o.tif",
            eio=lambda d, o: ["ortho", d / "eio" / "manifest.json", "--dem", _s(d, "reference/dem.tif"), "--out",
                              o / "o.tif"]),
    Command("rpc", lambda d, o: ["rpc", _s(d, "manifest.json"), "--band", "B2", "--ccd", "cam1_ccd1", "--out",
                                 o / "c_RPC.TXT"], "c_RPC.TXT",
            eio=lambda d, o: ["rpc", d / "eio" / "manifest.json", "--out", o / "c_RPC.TXT"]),
    Command("localize", lambda d, o: ["localize", _s(d, "manifest.json"), "--csv", d / "pts.csv", "--height", "100",
                                      "--out", o / "p.csv"], "p.csv",
            eio=lambda d, o: ["localize", _s(d, "manifest.json"), "--csv", d / "eio" / "pts.csv", "--height", "100",
                              "--out", o / "p.csv"]),
    Command("truth error", lambda d, o: ["truth", "error", _s(d, "manifest.json"), "--truth",
                                         _s(d, "truth_manifest.json"), "--step", "256", "--out", o / "t.json"],
            "t.json", eio=lambda d, o: ["truth", "error", d / "eio" / "manifest.json", "--truth",
                                        _s(d, "truth_manifest.json"), "--out", o / "t.json"]),
    Command("simulate geo-stars", lambda d, o: ["simulate", "geo-stars", "--frames", "3", "--out", o / "sim"], "sim"),
    Command("stars", lambda d, o: ["stars", d / "stars", "--out", o / "st"], "st",
            eio=lambda d, o: ["stars", d / "stars", "--manifest", d / "eio" / "manifest.json", "--out", o / "st"]),
    Command("thermal", lambda d, o: ["thermal", "--days", "3", "--interval-min", "60", "--points", "50", "--out",
                                     o / "th"], "th"),
    Command("compensate", lambda d, o: ["compensate", "--step", "1000", "--no-figures", "--out", o / "comp"], "comp"),
    Command("oalr", lambda d, o: ["oalr", d / "oalr" / "marks.csv", "--out", o / "oalr"], "oalr"),
]}

POINTS = ("guarded", "staging", "written", "moving")
SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP", "SIGKILL")
FAULTS = ([f"{p}:{s}" for p in POINTS for s in SIGNALS] + [f"delay:{s}" for s in SIGNALS]
          + ["enospc", "eio", "readonly"])

#: The default run's sample: every command once or twice, every kind of fault at least once.
SAMPLE = {
    ("match", "written:SIGTERM"), ("match", "moving:SIGKILL"), ("match", "enospc"), ("match", "eio"),
    ("calibrate", "staging:SIGHUP"), ("calibrate", "readonly"),
    ("ortho", "written:SIGINT"), ("rpc", "guarded:SIGTERM"), ("localize", "written:SIGKILL"),
    ("localize", "eio"), ("truth error", "moving:SIGTERM"), ("simulate geo-stars", "staging:SIGKILL"),
    ("stars", "written:SIGHUP"), ("thermal", "staging:SIGTERM"), ("compensate", "moving:SIGHUP"),
    ("compensate", "enospc"), ("oalr", "readonly"), ("oalr", "delay:SIGTERM"),
}


# --------------------------------------------------------------------------- invariants
def _tree(folder: Path) -> dict[str, str]:
    """Relative path -> SHA-256 (or the link's target) of everything under ``folder``."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = "-> " + os.readlink(p)
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _output_files(o: Path, name: str) -> dict[str, Path]:
    """The files of output ``name`` in folder ``o`` (a folder's tree, or the file and its sidecars)."""
    target = o / name
    if target.is_dir():
        return {str(p.relative_to(o)): p for p in target.rglob("*") if p.is_file() and p.name != LEDGER_NAME}
    stem = Path(name).stem
    return {p.name: p for p in o.iterdir() if p.is_file() and p.name != LEDGER_NAME and p.name.startswith(stem)}


def _residue(folder: Path) -> list[str]:
    marks = ("gcpcal-stage", "gcpcal-old", ".stage-", ".tmp", "gcpcal-probe")
    return [str(p) for p in folder.rglob("*") if any(m in p.name for m in marks)]


def _run_inprocess(argv, capsys, env=None):
    saved = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    try:
        code = main(argv)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    err = capsys.readouterr().err
    return code, [line for line in err.splitlines() if line.strip()]


def _startup_seconds() -> float:
    """Seconds until ``gcpcal`` runs (Python and the command modules imported): ``gcpcal --version``."""
    t0 = time.perf_counter()
    _run_subprocess(["--version"])
    return time.perf_counter() - t0


def _run_subprocess(argv, env=None, delay_s=None, signame=None, fsize=None, timeout=600):
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))

    def limit():
        if fsize is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    proc = subprocess.Popen([sys.executable, "-c", "import sys; from calibrate.cli import main; sys.exit(main())",
                             *argv], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, text=True,
                            preexec_fn=limit if fsize is not None else None)
    if delay_s is not None:
        try:
            proc.wait(timeout=delay_s)
        except subprocess.TimeoutExpired:
            proc.send_signal(getattr(signal, signame))
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, [line for line in err.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def clean_seconds():
    """Seconds a clean subprocess run of each command takes (measured once, for the delays)."""
    return {}


def _mount(folder: Path, *options: str) -> bool:
    folder.mkdir(parents=True, exist_ok=True)
    if not IS_ROOT or shutil.which("mount") is None:
        return False
    return subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join(options), "tmpfs", str(folder)],
                          capture_output=True).returncode == 0


def _umount(folder: Path) -> None:
    subprocess.run(["umount", str(folder)], capture_output=True)


def _record(row: dict) -> None:
    path = os.environ.get(TABLE_ENV)
    if path:
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")


def _cases():
    for name in COMMANDS:
        for fault in FAULTS:
            if fault == "eio" and COMMANDS[name].eio is None:
                continue
            marks = () if (name, fault) in SAMPLE else (pytest.mark.slow,)
            yield pytest.param(name, fault, marks=marks, id=f"{name}-{fault}")


@pytest.mark.parametrize("name, fault", list(_cases()))
def test_fault_then_rerun(name, fault, data, tmp_path, capsys, clean_seconds):
    cmd = COMMANDS[name]
    o = tmp_path / "out"
    o.mkdir()
    inputs_before = _tree(data)
    fixture_before = _tree(FIXTURE)
    row = {"command": name, "fault": fault}
    mounted = False
    kind, _, signame = fault.partition(":")
    if kind in POINTS and signame != "SIGKILL":
        # at "moving" the signal is held back until the moves are done, then stops the command
        code, lines = _run_inprocess(cmd.args(data, o), capsys, env={FAULT_ENV: f"{kind}:{signame}"})
        expected = {CODES[signame]}
    elif kind in POINTS:
        code, lines = _run_subprocess(cmd.args(data, o), env={FAULT_ENV: f"{kind}:{signame}"})
        expected = {CODES[signame]}
    elif kind == "delay":
        if name not in clean_seconds:
            t0 = time.perf_counter()
            probe = tmp_path / "probe"
            probe.mkdir()
            assert _run_subprocess(cmd.args(data, probe))[0] == cmd.code
            clean_seconds[name] = (_startup_seconds(), time.perf_counter() - t0)
            shutil.rmtree(probe)
        startup, total = clean_seconds[name]
        delay = startup + random.Random(f"{name}-{fault}").uniform(0.05, 0.95) * max(total - startup, 0.1)
        code, lines = _run_subprocess(cmd.args(data, o), delay_s=delay, signame=signame)
        # the run may end before the signal; a signal before gcpcal runs (Python still starting under
        # load) ends the process as the system does, before anything is written
        expected = {CODES[signame], cmd.code, -getattr(signal, signame)}
    elif kind == "enospc":
        mounted = _mount(o, "size=4k")
        if mounted:
            code, lines = _run_inprocess(cmd.args(data, o), capsys)
        else:
            code, lines = _run_subprocess(cmd.args(data, o), fsize=64)
        expected = {1}
    elif kind == "eio":
        code, lines = _run_inprocess(cmd.args(data, o, eio=True), capsys)
        expected = {1}
    else:  # readonly
        mounted = _mount(o, "ro", "size=1m")
        if not mounted:
            if IS_ROOT:
                pytest.skip("root without mount: a folder's permissions do not stop root")
            os.chmod(o, 0o555)
        code, lines = _run_inprocess(cmd.args(data, o), capsys)
        expected = {1}
    row["code"] = code
    left_staging = bool(_residue(tmp_path))
    if left_staging and not mounted:  # what the next run does first: finish or remove a dead run's staging
        from calibrate.actions._staging import clean_stale

        capsys.readouterr()
        clean_stale(o)
        said = capsys.readouterr().err
        assert "interrupted gcpcal run" in said, said
    faulted = _output_files(o, cmd.out)
    faulted_owned = all(owned(p) for p in faulted.values())
    # the rerun, the fault gone
    if mounted:
        _umount(o)  # what the faulted run left went with the mount; checked above
    os.chmod(o, 0o755)
    rerun_code, rerun_lines = _run_inprocess(cmd.args(data, o), capsys)
    clean = _output_files(o, cmd.out)
    checks = {
        "exit code": code in expected and (code <= 0 or code == cmd.code or len(lines) >= 1)
        and not any("Traceback" in x for x in lines),
        "inputs identical": _tree(data) == inputs_before and _tree(FIXTURE) == fixture_before,
        "complete or absent": not faulted or (set(faulted) == set(clean) and faulted_owned),
        "no residue": not _residue(tmp_path) and rerun_code == cmd.code,
    }
    row.update({k: bool(v) for k, v in checks.items()})
    _record(row)
    assert checks["exit code"], (code, expected, lines)
    if code > 0 and code != cmd.code:
        assert len(lines) == 1, lines  # one line saying why
    assert checks["inputs identical"]
    assert checks["complete or absent"], (sorted(faulted), sorted(clean))
    assert rerun_code == cmd.code, rerun_lines
    assert not _residue(tmp_path), _residue(tmp_path)


def _handlers_restored(test):
    """Run ``test`` with gcpcal's signal handler on SIGTERM, the previous handlers restored after."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        from calibrate import cli as cli_package

        signal.signal(signal.SIGTERM, cli_package._on_signal)
        return test()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def test_signal_inside_an_import_lock_callback_stops_the_command_after_it():
    """A signal landing in code whose exceptions Python swallows is raised once that code returns.

    The import system drops a module lock through a weakref callback; an exception raised there
    is printed as "Exception ignored in ..." with a traceback, and the command runs on. Here the
    signal is delivered inside a function compiled as importlib's frozen bootstrap.
    """
    from calibrate.cli._errors import Interrupted

    from calibrate import cli as cli_package

    bootstrap = {}
    source = ("def cb(handler, signum, busy_s):\n"
              "    import sys, time\n"
              "    handler(signum, sys._getframe())\n"  # as Python calls it when the signal lands here
              "    end = time.perf_counter() + busy_s\n"
              "    while time.perf_counter() < end:\n"
              "        pass\n"
              "    return 'returned'\n")
    exec(compile(source, "<frozen importlib._bootstrap>", "exec"), bootstrap)

    def deliver():
        with pytest.raises(Interrupted) as raised:
            bootstrap["cb"](cli_package._on_signal, signal.SIGTERM, 0.05)
            for _ in range(10_000_000):  # ordinary code after the callback: the stop lands here
                pass
        return raised

    raised = _handlers_restored(deliver)
    files = []
    tb = raised.tb
    while tb is not None:
        files.append(tb.tb_frame.f_code.co_filename)
        tb = tb.tb_next
    # raised where ordinary code resumed, not inside the callback (where it would be swallowed)
    assert not any(name.startswith("<frozen") for name in files), files
    assert signal.getsignal(signal.SIGALRM) == signal.SIG_DFL


def test_signal_in_ordinary_code_stops_at_once():
    """The negative control: in ordinary code the handler raises where the signal lands."""
    from calibrate.cli._errors import Interrupted

    def deliver():
        with pytest.raises(Interrupted):
            signal.raise_signal(signal.SIGTERM)
            for _ in range(1000):
                pass
        return True

    assert _handlers_restored(deliver)
