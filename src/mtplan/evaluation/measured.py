"""Measured data: read a readings CSV, estimate the measurands with their uncertainty.

Reading and checking a readings file, and completing the set-up from it, is
:mod:`mtplan.evaluation.readings` (:func:`read_readings`, :func:`read_measurement`,
re-exported here).

:func:`estimate_measured` gives the measurands with their uncertainty, by Monte
Carlo around the estimate (``"mc"``) or by the posterior of the forward model
(``"posterior"``, :func:`mtplan.evaluation.posterior.sample_posterior`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.evaluation.readings import Measurement, read_measurement, read_readings

__all__ = ["read_readings", "read_measurement", "Measurement", "estimate_measured",
           "MeasuredResult", "UNCERTAINTY_METHODS"]

UNCERTAINTY_METHODS = ("mc", "posterior")


# --------------------------------------------------------------------------- estimate
@dataclass
class MeasuredResult:
    """Measurands estimated from measured readings, with their uncertainty (display units).

    Attributes
    ----------
    procedure, estimator, uncertainty : str
        ``uncertainty`` is ``"mc"`` or ``"posterior"``.
    setup : the procedure's Setup
    measurands : tuple of Measurand
    estimate : array (n_measurands,)
        The estimator's value from the readings.
    value : array (n_measurands,)
        The reported value: the estimate (``mc``) or the posterior mean (``posterior``).
    std : array (n_measurands,)
        Standard uncertainty.
    low, high : array (n_measurands,)
        Coverage interval (``mc``: the estimate minus the Monte Carlo quantiles of the
        estimation error; ``posterior``: equal-tailed credible interval).
    coverage : float
    seed : int or list
    details : ProcedureResult or PosteriorResult
    notes : list of str
    """

    procedure: str
    estimator: str
    uncertainty: str
    setup: object
    measurands: tuple
    estimate: np.ndarray
    value: np.ndarray
    std: np.ndarray
    low: np.ndarray
    high: np.ndarray
    coverage: float
    seed: object
    details: object
    notes: list = field(default_factory=list)

    def summary(self):
        """DataFrame indexed by measurand: unit, estimate, value, std, low, high."""
        import pandas as pd

        return pd.DataFrame(
            {"unit": [m.unit for m in self.measurands], "estimate": self.estimate,
             "value": self.value, "std": self.std, "low": self.low, "high": self.high},
            index=pd.Index([m.name for m in self.measurands], name="measurand"))

    def to_dict(self) -> dict:
        """The ``--json`` document of ``mtplan estimate``."""
        doc = {
            "procedure": self.procedure,
            "estimator": self.estimator,
            "uncertainty": self.uncertainty,
            "setup": self.setup.as_dict(),
            "seed": self.seed,
            "measurands": [
                {"name": m.name, "unit": m.unit, "estimate": float(self.estimate[i]),
                 "value": float(self.value[i]), "std": float(self.std[i]),
                 "interval": [float(self.low[i]), float(self.high[i])],
                 "coverage": float(self.coverage)}
                for i, m in enumerate(self.measurands)
            ],
            "notes": list(self.notes),
        }
        if self.uncertainty == "posterior":
            doc["posterior"] = self.details.to_dict()
        else:
            doc["trials"] = int(self.details.mc.trials)
        return doc


def estimate_measured(
    procedure,
    setup,
    readings,
    *,
    estimator: str | None = None,
    uncertainty: str = "mc",
    trials: int = 10_000,
    coverage: float = 0.95,
    rng=None,
    noise=None,
    allow_unconverged: bool = False,
    posterior_options: dict | None = None,
) -> MeasuredResult:
    """The measurands of one measurement, with their uncertainty.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
    readings : dict of str to array
        A batch of one (:func:`read_readings`).
    estimator : str, optional
        Default: the procedure's default estimator.
    uncertainty : {"mc", "posterior"}
        ``"mc"``: Monte Carlo of the set-up's error sources around the estimate (the
        truth is ``procedure.truth_from_estimate(setup, estimate)`` when the procedure
        has that hook, else its default truth, noted in the result). ``"posterior"``:
        emcee posterior of the forward model (:func:`sample_posterior`).
    trials : int
        Monte Carlo trials (``"mc"``).
    coverage : float
    rng : None, int, SeedSequence or Generator
    noise, allow_unconverged, posterior_options
        Passed to :func:`sample_posterior` (``"posterior"``).

    Returns
    -------
    MeasuredResult
    """
    from mtplan.models import get
    from mtplan.uncertainty._random import as_seed_sequence

    proc = get(procedure)
    proc.check_setup(setup)
    p = Problems(f"estimate {proc.name}")
    p.choice("uncertainty", uncertainty, UNCERTAINTY_METHODS)
    p.number("trials", trials, integer=True, low=2)
    p.number("coverage", coverage, low=0, high=1, low_open=True, high_open=True)
    p.raise_if_any()
    est_name, _ = proc.estimator(estimator)
    measurands = tuple(proc.measurands(setup))
    est_internal = proc.estimate(setup, readings, est_name)
    est_internal = {m.name: float(np.asarray(est_internal[m.name]).reshape(-1)[0])
                    for m in measurands}
    estimate = np.array([est_internal[m.name] * m.scale for m in measurands])
    if not np.all(np.isfinite(estimate)):
        bad = [m.name for m, v in zip(measurands, estimate, strict=True) if not math.isfinite(v)]
        raise InvalidInput([f"The {est_name} estimator of {proc.name} gives no finite value of "
                            f"{', '.join(bad)} from these readings."])
    root = as_seed_sequence(rng)
    seed = root.entropy if isinstance(root.entropy, int) else list(root.entropy)
    notes = []
    if uncertainty == "mc":
        from mtplan.evaluation.simulation import simulate_uncertainty

        if proc.truth_from_estimate is not None:
            truth = proc.truth_from_estimate(setup, est_internal)
        else:
            truth = proc.Truth()
            notes.append(f"{proc.name} has no truth_from_estimate: the Monte Carlo ran at the "
                         "default truth, not at the estimate")
        r = simulate_uncertainty(proc, setup, truth, estimator=est_name, trials=trials,
                                 coverage=coverage, rng=root, progress=False)
        for i, m in enumerate(measurands):
            if not r.mc.std[i] > 0:
                notes.append(f"{m.name}: the {est_name} estimator gives the same value in every "
                             "trial around the estimate, so its uncertainty here is its "
                             "resolution, which this Monte Carlo cannot see; use another "
                             "estimator or --uncertainty posterior")
        err_low = r.mc.low - r.true  # quantiles of the estimation error
        err_high = r.mc.high - r.true
        return MeasuredResult(
            procedure=proc.name, estimator=est_name, uncertainty="mc", setup=setup,
            measurands=measurands, estimate=estimate, value=estimate.copy(),
            std=np.asarray(r.mc.std, dtype=float), low=estimate - err_high,
            high=estimate - err_low, coverage=float(coverage), seed=seed, details=r,
            notes=notes)
    from mtplan.evaluation.posterior import sample_posterior

    post = sample_posterior(proc, setup, readings, noise=noise, estimator=est_name,
                            coverage=coverage, rng=root, allow_unconverged=allow_unconverged,
                            **(posterior_options or {}))
    names = [m.name for m in measurands]
    notes.extend(post.notes)
    systematic = [k for k, src in proc.active_sources(setup).items() if k != proc.noise_source]
    if systematic:
        notes.append("the posterior's likelihood covers the readings' scatter only; the set-up's "
                     f"other error sources ({', '.join(systematic)}) are in --uncertainty mc")
    return MeasuredResult(
        procedure=proc.name, estimator=est_name, uncertainty="posterior", setup=setup,
        measurands=measurands, estimate=estimate,
        value=np.array([post.mean[n] for n in names]),
        std=np.array([post.std[n] for n in names]),
        low=np.array([post.low[n] for n in names]),
        high=np.array([post.high[n] for n in names]),
        coverage=float(coverage), seed=seed, details=post, notes=notes)
