"""Monte Carlo and GUM evaluation of a measurement procedure's set-up.

This joins a procedure's forward model and estimator: each trial draws the active
error sources, simulates the raw readings and estimates the measurands, in blocks
(block ``i`` from stream ``i`` of the seed), so results depend only on the seed.
Values are reported in each measurand's display unit (um, urad).
"""

from __future__ import annotations

import dataclasses
import os
import tracemalloc
from dataclasses import dataclass, field, fields
from typing import NamedTuple

import numpy as np

from mtplan._parallel import effective_jobs
from mtplan._validate import InvalidInput, Problems
from mtplan.evaluation.covariance import covariance_doc
from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.reliability import reliability as one_bad_reading
from mtplan.fitting.effects import element_moments
from mtplan.models import get
from mtplan.models.protocol import Procedure
from mtplan.uncertainty.coverage import (
    ASSUMED,
    MONTE_CARLO,
    RESOLUTION,
    K,
    controlled_fraction,
    coverage_se,
)
from mtplan.uncertainty.distributions import Normal
from mtplan.uncertainty.gum import GUMResult
from mtplan.uncertainty.montecarlo import MCResult, run_blocks
from mtplan.uncertainty.options import RunOptions
from mtplan.uncertainty.streams import (
    as_seed_sequence,
    block_sequence,
    named_generator,
    named_sequence,
)

__all__ = ["ProcedureResult", "LinearizedResult", "simulate_uncertainty", "linear_trials",
           "linear_reference", "reference_blocks",
           "linearize_procedure",
           "linearize_result", "source_budget", "check_memory", "MEASURAND_KEYS",
           "measurand_rows", "Reported", "undetermined_measurands", "ResultDocument",
           "simulate_readings"]


def _resolve(procedure, setup, truth):
    proc = get(procedure)
    setup = proc.Setup() if setup is None else setup
    proc.check_setup(setup)
    truth = proc.Truth() if truth is None else truth
    if not isinstance(truth, proc.Truth):
        Problems(proc.name).add("truth", type(truth).__name__, f"a {proc.name} Truth")
    return proc, setup, truth


def _measure(proc: Procedure, setup, readings, estimator) -> dict:
    est = proc.estimators[estimator](setup, readings)
    n = None
    out = {}
    for m in proc.measurands(setup):
        a = np.asarray(est[m.name], dtype=float) * m.scale
        n = a.shape[0] if n is None else n
        out[m.name] = a
    return out


def procedure_block(proc, setup, truth, estimator, only, root, index, size):
    seq = block_sequence(root, index)
    errors = proc.draw_errors(setup, size, seq, only)
    readings = proc.forward(setup, truth, errors)
    return _measure(proc, setup, readings, estimator)


def linear_trials(proc, setup, fo, *, sources=None, rng=None, trials: int,
                  block_size: int) -> np.ndarray:
    """The first-order model's output in each trial of a Monte Carlo (a control variate).

    Trial t of :func:`simulate_uncertainty` with the same `sources`, `rng` and
    `block_size` draws the error elements ``e_t``; its first-order output is
    ``J (e_t - E[e])`` with ``J`` the sensitivities of `fo`
    (:func:`~mtplan.evaluation.first_order.first_order`'s result, taken for the same
    sources). The
    draws are made again here, block by block from the same streams, so trial t here and
    there are one pair: the difference of the two outputs is the estimator's departure
    from first order in that trial, free of the draws' own scatter. No forward model and
    no estimator run: this costs the draws and one product.

    Returns
    -------
    array (trials, n_measurands) [display units]; its expectation is 0 and its covariance
    ``fo.cov``.
    """
    active = proc.active_sources(setup, sources)
    means = {name: element_moments(src)[0] for name, src in active.items()}
    root = as_seed_sequence(rng)
    out = []
    for i, start in enumerate(range(0, trials, block_size)):
        size = min(block_size, trials - start)
        errors = proc.draw_errors(setup, size, block_sequence(root, i), sources)
        dev = np.hstack([np.asarray(errors[k], dtype=float).reshape(size, -1) - m
                         for k, m in means.items()]) if means else np.zeros((size, 0))
        out.append(dev @ fo.sensitivity.T)
    return np.vstack(out) if out else np.zeros((0, len(fo.names)))


#: first-order outputs drawn apart for a coverage's control variate (their own count's
#: standard error at 95 %: 0.07 %)
REFERENCE_TRIALS = 100_000
#: values per block of them (rows times measurands, or times the elements drawn one by one)
_REFERENCE_CELLS = 2_000_000


