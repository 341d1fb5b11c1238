"""The engine's functions take their run options as one record, not a dozen parameters.

Every public function of the engine's modules (the uncertainty engine, a procedure's
evaluation, the fitting machinery, sweeps and the planner) takes at most
:data:`MOST_PARAMETERS` parameters, ``*args`` and ``**kwargs`` counted as one each: the
Monte Carlo's options travel as :class:`mtplan.uncertainty.options.RunOptions`.
"""

import importlib
import inspect
import pkgutil

import pytest

import mtplan.evaluation
import mtplan.fitting
import mtplan.uncertainty

MOST_PARAMETERS = 8

#: functions not yet given their records, with their parameter count today: a count may
#: only fall, and a function leaves this table when it reaches MOST_PARAMETERS
NOT_YET = {
    "mtplan.evaluation.correction.correction_spread": 11,
    "mtplan.evaluation.correction.correct_mc": 17,
    "mtplan.evaluation.fitcheck.fit_check": 9,
    "mtplan.evaluation.measured.estimate_measured": 17,
    "mtplan.evaluation.posterior.sample_posterior": 24,
}


def _modules():
    for package in (mtplan.uncertainty, mtplan.evaluation, mtplan.fitting):
        yield package
        for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
            yield importlib.import_module(info.name)
    yield importlib.import_module("mtplan.plans.sweep")
    yield importlib.import_module("mtplan.plans.planner")


def _public_functions():
    for module in _modules():
        for name, obj in vars(module).items():
            if name.startswith("_") or not inspect.isfunction(obj):
                continue
            if obj.__module__ != module.__name__:
                continue  # imported from elsewhere: judged where it is defined
            yield f"{module.__name__}.{name}", obj


def test_no_engine_function_takes_more_than_eight_parameters():
    counts = {name: len(inspect.signature(f).parameters) for name, f in _public_functions()}
    long = {name: n for name, n in counts.items()
            if n > MOST_PARAMETERS and n > NOT_YET.get(name, MOST_PARAMETERS)}
    assert not long, long
    done = {name for name, n in NOT_YET.items() if counts.get(name, 0) <= MOST_PARAMETERS}
    assert not done, f"{sorted(done)} now take at most {MOST_PARAMETERS}: remove from NOT_YET"


def test_run_options_are_one_record_from_the_engine_to_the_sweep():
    from mtplan.evaluation.simulation import simulate_uncertainty
    from mtplan.plans.sweep import sweep
    from mtplan.uncertainty import Normal, propagate
    from mtplan.uncertainty.options import RunOptions

    opts = RunOptions(trials=400, rng=3)
    by_record = propagate(lambda x: 2 * x, {"x": Normal(0, 1)}, options=opts)
    by_keyword = propagate(lambda x: 2 * x, {"x": Normal(0, 1)}, trials=400, rng=3)
    assert by_record.std[0] == by_keyword.std[0]
    # a keyword replaces the record's field
    more = propagate(lambda x: 2 * x, {"x": Normal(0, 1)}, options=opts, trials=800)
    assert more.trials == 800
    a = simulate_uncertainty("circle_centre", options=opts.replace(progress=False))
    b = simulate_uncertainty("circle_centre", trials=400, rng=3, progress=False)
    assert a.mc.std.tolist() == b.mc.std.tolist()
    table = sweep("circle_centre", vary={"n_points": [4]}, options=opts.replace(progress=False))
    assert table["trials"].eq(400).all()
    with pytest.raises(TypeError, match="'trails'"):
        simulate_uncertainty("circle_centre", trails=10)
    with pytest.raises(TypeError, match="RunOptions"):
        propagate(lambda x: x, {"x": Normal(0, 1)}, options={"trials": 10})
