"""The command line's structure: every command registered, actions free of click, one error boundary."""

from __future__ import annotations

import ast
import os
from pathlib import Path

import click
import pytest

import calibrate.cli as cli_package
from calibrate.cli import COMMAND_MODULES, cli, main

ROOT = Path(__file__).resolve().parents[1]
CLI_DIR = ROOT / "calibrate" / "cli"
ACTIONS_DIR = ROOT / "calibrate" / "actions"
EXAMPLE = str(ROOT / "fixtures" / "example_pushbroom" / "manifest.json")
SHARED_MODULES = {"__init__", "options", "_errors"}


def _command_paths(group: click.Group, prefix=()):
    for name, cmd in sorted(group.commands.items()):
        yield prefix + (name,)
        if isinstance(cmd, click.Group):
            yield from _command_paths(cmd, prefix + (name,))


def test_every_command_module_is_registered():
    on_disk = {p.stem for p in CLI_DIR.glob("*.py")} - SHARED_MODULES
    registered = {m.__name__.rsplit(".", 1)[1] for m in COMMAND_MODULES}
    assert on_disk == registered
    assert {m.command.name for m in COMMAND_MODULES} == set(cli.commands)
    for module in COMMAND_MODULES:
        assert cli.commands[module.command.name] is module.command
        assert module.__doc__, f"{module.__name__} has no module docstring"


def test_registration_is_explicit():
    source = (CLI_DIR / "__init__.py").read_text(encoding="utf-8")
    assert "importlib" not in source and "ModuleNotFoundError" not in source


@pytest.mark.parametrize("path", list(_command_paths(cli)), ids=" ".join)
def test_help_of_every_command_and_subcommand(path, capsys):
    assert main([*path, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Usage: gcpcal " + " ".join(path))


def test_group_help_documents_the_exit_codes(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for code in ("0", "1", "2", "3", "4", "130"):
        assert f"\n    {code} " in out


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return names


@pytest.mark.parametrize("path", sorted(ACTIONS_DIR.glob("*.py")), ids=lambda p: p.name)
def test_actions_import_neither_click_nor_the_cli(path):
    bad = {n for n in _imports(path) if n.split(".")[0] == "click" or n.startswith("calibrate.cli")}
    assert not bad, f"{path.name} imports {sorted(bad)}"


def test_library_modules_import_neither_actions_nor_cli():
    for path in (ROOT / "calibrate").glob("*.py"):
        bad = {n for n in _imports(path) if n.startswith(("calibrate.cli", "calibrate.actions", "click"))}
        assert not bad, f"{path.name} imports {sorted(bad)}"
    for pkg in ("gcpmatch", "sensor_models"):
        for path in (ROOT / pkg).rglob("*.py"):
            assert not {n for n in _imports(path) if n.startswith("calibrate")}, path


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_missing_input_is_exit_1_in_one_line(tmp_path, capsys):
    missing = tmp_path / "nothing.json"
    code = main(["localize", str(missing), "--rows", "1", "--cols", "1", "--height", "0"])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 1 and line.startswith("gcpcal: error:") and str(missing.name) in line


def test_unwritable_folder_is_exit_1_naming_the_file(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("running as root: chmod does not stop writes")
        out = locked / "sub" / "points.csv"
        code = main(["localize", EXAMPLE, "--rows", "1", "--cols", "1", "--height", "0", "--out", str(out)])
        line = _one_error_line(capsys.readouterr().err)
    finally:
        locked.chmod(0o700)
    assert code == 1
    assert line.startswith("gcpcal: error: ") and str(locked) in line and "Permission denied" in line


def test_output_under_a_file_is_exit_1_naming_the_file(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    out = blocker / "points.csv"
    code = main(["localize", EXAMPLE, "--rows", "1", "--cols", "1", "--height", "0", "--out", str(out)])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 1 and line.startswith("gcpcal: error: ") and str(blocker) in line


def test_usage_error_is_exit_2(capsys):
    assert main(["localize", EXAMPLE, "--no-such-option"]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_interrupt_is_exit_130(monkeypatch, tmp_path, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_package.rpc, "fit_rpcs", interrupted)
    code = main(["rpc", EXAMPLE, "--out", str(tmp_path / "x_RPC.TXT")])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 130 and line == "gcpcal: interrupted"


def test_internal_error_is_one_line_and_v_shows_the_traceback(monkeypatch, tmp_path, capsys):
    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(cli_package.rpc, "fit_rpcs", broken)
    code = main(["rpc", EXAMPLE, "--out", str(tmp_path / "x_RPC.TXT")])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 1
    assert line == "gcpcal: internal error: ZeroDivisionError: a bug (run with -v for the traceback)"
    assert main(["-v", "rpc", EXAMPLE, "--out", str(tmp_path / "x_RPC.TXT")]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_bad_scheduler_address_is_exit_1(tmp_path, capsys):
    sites = tmp_path / "sites.csv"
    sites.write_text("name,scene,dom,dem\n")
    code = main(["validate", str(sites), "--calibration", str(tmp_path), "--out", str(tmp_path / "o"),
                 "--scheduler", "tcp://host:notaport"])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 1 and line.startswith("gcpcal: error: tcp://host:notaport")
