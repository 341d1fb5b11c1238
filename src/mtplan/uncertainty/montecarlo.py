"""Monte Carlo propagation of distributions after JCGM 101:2008 (GUM Supplement 1).

The engine runs trials in fixed-size blocks. Block ``i`` draws from stream ``i`` of
the random seed's ``SeedSequence`` (see :mod:`mtplan.uncertainty.streams`), blocks are
joined in block order, so the same seed gives bit-identical results for any
``n_jobs`` and any joblib backend. Memory is bounded by the block size: the first
``keep`` values of every output are kept exactly; beyond that each output switches
to a fine histogram (2**18 bins over a range fixed by the kept values, exact values
kept outside it), whose coverage-interval end points are exact to a
small fraction of a bin.

Two ways to stop:

- ``trials=M``: exactly M trials.
- ``digits=d``: the adaptive procedure of JCGM 101 7.9. Blocks of
  ``max(100/(1-p), 10**4)`` trials run until twice the standard deviation of the
  block values of the estimate, of the standard uncertainty and of both interval
  end points is at most the numerical tolerance of u at ``d`` significant digits.
  The tolerance is taken at ``u - max(2 s_u, 10**-d u)`` (the low end of u's own
  spread, never narrower than one unit in u's last requested digit, since s_u from
  the first few blocks is unreliable), so that a u sitting just above a power of ten
  cannot stop the run with a tolerance ten times too coarse (the trap of 7.9.2
  when u crosses a power of ten).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from mtplan.uncertainty.coverage import K
from mtplan._parallel import effective_jobs, one_blas_thread, ordered_map, parallel_session
from mtplan._validate import InvalidInput, Problems
from mtplan.uncertainty.distributions import Distribution
from mtplan.uncertainty.options import INTERVALS, MAX_TRIALS, RunOptions, check_run_options
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence, named_generator

__all__ = ["MCResult", "ModelError", "propagate", "run_blocks", "numerical_tolerance",
           "coverage_interval", "RunOptions", "INTERVALS", "MAX_TRIALS"]

_HIST_BINS = 2**18


class ModelError(ValueError):
    """The model returned something the engine cannot use (wrong shape, non-finite values)."""


# --------------------------------------------------------------------------- intervals
def _jcgm_indices(m: int, p: float) -> tuple[int, int]:
    """(q, r): JCGM 101 7.7 index counts for M values and coverage probability p (1-based r)."""
    pm = p * m
    q = int(pm) if float(pm).is_integer() else int(pm + 0.5)
    q = min(max(q, 1), m - 1) if m > 1 else 0
    half = (m - q) / 2
    r = int(half) if float(half).is_integer() else int((m - q + 1) / 2)
    return q, max(r, 1)


def coverage_interval(values: np.ndarray, p: float = 0.95, kind: str = "symmetric"):
    """Coverage interval of a sample after JCGM 101 7.7.

    Parameters
    ----------
    values : array of shape (M,)
        Model values.
    p : float
        Coverage probability.
    kind : {"symmetric", "shortest"}
        Probabilistically symmetric (7.7.1) or shortest (7.7.2) interval.

    Returns
    -------
    (low, high) : tuple of float
    """
    x = np.asarray(values, dtype=float).ravel()
    m = x.size
    if m < 2:
        return (float(x[0]), float(x[0])) if m else (math.nan, math.nan)
    q, r = _jcgm_indices(m, p)
    if kind == "symmetric":
        lo, hi = r - 1, r + q - 1
        part = np.partition(x, (lo, hi))
        return float(part[lo]), float(part[hi])
    s = np.sort(x)
    widths = s[q:] - s[: m - q]
    j = int(np.argmin(widths))
    return float(s[j]), float(s[j + q])


class _Store:
    """Values of one output: exact up to `keep` values, a histogram beyond."""

    def __init__(self, keep: int):
        self.keep = keep
        self.chunks: list[np.ndarray] = []
        self.n = 0
        self.hist = None

    def add(self, x: np.ndarray) -> None:
        self.n += x.size
        if self.hist is None:
            self.chunks.append(x)
            if self.n > self.keep:
                self._to_histogram()
        else:
            self._bin(x)

    def _to_histogram(self) -> None:
        x = np.concatenate(self.chunks)
        lo, hi = float(x.min()), float(x.max())
        span = hi - lo or max(abs(lo), 1.0) * 1e-12
        self.edges = (lo - span, hi + span)
        self.hist = np.zeros(_HIST_BINS, dtype=np.int64)
        self.under: list[np.ndarray] = []
        self.over: list[np.ndarray] = []
        self.chunks = []
        self._bin(x)

    def _bin(self, x: np.ndarray) -> None:
        a, b = self.edges
        inside = (x >= a) & (x < b)
        if not inside.all():
            self.under.append(x[x < a])
            self.over.append(x[x >= b])
            x = x[inside]
        idx = ((x - a) * (_HIST_BINS / (b - a))).astype(np.int64)
        np.clip(idx, 0, _HIST_BINS - 1, out=idx)
        self.hist += np.bincount(idx, minlength=_HIST_BINS)

    @property
    def exact(self) -> bool:
        return self.hist is None

    def values(self) -> np.ndarray | None:
        if not self.exact:
            return None
        if len(self.chunks) > 1:
            self.chunks = [np.concatenate(self.chunks)]
        return self.chunks[0] if self.chunks else np.empty(0)

    def interval(self, p: float, kind: str) -> tuple[float, float]:
        if self.exact:
            return coverage_interval(self.values(), p, kind)
        return self._hist_interval(p, kind)

    def cdf(self) -> tuple[np.ndarray, np.ndarray]:
        """(xs, F): the cumulative distribution of a histogram store on its grid (exact
        tails, the bins' edges in between)."""
        under = np.sort(np.concatenate(self.under)) if self.under else np.empty(0)
        over = np.sort(np.concatenate(self.over)) if self.over else np.empty(0)
        a, b = self.edges
        edges = np.linspace(a, b, _HIST_BINS + 1)
        xs = np.concatenate([under, edges, over])
        cum_bins = np.concatenate([[0], np.cumsum(self.hist)]) + under.size
        cdf = np.concatenate(
            [np.arange(1, under.size + 1), cum_bins, cum_bins[-1] + np.arange(1, over.size + 1)]
        ).astype(float)
        return xs, cdf / self.n

    def _hist_interval(self, p, kind):
        # cumulative distribution on a grid: exact tails, histogram bins in between
        xs, cdf = self.cdf()
        # make xs strictly usable for interpolation of the inverse CDF
        def inv(prob):
            return np.interp(prob, cdf, xs)

        if kind == "symmetric":
            return float(inv((1 - p) / 2)), float(inv((1 + p) / 2))
        starts = np.linspace(0, 1 - p, 4097)
        lows, highs = inv(starts), inv(starts + p)
        j = int(np.argmin(highs - lows))
        return float(lows[j]), float(highs[j])


# --------------------------------------------------------------------------- results
@dataclass
class MCResult:
    """Result of a Monte Carlo propagation.

    Attributes
    ----------
    names : tuple of str
        Output names, in the model's order.
    mean, std, low, high : arrays of shape (n_outputs,)
        Estimate, standard uncertainty and coverage-interval end points per output.
    cov : array of shape (n_outputs, n_outputs)
        Covariance matrix of the outputs.
    trials : int
        Number of Monte Carlo trials used.
    coverage : float
        Coverage probability of the intervals.
    interval : str
        ``"symmetric"`` or ``"shortest"``.
    seed : int or sequence of int
        Entropy of the root ``SeedSequence``: pass it back as ``rng`` to repeat the run.
    block_size, blocks : int
        Size and number of blocks.
    digits : int or None
        Significant digits of the adaptive procedure (None for a fixed trial count).
    converged : bool
        Always True for a fixed trial count; for the adaptive procedure, whether the
        stopping rule was met before ``max_trials``.
    block_stats : dict or None
        For the adaptive procedure, arrays of shape (blocks, n_outputs) of the block
        values of ``mean``, ``std``, ``low`` and ``high``.

    :meth:`fraction_within` gives the fraction of an output's values in any interval, and
    :meth:`U_coverage` that of ``mean ± k std`` (the coverage of U = k u,
    :mod:`mtplan.uncertainty.coverage`), from the kept values or, beyond ``keep``, from the
    histogram's cumulative distribution.
    """

    names: tuple
    mean: np.ndarray
    std: np.ndarray
    low: np.ndarray
    high: np.ndarray
    cov: np.ndarray
    trials: int
    coverage: float
    interval: str
    seed: object
    block_size: int
    blocks: int
    digits: int | None = None
    converged: bool = True
    block_stats: dict | None = None
    _samples: dict = field(default_factory=dict, repr=False)
    #: {name: (xs, F)}: the cumulative distribution of an output kept as a histogram
    _cdfs: dict = field(default_factory=dict, repr=False)

    def summary(self):
        """A pandas DataFrame indexed by output name: mean, std, low, high, trials."""
        import pandas as pd

        return pd.DataFrame(
            {
                "mean": self.mean,
                "std": self.std,
                "low": self.low,
                "high": self.high,
                "trials": np.full(len(self.names), self.trials, dtype=np.int64),
            },
            index=pd.Index(self.names, name="output"),
        )

    def index(self, name: str) -> int:
        """Position of output `name`."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"No output named {name!r}; outputs are {', '.join(self.names)}") from None

    def samples(self, name: str) -> np.ndarray | None:
        """The kept model values of output `name` (None when only a histogram was kept)."""
        return self._samples.get(name)

    def fraction_within(self, name: str, low, high) -> np.ndarray:
        """The fraction of output `name`'s values within ``[low, high]`` (arrays broadcast:
        several intervals at once); NaN where an end is not finite."""
        low, high = np.broadcast_arrays(np.asarray(low, dtype=float),
                                        np.asarray(high, dtype=float))
        x = self.samples(name)
        if x is not None:
            inside = (x[:, None] >= low.ravel()) & (x[:, None] <= high.ravel())
            out = inside.mean(axis=0).reshape(low.shape) if x.size else np.full(low.shape,
                                                                                   np.nan)
        else:
            xs, cdf = self._cdfs[name]
            out = np.interp(high, xs, cdf) - np.interp(low, xs, cdf, left=0.0)
        return np.where(np.isfinite(low) & np.isfinite(high), out, np.nan)[()]

    def U_coverage(self, k: float | None = None) -> np.ndarray:  # noqa: N802 - U of the GUM
        """(n_outputs,): the fraction of each output's values within ``mean ± k std``: the
        coverage that U = k u really has (k default: :data:`mtplan.uncertainty.coverage.K`)."""
        k = K if k is None else k
        return np.array([float(self.fraction_within(n, m - k * s, m + k * s))
                         for n, m, s in zip(self.names, self.mean, self.std, strict=True)])

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix of the outputs."""
        s = np.sqrt(np.diag(self.cov))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.cov / np.outer(s, s)


