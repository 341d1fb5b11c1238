"""Posterior of a procedure's measurands from measured readings, sampled with emcee.

The likelihood is Gaussian on the readings' residuals from the forward model::

    r = readings - forward(setup, truth(theta), errors = 0)
    log L = sum over reading arrays k of  -1/2 sum (r_k / sigma_k)**2 - n_k log sigma_k - n_k/2 log 2 pi

The free parameters ``theta`` are Truth fields (``procedure.posterior_fields``, or
every float field of the Truth); the measurands follow from
``procedure.true_values(setup, truth(theta))``. The readings' noise ``sigma_k`` is
known (a number, or the spread of ``procedure.noise_source`` in the set-up) or a
free parameter per reading array with a log-uniform (Jeffreys) prior.

Default priors are weak and stated in :attr:`PosteriorResult.priors`: for each Truth
field a normal centred at the least-squares estimate with a standard deviation
1000 times its least-squares standard error (it moves the posterior standard
deviation by less than 1e-6 relative in the linear-Gaussian case), cut to the
field's allowed range; for each free noise a log-uniform prior over a factor 1000
either side of the residuals' RMS at the least-squares fit.

The sampler is emcee's affine-invariant ensemble sampler, done properly:

- seeded: every ensemble gets its own ``SeedSequence`` child and an emcee ``State``
  carrying a seeded ``RandomState`` (emcee would otherwise copy numpy's global
  state); numpy's global random state is neither read for the draws nor changed;
- the log-probability is vectorised (``vectorize=True``): one call evaluates all
  the walkers of a half-ensemble; forward models are batch-first over trials with
  one truth, so each walker's truth is run as a batch of one;
- walkers (at least 2 x ndim, default max(16, 4 ndim)) start in a small ball (0.1
  least-squares standard errors) around the least-squares estimate;
- several independent ensembles run until every ensemble's chain is longer than
  ``n_tau`` (50) integrated autocorrelation times, tau has settled (relative change
  below ``tau_rtol`` between checks) and the split R-hat over ensembles is below
  ``rhat_max``; burn-in of ``burn_tau`` (3) tau is discarded and the rest thinned
  by tau/2;
- when the step budget runs out first, :class:`NotConvergedError` carries the
  partial result (``allow_unconverged=True`` downgrades it to a warning and flags
  the result), never a silent number.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.uncertainty._random import as_seed_sequence
from mtplan.uncertainty.sampler import (
    NotConvergedError,
    UnconvergedWarning,
    integrated_time,
    run_ensembles,
    split_rhat,
    stderr_progress,
)

__all__ = [
    "PosteriorResult",
    "NotConvergedError",
    "UnconvergedWarning",
    "sample_posterior",
    "split_rhat",
]

_LOG_2PI = math.log(2 * math.pi)
PRIOR_WIDTH = 1000.0  # default prior std in least-squares standard errors
NOISE_RANGE = 1000.0  # log-uniform noise prior: this factor either side of the start


def _natural(chains: np.ndarray, nf: int) -> np.ndarray:
    """Chains in the parameters' own units: the noise is sampled as log sigma."""
    out = chains.copy()
    out[..., nf:] = np.exp(out[..., nf:])
    return out


