"""The package layers hold: imports go one way, production never imports the simulator, no cycles.

``sensor_models`` <- ``gcpmatch`` <- ``calibrate`` (docs: ``ARCHITECTURE.md``, "Layers"). The
checks read the source with :mod:`ast` (nothing is imported), so they see every import: at
module level, inside functions (lazy imports count: they still couple the modules), relative
imports, and ``importlib.import_module("literal")`` calls. An import ``from pkg import name``
is an edge to the module ``pkg.name`` when that module exists, else to ``pkg``; an import of
``a.b.c`` is an edge to ``a.b.c`` only (not to the packages ``a`` and ``a.b`` it also runs).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the layers, lowest first: a package may import only from itself and the ones before it
LAYERS = ("sensor_models", "gcpmatch", "calibrate")
SIMULATOR = "sensor_models.simulate"
CLI_MODULES = ("calibrate.cli", "calibrate.__main__")  # and calibrate.cli.*, calibrate.cli_*
#: the rooms of ``sensor_models``, lowest first (docs/architecture.md): a room imports only from
#: itself and the rooms before it; the package's ``__init__`` (the public API) may import any room
SENSOR_MODEL_ROOMS = ("errors", "base", "files", "geometry", "maps", "terrain", "models", "imaging",
                      "readers", "simulate")
#: the tiers of ``calibrate``, lowest first (docs/architecture.md): the library (every other module,
#: ``calibrate.experiments`` included) <- ``actions`` <- ``pipelines`` <- ``cli``; a tier imports only
#: from itself and the tiers before it (``calibrate.__main__`` counts as the CLI)
CALIBRATE_TIERS = ("library", "actions", "pipelines", "cli")



def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _discover() -> dict[str, Path]:
    """Every module of the three packages: dotted name -> file."""
    found = {}
    for package in LAYERS:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _discover()


def _resolve(name: str) -> str | None:
    """The longest dotted prefix of ``name`` that is one of our modules (None: third party)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        candidate = ".".join(parts[:k])
        if candidate in MODULES:
            return candidate
    return None


def _imported_names(module: str, tree: ast.AST):
    """Absolute dotted names imported anywhere in a module's syntax tree (with line numbers)."""
    is_package = MODULES[module].name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            for alias in node.names:
                yield (f"{prefix}.{alias.name}" if f"{prefix}.{alias.name}" in MODULES else prefix), node.lineno
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            yield node.args[0].value, node.lineno


def _build_graph() -> dict[str, dict[str, int]]:
    """Import graph between our modules: importer -> {imported module: first line}."""
    graph = {}
    for module, path in MODULES.items():
        edges = {}
        for name, line in _imported_names(module, ast.parse(path.read_text(encoding="utf-8"), str(path))):
            target = _resolve(name)
            if target is not None and target != module:
                edges.setdefault(target, line)
        graph[module] = edges
    return graph


GRAPH = _build_graph()


def _layer(module: str) -> int:
    return LAYERS.index(module.split(".")[0])


def _is_cli(module: str) -> bool:
    return module in CLI_MODULES or module.startswith("calibrate.cli.") or module.startswith("calibrate.cli_")


def _simulation_module(module: str) -> bool:
    """Modules allowed to import the simulator: the simulator itself and ``*simulate*`` modules (the
    ``simulate`` commands and the seed experiments ``calibrate/experiments/simulate_seed*``)."""
    return module == SIMULATOR or module.startswith(SIMULATOR + ".") or "simulate" in module.rsplit(".", 1)[-1]


def _strongly_connected(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative), each sorted; only those with a cycle."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def _report(failures: dict[tuple[str, str], str]) -> list[str]:
    return [message for _, message in sorted(failures.items())]


def test_the_scan_sees_the_packages_and_their_imports():
    """Not vacuous: every layer has modules, and known edges (module level and lazy) are found."""
    for package in LAYERS:
        assert package in MODULES and sum(m.startswith(package + ".") for m in MODULES) >= 5
    assert "sensor_models.imaging.locate" in GRAPH["gcpmatch.reference"]  # module level
    assert "sensor_models.imaging.locate" in GRAPH["sensor_models.imaging.ortho_geometry"]  # inside a function
    assert "sensor_models.simulate.truth" in GRAPH["sensor_models.simulate.pushbroom_sim"]


def test_imports_go_one_way():
    """sensor_models imports neither gcpmatch nor calibrate; gcpmatch does not import calibrate."""
    failures = {
        ("upward", f"{a} -> {b}"): f"{a} (line {line}) imports {b}, a higher layer"
        for a, edges in GRAPH.items() for b, line in edges.items() if _layer(b) > _layer(a)
    }
    assert not _report(failures), "\n".join(_report(failures))


def _room(module: str) -> str | None:
    """The room of a ``sensor_models`` module (None: the package itself or another package)."""
    parts = module.split(".")
    return parts[1] if parts[0] == "sensor_models" and len(parts) > 1 else None


def test_sensor_models_has_no_module_outside_its_rooms():
    """At the package's top level only errors.py, base.py and __init__.py; every other module
    lives in one of the rooms."""
    stray = sorted(m for m in MODULES if m.startswith("sensor_models.") and _room(m) not in SENSOR_MODEL_ROOMS)
    assert not stray, f"modules outside the rooms {SENSOR_MODEL_ROOMS}: {stray}"
    top = sorted(p.name for p in (ROOT / "sensor_models").glob("*.py"))
    assert top == ["__init__.py", "base.py", "errors.py"], top