def reference_blocks(proc, setup, fo, *, sources=None, rng=None,
                     trials: int = REFERENCE_TRIALS):
    """`trials` outputs of the first-order model ``J (e - E[e])`` drawn apart from any Monte
    Carlo of the seed `rng` (its own named stream), for :func:`~mtplan.uncertainty.
    coverage.controlled_fraction`, in blocks of rows (so that a result of hundreds of
    measurands never holds them all at once).

    Exact and cheap: the elements the Monte Carlo draws from a normal distribution, one by
    one, add up to a normal vector of covariance ``sum_e J_e J_eᵀ u_e²`` whatever their
    number, drawn as one; every other element is drawn from its own distribution
    (:meth:`~mtplan.models.protocol.Procedure.drawn_distributions`).

    Yields
    ------
    arrays (rows, n_measurands) [display units], `trials` rows in all
    """
    seq = named_sequence(as_seed_sequence(rng), "first-order reference")
    jac = np.asarray(fo.sensitivity, dtype=float)
    n = jac.shape[0]
    cov = np.zeros((n, n))
    drawn, pos = [], 0
    for name, (src, dist) in proc.drawn_distributions(setup, sources).items():
        mean, std, _ = element_moments(src)
        cols = jac[:, pos:pos + mean.size]
        pos += mean.size
        if type(dist) is Normal:
            cov += (cols * std**2) @ cols.T
        else:
            drawn.append((name, src, dist, mean, cols))
    w, v = np.linalg.eigh(cov)
    root = (v * np.sqrt(np.clip(w, 0.0, None))).T
    size = max(n, sum(d[3].size for d in drawn), 1)
    rows = max(1, _REFERENCE_CELLS // size)
    for i, start in enumerate(range(0, trials, rows)):
        k = min(rows, trials - start)
        block = block_sequence(seq, i)
        out = named_generator(block, "normal").standard_normal((k, n)) @ root
        for name, src, dist, mean, cols in drawn:
            e = np.asarray(dist.draw(named_generator(block, name), (k, *src.shape)),
                           dtype=float).reshape(k, -1)
            out += (e - mean) @ cols.T
        yield out


def linear_reference(proc, setup, fo, *, sources=None, rng=None,
                     trials: int = REFERENCE_TRIALS) -> np.ndarray:
    """:func:`reference_blocks` as one array (trials, n_measurands) [display units]."""
    return np.vstack(list(reference_blocks(proc, setup, fo, sources=sources, rng=rng,
                                           trials=trials)))


# --------------------------------------------------------------------------- one schema
#: The keys of one measurand in every result's JSON (and, with ``interval`` split into
#: ``low`` and ``high``, every result's CSV): what each command prints, whatever computed it.
#: ``U`` is the expanded uncertainty that decides (k u, k = 2,
#: :mod:`mtplan.uncertainty.coverage`), ``U_coverage`` the fraction of the distribution
#: within ``value ± U``, ``U_coverage_se`` the standard error to which that is counted
#: (null where it is assumed) and ``U_coverage_from`` where it comes from (the Monte Carlo,
#: or a normal distribution assumed by a first-order result).
MEASURAND_KEYS = ("name", "unit", "value", "u", "interval", "coverage", "U", "U_coverage",
                  "U_coverage_se", "U_coverage_from", "determinable", "reason")


def _num(x):
    """A float for JSON: None for NaN or infinity (JSON has neither)."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if np.isfinite(x) else None


class Reported(NamedTuple):
    """What a result reports of its measurands: arrays over them of the ``value``, ``u`` and
    the interval's ``low`` and ``high`` ends [display unit], the interval's ``coverage``
    probability, the coverage of ``value ± U`` (``U_coverage``, an array over the
    measurands), where that comes from (``U_from``: :data:`~mtplan.uncertainty.
    coverage.MONTE_CARLO` or :data:`~mtplan.uncertainty.coverage.ASSUMED`) and its standard
    error (``U_coverage_se``, an array; None where it is assumed)."""

    value: np.ndarray
    u: np.ndarray
    low: np.ndarray
    high: np.ndarray
    coverage: float
    U_coverage: np.ndarray
    U_from: str = MONTE_CARLO
    U_coverage_se: np.ndarray | None = None


def measurand_rows(measurands, reported: Reported, *, determinable=None, reasons=None,
                   undetermined=None, extra=None) -> list[dict]:
    """One dict per measurand in the common schema (:data:`MEASURAND_KEYS`), then ``extra``.

    ``extra`` maps a key to an array over the measurands (``true``, ``bias``,
    ``estimate``...). A measurand that is not determinable gets null value, u and interval
    and its reason; ``undetermined`` ({name: (unit, reason)}) lists the measurands the
    procedure can report that this set-up does not determine at all, after the others.
    """
    value, u, low, high, coverage, within, within_from, within_se = reported
    reasons = reasons or {}
    rows = []
    for i, m in enumerate(measurands):
        ok = True if determinable is None else bool(determinable[i])
        row = {"name": m.name, "unit": m.unit,
               "value": _num(value[i]) if ok else None, "u": _num(u[i]) if ok else None,
               "interval": [_num(low[i]), _num(high[i])] if ok else [None, None],
               "coverage": float(coverage), "U": _num(K * u[i]) if ok else None,
               "U_coverage": _num(within[i]) if ok else None,
               "U_coverage_se": _num(within_se[i]) if ok and within_se is not None else None,
               "U_coverage_from": within_from if ok else None, "determinable": ok,
               "reason": reasons.get(m.name)}
        row.update({k: _num(v[i]) for k, v in (extra or {}).items()})
        rows.append(row)
    for name, (unit, why) in (undetermined or {}).items():
        row = {"name": name, "unit": unit, "value": None, "u": None, "interval": [None, None],
               "coverage": float(coverage), "U": None, "U_coverage": None,
               "U_coverage_se": None, "U_coverage_from": None, "determinable": False,
               "reason": why}
        row.update({k: None for k in (extra or {})})
        rows.append(row)
    return rows


def rows_frame(rows):
    """The CSV of a result: :func:`measurand_rows` as a DataFrame indexed by measurand, the
    interval as ``low`` and ``high``."""
    import pandas as pd

    flat = []
    for r in rows:
        r = dict(r)
        r["low"], r["high"] = r.pop("interval")
        flat.append(r)
    df = pd.DataFrame(flat).set_index("name")
    df.index.name = "measurand"
    first = ["unit", "value", "u", "low", "high", "coverage", "U", "U_coverage",
             "U_coverage_se", "U_coverage_from", "determinable", "reason"]
    return df[first + [c for c in df.columns if c not in first]]


class ResultDocument:
    """What every result of :mod:`mtplan.evaluation` shares: its JSON and CSV.

    A subclass gives :meth:`_head` (the keys before the measurands) and :meth:`_rows`
    (:func:`measurand_rows`); ``notes`` and ``sections`` are dataclass fields. A further
    part of a result (a fit check, a covariance matrix) is added in ONE place for every
    command: put it in ``result.sections[key]`` in the function that computes the result;
    ``to_dict`` writes ``key: part.to_dict()`` (or the part itself when it has no
    ``to_dict``) after the measurands, and the CLI prints it with ``--json``.
    """

    def _head(self) -> dict:  # pragma: no cover - every subclass overrides it
        raise NotImplementedError

    def _rows(self) -> list[dict]:  # pragma: no cover
        raise NotImplementedError

    def to_dict(self) -> dict:
        """The ``--json`` document: the head, ``measurands`` (common schema), ``notes`` and
        the result's sections."""
        doc = self._head()
        doc["measurands"] = self._rows()
        doc["notes"] = list(self.notes)
        for key, part in self.sections.items():
            doc[key] = part.to_dict() if hasattr(part, "to_dict") else part
        return doc

    def summary(self):
        """DataFrame indexed by measurand in the common schema (the ``--out`` CSV)."""
        return rows_frame(self._rows())


def undetermined_measurands(proc, setup) -> dict:
    """{name: (unit, reason)}: the measurands `proc` can report that `setup` does not
    determine at all, from the procedure's ``identifiability`` table ({} from the generic
    default's empty table).

    What the readings determine does not depend on the estimator, so the hook is asked
    for its first exact estimator's table (the cheapest: the data's own view). The unit
    is the suffix of the measurand's Truth field (``EAX_urad``)."""
    estimator = proc.exact_names[0] if proc.exact_names else proc.default_estimator
    table = proc.capabilities.identifiability(setup, estimator)
    listed = {m.name for m in proc.measurands(setup)}
    units = dict(f.name.rsplit("_", 1) for f in fields(proc.Truth) if "_" in f.name)
    out = {}
    for name, row in table.iterrows():
        if name in listed or bool(row.get("listed", False)):
            continue
        partners = [p.strip() for p in str(row.get("confounded_with", "") or "").split(",")
                    if p.strip()]
        if str(row.get("status", "")) == "no effect":
            why = "it has no effect on the readings"
        else:
            shown = ", ".join("the mounting" if p == "mounting" else p for p in partners)
            why = "the readings do not separate it" + (f" from {shown}" if shown else "")
        out[name] = (units.get(name, ""), f"not determinable at this set-up ({why}); 'mtplan "
                     f"plan {proc.name} --determine all' finds a set-up that determines it")
    return out


@dataclass
class ProcedureResult(ResultDocument):
    """Monte Carlo uncertainty of one set-up of one procedure (display units).

    Attributes
    ----------
    procedure, estimator : str
    setup, truth : the procedure's Setup and Truth
    sources : tuple of str
        The error sources that were drawn.
    measurands : tuple of Measurand
    true : array (n_measurands,)
        True values [display unit].
    mc : MCResult
        The Monte Carlo result (means, standard deviations, intervals, covariance).
    duration_s : float
        Machine time of the test [s].
    undetermined : dict of str to (unit, reason)
        The measurands the procedure can report that this set-up does not determine: in
        the JSON and CSV after the others, ``determinable`` false, with the reason.
    notes : list of str
        What a reader must not miss (:meth:`findings`: an interval of zero width, a
        large bias).
    sections : dict
        Further parts of the result, written by :meth:`to_dict` (see
        :class:`ResultDocument`).

    The JSON and CSV give per measurand ``value`` (the mean of the Monte Carlo
    estimates), ``u`` (their standard deviation), ``interval``, ``coverage``, ``U`` with
    ``U_coverage`` (the fraction of the estimates within ``value ± U``),
    ``determinable``, ``reason``, ``true`` and ``bias``.
    """

    #: the procedure itself (its ``name`` is what the JSON and the documents print)
    procedure: Procedure
    estimator: str
    setup: object
    truth: object
    sources: tuple
    measurands: tuple
    true: np.ndarray
    mc: MCResult
    duration_s: float
    #: the measurands of a quantised estimator that never left their step, with the step
    #: [display unit]: their u is the rounding's, step / sqrt(12)
    quantised: dict = field(default_factory=dict)
    undetermined: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    sections: dict = field(default_factory=dict)
    #: the root SeedSequence the Monte Carlo drew from, as (entropy, spawn key, pool size)
    #: (:attr:`root`: its trials' draws again, paired)
    stream: tuple | None = None
    #: (p, se) of U's coverage once counted (:meth:`coverage_of_U`)
    _covered: tuple | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        if not self.notes:
            self.notes = self.findings()

    @property
    def root(self) -> np.random.SeedSequence | None:
        """The root SeedSequence the Monte Carlo drew from (None where not known)."""
        if self.stream is None:
            return None
        entropy, key, pool = self.stream
        return np.random.SeedSequence(entropy, spawn_key=key, pool_size=pool)

    @property
    def bias(self) -> np.ndarray:
        return self.mc.mean - self.true

    @property
    def u(self) -> np.ndarray:
        """Standard uncertainty of each measurand (the Monte Carlo standard deviation)."""
        return self.mc.std

    @property
    def U_coverage(self) -> np.ndarray:  # noqa: N802 - U of the GUM
        """The fraction of each measurand's Monte Carlo values within ``value ± U``, U = k u
        (:mod:`mtplan.uncertainty.coverage`): the coverage U really has; 1 for a quantised
        estimator whose values never left their step (:meth:`coverage_of_U`)."""
        return self.coverage_of_U()[0]

    @property
    def U_coverage_se(self) -> np.ndarray:  # noqa: N802
        """The standard error of :attr:`U_coverage` (:meth:`coverage_of_U`)."""
        return self.coverage_of_U()[1]

    def coverage_of_U(self) -> tuple:  # noqa: N802
        """(p, se): :meth:`coverage_within` of ``value ± U``, counted once."""
        if self._covered is None:
            self._covered = self.coverage_within(self.mc.mean, K * self.mc.std)
        return self._covered

    def coverage_within(self, centre, half_width) -> tuple:
        """(p, se), arrays over the measurands: the fraction of the Monte Carlo's values
        within ``centre ± half_width``, and its standard error.

        A plain count of M values resolves a coverage near 95 % to sqrt(0.05 0.95 / M):
        1.1 % at 400 trials. Where that is coarser than
        :data:`~mtplan.uncertainty.coverage.RESOLUTION`, the first-order model of the same
        set-up, truth, estimator and sources is the count's control variate
        (:func:`~mtplan.uncertainty.coverage.controlled_fraction`: the Monte Carlo's own
        draws through it, paired trial by trial, and :data:`REFERENCE_TRIALS` drawn apart,
        :func:`reference_blocks`), where its sensitivities come in closed form or cost no
        more estimator runs than the Monte Carlo made; per measurand, whichever of the two
        counts has the smaller standard error. Values kept only as a histogram (beyond
        the Monte Carlo's ``keep``) are counted plainly.
        """
        centre = np.broadcast_to(np.asarray(centre, dtype=float), self.mc.mean.shape)
        half = np.broadcast_to(np.asarray(half_width, dtype=float), self.mc.mean.shape)
        m = int(self.mc.trials)
        p = np.array([float(self.mc.fraction_within(n, c - h, c + h))
                      for n, c, h in zip(self.mc.names, centre, half, strict=True)])
        se = np.where(np.isfinite(p), coverage_se(p, m), np.nan)
        values = [self.mc.samples(n) for n in self.mc.names]
        if not np.any(se > RESOLUTION) or any(v is None for v in values) or self.root is None:
            return p, se
        fo = first_order(self.procedure, self.setup, self.truth, estimator=self.estimator,
                         sources=list(self.sources), max_runs=m)
        if fo is None:
            return p, se
        linear = linear_trials(self.procedure, self.setup, fo, sources=list(self.sources),
                               rng=self.root, trials=m, block_size=self.mc.block_size)
        reference = reference_blocks(self.procedure, self.setup, fo,
                                     sources=list(self.sources), rng=self.root)
        p_cv, se_cv = controlled_fraction(np.column_stack(values), linear, reference, centre,
                                          half)
        better = np.isfinite(se_cv) & (se_cv < se)
        return np.where(better, p_cv, p), np.where(better, se_cv, se)

    def findings(self) -> list[str]:
        """What a reader of the table must not miss: an interval of zero width (the estimator
        is quantised or blind to the measurand, or no simulated source moves it: its
        uncertainty is then its resolution, which the Monte Carlo cannot give) and a bias
        larger than twice the uncertainty. The set-up's own notes come first
        (:meth:`mtplan.models.protocol.SetupBase.notes`: a temperature assumed, not
        measured)."""
        out = list(self.setup.notes()) if hasattr(self.setup, "notes") else []
        for i, m in enumerate(self.measurands):
            u, bias = float(self.mc.std[i]), float(self.bias[i])
            if m.name in self.quantised:
                q = self.quantised[m.name]
                out.append(f"{m.name}: the {self.estimator} estimator's values come in steps of "
                           f"{q:.4g} {m.unit} and every trial gave the same one (an interval of "
                           f"zero width): its u is the rounding's, step / sqrt(12) = {u:.4g} "
                           f"{m.unit}, where the truth lies within the step not being known")
            elif not self.mc.high[i] > self.mc.low[i]:
                out.append(f"{m.name}: the {self.estimator} estimator gives the same value in "
                           f"(almost) every trial, an interval of zero width: it is quantised "
                           f"or blind to {m.name} here, or no simulated source moves it, so "
                           "this u is not its uncertainty")
            elif u > 0 and abs(bias) > 2 * u:
                out.append(f"{m.name}: the {self.estimator} estimator's bias ({bias:.3g} "
                           f"{m.unit}) is {abs(bias) / u:.1f} times its u: the estimate is off, "
                           "not merely uncertain")
        return out

    def _head(self) -> dict:
        seed = self.mc.seed
        return {"procedure": self.procedure.name, "estimator": self.estimator,
                "setup": self.setup.as_dict(),
                "seed": int(seed) if isinstance(seed, int | np.integer) else list(seed),
                "trials": int(self.mc.trials), "sources": list(self.sources),
                "interval_kind": self.mc.interval, "duration_s": float(self.duration_s)}

    def _rows(self) -> list[dict]:
        mc = self.mc
        return measurand_rows(self.measurands,
                              Reported(mc.mean, mc.std, mc.low, mc.high, mc.coverage,
                                       self.U_coverage, U_coverage_se=self.U_coverage_se),
                              undetermined=self.undetermined,
                              extra={"true": self.true, "bias": self.bias})

    def to_dict(self) -> dict:
        """The ``--json`` document of ``mtplan simulate``: the common schema, then the
        ``covariance`` of the Monte Carlo estimates
        (:func:`mtplan.evaluation.covariance.covariance_doc`)."""
        doc = super().to_dict()
        doc["covariance"] = covariance_doc(self.measurands, self.mc.cov)
        return doc


def _available_memory() -> int | None:
    """Memory the system can give this process now [bytes], None where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _peak_per_trial(proc, setup, truth, estimator, active) -> float:
    """Measured memory of one more trial in a block [bytes] (tracemalloc over 1 and 3)."""
    root = as_seed_sequence(0)
    procedure_block(proc, setup, truth, estimator, active, root, 0, 1)  # warm the caches
    peaks = []
    for size in (1, 3):
        tracemalloc.start()
        try:
            procedure_block(proc, setup, truth, estimator, active, root, 0, size)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    return max((peaks[1] - peaks[0]) / 2, peaks[0] / 3, 1.0)


def check_memory(proc, setup, truth, estimator, active, *, block_size: int, n_jobs: int = 1,
                 trials: int | None = None) -> None:
    """Refuse a Monte Carlo run predicted to need more memory than the system has.

    The need is the blocks in flight (``block_size`` trials per worker) plus the kept
    values of the outputs (at most 2 x 10**6 per measurand). A set-up whose error arrays
    alone exceed the memory is refused from their size; one within a tenth of it by a
    generous bound passes; in between, one small block is measured (tracemalloc).

    Raises
    ------
    InvalidInput
        With the estimate, the memory available and what to change.
    """
    available = _available_memory()
    if not available:
        return
    jobs = max(effective_jobs(n_jobs), 1)
    n_out = len(proc.measurands(setup))
    kept = 16.0 * n_out * min(trials or 2 * 10**6, 2 * 10**6)
    floats = sum(src.size for src in proc.sources(setup).values())
    floor = 8.0 * floats  # the error arrays of one trial, at the least
    per_trial = None
    if (floor * block_size * jobs + kept) <= available and \
            (24 * floor * block_size * jobs + kept) > 0.1 * available:
        per_trial = _peak_per_trial(proc, setup, truth, estimator, active)
    need = (per_trial or floor) * block_size * jobs + kept
    if need > 0.8 * available:
        measured = "measured" if per_trial else "at least, from the size of its error arrays"
        raise InvalidInput([
            f"This {proc.name} Monte Carlo run would need about {need / 1e9:.3g} GB of memory "
            f"({(per_trial or floor) / 1e6:.3g} MB per trial, {measured}, x {block_size} trials "
            f"per block x {jobs} worker(s), plus {kept / 1e9:.2g} GB of kept values); "
            f"{available / 1e9:.3g} GB are available. Make the set-up smaller (fewer points, "
            "lines or positions) or use fewer jobs."])


def _quantised(proc, setup, estimator, measurands, mc) -> dict:
    """A measurand of a quantised estimator whose Monte Carlo interval has zero width (it
    never left its step): where the procedure states the step q, u = q / sqrt(12) (the
    rounding error, uniform over a step, as where the truth lies is not known) and the
    interval is the mean +- coverage * q / 2, never u = 0 (`mc` is changed in place). A
    zero width without a stated step (a source that does not act, with --sources) stays,
    and :meth:`ProcedureResult.findings` names it."""
    steps = proc.estimators[estimator].steps(setup)
    out = {}
    for i, m in enumerate(measurands):
        q = steps.get(m.name)
        if q and not mc.high[i] > mc.low[i]:
            q = q * m.scale
            mc.std[i] = q / np.sqrt(12.0)
            mc.low[i], mc.high[i] = mc.mean[i] - mc.coverage * q / 2, mc.mean[i] + mc.coverage * q / 2
            out[m.name] = q
    return out


def simulate_uncertainty(
    procedure,
    setup=None,
    truth=None,
    *,
    estimator: str | None = None,
    sources=None,
    options: RunOptions | None = None,
    cache: dict | None = None,
    **option_overrides,
) -> ProcedureResult:
    """Monte Carlo uncertainty of a procedure's set-up.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup, optional (the procedure's defaults)
    truth : Truth, optional (the procedure's defaults)
    estimator : str, optional (the procedure's default estimator)
    sources : iterable of str, optional
        Simulate with only these error sources.
    options : RunOptions, optional
        How the run is made, as for :func:`mtplan.uncertainty.propagate`
        (:class:`~mtplan.uncertainty.options.RunOptions`; default 10**4 trials, at most
        10**7 for the adaptive procedure, blocks of the procedure's ``block_size``). Any
        of its fields may be given as a keyword instead (``trials=1500, rng=4``).
    cache : dict, optional
        Blocks kept between runs at the same set-up, truth, estimator, sources and seed
        (:func:`mtplan.uncertainty.montecarlo.run_blocks`): a longer run in blocks of the
        same `block_size` runs only the blocks a shorter one did not, with the same result
        as without the cache. A dict of one such run's; a fixed trial count only.

    Returns
    -------
    ProcedureResult
    """
    options = RunOptions.of(options, **option_overrides)
    proc, setup, truth = _resolve(procedure, setup, truth)
    p = Problems(f"simulate {proc.name}")
    options.check(p)
    p.raise_if_any()
    est_name, _ = proc.estimator(estimator)
    active = proc.active_sources(setup, sources)
    options = options.fixed(10**4).replace(rng=as_seed_sequence(options.rng))
    trials, digits, block_size = options.trials, options.digits, options.block_size
    max_trials = 10**7 if options.max_trials is None else options.max_trials
    measurands = tuple(proc.measurands(setup))
    if digits is not None and block_size is None:
        block_size = proc.capabilities.block_size
    block_size = block_size or min(proc.capabilities.block_size, max(trials or 0, 2))
    check_memory(proc, setup, truth, est_name, tuple(active), block_size=block_size,
                 n_jobs=options.n_jobs, trials=trials if digits is None else max_trials)
    mc = run_blocks(procedure_block, (proc, setup, truth, est_name, tuple(active)),
                    options.replace(block_size=block_size, max_trials=max_trials),
                    label=proc.name, cache=cache)
    quantised = _quantised(proc, setup, est_name, measurands, mc)
    tv = proc.display_truth(setup, truth)
    return ProcedureResult(
        procedure=proc,
        estimator=est_name,
        setup=setup,
        truth=truth,
        sources=tuple(active),
        measurands=measurands,
        true=np.array([tv[m.name] for m in measurands]),
        mc=mc,
        duration_s=float(proc.duration(setup)),
        undetermined=undetermined_measurands(proc, setup),
        quantised=quantised,
        stream=(options.rng.entropy, tuple(options.rng.spawn_key), options.rng.pool_size),
    )


def simulate_readings(procedure, setup=None, truth=None, *, rng=None, sources=None):
    """One simulated measurement as the readings table a measured file holds.

    Parameters
    ----------
    procedure : str or Procedure
    setup, truth : optional (the procedure's defaults)
    rng : None, int, SeedSequence or Generator
    sources : iterable of str, optional
        Simulate with only these error sources.

    Returns
    -------
    DataFrame in the procedure's readings format (``procedure.readings.frame``), which
    ``mtplan estimate`` reads back.
    """
    proc, setup, truth = _resolve(procedure, setup, truth)
    readings = proc.simulate(setup, truth, 1, rng=rng, sources=sources)
    return proc.readings.frame(setup, readings)


def linearize_procedure(
    procedure,
    setup=None,
    truth=None,
    *,
    estimator: str | None = None,
    sources=None,
    coverage: float = 0.95,
) -> GUMResult:
    """GUM law of propagation for a procedure's set-up (display units).

    The inputs are every element of every active error source (grouped by source
    in the budget); the model is forward model + estimator, linearised at the
    sources' means (zero error), by the first-order service
    (:func:`mtplan.evaluation.first_order.first_order`, which the planner and the
    designer call too): its result as it is, the procedure named or given. With an
    efficient estimator and Gaussian sources this is also the Cramer-Rao (Fisher)
    prediction of the set-up.
    """
    proc, setup, truth = _resolve(procedure, setup, truth)
    return first_order(proc, setup, truth, estimator=estimator, sources=sources,
                       coverage=coverage)


@dataclass
class LinearizedResult(ResultDocument):
    """The GUM law of propagation for one set-up (:func:`linearize_result`), with its budget.

    Attributes
    ----------
    procedure, estimator : str
    setup : the procedure's Setup
    measurands : tuple of Measurand
    gum : GUMResult
        Values, sensitivities, covariance (:func:`linearize_procedure`).
    undetermined, sections
        As for :class:`ProcedureResult`.
    notes : list of str
        Measurands whose u is 0 (no source moves the estimate at first order).

    The JSON gives per measurand ``value``, ``u``, ``interval``, ``coverage``, ``U`` with
    ``U_coverage`` (a normal distribution's, assumed: there is no Monte Carlo),
    ``determinable``, ``reason`` and ``budget`` ({source: {"u", "share"}}); the CSV is the
    budget (:meth:`GUMResult.budget`).
    """

    #: the procedure itself (its ``name`` is what the JSON and the documents print)
    procedure: Procedure
    estimator: str
    setup: object
    measurands: tuple
    gum: GUMResult
    undetermined: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    sections: dict = field(default_factory=dict)

    @property
    def u(self) -> np.ndarray:
        return self.gum.std

    def _head(self) -> dict:
        return {"procedure": self.procedure.name, "estimator": self.estimator,
                "setup": self.setup.as_dict(), "k": float(self.gum.k[0])
                if len(self.gum.k) else None}

    def _rows(self) -> list[dict]:
        g = self.gum
        rows = measurand_rows(self.measurands, Reported(g.value, g.std, g.low, g.high,
                                                        g.coverage, g.U_coverage, ASSUMED),
                              undetermined=self.undetermined)
        by_source = g.by_source()
        for row in rows:
            row["budget"] = by_source.get(row["name"], {})
        return rows


def linearize_result(procedure, setup=None, truth=None, *, estimator: str | None = None,
                     sources=None, coverage: float = 0.95,
                     reliability: bool = True) -> LinearizedResult:
    """:func:`linearize_procedure` as a complete result: the ``mtplan linearize`` document.

    With `reliability` (default), its ``reliability`` section: what one bad reading can do
    unseen by the fit check, the minimal detectable bias of the readings and the largest
    shift of each measurand it causes (:func:`mtplan.evaluation.reliability.reliability`,
    at the design readings; the ratio to u against the u of this result)."""
    proc, setup, truth = _resolve(procedure, setup, truth)
    g = linearize_procedure(proc, setup, truth, estimator=estimator, sources=sources,
                            coverage=coverage)
    est_name, _ = proc.estimator(estimator)
    measurands = tuple(proc.measurands(setup))
    notes = list(setup.notes()) if hasattr(setup, "notes") else []  # the set-up's own first
    notes += [f"{m.name}: u = 0: the {est_name} estimator does not move with any error source "
              f"at first order (it is quantised or blind to {m.name}, or no source moves it), "
              "so the law of propagation cannot give its uncertainty"
              for m, u in zip(measurands, g.std, strict=True) if not u > 0]
    result = LinearizedResult(procedure=proc, estimator=est_name, setup=setup,
                              measurands=measurands, gum=g, notes=notes,
                              undetermined=undetermined_measurands(proc, setup))
    if reliability:
        result.sections["reliability"] = one_bad_reading(
            proc, setup, truth, estimator=est_name,
            u={m.name: float(u) for m, u in zip(measurands, g.std, strict=True)})
    return result


def source_budget(procedure, setup=None, truth=None, *, estimator=None, options=None,
                  **option_overrides):
    """The budget by Monte Carlo: the standard uncertainty due to each error source alone.

    Returns the budget table (as :meth:`~mtplan.uncertainty.gum.GUMResult.budget`): one row
    per measurand (``output``) and source (``input``), its ``contribution`` (the measurand's
    standard deviation with that source alone) and ``share`` (its variance over the sum of
    the single-source variances); ``u_input`` and ``sensitivity`` are NaN (a Monte Carlo has
    neither). Sources draw from their own streams, so the runs share random numbers.
    `options` as for :func:`simulate_uncertainty` (default 10**4 trials, no progress bar).
    """
    import pandas as pd

    options = RunOptions.of(RunOptions(progress=False) if options is None else options,
                            **option_overrides)
    proc, setup, truth = _resolve(procedure, setup, truth)
    rows = []
    for name in proc.active_sources(setup):
        r = simulate_uncertainty(proc, setup, truth, estimator=estimator, sources=[name],
                                 options=options)
        for i, m in enumerate(r.measurands):
            rows.append((m.name, name, float(r.mc.std[i])))
    df = pd.DataFrame(rows, columns=["output", "input", "contribution"])
    var = df["contribution"] ** 2
    share = var / var.groupby(df["output"]).transform("sum").where(lambda s: s > 0, 1.0)
    return pd.DataFrame({"output": df["output"], "input": df["input"], "u_input": np.nan,
                         "sensitivity": np.nan, "contribution": df["contribution"],
                         "share": share})