# --------------------------------------------------------------------------- result
@dataclass
class PosteriorResult:
    """Posterior of a procedure's measurands and free parameters.

    Attributes
    ----------
    procedure : str
    setup : the procedure's Setup
    measurands : tuple of Measurand
    parameters : tuple of str
        Free parameters: Truth fields (in the unit their name states) and, when the
        noise is free, ``sigma_<reading>`` (in the reading's unit).
    samples : dict of str to array (n_samples,)
        Kept samples (burn-in discarded, thinned, ensembles pooled) of every
        measurand [display unit] and parameter.
    mean, std, low, high : dict of str to float
        Posterior mean, standard deviation and equal-tailed credible interval at
        ``coverage``, by measurand and parameter name.
    coverage : float
    tau : dict of str to float
        Integrated autocorrelation time [steps], the largest over ensembles.
    rhat : dict of str to float
        Split R-hat over the ensembles.
    ess : dict of str to float
        Effective sample size (kept draws over tau, summed over ensembles).
    acceptance : array (n_ensembles,)
        Mean acceptance fraction of each ensemble.
    converged : bool
    chains : array (n_ensembles, n_steps, n_walkers, n_params)
        Every step of every walker, burn-in included (trace plots).
    log_prob : array (n_ensembles, n_steps, n_walkers)
    discard, thin : int
        Burn-in steps discarded and thinning applied to obtain `samples`.
    start : dict of str to float
        The least-squares estimate the walkers started around.
    priors : dict of str to str
        The prior of every parameter, in words.
    noise : dict of str to float or None
        Known noise per reading array [its unit], None where free.
    seed : int or list
        Entropy of the root seed (the run is repeatable from it).
    wall_s : float
    notes : list of str
    """

    procedure: str
    setup: object
    measurands: tuple
    parameters: tuple
    samples: dict
    mean: dict
    std: dict
    low: dict
    high: dict
    coverage: float
    tau: dict
    rhat: dict
    ess: dict
    acceptance: np.ndarray
    converged: bool
    chains: np.ndarray
    log_prob: np.ndarray
    discard: int
    thin: int
    start: dict
    priors: dict
    noise: dict
    seed: object
    n_walkers: int
    n_steps: int
    wall_s: float
    notes: list = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        """Measurand names, then parameter names."""
        return [m.name for m in self.measurands] + list(self.parameters)

    def units(self) -> dict:
        """Unit of every measurand and parameter."""
        from mtplan.models._protocol import UNIT_SUFFIXES

        out = {m.name: m.unit for m in self.measurands}
        for p in self.parameters:
            out[p] = next((s for s in sorted(UNIT_SUFFIXES, key=len, reverse=True)
                           if p.endswith("_" + s)), "")
        return out

    def summary(self):
        """DataFrame indexed by name: kind, unit, mean, std, low, high, tau, rhat, ess."""
        import pandas as pd

        units = self.units()
        kinds = {m.name: "measurand" for m in self.measurands}
        rows = []
        for name in self.names:
            rows.append({
                "name": name,
                "kind": kinds.get(name, "parameter"),
                "unit": units[name],
                "mean": self.mean[name],
                "std": self.std[name],
                "low": self.low[name],
                "high": self.high[name],
                "tau": self.tau.get(name, math.nan),
                "rhat": self.rhat[name],
                "ess": self.ess[name],
            })
        return pd.DataFrame(rows).set_index("name")

    def frame(self):
        """Kept samples as a DataFrame (one column per measurand and parameter): corner plots."""
        import pandas as pd

        return pd.DataFrame({k: self.samples[k] for k in self.names})

    def trace(self, name: str) -> np.ndarray:
        """Chain of one parameter, shape (n_ensembles, n_steps, n_walkers): trace plots."""
        return self.chains[..., list(self.parameters).index(name)]

    def to_dict(self) -> dict:
        """Plain-Python summary (no samples) for JSON."""
        return {
            "converged": bool(self.converged),
            "n_ensembles": int(self.chains.shape[0]),
            "n_walkers": int(self.n_walkers),
            "n_steps": int(self.n_steps),
            "discard": int(self.discard),
            "thin": int(self.thin),
            "n_samples": int(len(next(iter(self.samples.values())))),
            "acceptance": [float(a) for a in self.acceptance],
            "coverage": float(self.coverage),
            "priors": dict(self.priors),
            "noise": {k: (None if v is None else float(v)) for k, v in self.noise.items()},
            "seed": self.seed,
            "wall_s": float(self.wall_s),
            "parameters": [
                {"name": p, "unit": self.units()[p], "start": float(self.start[p]),
                 "mean": float(self.mean[p]), "std": float(self.std[p]),
                 "interval": [float(self.low[p]), float(self.high[p])],
                 "tau": float(self.tau[p]), "rhat": float(self.rhat[p]), "ess": float(self.ess[p])}
                for p in self.parameters
            ],
            "notes": list(self.notes),
        }


