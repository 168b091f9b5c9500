"""A module as it was at an earlier git revision, loaded beside the current one.

Benchmarks time "before" and "after" in the same process and the same run (the machine is
shared and noisy; only ratios measured side by side mean something). The earlier source is read
with ``git show REV:PATH`` and executed as a fresh module whose imports resolve to the current
packages, so only the named module differs.
"""

from __future__ import annotations

import re
import subprocess
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the revision the speed work started from (the merge base of branch s4-speed)
BASE_REV = "dbf5db4"

#: Modules that moved since :data:`BASE_REV` (``sensor_models`` by role): old dotted name -> new.
#: A baseline's source is read from its old path, and its imports of moved modules are pointed at
#: the new ones; names that moved to another module (or were renamed) since are redirected by
#: :data:`MOVED_NAMES`.
RELOCATED = {
    "sensor_models.frames": "sensor_models.geometry.frames",
    "sensor_models.timescales": "sensor_models.geometry.timescales",
    "sensor_models.ephemeris": "sensor_models.geometry.ephemeris",
    "sensor_models.geodesy": "sensor_models.geometry.geodesy",
    "sensor_models.stars": "sensor_models.geometry.star_catalogue",
    "sensor_models.pushbroom": "sensor_models.models.pushbroom",
    "sensor_models.pushbroom_types": "sensor_models.models.pushbroom_types",
    "sensor_models.attitude_correction": "sensor_models.models.attitude_correction",
    "sensor_models.geo_staring": "sensor_models.models.geo_staring",
    "sensor_models.rpc": "sensor_models.models.rpc",
    "sensor_models.rpc_fit": "sensor_models.models.rpc_fit",
    "sensor_models.lab": "sensor_models.models.lab",
    "sensor_models.locgrid": "sensor_models.models.locgrid",
    "sensor_models.synthetic": "sensor_models.models.synthetic",
    "sensor_models.compare": "sensor_models.models.compare",
    "sensor_models.terrain": "sensor_models.terrain.dem",
    "sensor_models.dem_intersect": "sensor_models.terrain.intersect",
    "sensor_models.ortho_dem": "sensor_models.terrain.dem_windows",
    "sensor_models.locate": "sensor_models.imaging.locate",
    "sensor_models.ortho": "sensor_models.imaging.ortho",
    "sensor_models.psf": "sensor_models.imaging.psf",
    "sensor_models.ground_shift": "sensor_models.imaging.ground_shift",
    "sensor_models.raster": "sensor_models.maps.raster",
    "sensor_models.mosaic": "sensor_models.maps.mosaic",
    "sensor_models.dom_inputs": "sensor_models.maps.dom_inputs",
    "sensor_models.reference_qa": "sensor_models.maps.reference_qa",
    "sensor_models._qa_sampling": "sensor_models.maps._qa_sampling",
    "sensor_models.atomic": "sensor_models.files.atomic",
    "sensor_models.readers.documents": "sensor_models.files.documents",
    "gcpmatch.stars": "gcpmatch.star_tracks",
    "calibrate.stars": "calibrate.star_calibration",
    "calibrate.report.stars": "calibrate.report.star_report",
    "sensor_models.simulate.geo_stars": "sensor_models.simulate.star_sky",
}


#: ``(module, name)`` imported by a baseline (module named as it is now) -> ``(module, name)`` now.
MOVED_NAMES = {
    ("sensor_models.models.pushbroom", "_catmull_rom_weights"): ("sensor_models.models.line_table",
                                                                "catmull_rom_weights"),
    ("sensor_models.terrain.intersect", "_intersect_dem"): ("sensor_models.terrain.intersect", "intersect_dem_fixed"),
}


def load_baseline(path: str, rev: str = BASE_REV) -> types.ModuleType:
    """The module at ``path`` (relative to the repository) as it was at ``rev``.

    Parameters
    ----------
    path : str
        Source file as it is named now, e.g. ``"sensor_models/imaging/locate.py"`` (read from
        its path at ``rev``, :data:`RELOCATED`).
    rev : str
        Git revision.

    Returns
    -------
    types.ModuleType
        The module, named ``baseline_<stem>``.
    """
    old_path = _old_path(path)
    source = subprocess.run(["git", "show", f"{rev}:{old_path}"], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout
    source = _redirect_moved_names(_RELOCATED_NAME.sub(lambda m: RELOCATED[m.group(1)], source))
    module = types.ModuleType(f"baseline_{Path(path).stem}")
    module.__file__ = f"{rev}:{path}"
    sys.modules[module.__name__] = module  # dataclasses look their module up
    exec(compile(source, module.__file__, "exec"), module.__dict__)
    return module


_RELOCATED_NAME = re.compile(r"(?<![\w.])(" + "|".join(re.escape(k) for k in sorted(RELOCATED, key=len, reverse=True))
                             + r")(?![\w])")


def _old_path(path: str) -> str:
    """The file's path before the relocations (its path at :data:`BASE_REV`)."""
    dotted = path[:-3].replace("/", ".") if path.endswith(".py") else path.replace("/", ".")
    for old, new in RELOCATED.items():
        if dotted == new:
            return old.replace(".", "/") + ".py"
    return path


def _redirect_moved_names(source: str) -> str:
    """``source`` with each ``from M import N`` of a :data:`MOVED_NAMES` pair importing from its new home."""
    import ast

    lines = source.splitlines(keepends=True)
    edits = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ImportFrom) or node.module is None:
            continue
        if not any((node.module, a.name) in MOVED_NAMES for a in node.names):
            continue
        indent = lines[node.lineno - 1][: node.col_offset]
        statements = []
        for a in node.names:
            module, name = MOVED_NAMES.get((node.module, a.name), (node.module, a.name))
            statements.append(f"{indent}from {module} import {name} as {a.asname or a.name}\n")
        edits.append((node.lineno - 1, node.end_lineno, "".join(statements)))
    for start, end, text in sorted(edits, reverse=True):
        lines[start:end] = [text]
    return "".join(lines)