def test_sensor_model_rooms_import_downward_only():
    """geometry <- maps <- terrain <- models <- imaging <- readers <- simulate (errors, base and
    files below them all): no arrow runs back up."""
    failures = {}
    for a, edges in GRAPH.items():
        ra = _room(a)
        if ra is None:
            continue
        for b, line in edges.items():
            rb = _room(b)
            if rb is not None and SENSOR_MODEL_ROOMS.index(rb) > SENSOR_MODEL_ROOMS.index(ra):
                failures[("room", f"{a} -> {b}")] = f"{a} (line {line}) imports {b}: room {rb} is above {ra}"
    assert not _report(failures), "\n".join(_report(failures))


def _tier(module: str) -> str | None:
    """The tier of a ``calibrate`` module (None: another package)."""
    parts = module.split(".")
    if parts[0] != "calibrate":
        return None
    if _is_cli(module):
        return "cli"
    return parts[1] if len(parts) > 1 and parts[1] in ("actions", "pipelines") else "library"


def test_calibrate_tiers_import_downward_only():
    """library <- actions <- pipelines <- cli: actions never import a pipeline, the library (the
    seed experiments included) never imports an action or a pipeline."""
    assert _tier("calibrate.pipelines.demo") == "pipelines" and _tier("calibrate.experiments.registry") == "library"
    assert "calibrate.pipelines.scene" in GRAPH["calibrate.pipelines.demo"]  # not vacuous
    failures = {}
    for a, edges in GRAPH.items():
        ta = _tier(a)
        if ta is None:
            continue
        for b, line in edges.items():
            tb = _tier(b)
            if tb is not None and CALIBRATE_TIERS.index(tb) > CALIBRATE_TIERS.index(ta):
                failures[("tier", f"{a} -> {b}")] = f"{a} (line {line}) imports {b}: tier {tb} is above {ta}"
    assert not _report(failures), "\n".join(_report(failures))


def test_no_module_imports_another_modules_private_name():
    """``from m import _name`` across modules couples them through what ``m`` keeps private; a
    helper shared by modules gets a public name in its home. Private modules (``_phase_torch``)
    may be imported by their own package, and dunder names (``__version__``) are public."""
    failures = {}
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if not isinstance(node, ast.ImportFrom) or node.level or not node.module:
                continue
            if node.module.split(".")[0] not in LAYERS or node.module == module:
                continue
            for alias in node.names:
                name = alias.name
                if not name.startswith("_") or name.startswith("__"):
                    continue
                if f"{node.module}.{name}" in MODULES:  # a private module of that package
                    continue
                failures[("private", module, name)] = f"{module} (line {node.lineno}) imports {node.module}.{name}"
    assert not _report(failures), "\n".join(_report(failures))


#: the modules that may create temporary files and folders: the one transactional-output helper,
#: the stage actions' staging (its journal and ledger sit on that helper's rules), and the
#: scratch folder of GDAL VRT mosaics (not an output)
STAGING_MODULES = ("sensor_models.files.atomic", "calibrate.actions._staging", "sensor_models.maps.mosaic")
_TEMP_CALLS = ("mkdtemp", "mkstemp", "TemporaryDirectory", "NamedTemporaryFile")


def test_every_writer_stages_through_the_one_helper():
    """No module makes its own temporary file or folder to write outputs through: every writer
    uses :mod:`sensor_models.files.atomic` (atomic_file, atomic_folder, atomic_write_text,
    temporary_beside) so that outputs are whole or absent by one set of rules."""
    failures = {}
    for module, path in MODULES.items():
        if module in STAGING_MODULES:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) in _TEMP_CALLS:
                failures[("temp", module, node.lineno)] = f"{module} (line {node.lineno}) makes its own temporary output"
    assert not _report(failures), "\n".join(_report(failures))


def test_production_never_imports_the_simulator():
    """Only sensor_models/simulate/ itself and ``*simulate*`` command modules may import it."""
    failures = {}
    for a, edges in GRAPH.items():
        if _simulation_module(a):
            continue
        bad = sorted(b for b in edges if b == SIMULATOR or b.startswith(SIMULATOR + "."))
        if bad:
            failures[("simulate", a)] = f"production module {a} imports the simulator: {', '.join(bad)}"
    assert not _report(failures), "\n".join(_report(failures))


def test_no_import_cycles():
    """No two modules import each other, directly or through others (lazy imports included)."""
    failures = {}
    for component in _strongly_connected(GRAPH):
        edges = [f"{a} -> {b}" for a in component for b in sorted(GRAPH[a]) if b in component]
        failures[("cycle", " <-> ".join(component))] = (
            f"import cycle between {', '.join(component)} ({'; '.join(edges)})")
    assert not _report(failures), "\n".join(_report(failures))


def test_library_code_never_imports_the_cli():
    """calibrate.cli / calibrate.cli_* are imported only by other CLI modules."""
    failures = {
        ("cli", f"{a} -> {b}"): f"library module {a} (line {line}) imports the CLI module {b}"
        for a, edges in GRAPH.items() if not _is_cli(a)
        for b, line in edges.items() if _is_cli(b)
    }
    assert not _report(failures), "\n".join(_report(failures))


@pytest.mark.parametrize("graph, expected", [
    ({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}, [["a", "b", "c"]]),
    ({"a": {"b": 1}, "b": {}, "c": {"d": 1}, "d": {"c": 1}}, [["c", "d"]]),
    ({"a": {"b": 1}, "b": {"c": 1}, "c": {}}, []),
])
def test_cycle_finder_on_small_graphs(graph, expected):
    assert sorted(_strongly_connected(graph)) == expected
