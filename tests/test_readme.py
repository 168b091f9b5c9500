"""README.md agrees with the code: its set-up and test commands are CI's, its command table names
every command and only options that exist, its example on a user's own data parses, its links
resolve."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import click

from calibrate.cli import cli, load_all_commands

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _leaves(group: click.Group, prefix=()):
    for name, cmd in group.commands.items():
        if isinstance(cmd, click.Group):
            yield from _leaves(cmd, prefix + (name,))
        else:
            yield " ".join(prefix + (name,)), cmd


load_all_commands()  # the group imports a command's module on demand
LEAVES = dict(_leaves(cli))


def _options(cmd: click.Command) -> set:
    return {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)}


def _command_of(words: list[str]) -> tuple[str, list[str]]:
    """The leaf command a ``gcpcal`` word list names (two words for group commands), and the rest."""
    two = " ".join(words[:2])
    if two in LEAVES:
        return two, words[2:]
    return words[0], words[1:]


def _bash_blocks(text: str) -> list[str]:
    return re.findall(r"```bash\n(.*?)```", text, re.S)


def test_setup_and_test_commands_are_the_ones_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    setup = ('python3 -m venv .venv && . .venv/bin/activate && pip install -c constraints.txt torch==2.13.0 '
             '&& pip install -c constraints.txt -e ".[test,gpu]"')
    blocks = _bash_blocks(README)
    assert setup in blocks[0] and "gcpcal demo" in blocks[0]
    assert "pip install --quiet -c constraints.txt torch==2.13.0" in ci
    assert 'pip install --quiet -c constraints.txt -e ".[test,gpu]"' in ci
    # the CPU-only torch build is named for machines without a GPU
    assert "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu" in README
    test_cmd = 'python -m pytest -q -m "not slow"'
    assert test_cmd in README and test_cmd in ci


def test_command_table_names_every_command_and_only_existing_options():
    rows = re.findall(r"^\| `gcpcal ([^`]+)` \|", README, re.M)
    named = set()
    for row in rows:
        words = row.replace("\\|", "|").split()
        name, rest = _command_of(words)
        assert name in LEAVES, f"README names an unknown command: gcpcal {name}"
        named.add(name)
        tokens = [t.strip("[](),") for w in rest for t in w.split("|")]
        unknown = {t.split("=")[0] for t in tokens if t.startswith("--")} - _options(LEAVES[name])
        assert not unknown, f"gcpcal {name}: options not in its --help: {sorted(unknown)}"
    missing = set(LEAVES) - named
    assert not missing, f"commands missing from README's table: {sorted(missing)}"


def test_example_on_own_data_parses_with_the_cli():
    section = README.split("## On your own data", 1)[1].split("\n## ", 1)[0]
    (block,) = _bash_blocks(section)
    env = {}
    lines = 0
    for line in block.splitlines():
        line = line.split("  #", 1)[0].strip()
        m = re.match(r"^([A-Z]+)=(.*)$", line)
        if m:
            env[m.group(1)] = " ".join(shlex.split(m.group(2)))
            continue
        for key, value in env.items():
            line = line.replace(f"${key}", value)
        words = shlex.split(line)
        assert words[0] == "gcpcal", line
        name, args = _command_of(words[1:])
        cmd = LEAVES[name]
        # click parses the arguments (option names, choices, arity) without running the command
        ctx = cmd.make_context(name, list(args), resilient_parsing=False)
        assert ctx.params, line
        lines += 1
    assert [w for w in ("match", "calibrate", "relative", "ortho", "rpc") if f"gcpcal {w} " not in block] == []
    assert lines == 5


def test_links_resolve():
    links = re.findall(r"\]\(((?:docs/)?[\w./-]+\.md)(?:#[\w-]+)?\)", README)
    assert links
    missing = [link for link in links if not (ROOT / link).is_file()]
    assert not missing, missing


def test_docs_index_lists_every_page_once_under_one_kind():
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    kinds = re.split(r"^## ", index, flags=re.M)
    sections = {k.split("\n", 1)[0]: k for k in kinds[1:]}
    assert {"Tutorials", "How-to guides", "Reference", "Explanation", "References"} <= {
        name.split(" (")[0] for name in sections}
    listed = []
    for name, body in sections.items():
        if name != "References":
            listed += re.findall(r"^- \[[^]]+\]\(([\w.-]+\.md)\)", body, re.M)
            listed += re.findall(r" and \[[^]]+\]\(([\w.-]+\.md)\)", body)
    pages = sorted(p.name for p in (ROOT / "docs").glob("*.md") if p.name != "index.md")
    assert sorted(listed) == pages

