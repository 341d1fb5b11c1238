"""The package's layer rule, read from the source: dependencies point down only, no cycles.

Layers, lowest first: the shared utilities (``mtplan``, ``mtplan._validate``, ``_io``,
``_parallel``), ``uncertainty`` (the generic engine), ``fitting`` (the readings'
covariance, the generalised least-squares fitter and the fit check every procedure
shares), ``models`` (the procedures), ``evaluation`` (a procedure's set-up uncertainty
and measured data), ``testing`` (the conformance checks of a procedure), ``compensation``
(corrections for a controller from measured results), ``plans``,
``reports``, ``explore`` (the optional designer), ``cli``. Every ``import`` counts, also those
inside functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"
LAYERS = ("base", "uncertainty", "fitting", "models", "evaluation", "testing", "compensation",
          "plans", "reports", "explore", "cli")


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
            "mtplan.uncertainty.sampler", "mtplan.models.protocol", "mtplan.fitting.gls"} <= set(GRAPH)
    assert "mtplan.models.protocol" in GRAPH["mtplan.evaluation.simulation"]


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_dependencies_point_down(module):
    rank = LAYERS.index(_layer(module))
    upward = sorted(t for t in GRAPH[module] if LAYERS.index(_layer(t)) > rank)
    assert not upward, f"{module} ({_layer(module)}) imports higher layers: {upward}"


def _private_across_packages() -> list[str]:
    """Imports of an underscore module (``mtplan.models._x``) from outside its package.

    The top-level helpers (``mtplan._validate``, ``mtplan._io``, ``mtplan._parallel``) are
    the base layer every package shares; any other ``_module`` is its package's own."""
    bad = []
    for module, targets in GRAPH.items():
        for target in targets:
            parts = target.split(".")
            private = [i for i, part in enumerate(parts) if part.startswith("_") and i >= 2]
            if not private:
                continue
            owner = ".".join(parts[: private[0]])
            if not (module == owner or module.startswith(owner + ".")):
                bad.append(f"{module} imports {target}")
    return sorted(bad)


def test_no_underscore_module_is_imported_across_packages():
    """What one package uses of another is public: its ``__init__`` or a module without a
    leading underscore (docs/api.md lists them)."""
    assert _private_across_packages() == []


def _private_names_across_modules() -> list[str]:
    """Underscore names (not modules) that one mtplan module takes from another: imported
    by name (``from mtplan.plans.sweep import _grid``) or reached through the module
    (``posterior._start``). Relative imports count as their absolute module."""
    files = {_module_name(p): p for p in SRC.rglob("*.py")}
    bad = []
    for module, path in files.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = {}  # name bound to an mtplan module in this file -> that module
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                aliases.update({a.asname: a.name for a in node.names
                                if a.asname and a.name.startswith("mtplan.")})
            if not isinstance(node, ast.ImportFrom):
                continue
            base = package.split(".")[: len(package.split(".")) - node.level + 1] \
                if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            if target.split(".")[0] != "mtplan":
                continue
            for a in node.names:
                if f"{target}.{a.name}" in files:
                    aliases[a.asname or a.name] = f"{target}.{a.name}"
                elif a.name.startswith("_") and not a.name.startswith("__"):
                    bad.append(f"{module} imports {a.name} from {target}")
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                    and node.value.id in aliases and node.attr.startswith("_") \
                    and not node.attr.startswith("__") \
                    and f"{aliases[node.value.id]}.{node.attr}" not in files:
                bad.append(f"{module} uses {node.value.id}.{node.attr}")
    return sorted(set(bad))


def test_no_private_name_crosses_a_module():
    """A name one module uses from another is that module's public one; an underscore name
    is its own module's business (private modules of a package are imported whole)."""
    assert _private_names_across_modules() == []


def test_the_engine_knows_nothing_of_procedures():
    for module, targets in GRAPH.items():
        if _layer(module) == "uncertainty":
            bad = [t for t in targets if _layer(t) in ("fitting", "models", "evaluation",
                                                       "plans", "reports", "cli")]
            assert not bad, f"{module} imports {bad}"


def test_cli_common_imports_no_command():
    assert not [t for t in GRAPH["mtplan.cli._common"] if t.startswith("mtplan.cli")]


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module in `graph` (module ->
    the modules it imports): each is an import cycle. Every edge counts, a submodule's
    import of its own package's ``__init__`` too."""
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
    return cycles


def test_no_import_cycle():
    cycles = import_cycles(GRAPH)
    assert not cycles, f"import cycles: {cycles}"


