"""The lock file ``constraints.txt`` against ``pyproject.toml`` and the installed packages.

* The lock is stale when ``pyproject.toml``'s dependency declarations changed after it was
  generated (their sha256 is recorded in its header): regenerate it with
  ``python .ci/update_constraints.py`` and rerun the suite.
* Every declared dependency is pinned, and each pin lies inside its ``pyproject.toml`` bound (a
  bound with an upper limit: the major versions the suite was run with).
* Under ``.ci/run`` (``GCPCAL_EXPECT_CONSTRAINTS=1``) the installed versions are the pinned ones,
  so CI tests what a user installing with ``-c constraints.txt`` gets. A user who drops the
  constraints skips this check, not the others.
"""

from __future__ import annotations

import importlib.metadata as md
import importlib.util
import os
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "constraints.txt"


def _tool():
    spec = importlib.util.spec_from_file_location("update_constraints", ROOT / ".ci" / "update_constraints.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pins() -> dict[str, Version]:
    pins = {}
    for line in LOCK.read_text(encoding="utf-8").splitlines():
        if line and not line.startswith("#"):
            name, version = line.split("==")
            pins[canonicalize_name(name)] = Version(version)
    return pins


def _declared() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = list(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        declared += extra
    return [Requirement(r) for r in declared]


def test_lock_matches_the_declared_dependencies():
    header = [line for line in LOCK.read_text(encoding="utf-8").splitlines() if line.startswith("# dependencies-sha256:")]
    assert header, "constraints.txt has no dependencies-sha256 header: python .ci/update_constraints.py"
    recorded = header[0].split(":", 1)[1].strip()
    assert recorded == _tool().dependency_digest(), (
        "pyproject.toml's dependencies changed since constraints.txt was generated: "
        "run python .ci/update_constraints.py, then bash .ci/run")


def test_every_dependency_is_pinned_inside_its_bound():
    pins = _pins()
    for req in _declared():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is not pinned in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), f"{name}=={pins[name]} outside {req}"
        upper = [s for s in req.specifier if s.operator in ("<", "<=")]
        assert upper, f"{req} has no upper bound (the major versions tested)"


def test_the_dependency_digest_ignores_order_and_sees_changes(tmp_path):
    tool = _tool()
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    reordered = tmp_path / "a.toml"
    reordered.write_text(text.replace('    "numpy>=1.24,<3",\n', "").replace(
        "dependencies = [\n", 'dependencies = [\n    "numpy>=1.24,<3",\n', 1), encoding="utf-8")
    changed = tmp_path / "b.toml"
    changed.write_text(text.replace('"numpy>=1.24,<3"', '"numpy>=1.24,<4"'), encoding="utf-8")
    assert tool.dependency_digest(reordered) == tool.dependency_digest()
    assert tool.dependency_digest(changed) != tool.dependency_digest()


@pytest.mark.skipif(os.environ.get("GCPCAL_EXPECT_CONSTRAINTS") != "1",
                    reason="installed without constraints.txt (set GCPCAL_EXPECT_CONSTRAINTS=1 to check, as .ci/run does)")
def test_installed_versions_are_the_pinned_ones():
    differ = []
    for name, version in _pins().items():
        try:
            installed = Version(md.version(name))
        except md.PackageNotFoundError:
            differ.append(f"{name}: not installed")
            continue
        if Version(installed.public) != version:
            differ.append(f"{name}: {installed} installed, {version} pinned")
    assert not differ, differ
