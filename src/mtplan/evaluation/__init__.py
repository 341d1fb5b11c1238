"""Evaluation of a procedure: its set-up's uncertainty and its measured data.

The layer between the procedures (:mod:`mtplan.models`) and the plans: it joins a
procedure's forward model and estimators with the generic engine
(:mod:`mtplan.uncertainty`).

- :mod:`~mtplan.evaluation.first_order`: the one first-order (linearisation) service
  (:func:`mtplan.evaluation.first_order.first_order`): u per measurand, its budget by
  source and the sensitivities of a set-up, for the planner, the set-up designer and
  ``mtplan linearize``.
- :mod:`~mtplan.evaluation.simulation`: Monte Carlo (:func:`simulate_uncertainty`) and
  GUM (:func:`linearize_procedure`) of a set-up, budgets by error source
  (:func:`source_budget`).
- :mod:`~mtplan.evaluation.readings`: a readings file read and checked
  (:func:`read_readings`), or read with the set-up it implies (:func:`read_measurement`).
- :mod:`~mtplan.evaluation.measured`: measurands with their uncertainty from measured
  readings (:func:`estimate_measured`).
- :mod:`~mtplan.evaluation.posterior`: the emcee posterior of a procedure's
  measurands given measured readings (:func:`sample_posterior`).
- :mod:`~mtplan.evaluation.correction`: the uncertainty of the `mc` bias correction;
  :mod:`~mtplan.evaluation.covariance`: the results' covariance.

Heavy submodules are imported on first use, so ``import mtplan.evaluation`` is cheap.
"""

from __future__ import annotations

import importlib

__all__ = [
    "ProcedureResult",
    "simulate_uncertainty",
    "linearize_procedure",
    "linearize_result",
    "LinearizedResult",
    "simulate_readings",
    "source_budget",
    "read_readings",
    "read_measurement",
    "Measurement",
    "estimate_measured",
    "MeasuredResult",
    "sample_posterior",
    "PosteriorResult",
]

_WHERE = {
    "ProcedureResult": "simulation",
    "simulate_uncertainty": "simulation",
    "linearize_procedure": "simulation",
    "linearize_result": "simulation",
    "LinearizedResult": "simulation",
    "simulate_readings": "simulation",
    "source_budget": "simulation",
    "read_readings": "readings",
    "read_measurement": "readings",
    "Measurement": "readings",
    "estimate_measured": "measured",
    "MeasuredResult": "measured",
    "sample_posterior": "posterior",
    "PosteriorResult": "posterior",
}


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(f"mtplan.evaluation.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'mtplan.evaluation' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *__all__])