def numerical_tolerance(u: float, digits: int) -> float:
    """JCGM 101 7.9.2: half a unit in the last of `digits` significant digits of `u`."""
    if not (u > 0 and math.isfinite(u)):
        return 0.0
    exponent = math.floor(math.log10(u)) - digits + 1
    # guard against log10 rounding just below a power of ten
    if u >= 10 ** (exponent + digits):
        exponent += 1
    return 0.5 * 10.0**exponent


# --------------------------------------------------------------------------- engine
class _Accumulator:
    """Merges blocks in order: exact mean and covariance (Chan et al.), value stores."""

    def __init__(self, names, keep):
        self.names = names
        k = len(names)
        self.n = 0
        self.mean = np.zeros(k)
        self.comoment = np.zeros((k, k))
        self.stores = [_Store(keep) for _ in names]

    def add(self, x: np.ndarray) -> None:  # x of shape (m, k)
        m = x.shape[0]
        mb = x.mean(axis=0)
        d = x - mb
        cb = d.T @ d
        n = self.n + m
        delta = mb - self.mean
        self.mean = self.mean + delta * (m / n)
        self.comoment = self.comoment + cb + np.outer(delta, delta) * (self.n * m / n)
        self.n = n
        for j, store in enumerate(self.stores):
            store.add(np.ascontiguousarray(x[:, j]))

    def cov(self):
        return self.comoment / max(self.n - 1, 1)


