"""Planning for the compensation the user wants: a target on the residual after it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan import models
from mtplan._validate import InvalidInput
from mtplan.compensation.unseen import unseen_covariance
from mtplan.evaluation.first_order import first_order
from mtplan.plans.planner import plan, target_u


def test_the_residual_is_what_compensate_predicts():
    """The planner's residual after compensating EXX (the function at the travel's end) or
    EYX is the one ``mtplan compensate`` predicts: the measurand's u at the set-up plus the
    unseen covariance's diagonal (what the test cannot see, less what it moved in the
    estimate; its per-point variance is checked against a Monte Carlo of the fields in
    test_unseen.py). At the travel's end it is below the measurand's own u: the estimate
    took up part of the path residual there, and the table removes that part too; the
    quadrature of u and the unseen 0.3 um would overstate it."""
    proc = models.get("geometry21")
    setup = proc.setup(medium_wave_um=0.0)
    gum = first_order(proc, setup)
    u = dict(zip(gum.names, np.sqrt(np.diag(gum.cov))))
    names, d = unseen_covariance(proc, {"procedure": "geometry21", "setup": setup.as_dict(),
                                        "estimator": None})
    for m in ("EXX", "EYX"):
        i = names.index(m)
        assert target_u(proc, setup, "residual:" + m, u) == pytest.approx(
            math.sqrt(u[m] ** 2 + d[i, i]), rel=1e-12)
    assert target_u(proc, setup, "residual:EXX", u) < u["EXX"] < math.hypot(u["EXX"], 0.3)
    assert target_u(proc, setup, "residual:EBX", u) == u["EBX"]  # angles: nothing unseen
    assert target_u(proc, setup, "EXX", u) == u["EXX"]
    assert math.isnan(target_u(proc, setup, "residual:EAX", {"EXX": 0.3}))
    # nothing unseen (no path residual, no medium wave): the measurand's own u
    clean = proc.setup(medium_wave_um=0.0, path_residual_um=0.0)
    assert target_u(proc, clean, "residual:EXX", {"EXX": 0.3}) == 0.3


def test_geometry21_needs_fewer_repeats_for_the_same_target_on_the_residual():
    """EXX's u is 0.603, 0.575 and 0.560 um at one, two and five line repeats; the residual
    after compensating it, 0.568, 0.538 and 0.522 um (the path residual the estimate took
    up at the travel's end is removed by the table too). For 0.59 um the measured value
    needs two repeats, the residual one: the plan differs where the budget says it should,
    and its Monte Carlo confirms it."""
    proc = models.get("geometry21")
    base = proc.setup(medium_wave_um=0.0)
    kwargs = dict(vary={"line_repeats": [1, 2, 5]}, trials=400, confirm=2)
    on_value = plan(proc, base, targets={"EXX": 0.59}, **kwargs)
    on_residual = plan(proc, base, targets={"residual:EXX": 0.59}, **kwargs)
    assert on_value.best["setup"]["line_repeats"] == 2
    assert on_residual.best["setup"]["line_repeats"] == 1
    best = on_residual.best
    assert best["predicted"]["residual:EXX"] < best["predicted"]["EXX"]
    assert best["confirmed"]["residual:EXX"] <= 0.59


def test_a_residual_target_needs_a_measurand_and_a_correction():
    with pytest.raises(InvalidInput, match="names no measurand"):
        plan("circle_centre", None, targets={"residual:centre_z": 2.0}, trials=100)


def test_the_plans_set_up_meets_the_residual_target_in_a_closed_loop():
    """circle_centre: the plan's set-up for a residual target of the work offset, then a
    closed loop by Monte Carlo: 4000 machines, each probed, estimated and corrected; the
    true residual's spread (true centre minus the written correction) meets the target
    within its Monte Carlo error."""
    proc = models.get("circle_centre")
    target = 2.0
    result = plan(proc, None, vary={"n_points": [3, 4, 6, 8]},
                  targets={"residual:centre_x": target}, k=2, trials=200, confirm=2)
    setup = proc.setup(result.best["setup"])
    truth = proc.Truth()
    readings = proc.simulate(setup, truth, draws=4000, rng=11)
    estimate = proc.display_estimate(setup, readings)
    true = proc.display_truth(setup, truth)
    residual = true["centre_x"] - estimate["centre_x"]  # the neutral table: no rounding
    spread = 2 * np.std(residual)
    assert spread <= target * (1 + 3 / math.sqrt(2 * 4000))


def test_a_study_plan_takes_a_residual_target():
    from mtplan.plans.study import load_study

    study = {"title": "t", "procedure": [{"name": "circle_centre", "plan": {
        "targets": {"residual:centre_x": 2.0}, "vary": {"n_points": [3, 4]}}}]}
    assert load_study(study).procedures[0].plan["targets"] == {"residual:centre_x": 2.0}
    study["procedure"][0]["plan"]["targets"] = {"residual:centre_z": 2.0}
    with pytest.raises(InvalidInput, match="'residual:centre_z', which is no measurand"):
        load_study(study)