def test_a_cycle_through_a_packages_init_is_found():
    """A submodule that imports its package back closes a loop with the ``__init__`` that
    imports it: the check sees it like any other."""
    graph = {"p": {"p.a", "p.b"}, "p.a": {"q"}, "p.b": {"p"}, "q": set()}
    assert import_cycles(graph) == [["p", "p.b"]]
    assert import_cycles({**graph, "p.b": {"p.a"}}) == []


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


def test_the_fitting_machinery_knows_no_procedure():
    for module, targets in GRAPH.items():
        if _layer(module) == "fitting":
            bad = [t for t in targets if _layer(t) not in ("base", "uncertainty", "fitting")]
            assert not bad, f"{module} imports {bad}"


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


# --------------------------------------------------------------------------- the contract
# The Procedure record is a procedure's whole contract: nothing in mtplan may find a
# procedure's function by name in its module. The one allowed reach into a procedure's
# module is the registry's: importing each module of mtplan.models and reading its
# PROCEDURE. Other dynamic imports are allowed only when their target is statically a
# module outside mtplan.models (the lazy loaders of mtplan.evaluation and mtplan.cli).
PROCEDURE_PACKAGE = "mtplan.models"
REGISTRY = ("mtplan.models", "registry")  # (module, function) allowed to import procedures
REGISTRY_ATTRIBUTES = {"PROCEDURE"}  # all the registry may read from a procedure's module


def _static_prefix(node, module: str) -> str | None:
    """The leading constant text of an import target (a string, or an f-string up to its first
    field that is not ``__name__``, which is `module`); None when nothing of it is constant."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        text = ""
        for part in node.values:
            if isinstance(part, ast.Constant):
                text += str(part.value)
            elif isinstance(part.value, ast.Name) and part.value.id == "__name__":
                text += module
            else:
                break
        return text or None
    return None


def _may_be_procedure(prefix: str | None) -> bool:
    """Whether an import whose target starts with `prefix` may import a procedure's module."""
    if prefix is None:
        return True
    return prefix.startswith(PROCEDURE_PACKAGE + ".") or (PROCEDURE_PACKAGE + ".").startswith(
        prefix)


def _is_import_module(call) -> bool:
    f = call.func
    return (isinstance(f, ast.Name) and f.id in ("import_module", "__import__")) or (
        isinstance(f, ast.Attribute) and f.attr in ("import_module", "__import__"))


def procedure_module_lookups(source: str, module: str) -> list[str]:
    """Where `source` (the text of the mtplan module `module`) finds something in a
    procedure's module other than through the Procedure record: reading a function's
    ``__module__``, ``sys.modules``, ``inspect.getmodule``, or a dynamic import that may reach
    a procedure's module (anywhere but the registry, and there anything read from the module
    but ``PROCEDURE``: a ``getattr`` or an attribute)."""
    tree = ast.parse(source)
    found = []
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}

    def where(node):
        scope = node
        while scope in parents and not isinstance(scope, ast.FunctionDef | ast.AsyncFunctionDef):
            scope = parents[scope]
        return scope.name if isinstance(scope, ast.FunctionDef | ast.AsyncFunctionDef) else ""

    procedure_modules = {}  # name bound to a possibly-procedure module -> the function binding it
    for node in ast.walk(tree):
        line = f"{module}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Attribute) and node.attr == "__module__":
            found.append(f"{line} reads __module__ (a procedure's module from its function)")
        elif isinstance(node, ast.Attribute) and node.attr in ("modules", "getmodule") \
                and isinstance(node.value, ast.Name) and node.value.id in ("sys", "inspect"):
            found.append(f"{line} uses {node.value.id}.{node.attr}")
        elif isinstance(node, ast.Call) and _is_import_module(node):
            prefix = _static_prefix(node.args[0], module) if node.args else None
            if not _may_be_procedure(prefix):
                continue
            if (module, where(node)) != REGISTRY:
                found.append(f"{line} imports a module that may be a procedure's "
                             f"({ast.unparse(node)})")
                continue
            parent = parents.get(node)
            if isinstance(parent, ast.Assign) and all(isinstance(t, ast.Name)
                                                      for t in parent.targets):
                procedure_modules.update({t.id: where(node) for t in parent.targets})
            else:  # used in place (import_module(...).attr): only an assigned name is allowed
                found.append(f"{line} uses a procedure's module in place ({ast.unparse(parent)})")
    for node in ast.walk(tree):
        line = f"{module}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in ("getattr", "hasattr", "vars", "dir") and node.args \
                and isinstance(node.args[0], ast.Name) and node.args[0].id in procedure_modules:
            name = node.args[1] if len(node.args) > 1 else None
            allowed = (node.func.id == "getattr" and isinstance(name, ast.Constant)
                       and name.value in REGISTRY_ATTRIBUTES)
            if not allowed:
                found.append(f"{line} looks up {ast.unparse(node)} in a procedure's module")
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in procedure_modules and node.attr not in REGISTRY_ATTRIBUTES:
            found.append(f"{line} reads {ast.unparse(node)} from a procedure's module")
    return found


