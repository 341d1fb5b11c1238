"""Ensemble MCMC with convergence checked, never assumed: the generic sampler.

:func:`run_ensembles` runs several independent emcee ensembles on a vectorised
log-probability until every ensemble's chain is longer than ``n_tau`` integrated
autocorrelation times (the largest estimate over the ensembles), tau has settled
between checks (the ensembles' mean estimate: the largest of four noisy estimates
kept short chains running long after they had converged) and the split R-hat over
the ensembles is below ``rhat_max``. The ensembles advance side by side, each
step's log-probability calls of all of them joined into one (:class:`_Pool`). It knows nothing of procedures: the
procedure posterior (:mod:`mtplan.evaluation.posterior`) builds the
log-probability and the start, and reads the chains.

Randomness: ensemble ``e`` draws its start ball and its moves from child ``e``
of the root ``SeedSequence`` (emcee gets a seeded ``RandomState`` in its
``State``, so numpy's global random state is neither read nor changed).

Moves: :func:`independence_move` proposes every walker afresh from a fixed normal
approximation of the target (for a posterior, its Laplace approximation) and
accepts by the Metropolis-Hastings rule with the proposal's density ratio, so
the chain's target stays exact whatever the approximation; where the
approximation is good, the autocorrelation time is a step or two in any
dimension, where the stretch move's grows with the dimension. :func:`mixed_moves`
mixes it with a random-walk Metropolis move scaled by the same approximation, which
keeps every chain moving where the approximation is poor (heavy tails, bounded
supports, curved ridges).
"""

from __future__ import annotations

import functools
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.uncertainty.options import Options
from mtplan.uncertainty.streams import block_sequence

__all__ = [
    "NotConvergedError",
    "UnconvergedWarning",
    "EnsembleRun",
    "run_ensembles",
    "SamplerOptions",
    "independence_move",
    "random_walk_move",
    "mixed_moves",
    "psd_factor",
    "split_rhat",
    "integrated_time",
]


class NotConvergedError(RuntimeError):
    """The chains did not converge within the step budget.

    Attributes
    ----------
    result : object
        The partial result (flagged not converged), as emcee's ``AutocorrError`` carries ``tau``.
    """

    def __init__(self, message: str, result):
        super().__init__(message)
        self.result = result


class UnconvergedWarning(UserWarning):
    """Warning issued instead of :class:`NotConvergedError` when the caller allows it."""


