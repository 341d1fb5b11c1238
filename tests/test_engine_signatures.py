"""The engine's functions take their run options as one record, not a dozen parameters.

Every public function of the engine's modules (the uncertainty engine, a procedure's
evaluation, the fitting machinery, sweeps and the planner) takes at most
:data:`MOST_PARAMETERS` parameters, ``*args`` and ``**kwargs`` counted as one each: the
Monte Carlo's options travel as :class:`mtplan.uncertainty.options.RunOptions`, the
posterior's as :class:`mtplan.evaluation.posterior.PosteriorOptions`, a measured
evaluation's as :class:`mtplan.evaluation.measured.MeasuredOptions` and the fit check's as
:class:`mtplan.evaluation.fitcheck.FitCheckOptions`, each also given field by field as
keywords.
"""

import importlib
import inspect
import pkgutil

import pytest

import mtplan.evaluation
import mtplan.fitting
import mtplan.uncertainty

MOST_PARAMETERS = 8


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
    long = {name: n for name, n in counts.items() if n > MOST_PARAMETERS}
    assert not long, long


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


def test_the_evaluations_options_are_records_and_keywords_alike():
    """A keyword names a field of the function's record (or, for a measured evaluation, of
    the posterior's record within it); an unknown one is refused naming the fields."""
    from mtplan.evaluation.fitcheck import FitCheckOptions, fit_check
    from mtplan.evaluation.measured import MeasuredOptions
    from mtplan.evaluation.posterior import PosteriorOptions, sample_posterior
    from mtplan.models import get

    o = MeasuredOptions.of(None, trials=300, noise="free", max_steps=50)
    assert (o.trials, o.posterior.noise, o.posterior.max_steps) == (300, "free", 50)
    assert MeasuredOptions.of(o, rng=2).posterior == o.posterior
    sampler = PosteriorOptions(n_walkers=8, burn_tau=2.0).sampler("circle_centre")
    assert (sampler.n_walkers, sampler.burn_tau, sampler.label) == (8, 2.0, "circle_centre")
    proc = get("circle_centre")
    setup = proc.Setup()
    readings = proc.simulate(setup, proc.Truth(), 1, rng=4)
    by_record = fit_check(proc, setup, readings, options=FitCheckOptions(alpha=0.01, n_worst=2))
    by_keyword = fit_check(proc, setup, readings, alpha=0.01, n_worst=2)
    assert (by_record.alpha, by_record.chi2, by_record.worst) == \
        (by_keyword.alpha, by_keyword.chi2, by_keyword.worst)
    with pytest.raises(TypeError, match="'n_wrost'"):
        fit_check(proc, setup, readings, n_wrost=2)
    with pytest.raises(TypeError, match="'walkers'.*n_walkers"):
        sample_posterior(proc, setup, readings, walkers=8)
    with pytest.raises(TypeError, match="'trails'"):
        MeasuredOptions.of(None, trails=10)