def _cached_blocks(block_fn, block_args, root, sizes, cache, *, n_jobs, backend):
    """The outputs of blocks ``0 .. len(sizes) - 1`` in order: those in `cache` (keyed by
    ``(index, size)``) as they are, the others run (in parallel as :func:`ordered_map`
    runs them) and put there."""
    todo = [(i, n) for i, n in enumerate(sizes) if (i, n) not in cache]
    tasks = ((*block_args, root, i, n) for i, n in todo)
    for key, out in zip(todo, ordered_map(block_fn, tasks, n_jobs=n_jobs, backend=backend),
                        strict=True):
        cache[key] = out
    return (cache[(i, n)] for i, n in enumerate(sizes))


def _block_summary(x: np.ndarray, p: float, kind: str) -> np.ndarray:
    """(4, k): mean, std, low, high of one block."""
    k = x.shape[1]
    out = np.empty((4, k))
    out[0] = x.mean(axis=0)
    out[1] = x.std(axis=0, ddof=1)
    for j in range(k):
        out[2, j], out[3, j] = coverage_interval(x[:, j], p, kind)
    return out


def _stable(stats: list[np.ndarray], u_all: np.ndarray, digits: int) -> bool:
    arr = np.stack(stats)  # (h, 4, k)
    h = arr.shape[0]
    s = arr.std(axis=0, ddof=1) / math.sqrt(h)  # (4, k): std of the block average
    for j, u in enumerate(u_all):
        if u == 0 and not s[:, j].any():
            continue
        # Power-of-ten trap: take the tolerance at the low end of u's plausible range.
        # 2 s_u alone is not enough: from 2 or 3 blocks s_u can be far too small, so
        # the range is at least one unit in u's last requested digit (relative 10^-d).
        u_low = u - max(2 * s[1, j], u * 10.0 ** (-digits))
        tol = numerical_tolerance(u_low if u_low > 0 else u / 10, digits)
        if np.any(2 * s[:, j] > tol):
            return False
    return True


