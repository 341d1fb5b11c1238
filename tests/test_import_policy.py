"""The engine's lazy-import policy: imports at module level, except the heavy few.

In the packages of the engine (the uncertainty engine, the fitting machinery, a procedure's
set-up uncertainty and its first-order service, sweeps and the planner) a function imports
a module itself only where that saves a real cost: pandas, scipy, emcee, tqdm and modules
that load scipy when imported (the acceptance risks). Everything else is imported at module
level, where a reader sees what a module depends on; the layer test still sees every edge.
"""

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "mtplan"

#: the engine's modules under the policy
MODULES = [*sorted((SRC / "uncertainty").glob("*.py")), *sorted((SRC / "fitting").glob("*.py")),
           SRC / "evaluation" / "first_order.py", SRC / "evaluation" / "simulation.py",
           SRC / "plans" / "sweep.py", SRC / "plans" / "planner.py"]

#: what a function may import itself: heavy to load, and not needed by every caller (a
#: Monte Carlo's workers never make a table)
HEAVY = ("pandas", "scipy", "emcee", "tqdm", "mtplan.plans.acceptance")


def _local_imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for sub in ast.walk(node):
            if isinstance(sub, ast.ImportFrom):
                names = [sub.module or ""]
            elif isinstance(sub, ast.Import):
                names = [a.name for a in sub.names]
            else:
                continue
            out += [f"{path.relative_to(SRC)}:{sub.lineno} {node.name}: {n}" for n in names
                    if not any(n == h or n.startswith(h + ".") for h in HEAVY)]
    return out


def test_the_engine_imports_at_module_level_except_the_heavy_few():
    found = [line for path in MODULES for line in _local_imports(path)]
    assert not found, "\n".join(found)
