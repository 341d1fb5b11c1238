"""The generic ensemble sampler: R-hat, convergence on a known Gaussian, seeding, budgets."""

from __future__ import annotations

import math

import numpy as np

from mtplan.uncertainty.streams import as_seed_sequence
from mtplan.uncertainty.sampler import run_ensembles, split_rhat

MEAN = np.array([1.0, -2.0])
STD = np.array([0.5, 3.0])


def _log_prob(x):
    return -0.5 * np.sum(((x - MEAN) / STD) ** 2, axis=1)


def _run(seed=3, **kw):
    return run_ensembles(_log_prob, MEAN, 0.1 * STD, root=as_seed_sequence(seed), n_walkers=8,
                         **{"max_steps": 5000, **kw})


def test_split_rhat():
    rng = np.random.default_rng(1)
    same = rng.normal(size=(4, 500, 8, 2))
    assert np.all(split_rhat(same) < 1.01)
    shifted = same.copy()
    shifted[0] += 1.0
    assert np.all(split_rhat(shifted) > 1.05)


def test_converges_to_the_known_gaussian():
    run = _run()
    assert run.converged and run.stopped == "converged"
    discard, thin = run.burn_and_thin(3.0)
    x = run.chains[:, discard::thin].reshape(-1, 2)
    # kept draws are roughly independent after thinning by tau/2: allow 4 standard errors
    # of a mean and of a standard deviation with n_eff = n / 2
    n_eff = x.shape[0] / 2
    assert np.all(np.abs(x.mean(axis=0) - MEAN) < 4 * STD / math.sqrt(n_eff))
    assert np.all(np.abs(x.std(axis=0) / STD - 1) < 4 / math.sqrt(2 * (n_eff - 1)))


def test_same_seed_same_chains_and_global_state_untouched():
    before = np.random.get_state()[1].copy()
    a, b = _run(max_steps=300), _run(max_steps=300)
    assert np.array_equal(a.chains, b.chains)
    assert not np.array_equal(a.chains, _run(seed=4, max_steps=300).chains)
    assert np.array_equal(np.random.get_state()[1], before)


def test_stops_at_the_step_and_time_budgets():
    short = _run(max_steps=200, check_every=100)
    assert short.steps == 200 and not short.converged and short.stopped == "max_steps"
    timed = _run(max_steps=10**6, check_every=50, max_seconds=0.0)
    assert timed.steps == 50 and timed.stopped == "max_seconds"


def test_integrated_time_is_emcees_estimator():
    import emcee

    from mtplan.uncertainty.sampler import integrated_time

    rng = np.random.default_rng(1)
    x = 0.1 * np.cumsum(rng.normal(size=(700, 16, 3)), axis=0) + rng.normal(size=(700, 16, 3))
    np.testing.assert_allclose(integrated_time(x),
                               emcee.autocorr.integrated_time(x, quiet=True, tol=0), rtol=1e-12)
    x[:, :, 1] = 3.0  # a constant chain has no autocorrelation time
    assert np.isinf(integrated_time(x)[1])


def test_the_independence_move_samples_the_target_exactly():
    """A deliberately wrong Laplace approximation (shifted, too narrow) still samples the
    Gaussian: the Metropolis-Hastings ratio carries the proposal's density."""
    from mtplan.uncertainty.sampler import independence_move

    move = independence_move(MEAN + 0.3 * STD, np.diag((0.8 * STD) ** 2), inflate=1.0)
    run = _run(moves=move, max_steps=3000)
    discard, thin = run.burn_and_thin(3.0)
    x = run.chains[:, discard::thin].reshape(-1, 2)
    n_eff = x.shape[0] / 2
    assert np.all(np.abs(x.mean(axis=0) - MEAN) < 4 * STD / math.sqrt(n_eff))
    assert np.all(np.abs(x.std(axis=0) / STD - 1) < 4 / math.sqrt(2 * (n_eff - 1)))