def run_blocks(
    block_fn: Callable[[int, int], dict],
    block_args: tuple,
    options: RunOptions,
    *,
    label: str = "Monte Carlo",
    cache: dict | None = None,
) -> MCResult:
    """Run ``block_fn(*block_args, root, index, size)`` over blocks and join the results.

    `block_fn` must return a dict of output name -> array of shape (size,), the
    same names in the same order for every block. This is the one driver behind
    :func:`propagate` and the procedures' Monte Carlo, run as `options` say (checked by the
    caller; ``options.rng`` is made the root ``SeedSequence`` once, here; ``max_trials``
    None is 10**8, ``block_size`` None the default below).

    `cache` (a fixed trial count only): a dict the caller keeps between runs of the same
    `block_fn`, `block_args` and `root`, keyed by ``(index, size)``. A block found there
    is not run again, and each block run is put there: a run of more trials in blocks of
    the same size repeats none of a shorter run's work, and gives exactly what it gives
    without the cache (block i draws from stream i whoever computed it).
    """
    root = as_seed_sequence(options.rng)
    trials, digits, p, interval = options.trials, options.digits, options.coverage, options.interval
    n_jobs, backend, block_size = options.n_jobs, options.backend, options.block_size
    max_trials = 10**8 if options.max_trials is None else options.max_trials
    adaptive = digits is not None
    if block_size is None:
        # JCGM 101 7.9.2 for the adaptive procedure; larger blocks for a fixed count
        # (fewer Python round trips; memory is still bounded by the block)
        block_size = max(math.ceil(100 / (1 - p)), 10_000 if adaptive else 100_000)
    if adaptive:
        n_blocks_max = max(math.ceil(max_trials / block_size), 2)
    else:
        n_blocks_max = math.ceil(trials / block_size)

    def sizes(i):
        if adaptive:
            return block_size
        return min(block_size, trials - i * block_size)

    bar = _progress(options.progress, None if adaptive else trials, label)
    acc = None
    names = None
    stats: list[np.ndarray] = []
    converged = not adaptive
    jobs = max(effective_jobs(n_jobs), 1)
    # Blocks do many small matrix products: BLAS threads only fight each other (and the
    # workers) over the cores, so each block runs single-threaded, as joblib's workers do.
    with one_blas_thread(), \
            parallel_session(n_jobs, backend, options.scheduler) as session:
        chunk = jobs if adaptive else None
        # a fixed count in one block runs here: a worker would only add its start and the
        # pickling of the model (the block draws the same numbers wherever it runs)
        here = n_blocks_max == 1 and not adaptive and backend != "dask"
        workers = 1 if here else session["n_jobs"]
        if cache is None or adaptive:
            tasks = ((*block_args, root, i, sizes(i)) for i in range(n_blocks_max))
            outs = ordered_map(block_fn, tasks, n_jobs=workers, backend=backend, chunk=chunk)
        else:
            outs = _cached_blocks(block_fn, block_args, root, [sizes(i) for i in
                                                              range(n_blocks_max)],
                                  cache, n_jobs=workers, backend=backend)
        for i, out in enumerate(outs):
            if names is None:
                names = tuple(out)
                acc = _Accumulator(names, options.keep)
            elif tuple(out) != names:
                raise ModelError(f"Block {i} returned outputs {tuple(out)}, expected {names}.")
            x = np.column_stack([out[n] for n in names])
            bad = ~np.isfinite(x)
            if bad.any():
                cols = [names[j] for j in np.flatnonzero(bad.any(axis=0))]
                raise ModelError(
                    f"The model returned {int(bad.sum())} non-finite values in block {i} "
                    f"(outputs: {', '.join(cols)}); every trial must give a finite value."
                )
            acc.add(x)
            if bar is not None:
                bar.update(x.shape[0])
            if adaptive:
                stats.append(_block_summary(x, p, interval))
                if len(stats) >= 2 and _stable(stats, np.sqrt(np.diag(acc.cov())), digits):
                    converged = True
                    break
    if bar is not None:
        bar.close()

    cov = acc.cov()
    lows, highs = zip(*(s.interval(p, interval) for s in acc.stores), strict=True)
    samples = {n: s.values() for n, s in zip(names, acc.stores, strict=True) if s.exact}
    cdfs = {n: s.cdf() for n, s in zip(names, acc.stores, strict=True) if not s.exact}
    arr = np.stack(stats) if stats else None
    return MCResult(
        names=names,
        mean=acc.mean.copy(),
        std=np.sqrt(np.diag(cov)),
        low=np.array(lows),
        high=np.array(highs),
        cov=cov,
        trials=acc.n,
        coverage=p,
        interval=interval,
        seed=root.entropy,
        block_size=block_size,
        blocks=len(stats) if adaptive else n_blocks_max,
        digits=digits,
        converged=converged,
        block_stats=None
        if arr is None
        else {k: arr[:, j] for j, k in enumerate(("mean", "std", "low", "high"))},
        _samples=samples,
        _cdfs=cdfs,
    )