# --------------------------------------------------------------------------- truth builder
class _TruthBuilder:
    """Truth objects for parameter vectors, with the Truth's own validation.

    A field's range check (finite, low/high) is done vectorised for all walkers;
    when the Truth class has cross-field rules (``_check``) the object is built with
    ``dataclasses.replace`` (full validation), otherwise the checked values are
    set on a copy of the base, which is the same validation without re-reading the
    class's type hints for every walker (50 us -> 2 us).
    """

    def __init__(self, base, fields):
        from mtplan.models._protocol import SetupBase, fields_info

        self.base = base
        self.fields = tuple(fields)
        infos = {i["name"]: i for i in fields_info(type(base))}
        self.low = np.array([-np.inf if infos[f]["low"] is None else infos[f]["low"]
                             for f in self.fields], dtype=float)
        self.high = np.array([np.inf if infos[f]["high"] is None else infos[f]["high"]
                              for f in self.fields], dtype=float)
        self.low_open = np.array([bool(infos[f]["low_open"]) for f in self.fields])
        self.high_open = np.array([bool(infos[f]["high_open"]) for f in self.fields])
        self.full = getattr(type(base), "_check", None) is not SetupBase._check

    def valid(self, theta: np.ndarray) -> np.ndarray:
        """Mask of rows of `theta` (n, n_fields) inside every field's range."""
        ok = np.all(np.isfinite(theta), axis=1)
        ok &= np.all(np.where(self.low_open, theta > self.low, theta >= self.low), axis=1)
        ok &= np.all(np.where(self.high_open, theta < self.high, theta <= self.high), axis=1)
        return ok

    def make(self, row):
        """The Truth for one row (no range check: call `valid` first); None if invalid."""
        if self.full:
            try:
                return dataclasses.replace(self.base, **{f: float(v) for f, v in
                                                         zip(self.fields, row, strict=True)})
            except (InvalidInput, ValueError, TypeError):
                return None
        t = copy.copy(self.base)
        for f, v in zip(self.fields, row, strict=True):
            object.__setattr__(t, f, float(v))
        return t

    def make_checked(self, row):
        row = np.asarray(row, dtype=float)
        return self.make(row) if self.valid(row[None, :])[0] else None


# --------------------------------------------------------------------------- model
class _Model:
    """Residuals, log-likelihood and log-prior of one procedure's readings."""

    def __init__(self, proc, setup, readings, fields, base_truth, batch=True):
        self.proc, self.setup = proc, setup
        self.builder = _TruthBuilder(base_truth, fields)
        self.zero = proc.zero_errors(setup, 1)
        self.keys = []
        self.data = {}
        for k, v in readings.items():
            a = np.asarray(v)
            if a.dtype.kind not in "fiu":
                continue
            self.keys.append(k)
            self.data[k] = a.astype(float).reshape(-1)
        self.n = {k: self.data[k].size for k in self.keys}
        self.rank = max(np.ndim(readings[k]) for k in self.keys) - 1
        self.batched = None if batch else False  # None: not yet known
        self._zero_cache = {}

    def predict(self, truth) -> dict | None:
        try:
            with np.errstate(all="ignore"):
                out = self.proc.forward(self.setup, truth, self.zero)
        except (ValueError, ArithmeticError, InvalidInput):
            return None
        return {k: np.asarray(out[k], dtype=float).reshape(-1) for k in self.keys}

    def residuals(self, truth) -> dict | None:
        pred = self.predict(truth)
        if pred is None:
            return None
        res = {}
        for k in self.keys:
            if pred[k].shape != self.data[k].shape:
                raise InvalidInput([
                    f"The readings {k!r} of {self.proc.name} hold {self.data[k].size} values but "
                    f"the set-up's forward model gives {pred[k].size}."
                ])
            r = self.data[k] - pred[k]
            if not np.all(np.isfinite(r)):
                return None
            res[k] = r
        return res

    # ----------------------------------------------------------- many truths at once
    def _batched_truth(self, theta):
        """A Truth whose free fields are arrays (m, 1, ...) broadcasting over the readings."""
        t = copy.copy(self.builder.base)
        for i, f in enumerate(self.builder.fields):
            object.__setattr__(t, f, theta[:, i].reshape((-1,) + (1,) * self.rank))
        return t

    def _forward_batch(self, theta):
        m = theta.shape[0]
        zero = self._zero_cache.get(m)
        if zero is None:
            zero = self._zero_cache[m] = self.proc.zero_errors(self.setup, m)
        with np.errstate(all="ignore"):
            out = self.proc.forward(self.setup, self._batched_truth(theta), zero)
        res = {}
        for k in self.keys:
            a = np.asarray(out[k], dtype=float)
            if a.shape[0] != m:
                raise ValueError("not batched")
            res[k] = self.data[k] - a.reshape(m, -1)
        return res

    def residuals_many(self, theta) -> tuple[dict, np.ndarray]:
        """Residuals of every row of `theta` (m, n_fields) already in range: (dict of (m, n_k), ok).

        The forward model is called once with array-valued truth fields when it
        broadcasts them (checked against the per-walker loop on the first call,
        exactly), else once per row with a batch of one.
        """
        m = theta.shape[0]
        if self.builder.full:
            ok = np.array([self.builder.make(row) is not None for row in theta], dtype=bool)
        else:
            ok = np.ones(m, dtype=bool)
        if self.batched is not False and m >= 2:
            try:
                res = self._forward_batch(theta)
            except Exception:  # noqa: BLE001 - any failure means: the model does not batch truths
                res = None
                self.batched = False
            if res is not None and self.batched is None:
                loop, ok_loop = self._loop(theta, ok)
                same = all(
                    np.allclose(res[k][ok_loop], loop[k][ok_loop], rtol=1e-9,
                                atol=1e-12 * (np.max(np.abs(self.data[k])) + 1e-300))
                    for k in self.keys)
                self.batched = bool(same)
                if not same:
                    return loop, ok_loop
            if self.batched:
                for k in self.keys:
                    ok &= np.all(np.isfinite(res[k]), axis=1)
                return res, ok
        return self._loop(theta, ok)

    def _loop(self, theta, ok):
        m = theta.shape[0]
        res = {k: np.zeros((m, self.n[k])) for k in self.keys}
        ok = ok.copy()
        for j in np.flatnonzero(ok):
            t = self.builder.make(theta[j])
            r = None if t is None else self.residuals(t)
            if r is None:
                ok[j] = False
                continue
            for k in self.keys:
                res[k][j] = r[k]
        return res, ok


