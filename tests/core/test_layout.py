"""The package layout's rules: the core and the robots never import the app layer, no
module-level import cycle, the whole public API importable from ``qpik``."""

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


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Modules of qpik that ``path`` imports (module level only, if asked)."""
    tree = ast.parse(path.read_text())
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    nodes = tree.body if top_level_only else list(ast.walk(tree))
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
