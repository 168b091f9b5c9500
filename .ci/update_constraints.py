#!/usr/bin/env python3
"""Regenerate ``constraints.txt``, the versions the test suite was last run with.

Usage (from the repository root)::

    python .ci/update_constraints.py              # resolve anew in a fresh virtual environment
    python .ci/update_constraints.py --from-env   # pin what the running interpreter has installed

The fresh resolution installs ``torch==2.13.0`` (the CPU build, as the README's install line) and
then ``.[test,gpu]`` without constraints, so every other package resolves to the newest release
that ``pyproject.toml``'s bounds allow; it then writes ``pip freeze`` (gcpcal itself excluded) with a
header that records the interpreter, the platform and the sha256 of the dependency declarations.
``tests/test_constraints.py`` fails when ``pyproject.toml``'s dependencies change without the lock
being regenerated, or when a pin falls outside its bound. Run the suite with the new lock
(``bash .ci/run``) before committing it.
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import json
import platform
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "constraints.txt"
TORCH = "torch==2.13.0"


def dependency_digest(pyproject: Path = ROOT / "pyproject.toml") -> str:
    """sha256 of the project's declared dependencies (runtime and optional), order-independent."""
    project = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]
    spec = {"dependencies": sorted(project.get("dependencies", [])),
            "optional": {k: sorted(v) for k, v in sorted(project.get("optional-dependencies", {}).items())}}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()


def _freeze(python: str) -> list[str]:
    out = subprocess.run([python, "-m", "pip", "freeze", "--exclude", "gcpcal", "--exclude-editable"],
                         check=True, capture_output=True, text=True).stdout
    pins = (line.split("+", 1)[0] for line in out.splitlines() if line and not line.startswith("#"))
    return sorted(pins, key=str.lower)  # local labels dropped: torch==2.13.0 admits its CPU and CUDA builds


def _fresh_freeze() -> list[str]:
    with tempfile.TemporaryDirectory(prefix="gcpcal-lock-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        python = str(venv / "bin" / "python")
        pip = [python, "-m", "pip", "install", "--quiet"]
        subprocess.run([*pip, "--upgrade", "pip"], check=True)
        subprocess.run([*pip, TORCH], check=True)
        subprocess.run([*pip, f"{ROOT}[test,gpu]"], check=True)
        return _freeze(python)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from-env", action="store_true", help="pin the running interpreter's packages")
    parser.add_argument("--out", type=Path, default=LOCK, help="file to write (default: constraints.txt)")
    args = parser.parse_args(argv)
    pins = _freeze(sys.executable) if args.from_env else _fresh_freeze()
    header = [
        "# Versions the test suite was last run with; install with:",
        "#   pip install torch==2.13.0 && pip install -c constraints.txt -e \".[test,gpu]\"",
        "# Regenerate with: python .ci/update_constraints.py (then run bash .ci/run).",
        f"# generated: {dt.date.today().isoformat()}, Python {platform.python_version()}, "
        f"{platform.system().lower()}-{platform.machine()}",
        f"# dependencies-sha256: {dependency_digest()}",
    ]
    args.out.write_text("\n".join(header + pins) + "\n", encoding="utf-8")
    print(f"wrote {args.out}: {len(pins)} pins")
    return 0


if __name__ == "__main__":
    sys.exit(main())
