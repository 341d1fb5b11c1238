"""GUM law of propagation of a procedure by the chain rule: estimator map x reading effects.

``mtplan linearize`` (:func:`mtplan.evaluation.simulation.linearize_procedure`)
differentiates the whole chain, forward model then estimator, with respect to every
element of every error source: ``4 E + 1`` runs of both for E elements (Richardson
central differences, steps of 1e-3 standard deviation). This module gives the same
first-order propagation in two smaller parts:

- the **reading effects**: the derivative of the readings with respect to each element,
  times its standard deviation, by the same Richardson differences with the same steps.
  The elements of a source are moved together in groups in which every reading depends
  on one element at most (found by NaN probes, and checked with the elements moved by
  random signs), so that a source of reading noise costs 5 forward runs, not ``4 E``;
- the **estimator map** ``G = d estimate / d readings`` at the error-free readings (the
  readings at the sources' means), central differences over each reading with a step of
  1e-3 of its standard deviation under the budget.

Per measurand i and source s the variance is ``sum_j (G E_s)_ij^2``, as
``GUMResult.group_variance`` sums it. Both ways are finite differences of one
first-order propagation: u agrees to about 1e-7, each source's variance to about 1e-7 of
the product of its effects and the map (which can exceed its own size for a source the
estimator cancels, as circle_centre's start scatter); the tests hold 1e-5 of u and of
u^2. With up to ``_WHOLE_MAX`` source elements the whole chain is differentiated as
``mtplan linearize`` does (the cheaper way there, and exact to it).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.uncertainty.gum import sensitivities

__all__ = ["reading_effects", "estimator_map", "chain_variances", "chain_budget", "chain_std",
           "with_chain_rule", "secant_effects", "element_moments",
           "one_blas_thread"]

#: step of the differences, in standard deviations (that of ``mtplan.uncertainty.gum``)
REL_STEP = 1e-3
_CHUNK_CELLS = 400_000  # about this many numbers per batch of rows (cache-sized arrays)
_SUPPORT = 1e-9  # (mtplan.fitting.budget's) relative size below which an effect is zero
_PROBE = 32  # (mtplan.fitting.budget's) elements from which a source is first NaN-probed
_WHOLE_MAX = 256  # source elements up to which the whole chain is differentiated at once


def element_moments(src) -> tuple[np.ndarray, np.ndarray, tuple]:
    """A source's (mean, std) per element, flat, and the elements' shape (the source's
    shape and its distribution's event shape): the inputs of a linearisation."""
    shape = (*src.shape, *src.distribution.event_shape)
    size = int(np.prod(shape, dtype=np.int64))
    mean = np.broadcast_to(np.asarray(src.distribution.mean, dtype=float),
                           shape if shape else ()).ravel()
    std = np.broadcast_to(np.asarray(src.distribution.std, dtype=float),
                          shape if shape else ()).ravel()
    if mean.size != size:
        mean, std = np.resize(mean, size), np.resize(std, size)
    return mean, std, shape


def _base_errors(proc, setup, active) -> tuple[dict, dict]:
    """Error rows of one trial at the sources' means, and each active source's (mean,
    std) per element, broadcast as the linearisation does."""
    base = proc.zero_errors(setup, 1)
    stats = {}
    for name, src in active.items():
        mean, std, shape = element_moments(src)
        base[name] = mean.reshape((1, *shape))
        stats[name] = (mean, std, shape)
    return base, stats


def _readings(proc, setup, truth, errors) -> np.ndarray:
    m = next(iter(errors.values())).shape[0] if errors else 1
    r = proc.forward(setup, truth, errors)
    return np.concatenate([np.asarray(v, dtype=float).reshape(m, -1) for v in r.values()],
                          axis=1)


class _Batch:
    """Rows of errors, each at the sources' means but for one source's values, run through
    the forward model in cache-sized batches of rows."""

    def __init__(self, readings, base: dict):
        self.readings, self.base = readings, base
        self.parts: list[tuple[str, np.ndarray]] = []
        self.rows = 0
        width = sum(int(np.prod(v.shape[1:], dtype=np.int64)) for v in base.values())
        self.chunk = max(8, _CHUNK_CELLS // max(width, 1))

    def add(self, name: str, values: np.ndarray) -> slice:
        """Queue rows with source `name` at `values` (m, E); their slice of the result."""
        self.parts.append((name, values))
        self.rows += values.shape[0]
        return slice(self.rows - values.shape[0], self.rows)

    def run(self) -> np.ndarray:
        starts = np.cumsum([0] + [v.shape[0] for _, v in self.parts])
        out = []
        for s in range(0, self.rows, self.chunk):
            e = min(self.rows, s + self.chunk)
            errors = {k: np.repeat(v, e - s, axis=0) for k, v in self.base.items()}
            for (name, values), a in zip(self.parts, starts[:-1], strict=True):
                lo, hi = max(s, a), min(e, a + values.shape[0])
                if lo < hi:
                    errors[name][lo - s:hi - s] = values[lo - a:hi - a].reshape(
                        (hi - lo, *errors[name].shape[1:]))
            with np.errstate(all="ignore"):
                out.append(self.readings(errors))
        self.parts, self.rows = [], 0
        return np.concatenate(out) if out else np.zeros((0, 0))


class _Grouping:
    """A partition of a source's E elements: element j in group ``label[j]`` (0..G-1) at
    position ``pos[j]``; ``table[g, k]`` is the element at position k of group g."""

    def __init__(self, label: np.ndarray):
        self.label = label
        self.count = int(label.max()) + 1 if label.size else 0
        order = np.argsort(label, kind="stable")
        sizes = np.bincount(label, minlength=self.count)
        first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self.pos = np.empty_like(label)
        self.pos[order] = np.arange(label.size) - first[label[order]]
        self.size = int(sizes.max()) if label.size else 0
        self.table = np.full((self.count, max(self.size, 1)), -1)
        self.table[label, self.pos] = np.arange(label.size)

    def members(self) -> np.ndarray:
        """(G, E) bool: element j in group g."""
        return self.label[None, :] == np.arange(self.count)[:, None]


def _groupings(shape: tuple) -> list[_Grouping]:
    """Candidate groupings of a source's elements, fewest groups first: all in one, then
    the elements sharing their last (or first) k indices, k = 1, 2, ... (a source
    (points, 3) whose three components move the same readings makes 3 groups, one
    (2, points) 2); the last one element per group."""
    n_el = int(np.prod(shape, dtype=np.int64))
    j = np.arange(n_el)
    labels = {} if n_el <= 2 else {1: j * 0}
    for k in range(1, len(shape)):
        last = int(np.prod(shape[len(shape) - k:], dtype=np.int64))
        rest = int(np.prod(shape[k:], dtype=np.int64))
        labels.setdefault(last, j % last)
        labels.setdefault(n_el // rest, j // rest)
    labels.pop(n_el, None)
    return [_Grouping(labels[g]) for g in sorted(labels)] + [_Grouping(j)]


def _probe_rows(mean: np.ndarray, grouping: _Grouping) -> tuple[int, np.ndarray]:
    """NaN probes of a grouping: bits, rows (G, bits, 2, E); row (g, b, 0) sets the
    elements of group g whose position has bit b set to NaN, row (g, b, 1) those with
    it clear."""
    bits = max(1, (grouping.size - 1).bit_length())
    bit = (grouping.pos[None, :] >> np.arange(bits)[:, None]) & 1  # (bits, E)
    mask = np.stack([bit == 1, bit == 0], axis=1)[None] & grouping.members()[:, None, None, :]
    return bits, np.where(mask, np.nan, mean)


def _element_of(pred: np.ndarray, count: int, bits: int, size: int):
    """Each group's element (position in the group) of every reading, -1 for none, from
    its NaN probes `pred` (G bits 2, n); None where a reading depends on two."""
    nan = np.isnan(pred.reshape(count, bits, 2, -1))
    on, off = nan[:, :, 0], nan[:, :, 1]
    if np.any(on & off):
        return None
    dep = on.any(axis=1) | off.any(axis=1)  # (G, n)
    if not np.all((on ^ off) | ~dep[:, None, :]):
        return None
    elem = (on.astype(np.int64) << np.arange(bits)[None, :, None]).sum(axis=1)
    if np.any(elem[dep] >= size):
        return None
    return np.where(dep, elem, -1)


def _groups(batch: _Batch, stats: dict) -> dict:
    """Per source, a grouping of its elements in which every reading depends
    on one element at most, and each group's element of every reading (None: one
    element per group).

    Tried from the whole source down (a source (points, 3) whose three components move
    the same readings splits into 3 groups); NaN probes spell out each reading's element
    bit by bit, every source and grouping in one batch.
    """
    out = {name: (_groupings(shape)[-1], None) for name, (_m, _s, shape) in stats.items()}
    todo = {name: _groupings(shape)[:-1] for name, (_m, _s, shape) in stats.items()}
    while any(todo.values()):  # a round: the next candidate of every source not settled
        probes = {}
        for name, candidates in todo.items():
            if candidates:
                grouping = candidates.pop(0)
                bits, rows = _probe_rows(stats[name][0], grouping)
                probes[name] = (grouping, bits, batch.add(name, rows.reshape(-1, rows.shape[-1])))
        try:
            pred = batch.run()
        except Exception:  # noqa: BLE001 - a model that refuses NaN: element by element
            batch.parts, batch.rows = [], 0
            break
        for name, (grouping, bits, where) in probes.items():
            elem = _element_of(pred[where], grouping.count, bits, grouping.size)
            if elem is not None:
                out[name] = (grouping, elem)
                todo[name] = []
    return out


def reading_effects(proc, setup, truth, active: dict) -> tuple[np.ndarray, dict]:
    """Error-free readings f0 (n,) and per source the effects (n, E): the derivative of
    the readings with respect to each element times its standard deviation.

    Richardson central differences with steps of ``REL_STEP`` standard deviations (an
    element of zero standard deviation contributes nothing). A group's readings are
    checked with its elements moved by random signs: each reading must come out as its
    own element's move alone (else that source is taken element by element). The groups
    found are kept for the next call with the same procedure, number of readings and
    sources' shapes (the designer's next lever position) and checked the same way there;
    a source whose kept groups fail is grouped afresh.
    """
    base, stats = _base_errors(proc, setup, active)
    batch = _Batch(lambda errors: _readings(proc, setup, truth, errors), base)
    f0 = _readings(proc, setup, truth, base)[0]
    n = f0.size
    # the groups of the last set-up with these sources' shapes and as many readings (a
    # lever moved in the designer): checked below like new ones, found again where not
    key = (proc.name, n, tuple((name, st[2]) for name, st in stats.items()))
    kept = _EFFECT_GROUPS.get(key, {})
    fresh = set(stats) - set(kept)
    found = _groups(batch, {name: stats[name] for name in stats if name in fresh})
    grouping = {name: kept[name] if name in kept else found[name] for name in stats}
    passed = {}
    rng = np.random.default_rng(0)
    effects = {}
    while grouping:
        where, signs = {}, {}
        for name, (grp, _elem) in grouping.items():
            mean, std, _ = stats[name]
            signs[name] = np.where(rng.random(mean.size) < 0.5, -1.0, 1.0)
            factors = np.vstack([np.array([1.0, -1.0, 2.0, -2.0])[:, None] * np.ones(mean.size),
                                 signs[name]])  # (5, E): Richardson, then the check
            rows = mean + grp.members()[:, None, :] * (factors * (REL_STEP * std))[None]
            where[name] = batch.add(name, rows.reshape(-1, mean.size))
        pred = batch.run()
        redo = {}
        for name, (grp, elem) in grouping.items():
            mean, std, shape = stats[name]
            vals = pred[where[name]].reshape(grp.count, 5, n)
            if elem is not None and not _checked(vals, f0, elem, grp, signs[name]):
                redo[name] = (_groupings(shape)[-1], None)  # element by element
                continue
            if elem is not None:  # (element by element is not kept: found again next time)
                passed[name] = (grp, elem)
            # h J by Richardson: (4 d1 - d2) / 3, d1 = (f+ - f-) / 2h, d2 = (f2+ - f2-) / 4h;
            # the effect J std is h J / REL_STEP
            eff_g = (2 * (vals[:, 0] - vals[:, 1]) - (vals[:, 2] - vals[:, 3]) / 4) / 3 / REL_STEP
            if elem is None:  # one element per group, in order
                eff = eff_g.T * (std > 0)
            else:
                eff = np.zeros((n, mean.size))
                g, r = np.nonzero(elem >= 0)
                col = grp.table[g, elem[g, r]]
                eff[r, col] = np.where(std[col] > 0, eff_g[g, r], 0.0)
            effects[name] = eff
        stale = {name: stats[name] for name in redo if name not in fresh}
        if stale:  # kept groups that do not fit this set-up: found for it
            redo.update(_groups(batch, stale))
            fresh.update(stale)
        grouping = redo
    if len(_EFFECT_GROUPS) >= 16:  # (cleared, not trimmed: the designer's threads share it)
        _EFFECT_GROUPS.clear()
    _EFFECT_GROUPS[key] = passed
    return f0, {name: effects[name] for name in stats}


_EFFECT_GROUPS: dict = {}  # reading_effects' (procedure, readings, source shapes) -> groups


def _checked(vals, f0, elem, grp: _Grouping, sign) -> bool:
    """Every group moved by random signs (row 4) gives, reading by reading, the move of
    that reading's element alone (rows 0 and 1), and no move where it has none."""
    plus, minus, mixed = vals[:, 0], vals[:, 1], vals[:, 4]  # (P, n)
    dep = elem >= 0
    s = sign[grp.table[np.arange(grp.count)[:, None], np.maximum(elem, 0)]]
    expect = np.where(dep, np.where(s > 0, plus, minus), f0)
    scale = np.abs(f0) + np.abs(plus - minus) + 1e-300
    return bool(np.all(np.abs(mixed - expect) <= 1e-12 * scale)
                and np.all(np.abs(plus - f0)[~dep] <= 1e-15 * scale[~dep])
                and np.all(np.abs(minus - f0)[~dep] <= 1e-15 * scale[~dep]))


def secant_effects(model, *, key=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`mtplan.fitting.source_effects` of a :class:`~mtplan.fitting.SourceModel`,
    the same numbers (D (n,), U (n, k)), from grouped rows.

    Each element's secant (half the change of the readings with it at plus and minus one
    standard deviation, all other errors zero) is read off rows that move a whole group
    of elements at once where every reading depends on one element of the group at most
    (:func:`_groups`): the readings are the same numbers as with the element moved
    alone. An element is a term of D or a column of U by the rules of
    ``mtplan.fitting.budget``: by the readings that depend on it for a source of at
    least 32 elements whose readings each depend on one of them (its NaN probes), else
    by the readings it moves by more than 1e-9 of its largest secant or curvature.

    `key` (hashable), optional, names the model's dependency structure (its set-up): the
    groups found for it are used again for the next model of that key. Every group is
    checked with its elements moved by random signs (each reading must come out as its
    own element's move alone, exactly); one that fails is found again, then taken
    element by element.
    """
    names = [k for k, src in model.sources.items()
             if np.any(np.asarray(src.distribution.std) > 0)]
    base = model.errors(1)
    f0 = model.at(None, base)[0]
    n = f0.size
    stats = {}
    for name in names:
        src = model.sources[name]
        shape = (*src.shape, *src.distribution.event_shape)
        n_el = int(np.prod(shape, dtype=np.int64))
        std = np.asarray(src.distribution.std, dtype=float)
        sd = (np.full(n_el, float(std.reshape(-1)[0])) if std.size == 1 else std.reshape(-1)
              if std.size == n_el else np.broadcast_to(std, shape).reshape(-1))
        stats[name] = (base[name].reshape(-1).astype(float), sd, shape)
    batch = _Batch(lambda errors: model.at(None, errors), base)
    grouping = _GROUPINGS.get(key) if key is not None else None
    if grouping is not None and (set(grouping) != set(stats) or any(
            grouping[k][0].label.size != stats[k][1].size for k in stats)):
        grouping = None  # kept for other sources or sizes
    fresh = grouping is None
    grouping = _groups(batch, stats) if fresh else grouping
    sign = np.where(np.random.default_rng(0).random(max([st[0].size for st in stats.values()],
                                                        default=0)) < 0.5, -1.0, 1.0)
    while True:
        vals = _secant_rows(batch, grouping, stats, sign, n)
        bad = [name for name, (grp, elem) in grouping.items()
               if elem is not None and not _exact(vals[name], f0, _owner(grp, elem, n), sign)]
        if not bad:
            break
        if not fresh:  # the structure is not the one kept under this key
            grouping, fresh = _groups(batch, stats), True
            continue
        grouping = {**grouping, **{name: (_groupings(stats[name][2])[-1], None)
                                   for name in bad}}
    if key is not None:
        _GROUPINGS[key] = grouping
        while len(_GROUPINGS) > 64:
            _GROUPINGS.pop(next(iter(_GROUPINGS)))
    D, cols = np.zeros(n), [np.zeros((n, 0))]
    for name in names:
        grp, elem = grouping[name]
        plus, minus = vals[name][:, 0], vals[name][:, 1]
        if not (np.all(np.isfinite(plus)) and np.all(np.isfinite(minus))):
            raise InvalidInput([f"The forward model of {model.name} gives no finite readings "
                                f"with the source {name!r} one standard deviation off its mean."])
        sec, cur = 0.5 * (plus - minus), 0.5 * (plus + minus) - f0  # (G, n)
        sd = stats[name][1]
        probed = elem is not None and grp.count == 1 and sd.size >= _PROBE
        d, u = _classify(sec, cur, _owner(grp, elem, n), sd.size, n, probed=probed)
        D = D + d
        cols.append(u)
    return D, np.hstack(cols)


_GROUPINGS: dict = {}  # secant_effects' key -> its groups


def _secant_rows(batch, grouping, stats, sign, n) -> dict:
    """Per source, the readings (G, 3, n) with each group's elements at +sd, -sd and
    random signs times sd."""
    where = {}
    for name, (grp, _elem) in grouping.items():
        zero, sd, _ = stats[name]
        moves = np.vstack([sd, -sd, sign[:sd.size] * sd])
        where[name] = batch.add(name, (zero + grp.members()[:, None, :] * moves[None]).reshape(
            -1, sd.size))
    pred = batch.run() if where else np.zeros((0, n))
    return {name: pred[w].reshape(grouping[name][0].count, 3, n) for name, w in where.items()}


def _owner(grp, elem, n) -> np.ndarray:
    """The element behind each group's reading (G, n), -1 for none."""
    owner = np.full((grp.count, n), -1)
    if elem is None:
        owner[:] = grp.table[:, :1]
    else:
        live = elem >= 0
        owner[live] = grp.table[np.nonzero(live)[0], elem[live]]
    return owner


def _exact(vals, f0, owner, sign) -> bool:
    """Each group's readings with random signs (row 2) are, reading by reading, those of
    its element's move alone (rows 0 and 1), and f0 where it has none."""
    plus, minus, mixed = vals[:, 0], vals[:, 1], vals[:, 2]
    live = owner >= 0
    expect = np.where(live, np.where(sign[np.maximum(owner, 0)] > 0, plus, minus), f0)
    return bool(np.all(mixed == expect) and np.all((plus == f0) | live)
                and np.all((minus == f0) | live))


def _classify(sec, cur, owner, n_el, n, *, probed):
    """D's terms (n,) and U's columns (n, k) of one source from each group's secants and
    curvatures `sec`, `cur` (G, n) with the element `owner` (G, n) behind each reading."""
    g, r = np.nonzero(owner >= 0)
    j = owner[g, r]
    if probed:  # an element's readings: those that depend on it
        keep = np.ones(j.size, dtype=bool)
    else:  # those it moves by more than _SUPPORT of its largest secant or curvature
        big = np.zeros(n_el)
        np.maximum.at(big, j, np.maximum(np.abs(sec[g, r]), np.abs(cur[g, r])))
        keep = (np.abs(sec[g, r]) > _SUPPORT * big[j]) | (np.abs(cur[g, r]) > _SUPPORT * big[j])
    count = np.bincount(j[keep], minlength=n_el)
    d = np.zeros(n)
    one = keep & (count[j] == 1)
    order = np.argsort(j[one], kind="stable")  # element order, as the budget adds them
    np.add.at(d, r[one][order], sec[g[one], r[one]][order] ** 2)
    multi = np.flatnonzero(count > 1)
    u = np.zeros((n, multi.size))
    col = np.searchsorted(multi, j)
    sel = np.isin(j, multi)
    u[r[sel], col[sel]] = sec[g[sel], r[sel]]
    return d, u


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
    chunk = max(16, _CHUNK_CELLS // max(n, 1))
    out = []
    for s in range(0, 2 * n, chunk):
        e = min(2 * n, s + chunk)
        rows = np.repeat(y0[None, :], e - s, axis=0)
        rows[np.arange(e - s), cols[s:e]] += delta[s:e]
        out.append(np.asarray(estimate(rows), dtype=float))
    v = np.concatenate(out)
    return ((v[:n] - v[n:]) / (2 * steps[:, None])).T


def _whole_chain(proc, setup, truth, active, measure) -> dict:
    """Per source variances by differentiating forward model and estimator together
    (``mtplan linearize``'s way, the cheaper one for a few source elements)."""
    base, stats = _base_errors(proc, setup, active)
    names = list(stats)
    if not names:  # no active source: no variance
        return {}
    x = np.concatenate([stats[k][0] for k in names])
    u = np.concatenate([stats[k][1] for k in names])
    sizes = np.cumsum([0] + [stats[k][0].size for k in names])

    def chain(points):
        m = points.shape[0]
        errors = {k: np.repeat(v, m, axis=0) for k, v in base.items()}
        for k, a, b in zip(names, sizes[:-1], sizes[1:], strict=True):
            errors[k] = points[:, a:b].reshape((m, *stats[k][2]))
        return measure(proc.forward(setup, truth, errors))

    _, jac = sensitivities(chain, x, u, max_batch=max(64, _CHUNK_CELLS // max(x.size, 1)))
    return {k: np.sum((jac[:, a:b] * u[a:b]) ** 2, axis=1)
            for k, a, b in zip(names, sizes[:-1], sizes[1:], strict=True)}


def chain_variances(proc, setup, truth=None, *, estimator=None, sources=None) -> dict:
    """Per active source, the first-order variance (q,) of each measurand [display unit^2].

    The procedure's readings are the concatenation of its forward model's arrays (each
    flattened per trial), split back by their shapes for the estimator.
    """
    # small products: a team of BLAS threads costs more than it gains, most on a busy machine
    with one_blas_thread():
        return _chain_variances(proc, setup, truth, estimator, sources)


def _chain_variances(proc, setup, truth, estimator, sources) -> dict:
    truth = proc.Truth() if truth is None else truth
    est_name, _ = proc.estimator(estimator)
    active = proc.active_sources(setup, sources)
    measurands = proc.measurands(setup)

    def measure(readings):  # (m, q) [display units]
        est = proc.estimators[est_name](setup, readings)
        return np.column_stack([np.asarray(est[mm.name], dtype=float) * mm.scale
                                for mm in measurands])

    n_el = sum(int(np.prod((*s.shape, *s.distribution.event_shape), dtype=np.int64))
               for s in active.values())
    if n_el <= _WHOLE_MAX:
        return _whole_chain(proc, setup, truth, active, measure)
    zero = proc.forward(setup, truth, _base_errors(proc, setup, active)[0])
    layout = [(k, np.asarray(v).shape[1:]) for k, v in zero.items()]

    def estimate(rows):  # the readings flattened per trial, as reading_effects has them
        m, pos, readings = rows.shape[0], 0, {}
        for k, shape in layout:
            size = int(np.prod(shape, dtype=np.int64))
            readings[k] = rows[:, pos:pos + size].reshape((m, *shape))
            pos += size
        return measure(readings)

    f0, effects = reading_effects(proc, setup, truth, active)
    var_r = sum((e**2).sum(axis=1) for e in effects.values()) if effects else np.zeros(f0.size)
    sd = np.sqrt(var_r)
    steps = np.where(sd > 0, REL_STEP * sd,
                     np.cbrt(np.finfo(float).eps) * np.maximum(np.abs(f0), 1.0))
    g = estimator_map(estimate, f0, steps)
    return {name: np.sum((g @ e) ** 2, axis=1) for name, e in effects.items()}


def chain_budget(proc, setup, *, estimator=None, truth=None) -> pd.DataFrame:
    """First-order budget (columns ``measurand``, ``unit``, ``source``, ``std``, ``share``):
    the ``Procedure.first_order_budget`` hook by the chain rule (see the module notes)."""
    var = chain_variances(proc, setup, truth, estimator=estimator)
    rows = []
    for i, m in enumerate(proc.measurands(setup)):
        total = sum(float(v[i]) for v in var.values())
        for name, v in var.items():
            rows.append((m.name, m.unit, name, math.sqrt(float(v[i])),
                         float(v[i]) / total if total > 0 else 0.0))
    return pd.DataFrame(rows, columns=["measurand", "unit", "source", "std", "share"])


def chain_std(proc, setup, truth=None, *, estimator=None, sources=None) -> dict:
    """First-order standard uncertainty per measurand [display unit] (the
    ``Procedure.first_order_std`` hook by the chain rule)."""
    var = chain_variances(proc, setup, truth, estimator=estimator, sources=sources)
    return {m.name: math.sqrt(sum(float(v[i]) for v in var.values()))
            for i, m in enumerate(proc.measurands(setup))}


def with_chain_rule(proc):
    """`proc` with its ``first_order_budget`` and ``first_order_std`` hooks by the chain
    rule (:func:`chain_budget`, :func:`chain_std`): the live designer's and the planner's
    first-order prediction, the same as ``mtplan linearize`` gives."""
    box = {}

    def budget(setup, *, estimator=None):
        return chain_budget(box["proc"], setup, estimator=estimator)

    def std(setup, truth=None, *, estimator=None, sources=None):
        return chain_std(box["proc"], setup, truth, estimator=estimator, sources=sources)

    box["proc"] = dataclasses.replace(proc, first_order_budget=budget, first_order_std=std)
    return box["proc"]
