"""Monte Carlo engine: determinism across workers, block streams, adaptive stopping,
bounded memory, coverage intervals and error handling."""

from __future__ import annotations

import math
import os
import tracemalloc

import numpy as np
import pytest
from scipy import stats

from mtplan._validate import InvalidInput
from mtplan.uncertainty import (
    ModelError,
    MultivariateNormal,
    Normal,
    Rectangular,
    coverage_interval,
    propagate,
)
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence
from mtplan.uncertainty.montecarlo import numerical_tolerance


def additive(X1, X2, X3, X4):
    return X1 + X2 + X3 + X4


NORMAL4 = {f"X{i}": Normal(0.0, 1.0) for i in range(1, 5)}


def two_outputs(a, b):
    return {"sum": a + b, "prod": a * b}


TWO_INPUTS = {"a": Normal(1.0, 0.1), "b": Rectangular(2.0, 3.0)}


def _same(r1, r2):
    """Bit-identical summaries and covariances."""
    s1, s2 = r1.summary(), r2.summary()
    assert s1.index.equals(s2.index)
    np.testing.assert_array_equal(s1.to_numpy(), s2.to_numpy())
    np.testing.assert_array_equal(r1.cov, r2.cov)


# ----------------------------------------------------------------- determinism
@pytest.mark.parametrize(("n_jobs", "backend"), [(2, "loky"), (2, "threading"), (1, "sequential")])
def test_same_seed_same_result_for_any_worker_count(n_jobs, backend):
    kw = dict(trials=60_000, rng=2024, block_size=10_000, progress=False)
    ref = propagate(two_outputs, TWO_INPUTS, n_jobs=1, **kw)
    _same(ref, propagate(two_outputs, TWO_INPUTS, n_jobs=n_jobs, backend=backend, **kw))


def test_same_seed_same_result_adaptive_threading():
    kw = dict(digits=1, rng=99, block_size=10_000, progress=False)
    ref = propagate(additive, NORMAL4, n_jobs=1, **kw)
    other = propagate(additive, NORMAL4, n_jobs=2, backend="threading", **kw)
    assert ref.trials == other.trials
    _same(ref, other)


RAN_IN: list[int] = []


def pid_recorded(a, b):
    RAN_IN.append(os.getpid())
    return a + b


def test_a_fixed_count_in_one_block_runs_here_whatever_the_workers():
    """One block gains nothing from a worker (it would only pay for its start and the
    model's pickling); its numbers are the same wherever it runs."""
    RAN_IN.clear()
    kw = dict(trials=1000, rng=5, progress=False)
    here = propagate(pid_recorded, TWO_INPUTS, n_jobs=2, backend="loky", **kw)
    assert RAN_IN == [os.getpid()]
    _same(here, propagate(pid_recorded, TWO_INPUTS, n_jobs=1, **kw))


def test_dask_local_cluster_gives_the_same_result():
    import distributed  # noqa: F401 - the test extras hold it: missing is a failure, not a skip
    kw = dict(trials=30_000, rng=7, block_size=10_000, progress=False)
    ref = propagate(two_outputs, TWO_INPUTS, n_jobs=1, **kw)
    _same(ref, propagate(two_outputs, TWO_INPUTS, n_jobs=2, backend="dask", **kw))


def test_rng_forms_agree_and_differ_between_seeds():
    kw = dict(trials=20_000, progress=False)
    a = propagate(additive, NORMAL4, rng=5, **kw)
    _same(a, propagate(additive, NORMAL4, rng=np.random.SeedSequence(5), **kw))
    _same(a, propagate(additive, NORMAL4, rng=np.random.default_rng(5), **kw))
    assert a.mean[0] != propagate(additive, NORMAL4, rng=6, **kw).mean[0]
    c = propagate(additive, NORMAL4, rng=None, **kw)
    _same(c, propagate(additive, NORMAL4, rng=np.random.SeedSequence(c.seed), **kw))


def test_block_streams_are_the_seed_sequence_children():
    root = as_seed_sequence(123)
    children = np.random.SeedSequence(123).spawn(12)
    for i in (0, 1, 5, 11):
        np.testing.assert_array_equal(
            block_sequence(root, i).generate_state(8), children[i].generate_state(8)
        )


def test_first_blocks_do_not_depend_on_trial_count():
    """Block i draws from stream i: a longer run starts with the same values."""
    short = propagate(additive, NORMAL4, trials=20_000, rng=3, block_size=10_000, progress=False)
    long = propagate(additive, NORMAL4, trials=50_000, rng=3, block_size=10_000, progress=False)
    np.testing.assert_array_equal(long.samples("y")[:20_000], short.samples("y"))


