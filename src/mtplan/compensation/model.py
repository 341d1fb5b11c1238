"""Corrections: what a controller takes, from a measured result, with its uncertainty.

A procedure states its :class:`~mtplan.models.correction.CorrectionModel`: what is
corrected, in which frame, with which sign, and each corrected quantity (a
:class:`~mtplan.models.correction.CorrectionTerm`) as a linear function of the procedure's
measurands. :func:`correction` applies the model to a measured result (the
``mtplan estimate --json`` document): the values and their covariance follow exactly from
the measurands' through that linear map, so the written U is the measurement's own.

Writers for controllers' formats (:mod:`mtplan.compensation.formats`) read only the
:class:`Correction` record, never the procedure.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models.correction import CorrectionModel

__all__ = ["Correction", "correction", "read_result"]

#: display unit -> factor from the internal unit (mm, rad) for the units corrections use
_FACTOR = {"um": 1e3, "mm": 1.0, "urad": 1e6, "rad": 1.0, "1": 1.0}


@dataclass(frozen=True)
class Correction:
    """A correction with its uncertainty: what ``mtplan compensate`` writes.

    ``value`` [display units] and ``covariance`` [unit_i x unit_j] of the terms in order;
    ``U`` is ``k`` times the standard uncertainty (k = 2). ``source`` names the result it
    came from (procedure, estimator, seed, the measured file's name).
    """

    procedure: str
    kind: str
    frame: str
    sign: str
    names: tuple
    units: tuple
    descriptions: tuple
    value: np.ndarray
    covariance: np.ndarray
    setup: Mapping = field(default_factory=dict)
    source: Mapping = field(default_factory=dict)
    k: float = 2.0
    #: (terms, 2): each term's 95 % coverage interval where the result states one for the
    #: single measurand it scales (the Monte Carlo's own, not +-2u: a location error's
    #: distribution is often far from normal); NaN where the term combines measurands
    interval: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    #: per term: ``(axis, position [mm])`` of a table point, ``()`` for a constant
    arguments: tuple = ()
    #: per term: the standard uncertainty of what the test cannot see, and what it is
    unseen_u: np.ndarray = field(default_factory=lambda: np.empty(0))
    unseen: tuple = ()
    extrapolated: tuple = ()
    #: per term: the nominal value [mm, rad] it is the deviation from (0: none stated)
    nominal: np.ndarray = field(default_factory=lambda: np.empty(0))
    #: (terms, terms): what the test cannot see adds to the residual's covariance, with its
    #: covariance with the estimate's error (:mod:`mtplan.compensation.unseen`); empty:
    #: ``unseen_u`` taken as independent of the estimate and from term to term
    unseen_covariance: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))

    @property
    def u(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def U(self) -> np.ndarray:
        return self.k * self.u

    @property
    def residual_covariance(self) -> np.ndarray:
        """(terms, terms) [unit_i x unit_j]: the covariance of the residual ``true -
        value`` after compensation: the estimate's, plus what the test cannot see
        (``unseen_covariance``, or ``unseen_u`` in quadrature where the model realises
        nothing)."""
        if self.unseen_covariance.size:
            return self.covariance + self.unseen_covariance
        n = len(self.names)
        unseen = self.unseen_u if self.unseen_u.size else np.zeros(n)
        return self.covariance + np.diag(unseen ** 2)

    def internal(self, name: str) -> tuple[float, float]:
        """(value, U) of term `name` in internal units (mm, rad)."""
        i = self.names.index(name)
        f = _FACTOR[self.units[i]]
        return float(self.value[i]) / f, float(self.U[i]) / f

    def rows(self) -> list[dict]:
        """One plain dict per term: the neutral table's rows."""
        return [{"procedure": self.procedure, "term": n, "unit": un,
                 "axis": arg[0] if arg else "", "position": float(arg[1]) if arg else None,
                 "extrapolated": ex, "value": float(v), "u": float(u), "U": float(U),
                 "k": self.k, "interval_low": float(lo), "interval_high": float(hi),
                 "unseen_u": float(us), "unseen": ut, "description": d}
                for n, un, d, v, u, U, (lo, hi), arg, ex, us, ut in zip(
                    self.names, self.units, self.descriptions, self.value, self.u, self.U,
                    self.interval, self.arguments, self.extrapolated, self.unseen_u,
                    self.unseen)]

    @property
    def table(self) -> bool:
        """Some term is a point of a table along an axis."""
        return any(self.arguments)


def read_result(path) -> dict:
    """The ``mtplan estimate --json`` document at `path`, checked for what a correction
    needs: a procedure, measurands with values, and their covariance."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InvalidInput([f"result file {str(path)!r}: no such file"]) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidInput([f"result file {str(path)!r} is not a JSON document ({exc})"]) \
            from None
    problems = []
    if not isinstance(doc, dict) or not isinstance(doc.get("procedure"), str) \
            or not isinstance(doc.get("measurands"), list):
        raise InvalidInput([f"result file {str(path)!r} is not the output of 'mtplan estimate "
                            "--json' (a procedure and its measurands)"])
    cov = doc.get("covariance")
    if not isinstance(cov, dict) or not {"names", "units", "matrix"} <= set(cov):
        problems.append(f"result file {str(path)!r} has no covariance of its measurands: a "
                        "correction's uncertainty needs it (write the result with 'mtplan "
                        "estimate --json')")
    if not isinstance(doc.get("setup"), dict):
        problems.append(f"result file {str(path)!r} has no set-up")
    if problems:
        raise InvalidInput(problems)
    doc = dict(doc)
    doc.setdefault("file", path.name)
    return doc


def correction(model: CorrectionModel, doc: Mapping, *, procedure: str,
               unseen: tuple | None = None) -> Correction:
    """The correction that `model` makes of a measured result `doc` (``estimate --json``).

    Values are the weighted sums of the measurands' values (bias-corrected, as the result
    states them); the covariance is ``A C A^T`` with ``A`` the weights and ``C`` the
    result's covariance: exact, since every term is linear in the measurands. `unseen`,
    ``(measurand names, D)`` (:func:`mtplan.compensation.unseen.unseen_covariance`): what the
    test cannot see adds ``A D A^T`` to the residual's covariance (its share in the
    estimate included); None: ``unseen_u`` in quadrature.

    Raises
    ------
    InvalidInput
        The result is another procedure's, the procedure states no correction, or a
        measurand a term needs has no value or no covariance.
    """
    if doc.get("procedure") != procedure:
        raise InvalidInput([f"the result is of procedure {doc.get('procedure')!r}, not "
                            f"{procedure!r}"])
    held = tuple(m.get("name") for m in doc["measurands"] if m.get("value") is not None)
    setup = doc.get("setup") or {}
    terms = tuple(model.terms(setup, held))
    if not model.kind or not terms:
        raise InvalidInput([f"procedure {procedure!r} states no correction a controller "
                            "takes"])
    cov_doc = doc["covariance"]
    names = list(cov_doc["names"])
    values = {m["name"]: m for m in doc["measurands"]}
    C = np.array([[np.nan if v is None else float(v) for v in row]
                  for row in cov_doc["matrix"]], dtype=float).reshape(len(names), len(names))
    A = np.zeros((len(terms), len(names)))
    problems = []
    for i, term in enumerate(terms):
        for m, w in term.weights.items():
            if m not in names or m not in values:
                problems.append(f"term {term.name!r} needs measurand {m!r}, which the result "
                                "does not hold")
                continue
            A[i, names.index(m)] = w
    if problems:
        raise InvalidInput(problems)
    used = np.any(A != 0, axis=0)  # a term without weights is zero by definition (u = 0)
    x = np.array([values[n]["value"] if values.get(n, {}).get("value") is not None
                  else np.nan for n in names], dtype=float)
    bad = [n for n, ok in zip(names, np.isfinite(x) | ~used) if not ok]
    sub = C[np.ix_(used, used)]
    if bad or not np.all(np.isfinite(sub)):
        missing = bad or [n for j, n in enumerate(np.array(names)[used])
                          if not np.all(np.isfinite(sub[j]))]
        raise InvalidInput([f"measurand {n!r} has no value or no covariance in the result "
                            "(not determined at its set-up): no correction is written from it"
                            for n in missing])
    xs = np.where(used, x, 0.0)
    Cs = np.where(np.outer(used, used), C, 0.0)
    value = A @ xs
    cov = A @ Cs @ A.T
    interval = np.full((len(terms), 2), np.nan)
    for i, row in enumerate(A):
        (cols,) = np.nonzero(row)
        m = values.get(names[cols[0]], {}) if cols.size == 1 else {}
        if m.get("interval") and m.get("coverage") == 0.95 and None not in m["interval"]:
            interval[i] = np.sort(row[cols[0]] * np.asarray(m["interval"], dtype=float))
    if not np.all(np.isfinite(value)) or not all(math.isfinite(v) for v in np.diag(cov)):
        raise InvalidInput(["the result's values or covariance are not finite"])
    shared = np.empty((0, 0))
    if unseen is not None:
        d_names, d = unseen
        at = [list(d_names).index(n) if n in d_names else -1 for n in names]
        pick = np.array([max(i, 0) for i in at])
        known = np.array([i >= 0 for i in at])
        full = np.where(np.outer(known, known), np.asarray(d, float)[np.ix_(pick, pick)], 0.0)
        shared = A @ full @ A.T
        shared = 0.5 * (shared + shared.T)
    return Correction(
        procedure=procedure, kind=model.kind, frame=model.frame, sign=model.sign,
        names=tuple(t.name for t in terms), units=tuple(t.unit for t in terms),
        descriptions=tuple(t.description for t in terms), value=value,
        covariance=0.5 * (cov + cov.T), interval=interval,
        arguments=tuple(tuple(t.argument) for t in terms),
        unseen_u=np.array([math.sqrt(sum((w * model.unseen_of(setup, m)[0]) ** 2
                                          for m, w in t.weights.items())) for t in terms]),
        unseen_covariance=shared,
        unseen=tuple("; ".join(sorted({model.unseen_of(setup, m)[1] for m in t.weights}
                                      - {""})) for t in terms),
        extrapolated=tuple(bool(t.extrapolated) for t in terms),
        nominal=np.array([float(model.nominal(doc.get("setup") or {}).get(t.name, 0.0))
                          for t in terms]),
        setup=dict(doc.get("setup") or {}),
        source={k: doc.get(k) for k in ("procedure", "estimator", "uncertainty", "seed",
                                        "file")})
