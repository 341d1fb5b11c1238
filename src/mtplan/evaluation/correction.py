"""The uncertainty of the `mc` bias correction, and the `mc` conditional on the readings.

**Bias correction.** The `mc` value of a measured evaluation is the estimate minus the
estimator's bias ``b``, the mean estimation error of a Monte Carlo at a truth built from
the estimate (:mod:`mtplan.evaluation.measured`). The correction ``-b`` is always applied,
and its own uncertainty (GUM 3.2.3) goes into u:

- its Monte Carlo standard error, ``std(e) / sqrt(N)`` (covariance ``C_mc / N``);
- its dependence on the truth it was computed at. The Monte Carlo runs at one truth, with
  what the estimate does not give (an artifact's pose, a tracker's place, a head's tilts)
  at default values. What the readings say about the whole truth is the Laplace
  approximation of the generalised least squares over the set-up's whole error budget
  (the posterior's start, :mod:`mtplan.evaluation.posterior`); :func:`correction_spread`
  draws a few truths from it and evaluates the bias at each with common random numbers
  (the same error draws), so the difference ``d_k = b(T_k) - b(T_0)`` is free of most
  Monte Carlo noise. Its mean square ``(1/K) sum d_k d_k^T`` is the covariance of this
  part: the spread of the bias over the truths the readings allow, and the offset from
  the defaults, together.

**Conditional on the readings.** :func:`condition_on_readings`: an error source whose effect
is a move of free Truth fields on which no measurand depends (the posterior budget's
*absorbed* sources) is off in the `mc`, those fields at their least-squares values.

:func:`correct_mc` puts the correction's u into an `mc` result's u, interval and covariance
(:func:`mtplan.evaluation.covariance.mc_covariance`).
"""

from __future__ import annotations

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models.protocol import shown_with_unit
from mtplan.evaluation.covariance import correction_u, mc_covariance
from mtplan.evaluation.simulation import Reported

__all__ = ["NUISANCE_DRAWS", "DRAW_TRIALS", "draw_trials", "condition_on_readings",
           "laplace_truths", "correction_spread", "correct_mc"]

#: truths drawn from the readings' least squares at which the bias is evaluated again
NUISANCE_DRAWS = 6
#: Monte Carlo trials per such truth, at most (common random numbers: the differences need few)
DRAW_TRIALS = 200


