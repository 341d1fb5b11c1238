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
  readings`` at the readings of the sources' means (:func:`estimator_map`, central
  differences with a step of 1e-3 of each reading's standard deviation). Both ways are
  finite differences of one first-order propagation: u agrees to about 1e-7.

Std and budget follow from the sensitivities ``J`` and the elements' standard deviations
``u``: the variance of measurand i due to source s is ``sum_(e in s) (J_ie u_e)^2``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.fitting.effects import CHUNK_CELLS, REL_STEP, element_moments, reading_effects
from mtplan.uncertainty.gum import sensitivities

__all__ = ["FirstOrder", "first_order", "estimator_map", "WHOLE_MAX"]

WHOLE_MAX = 256  # source elements up to which the whole chain is differentiated at once


@dataclass
class FirstOrder:
    """The first-order propagation of one set-up's active error sources.

    Attributes
    ----------
    measurands : tuple of Measurand
    value : array (q,)
        The measurands at the sources' means [display unit] (the estimator's run on the
        readings there when first asked for: the planner and the designer need only u).
    sensitivity : array (q, E)
        Their derivative with respect to every element of every active source [display
        unit per internal unit], the sources in order, each one's elements flattened.
    input_std : array (E,)
        Each element's standard deviation [internal unit].
    inputs : tuple of str
        Each element's name (``source`` or ``source[j]``).
    groups : tuple of str
        Each element's source.
    method : str
        How the sensitivities were found (for a reader).
    """

    measurands: tuple
    sensitivity: np.ndarray
    input_std: np.ndarray
    inputs: tuple
    groups: tuple
    method: str
    value_of: Callable = field(repr=False)
    _value: np.ndarray | None = field(default=None, repr=False)

    @property
    def value(self) -> np.ndarray:
        if self._value is None:
            self._value = np.asarray(self.value_of(), dtype=float)
        return self._value

    @property
    def names(self) -> tuple:
        return tuple(m.name for m in self.measurands)

    @property
    def sources(self) -> tuple:
        """The active sources, in order."""
        return tuple(dict.fromkeys(self.groups))

    def variance_by_source(self) -> np.ndarray:
        """V (q, S): the variance of measurand i due to source s alone [display unit^2]."""
        contrib = (self.sensitivity * self.input_std) ** 2
        var = np.zeros((len(self.measurands), len(self.sources)))
        groups = np.asarray(self.groups, dtype=object)
        for s, name in enumerate(self.sources):
            var[:, s] = contrib[:, groups == name].sum(axis=1)
        return var

    @property
    def std(self) -> np.ndarray:
        """Standard uncertainty per measurand [display unit]."""
        return np.sqrt(self.variance_by_source().sum(axis=1))

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the measurands (q, q) [display unit^2], the inputs independent."""
        a = self.sensitivity * self.input_std
        return a @ a.T

    def u(self) -> dict:
        """{measurand: standard uncertainty [display unit]}."""
        return {n: float(s) for n, s in zip(self.names, self.std, strict=True)}

    def budget_std(self) -> dict:
        """{measurand: {source: its part of u [display unit]}}."""
        var = self.variance_by_source()
        return {n: {s: math.sqrt(max(float(var[i, j]), 0.0)) for j, s in enumerate(self.sources)}
                for i, n in enumerate(self.names)}

    def budget(self):
        """DataFrame with ``measurand``, ``unit``, ``source``, ``std`` (its part of u) and
        ``share`` (its share of u^2; the sources are independent, so they add to 1)."""
        import pandas as pd

        var = self.variance_by_source()
        rows = []
        for i, m in enumerate(self.measurands):
            total = float(var[i].sum())
            for j, name in enumerate(self.sources):
                v = max(float(var[i, j]), 0.0)
                rows.append((m.name, m.unit, name, math.sqrt(v), v / total if total > 0 else 0.0))
        return pd.DataFrame(rows, columns=["measurand", "unit", "source", "std", "share"])


def first_order(proc, setup, truth=None, *, estimator: str | None = None, sources=None
                ) -> FirstOrder:
    """The first-order propagation of a set-up's active error sources (module notes).

    Parameters
    ----------
    proc : Procedure
    setup : the procedure's Setup
    truth : the procedure's Truth, optional (its defaults)
    estimator : str, optional (the procedure's default)
    sources : iterable of str, optional
        Only these error sources (default: every active one).
    """
    proc.check_setup(setup)
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
            method = (f"GUM law of propagation (mtplan linearize), closed-form sensitivities "
                      f"of {proc.name}'s {est_name} estimator")
            return FirstOrder(measurands, jac, u, tuple(inputs), tuple(groups), method,
                              value_of)
        chain = _whole_chain if u.size <= WHOLE_MAX else _chain_rule
        value, jac = chain(proc, setup, truth, base, stats, measure)
    return FirstOrder(measurands, jac, u, tuple(inputs), tuple(groups),
                      "GUM law of propagation (mtplan linearize), chain rule through the "
                      "forward model and the estimator",
                      value_of, value)


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


def estimator_map(estimate, y0: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Jacobian (q, n) of ``estimate(rows (m, n)) -> (m, q)`` at `y0` by central
    differences with the given steps (cache-sized batches of rows).

    Central, not Richardson: with steps of 1e-3 of the readings' standard deviation the
    truncation error is of order 1e-6 (sd / L)^2 of the derivative for an estimator
    curving on a length L, far below the round-off of the differences (about 1e-7).
    """
    n = y0.size
    cols = np.tile(np.arange(n), 2)
    delta = np.concatenate([steps, -steps])
    chunk = max(16, CHUNK_CELLS // max(n, 1))
    out = []
    for s in range(0, 2 * n, chunk):
        e = min(2 * n, s + chunk)
        rows = np.repeat(y0[None, :], e - s, axis=0)
        rows[np.arange(e - s), cols[s:e]] += delta[s:e]
        out.append(np.asarray(estimate(rows), dtype=float))
    v = np.concatenate(out)
    return ((v[:n] - v[n:]) / (2 * steps[:, None])).T
