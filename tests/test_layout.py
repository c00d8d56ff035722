"""The package's layout: layers that import only downwards, no import circle, docstrings without history.

Every module's own imports are read from its source (``ast``: module-level and function-level imports of
``rollbot_oc`` modules alike; those under ``if TYPE_CHECKING:`` are never run and do not count), so the checks see what the code asks for, not what happens to be imported
first at run time.  ``LAYERS`` is the order of the layers (``rollbot_oc/__init__.py`` describes them): a
module may import modules of its own layer or of lower ones, never of a higher one.
"""

from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "rollbot_oc"

# module prefix -> layer; the longest prefix that matches a module gives its layer
LAYERS = {
    "rollbot_oc.core": 0,
    "rollbot_oc.model": 1,
    "rollbot_oc.view": 2,
    "rollbot_oc.ocp": 2,
    "rollbot_oc.control.protocol": 2,  # what the plant calls: below the simulation, which imports it
    "rollbot_oc.simulation": 3,
    "rollbot_oc.analysis": 4,
    "rollbot_oc.planning": 5,
    "rollbot_oc.missions": 5,
    "rollbot_oc.control": 6,
    "rollbot_oc.scenarios": 7,
    "rollbot_oc.campaign": 8,
    "rollbot_oc.export": 8,
    "rollbot_oc.robot": 8,
    "rollbot_oc.app": 9,
}


def _modules() -> dict[str, tuple[Path, bool]]:
    """Every module of the package: dotted name -> (file, is a package's ``__init__``)."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        package = parts[-1] == "__init__"
        found[".".join(parts[:-1] if package else parts)] = (path, package)
    return found


MODULES = _modules()


def _owner(name: str) -> str | None:
    """The module that an imported dotted name lives in (``a.b.c`` is module ``a.b`` when ``c`` is a name)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports(module: str) -> dict[str, int]:
    """The ``rollbot_oc`` modules that ``module`` imports anywhere in its source, each with a line number."""
    path, package = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    typing_only = {id(inner) for node in ast.walk(tree)
                   if isinstance(node, ast.If) and ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")
                   for child in node.body for inner in ast.walk(child)}
    found = {}
    for node in ast.walk(tree):
        if id(node) in typing_only:  # read by type checkers only, never run
            continue
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module if package else module.rpartition(".")[0]
                for _ in range(node.level - 1):
                    anchor = anchor.rpartition(".")[0]
                base = f"{anchor}.{base}" if base else anchor
            names = [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            owner = _owner(name) if name.startswith("rollbot_oc") else None
            if owner and owner != module:
                found.setdefault(owner, node.lineno)
    return found


GRAPH = {module: imports(module) for module in MODULES}


def layer(module: str) -> int | None:
    prefixes = [prefix for prefix in LAYERS if module == prefix or module.startswith(prefix + ".")]
    return LAYERS[max(prefixes, key=len)] if prefixes else None


def test_every_module_has_a_layer():
    assert [module for module in MODULES if module != "rollbot_oc" and layer(module) is None] == []


def test_the_package_root_imports_no_module():
    """``rollbot_oc/__init__.py`` only names modules (``MOVED``, ``EXPORTS``), so any layer may read it."""
    assert GRAPH["rollbot_oc"] == {}


def test_layers_import_only_downwards():
    upwards = [f"{module}:{line} imports {target} (layer {layer(target)} above {layer(module)})"
               for module, targets in GRAPH.items() if module != "rollbot_oc"
               for target, line in targets.items() if target != "rollbot_oc" and layer(target) > layer(module)]
    assert upwards == []


def _cycles(graph: dict[str, dict]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, {}):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def test_cycle_finder_finds_a_circle():
    assert _cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b": 1}, "b": {}}) == []


def test_no_import_circle():
    """No two modules import each other, directly or through others (a package's ``__init__`` counts as a module)."""
    assert _cycles(GRAPH) == []


def test_old_module_paths_name_existing_modules():
    """Every entry of ``MOVED`` leads to a module that exists, and none shadows a module that exists."""
    import rollbot_oc

    for old, new in rollbot_oc.MOVED.items():
        assert new in MODULES, (old, new)
        assert old not in MODULES, old
    for name, module in rollbot_oc.EXPORTS.items():
        assert module in MODULES, (name, module)


def test_an_old_path_imports_the_new_module_itself():
    import importlib

    import rollbot_oc

    old = importlib.import_module("rollbot_oc.params")
    assert old is importlib.import_module(rollbot_oc.MOVED["rollbot_oc.params"])
    from rollbot_oc import RollbotParams
    assert RollbotParams is old.RollbotParams


def test_the_wheel_declares_every_package():
    """``pyproject.toml`` lists every folder with an ``__init__.py`` (a missing one would be left out of the wheel)."""
    declared = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    packages = {module for module, (_, package) in MODULES.items() if package}
    assert packages - declared == set()
    data = {"rollbot_oc.export.c", "rollbot_oc.robot.c"}  # C sources, declared so that they ship quietly
    assert {name for name in declared if not name.startswith("rollbot_oc.problems_data")} - packages == data
    assert all((ROOT / name.replace(".", "/")).is_dir() for name in data)


HISTORY = re.compile(r"item [0-9]+|20[0-9]{2}-[0-9]{2}-[0-9]{2}|\bcourse [0-9]+\b", re.IGNORECASE)


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history_in_the_code(path):
    """Docstrings and comments say what is true now: no numbered benchmark entries, dates or course numbers."""
    hits = [f"{number}: {line.strip()}" for number, line in enumerate(path.read_text().splitlines(), 1)
            if HISTORY.search(line)]
    assert hits == []


# What the generic optimal-control layer may import of the package: the plumbing, itself, and the code generation
# of CasADi Functions (``model.codegen``: no physics, it compiles any Function).  Any system, Rollbot's included,
# comes in as the ``OCPModel`` it is given.
OCP_MAY_IMPORT = ("rollbot_oc.core", "rollbot_oc.ocp", "rollbot_oc.model.codegen")


def test_the_ocp_layer_knows_no_particular_system():
    """Nothing under ``rollbot_oc/ocp`` imports Rollbot's model (``model.dynamics``, ``model.params``, ...),
    the planning, the control or anything above."""
    assert "rollbot_oc.ocp.problem" in GRAPH and "rollbot_oc.ocp.routes.sqp" in GRAPH
    found = [f"{module}:{line} imports {target}" for module, targets in GRAPH.items()
             if module == "rollbot_oc.ocp" or module.startswith("rollbot_oc.ocp.")
             for target, line in targets.items()
             if target != "rollbot_oc" and not any(target == allowed or target.startswith(allowed + ".")
                                                   for allowed in OCP_MAY_IMPORT)]
    assert found == []