def split_rhat(chains: np.ndarray) -> np.ndarray:
    """Split R-hat (Gelman et al., BDA3 11.4) over independent ensembles.

    Parameters
    ----------
    chains : array of shape (n_ensembles, n_steps, n_walkers, n_params)
        Post burn-in samples. Each ensemble's chain (its walkers pooled, since the
        walkers of one ensemble are not independent) is split in two halves.

    Returns
    -------
    array of shape (n_params,)
    """
    chains = np.asarray(chains, dtype=float)
    n_steps = chains.shape[1]
    half = n_steps // 2
    if half < 2:
        return np.full(chains.shape[-1], np.inf)
    parts = np.concatenate([chains[:, :half], chains[:, n_steps - half :]], axis=0)
    parts = parts.reshape(parts.shape[0], -1, parts.shape[-1])  # (2 m, n, p)
    n = parts.shape[1]
    means = parts.mean(axis=1)
    within = parts.var(axis=1, ddof=1).mean(axis=0)
    between_over_n = means.var(axis=0, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        var_plus = (n - 1) / n * within + between_over_n
        rhat = np.sqrt(var_plus / within)
    return np.where(within > 0, rhat, np.where(between_over_n > 0, np.inf, 1.0))


def integrated_time(chain: np.ndarray, c: float = 5.0) -> np.ndarray:
    """Integrated autocorrelation time [steps] of (n_steps, n_walkers, n_params), no tolerance.

    emcee's estimator (``emcee.autocorr.integrated_time``: the walkers' normalised
    autocorrelation functions averaged, Sokal's window with c = 5), computed for every
    walker and parameter in one FFT instead of one per walker and parameter; ``inf``
    where it is undefined (a constant chain).
    """
    chain = np.asarray(chain, dtype=float)
    n_t = chain.shape[0]
    if n_t < 2:
        return np.full(chain.shape[-1], np.inf)
    n = 1 << (n_t - 1).bit_length()
    x = chain - chain.mean(axis=0)
    f = np.fft.rfft(x, n=2 * n, axis=0)
    acf = np.fft.irfft(f * np.conjugate(f), n=2 * n, axis=0)[:n_t]
    with np.errstate(divide="ignore", invalid="ignore"):
        acf = (acf / acf[0]).mean(axis=1)  # (n_t, n_params)
        taus = 2.0 * np.cumsum(acf, axis=0) - 1.0
        inside = np.arange(n_t)[:, None] < c * taus
        window = np.where(inside.any(axis=0), np.argmin(inside, axis=0), n_t - 1)
        tau = taus[window, np.arange(taus.shape[1])]
    return np.where(np.isfinite(tau), tau, np.inf)


@dataclass
class EnsembleRun:
    """Chains and diagnostics of :func:`run_ensembles`.

    Attributes
    ----------
    chains : array (n_ensembles, n_steps, n_walkers, n_params)
        Every step of every walker, burn-in included.
    log_prob : array (n_ensembles, n_steps, n_walkers)
    tau : array (n_ensembles, n_params)
        Integrated autocorrelation time of each ensemble [steps].
    rhat : array (n_params,)
        Split R-hat of the kept part at the last check.
    acceptance : array (n_ensembles,)
        Mean acceptance fraction of each ensemble.
    converged : bool
    steps : int
        Steps per ensemble.
    stopped : str
        Why the run stopped: "converged", "max_steps" or "max_seconds".
    """

    chains: np.ndarray
    log_prob: np.ndarray
    tau: np.ndarray
    rhat: np.ndarray
    acceptance: np.ndarray
    converged: bool
    steps: int
    stopped: str

    def burn_and_thin(self, burn_tau: float) -> tuple[int, int]:
        """(discard, thin): `burn_tau` of the largest tau discarded, thinned by half the smallest."""
        tau_max = self.tau.max(axis=0)
        t_max, t_min = float(np.max(tau_max)), float(np.min(tau_max))
        discard = int(math.ceil(burn_tau * t_max)) if math.isfinite(t_max) else self.steps // 2
        discard = min(discard, self.steps - 2)
        thin = max(1, int(0.5 * t_min)) if math.isfinite(t_min) else 1
        return discard, thin


def _ball_factor(ball, ndim: int) -> np.ndarray:
    """The start ball as a matrix A (ndim, ndim): walkers at ``center + A z``, z ~ N(0, I)."""
    ball = np.asarray(ball, dtype=float)
    if ball.ndim == 1 and ball.size == ndim:
        return np.diag(ball)
    if ball.shape == (ndim, ndim):
        return ball
    raise InvalidInput([f"The 'ball' parameter of run_ensembles must be an array ({ndim},) of "
                        f"standard deviations or a ({ndim}, {ndim}) factor. Got shape "
                        f"{ball.shape} instead."])


class _Pool:
    """The ensembles' log-probability calls of one step, joined into one vectorised call.

    Each ensemble runs in a thread of its own (:meth:`advance`); its calls of the
    log-probability wait until every ensemble still running has made its next one, and
    then all are evaluated together, in ensemble order: one forward-model call for all
    ensembles' walkers (a model whose cost per row falls with the batch evaluates 4
    ensembles of 16 walkers in about 60 % of the time of four calls). Which calls join is
    fixed by the ensembles' own (seeded) moves, never by the threads' timing, so the
    result does not depend on it.
    """

    def __init__(self, fn, n: int):
        self.fn, self.n = fn, n
        self.cond = threading.Condition()
        self.live, self.pending, self.results, self.error = n, {}, {}, None

    def call(self, e: int, coords: np.ndarray) -> np.ndarray:
        if self.n == 1:
            return self.fn(coords)
        with self.cond:
            self.pending[e] = coords
            self._run_if_complete()
            while e not in self.results and self.error is None:
                self.cond.wait()
            if e not in self.results:
                raise self.error
            return self.results.pop(e)

    def _leave(self) -> None:
        with self.cond:
            self.live -= 1
            self._run_if_complete()

    def _run_if_complete(self) -> None:
        if not self.pending or len(self.pending) < self.live:
            return
        keys = sorted(self.pending)
        rows = [self.pending.pop(k) for k in keys]
        try:
            out = np.asarray(self.fn(np.concatenate(rows)))
            ends = np.cumsum([len(r) for r in rows])[:-1]
            self.results.update(zip(keys, np.split(out, ends), strict=True))
        except BaseException as exc:  # noqa: BLE001 - every waiting ensemble raises it
            self.error = exc
        self.cond.notify_all()

    def advance(self, samplers, states, n: int, **kwargs) -> list:
        """Run every ensemble `n` steps from `states`; their new states."""
        if self.n == 1:
            return [samplers[0].run_mcmc(states[0], n, progress=False, **kwargs)]
        self.live, self.pending, self.results, self.error = len(samplers), {}, {}, None
        out, errors = [None] * len(samplers), []

        def run(e):
            try:
                out[e] = samplers[e].run_mcmc(states[e], n, progress=False, **kwargs)
            except BaseException as exc:  # noqa: BLE001 - raised again below
                errors.append(exc)
            finally:
                self._leave()

        threads = [threading.Thread(target=run, args=(e,), daemon=True)
                   for e in range(len(samplers))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if errors:
            raise errors[0]
        return out


def _start_state(log_prob, center, factor, n_walkers, seq):
    """An emcee State: walkers in the ball, pulled back inside the support, seeded RandomState."""
    import emcee

    gen = np.random.Generator(np.random.PCG64(seq.spawn(1)[0]))
    p0 = center + gen.standard_normal((n_walkers, center.size)) @ factor.T
    for _ in range(100):  # move starting walkers outside the support back in
        lp0 = log_prob(p0)
        bad = ~np.isfinite(lp0)
        if not bad.any():
            break
        p0[bad] = center + 0.5 * (p0[bad] - center)
    else:
        raise InvalidInput(["The posterior is zero around the start; check the readings and "
                            "the set-up."])
    from emcee.ensemble import walkers_independent

    # walkers in general position: independent when they outnumber the dimensions (emcee
    # would refuse them with a traceback), else spanning as many dimensions as they can
    spread = (walkers_independent(p0) if n_walkers > center.size + 1 else
              np.linalg.matrix_rank(p0 - p0.mean(axis=0), tol=1e-12 * float(np.abs(factor).max()))
              == n_walkers - 1)
    if not spread:
        raise InvalidInput(["The posterior's walkers cannot spread around the start (pulled "
                            "back into the support they collapse onto fewer dimensions than "
                            "the parameters: the readings fit exactly or a parameter sits at "
                            "the edge of its support); use the Monte Carlo uncertainty."])
    rstate = np.random.RandomState(np.random.MT19937(seq)).get_state()
    return emcee.State(p0, log_prob=lp0, random_state=rstate)


def psd_factor(cov) -> np.ndarray:
    """A lower-triangular factor L with ``L L^T`` the symmetric part of `cov`, positive
    definite by construction.

    Computed on the correlation matrix (parameters in mm and rad, or a poorly determined
    one, differ by many orders in variance, and a test in absolute units, such as
    numpy's ``multivariate_normal``'s, fails on such a covariance however exact); where
    round-off leaves it indefinite, its eigenvalues are floored at 1e-12 of the largest.

    Raises
    ------
    InvalidInput
        When a variance is not positive and finite.
    """
    cov = np.asarray(cov, dtype=float)
    cov = 0.5 * (cov + cov.T)
    s = np.sqrt(np.diag(cov))
    if not np.all(np.isfinite(cov)) or not np.all(s > 0):
        raise InvalidInput(["The proposal covariance of the sampler needs positive, finite "
                            "variances on its diagonal."])
    corr = cov / np.outer(s, s)
    try:
        return s[:, None] * np.linalg.cholesky(corr)
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(corr)
        lam = np.maximum(lam, 1e-12 * lam.max())
        # QR of (V sqrt(lam))^T: the same L L^T, lower triangular
        r = np.linalg.qr((vec * np.sqrt(lam)).T, mode="r")
        return s[:, None] * (r.T * np.sign(np.diag(r)))


def independence_move(center, cov, *, inflate: float = 1.1):
    """An emcee move proposing every walker from ``N(center, inflate^2 cov)``.

    Metropolis-Hastings with an independence proposal: the acceptance uses the
    proposal's density at the old and the new point, so the target is sampled
    exactly; the proposal only decides how fast. Inflating it a little keeps its
    tails above a near-normal target's.

    Parameters
    ----------
    center : array (n_params,)
    cov : array (n_params, n_params)
        Positive definite (a Laplace approximation of the target); factored by
        :func:`psd_factor`.
    inflate : float
        Scale factor on the proposal's standard deviations.
    """
    import emcee

    center = np.asarray(center, dtype=float)
    chol = psd_factor(cov) * float(inflate)
    inv = np.linalg.inv(chol)

    def log_q(x):
        z = (x - center) @ inv.T
        return -0.5 * np.einsum("ij,ij->i", z, z)

    def propose(coords, random):
        new = center + random.standard_normal(coords.shape) @ chol.T
        return new, log_q(coords) - log_q(new)

    return emcee.moves.MHMove(propose, ndim=center.size)


def random_walk_move(cov):
    """Random-walk Metropolis: every walker steps by ``N(0, cov)``, drawn through
    :func:`psd_factor` (emcee's ``GaussianMove`` draws with numpy's
    ``multivariate_normal``, which warns of, and mis-draws from, an ill-conditioned
    covariance in absolute units)."""
    import emcee

    chol = psd_factor(cov)

    def propose(coords, random):
        return coords + random.standard_normal(coords.shape) @ chol.T, np.zeros(len(coords))

    return emcee.moves.MHMove(propose, ndim=chol.shape[0])


def mixed_moves(center, cov, *, weight: float = 0.8, inflate: float = 1.0):
    """[(independence move, weight), (random-walk Metropolis, 1 - weight)] for ``run_ensembles``.

    The random walk (:func:`random_walk_move`) steps by ``N(0, 2.38^2 cov / n_params)``,
    the classic scale for a near-normal target; it keeps every chain moving where the
    independence proposal is poor (heavy tails, bounded supports, curved ridges). Both
    moves act on each walker alone, so any number of walkers works (the stretch move
    needs at least twice the dimension).
    """
    cov = np.asarray(cov, dtype=float)
    step = cov * (2.38**2 / cov.shape[0])
    return [(independence_move(center, cov, inflate=inflate), float(weight)),
            (random_walk_move(step), 1.0 - float(weight))]


@dataclass(frozen=True)
class SamplerOptions(Options):
    """How :func:`run_ensembles` runs and when it stops (frozen: change one with
    :meth:`replace`).

    Attributes
    ----------
    n_walkers, n_ensembles, max_steps : int
        Walkers per ensemble, independent ensembles (>= 2 for R-hat), steps per ensemble
        at the most.
    check_every : int, optional
        Steps between convergence checks; default: 25, then a tenth of the chain so far
        (checks soon for fast-mixing chains, rarely for long ones).
    n_tau, tau_rtol, rhat_max, burn_tau : float
        Convergence: chain longer than `n_tau` tau (the largest over the ensembles), the
        relative change of the ensembles' mean tau between checks below `tau_rtol`, split
        R-hat (after `burn_tau` tau of burn-in) below `rhat_max`.
    max_seconds : float, optional
        Wall-clock budget; checked after every ensemble's share of a check interval.
    progress : bool or callable(steps, tau_max, rhat_max), optional
        True: a tqdm bar on stderr (labelled `label`); a callable is called after
        every check.
    label : str
        Name shown by the progress bar.
    """

    n_walkers: int = 16
    n_ensembles: int = 4
    max_steps: int = 20_000
    check_every: int | None = None
    n_tau: float = 50.0
    tau_rtol: float = 0.05
    rhat_max: float = 1.01
    burn_tau: float = 3.0
    max_seconds: float | None = None
    progress: object = None
    label: str = "sampler"

    WHAT = "sampler option"


def run_ensembles(
    log_prob: Callable[[np.ndarray], np.ndarray],
    center: np.ndarray,
    ball: np.ndarray,
    *,
    root: np.random.SeedSequence,
    moves=None,
    options: SamplerOptions | None = None,
    **option_overrides,
) -> EnsembleRun:
    """Run independent emcee ensembles until converged, the step budget or the time budget.

    Parameters
    ----------
    log_prob : callable
        Vectorised log-probability: array (n_walkers, n_params) -> (n_walkers,).
    center : array (n_params,)
    ball : array (n_params,) or (n_params, n_params)
        Walkers start at ``center + ball * N(0, 1)`` (standard deviations), or
        ``center + ball @ N(0, I)`` (a factor of the start covariance).
    root : SeedSequence
        Ensemble ``e`` uses child ``e`` (:func:`mtplan.uncertainty.streams.block_sequence`).
    moves : emcee move(s), optional
        Default: emcee's stretch move (see :func:`mixed_moves`).
    options : SamplerOptions, optional
        Walkers, ensembles, when to stop, progress (:class:`SamplerOptions`); any of its
        fields may be given as a keyword instead (``n_walkers=8, max_steps=2000``).
    """
    o = SamplerOptions.of(options, **option_overrides)
    n_walkers, n_ensembles, max_steps = o.n_walkers, o.n_ensembles, o.max_steps
    check_every, n_tau, tau_rtol, rhat_max = o.check_every, o.n_tau, o.tau_rtol, o.rhat_max
    burn_tau, max_seconds = o.burn_tau, o.max_seconds
    import emcee

    t0 = time.perf_counter()
    center = np.asarray(center, dtype=float)
    ndim = center.size
    factor = _ball_factor(ball, ndim)
    samplers, states = [], []
    pool = _Pool(log_prob, int(n_ensembles))
    for e in range(int(n_ensembles)):
        samplers.append(emcee.EnsembleSampler(n_walkers, ndim, functools.partial(pool.call, e),
                                              vectorize=True, moves=moves))
        states.append(_start_state(log_prob, center, factor, n_walkers, block_sequence(root, e)))
    bar = _bar(o.progress, o.label, int(max_steps))
    steps, tau_prev, converged, stopped = 0, None, False, "max_steps"
    tau_all = np.full((n_ensembles, ndim), np.inf)
    rhat = np.full(ndim, np.inf)
    out_of_time = False
    while steps < max_steps and not out_of_time:
        every = check_every if check_every is not None else max(25, steps // 10)
        n = min(int(every), int(max_steps) - steps)
        states = pool.advance(samplers, states, n, skip_initial_state_check=n_walkers <= ndim + 1)
        steps += n
        tau_all = np.array([integrated_time(s.get_chain()) for s in samplers])
        tau_max = tau_all.max(axis=0)
        t = float(np.max(tau_max))
        discard = min(int(math.ceil(burn_tau * t)) if math.isfinite(t) else steps // 2, steps - 4)
        rhat = split_rhat(np.stack([s.get_chain()[discard:] for s in samplers]))
        # settled: the ensembles' mean tau (half the noise of their largest) moved by less
        # than tau_rtol since the last check; an infinite tau (a chain that has not moved)
        # never counts as settled
        tau_mean = tau_all.mean(axis=0)
        settled = tau_prev is not None and bool(np.all(np.isfinite(tau_mean))
                                                and np.all(np.isfinite(tau_prev))
                                                and np.all(np.abs(tau_mean - tau_prev)
                                                           < tau_rtol * tau_mean))
        if bar is not None:
            bar(steps, t, float(np.max(rhat)))
        if bool(np.all(steps > n_tau * tau_max)) and settled and bool(np.all(rhat < rhat_max)):
            converged, stopped = True, "converged"
            break
        out_of_time = max_seconds is not None and time.perf_counter() - t0 > max_seconds
        if out_of_time:
            stopped = "max_seconds"
        tau_prev = tau_mean
    if bar is not None and hasattr(bar, "close"):
        bar.close()
    return EnsembleRun(
        chains=np.stack([s.get_chain() for s in samplers]),
        log_prob=np.stack([s.get_log_prob() for s in samplers]),
        tau=tau_all,
        rhat=rhat,
        acceptance=np.array([float(np.mean(s.acceptance_fraction)) for s in samplers]),
        converged=converged,
        steps=steps,
        stopped=stopped,
    )


class _TqdmProgress:
    """A tqdm bar over the step budget, with tau and R-hat after every check (stderr)."""

    def __init__(self, label: str, total: int):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=f"posterior {label}", unit="step", file=sys.stderr,
                        leave=False, dynamic_ncols=True)
        self.done = 0

    def __call__(self, steps, tau, rhat):
        self.bar.update(steps - self.done)
        self.done = steps
        self.bar.set_postfix_str(f"tau max {tau:.1f}, R-hat max {rhat:.4f}")

    def close(self):
        self.bar.close()


def _bar(progress, label: str, total: int):
    if progress is True:
        return _TqdmProgress(label, total)
    return progress or None


def stderr_progress(label: str) -> Callable[[int, float, float], None]:
    """A `progress` callback printing one line per check on stderr."""

    def show(steps, tau, rhat):
        print(f"posterior {label}: {steps} steps, tau max {tau:.1f}, R-hat max {rhat:.4f}",
              file=sys.stderr)

    return show
