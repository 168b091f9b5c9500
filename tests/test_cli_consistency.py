"""One consistent command line (issue 14 item 5): -q/-v anywhere, exit 3/4 reasons, the height family,
--json on every command, the progress display only on a terminal, uncut table names, OALR marks."""

from __future__ import annotations

import io
import json
import os
import pty
import select
import subprocess
import sys
from pathlib import Path

import click
import numpy as np
import pytest

from calibrate.cli import cli, load_all_commands, main

load_all_commands()  # the group imports a command's module on demand: walk them all

ROOT = Path(__file__).resolve().parents[1]
HY1C = ROOT / "fixtures" / "hy1c_czi"
SCENE = HY1C / "manifest.json"
TRUTH = HY1C / "truth_manifest.json"
DEM = HY1C / "reference" / "dem.tif"
EXAMPLE = ROOT / "fixtures" / "example_pushbroom" / "manifest.json"
MARKS = ROOT / "fixtures" / "oalr_marks" / "marks.csv"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _leaves(group: click.Group, prefix=()):
    for name, cmd in sorted(group.commands.items()):
        if isinstance(cmd, click.Group):
            yield from _leaves(cmd, prefix + (name,))
        else:
            yield prefix + (name,), cmd


@pytest.fixture(scope="module")
def exact_gcps(tmp_path_factory) -> Path:
    """A GCP table of the reference band B2 from the TRUE model (every 4th point a check point)."""
    folder = tmp_path_factory.mktemp("gcps")
    rows, cols = np.meshgrid(np.linspace(20.5, 492.5, 12), np.linspace(20.5, 748.5, 24), indexing="ij")
    code = main(["localize", str(TRUTH), "--rows", ",".join(map(str, rows.ravel())), "--cols",
                 ",".join(map(str, cols.ravel())), "--height", "200", "--out", str(folder / "points.csv")])
    assert code == 0
    lines = (folder / "points.csv").read_text().splitlines()
    header = lines[0].split(",")
    out = ["id,row,col,lon,lat,h,kind"]
    for i, line in enumerate(lines[1:]):
        rec = dict(zip(header, line.split(",")))
        out.append(f"p{i},{rec['row']},{rec['col']},{rec['lon']},{rec['lat']},{rec['h']},"
                   f"{'check' if i % 4 == 0 else 'gcp'}")
    (folder / "gcps.csv").write_text("\n".join(out) + "\n")
    return folder / "gcps.csv"


# ----------------------------------------------------------------------------- -q / -v after the command
def test_every_command_takes_q_and_v_and_json():
    for path, cmd in _leaves(cli):
        names = {opt for p in cmd.params for opt in getattr(p, "opts", ())}
        assert {"-q", "--quiet", "-v", "--verbose"} <= names, path
        assert "--json" in names, f"gcpcal {' '.join(path)} has no --json"


@pytest.mark.parametrize("where", ["before", "after name", "at the end"])
def test_q_anywhere_silences_the_steps_of_calibrate(where, exact_gcps, tmp_path, capsys):
    args = [str(SCENE), "--gcps", str(exact_gcps), "--out", str(tmp_path / "cal"), "--no-report"]
    argv = {"before": ["-q", "calibrate", *args], "after name": ["calibrate", "-q", *args],
            "at the end": ["calibrate", *args, "-q"]}[where]
    code, out, err = run(capsys, *argv)
    assert code == 4  # partial: the bands B1, B3, B4 are left to gcpcal relative
    assert "GCPs, " not in err and "fitting" not in err  # the step lines are gone ...
    assert err.strip().splitlines() == ["gcpcal: partial: band(s) B1, B3, B4 without GCPs: run gcpcal relative"]
    assert "PARTIAL" in out  # ... the result stays on stdout


def test_without_q_the_steps_are_stderr_lines(exact_gcps, tmp_path, capsys):
    code, _out, err = run(capsys, "calibrate", SCENE, "--gcps", exact_gcps, "--out", tmp_path / "cal", "--no-report")
    assert code == 4
    assert "216 GCPs, 72 check points" in err and "fitting the model" in err
    assert err.strip().splitlines()[-1].startswith("gcpcal: partial: ")


def test_exit_4_reason_with_json_and_stdout_is_json_only(exact_gcps, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate", SCENE, "--gcps", exact_gcps, "--out", tmp_path / "cal", "--no-report",
                         "--json")
    assert code == 4
    assert json.loads(out)["status"] == "partial"
    assert err.strip().splitlines() == ["gcpcal: partial: band(s) B1, B3, B4 without GCPs: run gcpcal relative"]


