"""No import cycle anywhere: among qpik's modules counting every import (those inside
functions too, which only defer a cycle to the first call), among the benchmark scripts;
and no test, harness package or tool imports a benchmark script: what tests and
benchmarks share is library code, the lab's harness packages (``benchmarks.fuzz``,
``benchmarks.peers``) and the results renderer (``tools``). The imports are read from
the sources with ``ast``."""

from __future__ import annotations

import ast
from pathlib import Path

import qpik

SRC = Path(qpik.__file__).resolve().parent
ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
# The lab's packages that tests may import: harnesses, not scripts.
HARNESS = ("benchmarks.fuzz", "benchmarks.peers")


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _qpik_imports(path: Path, modules: set[str]) -> set[str]:
    """The qpik modules ``path`` imports anywhere in it; a name imported from a package
    counts as its module when it is one (``from . import runs``)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                found.add(f"{target}.{alias.name}" if f"{target}.{alias.name}" in modules else target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    # A module that imports a name its package's __init__ defines depends on that __init__:
    # the edge counts (an __init__ that imports the module back closes a cycle).
    return {m for m in found if m in modules and m != name}


def _script_imports(path: Path, scripts: set[str]) -> set[str]:
    """The other benchmark scripts a benchmark script imports (by module name)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and not node.level:
            found.add((node.module or "").split(".")[0])
        elif isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
    return (found & scripts) - {path.stem}


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """A cycle of ``graph`` (nodes in order, the first repeated at the end), or []."""
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> list[str]:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [node, nxt] if nxt in stack else [node, nxt]
            if state.get(nxt) is None and (cycle := visit(nxt, stack + [node])):
                return cycle
        state[node] = 2
        return []

    for node in sorted(graph):
        if state.get(node) is None and (cycle := visit(node, [])):
            return cycle
    return []


def test_find_cycle_finds_one_and_only_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"a"}}) == ["a", "a"]


def test_no_import_cycle_in_qpik_counting_imports_inside_functions():
    paths = list(SRC.rglob("*.py"))
    modules = {_module_name(p) for p in paths}
    graph = {_module_name(p): _qpik_imports(p, modules) for p in paths}
    assert "qpik.app.runs" in graph["qpik.app.cli"]  # the reader sees imports inside functions
    cycle = find_cycle(graph)
    assert not cycle, " -> ".join(cycle)


def _scripts() -> list[Path]:
    """The benchmark scripts (``python benchmarks/NAME.py``): the folder's modules, not its packages."""
    return [p for p in BENCHMARKS.glob("*.py") if p.name != "__init__.py"]


def test_no_import_cycle_among_the_benchmark_scripts():
    paths = _scripts()
    scripts = {p.stem for p in paths}
    graph = {p.stem: _script_imports(p, scripts) for p in paths}
    assert graph["third_party"] >= {"timing"}
    cycle = find_cycle(graph)
    assert not cycle, " -> ".join(cycle)


def _puts_benchmarks_on_the_path(path: Path) -> bool:
    """Whether a file adds the benchmarks folder to the import path (``sys.path.insert``,
    ``append``, pytest's ``syspath_prepend`` with "benchmarks" in the arguments)."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
                node.func.attr in ("insert", "append", "syspath_prepend"):
            if any(isinstance(n, ast.Constant) and n.value == "benchmarks" for arg in node.args for n in ast.walk(arg)):
                return True
    return False


def _imported_modules(path: Path) -> set[str]:
    """Every module name ``path`` imports, absolute (``from benchmarks import fuzz`` gives
    ``benchmarks.fuzz``); relative imports are left out (they stay in their package)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return found


def _script_imported(modules: set[str], scripts: set[str]) -> list[str]:
    """The modules among ``modules`` that are benchmark scripts: by their own name (the
    benchmarks folder on the path) or as ``benchmarks.NAME``."""
    return sorted(m for m in modules if m.split(".")[0] in scripts
                  or (m.startswith("benchmarks.") and m.split(".")[1] in scripts))


def test_the_rule_tells_a_harness_from_a_script():
    scripts = {"step_time", "timing"}
    assert _script_imported({"benchmarks.fuzz.pool", "benchmarks.fuzz", "tools.tables", "qpik"}, scripts) == []
    assert _script_imported({"benchmarks", "benchmarks.step_time", "timing"}, scripts) == ["benchmarks.step_time",
                                                                                            "timing"]


def test_tests_harnesses_and_tools_import_no_benchmark_script():
    """Tests may import the lab's harness packages and tools/, never a benchmark script;
    neither may those packages and tools."""
    scripts = {p.stem for p in _scripts()}
    files = [*ROOT.joinpath("tests").rglob("*.py"), *ROOT.joinpath("tools").rglob("*.py"),
             *(p for package in HARNESS for p in ROOT.joinpath(*package.split(".")).rglob("*.py"))]
    offenders = [f"{path.relative_to(ROOT)}: {_script_imported(_imported_modules(path), scripts)}"
                 for path in files
                 if _script_imported(_imported_modules(path), scripts) or _puts_benchmarks_on_the_path(path)]
    assert not offenders, offenders
    harness = {m for path in ROOT.joinpath("tests").rglob("*.py") for m in _imported_modules(path)
               if m.startswith("benchmarks.")}
    assert harness and all(m.startswith(HARNESS) for m in harness), harness  # the tests do use the harness
