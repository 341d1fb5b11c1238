"""The first-order (linearisation) service: one answer for the planner, the designer and
``mtplan linearize``.

:func:`first_order` answers "what is the first-order budget of this set-up with this
estimator and these sources?": the measurands at the sources' means, their sensitivity to
every element of every active error source, and from these the standard uncertainty per
measurand and its budget by source (the GUM law of propagation, the sources independent).
The planner's screening (:func:`mtplan.plans.plan`), the set-up designer's live numbers
and ``mtplan linearize`` (:func:`mtplan.evaluation.linearize_procedure`) all call it, so
they give the same numbers.

The sensitivities come from one of two places:

- the procedure's derivative hook, ``Capabilities.first_order_sensitivities`` (as
  astropy.modeling's ``fit_deriv``), where the procedure overrides it and it answers for the
  estimator: a closed form through the estimator's linear map (geometry21, line_laser);
- otherwise the chain rule, forward model then estimator, by finite differences. With up
  to :data:`WHOLE_MAX` source elements the whole chain is differentiated at once
  (Richardson central differences, steps of 1e-3 standard deviation: ``4 E + 1`` runs);
  above, in two smaller parts: the readings' derivative with respect to every element
  (:func:`mtplan.fitting.effects.reading_effects`: elements moved together in groups in
  which every reading depends on one element at most, so that a source of reading noise
  costs 5 forward runs, not ``4 E``) and the estimator's map ``G = d estimate / d
  readings`` at the readings of the sources' means
  (:func:`~mtplan.fitting.effects.estimator_map`, central
  differences with a step of 1e-3 of each reading's standard deviation). Both ways are
  finite differences of one first-order propagation: u agrees to about 1e-7.

The result is the engine's one first-order result, a
:class:`~mtplan.uncertainty.gum.GUMResult` (``mtplan linearize`` prints it as it is): u
and the budget follow from the sensitivities ``J`` and the elements' standard deviations
``u``: the variance of measurand i due to source s is ``sum_(e in s) (J_ie u_e)^2``. Its
``path`` says which of the ways above gave the sensitivities and ``cost`` what they took,
so that a caller (the designer's cost guard) reads them instead of timing the hook.
"""

from __future__ import annotations

import time

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput, Problems
from mtplan.fitting.effects import (
    CHUNK_CELLS,
    REL_STEP,
    element_moments,
    estimator_map,
    reading_effects,
)
from mtplan.uncertainty.gum import Cost, GUMResult, sensitivities

__all__ = ["first_order", "WHOLE_MAX"]

WHOLE_MAX = 256  # source elements up to which the whole chain is differentiated at once


def first_order(proc, setup, truth=None, *, estimator: str | None = None, sources=None,
                coverage: float = 0.95, chain: bool = True,
                max_runs: int | None = None) -> GUMResult | None:
    """The first-order propagation of a set-up's active error sources (module notes).

    Parameters
    ----------
    proc : Procedure
    setup : the procedure's Setup
    truth : the procedure's Truth, optional (its defaults)
    estimator : str, optional (the procedure's default)
    sources : iterable of str, optional
        Only these error sources (default: every active one).
    coverage : float
        Coverage probability of the intervals ``value +- k u`` (k normal: the sources'
        standard deviations are known, infinite degrees of freedom).
    chain : bool
        False: only the procedure's closed form; None where it has none for the estimator
        (what it would take to ask, without running the chain rule).
    max_runs : int, optional
        The chain rule only where it runs the estimator at most this many times (the whole
        chain ``4 E + 1``, the estimator's map two per reading); None where it would take
        more (a caller for whom the sensitivities are worth no more than that).

    Returns
    -------
    GUMResult
        In display units, one input per source element (``source`` or ``source[j]``,
        grouped by source); ``path`` says which way the sensitivities were found
        (:data:`~mtplan.uncertainty.gum.PATHS`) and ``cost`` what that took.
    """
    proc.check_setup(setup)
    p = Problems(f"linearize {proc.name}")
    p.number("coverage", coverage, low=0, high=1, low_open=True, high_open=True)
    p.raise_if_any()
    truth = proc.Truth() if truth is None else truth
    est_name, _ = proc.estimator(estimator)
    active = proc.active_sources(setup, sources)
    measurands = tuple(proc.measurands(setup))
    stats, inputs, groups = {}, [], []
    for name, src in active.items():
        mean, std, shape = element_moments(src)
        stats[name] = (mean, std, shape)
        groups += [name] * mean.size
        inputs += [name] if mean.size == 1 and not shape else [f"{name}[{j}]"
                                                                for j in range(mean.size)]
    u = np.concatenate([st[1] for st in stats.values()]) if stats else np.zeros(0)
    base = proc.zero_errors(setup, 1)  # one trial at the sources' means
    for name, (mean, _std, shape) in stats.items():
        base[name] = mean.reshape((1, *shape))

    def measure(readings):  # (m, q) [display units]
        est = proc.estimators[est_name](setup, readings)
        return np.column_stack([np.asarray(est[m.name], dtype=float).reshape(-1) * m.scale
                                for m in measurands])

    def value_of():
        with one_blas_thread():
            return measure(proc.forward(setup, truth, base))[0]

    def result(jac, path, method, value=None):
        return GUMResult(names=tuple(m.name for m in measurands), inputs=tuple(inputs),
                         groups=tuple(groups), sensitivity=jac, input_std=u,
                         dof=np.full(len(measurands), np.inf), coverage=coverage,
                         units=tuple(m.unit for m in measurands), path=path, method=method,
                         cost=Cost(time.perf_counter() - start[0],
                                   time.thread_time() - start[1]),
                         value_of=value_of, _value=value)

    start = time.perf_counter(), time.thread_time()
    # small products: a team of BLAS threads costs more than it gains, most on a busy machine
    with one_blas_thread():
        jac = proc.capabilities.first_order_sensitivities(setup, truth, estimator=est_name,
                                                           sources=sources)
        if jac is not None:
            jac = np.asarray(jac, dtype=float)
            if jac.shape != (len(measurands), u.size):
                raise InvalidInput([f"The first_order_sensitivities hook of {proc.name} gave "
                                    f"shape {jac.shape}; the linearisation needs "
                                    f"({len(measurands)}, {u.size})."])
            return result(jac, "closed form",
                          f"GUM law of propagation (mtplan linearize), closed-form "
                          f"sensitivities of {proc.name}'s {est_name} estimator")
        if not chain:
            return None
        whole = u.size <= WHOLE_MAX
        if max_runs is not None and _chain_runs(proc, setup, truth, base, whole, u.size) \
                > max_runs:
            return None
        value, jac = (_whole_chain if whole else _chain_rule)(proc, setup, truth, base, stats,
                                                              measure)
    return result(jac, "whole chain" if whole else "chain rule",
                  "GUM law of propagation (mtplan linearize), chain rule through the forward "
                  "model and the estimator", value)