def _free_float_fields(proc, truth_cls, fields):
    from mtplan.models._protocol import fields_info

    infos = {i["name"]: i for i in fields_info(truth_cls)}
    floats = [n for n, i in infos.items() if i["kind"] is float and not i["optional"]]
    if fields is None:
        fields = tuple(proc.posterior_fields) or tuple(floats)
    else:
        fields = (fields,) if isinstance(fields, str) else tuple(fields)
    bad = [f for f in fields if f not in floats]
    if bad or not fields:
        raise InvalidInput([
            f"The 'fields' parameter of sample_posterior must name float Truth fields of "
            f"{proc.name} ({', '.join(floats)}). Got {list(bad) or 'none'} instead."
        ])
    return fields


def _least_squares_start(model: _Model, theta0, weights):
    """Weighted least squares over the free fields, from `theta0`; (theta, jac, rms per key)."""
    from scipy.optimize import least_squares

    b = model.builder
    lo = np.where(np.isfinite(b.low), b.low + np.where(b.low_open, 1e-12 * np.maximum(abs(b.low), 1e-300), 0), -np.inf)
    hi = np.where(np.isfinite(b.high), b.high - np.where(b.high_open, 1e-12 * np.maximum(abs(b.high), 1e-300), 0), np.inf)
    theta0 = np.clip(np.asarray(theta0, dtype=float), lo, hi)
    big = None

    def fun(theta):
        nonlocal big
        truth = b.make_checked(theta)
        res = None if truth is None else model.residuals(truth)
        if res is None:
            return np.full(sum(model.n.values()), 1e6 if big is None else big)
        out = np.concatenate([res[k] * weights[k] for k in model.keys])
        if big is None:
            big = 1e3 * float(np.max(np.abs(out)) + 1.0)
        return out

    sol = least_squares(fun, theta0, bounds=(lo, hi), x_scale="jac", method="trf",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200 * (theta0.size + 1))
    truth = b.make_checked(sol.x)
    res = model.residuals(truth) if truth is not None else None
    if res is None:
        raise InvalidInput([f"The least-squares fit of {model.proc.name} to the readings did not "
                            "reach a valid truth; give a start."])
    rms = {k: float(np.sqrt(np.mean(res[k] ** 2))) for k in model.keys}
    return sol.x, sol.jac, rms


def _setup_noise(proc, setup):
    if not proc.noise_source:
        return None
    src = proc.sources(setup).get(proc.noise_source)
    if src is None:
        return None
    std = np.asarray(src.distribution.std, dtype=float)
    return float(np.max(std)) if std.size else None


