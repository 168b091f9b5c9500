"""A module as it was at an earlier git revision, loaded beside the current one.

Benchmarks time "before" and "after" in the same process and the same run (the machine is
shared and noisy; only ratios measured side by side mean something). The earlier source is read
with ``git show REV:PATH`` and executed as a fresh module whose imports resolve to the current
packages, so only the named module differs.
"""

from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the revision the speed work started from (the merge base of branch s4-speed)
BASE_REV = "dbf5db4"


def load_baseline(path: str, rev: str = BASE_REV) -> types.ModuleType:
    """The module at ``path`` (relative to the repository) as it was at ``rev``.

    Parameters
    ----------
    path : str
        Source file, e.g. ``"sensor_models/imaging/locate.py"``.
    rev : str
        Git revision.

    Returns
    -------
    types.ModuleType
        The module, named ``baseline_<stem>``.
    """
    source = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout
    module = types.ModuleType(f"baseline_{Path(path).stem}")
    module.__file__ = f"{rev}:{path}"
    sys.modules[module.__name__] = module  # dataclasses look their module up
    exec(compile(source, module.__file__, "exec"), module.__dict__)
    return module
