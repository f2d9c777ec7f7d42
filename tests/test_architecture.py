"""The package's layout, measured from its source (the style guide's rules).

The import graph is built from the AST of every module of ``torch_dq/`` (imports at module
level and inside functions alike: a lazy import is still a dependency), each ``from X
import name`` resolved to the submodule ``X.name`` where one exists, else to ``X``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "torch_dq"
MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 60


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _resolve(module: str, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    base = base if _is_package(module) else base[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str) -> set[str]:
    """The modules of ``torch_dq`` that ``module`` imports, anywhere in its source."""
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "torch_dq"}
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, node)
            if target.split(".")[0] != "torch_dq":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                out.add(sub if sub in MODULES else target)
    return {m for m in out if m in MODULES and m != module}


GRAPH = {m: _imports(m) for m in MODULES}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _unit(module: str) -> str:
    """The top-level unit of a module: ``torch_dq.fitting._x`` -> ``torch_dq.fitting``."""
    return ".".join(module.split(".")[:2])


def test_module_import_graph_has_no_cycle():
    graph = {m: {t for t in ts if t != "torch_dq"} for m, ts in GRAPH.items()}
    assert _cycles(graph) == []


def test_top_level_units_import_one_way():
    """Subpackages and top-level modules form a DAG: no unit imports a unit that imports it
    back (an upward import: a core module reaching into ``fitting``, say)."""
    units: dict[str, set[str]] = {}
    for m, targets in GRAPH.items():
        if m == "torch_dq":
            continue
        units.setdefault(_unit(m), set()).update(
            _unit(t) for t in targets if _unit(t) != _unit(m))
    assert _cycles({u: {t for t in ts if t in units} for u, ts in units.items()}) == []


def test_no_module_imports_its_own_package_or_the_root():
    """A module inside a package imports its siblings, never the package's ``__init__``
    (which imports it) nor ``torch_dq`` itself."""
    upward = []
    for m, targets in GRAPH.items():
        parents = {".".join(m.split(".")[:i]) for i in range(1, m.count(".") + 1)}
        upward += [(m, t) for t in targets if t in parents]
    assert upward == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_length(module):
    lines = MODULES[module].read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_MODULE_LINES, f"{module}: {lines} lines"


def _code_lines(node: ast.AST, source: list[str]) -> int:
    """Lines of a function that hold code (its docstring, blank and comment lines aside)."""
    body = node.body
    skip: set[int] = set()
    if body and isinstance(body[0], ast.Expr) and isinstance(
            getattr(body[0], "value", None), ast.Constant) and isinstance(
            body[0].value.value, str):
        skip = set(range(body[0].lineno, body[0].end_lineno + 1))
    count = 0
    for i in range(node.lineno, node.end_lineno + 1):
        text = source[i - 1].strip()
        if i not in skip and text and not text.startswith("#"):
            count += 1
    return count


def _long_functions() -> list[str]:
    out = []
    for module, path in MODULES.items():
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines()
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = _code_lines(node, lines)
                if n > MAX_FUNCTION_LINES:
                    out.append(f"{module}.{node.name}: {n}")
    return sorted(out)


def test_function_length():
    assert _long_functions() == []


def test_the_measure_counts_what_it_should():
    """The graph resolves relative and submodule imports (a known edge is found)."""
    assert "torch_dq.dualquat" in GRAPH["torch_dq.fitting._local"]
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