# --------------------------------------------------------------------------- main entry
def sample_posterior(
    procedure,
    setup,
    readings,
    *,
    fields=None,
    noise=None,
    priors: Mapping | None = None,
    start=None,
    truth=None,
    estimator: str | None = None,
    n_walkers: int | None = None,
    n_ensembles: int = 4,
    max_steps: int = 20_000,
    check_every: int = 100,
    n_tau: float = 50.0,
    tau_rtol: float = 0.05,
    rhat_max: float = 1.01,
    burn_tau: float = 3.0,
    coverage: float = 0.95,
    allow_unconverged: bool = False,
    moves=None,
    batch: bool = True,
    rng=None,
    progress: bool | None = None,
) -> PosteriorResult:
    """Sample the posterior of a procedure's measurands given one set of readings.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
        The set-up the readings were taken with.
    readings : dict of str to array
        A batch of one (leading axis 1), as ``procedure.from_frame`` returns.
    fields : iterable of str, optional
        Free Truth fields (default ``procedure.posterior_fields``, else every float field).
    noise : None, "setup", float or mapping of str to float, optional
        The readings' noise standard deviation [the readings' unit, mm or rad]. None
        (default): one free noise parameter per reading array, log-uniform prior.
        ``"setup"``: the spread of ``procedure.noise_source`` in `setup`. A number: known,
        for every reading array; a mapping: per reading array (None = free).
    priors : mapping of str to object with ``logpdf``, optional
        Replaces the default (weak) prior of the named parameters, e.g.
        ``{"offset_mm": scipy.stats.norm(0, 0.1)}``; a ``sigma_<reading>`` prior is on sigma.
    start : mapping of str to float, optional
        Start of the least-squares fit (default: ``truth_from_estimate`` of the
        procedure's estimate when the hook exists, else `truth`).
    truth : Truth, optional
        Values of the fields that are not free (default: the Truth's defaults).
    estimator : str, optional
        Estimator used for the start (default: the procedure's default).
    n_walkers : int, optional
        Walkers per ensemble, even and >= 2 x ndim (default max(16, 4 ndim)).
    n_ensembles : int
        Independent ensembles (>= 2 for R-hat).
    max_steps : int
        Step budget per ensemble.
    check_every : int
        Steps between convergence checks.
    n_tau, tau_rtol, rhat_max, burn_tau : float
        Convergence: chain longer than `n_tau` tau, tau's relative change between checks
        below `tau_rtol`, split R-hat below `rhat_max`; `burn_tau` tau discarded.
    coverage : float
        Probability of the equal-tailed credible intervals.
    allow_unconverged : bool
        Warn (:class:`UnconvergedWarning`) instead of raising :class:`NotConvergedError`.
    moves : emcee move(s), optional
        Default: emcee's stretch move. (A differential-evolution mixture has a third of
        its autocorrelation time on toy_line but, with the noise free, under-sampled the
        Student-t tails by 10 % even on long chains, so it is not the default.)
    batch : bool
        Evaluate all walkers with one forward call (array-valued truth fields) when the
        model broadcasts them (verified exactly against the per-walker loop); False: loop.
    rng : None, int, SeedSequence or Generator
    progress : bool, optional
        Print a line per check on stderr (default: when stderr is a terminal).

    Returns
    -------
    PosteriorResult
    """
    from mtplan.models import get

    t_start = time.perf_counter()
    proc = get(procedure)
    proc.check_setup(setup)
    p = Problems(f"sample_posterior {proc.name}")
    p.number("n_ensembles", n_ensembles, integer=True, low=2)
    p.number("max_steps", max_steps, integer=True, low=2)
    p.number("check_every", check_every, integer=True, low=2)
    p.number("n_tau", n_tau, low=1)
    p.number("tau_rtol", tau_rtol, low=0, low_open=True)
    p.number("rhat_max", rhat_max, low=1, low_open=True)
    p.number("burn_tau", burn_tau, low=0)
    p.number("coverage", coverage, low=0, high=1, low_open=True, high_open=True)
    if not isinstance(readings, Mapping) or not readings:
        p.add("readings", readings, "a dict of reading arrays (procedure.from_frame)")
    p.raise_if_any()
    root = as_seed_sequence(rng)
    base = proc.Truth() if truth is None else truth
    if not isinstance(base, proc.Truth):
        raise InvalidInput([f"The 'truth' parameter of sample_posterior must be a {proc.name} "
                            f"Truth. Got {type(base).__name__} instead."])
    fields_given = fields is not None
    fields = _free_float_fields(proc, proc.Truth, fields)
    model = _Model(proc, setup, readings, fields, base, batch=batch)
    notes = []

    # ---- known and free noise
    keys = model.keys
    setup_sigma = _setup_noise(proc, setup)
    if noise is None:
        known = {k: None for k in keys}
    elif isinstance(noise, str):
        if noise != "setup" or setup_sigma is None or setup_sigma <= 0:
            raise InvalidInput([
                f"The 'noise' parameter of sample_posterior must be None, a number > 0, a mapping "
                f"or 'setup' (for a procedure whose noise source is set and active). Got {noise!r} "
                f"instead."])
        known = {k: setup_sigma for k in keys}
    elif isinstance(noise, Mapping):
        unknown = [k for k in noise if k not in keys]
        if unknown:
            raise InvalidInput([f"The 'noise' parameter of sample_posterior names readings "
                                f"{unknown}; the readings are {keys}."])
        known = {k: noise.get(k) for k in keys}
    else:
        known = {k: noise for k in keys}
    for k, v in known.items():
        if v is not None:
            p.number(f"noise[{k}]", v, low=0, low_open=True)
    p.raise_if_any()
    known = {k: (None if v is None else float(v)) for k, v in known.items()}

    # ---- least-squares start
    if start is not None:
        theta0 = np.array([float(start.get(f, getattr(base, f))) for f in fields])
    else:
        t0 = base
        if proc.truth_from_estimate is not None:
            try:
                est = proc.estimate(setup, readings, estimator)
                est = {k: float(np.asarray(v).reshape(-1)[0]) for k, v in est.items()}
                t0 = proc.truth_from_estimate(setup, est)
            except (InvalidInput, ValueError, ArithmeticError) as exc:
                notes.append(f"start: the estimator failed ({exc}); started from the default truth")
                t0 = base
        theta0 = np.array([float(getattr(t0, f)) for f in fields])
    weights = {k: 1.0 / (known[k] or setup_sigma or 1.0) for k in keys}
    theta_ls, jac, rms = _least_squares_start(model, theta0, weights)
    if len(keys) > 1 and any(known[k] is None for k in keys):
        weights = {k: 1.0 / (known[k] or rms[k] or 1.0) for k in keys}
        theta_ls, jac, rms = _least_squares_start(model, theta_ls, weights)
    free_noise = []
    for k in keys:
        if known[k] is None:
            scale = np.max(np.abs(model.data[k])) or 1.0
            if rms[k] <= 1e-12 * scale:
                notes.append(f"reading {k!r} is reproduced exactly by the model; left out of the "
                             "likelihood")
                continue
            free_noise.append(k)
    like_keys = [k for k in keys if known[k] is not None or k in free_noise]
    # least-squares covariance of the fields (weights = known sigma or the RMS)
    factor = np.concatenate([np.full(model.n[k], 1.0 / (weights[k] * (known[k] or rms[k] or 1.0)))
                             for k in keys])
    Jw = jac * factor[:, None]  # jacobian of the residuals over their sigma
    col = np.linalg.norm(Jw, axis=0)
    dead = [f for f, c in zip(fields, col, strict=True) if not c > 0]
    if dead and (fields_given or len(dead) == len(fields)):
        raise InvalidInput([
            f"The Truth field(s) {', '.join(dead)} of {proc.name} do not affect the readings; "
            "leave them out of 'fields'."])
    if dead:  # default fields: keep those the readings determine, fix the rest
        notes.append(f"Truth field(s) {', '.join(dead)} do not affect the readings: held at "
                     f"{', '.join(f'{f} = {getattr(base, f):g}' for f in dead)}")
        alive = [i for i, f in enumerate(fields) if f not in dead]
        fields = tuple(fields[i] for i in alive)
        theta_ls, Jw, col = theta_ls[alive], Jw[:, alive], col[alive]
        base = model.builder.make(np.array([getattr(base, f) if f in dead else
                                            theta_ls[fields.index(f)] for f in model.builder.fields]))
        model = _Model(proc, setup, readings, fields, base, batch=batch)
    try:
        cov = np.linalg.inv(Jw.T @ Jw)
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        se = 1.0 / col
    if not np.all(np.isfinite(se) & (se > 0)):
        se = 1.0 / col
        notes.append("the least-squares covariance is singular: some fields are not separately "
                     "determined by the readings")

    # ---- parameters and priors
    names = list(fields) + [f"sigma_{k}" for k in free_noise]
    ndim = len(names)
    priors = dict(priors or {})
    unknown = [k for k in priors if k not in names]
    if unknown:
        raise InvalidInput([f"The 'priors' parameter of sample_posterior names {unknown}; the "
                            f"parameters are {names}."])
    for k, v in priors.items():
        if not hasattr(v, "logpdf"):
            raise InvalidInput([f"The prior of {k!r} must have a logpdf method (a scipy.stats "
                                f"distribution). Got {type(v).__name__} instead."])
    prior_text = {}
    prior_mu = theta_ls.copy()
    prior_sd = PRIOR_WIDTH * se
    for i, f in enumerate(fields):
        if f in priors:
            prior_text[f] = f"user: {priors[f]!r}"
        else:
            prior_text[f] = (f"normal(mean {prior_mu[i]:.6g}, std {prior_sd[i]:.3g}) = least-squares "
                             f"estimate +- {PRIOR_WIDTH:g} standard errors, within the field's range")
    sig0 = np.array([rms[k] for k in free_noise])
    for k, s in zip(free_noise, sig0, strict=True):
        name = f"sigma_{k}"
        prior_text[name] = (f"user: {priors[name]!r}" if name in priors else
                            f"log-uniform on [{s / NOISE_RANGE:.3g}, {s * NOISE_RANGE:.3g}] "
                            f"(Jeffreys; residual RMS {s:.3g} x/÷ {NOISE_RANGE:g})")
    user_prior = [(i, priors[n]) for i, n in enumerate(names) if n in priors]
    nf = len(fields)
    default_field = np.array([f not in priors for f in fields])
    log_sig_lo = np.log(sig0 / NOISE_RANGE) if free_noise else np.zeros(0)
    log_sig_hi = np.log(sig0 * NOISE_RANGE) if free_noise else np.zeros(0)
    default_sig = np.array([f"sigma_{k}" not in priors for k in free_noise], dtype=bool)
    known_keys = [k for k in like_keys if known[k] is not None]

    def log_prob(coords: np.ndarray) -> np.ndarray:
        """Vectorised log-posterior: coords (n_walkers, ndim) -> (n_walkers,)."""
        coords = np.atleast_2d(coords)
        out = np.full(coords.shape[0], -np.inf)
        th = coords[:, :nf]
        ls = coords[:, nf:]  # log sigma
        ok = model.builder.valid(th) & np.all(np.isfinite(ls), axis=1)
        if free_noise:
            ok &= np.all(~default_sig | ((ls >= log_sig_lo) & (ls <= log_sig_hi)), axis=1)
        lp = -0.5 * np.sum(np.where(default_field, ((th - prior_mu) / prior_sd) ** 2, 0.0), axis=1)
        for i, dist in user_prior:
            x = coords[:, i] if i < nf else np.exp(coords[:, i])
            with np.errstate(all="ignore"):
                lp = lp + np.asarray(dist.logpdf(x), dtype=float)
                if i >= nf:
                    lp = lp + coords[:, i]  # Jacobian of sigma = exp(log sigma)
        ok &= np.isfinite(lp)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            return out
        res, good = model.residuals_many(th[idx])
        ll = np.zeros(idx.size)
        for k in known_keys:
            ll -= 0.5 * np.einsum("ij,ij->i", res[k], res[k]) / known[k] ** 2 + model.n[k] * (
                math.log(known[k]) + 0.5 * _LOG_2PI)
        for q, k in enumerate(free_noise):
            lsq = ls[idx, q]
            ll -= 0.5 * np.einsum("ij,ij->i", res[k], res[k]) * np.exp(-2 * lsq) + model.n[k] * (
                lsq + 0.5 * _LOG_2PI)
        out[idx[good]] = lp[idx[good]] + ll[good]
        return out

    # ---- walkers
    if n_walkers is None:
        n_walkers = max(16, 4 * ndim)
        n_walkers += n_walkers % 2
    p.number("n_walkers", n_walkers, integer=True, low=2 * ndim)
    p.raise_if_any()
    if int(n_walkers) % 2:
        raise InvalidInput([f"The 'n_walkers' parameter of sample_posterior must be an even int >= "
                            f"{2 * ndim}. Got {n_walkers!r} instead."])
    n_walkers = int(n_walkers)
    center = np.concatenate([theta_ls, np.log(sig0)])
    # small ball: 0.1 standard errors (noise: 0.1 / sqrt(2 n) in log sigma)
    ball = np.concatenate([0.1 * se, [0.1 / math.sqrt(2 * model.n[k]) for k in free_noise]])
    if progress is None:
        progress = sys.stderr.isatty()
    run = run_ensembles(log_prob, center, ball, root=root, n_walkers=n_walkers,
                        n_ensembles=int(n_ensembles), max_steps=max_steps,
                        check_every=check_every, n_tau=n_tau, tau_rtol=tau_rtol,
                        rhat_max=rhat_max, burn_tau=burn_tau, moves=moves,
                        progress=stderr_progress(proc.name) if progress else None)
    steps, converged, rhat = run.steps, run.converged, run.rhat

    # ---- kept samples and diagnostics
    chains, logp = run.chains, run.log_prob  # (E, S, W, D), (E, S, W)
    tau_max = run.tau.max(axis=0)
    t_max = float(np.max(tau_max))
    discard, thin = run.burn_and_thin(burn_tau)
    kept = chains[:, discard::thin]  # (E, s, W, D)
    values = kept.copy()
    values[..., nf:] = np.exp(values[..., nf:])
    measurands = tuple(proc.measurands(setup))
    flat = values.reshape(-1, ndim)
    mvals = np.empty((flat.shape[0], len(measurands)))
    for i, row in enumerate(flat):
        tv = proc.true_values(setup, model.builder.make(row[:nf]))
        mvals[i] = [float(tv[m.name]) * m.scale for m in measurands]
    mchains = mvals.reshape(*kept.shape[:3], len(measurands))
    all_chains = np.concatenate([values, mchains], axis=-1)
    all_names = names + [m.name for m in measurands]
    rhat_all = split_rhat(all_chains)
    kept_draws = kept.shape[1] * kept.shape[2]
    tau_thin = np.array([integrated_time(all_chains[e]) for e in range(all_chains.shape[0])])  # in kept steps
    ess_all = np.sum(kept_draws / np.maximum(tau_thin, 1.0), axis=0)
    tau_steps = {n: float(tau_max[i]) for i, n in enumerate(names)}
    for j, m in enumerate(measurands):
        tau_steps[m.name] = float(np.max(tau_thin[:, ndim + j]) * thin)
    samples, mean, std, low, high, rh, ess = {}, {}, {}, {}, {}, {}, {}
    a = (1 - coverage) / 2
    for i, name in enumerate(all_names):
        x = all_chains[..., i].reshape(-1)
        samples[name] = x
        mean[name] = float(np.mean(x))
        std[name] = float(np.std(x, ddof=1)) if x.size > 1 else math.nan
        low[name], high[name] = (float(v) for v in np.quantile(x, [a, 1 - a]))
        rh[name] = float(rhat_all[i])
        ess[name] = float(ess_all[i])
    start_d = {n: float(v) for n, v in zip(names, np.concatenate([theta_ls, sig0]), strict=True)}
    seed = root.entropy if isinstance(root.entropy, int) else list(root.entropy)
    result = PosteriorResult(
        procedure=proc.name,
        setup=setup,
        measurands=measurands,
        parameters=tuple(names),
        samples=samples,
        mean=mean,
        std=std,
        low=low,
        high=high,
        coverage=float(coverage),
        tau=tau_steps,
        rhat=rh,
        ess=ess,
        acceptance=run.acceptance,
        converged=converged,
        chains=_natural(chains, nf),
        log_prob=logp,
        discard=discard,
        thin=thin,
        start=start_d,
        priors=prior_text,
        noise={k: known[k] for k in keys},
        seed=seed,
        n_walkers=n_walkers,
        n_steps=steps,
        wall_s=time.perf_counter() - t_start,
        notes=notes,
    )
    if not converged:
        msg = (f"The posterior of {proc.name} did not converge in {steps} steps per ensemble "
               f"(needs > {n_tau:g} tau with tau settled and R-hat < {rhat_max:g}; tau max "
               f"{t_max:.1f} steps, R-hat max {float(np.max(rhat)):.4f}); raise max_steps or pass "
               "allow_unconverged=True for the flagged partial result.")
        result.notes.append("NOT CONVERGED: " + msg)
        if not allow_unconverged:
            raise NotConvergedError(msg, result)
        warnings.warn(msg, UnconvergedWarning, stacklevel=2)
    return result
