"""The first-order service: one answer for the planner, the set-up designer and linearize.

The primary test runs the four callers (the planner, the designer, linearize and
estimate's first order) on every procedure at its default set-up with every estimator
(line_laser's registration at 16 profiles: its chain rule over the full scan takes
minutes) and requires the same u and budget to 1e-9 relative. The second holds the
service to the numbers in ``first_order_fixture.json``, first made on the tree before the
service; a change of a procedure's physics (a new error source, another default) changes
them legitimately: regenerate them with the command in ``make_first_order_fixture.py``.

Both take the service through :func:`service_once`: the service is deterministic, so each
distinct question (procedure, set-up, truth, estimator, sources, coverage, chain) is
computed once in this module and its answer (a copy) given to every caller that asks it.
A caller that asks another question (another set-up, truth or set of sources) or finds
its numbers without the service still computes its own and is compared; what is saved is
the same chain rule run five times (line_laser's registration: 8 s each).
"""

import copy
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from mtplan.evaluation import first_order as fo
from mtplan.evaluation.simulation import linearize_result
from mtplan.models import registry
from tests.evaluation.make_first_order_fixture import setup_of

FIXTURE = Path(__file__).with_name("first_order_fixture.json")
CASES = [(name, est) for name, proc in sorted(registry().items()) for est in proc.estimators]


def _close(got: float, want: float, rtol: float, scale: float = 0.0) -> bool:
    """|got - want| within `rtol` of the larger of the two (and of `scale`)."""
    return abs(got - want) <= rtol * max(abs(got), abs(want), scale)


def _linearize_numbers(proc, setup, estimator) -> tuple[dict, dict]:
    """u and budget by source as ``mtplan linearize`` reports them."""
    res = linearize_result(proc, setup, estimator=estimator, reliability=False)
    u = {m.name: float(s) for m, s in zip(res.measurands, res.u, strict=True)}
    budget = {row["name"]: {src: part["u"] for src, part in row["budget"].items()}
              for row in res.to_dict()["measurands"] if row["determinable"]}
    return u, budget


#: the service's answers in this module: (id of the procedure, question) -> (procedure, answer)
_ANSWERS: dict = {}


@pytest.fixture
def service_once(monkeypatch):
    """The first-order service with each question answered once (module notes), where the
    planner, linearize, the designer and estimate take it."""
    from mtplan.evaluation import simulation
    from mtplan.plans import planner

    real = fo.first_order

    def once(proc, setup, truth=None, *, estimator=None, sources=None, coverage=0.95,
             chain=True):
        key = (id(proc), setup, proc.Truth() if truth is None else truth,
               proc.estimator(estimator)[0], None if sources is None else tuple(sources),
               coverage, chain)
        if key not in _ANSWERS:  # (the procedure kept with it: its id is not reused)
            _ANSWERS[key] = proc, real(proc, setup, truth, estimator=estimator,
                                       sources=sources, coverage=coverage, chain=chain)
        return copy.deepcopy(_ANSWERS[key][1])

    for module in (fo, planner, simulation):
        monkeypatch.setattr(module, "first_order", once)


@pytest.mark.parametrize("name, estimator", CASES)
def test_planner_designer_linearize_and_estimate_give_the_same_first_order_numbers(
        name, estimator, service_once):
    from mtplan.evaluation.measured import _first_order
    from mtplan.explore.prediction import compute_prediction
    from mtplan.plans.planner import _assess

    proc = registry()[name]
    setup = setup_of(proc, estimator)
    planner, *_ = _assess(proc, setup, None, estimator, None, True, False)
    designer = compute_prediction(proc, setup, estimator)
    lin_u, lin_budget = _linearize_numbers(proc, setup, estimator)
    estimate = _first_order(proc, setup, proc.Truth(), estimator, None)
    estimate_u, estimate_budget = estimate.u(), estimate.by_source()
    names = [m.name for m in proc.measurands(setup)]
    assert list(planner) == list(designer["u"]) == list(lin_u) == list(estimate_u) == names
    for m in names:
        assert _close(planner[m], lin_u[m], 1e-9), (m, planner[m], lin_u[m])
        assert _close(designer["u"][m], lin_u[m], 1e-9), (m, designer["u"][m], lin_u[m])
        assert _close(estimate_u[m], lin_u[m], 1e-9), (m, estimate_u[m], lin_u[m])
        assert list(estimate_budget[m]) == list(lin_budget[m])
        for src, part in lin_budget[m].items():
            assert _close(estimate_budget[m][src]["u"], part, 1e-9), (m, src)
        assert list(designer["budget"][m]) == list(lin_budget[m])
        for src, part in lin_budget[m].items():
            assert _close(designer["budget"][m][src], part, 1e-9), (m, src)