# ----------------------------------------------------------------- adaptive Monte Carlo (7.9)
def test_adaptive_stops_and_agrees_with_a_long_run():
    digits = 2
    res = propagate(additive, NORMAL4, digits=digits, rng=11, progress=False)
    assert res.converged and res.digits == digits
    assert res.block_size == 10_000  # max(100/(1-p), 10^4) for p = 0.95
    assert res.trials == res.blocks * res.block_size < 10**8
    long = propagate(additive, NORMAL4, trials=10**6, rng=12, progress=False)
    tol = numerical_tolerance(res.std[0], digits)  # 0.05 for u = 2.0
    assert tol == 0.05
    for name in ("mean", "std", "low", "high"):
        a, b = getattr(res, name)[0], getattr(long, name)[0]
        assert abs(a - b) <= tol, (name, a, b)
    # the stopping rule held: twice the std of the block means <= tolerance
    h = res.blocks
    for name in ("mean", "std", "low", "high"):
        s = res.block_stats[name][:, 0].std(ddof=1) / math.sqrt(h)
        assert 2 * s <= tol


def test_adaptive_reports_non_convergence():
    res = propagate(additive, NORMAL4, digits=4, rng=1, max_trials=30_000, progress=False)
    assert not res.converged
    assert res.trials == 30_000


def test_numerical_tolerance():
    """7.9.2: half a unit in the last significant digit of u."""
    assert numerical_tolerance(2.0, 2) == 0.05
    assert numerical_tolerance(0.0754, 2) == pytest.approx(0.0005)  # u = 75 x 10^-3
    assert numerical_tolerance(0.0234, 2) == pytest.approx(0.0005)  # JCGM 101 7.9.2 example
    assert numerical_tolerance(1.02, 2) == pytest.approx(0.05)
    assert numerical_tolerance(0.99, 2) == pytest.approx(0.005)
    assert numerical_tolerance(1000.0, 2) == pytest.approx(50.0)
    assert numerical_tolerance(32.0, 1) == pytest.approx(5.0)
    assert numerical_tolerance(0.0, 2) == 0.0


def test_power_of_ten_trap():
    """u just above 10^0: the run must use the tolerance of u just below 1 (0.005, not 0.05).

    With u = 1.0005, u's own spread straddles 1; stopping on the coarse tolerance of
    1.0005 (0.05) would take 2 or 3 blocks and leave the last digit undetermined.
    """
    model = lambda x: x  # noqa: E731
    res = propagate(model, {"x": Normal(0.0, 1.0005)}, digits=2, rng=4, progress=False)
    assert res.converged
    h = res.blocks
    s = {k: res.block_stats[k][:, 0].std(ddof=1) / math.sqrt(h) for k in ("mean", "std", "low", "high")}
    assert max(2 * v for v in s.values()) <= 0.005
    assert h > 20  # far more blocks than the coarse tolerance needs
    assert abs(res.std[0] - 1.0005) <= 0.005


# ----------------------------------------------------------------- memory and histogram mode
def _peak(trials, keep):
    tracemalloc.start()
    try:
        propagate(additive, NORMAL4, trials=trials, rng=1, block_size=10_000, keep=keep, progress=False)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_is_bounded_by_block_size():
    small = _peak(10**5, keep=20_000)
    large = _peak(10**7, keep=20_000)  # 100 times more trials, same block size and keep
    assert large < 1.5 * small + 2**20, (small, large)


def test_histogram_interval_matches_exact():
    kw = dict(trials=400_000, rng=21, block_size=10_000, progress=False)
    model = lambda a, b: np.exp(a) + b  # noqa: E731  skewed output
    inputs = {"a": Normal(0.0, 0.5), "b": Rectangular(-1.0, 1.0)}
    for kind in ("symmetric", "shortest"):
        exact = propagate(model, inputs, keep=10**6, interval=kind, **kw)
        hist = propagate(model, inputs, keep=50_000, interval=kind, **kw)
        assert exact.samples("y") is not None and hist.samples("y") is None
        np.testing.assert_array_equal(exact.mean, hist.mean)
        np.testing.assert_array_equal(exact.std, hist.std)
        u = exact.std[0]
        assert abs(hist.low[0] - exact.low[0]) <= 2e-3 * u
        assert abs(hist.high[0] - exact.high[0]) <= 2e-3 * u


# ----------------------------------------------------------------- coverage intervals
def test_jcgm_index_rule():
    """7.7.1: M = 10^4, p = 0.95: q = 9500, r = 250: [y_(250), y_(9750)] (1-based)."""
    y = np.random.default_rng(0).permutation(10_000).astype(float)
    assert coverage_interval(y, 0.95, "symmetric") == (249.0, 9749.0)
    lo, hi = coverage_interval(y, 0.95, "shortest")
    assert hi - lo == 9500.0


