"""The forward model as the posterior sees it: free parameters, truths, batched predictions.

A posterior's free parameters are Truth fields: float fields, and the elements of
tuple fields (``wrist_dx_um[1]``). :class:`TruthBuilder` turns parameter vectors
into Truth objects, one per row (validated like the dataclass) or one *batched*
Truth for many rows (each float field an array ``(m,)``, each tuple field a tuple
of such arrays: the convention of the procedure protocol for "one truth per batch
row"). :class:`Forward` predicts the readings for many parameter rows at once:
through one forward call with the batched Truth when the procedure's forward model
accepts it (checked against the per-row loop on the first call, to 1e-9), else
row by row.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from mtplan._validate import InvalidInput, Problems

__all__ = ["Param", "truth_parameters", "TruthBuilder", "Forward"]

#: errors a forward model raises for a truth or error row outside its domain
DOMAIN_ERRORS = (InvalidInput, ValueError, ArithmeticError, IndexError)
#: finite-difference step of a parameter, in internal units (mm or rad; 1 for plain numbers)
_STEP = 1e-7


@dataclass(frozen=True)
class Param:
    """One free parameter: a float Truth field or one element of a tuple field."""

    name: str
    field: str
    index: int | None
    unit: str
    low: float
    high: float
    low_open: bool
    high_open: bool

    @property
    def step(self) -> float:
        """Finite-difference step [the parameter's unit]: 1e-7 mm or 1e-7 rad."""
        from mtplan.models.protocol import UNITS

        return _STEP * UNITS.get(self.unit, 1.0)


def truth_parameters(proc, truth, fields=None) -> list[Param]:
    """The free parameters: `fields` (names of fields or of elements ``field[i]``), else
    every float field and every element of a tuple field."""
    from mtplan.models.protocol import fields_info

    every = []
    for info in fields_info(type(truth)):
        lo = -np.inf if info.low is None else float(info.low)
        hi = np.inf if info.high is None else float(info.high)
        args = (info.unit, lo, hi, bool(info.low_open), bool(info.high_open))
        value = getattr(truth, info.name)
        if info.kind is float and not info.optional:
            every.append(Param(info.name, info.name, None, *args))
        elif info.kind == "tuple" and info.element is float and value is not None:
            every += [Param(f"{info.name}[{i}]", info.name, i, *args)
                      for i in range(len(value))]
    if fields is None:
        return every
    wanted = (fields,) if isinstance(fields, str) else tuple(fields)
    chosen = [p for p in every if p.name in wanted or p.field in wanted]
    known = {p.name for p in every} | {p.field for p in every}
    bad = [f for f in wanted if f not in known]
    if bad or not chosen:
        raise InvalidInput([
            f"The 'fields' parameter of sample_posterior must name float Truth fields of "
            f"{proc.name} or elements of its tuple fields ({', '.join(sorted(known))}). Got "
            f"{list(bad) or 'none'} instead."])
    return chosen


class _Reader:
    """Stands in for a Truth and records which attributes its ``_check`` reads."""

    def __init__(self, base):
        self._base = base
        self.read = set()

    def __getattr__(self, name):
        self.read.add(name)
        return getattr(self._base, name)


class TruthBuilder:
    """Truth objects for parameter vectors, with the Truth's own validation.

    Ranges are checked vectorised (:meth:`valid`); a Truth class with cross-field
    rules (``_check``) has them run per row on an unvalidated copy
    (:meth:`cross_valid`), which is the dataclass's validation without re-reading its
    type hints for every row; only when a parameter that varies between rows
    (:attr:`varying`) is a field the rules read (found by running them once on a
    recorder), else once for all rows.
    """

    def __init__(self, base, params):
        from mtplan.models.protocol import SetupBase

        self.base = base
        self.params = tuple(params)
        self.low = np.array([p.low for p in self.params], dtype=float)
        self.high = np.array([p.high for p in self.params], dtype=float)
        self.low_open = np.array([p.low_open for p in self.params])
        self.high_open = np.array([p.high_open for p in self.params])
        self.full = getattr(type(base), "_check", None) is not SetupBase._check
        self.values = np.array([self.value_of(base, p) for p in self.params], dtype=float)
        self.varying = None  # indices of the parameters that vary between rows (None: all)
        self.check_reads = self._check_reads() if self.full else set()

    def _check_reads(self):
        """The fields the Truth's ``_check`` reads, or None when that cannot be told."""
        rec = _Reader(self.base)
        try:
            type(self.base)._check(rec, Problems("truth"))
        except Exception:  # noqa: BLE001 - rules that need more than attributes: run them always
            return None
        fields = {f.name for f in dataclasses.fields(self.base)}
        return None if rec.read - fields else rec.read

    @staticmethod
    def value_of(truth, p: Param) -> float:
        v = getattr(truth, p.field)
        return float(v if p.index is None else v[p.index % len(v)])  # tuples cycle

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.params]

    def steps(self, theta) -> np.ndarray:
        """Finite-difference steps: 1e-7 mm or rad, at least 1e-6 of the value."""
        unit = np.array([p.step for p in self.params])
        return np.maximum(unit, 1e-6 * np.abs(np.asarray(theta, dtype=float)))

    def valid(self, theta: np.ndarray) -> np.ndarray:
        """Mask of rows of `theta` (n, n_params) inside every field's range."""
        theta = np.atleast_2d(theta)
        ok = np.all(np.isfinite(theta), axis=1)
        ok &= np.all(np.where(self.low_open, theta > self.low, theta >= self.low), axis=1)
        ok &= np.all(np.where(self.high_open, theta < self.high, theta <= self.high), axis=1)
        return ok

    def _changes(self, values) -> dict:
        """The fields of the base that `values` (one per parameter: floats or arrays (m,))
        change: field -> value (a tuple field whole, its other elements as in the base)."""
        changes, tuples = {}, {}
        for p, v in zip(self.params, values, strict=True):
            if p.index is None:
                changes[p.field] = v
            else:
                tuples.setdefault(p.field, {})[p.index] = v
        for name, items in tuples.items():
            old = getattr(self.base, name)
            shape = np.shape(next(iter(items.values())))
            changes[name] = tuple(items.get(i, np.full(shape, float(x)) if shape else float(x))
                                  for i, x in enumerate(old))
        return changes

    def _assign(self, values) -> object:
        """The base with `values` set, as a batch of truths (``Truth.batch``; of one where
        the values are floats): checked by :meth:`valid` and :meth:`cross_valid` rather
        than field by field (the Truth's own rules run on it as they would on a Truth)."""
        return type(self.base).batch(self.base, **self._changes(values))

    def cross_valid(self, theta: np.ndarray) -> np.ndarray:
        """Mask of rows that pass the Truth's cross-field rules (all True without rules)."""
        theta = np.atleast_2d(theta)
        if not self.full:
            return np.ones(theta.shape[0], dtype=bool)
        varying = range(len(self.params)) if self.varying is None else self.varying
        if self.check_reads is not None and not any(self.params[i].field in self.check_reads
                                                    for i in varying):
            return np.repeat(self._row_ok(theta[0]), theta.shape[0])
        ok = np.empty(theta.shape[0], dtype=bool)
        for j, row in enumerate(theta):
            ok[j] = self._row_ok(row)
        return ok

    def _row_ok(self, row) -> bool:
        p = Problems("truth")
        try:
            self._assign([float(v) for v in row])._check(p)
        except DOMAIN_ERRORS:
            return False
        return not p

    def make(self, row):
        """The Truth of one row, validated; None when it is not a valid Truth."""
        row = np.asarray(row, dtype=float)
        if not (self.valid(row[None])[0] and self.cross_valid(row[None])[0]):
            return None
        try:
            return self.checked_replace(row)
        except InvalidInput:
            return None

    def batch(self, theta: np.ndarray):
        """One Truth for all rows of `theta` (m, n_params): fields as arrays (m,)."""
        theta = np.atleast_2d(theta)
        return self._assign([theta[:, i].copy() for i in range(theta.shape[1])])

    def checked_replace(self, row):
        """The Truth of one row through ``dataclasses.replace`` (full validation)."""
        return dataclasses.replace(self.base, **self._changes([float(v) for v in row]))


