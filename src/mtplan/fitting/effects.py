"""How each element of each error source moves each reading: probes and secants, once.

The posterior's likelihood (:mod:`mtplan.fitting.error_model`), the readings' covariance of a
fit (:func:`mtplan.fitting.source_effects`) and the first-order linearisation service
(:mod:`mtplan.evaluation.first_order`) all ask the forward model the same question: which
readings does each element of a source move, and by how much. The answer is found here:

- **NaN probes.** A source's elements are numbered; probe row pair b sets the elements
  whose position has bit b set (then those with it clear) to NaN. The readings that turn
  NaN spell out, bit by bit, the element each depends on (:func:`probe_rows`,
  :func:`element_of`): ``2 log2(E)`` forward rows instead of ``2 E`` when every reading
  depends on one element at most (reading noise). Groups of elements are tried from the
  whole source down (:func:`find_groups`), so that a source (points, 3) whose three
  components move the same readings splits into three groups.
- **Checked groups.** Every grouping is checked with its elements moved by random signs:
  each reading must come out as its own element's move alone (:func:`grouped_ok`); a model
  that does not pass NaN on, or whose readings depend on several elements, fails it and
  is taken element by element.
- **Secants** (:func:`effect`, :func:`secant_effects`): each element at its mean plus and
  minus one standard deviation; half the difference is its secant effect, the half sum
  minus the prediction its curvature. An element's readings are those that depend on it
  (probed sources of at least :data:`PROBE` elements), else those it moves by more than
  :data:`SUPPORT` of its largest secant or curvature (:func:`classify`).
- **Derivatives** (:func:`reading_effects`): Richardson central differences with steps of
  :data:`REL_STEP` standard deviations, from the same grouped rows (the linearisation).
- **An estimate's first-order response**, by central differences over batches of rows: to
  its readings (:func:`estimator_map`, the first-order service's map from readings to
  measurands) or to one standard deviation of each element of named sources through the
  forward model (:func:`source_response`, geometry21's closed forms' fallback).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["SUPPORT", "ROUNDOFF", "PROBE", "REL_STEP", "Effect", "element_moments", "classify", "Batch",
           "Grouping", "groupings", "probe_rows", "element_of", "find_groups", "grouped_ok",
           "effect", "secant_effects", "reading_effects", "estimator_map", "source_response"]

SUPPORT = 1e-9  # relative size below which an element's effect on a reading is zero
#: an element's move of a reading below this share of the reading's own size is the
#: forward model's round-off, no effect (a reading of 250 mm carries about 3e-14 mm of it)
ROUNDOFF = 1e-12
PROBE = 32  # sources with at least this many elements are first tried by NaN probes
#: step of the derivatives, in standard deviations (that of ``mtplan.uncertainty.gum``)
REL_STEP = 1e-3
CHUNK_CELLS = 400_000  # about this many numbers per batch of rows (cache-sized arrays)


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


# --------------------------------------------------------------------------- secants
@dataclass
class Effect:
    """Secant and curvature of every element of one source (sparse where they touch one reading)."""

    std: np.ndarray  # (E,)
    row: np.ndarray  # (E,) the reading an element touches alone, -1 when several or none
    s1: np.ndarray  # (E,) its secant there
    c1: np.ndarray  # (E,) its curvature there
    multi: np.ndarray  # (k,) elements touching several readings
    S: np.ndarray  # (n, k) their secants
    C: np.ndarray  # (n, k) their curvatures

    @property
    def any(self) -> bool:
        return bool(np.any(self.row >= 0) or self.multi.size)

    def diag(self, n: int) -> np.ndarray:
        d = np.zeros(n)
        one = self.row >= 0
        np.add.at(d, self.row[one], self.s1[one] ** 2)
        return d

    def curvature(self, n: int) -> np.ndarray:
        c = np.zeros(n)
        one = self.row >= 0
        np.add.at(c, self.row[one], self.c1[one])
        return c + self.C.sum(axis=1)

    def dense(self, n: int) -> np.ndarray:
        """Secants of every element as a dense array (n, E)."""
        out = np.zeros((n, self.std.size))
        one = np.flatnonzero(self.row >= 0)
        out[self.row[one], one] = self.s1[one]
        out[:, self.multi] = self.S
        return out

    def nonlinearity(self, ref: np.ndarray) -> float:
        """Largest norm of an element's curvature in units of `ref` (a std per reading)."""
        one = self.row >= 0
        single = np.abs(self.c1[one]) / ref[self.row[one]] if one.any() else np.zeros(0)
        multi = np.sqrt(np.sum((self.C / ref[:, None]) ** 2, axis=0))
        return float(max(single.max(initial=0.0), multi.max(initial=0.0)))


