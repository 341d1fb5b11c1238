"""Validation against references: measured results against calibrated values (E_n numbers).

Simulation-based uncertainty must be checked against measurements of calibrated
artefacts (ISO/TS 15530-4; a laboratory validating its method, ISO/IEC 17025 7.2.2): a
ring gauge's centre and diameter, a calibrated plane's incline, a ball plate. Each
measured value ``y`` is compared with the reference ``y_ref``:

- by its own coverage interval: ``U`` is the half-width of the result's interval on
  the side facing the reference (a Monte Carlo interval is not ``2 u`` where the
  output is not normal), the reference's ``U_ref`` (stated at ``k = 2``) is taken to
  the results' coverage ``p`` (``U_ref,p = z_p U_ref / 2``), and

      E_n = (y - y_ref) / sqrt(U^2 + U_ref,p^2)

  lies within +-1 with probability about ``p`` when both uncertainties are right;
- by the standard uncertainties and their covariance: ``d = y - y_ref`` over the
  comparisons has the covariance ``V``: each result's own (``u^2``, and the covariance
  of the measurands of one measurement from its ``covariance``) plus ``u_ref^2`` for
  every pair of comparisons that share one reference value (repeated measurements of
  one artefact against one calibrated value). The generalised chi-square
  ``T = d^T V^-1 d`` is chi-square with ``n`` degrees of freedom when the
  uncertainties are right; with ``V`` diagonal it is ``sum zeta^2``,
  ``zeta = d / sqrt(u^2 + u_ref^2)``.

Verdicts, each made at the confidence ``LEVEL`` (a right uncertainty is called wrong
with probability at most ``1 - LEVEL``):

- independent comparisons (``V`` diagonal): the share with ``|E_n| <= 1`` against
  ``p`` through its Clopper-Pearson interval, and ``T`` against its two-sided
  chi-square quantiles, each test at half of ``1 - LEVEL``;
- correlated comparisons: the share is no longer binomial (a shared reference's
  error moves every comparison at once), so ``T`` alone decides, at ``1 - LEVEL``.

**uncertainty too small** when ``p`` lies above the share's interval or ``T`` above its
upper quantile; **uncertainty too large** when ``p`` lies below the interval or ``T``
below its lower quantile; **consistent** otherwise. Refused, with the reason: results
at different coverages in one verdict, and a singular ``V``. docs/validate.md states
the method.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["Comparison", "Validation", "validate", "read_results", "read_references",
           "validation_figure", "K_REFERENCE", "LEVEL", "VERDICTS"]

#: coverage factor of the references' stated U (the references file's convention)
K_REFERENCE = 2.0
#: confidence of every verdict: a right uncertainty is called wrong at most 1 - LEVEL
LEVEL = 0.95
CONSISTENT = "consistent"
TOO_SMALL = "uncertainty too small"
TOO_LARGE = "uncertainty too large"
VERDICTS = (CONSISTENT, TOO_SMALL, TOO_LARGE)
SHARE_AND_DISPERSION = "share and dispersion (independent comparisons)"
GENERALISED = "generalised chi-square (correlated comparisons)"
_REF_COLUMNS = ("procedure", "measurand", "value", "U", "unit")
_CORRELATED = 1e-9  # |V_ij| / sqrt(V_ii V_jj) above this: the comparisons are correlated


@lru_cache(maxsize=64)
def _z(p: float) -> float:
    """The coverage factor of a normal at coverage p."""
    from scipy import stats

    return float(stats.norm.isf((1.0 - p) / 2.0))


@dataclass
class Comparison:
    """One measured value against its reference (display units).

    ``U`` is the half-width of the result's own interval at its ``coverage`` on the side
    facing the reference; ``U_reference`` the reference's stated U (k = 2); ``u`` and
    ``u_reference`` the standard uncertainties; ``reference_row`` the reference's row in
    its file (comparisons with the same row share the reference value's error).
    """

    result: str
    procedure: str
    measurand: str
    unit: str
    value: float
    U: float
    reference: float
    U_reference: float
    u: float = math.nan
    coverage: float = 0.9545
    reference_row: int = 0

    @property
    def u_reference(self) -> float:
        return self.U_reference / K_REFERENCE

    @property
    def U_reference_p(self) -> float:
        """The reference's U at the result's coverage (normal)."""
        return _z(self.coverage) * self.u_reference

    @property
    def en(self) -> float:
        """``E_n = (y - y_ref) / sqrt(U^2 + U_ref,p^2)``."""
        return (self.value - self.reference) / math.hypot(self.U, self.U_reference_p)

    @property
    def zeta(self) -> float:
        """``(y - y_ref) / sqrt(u^2 + u_ref^2)``: standard normal when both are right."""
        return (self.value - self.reference) / math.hypot(self.u, self.u_reference)

    def row(self) -> dict:
        return {"result": self.result, "procedure": self.procedure, "measurand": self.measurand,
                "unit": self.unit, "value": self.value, "U": self.U, "coverage": self.coverage,
                "u": self.u, "reference": self.reference, "U_reference": self.U_reference,
                "U_reference_at_coverage": self.U_reference_p, "reference_row": self.reference_row,
                "E_n": self.en, "zeta": self.zeta}


@dataclass
class Verdict:
    """The tests of one group of comparisons, and the verdict.

    ``share``/``interval``: the share with ``|E_n| <= 1`` and its Clopper-Pearson
    interval (at ``share_level``; not tested where ``method`` is the generalised
    chi-square); ``nominal``: the intervals' coverage; ``dispersion``: ``T = d^T V^-1 d``
    with ``n`` degrees of freedom and its ``dispersion_limits`` (two-sided, at
    ``dispersion_level``); ``correlated_by``: what correlates the comparisons.
    """

    n: int
    inside: int
    share: float
    interval: tuple
    nominal: float
    dispersion: float
    dispersion_limits: tuple
    verdict: str
    method: str = SHARE_AND_DISPERSION
    share_level: float | None = None
    dispersion_level: float = LEVEL
    correlated_by: list = field(default_factory=list)

    @property
    def share_tested(self) -> bool:
        return self.method == SHARE_AND_DISPERSION

    def to_dict(self) -> dict:
        return {"n": self.n, "inside": self.inside, "share": self.share,
                "interval": list(self.interval), "nominal": self.nominal,
                "share_tested": self.share_tested, "share_level": self.share_level,
                "dispersion": self.dispersion, "dispersion_limits": list(self.dispersion_limits),
                "dispersion_level": self.dispersion_level, "method": self.method,
                "correlated_by": list(self.correlated_by), "verdict": self.verdict}

    def text(self) -> str:
        """One line: the tests and the verdict."""
        share = (f"{self.inside}/{self.n} with |E_n| <= 1 ({100 * self.share:.0f} %, nominal "
                 f"{100 * self.nominal:.4g} %")
        disp = (f"T = {self.dispersion:.3g} with {self.n} degrees of freedom "
                f"({100 * self.dispersion_level:g} % range [{self.dispersion_limits[0]:.3g}, "
                f"{self.dispersion_limits[1]:.3g}])")
        if self.share_tested:
            return (f"{share}, {100 * self.share_level:g} % interval [{100 * self.interval[0]:.0f}"
                    f", {100 * self.interval[1]:.0f}] %); {disp}: {self.verdict}")
        return (f"{disp} (generalised chi-square: the comparisons are correlated by "
                f"{' and '.join(self.correlated_by)}); {share}, not tested: not binomial): "
                f"{self.verdict}")


@dataclass
class Validation:
    """Every comparison, the verdict over all and per measurand, and what was skipped."""

    comparisons: list
    overall: Verdict
    by_measurand: dict
    level: float = LEVEL
    notes: list = field(default_factory=list)
    covariance: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """The ``--json`` document of ``mtplan validate``."""
        return {"level": self.level, "k_reference": K_REFERENCE,
                "comparisons": [c.row() for c in self.comparisons],
                "overall": self.overall.to_dict(),
                "by_measurand": {k: v.to_dict() for k, v in self.by_measurand.items()},
                "notes": list(self.notes)}

    def frame(self):
        """DataFrame of the comparisons (one row each, E_n included)."""
        import pandas as pd

        return pd.DataFrame([c.row() for c in self.comparisons])


def _verdict(comps: list, V: np.ndarray, level: float, causes: list) -> Verdict:
    """The verdict of comparisons `comps` with covariance `V` (n, n)."""
    from scipy import stats

    n = len(comps)
    coverages = sorted({round(c.coverage, 9) for c in comps})
    if len(coverages) > 1:
        raise InvalidInput([f"the results compared together have intervals at different "
                            f"coverages ({', '.join(f'{p:g}' for p in coverages)}); evaluate "
                            "them at one coverage ('mtplan estimate --coverage')"])
    nominal = coverages[0]
    d = np.array([c.value - c.reference for c in comps])
    try:
        L = np.linalg.cholesky(V)
    except np.linalg.LinAlgError:
        raise InvalidInput(["the comparisons' covariance is singular (a result and its "
                            "reference both without uncertainty, or results that repeat one "
                            "another): no test of the uncertainty is possible"]) from None
    from scipy.linalg import solve_triangular

    white = solve_triangular(L, d, lower=True)
    T = float(white @ white)
    sd = np.sqrt(np.diag(V))
    off = np.abs(V - np.diag(np.diag(V))) > _CORRELATED * np.outer(sd, sd)
    correlated = bool(np.any(off))
    inside = int(sum(abs(c.en) <= 1 for c in comps))
    if correlated:
        a = 1.0 - level
        ci = stats.binomtest(inside, n).proportion_ci(level, method="exact")
        lo, hi = float(stats.chi2.ppf(a / 2, n)), float(stats.chi2.ppf(1 - a / 2, n))
        verdict = TOO_SMALL if T > hi else TOO_LARGE if T < lo else CONSISTENT
        return Verdict(n, inside, inside / n, (float(ci.low), float(ci.high)), nominal, T,
                       (lo, hi), verdict, GENERALISED, None, level, causes)
    half = (1.0 - level) / 2  # each test's share of the false-verdict probability
    ci = stats.binomtest(inside, n).proportion_ci(1.0 - half, method="exact")
    lo, hi = float(stats.chi2.ppf(half / 2, n)), float(stats.chi2.ppf(1 - half / 2, n))
    if nominal > ci.high or T > hi:
        verdict = TOO_SMALL
    elif nominal < ci.low or T < lo:
        verdict = TOO_LARGE
    else:
        verdict = CONSISTENT
    return Verdict(n, inside, inside / n, (float(ci.low), float(ci.high)), nominal, T,
                   (lo, hi), verdict, SHARE_AND_DISPERSION, 1.0 - half, 1.0 - half)


def _result_u(name: str, m: dict, notes: list) -> tuple[float, float, float]:
    """(u, half-width below the value, above it, coverage) of a result's measurand."""
    u = float(m["u"])
    interval, p = m.get("interval"), m.get("coverage")
    if interval is None or p is None or None in interval:
        k = K_REFERENCE
        notes.append(f"{name}: {m['name']} has no coverage interval; U = {k:g} u taken "
                     f"(coverage {100 * (2 * _normal_cdf(k) - 1):.4g} %)")
        return u, k * u, k * u, 2 * _normal_cdf(k) - 1
    y = float(m["value"])
    return u, y - float(interval[0]), float(interval[1]) - y, float(p)


def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


_SHARED_REFERENCE = "a shared reference value"
_RESULT_COVARIANCE = "the covariance of one result's measurands"
_COMMON_SHARE = "the results' common share of u² (the same sensor, set-up or machine)"


def _covariance(comparisons: list, docs: dict, notes: list,
                common: float = 0.0) -> tuple[np.ndarray, dict]:
    """V of the comparisons (display units squared), and what correlates them: cause ->
    boolean (n, n) of the pairs it correlates. `common`: the share of each result's u²
    that every result of the same procedure and measurand has in common (one error for
    all of them: ``common u_i u_j`` between two results)."""
    n = len(comparisons)
    u = np.array([c.u for c in comparisons])
    ur = np.array([c.u_reference for c in comparisons])
    rows = np.array([c.reference_row for c in comparisons])
    shared = (rows[:, None] == rows[None, :]) & (ur[:, None] > 0) & ~np.eye(n, dtype=bool)
    V = np.diag(u**2) + np.where(shared | np.eye(n, dtype=bool), np.outer(ur, ur), 0.0)
    key = np.array([f"{c.procedure} {c.measurand}" for c in comparisons])
    result = np.array([c.result for c in comparisons])
    alike = (key[:, None] == key[None, :]) & (result[:, None] != result[None, :])
    together = alike & (common > 0)
    V += np.where(together, common * np.outer(u, u), 0.0)
    within = np.zeros((n, n), dtype=bool)
    by_result: dict = {}
    for i, c in enumerate(comparisons):
        by_result.setdefault(c.result, []).append(i)
    for name, idx in by_result.items():
        if len(idx) < 2:
            continue
        cov = docs[name].get("covariance")
        try:
            names = list(cov["names"])
            units = cov.get("units") or [comparisons[idx[0]].unit] * len(names)
            at = [names.index(comparisons[i].measurand) for i in idx]
            if any(units[j] != comparisons[i].unit for i, j in zip(idx, at, strict=True)):
                raise ValueError
            block = np.asarray(cov["matrix"], dtype=float)[np.ix_(at, at)]
        except (TypeError, KeyError, ValueError, IndexError):
            notes.append(f"{name}: no covariance of its measurands in the result; they are "
                         "compared as uncorrelated")
            continue
        off = block - np.diag(np.diag(block))
        V[np.ix_(idx, idx)] += off
        within[np.ix_(idx, idx)] = off != 0
    return V, {_SHARED_REFERENCE: shared, _RESULT_COVARIANCE: within, _COMMON_SHARE: together}


def _alike_setups(docs: dict) -> list[str]:
    """Procedures of which several results share one set-up (repeated tests, perhaps with
    one sensor on one machine)."""
    seen: dict = {}
    for doc in docs.values():
        key = (doc.get("procedure"), json.dumps(doc.get("setup"), sort_keys=True, default=str))
        seen[key] = seen.get(key, 0) + 1
    return sorted({proc for (proc, setup), count in seen.items() if count > 1 and setup != "null"})


def validate(results, references, *, level: float = LEVEL, common: float = 0.0) -> Validation:
    """E_n of every measured value that has a reference, and the verdict.

    Parameters
    ----------
    results : list of (str, dict)
        (name, ``mtplan estimate --json`` document) pairs (:func:`read_results`).
    references : list of dict
        Rows ``procedure``, ``measurand``, ``value``, ``U`` (k = 2), ``unit`` and
        optionally ``result`` (the name of the one result it belongs to; empty: every
        result of that procedure, a value they share) (:func:`read_references`).
    level : float
        Confidence of each verdict.
    common : float
        The share (0 to 1) of each result's u² that all results of one procedure and
        measurand have in common: repeated tests with one sensor, one set-up or on one
        machine share those errors, and their comparisons are correlated by them as by a
        shared reference (``common u_i u_j`` between two results). 0: independent results.

    Raises
    ------
    InvalidInput
        No comparison; a reference in another unit; results at different coverages;
        a singular covariance of the comparisons; `common` outside [0, 1].
    """
    if not (isinstance(common, (int, float)) and 0.0 <= common <= 1.0):
        raise InvalidInput([f"The 'common' parameter of validate must be a share from 0 to 1 of "
                            f"the results' u² they have in common. Got {common!r} instead."])
    comparisons, notes, used, docs = [], [], set(), {}
    for name, doc in results:
        proc = doc["procedure"]
        docs[name] = doc
        for m in doc["measurands"]:
            refs = [(i, r) for i, r in enumerate(references)
                    if r["procedure"] == proc and r["measurand"] == m["name"]
                    and r.get("result", "") in ("", name)]
            if not refs:
                continue
            specific = [x for x in refs if x[1].get("result", "")]
            i, ref = (specific or refs)[0]
            used.add(i)
            if ref["unit"] != m["unit"]:
                raise InvalidInput([f"reference of {proc} {m['name']} is in {ref['unit']!r} but "
                                    f"the result {name} gives it in {m['unit']!r}; state the "
                                    "reference in the result's unit"])
            if m.get("value") is None or m.get("u") is None:
                notes.append(f"{name}: {m['name']} not determinable, not compared")
                continue
            u, below, above, p = _result_u(name, m, notes)
            side = above if float(ref["value"]) >= float(m["value"]) else below
            comparisons.append(Comparison(name, proc, m["name"], m["unit"], float(m["value"]),
                                          side, float(ref["value"]), float(ref["U"]), u, p,
                                          i + 1))
    for i, r in enumerate(references):
        if i not in used:
            notes.append(f"reference {r['procedure']} {r['measurand']}"
                         + (f" ({r['result']})" if r.get("result") else "")
                         + " matches no result")
    if not comparisons:
        raise InvalidInput(["no result has a measurand with a reference (the references name "
                            "procedure and measurand as the results do)"])
    V, causes = _covariance(comparisons, docs, notes, float(common))
    if common == 0:
        for proc in _alike_setups({c.result: docs[c.result] for c in comparisons}):
            notes.append(f"{proc}: several results of one set-up were compared as independent "
                         "measurements; where they share a sensor, a set-up or a machine, "
                         "their common errors correlate them: state the common share of u² "
                         "(--common F), or the verdict is wrong far more often than "
                         f"{100 * (1 - level):g} %")
    def group(idx):
        idx = np.asarray(idx)
        why = [c for c, pairs in causes.items() if np.any(pairs[np.ix_(idx, idx)])]
        return _verdict([comparisons[i] for i in idx], V[np.ix_(idx, idx)], level, why)

    groups = {}
    for i, c in enumerate(comparisons):
        groups.setdefault(f"{c.procedure} {c.measurand}", []).append(i)
    by = {g: group(v) for g, v in groups.items()}
    return Validation(comparisons, group(range(len(comparisons))), by, level, notes, V)


# --------------------------------------------------------------------------- files
def read_results(paths) -> list[tuple[str, dict]]:
    """(name, document) of every ``mtplan estimate --json`` file; name: the file's stem."""
    out = []
    for path in map(Path, paths):
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InvalidInput([f"results file {str(path)!r}: no such file"]) from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InvalidInput([f"results file {str(path)!r} is not a JSON document "
                                f"({exc})"]) from None
        ok = isinstance(doc, dict) and isinstance(doc.get("procedure"), str) \
            and isinstance(doc.get("measurands"), list) and all(
                isinstance(m, dict) and {"name", "unit", "value", "u"} <= set(m)
                for m in doc["measurands"])
        if not ok:
            raise InvalidInput([f"results file {str(path)!r} is not the output of 'mtplan "
                                "estimate --json' (a procedure and measurands with name, unit, "
                                "value and u)"])
        out.append((path.stem, doc))
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        raise InvalidInput(["two results files have the same name; the references' 'result' "
                            "column could not tell them apart"])
    return out


def read_references(path) -> list[dict]:
    """Rows of a references CSV: procedure, measurand, value, U, unit[, result].

    Lines starting with ``#`` are comments; ``U`` is the expanded uncertainty (k = 2) of
    the reference value, in the measurand's display unit.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InvalidInput([f"references file {str(path)!r}: no such file"]) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInput([f"references file {str(path)!r} cannot be read ({exc})"]) from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    reader = csv.DictReader(io.StringIO("\n".join(lines)))
    missing = [c for c in _REF_COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise InvalidInput([f"references file {str(path)!r} lacks the column(s) "
                            f"{', '.join(missing)}; its columns must be "
                            f"{', '.join(_REF_COLUMNS)} and optionally result"])
    rows = []
    for j, r in enumerate(reader, start=1):
        row = {c: (r.get(c) or "").strip() for c in (*_REF_COLUMNS, "result")}
        for c in ("value", "U"):
            try:
                row[c] = float(row[c])
            except ValueError:
                row[c] = math.nan
            if not math.isfinite(row[c]) or (c == "U" and row[c] < 0):
                raise InvalidInput([f"references file {str(path)!r}, data row {j}: {c} must be "
                                    f"a finite number{' >= 0' if c == 'U' else ''}. Got "
                                    f"{r.get(c)!r} instead."])
        rows.append(row)
    if not rows:
        raise InvalidInput([f"references file {str(path)!r} has no reference rows"])
    return rows


def validation_figure(v: Validation) -> bytes:
    """PNG: E_n of every comparison by measurand, the |E_n| = 1 limits, the verdict."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(v.by_measurand)
    fig, ax = plt.subplots(figsize=(6.4, 1.6 + 0.35 * len(groups)), layout="constrained")
    for y, g in enumerate(groups):
        en = [c.en for c in v.comparisons if f"{c.procedure} {c.measurand}" == g]
        colour = ["#1b5e20" if abs(e) <= 1 else "#b3261e" for e in en]
        ax.scatter(en, np.full(len(en), y), c=colour, s=18, zorder=3)
    for x in (-1, 1):
        ax.axvline(x, color="#555555", ls="--", lw=1)
    ax.axvline(0, color="#999999", lw=0.8)
    ax.set_yticks(range(len(groups)), [f"{g}: {v.by_measurand[g].verdict}" for g in groups],
                  fontsize=7.5)
    ax.set_xlabel("E_n = (y - y_ref) / sqrt(U^2 + U_ref^2), U at the results' own coverage")
    o = v.overall
    ax.set_ylim(-0.6, len(groups) - 0.4)
    ax.set_title(f"{o.inside}/{o.n} with |E_n| <= 1 (nominal {100 * o.nominal:.4g} %); "
                 f"T = {o.dispersion:.3g}, range [{o.dispersion_limits[0]:.3g}, "
                 f"{o.dispersion_limits[1]:.3g}]\n{o.method}; verdict: {o.verdict}",
                 fontsize=8, loc="left")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=140)
    plt.close(fig)
    return buf.getvalue()
