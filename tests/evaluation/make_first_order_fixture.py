"""Write ``first_order_fixture.json``: every procedure's first-order numbers at its default
set-up, for every estimator (u per measurand and the budget by source, display units).

``tests/evaluation/test_first_order.py`` holds the linearisation service to these numbers
to 1e-9 relative. When a procedure's physics changes (a new error source, another
default), regenerate them and review the diff:

    PYTHONPATH=src python tests/evaluation/make_first_order_fixture.py [PROCEDURE ...]

(a few minutes; name the procedures whose physics changed to redo only theirs). The numbers are those of :func:`mtplan.evaluation.first_order.first_order`,
which the planner, the set-up designer and ``mtplan linearize`` all call, each with the
relative tolerance (``rtol``, ``linearize_rtol``: 1e-9) to which the service must give
them again.

The fixture was first made on the tree before that service (commit 5b6fcea): ``u`` and
``budget`` are the set-up designer's numbers there, ``linearize_u`` linearize's (the
planner's were those of one of the two: its ``first_order_std`` hook, the designer's chain
rule or closed form, else linearize). Where linearize (or, for line_laser's registration,
the designer) differentiated the whole chain at once over more than 256 source elements,
the service takes the chain rule in two parts: the same first-order propagation by other
finite differences, equal to about 1e-7 (``tests/models/first_order_check.py`` holds 1e-5),
so that first fixture's tolerance there is 1e-5 (of u, for the budget's parts).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

OUT = Path(__file__).with_name("first_order_fixture.json")
#: set-up changes from the default for a case whose chain rule at the default set-up takes
#: minutes (line_laser's registration: its estimator's map over 15 600 readings); 16
#: profiles 0.25 mm apart give 3 120 readings
SMALLER = {("line_laser", "registration"): {"lines": 16, "step_mm": 0.25}}


def setup_of(proc, estimator):
    """The set-up a case is taken at: the default, or :data:`SMALLER`'s."""
    return proc.setup(SMALLER.get((proc.name, estimator), {}))


def _service(proc, setup, estimator) -> dict:
    from mtplan.evaluation.first_order import first_order

    fo = first_order(proc, setup, estimator=estimator)
    budget = {m: {src: part["u"] for src, part in parts.items()}
              for m, parts in fo.by_source().items()}
    return {"u": fo.u(), "budget": budget, "rtol": 1e-9, "linearize_u": fo.u(),
            "linearize_rtol": 1e-9}


def numbers(only=()) -> dict:
    """Every procedure's numbers; with `only`, those procedures' anew and the others' kept."""
    from mtplan.models import registry

    out = json.loads(OUT.read_text()) if only else {}
    for name, proc in sorted(registry().items()):
        if only and name not in only:
            continue
        out[name] = {est: _service(proc, setup_of(proc, est), est) for est in proc.estimators}
        print(name, "done", file=sys.stderr, flush=True)
    return out


if __name__ == "__main__":
    OUT.write_text(json.dumps(numbers(sys.argv[1:]), indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT}", file=sys.stderr)