def test_nothing_is_found_by_name_in_a_procedures_module():
    found = [hit for path in sorted(SRC.rglob("*.py"))
             for hit in procedure_module_lookups(path.read_text(encoding="utf-8"),
                                                 _module_name(path))]
    assert not found, found


def test_no_procedure_module_is_imported_outside_the_models():
    """Above the models a procedure is reached through the registry's Procedure only (a module
    imported by its name would let its functions be called outside the contract)."""
    from mtplan.models import registry

    # a procedure's module and its submodules (the protocol and shared kinematics are not one)
    homes = {proc.forward.__module__.removesuffix(".__init__") for proc in registry().values()}
    homes = {h if h.count(".") == 2 else h.rpartition(".")[0] for h in homes}
    procedures = {m for m in GRAPH if m in homes or any(m.startswith(h + ".") for h in homes)}
    assert {"mtplan.models.rotary_axis", "mtplan.models.geometry21"} <= procedures
    assert "mtplan.models.protocol" not in procedures
    bad = {m: sorted(GRAPH[m] & procedures) for m in GRAPH
           if not m.startswith(PROCEDURE_PACKAGE) and GRAPH[m] & procedures}
    assert not bad, bad


OLD_HOOK_LOOKUP = '''
import importlib

def _predict(proc, setup):
    own = getattr(importlib.import_module(proc.forward.__module__), "first_order_std", None)
    return own(setup) if callable(own) else None

def _extras(proc, ps):
    module = importlib.import_module(proc.forward.__module__)
    hook = getattr(module, "report_extras", None)
    return hook(ps.setup, ps.truth)
'''

REGISTRY_SOURCE = '''
import importlib, pkgutil

def registry():
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        proc = getattr(module, "PROCEDURE", None)
'''


@pytest.mark.parametrize("snippet, module, expected", [
    # the pattern the Procedure record replaced: both functions caught, each twice
    (OLD_HOOK_LOOKUP, "mtplan.plans.planner", 4),
    # the same without __module__: a procedure's module named from its procedure's name
    ("from importlib import import_module\ndef f(proc):\n"
     "    m = import_module('mtplan.models.' + proc.name)\n    return m.first_order_std\n",
     "mtplan.plans.planner", 1),
    ("import importlib\ndef f(name):\n"
     "    return getattr(importlib.import_module(f'mtplan.models.{name}'), 'report_extras')\n",
     "mtplan.reports.html", 1),
    ("import sys\ndef f(proc):\n    return sys.modules[proc.name].observability\n",
     "mtplan.plans.study", 1),
    # the registry may import procedures and read PROCEDURE, nothing else
    (REGISTRY_SOURCE, "mtplan.models", 0),
    (REGISTRY_SOURCE + "        hook = getattr(module, 'report_extras', None)\n",
     "mtplan.models", 1),
    (REGISTRY_SOURCE + "        hook = module.identifiability\n", "mtplan.models", 1),
    # the same code outside the registry is refused (and its own submodules are no procedures)
    (REGISTRY_SOURCE.replace("{__name__}", "mtplan.models"), "mtplan.plans.study", 1),
    (REGISTRY_SOURCE, "mtplan.plans.study", 0),
    # a lazy loader of another package is no procedure lookup
    ("import importlib\ndef __getattr__(name):\n"
     "    return getattr(importlib.import_module(f'mtplan.evaluation.{name}'), name)\n",
     "mtplan.evaluation", 0),
    ("import importlib\ndef register(sub, module):\n"
     "    importlib.import_module(f'mtplan.cli.{module}').register(sub)\n", "mtplan.cli", 0),
])
def test_the_procedure_lookup_checker_catches_the_old_pattern(snippet, module, expected):
    found = procedure_module_lookups(snippet, module)
    assert len(found) == expected, found
