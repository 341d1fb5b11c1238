"""The generic ensemble sampler: R-hat, convergence on a known Gaussian, seeding, budgets."""

from __future__ import annotations

import math
import warnings

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


def _ill_conditioned():
    """A covariance like a posterior's Laplace approximation in mm and rad with poorly
    determined parameters (geometry21's, 34 of them: standard deviations 0.4 to 4e4,
    correlation eigenvalues from 4e-8 to 13): numpy's ``multivariate_normal`` calls it not
    positive-semidefinite (its test is in absolute units), though it is positive definite."""
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(34, 34)))
    corr = (q * np.logspace(-7.5, 1.1, 34)) @ q.T
    d = np.sqrt(np.diag(corr))
    s = np.concatenate([np.full(21, 0.5), np.logspace(3, 4.6, 13)])
    return corr / np.outer(d, d) * np.outer(s, s)


def test_psd_factor_is_positive_definite_where_numpy_warns():
    from mtplan.uncertainty.sampler import psd_factor

    cov = _ill_conditioned()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        np.random.RandomState(0).multivariate_normal(np.zeros(34), cov)
    assert any("positive-semidefinite" in str(w.message) for w in caught)  # the old path
    f = psd_factor(cov)
    assert np.all(np.triu(f, 1) == 0) and np.all(np.diag(f) > 0)
    s = np.sqrt(np.diag(cov))
    # L L^T reproduces the covariance in correlation units (relative to each variance)
    np.testing.assert_allclose((f @ f.T) / np.outer(s, s), cov / np.outer(s, s), atol=1e-7)
    # an indefinite one (round-off gone wrong) is floored, never refused
    bad = cov.copy()
    bad[0, 1] = bad[1, 0] = 1.0001 * s[0] * s[1]
    g = psd_factor(bad)
    assert np.all(np.isfinite(g)) and np.all(np.linalg.eigvalsh((g @ g.T) / np.outer(s, s)) > 0)


def test_random_walk_move_samples_the_target_without_warnings():
    """The random walk scaled by a covariance that numpy's check rejects: no warning
    (warnings are errors here), and the Gaussian is sampled (mean and std within 4 standard
    errors)."""
    from mtplan.uncertainty.sampler import random_walk_move

    cov = np.diag((STD * 2.38 / math.sqrt(2)) ** 2) * 1e12
    cov[0, 0], cov[1, 1] = cov[0, 0] * 1e-12, cov[1, 1] * 1e-12
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = _run(moves=random_walk_move(cov), max_steps=5000)
    discard, thin = run.burn_and_thin(3.0)
    x = run.chains[:, discard::thin].reshape(-1, 2)
    n_eff = x.shape[0] / 2
    assert np.all(np.abs(x.mean(axis=0) - MEAN) < 4 * STD / math.sqrt(n_eff))
    assert np.all(np.abs(x.std(axis=0) / STD - 1) < 4 / math.sqrt(2 * (n_eff - 1)))
