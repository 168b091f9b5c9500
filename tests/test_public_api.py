"""The curated public API: every exported name resolves to its defining module, importing a
package loads none of its rooms, and docs/api.md documents exactly the exported names."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sensor_models", "gcpmatch", "calibrate")
PLAIN = {"GcpcalError", "InputError", "__version__"}  # defined or imported eagerly by sensor_models


@pytest.mark.parametrize("package", PACKAGES)
def test_every_exported_name_resolves_to_the_module_that_defines_it(package):
    pkg = importlib.import_module(package)
    assert pkg.__all__ == sorted(pkg.__all__) and len(pkg.__all__) <= 16  # small and curated
    for name in pkg.__all__:
        value = getattr(pkg, name)
        if name in PLAIN:
            continue
        home = pkg._EXPORTS[name]
        assert value.__module__ == home, (name, value.__module__, home)
        assert getattr(importlib.import_module(home), name) is value
    with pytest.raises(AttributeError):
        getattr(pkg, "no_such_name")


def test_importing_the_packages_loads_no_room():
    code = ("import sys, sensor_models, gcpmatch, calibrate; "
            "print(sorted(m for m in sys.modules if m.count('.') and m.split('.')[0] in "
            "('sensor_models', 'gcpmatch', 'calibrate')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['sensor_models.errors']"


def test_docs_api_documents_exactly_the_exported_names():
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    for package in PACKAGES:
        section = text.split(f"## `{package}`", 1)[1].split("\n## ", 1)[0]
        documented = set()
        for cell in re.findall(r"^\| `([^|]+)` \|", section, flags=re.M):
            documented |= {re.match(r"\w+", part.strip()).group(0) for part in cell.split("`, `")}
        assert documented == set(importlib.import_module(package).__all__), package


def test_the_documented_example_runs_on_the_embedded_fixture(tmp_path, monkeypatch):
    """docs/api.md's example, its file names pointed at fixtures/hy1c_czi, runs and calibrates."""
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    lines = text.split("## An example", 1)[1].splitlines()[1:]
    start = next(i for i, line in enumerate(lines) if line.startswith("    "))
    end = next(i for i in range(start, len(lines)) if lines[i] and not lines[i].startswith("    "))
    code = "\n".join(line[4:] for line in lines[start:end])
    fixture = ROOT / "fixtures" / "hy1c_czi"
    for name, path in (("scene.json", fixture / "manifest.json"), ("dem.tif", fixture / "reference" / "dem.tif"),
                       ("dom.tif", fixture / "reference" / "dom.tif")):
        assert f'"{name}"' in code
        code = code.replace(f'"{name}"', repr(str(path)))
    namespace = {}
    exec(compile(code, "docs/api.md", "exec"), namespace)  # noqa: S102 - the documented example itself
    assert namespace["result"].success and len(namespace["gcps"]) > 100
