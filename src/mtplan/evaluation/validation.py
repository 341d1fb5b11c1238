"""Validation against references: measured results against calibrated values (E_n numbers).

Simulation-based uncertainty must be checked against measurements of calibrated
artefacts (ISO/TS 15530-4; a laboratory validating its method, ISO/IEC 17025 7.2.2): a
ring gauge's centre and diameter, a calibrated plane's incline, a ball plate. Each
measured value ``y`` with its expanded uncertainty ``U = k u`` is compared with the
reference ``y_ref`` and its ``U_ref`` (both at ``k = 2``):

    E_n = (y - y_ref) / sqrt(U^2 + U_ref^2)

When both uncertainties are right, ``2 E_n`` is standard normal, so ``|E_n| <= 1``
holds with the nominal probability ``P(|N(0,1)| <= k) = 0.9545``. Over ``n``
comparisons the share with ``|E_n| <= 1`` is compared with that probability through
its 95 % Clopper-Pearson interval, and the dispersion ``sum (k E_n)^2`` with the
chi-square distribution of ``n`` degrees of freedom (two-sided 95 %):

- **uncertainty too small**: the nominal probability lies above the share's interval,
  or the dispersion is above its upper quantile;
- **uncertainty too large**: the nominal probability lies below the share's interval,
  or the dispersion is below its lower quantile (the share alone rarely shows this:
  it cannot exceed 1);
- **consistent** otherwise.

Comparisons of the measurands of one measurement are correlated; the test treats
them as independent, which is exact for one measurand over independent
measurements. docs/fit_check.md states the method with the fit check.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["Comparison", "Validation", "validate", "read_results", "read_references",
           "validation_figure", "K", "VERDICTS"]

#: coverage factor of every expanded uncertainty compared (results' and references')
K = 2.0
CONSISTENT = "consistent"
TOO_SMALL = "uncertainty too small"
TOO_LARGE = "uncertainty too large"
VERDICTS = (CONSISTENT, TOO_SMALL, TOO_LARGE)
_LEVEL = 0.95  # confidence of the share's interval and of the dispersion's quantiles
_REF_COLUMNS = ("procedure", "measurand", "value", "U", "unit")


@dataclass
class Comparison:
    """One measured value against its reference (display units)."""

    result: str
    procedure: str
    measurand: str
    unit: str
    value: float
    U: float
    reference: float
    U_reference: float

    @property
    def en(self) -> float:
        """``E_n = (y - y_ref) / sqrt(U^2 + U_ref^2)``."""
        return (self.value - self.reference) / math.hypot(self.U, self.U_reference)

    def row(self) -> dict:
        return {"result": self.result, "procedure": self.procedure, "measurand": self.measurand,
                "unit": self.unit, "value": self.value, "U": self.U, "reference": self.reference,
                "U_reference": self.U_reference, "E_n": self.en}


@dataclass
class Verdict:
    """The share of ``|E_n| <= 1`` against the nominal probability, and the verdict."""

    n: int
    inside: int
    share: float
    interval: tuple
    nominal: float
    dispersion: float
    dispersion_limits: tuple
    verdict: str

    def to_dict(self) -> dict:
        return {"n": self.n, "inside": self.inside, "share": self.share,
                "interval": list(self.interval), "nominal": self.nominal,
                "dispersion": self.dispersion, "dispersion_limits": list(self.dispersion_limits),
                "verdict": self.verdict}


@dataclass
class Validation:
    """Every comparison, the verdict over all and per measurand, and what was skipped."""

    comparisons: list
    overall: Verdict
    by_measurand: dict
    k: float = K
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """The ``--json`` document of ``mtplan validate``."""
        return {"k": self.k, "comparisons": [c.row() for c in self.comparisons],
                "overall": self.overall.to_dict(),
                "by_measurand": {k: v.to_dict() for k, v in self.by_measurand.items()},
                "notes": list(self.notes)}

    def frame(self):
        """DataFrame of the comparisons (one row each, E_n included)."""
        import pandas as pd

        return pd.DataFrame([c.row() for c in self.comparisons])


def _verdict(en: np.ndarray, k: float) -> Verdict:
    from scipy import stats

    n = int(en.size)
    nominal = float(2 * stats.norm.cdf(k) - 1)
    inside = int(np.sum(np.abs(en) <= 1))
    ci = stats.binomtest(inside, n).proportion_ci(_LEVEL, method="exact")
    disp = float(np.sum((k * en) ** 2))
    a = (1 - _LEVEL) / 2
    lo, hi = float(stats.chi2.ppf(a, n)), float(stats.chi2.ppf(1 - a, n))
    if nominal > ci.high or disp > hi:
        verdict = TOO_SMALL
    elif nominal < ci.low or disp < lo:
        verdict = TOO_LARGE
    else:
        verdict = CONSISTENT
    return Verdict(n, inside, inside / n, (float(ci.low), float(ci.high)), nominal, disp,
                   (lo, hi), verdict)


def validate(results, references, *, k: float = K) -> Validation:
    """E_n of every measured value that has a reference, and the verdict.

    Parameters
    ----------
    results : list of (str, dict)
        (name, ``mtplan estimate --json`` document) pairs (:func:`read_results`).
    references : list of dict
        Rows ``procedure``, ``measurand``, ``value``, ``U``, ``unit`` and optionally
        ``result`` (the name of the one result it belongs to; empty: every result of
        that procedure) (:func:`read_references`).
    k : float
        Coverage factor of the results' ``U = k u`` and of the references' ``U``.
    """
    comparisons, notes, used = [], [], set()
    for name, doc in results:
        proc = doc["procedure"]
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
            comparisons.append(Comparison(name, proc, m["name"], m["unit"], float(m["value"]),
                                          k * float(m["u"]), float(ref["value"]),
                                          float(ref["U"])))
    for i, r in enumerate(references):
        if i not in used:
            notes.append(f"reference {r['procedure']} {r['measurand']}"
                         + (f" ({r['result']})" if r.get("result") else "")
                         + " matches no result")
    if not comparisons:
        raise InvalidInput(["no result has a measurand with a reference (the references name "
                            "procedure and measurand as the results do)"])
    en = np.array([c.en for c in comparisons])
    groups = {}
    for c, e in zip(comparisons, en, strict=True):
        groups.setdefault(f"{c.procedure} {c.measurand}", []).append(e)
    by = {g: _verdict(np.array(v), k) for g, v in groups.items()}
    return Validation(comparisons, _verdict(en, k), by, k, notes)


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
    ax.set_xlabel("E_n = (y - y_ref) / sqrt(U^2 + U_ref^2)")
    o = v.overall
    ax.set_ylim(-0.6, len(groups) - 0.4)
    ax.set_title(f"{o.inside}/{o.n} with |E_n| <= 1 (nominal {100 * o.nominal:.1f} %, share's "
                 f"95 % interval [{100 * o.interval[0]:.0f}, {100 * o.interval[1]:.0f}] %)\n"
                 f"verdict: {o.verdict}", fontsize=8, loc="left")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=140)
    plt.close(fig)
    return buf.getvalue()