def test_exit_3_reason_under_q(exact_gcps, tmp_path, capsys):
    two = tmp_path / "two.csv"
    lines = exact_gcps.read_text().splitlines()
    two.write_text("\n".join([lines[0], lines[2], lines[3]]) + "\n")  # two GCPs: too few to fit
    code, out, err = run(capsys, "calibrate", "-q", SCENE, "--gcps", two, "--out", tmp_path / "cal", "--no-report")
    assert code == 3 and "FAILED" in out
    err_lines = err.strip().splitlines()
    assert len(err_lines) == 1 and err_lines[0].startswith("gcpcal: failed: ") and "too few observations" in err[0:400]


def test_v_after_the_command_shows_the_traceback(monkeypatch, tmp_path, capsys):
    import calibrate.cli as cli_package

    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(cli_package.rpc, "fit_rpcs", broken)
    code, _out, err = run(capsys, "rpc", EXAMPLE, "--out", tmp_path / "x_RPC.TXT")
    assert code == 1 and "Traceback" not in err
    code, _out, err = run(capsys, "rpc", EXAMPLE, "--out", tmp_path / "x_RPC.TXT", "-v")
    assert code == 1 and "Traceback" in err


# ----------------------------------------------------------------------------- the height family
def test_truth_height_family(tmp_path, capsys):
    code, out, _ = run(capsys, "truth", "error", SCENE, "--truth", TRUTH, "--height", "500", "--step", "64", "--json")
    assert code == 0
    at_500 = json.loads(out)
    code, out, _ = run(capsys, "truth", "error", SCENE, "--truth", TRUTH, "--height-range", "0", "1000", "--step",
                       "64", "--json")
    assert code == 0
    spanned = json.loads(out)
    assert spanned["n_points"] == 3 * at_500["n_points"]  # planes at 0, 500 and 1000 m
    assert 1.0 < spanned["rms_px"] < 1e4 and 1.0 < at_500["rms_px"] < 1e4  # the LAB model is off by pixels
    code, out, _ = run(capsys, "truth", "error", SCENE, "--truth", TRUTH, "--dem", DEM, "--step", "64", "--json")
    assert code == 0 and json.loads(out)["rms_px"] != at_500["rms_px"]
    code, _, err = run(capsys, "truth", "error", SCENE, "--truth", TRUTH, "--heights", "0", "--json")
    assert code == 2 and "No such option '--heights'" in err


