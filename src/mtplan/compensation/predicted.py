"""The machine after compensation, predicted from a measured result: for the documents.

:func:`predicted` applies the procedure's correction model to a measured result
(:func:`~mtplan.compensation.model.correction`) and predicts the residual after it
(:func:`~mtplan.compensation.formats.residual`, written to full precision: the neutral
table's values), then states which measurand each term corrects and, for the terms that are
points of an error along the travel, the residual's simultaneous band over the whole
curve (:mod:`mtplan.evaluation.along`) from the residual's covariance of the points: the
result's, plus what the test cannot see with its covariance with the estimate's error
(:mod:`mtplan.compensation.unseen`; where the model states no value of it, independent from
point to point, by Slepian's inequality the larger band where the unseen part is in truth
positively correlated).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.compensation.formats import Residual, residual
from mtplan.compensation.model import Correction, correction
from mtplan.compensation.unseen import unseen_covariance
from mtplan.evaluation.along import simultaneous_factor, widen

__all__ = ["Predicted", "predicted"]


@dataclass(frozen=True)
class Predicted:
    """A result's correction and the residual predicted after it.

    ``corrects`` maps each measurand that a term corrects (alone, or as the same quantity
    by the model's ``restates``) to the term's index; ``simultaneous`` holds
    ``(low, high)`` of the residual's simultaneous band per table term and ``factor`` the
    sup-t factor per function (``EXX``)."""

    correction: Correction
    residual: Residual
    corrects: dict = field(default_factory=dict)
    simultaneous: dict = field(default_factory=dict)
    factor: dict = field(default_factory=dict)

    def of(self, measurand: str) -> tuple | None:
        """(low, high, unit) of the residual's 95 % interval after correcting `measurand`,
        or None where no term corrects it."""
        i = self.corrects.get(measurand)
        if i is None:
            return None
        return float(self.residual.low[i]), float(self.residual.high[i]), self.residual.units[i]


def predicted(procedure, doc: dict, *, coverage: float = 0.95) -> Predicted | str:
    """The correction of the measured result `doc` (``estimate --json``, as
    :meth:`MeasuredResult.to_dict` gives it) and the residual after it, or why there is
    none (the procedure states no correction, or the result lacks what it needs)."""
    model = procedure.correction
    if not model.kind:
        return f"{procedure.name} states no correction a controller takes"
    try:
        corr = correction(model, doc, procedure=procedure.name,
                          unseen=unseen_covariance(procedure, doc))
    except InvalidInput as exc:
        return " ".join(exc.problems)
    res = residual(corr)
    setup = doc.get("setup") or {}
    held = tuple(m.get("name") for m in doc["measurands"] if m.get("value") is not None)
    terms = {t.name: t for t in model.terms(setup, held)}
    corrects = {}
    for i, name in enumerate(corr.names):
        weights = dict(terms[name].weights)
        if len(weights) == 1:
            corrects[next(iter(weights))] = i
    for same, other in model.restates(setup).items():
        if other in corrects and same in held:
            corrects.setdefault(same, corrects[other])
    simultaneous, factor = _simultaneous(corr, res, coverage, doc.get("seed"))
    return Predicted(corr, res, corrects, simultaneous, factor)


def _simultaneous(corr: Correction, res: Residual, coverage: float, seed) -> tuple:
    """The residual's simultaneous band over each function's table points."""
    groups: dict = {}
    for i, (name, arg) in enumerate(zip(corr.names, corr.arguments)):
        if arg:
            groups.setdefault(name.split("@")[0], []).append(i)
    total = corr.residual_covariance
    bands, factors = {}, {}
    for function, idx in groups.items():
        idx = np.array(idx)
        cov = total[np.ix_(idx, idx)]
        c = simultaneous_factor(cov, coverage, seed=seed, name=f"residual {function}")
        lo, hi = widen(res.shift[idx], res.low[idx], res.high[idx], c, coverage)
        factors[function] = c
        bands.update({corr.names[i]: (float(a), float(b)) for i, a, b in zip(idx, lo, hi)})
    return bands, factors