def draw_trials(trials: int) -> int:
    """Trials per drawn truth: a tenth of the Monte Carlo's, at least 20, at most
    :data:`DRAW_TRIALS`. With the run at the Monte Carlo's truth, seven runs: 70 % of the
    Monte Carlo's trials from 200 to 2000 trials, 14 % at 10 000."""
    return int(min(DRAW_TRIALS, max(int(trials) // 10, 20)))


_STREAM = "bias_correction_truths"  # the draws' own stream in the root seed

_CACHE: dict = {}


def _readings_key(proc, setup, readings) -> tuple:
    import hashlib

    h = hashlib.sha1()
    for k in sorted(readings):
        a = np.ascontiguousarray(np.asarray(readings[k], dtype=float))
        h.update(k.encode() + str(a.shape).encode() + a.tobytes())
    return proc.name, setup, h.hexdigest()


def _least_squares(proc, setup, readings):
    """The readings' generalised least squares over the whole budget, cached per readings:
    ``((builder, theta, kept, root of the kept parameters' covariance, how), None)`` or
    ``(None, reason)``."""
    from mtplan._parallel import one_blas_thread
    from mtplan.evaluation import posterior as post
    from mtplan.evaluation._posterior_model import DOMAIN_ERRORS, Forward, TruthBuilder, \
        truth_parameters

    key = _readings_key(proc, setup, readings)
    if key not in _CACHE:
        if len(_CACHE) > 16:
            _CACHE.clear()
        base = proc.Truth()
        builder = TruthBuilder(base, truth_parameters(proc, base, None))
        try:  # the posterior's start, without its sampling
            fwd = Forward(proc, setup, readings, builder, batch=True)
            with one_blas_thread():
                theta0 = post.initial_theta(proc, setup, readings, builder, None, None, [])
                fit = post.start_fit(fwd, theta0, "setup", None, [])
                space = post.identify(fwd, fit, [])
        except DOMAIN_ERRORS as exc:
            text = " ".join(exc.problems) if isinstance(exc, InvalidInput) else str(exc)
            _CACHE[key] = (None, f"the readings' least squares failed: {text}")
        else:
            k = len(space.kept)
            w, v = np.linalg.eigh(space.cov[:k, :k])
            _CACHE[key] = ((builder, fit.theta.copy(), space.kept,
                            v * np.sqrt(np.clip(w, 0.0, None)), dict(fit.error_model.how)), None)
    return _CACHE[key]


def condition_on_readings(proc, setup, readings, truth):
    """The truth and the sources of an `mc` conditional on what the readings reveal.

    An error source whose effect free Truth parameters that no measurand depends on
    reproduce exactly is *absorbed* by them (the posterior's budget,
    :mod:`mtplan.fitting.error_model`): circle_centre's start scatter is a move of the start
    point, and where the probe started shows in the readings (p1 and p2 lie on the line
    through it). Its realised value sets the design (the contacts' angles), which the
    readings show and a Monte Carlo over it would average away: the covariance of the
    centre would be the average over designs, not this measurement's. So the absorbing
    fields are put at their least-squares values and the absorbed sources are off.

    Returns
    -------
    truth : Truth
        `truth` with the absorbing fields replaced (unchanged when none).
    sources : list of str or None
        The active sources less the absorbed ones (None: all).
    note : str or None
    """
    found, _ = _least_squares(proc, setup, readings)
    if found is None:
        return truth, None, None
    builder, theta, _, _, how = found
    absorbed = {k: v.removeprefix("absorbed by ") for k, v in how.items()
                if v.startswith("absorbed by ")}
    if not absorbed:
        return truth, None, None
    fields = {f.strip() for v in absorbed.values() for f in v.split(",")}
    row = np.array([builder.value_of(truth, p) for p in builder.params])
    at = [i for i, name in enumerate(builder.names) if name in fields]
    row[at] = theta[at]
    conditioned = builder.make(row)
    if conditioned is None:
        return truth, None, None
    sources = [k for k in proc.active_sources(setup) if k not in absorbed]
    shown = ", ".join(shown_with_unit(builder.names[i], theta[i]) for i in at)
    note = (f"the Monte Carlo is conditional on what the readings show: {', '.join(absorbed)} "
            f"off, its realised effect taken as {shown} (the readings' least squares)")
    return conditioned, sources, note


def laplace_truths(proc, setup, readings, n: int, rng) -> tuple[list, str | None]:
    """`n` Truths drawn from what the readings say about the truth, and why none, if so.

    The Laplace approximation of the generalised least squares of every free Truth
    parameter over the set-up's whole error budget (the posterior's start and its
    identification: what the readings do not determine is held at its least-squares
    value, the nuisance error elements marginalised out). A draw outside the Truth's
    domain is left out. Returns ``([], reason)`` where the least squares cannot be made
    (a measurand the readings do not determine, a fit that fails).
    """
    from mtplan.uncertainty.streams import as_seed_sequence, named_generator

    found, why = _least_squares(proc, setup, readings)
    if found is None:
        return [], why
    builder, theta, kept, root_cov, _ = found
    gen = named_generator(as_seed_sequence(rng), _STREAM)
    z = gen.standard_normal((4 * n, root_cov.shape[1]))
    truths = []
    for row in z:  # a few truths, not trials
        th = theta.copy()
        th[kept] = theta[kept] + root_cov @ row
        truth = builder.make(th)
        if truth is not None:
            truths.append(truth)
        if len(truths) == n:
            break
    return truths, None if truths else "no draw of the readings' least squares was a valid truth"


def correction_spread(r, readings, *, heavy, rng, draws: int = NUISANCE_DRAWS,
                      trials: int = DRAW_TRIALS, n_jobs: int = 1):
    """Bias at truths the readings allow minus the bias at the truth of the Monte Carlo `r`
    [display units].

    Parameters
    ----------
    r : ProcedureResult
        The Monte Carlo of the correction: its procedure, set-up, estimator (the one that
        gave the estimate), truth and error sources are those of every run here.
    readings : dict of str to array
        The measurement's readings.
    heavy : array of bool (n_measurands,)
        Measurands whose errors are heavy-tailed: the bias there is the middle of the
        coverage interval, not the mean.
    rng : seed of the estimate; every run here uses the same error draws.
    draws, trials : int
        Truths drawn (:func:`laplace_truths`) and Monte Carlo trials at each.
    n_jobs : int
        Workers over which the truths' Monte Carlos are spread, one Monte Carlo per worker
        at a time (the numbers do not depend on it).

    Returns
    -------
    d : array (n_drawn, n_measurands)
        ``b(T_k) - b(r.truth)`` per drawn truth; (0, n) when none could be drawn.
    reason : str or None
        Why none was drawn.
    """
    from mtplan._parallel import effective_jobs, ordered_map

    proc, setup, estimator, sources = r.procedure, r.setup, r.estimator, r.sources
    n = len(proc.measurands(setup))
    if draws < 1:
        return np.zeros((0, n)), "no truths were drawn (draws = 0)"
    truths, why = laplace_truths(proc, setup, readings, draws, rng)
    if not truths:
        return np.zeros((0, n)), why
    heavy = np.asarray(heavy, dtype=bool)
    # one Monte Carlo per truth, each in one process, the truths spread over the workers
    # (a Monte Carlo of a few dozen trials is one block: within it there is nothing to share)
    tasks = ((proc, setup, t, estimator, sources, trials, rng, heavy, k > 0)
             for k, t in enumerate([r.truth, *truths]))
    b0, *rest = ordered_map(_bias, tasks, n_jobs=min(effective_jobs(n_jobs), len(truths) + 1))
    d = [b - b0 for b in rest if b is not None]
    if not d:
        return np.zeros((0, n)), "the estimator failed at every drawn truth"
    return np.array(d), None


def _bias(proc, setup, truth, estimator, sources, trials, rng, heavy, tolerant):
    """The estimator's bias at `truth` [display units] (:func:`correction_spread`): the
    mean error of a Monte Carlo of `trials` trials, the middle of its interval for the
    `heavy` measurands; None where the estimator fails there and `tolerant` (a drawn truth
    is then left out)."""
    from mtplan.evaluation.simulation import simulate_uncertainty

    try:
        r = simulate_uncertainty(proc, setup, truth, estimator=estimator, sources=sources,
                                 trials=trials, rng=rng, progress=False, n_jobs=1)
    except (InvalidInput, ValueError, ArithmeticError):
        if tolerant:
            return None
        raise
    middle = 0.5 * (r.mc.low + r.mc.high)
    return np.where(heavy, middle, r.mc.mean) - r.true


def correct_mc(r, readings, reported: Reported, *, heavy, rng, cov=None,
               draws: int = NUISANCE_DRAWS, n_jobs: int = 1) -> dict:
    """The correction's uncertainty put into an `mc` result: u, interval and covariance.

    `r` is the Monte Carlo of the correction (:func:`correction_spread`); `reported` the
    corrected values and the Monte Carlo's own u and interval (NaN where a measurand is not
    determinable) at its coverage; `cov` the covariance that stands for the Monte Carlo's
    (the validated first order's).
    The correction's u is ``u_c = sqrt(u_se^2 + u_truth^2)`` (:func:`correction_u`), the
    result's ``sqrt(u^2 + u_c^2)``, each side of the interval ``sqrt(side^2 + (k u_c)^2)``
    (k the normal coverage factor) and the covariance :func:`mc_covariance`.

    Returns
    -------
    dict
        ``u``, ``low``, ``high``, ``u_correction``, ``u_correction_mc``,
        ``u_correction_truth``, ``covariance`` (arrays, display units) and ``notes``.
    """
    from scipy import special

    value, u = np.asarray(reported.value, dtype=float), np.asarray(reported.u, dtype=float)
    low, high, coverage = reported.low, reported.high, reported.coverage
    trials = int(r.mc.trials)
    d, why = correction_spread(r, readings, heavy=heavy, rng=rng, draws=draws,
                               trials=draw_trials(trials), n_jobs=n_jobs)
    se, nuis = correction_u(np.where(heavy, u, r.mc.std), trials, d)
    bad = ~np.isfinite(u)
    # a heavy-tailed measurand is not corrected (its interval is the result): no correction,
    # no correction's uncertainty (a bias from a few hundred trials of such errors is noise)
    u_c = np.where(bad, np.nan, np.where(heavy, 0.0, np.hypot(se, nuis)))
    k = special.ndtri(0.5 + coverage / 2)  # scipy.stats' norm.ppf, without importing it
    notes = []
    if why is not None:
        notes.append(f"the bias correction's dependence on the truth is not in u: {why}")
    else:
        notes.append(f"bias correction: its u is its Monte Carlo standard error and its spread "
                     f"over {d.shape[0]} truths drawn from the readings' least squares "
                     f"({draw_trials(trials)} trials each, common random numbers)")
    return {"u": np.hypot(u, u_c),
            "low": value - np.hypot(value - low, k * u_c),
            "high": value + np.hypot(high - value, k * u_c),
            "u_correction": u_c, "u_correction_mc": np.where(bad, np.nan, se),
            "u_correction_truth": np.where(bad, np.nan, nuis),
            "covariance": mc_covariance(r.mc.cov if cov is None else cov, trials, d,
                                        np.hypot(u, u_c)),
            "notes": notes}