class _CallbackBar:
    """A progress bar that calls ``callback(done, total)`` after each block (total None:
    adaptive); what a caller that shows its own progress (the explore page) passes."""

    def __init__(self, callback, total):
        self.callback, self.total, self.done = callback, total, 0

    def update(self, n):
        self.done += int(n)
        self.callback(self.done, self.total)

    def close(self):
        pass


def _progress(progress, total, label):
    if progress is False or (progress is None and not sys.stderr.isatty()):
        return None  # no bar: tqdm (a quarter second of imports) is not loaded
    if callable(progress):
        return _CallbackBar(progress, total)
    try:
        from tqdm.auto import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=total, desc=label, unit="trial", unit_scale=True, delay=1.0,
                file=sys.stderr, leave=False)


# --------------------------------------------------------------------------- propagate
def as_outputs(out, size: int) -> dict:
    if isinstance(out, Mapping):
        items = list(out.items())
    else:
        items = [("y", out)]
    result = {}
    for name, value in items:
        a = np.asarray(value, dtype=float)
        if a.ndim == 0:
            a = np.broadcast_to(a, (size,))
        if a.shape[0] != size or a.ndim > 2:
            raise ModelError(
                f"The model's output {name!r} has shape {a.shape}; expected ({size},) or "
                f"({size}, k): one value (or one vector) per trial."
            )
        if a.ndim == 2:
            for j in range(a.shape[1]):
                result[f"{name}[{j}]"] = a[:, j]
        else:
            result[str(name)] = a
    return result


