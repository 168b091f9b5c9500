"""The command line's structure: every command registered, actions free of click, one error boundary."""

from __future__ import annotations

import ast
import importlib
import os
from pathlib import Path

import click
import pytest

import calibrate.cli as cli_package
from calibrate.cli import COMMANDS, cli, load_all_commands, main

ROOT = Path(__file__).resolve().parents[1]
CLI_DIR = ROOT / "calibrate" / "cli"
ACTIONS_DIR = ROOT / "calibrate" / "actions"
EXAMPLE = str(ROOT / "fixtures" / "example_pushbroom" / "manifest.json")
SHARED_MODULES = {"__init__", "options", "_errors", "_progress"}


ALL_COMMANDS = load_all_commands()


def _command_paths(group: click.Group, prefix=()):
    for name, cmd in sorted(group.commands.items()):
        yield prefix + (name,)
        if isinstance(cmd, click.Group):
            yield from _command_paths(cmd, prefix + (name,))


def test_every_command_module_is_registered():
    on_disk = {p.stem for p in CLI_DIR.glob("*.py")} - SHARED_MODULES
    registered = {module.rsplit(".", 1)[1] for module, _ in COMMANDS.values()}
    assert on_disk == registered
    assert set(ALL_COMMANDS) == set(COMMANDS) == set(cli.commands)
    for name, (module_name, _) in COMMANDS.items():
        module = importlib.import_module(module_name)
        assert ALL_COMMANDS[name] is module.command and module.command.name == name
        assert module.__doc__, f"{module.__name__} has no module docstring"


def test_registration_is_explicit():
    """The command table is a literal (no discovery of modules on disk)."""
    source = (CLI_DIR / "__init__.py").read_text(encoding="utf-8")
    assert "ModuleNotFoundError" not in source and "pkgutil" not in source and "glob(" not in source
    table = next(node for node in ast.parse(source).body
                 if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "COMMANDS")
    assert isinstance(table.value, ast.Dict) and all(isinstance(k, ast.Constant) for k in table.value.keys)


def test_the_command_table_shows_each_commands_own_summary():
    """``gcpcal --help`` lists the commands without importing them: each line must be the
    command's own first sentence."""
    for name, (_, summary) in COMMANDS.items():
        assert summary == ALL_COMMANDS[name].get_short_help_str(limit=10**6), name


def test_top_level_help_imports_no_command_and_answers_fast():
    """``gcpcal --help`` in a fresh interpreter imports no command module (nor numpy's heavy
    users); its wall time is printed, bounded loosely since CI machines are shared."""
    import subprocess
    import sys
    import time

    code = ("import sys, time; t = time.perf_counter(); from calibrate.cli import main; "
            "code = main(['--help']); loaded = sorted(m for m in sys.modules if m.startswith('calibrate.cli.') "
            "and m.rsplit('.', 1)[1] not in ('options', '_errors', '_progress')); "
            "print(repr(loaded), 'scipy' in sys.modules, 'cv2' in sys.modules, code)")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    wall = time.perf_counter() - t0
    print(f"gcpcal --help in a fresh interpreter: {wall:.3f} s")
    assert out.strip().splitlines()[-1] == "[] False False 0", out
    assert wall < 3.0


@pytest.mark.parametrize("path", list(_command_paths(cli)), ids=" ".join)
def test_help_of_every_command_and_subcommand(path, capsys):
    assert main([*path, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Usage: gcpcal " + " ".join(path))


def _all_commands(group: click.Group, prefix=("gcpcal",)):
    yield prefix, group
    for name, cmd in sorted(group.commands.items()):
        if isinstance(cmd, click.Group):
            yield from _all_commands(cmd, prefix + (name,))
        else:
            yield prefix + (name,), cmd


def test_every_option_and_argument_has_help():
    """Walk the click tree (the group, its subgroups, every command): no option without help text,
    no argument that the command's help does not name."""
    missing = []
    for path, cmd in _all_commands(cli):
        assert (cmd.help or "").strip(), f"{' '.join(path)} has no help"
        for param in cmd.params:
            if isinstance(param, click.Option):
                if not (param.help or "").strip():
                    missing.append(f"{' '.join(path)} {param.opts[0]}")
            elif isinstance(param, click.Argument):
                name = param.metavar or param.name.upper()
                if name.split(".")[0] not in cmd.help:
                    missing.append(f"{' '.join(path)} argument {name}")
    assert not missing, "without help: " + ", ".join(missing)


def test_help_walk_would_catch_an_option_without_help():
    @click.command("probe")
    @click.option("--bare")
    @click.argument("thing")
    def probe(bare, thing):
        """A command whose option and argument are undocumented."""

    group = click.Group("g", commands={"probe": probe})
    bad = [p for _, c in _all_commands(group) for p in c.params if isinstance(p, click.Option) and not p.help]
    assert [p.name for p in bad] == ["bare"]
    assert "THING" not in probe.help


def test_shell_completion_script_is_produced():
    """click 8's completion: ``_GCPCAL_COMPLETE=bash_source gcpcal`` prints the script, and the
    script's callback completes command names and options (docs/cli.md)."""
    import subprocess
    import sys

    code = "import sys; from calibrate.cli import main; sys.exit(main())"
    env = dict(os.environ, PYTHONPATH=str(ROOT), _GCPCAL_COMPLETE="bash_source")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "_gcpcal_completion()" in proc.stdout and "complete -o nosort -F _gcpcal_completion gcpcal" in proc.stdout
    env.update(_GCPCAL_COMPLETE="bash_complete", COMP_WORDS="gcpcal loc", COMP_CWORD="1")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0 and proc.stdout.split() == ["plain,localize"], proc.stdout
    env.update(COMP_WORDS="gcpcal rpc --height", COMP_CWORD="2")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert proc.stdout.split() == ["plain,--height-range"], proc.stdout
    env.update(_GCPCAL_COMPLETE="zsh_source")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert "#compdef gcpcal" in proc.stdout


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
