"""Write ``first_order_fixture.json``: every procedure's first-order numbers at its default
set-up, for every estimator (u per measurand and the budget by source, display units).

``tests/evaluation/test_first_order.py`` holds the linearisation service to these numbers
to 1e-9 relative. When a procedure's physics changes (a new error source, another
default), regenerate them and review the diff:

    PYTHONPATH=src python tests/evaluation/make_first_order_fixture.py

(a few minutes). The numbers are those of :func:`mtplan.evaluation.first_order.first_order`,
which the planner, the set-up designer and ``mtplan linearize`` all call. Run on a tree
from before that service (as the fixture was first made), it records the designer's u and
budget and linearize's u there, each with the relative tolerance (``rtol``,
``linearize_rtol``) to which the service must give them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

OUT = Path(__file__).with_name("first_order_fixture.json")


def _service(proc, setup, estimator) -> dict:
    from mtplan.evaluation.first_order import first_order

    fo = first_order(proc, setup, estimator=estimator)
    return {"u": fo.u(), "budget": fo.budget_std(), "rtol": 1e-9, "linearize_u": fo.u(),
            "linearize_rtol": 1e-9}


def _before_the_service(proc, setup, estimator) -> dict:
    """The tree before the service: the designer's u and budget, and linearize's u.

    The planner's numbers there were those of one of the two (its ``first_order_std``
    hook: the designer's chain rule or closed form; without one, linearize's). Where
    linearize (or, without a first-order budget hook, the designer) differentiated the
    whole chain over more than 256 source elements, the service takes the chain rule in
    two parts: the same first-order propagation by other finite differences, equal to
    about 1e-7 (``tests/models/first_order_check.py`` holds 1e-5), so their ``rtol`` is 1e-5.
    """
    from mtplan.evaluation.simulation import linearize_procedure
    from mtplan.explore import design

    n_el = sum(src.size for src in proc.active_sources(setup).values())
    hook = proc.capabilities.first_order_sensitivities
    closed = hook is not None and hook(setup, proc.Truth(), estimator=estimator) is not None
    whole_rtol = 1e-9 if closed or n_el <= 256 else 1e-5
    chain_hooks = proc.first_order_budget is not None and \
        proc.first_order_budget.__module__ == "mtplan.models.first_order"
    closed_budget = proc.first_order_budget is not None and \
        proc.first_order_budget(setup, estimator=estimator) is not None
    d = design._predict(proc, setup, estimator)
    out = {"u": d["u"], "budget": d["budget"],
           "rtol": 1e-9 if chain_hooks or closed_budget else whole_rtol}
    if not (chain_hooks or closed_budget):  # the designer called linearize itself
        out["linearize_u"] = d["u"]
    else:
        g = linearize_procedure(proc, setup, estimator=estimator)
        out["linearize_u"] = {n: float(s) for n, s in zip(g.names, g.std, strict=True)}
    out["linearize_rtol"] = whole_rtol
    return out


def numbers() -> dict:
    from mtplan.models import registry

    try:
        import mtplan.evaluation.first_order  # noqa: F401

        one = _service
    except ImportError:
        one = _before_the_service
    out = {}
    for name, proc in sorted(registry().items()):
        setup = proc.Setup()
        out[name] = {est: one(proc, setup, est) for est in proc.estimators}
        print(name, "done", file=sys.stderr, flush=True)
    return out


if __name__ == "__main__":
    OUT.write_text(json.dumps(numbers(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT}", file=sys.stderr)