def _propagate_block(model, inputs, root, index, size):
    seq = block_sequence(root, index)
    values = {name: dist.draw(named_generator(seq, name), size) for name, dist in inputs.items()}
    return as_outputs(model(**values), size)


def check_inputs(p: Problems, model, inputs) -> None:
    """Record problems with a model and its named input distributions."""
    p.require(callable(model), "model", model, "a callable taking the inputs as keyword arrays")
    if not isinstance(inputs, Mapping) or not inputs:
        p.add("inputs", inputs, "a non-empty mapping of names to distributions")
        return
    for name, dist in inputs.items():
        if not isinstance(name, str) or not name.isidentifier():
            p.add("inputs", name, "keyed by names that are Python identifiers")
        if not isinstance(dist, Distribution):
            p.add(f"inputs[{name!r}]", dist, "an mtplan.uncertainty distribution")


def propagate(
    model: Callable,
    inputs: Mapping[str, Distribution],
    *,
    options: RunOptions | None = None,
    **option_overrides,
) -> MCResult:
    """Propagate distributions through a vectorised model by Monte Carlo (JCGM 101).

    Parameters
    ----------
    model : callable
        ``model(**inputs)`` takes one array of shape (M,) per input (shape (M, n) for a
        vector input) and returns an array of shape (M,) or (M, k), or a dict of such
        arrays keyed by output name.
    inputs : mapping of str to Distribution
        The input quantities.
    options : RunOptions, optional
        How the run is made (:class:`~mtplan.uncertainty.options.RunOptions`: trials or
        digits, coverage, interval, rng, n_jobs, backend, scheduler, block_size,
        max_trials, progress, keep). Any of its fields may be given as a keyword instead
        (``trials=10**5, rng=1``), which replaces the field of `options`. Here the
        defaults are 10**6 trials when `digits` is not given; blocks of
        ``max(100/(1-p), 10**4)`` trials for the adaptive procedure (JCGM 101 7.9.2) and
        ``10**5`` for a fixed number; at most 10**8 trials (``converged`` is False if
        reached). The same seed gives bit-identical results for any `n_jobs` and backend.

    Returns
    -------
    MCResult
    """
    options = RunOptions.of(options, **option_overrides)
    p = Problems("propagate")
    check_inputs(p, model, inputs)
    options.check(p)
    p.raise_if_any()
    return run_blocks(_propagate_block, (model, dict(inputs)), options.fixed(10**6),
                      label="propagate")


__all__ += ["check_run_options", "check_inputs", "InvalidInput"]
