"""The package's layer rule, read from the source: dependencies point down only, no cycles.

Layers, lowest first: the shared utilities (``mtplan``, ``mtplan._validate``, ``_io``,
``_parallel``), ``uncertainty`` (the generic engine), ``models`` (the procedures),
``evaluation`` (a procedure's set-up uncertainty and measured data), ``plans``,
``reports``, ``explore`` (the optional designer), ``cli``. Every ``import`` counts, also those inside functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"
LAYERS = ("base", "uncertainty", "models", "evaluation", "plans", "reports", "explore", "cli")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else "base"


def _imports(path: Path, module: str, modules: set[str]) -> set[str]:
    """The mtplan modules that `path` imports (a name imported from a package that is a
    submodule counts as that submodule)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "mtplan")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "mtplan":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.add(sub if sub in modules else target)
    return out


def _graph() -> dict[str, set[str]]:
    files = {_module_name(p): p for p in SRC.rglob("*.py")}
    return {m: {t for t in _imports(p, m, set(files)) if t != m} for m, p in files.items()}


GRAPH = _graph()


def test_the_graph_sees_the_package():
    assert {"mtplan.cli", "mtplan.cli._common", "mtplan.evaluation.simulation",
            "mtplan.uncertainty.sampler", "mtplan.models._protocol"} <= set(GRAPH)
    assert "mtplan.models._protocol" in GRAPH["mtplan.evaluation.simulation"]


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_dependencies_point_down(module):
    rank = LAYERS.index(_layer(module))
    upward = sorted(t for t in GRAPH[module] if LAYERS.index(_layer(t)) > rank)
    assert not upward, f"{module} ({_layer(module)}) imports higher layers: {upward}"


def test_the_engine_knows_nothing_of_procedures():
    for module, targets in GRAPH.items():
        if _layer(module) == "uncertainty":
            bad = [t for t in targets if _layer(t) in ("models", "evaluation", "plans",
                                                       "reports", "cli")]
            assert not bad, f"{module} imports {bad}"


def test_cli_common_imports_no_command():
    assert not [t for t in GRAPH["mtplan.cli._common"] if t.startswith("mtplan.cli")]


def test_no_import_cycle():
    # a package's __init__ importing its own submodules is how packages work; a cycle is
    # a loop between modules through their own names
    graph = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in GRAPH.items()}
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def _long_functions(limit: int) -> list[str]:
    """Functions whose code (signature and body, docstring left out) is over `limit` lines."""
    out = []
    for path in SRC.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            lines = node.end_lineno - node.lineno + 1
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                lines -= first.end_lineno - first.lineno + 1
            if lines > limit:
                out.append(f"{_module_name(path)}.{node.name} ({lines} lines)")
    return out


def test_no_function_too_long_to_hold_in_ones_head():
    assert not _long_functions(120), _long_functions(120)


def test_no_merge_conflict_markers_in_the_sources_and_documents():
    """A merge must not leave its conflict markers in a file users read or run."""
    root = SRC.parent
    files = [*root.glob("*.md"), *(root / "docs").glob("*.md"), *SRC.rglob("*.py"),
             *(root / "tests").rglob("*.py"), *(root / "benchmarks").glob("*.py"),
             *SRC.rglob("*.toml")]
    marked = [str(f.relative_to(root)) for f in files
              if any(line.startswith(("<<<<<<< ", ">>>>>>> ")) or line == "======="
                     for line in f.read_text(encoding="utf-8").splitlines())]
    assert not marked
