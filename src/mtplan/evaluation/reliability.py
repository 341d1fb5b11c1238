"""What one bad reading can do unseen: the fit check's internal and external reliability.

Baarda's reliability of a test, from the same whitened design the fit check uses
(:mod:`mtplan.evaluation.fitcheck`):

- **internal**: the minimal detectable bias (MDB) of every reading, the error of that
  reading alone that the whole check (the chi-square OR any reading's w-test at its
  Bonferroni limit) flags with probability ``MDB_POWER`` (0.8) (:attr:`FitCheck.mdb`,
  :mod:`mtplan.evaluation.detectability`: the check's exact law given the error, its
  orthogonal part by a fixed-seed Monte Carlo), and of every error the procedure declares
  that moves several readings (a bad contact along its probing direction);
- **external**: the largest shift of each measurand that an error of that size can cause
  and still pass more often than not (one time in five): ``max_i |G_ki| mdb_i``, with ``G``
  the estimator's own first-order response to the readings, ``d estimate / d reading``
  (central differences, as the first-order service takes it,
  :func:`mtplan.fitting.effects.estimator_map`, or the procedure's derivative hook where
  it maps the estimator, :func:`_mapped_response`), not the least squares' map: the
  evaluation's estimator is what the bad reading moves.

Before the test (``mtplan linearize``, the plan) both are taken at the readings the
set-up gives with every error source at its mean (the design); after it (the report), at
the measured readings. A reading the fit reproduces exactly (no residual freedom, no
``w``) has no MDB: any error of it passes, and a measurand that responds to it can be
moved without limit (``shift`` infinite, ``unchecked`` names the reading).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan.evaluation.fitcheck import (
    FIT_ALPHA,
    MDB_POWER,
    FitCheck,
    fit_check,
    reading_vector,
)
from mtplan.fitting.effects import REL_STEP, estimator_map
from mtplan.models import get
from mtplan.models.protocol import UNITS, Readings, split_unit

__all__ = ["Reliability", "reliability", "design_readings", "RESPONSE_TOL"]

#: a measurand whose response to an unchecked reading is below this share of its largest
#: response to any reading is not moved by it (round-off of the differences)
RESPONSE_TOL = 1e-6

#: shifts within this share of the largest are ties, won by the first error (one reading's
#: before a declared one): round-off must not choose among them
TIE_TOL = 1e-9

#: display unit of a reading in an internal unit
_SHOWN = {"mm": "um", "rad": "urad"}


def design_readings(proc, setup, truth) -> dict:
    """The readings the set-up gives at `truth` with every active error source at its mean
    (the first-order service's point): a batch of one."""
    base = proc.zero_errors(setup, 1)
    for name, src in proc.active_sources(setup).items():
        mean = np.asarray(src.distribution.mean, dtype=float)
        base[name] = np.broadcast_to(mean, base[name].shape).copy()
    with one_blas_thread():
        return proc.forward(setup, truth, base)


def _unit_of(key: str) -> tuple[str, float]:
    """(display unit, factor from the internal one) of a reading array."""
    unit = split_unit(key)[1]
    shown = _SHOWN.get(unit, unit)
    return shown, (UNITS[shown] / UNITS[unit]) if unit in UNITS and shown in UNITS else 1.0


def _where(label: tuple) -> str:
    return FitCheck._where({"row": label[0], "column": label[1], "reading": label[2]})


@dataclass
class Reliability:
    """The fit check's reliability for one set of readings (module notes).

    Attributes
    ----------
    alpha, power : float
        The check's significance level and the power the MDB is stated at.
    w_critical : float or None
        The w-test's limit (None: no test possible, :attr:`reason`).
    n_readings, n_tested : int
        Readings used; readings with a w (the Bonferroni count).
    mdb : list of dict
        Per reading array: ``readings`` (the array), ``unit`` (um or urad), ``largest``
        (the worst reading's MDB), ``at`` (that reading: row and column as the fit check
        names it), ``smallest``, ``median``.
    unchecked : list of str
        Readings without a w (any error of them passes).
    measurands : dict
        Per measurand: ``shift`` (the largest shift an MDB-sized error of one reading
        causes [its display unit]; inf where an unchecked reading moves it), ``unit``,
        ``u`` (its standard uncertainty, when given), ``in_u`` (shift / u), ``at`` (the
        reading), ``mdb`` (that reading's MDB) and ``mdb_unit``.
    reason : str or None
        Why there is no figure (the fit check could not be made).
    """

    alpha: float
    power: float = MDB_POWER
    w_critical: float | None = None
    n_readings: int = 0
    n_tested: int = 0
    mdb: list = field(default_factory=list)
    unchecked: list = field(default_factory=list)
    measurands: dict = field(default_factory=dict)
    reason: str | None = None
    mdb_values: np.ndarray | None = field(default=None, repr=False)
    response: np.ndarray | None = field(default=None, repr=False)
    directions: np.ndarray | None = field(default=None, repr=False)
    sizes: np.ndarray | None = field(default=None, repr=False)

    def effect(self, j: int) -> np.ndarray:
        """The readings' change per unit of gross error `j` (used readings): error `j`
        of :attr:`sizes`, a reading alone for the first ``n_readings``, then the
        procedure's declared errors (:attr:`directions`)."""
        n = self.response.shape[1]
        if j < n:
            out = np.zeros(n)
            out[j] = 1.0
            return out
        return self.directions[:, j - n]

    def moved(self) -> np.ndarray:
        """(measurands, errors): each measurand's shift per unit of each gross error, in
        the order of :attr:`sizes`."""
        return np.hstack([self.response, self.response @ self.directions])

    def with_u(self, u: dict) -> Reliability:
        """A copy whose ``u`` and ``in_u`` are against `u` (measurand -> standard
        uncertainty [display unit]): the Monte Carlo's, say, rather than the GUM's."""
        rows = {}
        for name, row in self.measurands.items():
            uk = u.get(name)
            uk = None if uk is None else float(uk)
            rows[name] = {**row, "u": uk,
                          "in_u": row["shift"] / uk if uk and uk > 0 else None}
        return dataclasses.replace(self, measurands=rows)

    def shift(self, name: str) -> float:
        """The largest undetected shift of measurand `name` [display unit] (NaN: none)."""
        m = self.measurands.get(name)
        return float("nan") if m is None else float(m["shift"])

    def to_dict(self) -> dict:
        """The ``reliability`` object of ``mtplan linearize --json`` (inf, an error the
        check cannot see, as null)."""
        def num(x):
            return None if x is None or not np.isfinite(x) else float(x)

        return {"alpha": float(self.alpha), "power": float(self.power),
                "test": "the whole fit check: the chi-square or any reading's w-test (at its "
                        "Bonferroni limit)",
                "w_critical": num(self.w_critical), "n_readings": int(self.n_readings),
                "n_tested": int(self.n_tested),
                "mdb": [{k: num(v) if k in ("largest", "smallest", "median") else v
                         for k, v in m.items()} for m in self.mdb],
                "unchecked": list(self.unchecked),
                "measurands": {k: {**v, "shift": num(v["shift"]), "in_u": num(v["in_u"]),
                                   "u": num(v["u"]), "mdb": num(v["mdb"])}
                               for k, v in self.measurands.items()},
                "reason": self.reason}

    def lines(self, top: int = 3) -> list[str]:
        """The figures in a few lines of text: the MDB per reading array, then the
        measurands an undetected error moves most, in units of their u."""
        if self.reason:
            return [f"one bad reading: no figure ({self.reason})"]
        out = [f"one bad reading: the fit check (alpha {self.alpha:g}) detects with "
               f"{100 * self.power:.0f} % power an error of "
               + "; ".join(f"{m['readings']} {_range(m)} {m['unit']} (worst {m['at']})"
                           for m in self.mdb)]
        rank = sorted(self.measurands.items(),
                      key=lambda kv: -(kv[1]["in_u"] if kv[1]["in_u"] is not None
                                       else kv[1]["shift"]))
        parts = [f"{k} {_shift_text(v)}" for k, v in rank[:top]]
        if parts:
            out.append("  an undetected one moves " + ", ".join(parts)
                       + (f" (and {len(rank) - top} more)" if len(rank) > top else ""))
        if self.unchecked:
            out.append(f"  {len(self.unchecked)} readings have no test (the fit reproduces "
                       f"them): {', '.join(self.unchecked[:3])}")
        return out


def _range(m: dict) -> str:
    low, high = f"{m['smallest']:.3g}", f"{m['largest']:.3g}"
    return high if low == high else f"{low}-{high}"


def _shift_text(v: dict) -> str:
    if not np.isfinite(v["shift"]):
        return f"without limit ({v['at']} has no test)"
    if v["shift"] == 0:  # no first-order response to any one reading
        return ("not at first order (its estimator does not respond to one reading: "
                "quantised or blind; a gross error may still move it by a whole step)")
    ratio = f" = {v['in_u']:.2g} u" if v["in_u"] is not None and np.isfinite(v["in_u"]) else ""
    return f"by up to {v['shift']:.3g} {v['unit']}{ratio} ({v['at']})"


def reliability(procedure, setup, truth=None, *, estimator: str | None = None,
                alpha: float = FIT_ALPHA, readings=None, check: FitCheck | None = None,
                u=None) -> Reliability:
    """The MDB of every reading and the largest undetected shift of every measurand.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
    truth : the procedure's Truth, optional (its defaults)
    estimator : str, optional
        The estimator whose response is taken (the procedure's default).
    alpha : float
        The fit check's significance level.
    readings : dict, optional
        A batch of one; default :func:`design_readings` (before the test).
    check : FitCheck, optional
        The fit check of `readings` where already made (not made again).
    u : dict, optional
        Standard uncertainty per measurand [display unit], for ``in_u``.
    """
    proc = get(procedure)
    truth = proc.Truth() if truth is None else truth
    est_name, _ = proc.estimator(estimator)
    if readings is None:
        readings = design_readings(proc, setup, truth)
    keys, full = reading_vector(readings)
    used = np.isfinite(full)
    declared = proc.capabilities.gross_errors(setup, readings)
    if check is None or (declared is not None and check.mdb_directions is None):
        check = fit_check(proc, setup, readings, alpha=check.alpha if check else alpha,
                          estimator=est_name,
                          directions=None if declared is None else declared[2])
    if check.mdb is None:
        return Reliability(alpha=check.alpha, reason=check.reason or "the fit check makes no "
                           "w-test", n_readings=check.n_readings)
    key_of = np.concatenate([np.full(np.asarray(readings[k])[0].size, k, dtype=object)
                             for k in keys])[used]
    measurands = tuple(proc.measurands(setup))
    G = _mapped_response(proc, setup, truth, est_name, measurands, used)
    if G is None:
        G = _response(proc, setup, readings, keys, full, used, est_name, measurands,
                      check.scatter)
    mdb = np.asarray(check.mdb, dtype=float)
    # every gross error: each reading alone, then those the procedure declares (the
    # readings' own as the identity, never built: 15 600 readings would be 2 GB)
    directions = np.zeros((mdb.size, 0))
    sizes = np.where(np.isfinite(mdb), mdb, np.inf)
    labels = [_where(lab) for lab in check.labels]
    groups = list(key_of)
    unit_key = dict(zip(keys, keys))
    if declared is not None:
        kind, names, D = declared
        D = np.asarray(D, dtype=float)[used]
        directions = D
        sizes = np.concatenate([sizes, np.asarray(check.mdb_directions, dtype=float)])
        labels += list(names)
        groups += [kind] * D.shape[1]
        unit_key[kind] = key_of[int(np.argmax(np.abs(D).sum(axis=1)))]
    groups = np.array(groups, dtype=object)
    per_group = []
    for group in dict.fromkeys(groups):
        on = np.flatnonzero(groups == group)
        unit, scale = _unit_of(unit_key[group])
        j = on[np.argmax(sizes[on])]
        seen = on[np.isfinite(sizes[on])]
        per_group.append({"readings": group, "unit": unit,
                          "largest": float(sizes[j] * scale), "at": labels[j],
                          "smallest": float(np.min(sizes[seen]) * scale) if seen.size
                          else np.inf,
                          "median": float(np.median(sizes[seen]) * scale) if seen.size
                          else np.inf, "undetectable": int(on.size - seen.size)})
    response = np.hstack([G, G @ directions])  # (measurands, errors): per unit of each
    rows = {}
    for k, m in enumerate(measurands):
        if not response.shape[1]:
            continue
        moved = np.abs(response[k])
        blind = np.flatnonzero(~np.isfinite(sizes) & (moved > RESPONSE_TOL * np.max(
            np.abs(G[k]) if G.shape[1] else 0.0)))
        with np.errstate(invalid="ignore"):
            shifts = np.where(np.isfinite(sizes), moved * sizes, 0.0)
        # the first of the errors within round-off of the largest shift (a declared error
        # that moves one reading alone ties with that reading's own)
        i = int(blind[0]) if blind.size else int(np.argmax(
            shifts >= np.max(shifts) * (1.0 - TIE_TOL)))
        shift = np.inf if blind.size else float(shifts[i])
        uk = None if u is None or m.name not in u else float(u[m.name])
        unit, scale = _unit_of(unit_key[groups[i]])
        rows[m.name] = {"shift": shift, "unit": m.unit, "u": uk,
                        "in_u": shift / uk if uk and uk > 0 else None, "at": labels[i],
                        "mdb": float(sizes[i] * scale), "mdb_unit": unit}
    return Reliability(alpha=check.alpha, w_critical=check.w_critical,
                       n_readings=check.n_readings, n_tested=check.n_tested, mdb=per_group,
                       unchecked=[labels[i] for i in np.flatnonzero(~np.isfinite(sizes))],
                       measurands=rows, mdb_values=mdb, response=G,
                       directions=directions, sizes=sizes)


def _mapped_response(proc, setup, truth, est_name, measurands, used):
    """``G`` from the procedure's derivative hook, where it gives one: the measurands'
    sensitivity to the readings' own noise source (``ReadingsFormat.noise_source``, which
    adds itself to each reading, one element per reading in the order of
    :func:`~mtplan.evaluation.fitcheck.reading_vector`) is ``d estimate / d reading`` at
    the design (`truth`'s error-free readings). None where the procedure names no noise
    source, its hook does not map the estimator, or the noise's elements are not the
    readings one for one: then :func:`_response` differentiates the estimator itself.

    After the test the map is the design's, not the measured readings' own: Baarda's
    reliability is a first-order statement, and the two differ by the second order of the
    readings' departure from the design (line_laser: its estimators' maps at the truth,
    exact in closed form, instead of 31 200 runs of the estimator)."""
    name = proc.readings.noise_source
    if name is None or name not in proc.active_sources(setup):
        return None
    with one_blas_thread():
        jac = proc.capabilities.first_order_sensitivities(setup, truth, estimator=est_name,
                                                           sources=(name,))
    if jac is None:
        return None
    jac = np.asarray(jac, dtype=float)
    if jac.shape != (len(measurands), used.size) or not np.all(np.isfinite(jac)):
        return None
    return jac[:, used]


def _response(proc, setup, readings, keys, full, used, est_name, measurands, scatter):
    """``G = d estimate / d reading`` (measurands [display unit] per internal unit, used
    readings), central differences of 1e-3 of each reading's own scatter."""
    shapes = {k: np.asarray(readings[k]).shape[1:] for k in keys}
    y0 = full[used]

    def estimate(rows):
        m = rows.shape[0]
        vec = np.repeat(full[None, :], m, axis=0)
        vec[:, used] = rows
        batch, at = {}, 0
        for key, value in readings.items():
            if key in shapes:
                size = int(np.prod(shapes[key], dtype=np.int64))
                batch[key] = vec[:, at:at + size].reshape((m, *shapes[key]))
                at += size
            else:
                batch[key] = np.repeat(np.asarray(value), m, axis=0)
        est = proc.estimators[est_name](setup, Readings(batch))
        return np.column_stack([np.asarray(est[mm.name], dtype=float).reshape(-1) * mm.scale
                                for mm in measurands])

    sd = np.asarray(scatter, dtype=float) if scatter is not None else np.zeros(y0.size)
    steps = np.where(sd > 0, REL_STEP * sd,
                     np.cbrt(np.finfo(float).eps) * np.maximum(np.abs(y0), 1.0))
    with one_blas_thread():
        return estimator_map(estimate, y0, steps)
