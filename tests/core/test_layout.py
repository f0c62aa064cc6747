"""The package layout's rules: the core imports nothing above it (robots, rollouts, the
app), the core and the robots never import the app layer, no module-level import cycle,
the whole public API importable from ``qpik``."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import qpik

SRC = Path(qpik.__file__).resolve().parent


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _run_time_nodes(tree: ast.AST):
    """Every node of ``tree`` except those under ``if TYPE_CHECKING:`` (never run)."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            continue
        yield node
        yield from _run_time_nodes(node)


def _imports(path: Path, top_level_only: bool, run_time: bool = False) -> set[str]:
    """Modules of qpik that ``path`` imports (module level only, if asked; ``run_time``:
    leaving out the imports only a type checker reads)."""
    tree = ast.parse(path.read_text())
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    nodes = tree.body if top_level_only else list(_run_time_nodes(tree) if run_time else ast.walk(tree))
    found = set()
    for node in nodes:
        if isinstance(node, ast.If) and top_level_only:  # `if TYPE_CHECKING:` imports are not run
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("qpik"):
                found.add(target)
                found.update(f"{target}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("qpik"))
    modules = {_module_name(p) for p in SRC.rglob("*.py")}
    return {m for m in found if m in modules}


# The core: the robot, the engine (tasks, limits, the step's problem, controllers and
# their numerics primitives), solvers, the batched robot and what they stand on. Above it: the bundled robots, the rollouts, the app.
CORE = ("qpik.robot", "qpik.actuation", "qpik.errors", "qpik.numerics", "qpik.extras", "qpik.scenes",
        "qpik.equalities", "qpik.tasks", "qpik.limits", "qpik.problem", "qpik.controllers", "qpik.solvers",
        "qpik.batch")
ABOVE_THE_CORE = ("qpik.robots", "qpik.rollout", "qpik.app", "qpik.scenario")


def _within(name: str, packages: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in packages)


def test_the_core_imports_nothing_above_it():
    """Every import of a core module, those inside functions too, and what they import in
    turn: nothing of the robots, the rollouts or the app (``qpik``'s own __init__ loads
    its names lazily, so ``from .. import limits`` imports qpik.limits only)."""
    graph = {_module_name(p): _imports(p, top_level_only=False, run_time=True) for p in SRC.rglob("*.py")}
    core = sorted(m for m in graph if _within(m, CORE))
    assert "qpik.robot" in core and "qpik.batch.rollout" in core and graph["qpik.batch.robot"]
    reached, todo = {}, [(m, m) for m in core]
    while todo:
        module, via = todo.pop()
        if module in reached:
            continue
        reached[module] = via
        todo += [(m, via) for m in graph.get(module, ()) if m != "qpik"]
    offenders = sorted(f"{m} (imported from {via})" for m, via in reached.items() if _within(m, ABOVE_THE_CORE))
    assert not offenders, offenders
    assert set(reached) - {"qpik"} <= set(core), sorted(set(reached) - set(core))


CORE_ONLY = """
import sys, qpik
from qpik import batch
names = (qpik.Robot, qpik.QPController, qpik.FrameTask, qpik.JointPositionLimit, batch.Robot, batch.QPController,
         batch.FrameTask, batch.rollout)
robot = qpik.Robot.load("arm")
robots = batch.Robot.load("arm", n=2)
print(" ".join(sorted(m for m in sys.modules if m.startswith("qpik."))))
"""


def test_the_core_at_work_loads_nothing_above_it():
    """``import qpik``, the core's names touched and a bundled robot loaded (serial and
    batched): no module of the robots, the rollouts or the app is loaded."""
    done = subprocess.run([sys.executable, "-c", CORE_ONLY], capture_output=True, text=True, check=True)
    loaded = done.stdout.split()
    assert "qpik.robot" in loaded and "qpik.controllers.qp" in loaded and "qpik.scenes" in loaded
    assert not [m for m in loaded if _within(m, ABOVE_THE_CORE)], loaded


def test_core_and_robots_never_import_the_app_layer():
    offenders = []
    for path in SRC.rglob("*.py"):
        name = _module_name(path)
        if name.startswith("qpik.app") or name == "qpik.__main__":  # the entry point runs the app
            continue
        bad = sorted(m for m in _imports(path, top_level_only=False) if m.startswith("qpik.app"))
        if bad:
            offenders.append(f"{name} -> {bad}")
    assert not offenders, offenders


def test_no_module_level_import_cycle():
    graph = {_module_name(p): _imports(p, top_level_only=True) for p in SRC.rglob("*.py")}
    # A package's __init__ runs before its modules: importing qpik.tasks.frame needs qpik.tasks.
    for name in graph:
        graph[name] = {m for m in graph[name] if not name.startswith(m + ".")}
    state: dict[str, int] = {}
    cycle: list[str] = []

    def visit(node: str, stack: list[str]) -> bool:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycle.extend(stack[stack.index(nxt):] + [node, nxt] if nxt in stack else [node, nxt])
                return True
            if state.get(nxt) is None and visit(nxt, stack + [node]):
                return True
        state[node] = 2
        return False

    for node in sorted(graph):
        if state.get(node) is None and visit(node, []):
            break
    assert not cycle, " -> ".join(cycle)


def test_every_public_name_imports_from_qpik():
    for name in qpik.__all__:
        assert getattr(qpik, name) is not None, name


def test_importing_qpik_loads_no_heavy_dependency():
    code = "import sys, qpik; print(' '.join(m for m in ('mujoco', 'scipy', 'numpy', 'matplotlib') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