def _above_roundoff(sec: np.ndarray, cur: np.ndarray, f0: np.ndarray | None) -> np.ndarray:
    """Where a secant or curvature (..., n) is more than the round-off of the readings `f0`
    (n,) (:data:`ROUNDOFF` of each reading's size): an element whose only "effect" is
    round-off (a start coordinate that no reading depends on, moved by 14 mm, leaves 1e-14
    mm on a 249 mm reading) would otherwise count as touching that reading alone, with a
    variance of 1e-28 mm^2 that then stands for the reading's own scatter."""
    if f0 is None:
        return np.ones(np.shape(sec), dtype=bool)
    floor = ROUNDOFF * np.abs(f0)
    return (np.abs(sec) > floor) | (np.abs(cur) > floor)


def classify(sec: np.ndarray, cur: np.ndarray, owner: np.ndarray, sd: np.ndarray, *,
             probed: bool, f0: np.ndarray | None = None) -> Effect:
    """One source's :class:`Effect` from rows of secants and curvatures `sec`, `cur`
    (G, n), with `owner` (G, n) the element behind each row's reading (-1: none).

    An element's readings are those it owns when `probed` (NaN probes found them), else
    those it moves by more than :data:`SUPPORT` of its largest secant or curvature and by
    more than the round-off of the readings `f0` (n,) where given. An element with one
    reading is a term of the diagonal; one with several, a column."""
    n_el, n = sd.size, sec.shape[1]
    g, r = np.nonzero(owner >= 0)
    j = owner[g, r]
    s, c = sec[g, r], cur[g, r]
    if probed:
        keep = np.ones(j.size, dtype=bool)
    else:
        big = np.zeros(n_el)
        np.maximum.at(big, j, np.maximum(np.abs(s), np.abs(c)))
        keep = ((np.abs(s) > SUPPORT * big[j]) | (np.abs(c) > SUPPORT * big[j])) & (
            _above_roundoff(sec, cur, f0)[g, r])
    count = np.bincount(j[keep], minlength=n_el)
    row, s1, c1 = np.full(n_el, -1), np.zeros(n_el), np.zeros(n_el)
    one = keep & (count[j] == 1)
    row[j[one]], s1[j[one]], c1[j[one]] = r[one], s[one], c[one]
    multi = np.flatnonzero(count > 1)
    col = np.full(n_el, -1)
    col[multi] = np.arange(multi.size)
    many = count[j] > 1
    S, C = np.zeros((n, multi.size)), np.zeros((n, multi.size))
    S[r[many], col[j[many]]] = s[many]
    C[r[many], col[j[many]]] = c[many]
    return Effect(sd, row, s1, c1, multi, S, C)


def _name(fwd) -> str:
    """The procedure's name for messages (a posterior's Forward, or a SourceModel)."""
    proc = getattr(fwd, "proc", None)
    return getattr(proc, "name", None) or getattr(fwd, "name", "the procedure")


def _secants(fwd, truth, name: str, shape, step: np.ndarray, f0: np.ndarray):
    """Secants and curvatures (rows, n) of the source `name` moved by each row of ``step``
    (rows, elements) about its mean, plus and minus: one forward call of 2 rows each."""
    m = step.shape[0]
    errors = fwd.errors(2 * m, copy_of=(name,))
    a = errors[name].reshape(2 * m, -1)
    a[:m] += step
    a[m:] -= step
    errors[name] = a.reshape(2 * m, *shape)
    pred = fwd.at(truth, errors)
    _finite(pred, fwd, name)
    return 0.5 * (pred[:m] - pred[m:]), 0.5 * (pred[:m] + pred[m:]) - f0


