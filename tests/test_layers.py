"""The layer contract of femphase's package tree (docs/architecture.md, "Layers").

Every import of one femphase module by another counts: at module level, inside functions,
and under ``if TYPE_CHECKING``. A module may import its own layer or lower ones, never a
higher one; and no import cycle exists, between modules or between the units of the
layers (a top-level module or package of femphase: ``domains``, ``run``, ``scene``, …), a
package importing its own submodules aside.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "femphase"

#: Units of femphase by layer, bottom first. A unit is a top-level module or package.
LAYERS = (
    ("errors", "config", "registry", "tomlio", "caches"),  # depend on nothing of femphase
    ("model", "placement"),                     # the physics, independent of discretisation
    ("fem",),                                   # P1 operators, periodic dofs, solvers, mesh files
    ("flows",),                                 # imposed velocity fields
    ("domains",),                               # where fields live: grid and mesh kinds
    ("state",),
    ("timestepping", "analysis"),               # stepping a state; observing it
    ("scene",),                                 # what to simulate, validated
    ("io",),                                    # run directories written and read back
    ("run",),                                   # the phase loop and its trackers
    ("sweep", "converge", "aggregate", "compare", "oscillations", "plot"),  # applications
    ("cli",),                                   # the command line; argparse lives here only
    ("testing",),                               # harnesses for tests/ and benchmarks/
)

#: Imports allowed against the layer order, each with its reason. None are needed today.
ALLOWED: dict[tuple[str, str], str] = {}

LAYER = {unit: depth for depth, units in enumerate(LAYERS) for unit in units}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path, name: str | None = None) -> set[str]:
    """The femphase modules that the module ``name`` (default: from ``path``) imports,
    anywhere in it (names imported from a package that are its submodules count as those
    submodules)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = (name or module_name(path)).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.split(".")[0] == "femphase"}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            if base.split(".")[0] != "femphase":
                continue
            for alias in node.names:
                candidate = f"{base}.{alias.name}"
                found.add(candidate if candidate in MODULES else base)
    return found


MODULES = {module_name(path): path for path in PACKAGE.rglob("*.py")}
GRAPH = {name: imports(path) - {name} for name, path in MODULES.items()}


def unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "femphase"


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of nodes (first = last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == 1:
                return stack[stack.index(target):] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_every_unit_has_a_layer():
    units = {unit(module) for module in MODULES} - {"femphase"}
    assert units <= set(LAYER), f"units without a layer in LAYERS: {sorted(units - set(LAYER))}"
    assert set(LAYER) <= units, f"layers name units that do not exist: {sorted(set(LAYER) - units)}"


def test_no_module_imports_a_higher_layer():
    upward = []
    for source, targets in GRAPH.items():
        for target in targets:
            a, b = unit(source), unit(target)
            if "femphase" in (a, b):  # the package root holds only the version and the logger
                continue
            if LAYER[b] > LAYER[a] and (source, target) not in ALLOWED:
                upward.append(f"{source} (layer {LAYER[a]}: {a}) imports {target} (layer {LAYER[b]}: {b})")
    assert not upward, "imports against the layer order:\n" + "\n".join(sorted(upward))


def test_the_package_root_imports_nothing_of_femphase():
    assert GRAPH["femphase"] == set()


def test_no_import_cycle_between_modules():
    cycle = find_cycle(GRAPH)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_no_import_cycle_between_units():
    graph: dict[str, set[str]] = {}
    for source, targets in GRAPH.items():
        graph.setdefault(unit(source), set()).update(unit(t) for t in targets if unit(t) != unit(source))
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle between units: " + " -> ".join(cycle)


@pytest.mark.parametrize("package", ["domains"])
def test_no_import_cycle_between_subpackages(package):
    """The grid and the mesh kinds: the mesh may use the grid's lattice, not the other way."""
    graph: dict[str, set[str]] = {}
    for source, targets in GRAPH.items():
        parts = source.split(".")
        if len(parts) < 3 or parts[1] != package:
            continue
        sub = parts[2] if len(parts) > 3 else parts[2]
        for target in targets:
            target_parts = target.split(".")
            if len(target_parts) >= 3 and target_parts[1] == package and target_parts[2] != sub:
                graph.setdefault(sub, set()).add(target_parts[2])
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle between {package}'s parts: " + " -> ".join(cycle)


def test_the_contract_sees_an_upward_import(tmp_path):
    """The checker itself: an upward import, a function-local one, is found."""
    path = PACKAGE / "model" / "parameters.py"
    source = path.read_text() + "\n\ndef _probe():\n    from femphase.run.simulation import Simulation\n"
    probe = tmp_path / "parameters.py"
    probe.write_text(source)
    found = imports(probe, "femphase.model.parameters")
    assert "femphase.run.simulation" in found
    assert LAYER[unit("femphase.run.simulation")] > LAYER[unit("femphase.model.parameters")]


def test_argparse_is_used_by_the_command_line_only():
    users = sorted(name for name, path in MODULES.items()
                   if unit(name) != "cli" and "argparse" in {alias.name for node in ast.walk(ast.parse(path.read_text()))
                                                             if isinstance(node, ast.Import) for alias in node.names})
    assert not users, f"argparse outside femphase.cli: {users}"


def test_every_module_declares_its_public_api():
    """Each module with public definitions lists them in ``__all__`` (the API reference is
    generated from it), and every name listed exists."""
    import importlib

    missing, unknown = [], []
    for name, path in sorted(MODULES.items()):
        tree = ast.parse(path.read_text())
        public = [node for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef))
                  and not node.name.startswith("_")]
        declares = any(isinstance(node, (ast.Assign, ast.AnnAssign)) and "__all__" in ast.unparse(node).split("=")[0]
                       for node in tree.body)
        if public and not declares:
            missing.append(name)
        if declares and not name.endswith("__main__"):
            module = importlib.import_module(name)
            unknown += [f"{name}.{item}" for item in module.__all__ if not hasattr(module, item)]
    assert not missing, f"modules without __all__: {missing}"
    assert not unknown, f"__all__ names that do not exist: {unknown}"