@pytest.mark.parametrize("argv", [
    ["truth", "error", str(SCENE), "--truth", str(TRUTH), "--height", "0", "--dem", str(DEM)],
    ["truth", "error", str(SCENE), "--truth", str(TRUTH), "--height", "0", "--height-range", "0", "9"],
    ["localize", str(EXAMPLE), "--rows", "1", "--cols", "1", "--height", "0", "--dem", str(DEM)],
    ["rpc", str(EXAMPLE), "--out", "x_RPC.TXT", "--height-range", "0", "9", "--dem", str(DEM)],
])
def test_two_height_sources_are_a_usage_error(argv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.startswith("gcpcal: error: give one of --height") and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_height_options_read_the_same_everywhere():
    seen = {}
    for path, cmd in _leaves(cli):
        for p in cmd.params:
            for opt in getattr(p, "opts", ()):
                if opt in ("--height", "--height-range", "--dem", "--dem-datum", "--geoid"):
                    seen.setdefault(opt, {})[" ".join(path)] = (p.help, p.nargs, p.type.name)
    for opt in ("--height", "--height-range", "--dem"):
        variants = set(seen[opt].values())
        if opt == "--dem":  # simulate renders from a DEM that declares its datum: its own text
            variants = {v for k, v in seen[opt].items() if not k.startswith("simulate")}
        assert len(variants) == 1, (opt, seen[opt])
    assert {"localize", "truth error"} <= set(seen["--height"])
    assert {"rpc", "truth error"} <= set(seen["--height-range"])


# ----------------------------------------------------------------------------- --json prints JSON only
@pytest.mark.parametrize("name, argv", [
    ("localize", ["localize", str(EXAMPLE), "--rows", "1,2", "--cols", "1,2", "--height", "0", "--json"]),
    ("rpc", ["rpc", str(EXAMPLE), "--ccd", "ccd1", "--out", "{tmp}/x_RPC.TXT", "--json"]),
    ("truth", ["truth", "error", str(SCENE), "--truth", str(TRUTH), "--height", "0", "--step", "64", "--json"]),
    ("oalr", ["oalr", str(MARKS), "--out", "{tmp}/oalr", "--json"]),
    ("thermal", ["thermal", "--out", "{tmp}/th", "--days", "2", "--points", "50", "--max-order", "1", "--json"]),
    ("compensate", ["compensate", "--out", "{tmp}/c", "--step", "1000", "--no-figures", "--scheme", "ICO", "--json"]),
    ("geo-stars", ["simulate", "geo-stars", "--out", "{tmp}/gs", "--frames", "3", "--json"]),
])
def test_json_is_alone_on_stdout(name, argv, tmp_path, capsys):
    code, out, _err = run(capsys, *[a.format(tmp=tmp_path) for a in argv])
    assert code == 0, _err
    doc = json.loads(out)  # the whole of stdout is one JSON document
    assert isinstance(doc, dict) and doc
    assert out.strip().count("\n") == 0


# ----------------------------------------------------------------------------- progress: terminals only
def _run_with_stderr_on_a_pty(argv: list[str], timeout_s: float = 120.0) -> tuple[int, str, str]:
    """Run ``gcpcal argv`` with stderr on a pseudo-terminal and stdout on a pipe."""
    primary, secondary = pty.openpty()
    env = dict(os.environ, PYTHONPATH=str(ROOT), COLUMNS="100", TERM="xterm")
    env.pop("NO_COLOR", None)
    code = "import sys; from calibrate.cli import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, *argv], stdout=subprocess.PIPE, stderr=secondary,
                            stdin=subprocess.DEVNULL, env=env)
    os.close(secondary)
    chunks = []
    while True:
        ready, _, _ = select.select([primary], [], [], timeout_s)
        if not ready:
            proc.kill()
            break
        try:
            data = os.read(primary, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(primary)
    out = proc.stdout.read().decode()
    return proc.wait(timeout=timeout_s), out, b"".join(chunks).decode(errors="replace")


@pytest.mark.parametrize("extra, shown", [([], True), (["-q"], False), (["--json"], False)])
def test_progress_display_on_a_terminal_only(extra, shown, exact_gcps, tmp_path):
    argv = ["calibrate", str(SCENE), "--gcps", str(exact_gcps), "--out", str(tmp_path / "cal"), *extra]
    code, out, err = _run_with_stderr_on_a_pty(argv)
    assert code == 4, err
    assert ("gcpcal calibrate" in err) is shown  # the live display's label
    assert ("\x1b[" in err) is shown  # cursor and colour codes: a live display, never in a log
    assert "gcpcal calibrate" not in out and "\x1b" not in out  # never on stdout
    assert "partial: band(s) B1, B3, B4" in err  # the exit reason, whatever the flags
    if extra == ["--json"]:
        assert json.loads(out)["status"] == "partial"


def test_no_progress_display_when_stderr_is_a_file(exact_gcps, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    code = "import sys; from calibrate.cli import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, "calibrate", str(SCENE), "--gcps", str(exact_gcps), "--out",
                           str(tmp_path / "cal"), "--no-report"], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 4, proc.stderr
    assert "gcpcal calibrate" not in proc.stderr and "\x1b" not in proc.stderr and "\r" not in proc.stderr
    assert "fitting the model" in proc.stderr  # the steps, as plain lines


def test_stage_progress_forced_terminal_and_quiet():
    from rich.console import Console

    from calibrate.cli._progress import StageProgress

    for quiet, live in ((False, True), (True, False)):
        buf = io.StringIO()
        console = Console(file=buf, force_terminal=True, width=100)
        with StageProgress("gcpcal test-stage", quiet=quiet, console=console) as progress:
            assert progress.live is live
            progress.count(3, 10)
            progress.message("step two")
        assert ("gcpcal test-stage" in buf.getvalue()) is live
    plain = Console(file=io.StringIO(), force_terminal=False)
    assert StageProgress("x", quiet=False, console=plain).live is False


def test_counted_progress_off_a_terminal_prints_tenths_with_time_left(monkeypatch, capsys):
    """Off a terminal, counted work prints a plain line at each further tenth once the stage has
    run 2 s, with the time left from the rate since counting began; nothing before 2 s, none
    under -q."""
    import io

    from rich.console import Console

    import calibrate.cli._progress as progress_module
    from calibrate.cli._progress import StageProgress, format_seconds

    clock = [100.0]
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: clock[0])
    with StageProgress("gcpcal match: windows", quiet=False, console=Console(file=io.StringIO())) as progress:
        progress.count(0, 1000)
        clock[0] += 1.0
        progress.count(150, 1000)  # 1 s: too early for a line
        clock[0] += 2.0
        progress.count(300, 1000)  # 3 s, 300 done at 100/s: 7 s left
        progress.count(320, 1000)  # same tenth: no line
        clock[0] += 7.0
        progress.count(1000, 1000)
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == ["gcpcal match: windows 30 % (300/1000), 3 s, about 7 s left",
                     "gcpcal match: windows 100 % (1000/1000), 10 s"]
    with StageProgress("x", quiet=True, console=Console(file=io.StringIO())) as progress:
        clock[0] += 5.0
        progress.count(5, 10)
    assert capsys.readouterr().err == ""
    assert [format_seconds(s) for s in (0.4, 59.6, 200, 3725)] == ["0 s", "1 min 00 s", "3 min 20 s", "1 h 02 min"]