def _finite(pred, fwd, name: str) -> None:
    if not np.all(np.isfinite(pred)):
        raise InvalidInput([f"The forward model of {_name(fwd)} gives no finite readings "
                            f"with the source {name!r} one standard deviation off its mean."])


def _probed(fwd, truth, name: str, sd: np.ndarray, f0: np.ndarray, shape) -> Effect | None:
    """The effects of a source whose readings each depend on one element at most, found
    in 2 log2(E) + 3 forward rows instead of 2 E: the NaN probes of the whole source
    (:func:`probe_rows`), then all elements at +sigma, all at -sigma, and a random
    mixture, checked (:func:`grouped_ok`). None where that does not hold."""
    n_el = sd.size
    whole = Grouping(np.zeros(n_el, dtype=np.int64))
    sign = np.where(np.random.default_rng(0).random(n_el) < 0.5, -1.0, 1.0)
    errors = fwd.errors(1, copy_of=(name,))
    mean = errors[name].reshape(-1).astype(float)
    bits, probes = probe_rows(mean, whole)
    rows = np.vstack([probes.reshape(2 * bits, n_el), mean + sd, mean - sd, mean + sign * sd])
    errors = fwd.errors(rows.shape[0], copy_of=(name,))
    errors[name] = rows.reshape(rows.shape[0], *shape)
    try:
        with np.errstate(all="ignore"):
            pred = fwd.at(truth, errors)
    except Exception:  # noqa: BLE001 - a model that refuses NaN: element by element
        return None
    elem = element_of(pred[:2 * bits], 1, bits, n_el)
    plus, minus, mixed = pred[2 * bits:]
    if elem is None or not np.all(np.isfinite(pred[2 * bits:])) or not grouped_ok(
            plus[None], minus[None], mixed[None], f0, elem, sign, rtol=1e-12, rtol_free=0.0):
        return None
    return classify(0.5 * (plus - minus)[None], (0.5 * (plus + minus) - f0)[None], elem, sd,
                    probed=True)


def _coloured(fwd, truth, name: str, sd: np.ndarray, f0: np.ndarray, shape, colours,
              owners) -> Effect | None:
    """The effects of a source whose elements the model has coloured: elements of one
    colour never move a common reading, so each colour is one row at +sigma and one at
    -sigma (Curtis, Powell and Reid's grouping of a sparse Jacobian's columns), and
    ``owners`` (colours, n) names the element of each colour that each reading depends
    on (-1: none). 2 C forward rows instead of 2 E; the secants and curvatures are those
    of the element-by-element evaluation, and so is the support rule (:data:`SUPPORT`).
    None where a reading no element of a colour owns moves in that colour's rows (a
    colouring that does not hold: the caller evaluates element by element)."""
    colours = np.asarray(colours, dtype=np.int64).reshape(-1)
    owners = np.asarray(owners, dtype=np.int64)
    n_el, k = sd.size, owners.shape[0]
    step = np.zeros((k, n_el))
    for c in range(k):
        on = colours == c
        step[c, on] = sd[on]
    sec, cur = _secants(fwd, truth, name, shape, step, f0)
    free = owners < 0
    if np.any(sec[free] != 0) or np.any(cur[free] != 0):
        return None
    c_idx, _ = np.nonzero(~free)
    if np.any(colours[owners[~free]] != c_idx):
        raise ValueError(f"the colouring of {name!r} names an element in a colour not its own")
    return classify(sec, cur, owners, sd, probed=False, f0=f0)