@pytest.mark.parametrize("name, estimator", CASES)
def test_first_order_numbers_are_the_pinned_ones(name, estimator, service_once):
    """u and budget as pinned (to ``rtol``: 1e-9, or 1e-5 of u where the numbers were
    first made by another finite-difference way of the same propagation, the whole chain
    at once for more than ``WHOLE_MAX`` source elements), and u as linearize had it."""
    want = json.loads(FIXTURE.read_text())[name][estimator]
    proc = registry()[name]
    got = fo.first_order(proc, setup_of(proc, estimator), estimator=estimator)
    u = got.u()
    budget = {m: {src: part["u"] for src, part in parts.items()}
              for m, parts in got.by_source().items()}
    assert sorted(u) == sorted(want["u"])
    for m, value in u.items():
        assert _close(value, want["u"][m], want["rtol"]), (m, value, want["u"][m])
        assert _close(value, want["linearize_u"][m], want["linearize_rtol"]), m
        assert sorted(budget[m]) == sorted(want["budget"][m])
        scale = value if want["rtol"] > 1e-9 else 0.0
        for src, part in budget[m].items():
            assert _close(part, want["budget"][m][src], want["rtol"], scale), (m, src)


def test_derivative_hook_is_used_and_std_and_budget_follow_from_it():
    """A procedure's closed-form sensitivities are the service's, and u and the budget
    follow from them and the sources' standard deviations: doubling the hook's answer
    doubles every number."""
    proc = registry()["geometry21"]
    setup = proc.Setup()
    plain = fo.first_order(proc, setup)
    assert "closed-form" in plain.method and plain.path == "closed form"
    assert plain.cost.seconds > 0 and plain.cost.cpu_seconds > 0

    def doubled(*args, **kw):
        return 2.0 * proc.capabilities.first_order_sensitivities(*args, **kw)

    twice = fo.first_order(dataclasses.replace(proc, capabilities=proc.capabilities.overriding(
        first_order_sensitivities=doubled)), setup)
    np.testing.assert_allclose(twice.std, 2.0 * plain.std, rtol=1e-12)
    np.testing.assert_allclose(twice.group_variance()[1], 4.0 * plain.group_variance()[1],
                               rtol=1e-12)
    table = plain.budget()
    for i, m in enumerate(plain.names):
        shares = table[table.output == m]["share"].sum()
        assert shares == pytest.approx(1.0 if plain.std[i] > 0 else 0.0)


def test_a_hook_of_the_wrong_shape_is_refused_naming_it():
    from mtplan._validate import InvalidInput

    proc = registry()["geometry21"]
    bad = dataclasses.replace(proc, capabilities=proc.capabilities.overriding(
        first_order_sensitivities=lambda *a, **k: np.zeros((1, 1))))
    with pytest.raises(InvalidInput, match="first_order_sensitivities hook of geometry21"):
        fo.first_order(bad, proc.Setup())


def test_the_path_is_named_and_asking_for_the_closed_form_alone_runs_no_chain():
    """``path`` names the way the service took; ``chain=False`` answers None, without the
    chain rule, where the procedure has no closed form for the estimator."""
    proc = registry()["circle_centre"]
    setup = proc.Setup()
    whole = fo.first_order(proc, setup)
    assert whole.path == "whole chain" and "chain rule" in whole.method
    assert fo.first_order(proc, setup, chain=False) is None
    g21 = registry()["geometry21"]
    assert fo.first_order(g21, g21.Setup(), chain=False).path == "closed form"