class Forward:
    """Predicted readings of a procedure for parameter rows, batched where the model allows.

    Parameters
    ----------
    proc : Procedure
    setup : Setup
    readings : dict of str to array
        A batch of one; numeric arrays are the data, flattened in key order into
        :attr:`y` (readings that are NaN, e.g. columns a reduced file leaves out, are
        left out of the likelihood).
    builder : TruthBuilder
    batch : bool
        Try one forward call for all rows (array-valued truth fields).
    """

    def __init__(self, proc, setup, readings, builder: TruthBuilder, batch: bool = True):
        self.proc, self.setup, self.builder = proc, setup, builder
        self.keys, parts = [], []
        for k, v in readings.items():
            a = np.asarray(v)
            if a.dtype.kind not in "fiu":
                continue
            self.keys.append(k)
            parts.append(a.astype(float).reshape(a.shape[0], -1)[0])
        if not self.keys:
            raise InvalidInput([f"The readings of {proc.name} hold no numeric arrays."])
        self.sizes = [p.size for p in parts]
        full = np.concatenate(parts)
        self.mask = np.isfinite(full)
        self.all_used = bool(self.mask.all())
        self.y = full[self.mask]
        self.sources = proc.sources(setup)
        self.mean = {k: np.broadcast_to(np.asarray(s.distribution.mean, dtype=float),
                                        (1, *s.shape, *s.distribution.event_shape))
                     for k, s in self.sources.items()}
        self.slots: list[tuple[str, np.ndarray]] = []  # nuisance sources: (name, flat indices)
        self.batched = None if batch else False
        self.mbatched = None if batch else False
        self.measurands = tuple(proc.measurands(setup))

    @property
    def n(self) -> int:
        return int(self.y.size)

    @property
    def n_nuisance(self) -> int:
        return int(sum(idx.size for _, idx in self.slots))

    def labels(self) -> list[str]:
        """Reading array of every used reading (for messages)."""
        out = np.concatenate([np.full(s, k, dtype=object)
                              for k, s in zip(self.keys, self.sizes, strict=True)])
        return list(out[self.mask])

    # ----------------------------------------------------------------- errors
    def errors(self, m: int, nuis=None, *, copy_of=()) -> dict:
        """Every source at its mean, (m, ...) each; nuisance sources from `nuis` (m, q)."""
        out = {k: np.broadcast_to(v, (m, *v.shape[1:])) for k, v in self.mean.items()}
        col = 0
        for name, idx in self.slots:
            a = np.array(out[name]).reshape(m, -1)
            if nuis is not None:
                a[:, idx] = nuis[:, col:col + idx.size]
            col += idx.size
            out[name] = a.reshape(m, *self.mean[name].shape[1:])
        for name in copy_of:
            if name not in dict(self.slots):
                out[name] = np.array(out[name])
        return out

    def _flat(self, out, m: int) -> np.ndarray:
        parts = []
        for k, size in zip(self.keys, self.sizes, strict=True):
            a = np.asarray(out[k], dtype=float)
            if a.size != m * size:
                raise InvalidInput([
                    f"The readings {k!r} of {self.proc.name} hold {size} values but the "
                    f"set-up's forward model gives {a.size // max(m, 1)}."])
            parts.append(a.reshape(m, size))
        flat = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
        return flat if self.all_used else flat[:, self.mask]

    def at(self, truth, errors) -> np.ndarray:
        """Readings (B, n) for one Truth and error rows (B, ...) (the model's own batch)."""
        m = next(iter(errors.values())).shape[0]
        with np.errstate(all="ignore"):
            return self._flat(self.proc.forward(self.setup, truth, errors), m)

    def structure(self, truth, name: str):
        """The procedure's colouring of source `name` at `truth`
        (``Capabilities.source_structure``), on the used readings; None without one."""
        plan = self.proc.capabilities.source_structure(self.setup, truth, name)
        if plan is None:
            return None
        colours, owners = plan
        return colours, np.asarray(owners)[:, self.mask]

    # ----------------------------------------------------------------- many rows
    def _loop(self, theta, nuis):
        m = theta.shape[0]
        pred = np.zeros((m, self.n))
        ok = np.zeros(m, dtype=bool)
        errors = self.errors(m, nuis)
        for j in range(m):
            t = self.builder.make(theta[j])
            if t is None:
                continue
            try:
                pred[j] = self.at(t, {k: v[j:j + 1] for k, v in errors.items()})[0]
            except DOMAIN_ERRORS:
                continue
            ok[j] = bool(np.all(np.isfinite(pred[j])))
        return pred, ok

    def predict(self, theta, nuis=None) -> tuple[np.ndarray, np.ndarray]:
        """Readings (m, n) of rows `theta` (m, n_params) (and nuisance rows (m, q)), and the
        mask of rows the model could evaluate."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        m = theta.shape[0]
        if self.batched is False or m < 2:
            return self._loop(theta, nuis)
        try:
            pred = self.at(self.builder.batch(theta), self.errors(m, nuis))
        except Exception:  # noqa: BLE001 - a model that does not take array-valued truths
            loop, ok = self._loop(theta, nuis)
            if ok.all():
                self.batched = False
            return loop, ok
        ok = (np.all(np.isfinite(pred), axis=1) & self.builder.valid(theta)
              & self.builder.cross_valid(theta))
        if self.batched is None:
            loop, ok_loop = self._loop(theta, nuis)
            scale = 1e-12 * (float(np.max(np.abs(self.y))) + 1e-300)
            self.batched = bool(np.array_equal(ok, ok_loop) and np.allclose(
                pred[ok], loop[ok], rtol=1e-9, atol=scale))
            if not self.batched:
                return loop, ok_loop
        return pred, ok

    def jacobian(self, theta, nuis=None, steps=None, *, check: bool = True) -> np.ndarray:
        """Central-difference Jacobian (n, n_params + q) of the readings at one row.

        With `check`, a column is taken again with steps 1000 times larger; where that
        one is below a hundredth of it, the first was the model's round-off (an
        iterative solver's last digits), not an effect, and the column is 0.
        """
        theta = np.asarray(theta, dtype=float)
        q = 0 if nuis is None else len(nuis)
        p = theta.size
        h = np.concatenate([self.builder.steps(theta), np.zeros(q)]) if steps is None \
            else np.asarray(steps, dtype=float)
        x = np.concatenate([theta, np.zeros(q) if nuis is None else nuis])
        lo = np.concatenate([self.builder.low, np.full(q, -np.inf)]) + 1.01 * h
        hi = np.concatenate([self.builder.high, np.full(q, np.inf)]) - 1.01 * h
        x = np.where(lo <= hi, np.clip(x, lo, hi), x)  # at a bound: the pair moves inside
        pts = np.repeat(x[None], 2 * (p + q), axis=0)
        i = np.arange(p + q)
        pts[i, i] += h
        pts[p + q + i, i] -= h
        pred, ok = self.predict(pts[:, :p], pts[:, p:] if q else None)
        if not ok.all():
            raise InvalidInput([f"The forward model of {self.proc.name} fails next to the "
                                "least-squares estimate; check the readings and the set-up."])
        jac = ((pred[:p + q] - pred[p + q:]) / (2 * h[:, None])).T
        if check:
            try:
                wide = self.jacobian(theta, nuis, 1000.0 * h, check=False)
            except InvalidInput:  # the wider steps leave the model's domain: no check
                return jac
            noise = np.linalg.norm(wide, axis=0) < 0.01 * np.linalg.norm(jac, axis=0)
            jac[:, noise] = 0.0
        return jac

    # ----------------------------------------------------------------- measurands
    def _measurands_loop(self, theta) -> np.ndarray:
        out = np.empty((theta.shape[0], len(self.measurands)))
        for j, row in enumerate(theta):
            t = self.builder.make(row)
            if t is None:  # pragma: no cover - rows come from the chains, all valid
                t = self.builder._assign([float(v) for v in row])
            tv = self.proc.true_values(self.setup, t)
            out[j] = [float(tv[m.name]) * m.scale for m in self.measurands]
        return out

    def measurand_values(self, theta) -> np.ndarray:
        """Measurands [display units] of rows `theta` (m, n_params): array (m, n_measurands)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        uniq, inverse = np.unique(theta, axis=0, return_inverse=True)
        inverse = np.asarray(inverse).reshape(-1)
        m = uniq.shape[0]
        if self.mbatched is not False and m >= 2:
            try:
                tv = self.proc.true_values(self.setup, self.builder.batch(uniq))
                out = np.column_stack([np.broadcast_to(np.asarray(tv[x.name], dtype=float),
                                                       (m,)) * x.scale for x in self.measurands])
            except Exception:  # noqa: BLE001 - true_values that do not take array truths
                self.mbatched, out = False, None
            if out is not None and self.mbatched is None:
                few = min(m, 8)
                self.mbatched = bool(np.allclose(out[:few], self._measurands_loop(uniq[:few]),
                                                 rtol=1e-9, atol=1e-12))
            if self.mbatched:
                return out[inverse]
        return self._measurands_loop(uniq)[inverse]

    def measurand_gradient(self, theta) -> np.ndarray:
        """Central-difference gradient (n_measurands, n_params) of the measurands [display]."""
        theta = np.asarray(theta, dtype=float)
        p = theta.size
        h = self.builder.steps(theta)
        pts = np.repeat(theta[None], 2 * p, axis=0)
        i = np.arange(p)
        pts[i, i] += h
        pts[p + i, i] -= h
        vals = self.measurand_values(pts)
        return ((vals[:p] - vals[p:]) / (2 * h[:, None])).T