# ----------------------------------------------------------------------------- tables keep whole names
def test_validate_table_folds_long_scene_names():
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from calibrate.cli.validate import _print_table

    name = "LC08_L1TP_196029_20230815_20230822_02_T1_very_long_validation_site_name_[x]_end"
    row = {"status": "ok", "name": name, "date": "2023-08-15", "rmse_along_px": 0.1, "rmse_across_px": 0.2,
           "rmse_planar_px": 0.22, "rmse_planar_m": 11.0, "points": 120, "lab_rmse_planar_px": 40.0}
    summary = {"mean": {k: row[k] for k in ("rmse_along_px", "rmse_across_px", "rmse_planar_px", "rmse_planar_m",
                                            "points", "lab_rmse_planar_px")},
               "ok": 1, "scenes": 1, "failures": {}, "seconds": 1.0, "workers": 1}
    buf = io.StringIO()
    _print_table(Console(file=buf, width=80, force_terminal=False), Table, escape, [row], summary, "out")
    text = buf.getvalue()
    assert "…" not in text and "..." not in text
    cells = "".join(line.split("│")[2].strip() for line in text.splitlines() if line.count("│") > 3)
    assert name in cells  # folded over several lines, every character kept


# ----------------------------------------------------------------------------- the OALR marks example
def test_oalr_example_recovers_the_injected_changes(tmp_path, capsys):
    sys.path.insert(0, str(ROOT / "fixtures"))
    from make_oalr_marks import NOISE_PX, build, injected_changes

    from calibrate.schemes.autocollimation import ARCSEC

    assert MARKS.read_text() == build()  # the committed file is the generator's
    code, _out, err = run(capsys, "oalr", MARKS, "--out", tmp_path / "o", "--sigma-k-px", NOISE_PX)
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "oalr.json").read_text())
    truth = injected_changes()
    est = {k: np.array([e[k] for e in doc["epochs"]]) for k in ("delta_f_mm", "rot_x_arcsec", "rot_y_arcsec",
                                                               "rot_z_arcsec")}
    pairs = (("delta_f_mm", truth.delta_f_mm, "sigma_f_mm"), ("rot_x_arcsec", truth.rot_x_rad / ARCSEC,
             "sigma_rot_x_arcsec"), ("rot_y_arcsec", truth.rot_y_rad / ARCSEC, "sigma_rot_y_arcsec"),
             ("rot_z_arcsec", truth.rot_z_rad / ARCSEC, "sigma_rot_z_arcsec"))
    for key, true, sigma in pairs:
        s = doc["sigmas"][sigma]
        assert np.all(np.abs(est[key] - true) < 4.0 * s), key  # within the noise ...
        assert np.max(np.abs(est[key])) > 6.0 * s, key  # ... and the changes are far above it


def test_simulate_line_says_when_the_lab_error_is_not_measurable(tmp_path):
    """A scene shorter than the LAB model's error: every compared point falls outside; said, no crash."""
    import json as _json

    from calibrate.cli import main

    cfg = tmp_path / "tiny.json"
    cfg.write_text(_json.dumps({"scene": {"n_rows": 64}}))
    assert main(["simulate", "pushbroom", "--config", str(cfg), "--out", str(tmp_path / "sim")]) == 0
    summary = _json.loads((tmp_path / "sim" / "summary.json").read_text())
    assert summary["lab_truth_error_px"]["rms"] is None