def effect(fwd, truth, name: str, std, f0: np.ndarray) -> Effect:
    """Evaluate one source's elements at their mean +- `std`: by the model's colouring
    where it gives one (``fwd.structure``), by NaN probes when every reading depends on one
    element at most, else element by element in chunks of rows.

    `fwd` has ``sources``, ``n`` (readings), ``errors(m, copy_of=())`` (m rows of errors at
    the sources' means) and ``at(truth, errors) -> (m, n)``: a posterior's forward model
    or a :class:`~mtplan.fitting.SourceModel`."""
    src = fwd.sources[name]
    shape = (*src.shape, *src.distribution.event_shape)
    n_el = int(np.prod(shape, dtype=np.int64))
    std = np.asarray(std, dtype=float)
    if std.size == 1:
        sd = np.full(n_el, float(std.reshape(-1)[0]))
    elif std.size == n_el:
        sd = std.reshape(-1)
    else:
        sd = np.broadcast_to(std, shape).reshape(-1)
    hook = getattr(fwd, "structure", None)
    plan = hook(truth, name) if hook is not None else None
    if plan is not None:
        eff = _coloured(fwd, truth, name, sd, f0, shape, *plan)
        if eff is not None:
            return eff
    if n_el >= PROBE:
        eff = _probed(fwd, truth, name, sd, f0, shape)
        if eff is not None:
            return eff
    n = fwd.n
    chunk = int(max(8, min(n_el, 4_000_000 // max(n, n_el, 1))))
    row, s1, c1 = np.full(n_el, -1), np.zeros(n_el), np.zeros(n_el)
    multi, S, C = [], [], []
    for start in range(0, n_el, chunk):
        idx = np.arange(start, min(n_el, start + chunk))
        b = idx.size
        step = np.zeros((b, n_el))
        step[np.arange(b), idx] = sd[idx]
        sec, cur = _secants(fwd, truth, name, shape, step, f0)
        big = np.maximum(np.abs(sec).max(axis=1), np.abs(cur).max(axis=1))
        nz = ((np.abs(sec) > SUPPORT * big[:, None]) | (np.abs(cur) > SUPPORT * big[:, None])) & (
            _above_roundoff(sec, cur, f0))
        count = nz.sum(axis=1)
        one = count == 1
        r = np.argmax(nz, axis=1)
        row[idx[one]] = r[one]
        s1[idx[one]] = sec[one, r[one]]
        c1[idx[one]] = cur[one, r[one]]
        many = count > 1
        multi.append(idx[many])
        S.append(sec[many].T)
        C.append(cur[many].T)
    return Effect(sd, row, s1, c1, np.concatenate(multi), np.hstack(S) if S else np.zeros((n, 0)),
                  np.hstack(C) if C else np.zeros((n, 0)))


# --------------------------------------------------------------------------- grouped rows
class Batch:
    """Rows of errors, each at the sources' means but for one source's values, run through
    the forward model in cache-sized batches of rows."""

    def __init__(self, readings, base: dict):
        self.readings, self.base = readings, base
        self.parts: list[tuple[str, np.ndarray]] = []
        self.rows = 0
        width = sum(int(np.prod(v.shape[1:], dtype=np.int64)) for v in base.values())
        self.chunk = max(8, CHUNK_CELLS // max(width, 1))

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


class Grouping:
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

    def owner(self, elem: np.ndarray | None, n: int) -> np.ndarray:
        """The element behind each group's reading (G, n), -1 for none, from each group's
        position of every reading `elem` (G, n) (None: one element per group, all readings)."""
        owner = np.full((self.count, n), -1)
        if elem is None:
            owner[:] = self.table[:, :1]
        else:
            live = elem >= 0
            owner[live] = self.table[np.nonzero(live)[0], elem[live]]
        return owner


def groupings(shape: tuple) -> list[Grouping]:
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
    return [Grouping(labels[g]) for g in sorted(labels)] + [Grouping(j)]


def probe_rows(mean: np.ndarray, grouping: Grouping) -> tuple[int, np.ndarray]:
    """NaN probes of a grouping: bits, rows (G, bits, 2, E); row (g, b, 0) sets the
    elements of group g whose position has bit b set to NaN, row (g, b, 1) those with
    it clear."""
    bits = max(1, (grouping.size - 1).bit_length())
    bit = (grouping.pos[None, :] >> np.arange(bits)[:, None]) & 1  # (bits, E)
    mask = np.stack([bit == 1, bit == 0], axis=1)[None] & grouping.members()[:, None, None, :]
    return bits, np.where(mask, np.nan, mean)


def element_of(pred: np.ndarray, count: int, bits: int, size: int):
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


def grouped_ok(plus, minus, mixed, f0, owner, sign, *, rtol: float, rtol_free: float) -> bool:
    """Each group's readings with its elements moved by random signs `mixed` (G, n) are,
    reading by reading, those of the reading's own element's move alone (`plus` or `minus`,
    by the sign of the element `owner` (G, n)), to `rtol`; and a reading no element of the
    group owns does not move, to `rtol_free` (0: exactly)."""
    live = owner >= 0
    expect = np.where(live, np.where(sign[np.maximum(owner, 0)] > 0, plus, minus), f0)
    scale = np.abs(f0) + np.abs(plus - minus) + 1e-300
    free = ~live
    return bool(np.all(np.abs(mixed - expect) <= rtol * scale)
                and np.all(np.abs(plus - f0)[free] <= rtol_free * scale[free])
                and np.all(np.abs(minus - f0)[free] <= rtol_free * scale[free]))


def find_groups(batch: Batch, stats: dict) -> dict:
    """Per source, a grouping of its elements in which every reading depends
    on one element at most, and each group's element of every reading (None: one
    element per group).

    Tried from the whole source down (a source (points, 3) whose three components move
    the same readings splits into 3 groups); NaN probes spell out each reading's element
    bit by bit, every source and grouping in one batch.
    """
    out = {name: (groupings(shape)[-1], None) for name, (_m, _s, shape) in stats.items()}
    todo = {name: groupings(shape)[:-1] for name, (_m, _s, shape) in stats.items()}
    while any(todo.values()):  # a round: the next candidate of every source not settled
        probes = {}
        for name, candidates in todo.items():
            if candidates:
                grouping = candidates.pop(0)
                bits, rows = probe_rows(stats[name][0], grouping)
                probes[name] = (grouping, bits, batch.add(name, rows.reshape(-1, rows.shape[-1])))
        try:
            pred = batch.run()
        except Exception:  # noqa: BLE001 - a model that refuses NaN: element by element
            batch.parts, batch.rows = [], 0
            break
        for name, (grouping, bits, where) in probes.items():
            elem = element_of(pred[where], grouping.count, bits, grouping.size)
            if elem is not None:
                out[name] = (grouping, elem)
                todo[name] = []
    return out


def secant_effects(model, *, key=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`mtplan.fitting.source_effects` of a :class:`~mtplan.fitting.SourceModel`,
    the same numbers (D (n,), U (n, k)), from grouped rows.

    Each element's secant (half the change of the readings with it at plus and minus one
    standard deviation, all other errors zero) is read off rows that move a whole group
    of elements at once where every reading depends on one element of the group at most
    (:func:`find_groups`): the readings are the same numbers as with the element moved
    alone. An element is a term of D or a column of U by :func:`classify`'s rules.

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
    batch = Batch(lambda errors: model.at(None, errors), base)
    grouping = _GROUPINGS.get(key) if key is not None else None
    if grouping is not None and (set(grouping) != set(stats) or any(
            grouping[k][0].label.size != stats[k][1].size for k in stats)):
        grouping = None  # kept for other sources or sizes
    fresh = grouping is None
    grouping = find_groups(batch, stats) if fresh else grouping
    sign = np.where(np.random.default_rng(0).random(max([st[0].size for st in stats.values()],
                                                        default=0)) < 0.5, -1.0, 1.0)
    while True:
        vals = _secant_rows(batch, grouping, stats, sign, n)
        bad = [name for name, (grp, elem) in grouping.items()
               if elem is not None and not grouped_ok(
                   *np.moveaxis(vals[name], 1, 0), f0, grp.owner(elem, n), sign,
                   rtol=0.0, rtol_free=0.0)]
        if not bad:
            break
        if not fresh:  # the structure is not the one kept under this key
            grouping, fresh = find_groups(batch, stats), True
            continue
        grouping = {**grouping, **{name: (groupings(stats[name][2])[-1], None) for name in bad}}
    if key is not None:
        _GROUPINGS[key] = grouping
        while len(_GROUPINGS) > 64:
            _GROUPINGS.pop(next(iter(_GROUPINGS)))
    D, cols = np.zeros(n), [np.zeros((n, 0))]
    for name in names:
        grp, elem = grouping[name]
        plus, minus = vals[name][:, 0], vals[name][:, 1]
        _finite(np.stack([plus, minus]), model, name)
        sd = stats[name][1]
        probed = elem is not None and grp.count == 1 and sd.size >= PROBE
        eff = classify(0.5 * (plus - minus), 0.5 * (plus + minus) - f0, grp.owner(elem, n), sd,
                       probed=probed)
        D = D + eff.diag(n)
        cols.append(eff.S)
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


# --------------------------------------------------------------------------- derivatives
def reading_effects(readings, base: dict, stats: dict, *, key=None
                    ) -> tuple[np.ndarray, dict]:
    """Readings f0 (n,) at `base` and per source the effects (n, E): the derivative of
    the readings with respect to each element times its standard deviation.

    Parameters
    ----------
    readings : callable
        ``readings(errors) -> (m, n)``: the forward model's readings, flattened per row.
    base : dict of str to array (1, ...)
        Every source's errors in one row at the sources' means.
    stats : dict of str to (mean (E,), std (E,), shape)
        The sources to differentiate by (:func:`element_moments`).
    key : hashable, optional
        Names the model (procedure and sources); with it the groups found are kept.

    Richardson central differences with steps of :data:`REL_STEP` standard deviations (an
    element of zero standard deviation contributes nothing). A group's readings are
    checked with its elements moved by random signs: each reading must come out as its
    own element's move alone (else that source is taken element by element). The groups
    found are kept for the next call with the same key, number of readings and sources'
    shapes (the designer's next lever position) and checked the same way there; a source
    whose kept groups fail is grouped afresh.
    """
    batch = Batch(readings, base)
    f0 = readings(base)[0]
    n = f0.size
    key = (key, n, tuple((name, st[2]) for name, st in stats.items()))
    kept = _EFFECT_GROUPS.get(key, {}) if key[0] is not None else {}
    fresh = set(stats) - set(kept)
    found = find_groups(batch, {name: stats[name] for name in stats if name in fresh})
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
            if elem is not None and not grouped_ok(
                    vals[:, 0], vals[:, 1], vals[:, 4], f0, grp.owner(elem, n), signs[name],
                    rtol=1e-12, rtol_free=1e-15):
                redo[name] = (groupings(shape)[-1], None)  # element by element
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
            redo.update(find_groups(batch, stale))
            fresh.update(stale)
        grouping = redo
    if key[0] is not None:
        if len(_EFFECT_GROUPS) >= 16:  # (cleared, not trimmed: the designer's threads share it)
            _EFFECT_GROUPS.clear()
        _EFFECT_GROUPS[key] = passed
    return f0, {name: effects[name] for name in stats}


_EFFECT_GROUPS: dict = {}  # reading_effects' (key, readings, source shapes) -> groups


# --------------------------------------------------------------------------- responses
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


def source_response(estimate: Callable, errors: Callable, sources: Mapping, names: Sequence[str],
                    *, rel_step: float = 0.01) -> np.ndarray:
    """An estimate's first-order response to one standard deviation of each element of the
    named sources (as the GUM linearisation does, about the sources' means; central
    differences with a step of `rel_step` of the standard deviation, every element in one
    batch).

    Parameters
    ----------
    estimate : callable
        ``estimate(errors) -> (m, q)``: the estimate from readings simulated with error
        rows ``errors``.
    errors : callable
        ``errors(m) -> dict``: fresh error rows of every source, zero.
    sources : dict of str to Source
    names : sequence of str

    Returns
    -------
    array (q, K): K the named sources' elements, in order.
    """
    elems = [(name, idx) for name in names for idx in np.ndindex(*sources[name].shape)]
    k = len(elems)
    if not k:
        return np.zeros((0, 0))
    err = errors(2 * k)
    for name in names:
        err[name][...] = sources[name].distribution.mean
    for j, (name, idx) in enumerate(elems):
        h = rel_step * float(sources[name].distribution.std)
        err[name][(2 * j, *idx)] += h
        err[name][(2 * j + 1, *idx)] -= h
    th = np.asarray(estimate(err), dtype=float)
    return ((th[0::2] - th[1::2]) / (2 * rel_step)).T
