"""How a Monte Carlo run is made: one record, passed down the layers unchanged.

:class:`RunOptions` holds what every Monte Carlo entry point shares (how many trials or
how many stable digits, the coverage probability and interval, the seed, the workers and
the block size, the progress display). The engine (:func:`~mtplan.uncertainty.propagate`,
:func:`~mtplan.uncertainty.montecarlo.run_blocks`), a procedure's Monte Carlo
(:func:`mtplan.evaluation.simulate_uncertainty`), the sweeps and the command line take the
record instead of restating a dozen parameters at every layer. For convenience every
entry point also takes the fields as keywords (``simulate_uncertainty("rotary_axis",
trials=1500, rng=4)``), which :meth:`RunOptions.of` folds into the record.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from mtplan._parallel import check_parallel
from mtplan._validate import Problems

__all__ = ["RunOptions", "Options", "INTERVALS", "MAX_TRIALS", "check_run_options"]

INTERVALS = ("symmetric", "shortest")
#: the most trials one run may ask for: 10**9 trials of a procedure take hours to days;
#: ``digits`` stops as soon as the result is stable
MAX_TRIALS = 10**9


class Options:
    """What an options record (a frozen dataclass) shares: made from another with keyword
    changes (:meth:`of`, :meth:`replace`), an unknown name refused naming the fields."""

    #: what the record's fields are called in a message
    WHAT = "option"

    @classmethod
    def of(cls, options=None, /, **overrides):
        """`options` (default: the defaults) with the named fields replaced.

        Raises
        ------
        TypeError
            For `options` of another type, or a keyword that names no field.
        """
        if options is None:
            options = cls()
        elif not isinstance(options, cls):
            raise TypeError(f"The 'options' parameter must be a {cls.__name__}. Got "
                            f"{type(options).__name__} instead.")
        if not overrides:
            return options
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = [k for k in overrides if k not in names]
        if unknown:
            raise TypeError(f"Unknown {cls.WHAT}(s) {', '.join(map(repr, unknown))}; the "
                            f"{cls.WHAT}s are: {', '.join(sorted(names))}.")
        return dataclasses.replace(options, **overrides)

    def replace(self, **changes):
        """A copy with the named fields changed."""
        return type(self).of(self, **changes)


@dataclass(frozen=True)
class RunOptions(Options):
    """The options of one Monte Carlo run (frozen: change one with :meth:`replace`).

    Attributes
    ----------
    trials : int, optional
        A fixed number of trials (None: the entry point's default, unless `digits`).
    digits : int, optional
        Run the adaptive procedure of JCGM 101 7.9 to this many significant digits.
    coverage : float
        Coverage probability of the intervals.
    interval : {"symmetric", "shortest"}
        Probabilistically symmetric or shortest coverage interval.
    rng : None, int, SeedSequence or Generator
        The seed (SPEC 7). The same seed gives the same result for any `n_jobs` and
        `backend`.
    n_jobs : int
        Worker count (joblib's convention; -1 uses every core).
    backend : {"loky", "threading", "multiprocessing", "dask", "sequential"}, optional
        joblib backend; "dask" runs on `scheduler` or on a local Dask cluster.
    scheduler : str, optional
        Address of a Dask scheduler for ``backend="dask"``.
    block_size : int, optional
        Trials per block (None: the entry point's default).
    max_trials : int, optional
        Upper limit of the adaptive procedure (None: the entry point's default).
    progress : bool or callable, optional
        Progress bar on stderr (None: when stderr is a terminal); a callable is called as
        ``progress(done, total)`` after each block.
    keep : int
        Model values kept exactly per output; beyond that each output is kept as a fine
        histogram, so memory stays bounded by `keep` and the block size.
    """

    trials: int | None = None
    digits: int | None = None
    coverage: float = 0.95
    interval: str = "symmetric"
    rng: object = None
    n_jobs: int = 1
    backend: str | None = None
    scheduler: str | None = None
    block_size: int | None = None
    max_trials: int | None = None
    progress: object = None
    keep: int = 2 * 10**6

    WHAT = "run option"

    def fixed(self, trials: int) -> RunOptions:
        """These options with `trials` filled in where neither trials nor digits is given."""
        if self.trials is None and self.digits is None:
            return dataclasses.replace(self, trials=trials)
        return self

    def check(self, problems: Problems, *, parallel: bool = True) -> None:
        """Record every problem of these options (`parallel`: of the workers too)."""
        check_run_options(problems, self.trials, self.digits, self.coverage, self.interval,
                          self.max_trials, self.block_size)
        problems.number("keep", self.keep, integer=True, low=1)
        if parallel:
            check_parallel(problems, self.n_jobs, self.backend, self.scheduler)


def check_run_options(p: Problems, trials, digits, coverage, interval, max_trials=None,
                      block_size=None):
    """Record problems with the common Monte Carlo options."""
    if trials is not None and digits is not None:
        p.add_text("Give either 'trials' or 'digits', not both")
    if trials is not None:
        p.number("trials", trials, integer=True, low=2, high=MAX_TRIALS)
    if digits is not None:
        p.number("digits", digits, integer=True, low=1, high=6)
    p.number("coverage", coverage, low=0, high=1, low_open=True, high_open=True)
    p.choice("interval", interval, INTERVALS)
    if max_trials is not None:
        p.number("max_trials", max_trials, integer=True, low=2)
    if block_size is not None:
        p.number("block_size", block_size, integer=True, low=2)
