"""The package's shape: its imports form a DAG, and no layer imports a higher one.

Every import counts: at the top of a module, inside a function, and under
``TYPE_CHECKING`` (a type is a dependency too: the plan's types became a
leaf module so that the explanation and the runtime table would not name
the planner even for their annotations).  An import of an ancestor package
is not an edge: Python runs every ancestor's ``__init__`` before the module
anyway, and ``catanc/__init__.py`` is the lazy public API above everything.
The layers, lowest first, are :data:`LAYERS` (docs/development.md's "Layout" draws them).
``python3 ../shared/tools/import_cycles.py catanc`` checks the same graph
without the ``TYPE_CHECKING`` imports.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "catanc"

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "base",
        ("catanc.errors", "catanc.extras", "catanc.files", "catanc.numba_cache", "catanc.text"),
    ),  # errors, extras, atomic writes, numba's cache, words
    # The node's end of the protocol: standard library only (copyable), and catanc.ros beside it (rclpy).
    ("client", ("catanc.client", "catanc.ros")),
    ("spec", ("catanc.spec",)),  # the language, YAML positions, syntax and shape, the deploy section's checks
    ("model", ("catanc.model",)),  # the problem, its building (meaning checks), the analytic model, loading a spec
    ("planning", ("catanc.planning",)),  # the plan's types, Stage I, Stage II, the planner, re-planning, baseline
    ("explain", ("catanc.explain",)),
    ("artifacts", ("catanc.artifacts",)),  # the runtime table, deployment, emit, output, compile
    # The runtime decisions and measurements shared by the enforcer and the simulator.
    ("control", ("catanc.control",)),
    # The simulator replays control's decisions and measurements; it imports no runtime module.
    ("sim", ("catanc.sim",)),
    # The runtime, lowest first: the enforcer's end of the wire protocol, Linux calls, run logs, the
    # synthetic worker, the enforcer's state (nodes, cores, runs, costs, processes, re-plans), the compiled
    # loop that walks that state, the enforcer's loop that runs the compiled one, and the commands that
    # run the enforcer to measure (profile, calibrate, doctor).
    ("runtime protocol", ("catanc.runtime", "catanc.runtime.protocol")),
    ("runtime linux", ("catanc.runtime.linux",)),
    ("runtime logs", ("catanc.runtime.logs",)),
    ("runtime worker", ("catanc.runtime.worker",)),
    ("enforcer state", ("catanc.runtime.enforcer",)),
    ("compiled loop", ("catanc.runtime.compiled",)),
    ("enforcer loop", ("catanc.runtime.enforcer.run",)),
    ("measuring", ("catanc.runtime.profile", "catanc.doctor")),
    ("realbench", ("catanc.realbench",)),  # `catanc bench`: the real enforcer and workers, the simulator's metrics
    ("cli", ("catanc.cli", "catanc.__main__")),
    ("api", ("catanc",)),  # the lazy public API (catanc/__init__.py)
)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@cache
def modules() -> dict[str, Path]:
    return {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def imported(module: str) -> Iterator[str]:
    """Every catanc module ``module`` imports, anywhere in its text."""
    known = modules()
    is_package = known[module].name == "__init__.py"
    for node in ast.walk(ast.parse(known[module].read_text(), str(known[module]))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: len(module.split(".")) - node.level + is_package]
                target = ".".join([*base, *([node.module] if node.module else [])])
            else:
                target = node.module or ""
            targets = [target, *(f"{target}.{alias.name}" for alias in node.names)]
        else:
            continue
        for target in targets:
            if target in known and target != module and not module.startswith(target + "."):
                yield target


@cache
def graph() -> dict[str, frozenset[str]]:
    return {module: frozenset(imported(module)) for module in modules()}


def layer_of(module: str) -> int:
    matches = [
        (len(prefix), index)
        for index, (_, prefixes) in enumerate(LAYERS)
        for prefix in prefixes
        if module == prefix or module.startswith(prefix + ".")
    ]
    assert matches, f"{module} is in no layer: add it to LAYERS"
    return max(matches)[1]


def find_cycle(edges: dict[str, frozenset[str]]) -> list[str] | None:
    """One import cycle as a path ``a -> b -> a``, or None (depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(module: str) -> list[str] | None:
        state[module] = 1
        path.append(module)
        for target in sorted(edges[module]):
            if state.get(target) == 1:
                return [*path[path.index(target) :], target]
            if target not in state and (found := visit(target)) is not None:
                return found
        path.pop()
        state[module] = 2
        return None

    for module in sorted(edges):
        if module not in state and (found := visit(module)) is not None:
            return found
    return None


def test_the_finder_sees_every_kind_of_import() -> None:
    # The oracle for the tests below: imports inside functions and under TYPE_CHECKING are edges.
    edges = graph()
    assert "catanc.planning.planner" in edges["catanc"]  # inside __getattr__
    assert "catanc.planning.types" in edges["catanc.artifacts.emit"]  # under TYPE_CHECKING
    assert "catanc.errors" in edges["catanc.runtime.linux.watchdog"]  # inside a function
    assert find_cycle({"a": frozenset({"b"}), "b": frozenset({"c"}), "c": frozenset({"a"})}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": frozenset({"b"}), "b": frozenset()}) is None


def test_the_imports_form_a_dag() -> None:
    cycle = find_cycle(graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_every_module_has_a_layer_and_no_layer_imports_a_higher_one() -> None:
    upward = [
        f"{module} ({LAYERS[layer_of(module)][0]}) imports {target} ({LAYERS[layer_of(target)][0]})"
        for module, targets in sorted(graph().items())
        for target in sorted(targets)
        if layer_of(target) > layer_of(module)
    ]
    assert not upward, "\n".join(upward)


def test_the_simulator_imports_no_runtime_module() -> None:
    # Stated apart from the layers: the simulator must stay runnable where the enforcer's parts are not.
    found = sorted(
        f"{module} imports {target}"
        for module, targets in graph().items()
        if module.startswith("catanc.sim")
        for target in targets
        if target.startswith("catanc.runtime")
    )
    assert not found, found


def test_no_folder_holds_more_than_fifteen_modules() -> None:
    # A folder that grows past this holds more than one idea: split it by what its modules hold.
    crowded = {
        str(folder.relative_to(PACKAGE.parent)): count
        for folder in [PACKAGE, *(p for p in PACKAGE.rglob("*") if p.is_dir() and p.name != "__pycache__")]
        if (count := len([m for m in folder.glob("*.py") if m.name != "__init__.py"])) > 15
    }
    assert not crowded, crowded


def test_the_plans_types_name_no_planner_and_no_solver() -> None:
    allowed_layers = {"base", "spec", "model"}
    stage1_answer = {"catanc.planning.stage1.estimate", "catanc.planning.stage1.result"}
    found = graph()["catanc.planning.types"]
    assert all(LAYERS[layer_of(t)][0] in allowed_layers or t in stage1_answer for t in found), sorted(found)


def loaded_by(statement: str) -> set[str]:
    code = f"import json, sys\n{statement}\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    return set(json.loads(out.stdout))


SOLVERS = ("cvxpy", "pulp", "highspy", "clarabel", "scipy", "numba", "matplotlib")


@pytest.mark.parametrize(
    ("statement", "unwanted"),
    [
        ("import catanc.planning.types", (*SOLVERS, "catanc.planning.planner", "catanc.planning.stage2")),
        ("import catanc.artifacts.runtime_table", (*SOLVERS, "jinja2", "rich", "catanc.explain")),
        ("import catanc.model.load", (*SOLVERS, "catanc.planning")),
    ],
)
def test_light_modules_stay_light(statement: str, unwanted: tuple[str, ...]) -> None:
    loaded = loaded_by(statement)
    heavy = sorted(m for m in loaded if any(m == u or m.startswith(u + ".") for u in unwanted))
    assert not heavy, f"`{statement}` loads {heavy}"