@pytest.mark.parametrize("p", [0.5, 0.9, 0.95, 0.99])
def test_intervals_against_analytic_quantiles(p):
    n = 10**6
    rng = np.random.default_rng(int(p * 100))
    z = rng.standard_normal(n)
    lo, hi = coverage_interval(z, p, "symmetric")
    q = stats.norm.ppf((1 + p) / 2)
    se = math.sqrt((1 - p) / 2 * (1 + p) / 2 / n) / stats.norm.pdf(q)
    assert abs(lo + q) <= 4 * se and abs(hi - q) <= 4 * se
    # shortest for the exponential: [0, -ln(1 - p)]
    e = rng.exponential(1.0, n)
    lo, hi = coverage_interval(e, p, "shortest")
    assert lo < 1e-4
    se = math.sqrt(p * (1 - p) / n) / (1 - p)
    assert abs(hi + math.log(1 - p)) <= 4 * se
    # shortest of a symmetric distribution: close to the symmetric one
    lo, hi = coverage_interval(z, p, "shortest")
    assert abs((hi - lo) - 2 * q) <= 0.01


def test_propagate_shortest_and_coverage():
    res = propagate(lambda x: x, {"x": Rectangular(0.0, 1.0)}, trials=200_000, rng=2,
                    coverage=0.9, interval="shortest", progress=False)
    assert res.interval == "shortest" and res.coverage == 0.9
    assert res.high[0] - res.low[0] == pytest.approx(0.9, abs=5e-3)


# ----------------------------------------------------------------- outputs and errors
def test_dict_and_vector_outputs():
    res = propagate(two_outputs, TWO_INPUTS, trials=20_000, rng=1, progress=False)
    assert list(res.summary().index) == ["sum", "prod"]
    assert res.summary()["trials"].tolist() == [20_000, 20_000]
    assert res.mean[res.index("sum")] == pytest.approx(3.5, abs=0.01)
    vec = propagate(lambda X: X * 2.0, {"X": MultivariateNormal([1.0, 2.0], np.eye(2))},
                    trials=20_000, rng=1, progress=False)
    assert vec.names == ("y[0]", "y[1]")
    with pytest.raises(KeyError):
        res.index("nope")


@pytest.mark.parametrize(
    "model",
    [
        lambda x: np.where(x > 2.5, np.nan, x),
        lambda x: np.where(x > 2.5, np.inf, x),
        lambda x: x / (x > -3.0),  # division by zero below -3 gives -inf
    ],
)
def test_non_finite_outputs_raise_model_error(model):
    with np.errstate(all="ignore"), pytest.raises(ModelError, match="non-finite"):
        propagate(model, {"x": Normal(0.0, 1.0)}, trials=50_000, rng=0, progress=False)


def test_wrong_output_shape_raises_model_error():
    with pytest.raises(ModelError, match="shape"):
        propagate(lambda x: x[:10], {"x": Normal(0.0, 1.0)}, trials=1000, rng=0, progress=False)


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [
        ({"trials": 0}, "trials"),
        ({"trials": 1.5}, "trials"),
        ({"trials": "many"}, "trials"),
        ({"digits": 0}, "digits"),
        ({"digits": 9}, "digits"),
        ({"coverage": 1.0}, "coverage"),
        ({"coverage": math.nan}, "coverage"),
        ({"interval": "widest"}, "interval"),
        ({"n_jobs": 0}, "n_jobs"),
        ({"backend": "mpi"}, "backend"),
        ({"block_size": 1}, "block_size"),
        ({"max_trials": -5}, "max_trials"),
        ({"keep": 0}, "keep"),
        ({"scheduler": ""}, "scheduler"),
    ],
)
def test_bad_arguments_raise_invalid_input(kwargs, param):
    with pytest.raises(InvalidInput, match=f"'{param}'"):
        propagate(additive, NORMAL4, **kwargs)


def test_bad_model_inputs_and_rng():
    with pytest.raises(InvalidInput, match="'model'"):
        propagate("x + y", NORMAL4)
    with pytest.raises(InvalidInput, match="'inputs'"):
        propagate(additive, {})
    with pytest.raises(InvalidInput, match="inputs"):
        propagate(additive, {"X1": 1.0})
    with pytest.raises(InvalidInput, match="inputs"):
        propagate(additive, {"not a name": Normal(0, 1)})
    with pytest.raises(InvalidInput, match="trials"):
        propagate(additive, NORMAL4, trials=10, digits=2)
    for bad in (-1, "seed", 1.5):
        with pytest.raises(InvalidInput, match="rng"):
            propagate(additive, NORMAL4, trials=100, rng=bad)