def _chain_runs(proc, setup, truth, base, whole: bool, elements: int) -> int:
    """The estimator runs the chain rule takes: ``4 E + 1`` for the whole chain (Richardson
    central differences), two per reading for the estimator's map."""
    if whole:
        return 4 * elements + 1
    return 2 * sum(np.asarray(v).size for v in proc.forward(setup, truth, base).values())


def _whole_chain(proc, setup, truth, base, stats, measure):
    """Value and Jacobian by differentiating forward model and estimator together."""
    names = list(stats)
    if not names:  # no active source: no sensitivity
        value = measure(proc.forward(setup, truth, base))[0]
        return value, np.zeros((value.size, 0))
    x = np.concatenate([stats[k][0] for k in names])
    u = np.concatenate([stats[k][1] for k in names])
    sizes = np.cumsum([0] + [stats[k][0].size for k in names])

    def chain(points):
        m = points.shape[0]
        errors = {k: np.repeat(v, m, axis=0) for k, v in base.items()}
        for k, a, b in zip(names, sizes[:-1], sizes[1:], strict=True):
            errors[k] = points[:, a:b].reshape((m, *stats[k][2]))
        return measure(proc.forward(setup, truth, errors))

    return sensitivities(chain, x, u, max_batch=max(64, CHUNK_CELLS // max(x.size, 1)))


def _chain_rule(proc, setup, truth, base, stats, measure):
    """Jacobian as the estimator's map times the readings' effects (value None: taken when
    first asked for)."""
    zero = proc.forward(setup, truth, base)
    layout = [(k, np.asarray(v).shape[1:]) for k, v in zero.items()]

    def flat(readings):  # the readings flattened per row, in the forward model's order
        m = next(iter(readings.values())).shape[0]
        return np.concatenate([np.asarray(v, dtype=float).reshape(m, -1)
                               for v in readings.values()], axis=1)

    def estimate(rows):  # rows of flattened readings, split back for the estimator
        m, pos, readings = rows.shape[0], 0, {}
        for k, shape in layout:
            size = int(np.prod(shape, dtype=np.int64))
            readings[k] = rows[:, pos:pos + size].reshape((m, *shape))
            pos += size
        return measure(readings)

    f0, effects = reading_effects(lambda errors: flat(proc.forward(setup, truth, errors)),
                                  base, stats, key=proc.name)
    var_r = sum((e**2).sum(axis=1) for e in effects.values())
    sd = np.sqrt(var_r)
    steps = np.where(sd > 0, REL_STEP * sd,
                     np.cbrt(np.finfo(float).eps) * np.maximum(np.abs(f0), 1.0))
    g = estimator_map(estimate, f0, steps)
    cols = []
    for name, e in effects.items():
        std = stats[name][1]
        with np.errstate(divide="ignore", invalid="ignore"):
            cols.append(np.where(std > 0, (g @ e) / np.where(std > 0, std, 1.0), 0.0))
    return None, np.hstack(cols)  # (the value when asked for: the planner and designer need u)
