"""Posterior of a procedure's measurands from measured readings, sampled with emcee.

The likelihood covers the whole error budget of the set-up
(:mod:`mtplan.fitting.error_model`): the readings are Gaussian about the forward
model's prediction with every error source at its mean (plus the second-order
shift of the mean), with the covariance of every linear source's effect (noise
plus systematic sources through the forward model's sensitivity to each element,
low rank plus diagonal); strongly non-linear sources are sampled as nuisance
parameters with the set-up's distributions as priors. Which source went where is
in :attr:`PosteriorResult.budget`; docs/posterior.md says it per procedure.

The free parameters ``theta`` are Truth fields and elements of tuple fields
(those asked for, else all of them); the measurands follow from
``procedure.true_values(setup, truth(theta))``. The noise source's standard
deviation is the set-up's (default), a given number, or free (log-uniform prior).

Before sampling, the readings are checked to determine what is sampled: a free
parameter the readings do not determine (no effect, or only together with
others) is held at its least-squares value and named in the notes; a measurand
that depends on no sampled parameter, and a free noise with fewer than 3
residual degrees of freedom, are refused with what to give instead.

Default priors are weak and stated in :attr:`PosteriorResult.priors`: for each
free field a normal centred at the least-squares estimate with a standard
deviation 1000 times its standard error (a change of the posterior standard
deviation below 1e-6 relative in the linear case), cut to the field's range; for
a free noise a log-uniform prior over a factor 1000 either side of its maximum-
likelihood value.

The sampler (:func:`mtplan.uncertainty.sampler.run_ensembles`): several
independent ensembles, seeded (numpy's global state untouched), every half-step
of all walkers one vectorised call (one forward-model call with array-valued truth
fields where the model allows), walkers started from the Laplace approximation
(the least-squares estimate and its covariance), moved by an independence
proposal from that approximation (Metropolis-Hastings, so exact) mixed with
emcee's stretch move; run until every chain is longer than ``n_tau`` integrated
autocorrelation times, tau has settled and the split R-hat is below
``rhat_max``; ``burn_tau`` tau discarded, thinned by tau/2. When the step or time
budget runs out first, :class:`NotConvergedError` carries the partial result
(``allow_unconverged=True`` downgrades it to a flagged warning).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.fitting import ErrorModel, error_model
from mtplan.models.protocol import Procedure, shown_with_unit
from mtplan.evaluation._posterior_model import DOMAIN_ERRORS, Forward, TruthBuilder, \
    truth_parameters
from mtplan.uncertainty.streams import as_seed_sequence
from mtplan.uncertainty.sampler import (
    NotConvergedError,
    SamplerOptions,
    UnconvergedWarning,
    integrated_time,
    mixed_moves,
    psd_factor,
    run_ensembles,
    split_rhat,
)

__all__ = [
    "PosteriorResult",
    "PosteriorOptions",
    "NotConvergedError",
    "UnconvergedWarning",
    "sample_posterior",
    "split_rhat",
    "NOISE_MODES",
]

PRIOR_WIDTH = 1000.0  # default prior std in least-squares standard errors
NOISE_RANGE = 1000.0  # log-uniform noise prior: this factor either side of the start
NOISE_MODES = ("setup", "free")
MIN_NOISE_DOF = 3  # a free noise needs this many residual degrees of freedom (finite variance)
RANK_TOL = 1e-4  # a parameter whose whitened column lies this close to the others' span (the
# finite differences of an exact model are good to about 1e-6) is held: the readings determine
# it only together with others; a held direction that moves a measurand refuses that measurand,
# so holding never understates u. Weakly but truly determined parameters stay sampled.


# --------------------------------------------------------------------------- options
@dataclass(frozen=True)
class PosteriorOptions(SamplerOptions):
    """What :func:`sample_posterior` samples and how (frozen: change one with :meth:`replace`).

    The sampler's walkers and stopping rules are those of
    :class:`~mtplan.uncertainty.sampler.SamplerOptions` (``n_walkers``: even, default 16; with
    your own `moves`, >= 2 x ndim; ``label``: default the procedure's name); beside them:

    Attributes
    ----------
    fields : iterable of str, optional
        Free Truth fields or tuple elements (``"wrist_dx_um[1]"``); default all of them.
    noise : "setup", "free" or float
        The noise source's standard deviation: the set-up's (default; None means the
        same), free (log-uniform prior; refused with fewer than 3 residual degrees of
        freedom), or this number [the source's unit, mm or rad].
    priors : mapping of str to object with ``logpdf``, optional
        Replaces the default prior of the named sampled parameters, e.g.
        ``{"offset_mm": scipy.stats.norm(0, 0.1)}``; a ``sigma_<source>`` prior is on sigma.
    start : mapping of str to float, optional
        Start of the least squares (default: ``truth_from_estimate`` of the estimate
        when the procedure has that hook, else `truth`).
    truth : Truth, optional
        Values of the fields that are not free (default: the Truth's defaults).
    estimator : str, optional
        Estimator used for the start (default: the procedure's first exact estimator).
    coverage : float
        Probability of the equal-tailed credible intervals.
    allow_unconverged : bool
        Warn (:class:`UnconvergedWarning`) instead of raising :class:`NotConvergedError`.
    moves : emcee move(s), optional
        Default: the independence move from the Laplace approximation (80 %) mixed with a
        random-walk Metropolis move scaled by it
        (:func:`mtplan.uncertainty.sampler.mixed_moves`).
    batch : bool
        Evaluate all walkers with one forward call (array-valued truth fields) when the
        model takes them (verified against the per-walker loop); False: loop.
    rng : None, int, SeedSequence or Generator
    """

    label: str | None = None
    fields: object = None
    noise: object = "setup"
    priors: Mapping | None = None
    start: Mapping | None = None
    truth: object = None
    estimator: str | None = None
    coverage: float = 0.95
    allow_unconverged: bool = False
    moves: object = None
    batch: bool = True
    rng: object = None

    WHAT = "posterior option"

    def sampler(self, label: str) -> SamplerOptions:
        """The sampler's share of these options (`label` where none is given)."""
        shared = {f.name: getattr(self, f.name) for f in dataclasses.fields(SamplerOptions)}
        return SamplerOptions(**(shared | {"label": self.label or label}))


# --------------------------------------------------------------------------- result
@dataclass
class PosteriorResult:
    """Posterior of a procedure's measurands and free parameters.

    Attributes
    ----------
    procedure : Procedure
    setup : the procedure's Setup
    measurands : tuple of Measurand
    parameters : tuple of str
        Sampled parameters: Truth fields or elements (in the unit their name states),
        nuisance error-source elements (``source`` or ``source[i]``, internal units)
        and, when the noise is free, ``sigma_<noise source>`` (its unit).
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
    converged : bool
    chains : array (n_ensembles, n_steps, n_walkers, n_params)
        Every step of every walker, burn-in included (trace plots).
    log_prob : array (n_ensembles, n_steps, n_walkers)
    discard, thin : int
    start : dict of str to float
        The least-squares estimate the walkers started around.
    priors : dict of str to str
        The prior of every parameter, in words.
    noise : dict
        ``source`` (the noise source or None), ``mode`` ("setup", "given", "free") and
        ``sigma`` (its standard deviation [its unit]; the start value when free).
    budget : dict of str to str
        What became of every error source of the set-up (covariance, nuisance, ...).
    held : dict of str to float
        Free fields the readings do not determine, held at these values.
    units : dict of str to str
        Unit of every measurand and parameter.
    seed : int or list
    wall_s : float
    notes : list of str
    """

    procedure: Procedure
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
    budget: dict
    held: dict
    units: dict
    seed: object
    n_walkers: int
    n_steps: int
    wall_s: float
    notes: list = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        """Measurand names, then parameter names."""
        return [m.name for m in self.measurands] + list(self.parameters)

    def summary(self):
        """DataFrame indexed by name: kind, unit, value (the posterior mean), u (its standard
        deviation), low, high, tau, rhat, ess."""
        import pandas as pd

        kinds = {m.name: "measurand" for m in self.measurands}
        rows = [{"name": n, "kind": kinds.get(n, "parameter"), "unit": self.units[n],
                 "value": self.mean[n], "u": self.std[n], "low": self.low[n],
                 "high": self.high[n], "tau": self.tau.get(n, math.nan), "rhat": self.rhat[n],
                 "ess": self.ess[n]} for n in self.names]
        return pd.DataFrame(rows).set_index("name")

    def frame(self):
        """Kept samples as a DataFrame (one column per measurand and parameter): corner plots."""
        import pandas as pd

        return pd.DataFrame({k: self.samples[k] for k in self.names})

    def trace(self, name: str) -> np.ndarray:
        """Chain of one parameter, shape (n_ensembles, n_steps, n_walkers): trace plots."""
        return self.chains[..., list(self.parameters).index(name)]

    def to_dict(self) -> dict:
        """Plain-Python summary (no samples) for JSON: one row per parameter."""
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
            "noise": {k: (float(v) if isinstance(v, float) else v) for k, v in self.noise.items()},
            "budget": dict(self.budget),
            "held": {k: float(v) for k, v in self.held.items()},
            "seed": self.seed,
            "wall_s": float(self.wall_s),
            "parameters": [
                {"name": p, "unit": self.units[p], "start": float(self.start[p]),
                 "value": float(self.mean[p]), "u": float(self.std[p]),
                 "interval": [float(self.low[p]), float(self.high[p])],
                 "tau": float(self.tau[p]), "rhat": float(self.rhat[p]), "ess": float(self.ess[p])}
                for p in self.parameters
            ],
            "notes": list(self.notes),
        }


# --------------------------------------------------------------------------- set-up and checks
def _check_arguments(proc, setup, readings, o: PosteriorOptions):
    """Validate every argument at once; return the noise mode ("setup", "known", "free")
    and the given noise [its unit] or None."""
    proc.check_setup(setup)
    noise = o.noise
    p = Problems(f"sample_posterior {proc.name}")
    p.number("n_ensembles", o.n_ensembles, integer=True, low=2)
    p.number("max_steps", o.max_steps, integer=True, low=2)
    if o.check_every is not None:
        p.number("check_every", o.check_every, integer=True, low=2)
    p.number("n_tau", o.n_tau, low=1)
    p.number("tau_rtol", o.tau_rtol, low=0, low_open=True)
    p.number("rhat_max", o.rhat_max, low=1, low_open=True)
    p.number("burn_tau", o.burn_tau, low=0)
    p.number("coverage", o.coverage, low=0, high=1, low_open=True, high_open=True)
    if o.max_seconds is not None:
        p.number("max_seconds", o.max_seconds, low=0, low_open=True)
    if not isinstance(readings, Mapping) or not readings:
        p.add("readings", readings, "a dict of reading arrays (procedure.readings.from_frame)")
    allowed = ("None, 'setup' (every source at the set-up's size), 'free' (the noise source's "
               "size free) or a number > 0 (the noise source's standard deviation)")
    mode, sigma = "setup", None
    if noise is None or (isinstance(noise, str) and noise == "setup"):
        pass
    elif isinstance(noise, str) and noise == "free":
        mode = "free"
    elif isinstance(noise, bool) or isinstance(noise, str) or isinstance(noise, Mapping):
        p.add("noise", noise, allowed)
    elif p.number("noise", noise, low=0, low_open=True):
        mode, sigma = "known", float(noise)
    if mode != "setup" and proc.readings.noise_source is None:
        p.add_text(f"The 'noise' parameter of sample_posterior must be 'setup' for {proc.name}: "
                   f"it names no noise source whose size could be given or left free (got "
                   f"{noise!r}); its readings' noise is the set-up's error sources")
    p.raise_if_any()
    return mode, sigma


def initial_theta(proc, setup, readings, builder, start, estimator, notes) -> np.ndarray:
    """Where the least squares start: `start`, else the estimate's truth, else the base truth."""
    if start is not None:
        unknown = [k for k in start if k not in builder.names]
        if unknown:
            raise InvalidInput([f"The 'start' parameter of sample_posterior names {unknown}; the "
                                f"free parameters are {builder.names}."])
        return np.array([float(start.get(p.name, v)) for p, v in
                         zip(builder.params, builder.values, strict=True)])
    if not proc.capabilities.builds_truths:
        return builder.values.copy()
    if estimator is None and proc.exact_names:  # one that sees every measurand
        estimator = proc.exact_names[0]
    try:
        est = proc.estimate(setup, readings, estimator)
        est = {k: float(np.asarray(v).reshape(-1)[0]) for k, v in est.items()}
        t0 = proc.capabilities.start_from_readings(
            setup, readings, proc.capabilities.truth_from_estimate(setup, est))
        return np.array([builder.value_of(t0, p) for p in builder.params])
    except DOMAIN_ERRORS as exc:
        notes.append(f"start: the estimator failed ({exc}); started from the default truth")
        return builder.values.copy()


# --------------------------------------------------------------------------- start: least squares
@dataclass
class _Fit:
    """The least-squares (generalised, under the whole error model) estimate."""

    error_model: ErrorModel
    theta: np.ndarray  # every free parameter
    nuis: np.ndarray  # nuisance source elements
    sigma: float | None  # the noise source's standard deviation (None: the set-up's)
    correction: np.ndarray


def nuisance_priors(model: ErrorModel):
    """Per nuisance element: (mean, std, low, high) of the set-up's distribution."""
    rows = []
    for _, src in model.nuisance:
        d = src.distribution
        size = int(np.prod((*src.shape, *d.event_shape), dtype=np.int64))
        lo, hi = getattr(d, "low", -np.inf), getattr(d, "high", np.inf)
        rows += [(float(d.mean), float(np.max(d.std)), float(lo), float(hi))] * size
    return np.array(rows, dtype=float).reshape(-1, 4)


def _least_squares(fwd, fit: _Fit, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares of (theta[free], nuisance) with the budget's covariance at
    fit.sigma; the parameters that do not affect the readings stay where they are."""
    from scipy.optimize import least_squares

    b, gauss = fwd.builder, fit.error_model.gaussian(fit.sigma)
    pri = nuisance_priors(fit.error_model)
    idx = np.flatnonzero(free)
    p, q = idx.size, pri.shape[0]
    with np.errstate(invalid="ignore"):  # infinite bounds stay infinite
        lo_t = b.low + np.where(b.low_open & np.isfinite(b.low), 1e-12 * np.abs(b.low) + 1e-300, 0)
        hi_t = b.high - np.where(b.high_open & np.isfinite(b.high), 1e-12 * np.abs(b.high) + 1e-300,
                                 0)
    lo, hi = np.concatenate([lo_t[idx], pri[:, 2]]), np.concatenate([hi_t[idx], pri[:, 3]])
    steps = np.concatenate([b.steps(fit.theta), 1e-3 * pri[:, 1]])
    start = np.concatenate([fit.theta[idx], fit.nuis])
    x0 = np.clip(start, lo, hi)
    x0 = np.where((x0 == lo) | (x0 == hi), x0 + 1e-9 * (hi - lo) * np.where(x0 == lo, 1, -1), x0)
    x0 = np.where(np.isfinite(x0), x0, start)

    def theta(x):
        th = fit.theta.copy()
        th[idx] = x[:p]
        return th

    def fun(x):
        pred, ok = fwd.predict(theta(x)[None], x[None, p:] if q else None)
        if not ok[0]:
            return np.full(fwd.n + q, 1e8)
        w = gauss.whiten(fwd.y - pred[0] - fit.correction)[0]
        return np.concatenate([w, (x[p:] - pri[:, 0]) / pri[:, 1]])

    def jac(x):
        j = fwd.jacobian(theta(x), x[p:] if q else None, steps)
        j = -gauss.whiten(j[:, np.concatenate([idx, fit.theta.size + np.arange(q)])].T).T
        return np.vstack([j, np.hstack([np.zeros((q, p)), np.diag(1.0 / pri[:, 1])])])

    sol = least_squares(fun, x0, jac=jac, bounds=(lo, hi), x_scale="jac", method="trf",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=50 * (p + q + 1))
    th = theta(sol.x)
    if b.make(th) is None or not fwd.predict(th[None], sol.x[None, p:] if q else None)[1][0]:
        raise InvalidInput([f"The least-squares fit of {fwd.proc.name} to the readings did not "
                            "reach a valid truth; give a start."])
    return th, sol.x[p:]


def _noise_ml(fwd, fit: _Fit) -> float:
    """Maximum-likelihood standard deviation of a free noise at the fitted parameters."""
    from scipy.optimize import minimize_scalar

    gauss = fit.error_model.gaussian()
    pred, _ = fwd.predict(fit.theta[None], fit.nuis[None] if fit.nuis.size else None)
    r = fwd.y - pred[0] - fit.correction
    s0 = math.sqrt(max(float(np.mean(r**2)), 1e-300))
    res = minimize_scalar(lambda ls: -gauss.loglike(r, np.array([ls]))[0],
                          bounds=(math.log(s0) - 15, math.log(s0) + 5), method="bounded",
                          options={"xatol": 1e-6})
    return float(math.exp(res.x))


#: recent starts (an estimate's bias correction, its fit check and its posterior start
#: from the same readings): key -> (fit, notes, nuisance slots); a copy is handed out
_STARTS: dict = {}


def start_fit(fwd, theta0, mode, sigma, notes) -> _Fit:
    """:func:`_fit_start`, remembered for the same procedure, set-up, readings, parameters,
    start and noise (a pure function of them: the result is the same, only sooner)."""
    b = fwd.builder
    key = (fwd.proc.name, fwd.setup, tuple(fwd.keys), fwd.y.tobytes(), fwd.mask.tobytes(),
           repr(b.base), tuple((p.name, p.low, p.high) for p in b.params),
           np.asarray(theta0, dtype=float).tobytes(), mode, sigma)
    if key not in _STARTS:
        own: list = []
        fit = _fit_start(fwd, theta0, mode, sigma, own)
        if len(_STARTS) >= 2:  # a budget's low-rank part can hold tens of MB
            _STARTS.pop(next(iter(_STARTS)))
        _STARTS[key] = (fit, own, list(fwd.slots))
    fit, own, slots = _STARTS[key]
    notes.extend(own)
    fwd.slots = list(slots)
    return dataclasses.replace(fit, theta=fit.theta.copy(), nuis=fit.nuis.copy())


def _fit_start(fwd, theta0, mode, sigma, notes) -> _Fit:
    """ErrorModel at the start, generalised least squares, the budget again where it moved."""
    setup_sd = None
    if fwd.proc.readings.noise_source is not None:
        noise = fwd.sources[fwd.proc.readings.noise_source]
        setup_sd = float(np.max(np.asarray(noise.distribution.std)))
    names = fwd.builder.names
    fit = None
    for _ in range(2):
        truth = fwd.builder.make(theta0)
        if truth is None:
            raise InvalidInput([f"The start of the least squares of {fwd.proc.name} is not a "
                                "valid truth; give a start."])
        J, G = fwd.jacobian(theta0), fwd.measurand_gradient(theta0)
        model = error_model(fwd, truth, mode, sigma, J, G, names)
        sig = {"known": sigma, "free": setup_sd or 1e-3}.get(mode)
        nuis0 = nuisance_priors(model)[:, 0]
        fit = _Fit(model, theta0.copy(), nuis0, sig, model.correction)
        # what the readings do not determine stays where it starts (and is held, identify)
        gw = fit.error_model.gaussian(fit.sigma).whiten(J.T).T
        free = np.zeros(J.shape[1], dtype=bool)
        free[_rank_order(gw, np.any(G != 0, axis=0), J.shape[1], 0)[0]] = True
        fit.theta, fit.nuis = _least_squares(fwd, fit, free)
        if mode == "free":
            fit.sigma = _noise_ml(fwd, fit)
            fit.theta, fit.nuis = _least_squares(fwd, fit, free)
        se = np.sqrt(np.clip(np.diag(np.linalg.pinv(gw.T @ gw)), 1e-300, None))
        if np.all(np.abs(fit.theta - theta0) < se):
            break
        theta0 = fit.theta
    notes.extend(fit.error_model.notes)
    notes.extend(_near_bounds(fwd, fit))
    return fit


#: an estimate within this share of its allowed range from a bound is flagged
NEAR_BOUND = 0.01


def _near_bounds(fwd, fit: _Fit) -> list[str]:
    """Notes for the least-squares values that sit at or near an assumed hard bound (a
    Truth field's range, a bounded source's distribution): there the prior, not the
    readings, decides, and the result may be pulled by the bound."""
    b, out = fwd.builder, []
    rows = [(p.name, v, p.low, p.high) for p, v in zip(b.params, fit.theta, strict=True)]
    pri = nuisance_priors(fit.error_model)
    labels = [f"{name}[{i}]" if src.size > 1 else name for name, src in fit.error_model.nuisance
              for i in range(src.size)]
    rows += [(lab, v, lo, hi) for lab, v, (_, _, lo, hi) in zip(labels, fit.nuis, pri,
                                                                 strict=True)]
    for name, value, lo, hi in rows:
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
            continue
        if min(value - lo, hi - value) <= NEAR_BOUND * (hi - lo):
            side = "lower" if value - lo < hi - value else "upper"
            out.append(f"{name} = {value:.6g} lies at or near the {side} bound of its assumed "
                       f"range [{lo:.6g}, {hi:.6g}]: the bound, not the readings, may decide "
                       "it; check the set-up's stated range")
    return out


# --------------------------------------------------------------------------- what is sampled
@dataclass
class _Space:
    """The sampled coordinates and their Laplace approximation (mean and covariance)."""

    kept: list  # indices of the free parameters that are sampled
    held: dict  # name -> value of free parameters held at the least-squares estimate
    names: list  # sampled coordinates: kept parameters, nuisance elements, sigma
    units: dict
    center: np.ndarray  # (log sigma for a free noise)
    cov: np.ndarray
    free_noise: bool


def _internal_unit(setup, source: str) -> str:
    """Internal unit of a source's elements, from its set-up field's unit suffix."""
    from mtplan.models.protocol import fields_info

    unit = next((i.unit for i in fields_info(type(setup)) if i.name.startswith(source + "_")),
                "")
    return {"um": "mm", "nm": "mm", "mm": "mm", "urad": "rad", "mrad": "rad", "arcsec": "rad",
            "deg": "rad", "ppm": "1"}.get(unit.split("_")[0], "")


_DEAD = "does not affect the readings"
_TOGETHER = "is determined by the readings only together with other parameters"


def _rank_order(Jw, relevant, p, q, Jd=None):
    """Greedy rank: nuisance elements first, then parameters the measurands depend on.

    A column counts as in the others' span when it is so in the whitened Jacobian `Jw`
    or in `Jd` (the same rows weighted by each reading's own scatter only): an exact
    dependence (a scale factor times the coefficients it scales) is one in both, but
    whitening by correlated readings (an AR(1) path deviation) amplifies the finite
    differences' round-off, which is white, over a smooth effect, which it damps, and
    can lift the whitened residual above the tolerance.

    Returns the kept parameter indices, {index: reason} of the held ones, and for each
    one held for lying in the others' span its direction of no change of the readings
    (an array (p,): 1 at its own index, minus the regression on the kept ones).
    """
    order = list(range(p, p + q)) + [j for j in range(p) if relevant[j]] + \
        [j for j in range(p) if not relevant[j]]
    mats = [Jw] if Jd is None else [Jw, Jd]
    bases = [np.zeros((m.shape[0], 0)) for m in mats]
    kept, held = [], {}
    for j in order:
        nc = [float(np.linalg.norm(m[:, j])) for m in mats]
        if not nc[0] > 0:
            held[j] = _DEAD
            continue
        rs = []
        for m, basis, n_ in zip(mats, bases, nc, strict=True):
            r = m[:, j] / n_ - basis @ (basis.T @ (m[:, j] / n_))
            r -= basis @ (basis.T @ r)
            rs.append(r)
        if min(float(np.linalg.norm(r)) for r in rs) < RANK_TOL:
            held[j] = _TOGETHER
            continue
        bases = [np.hstack([b, (r / np.linalg.norm(r))[:, None]]) for b, r in zip(bases, rs,
                                                                                   strict=True)]
        if j < p:
            kept.append(j)
    kept = sorted(kept)
    cols = kept + list(range(p, p + q))
    null = {}
    for j in (j for j, why in held.items() if why == _TOGETHER):
        beta, *_ = np.linalg.lstsq(Jw[:, cols], Jw[:, j], rcond=None)
        v = np.zeros(p)
        v[j], v[kept] = 1.0, -beta[:len(kept)]
        null[j] = v
    return kept, held, null


def _held_notes(fwd, fit: _Fit, kept, held, null, G, Jw, cov, notes) -> None:
    """Refuse measurands that the readings do not determine; note what was held.

    A measurand is not determined when it depends on no sampled parameter, or when
    sampling a held direction under its default prior (``PRIOR_WIDTH`` standard errors
    of the held field alone) would change it by more than a tenth of its uncertainty.
    """
    b, names = fwd.builder, [m.name for m in fwd.measurands]
    gk = G[:, kept]
    u = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", gk, cov[:len(kept), :len(kept)], gk), 0))
    dead = [n for i, n in enumerate(names) if not np.any(gk[i] != 0)]
    for j, v in null.items():
        moved = np.abs(G @ v) * PRIOR_WIDTH / np.linalg.norm(Jw[:, j])
        dead += [n for i, n in enumerate(names) if moved[i] > 0.1 * u[i] and n not in dead]
    if dead:
        raise InvalidInput([
            f"The posterior of {fwd.proc.name} cannot give {', '.join(dead)}: the readings do "
            f"not determine {'them' if len(dead) > 1 else 'it'} (sampled: "
            f"{', '.join(b.names[j] for j in kept) or 'none'}; held: "
            f"{', '.join(b.names[j] for j in held) or 'none'}), so its uncertainty would be "
            "0 or unbounded; free the Truth fields it depends on or add readings"])
    for why in (_DEAD, _TOGETHER):
        group = [j for j, w in held.items() if w == why]
        if not group:
            continue
        cond = [n for i, n in enumerate(names) if why == _DEAD and np.any(G[i, group] != 0)]
        one = len(group) == 1
        verb = why if one else why.replace("does not", "do not").replace(
            "is determined", "are determined")
        notes.append(f"{', '.join(shown_with_unit(b.names[j], fit.theta[j]) for j in group)}: "
                     f"held there, since {'it' if one else 'they'} {verb}"
                     + (f" ({', '.join(cond)} conditional on {'it' if one else 'them'})"
                        if cond else ""))


def _scatter(model: ErrorModel, sigma) -> np.ndarray:
    """Each reading's own standard deviation under the error model (the covariance's
    diagonal)."""
    var = model.D0 + np.sum(model.U0**2, axis=1)
    if model.Dn is not None:
        var = var + sigma**2 * (model.Dn + np.sum(model.Un**2, axis=1))
    return np.sqrt(np.where(var > 0, var, 1.0))


def identify(fwd, fit: _Fit, notes) -> _Space:
    """Hold what the readings do not determine, refuse what cannot be reported, and the
    Laplace approximation of what is sampled."""
    proc, b = fwd.proc, fwd.builder
    pri = nuisance_priors(fit.error_model)
    p, q = fit.theta.size, pri.shape[0]
    steps = np.concatenate([b.steps(fit.theta), 1e-3 * pri[:, 1]])
    J = fwd.jacobian(fit.theta, fit.nuis if q else None, steps)
    Jw = fit.error_model.gaussian(fit.sigma).whiten(J.T).T
    prior_rows = np.hstack([np.zeros((q, p)), np.diag(1.0 / pri[:, 1])])
    Jw = np.vstack([Jw, prior_rows])
    Jd = np.vstack([J / _scatter(fit.error_model, fit.sigma)[:, None], prior_rows])
    G = fwd.measurand_gradient(fit.theta)
    kept, held, null = _rank_order(Jw, np.any(G != 0, axis=0), p, q, Jd)
    cols = kept + list(range(p, p + q))
    cov = np.linalg.pinv(Jw[:, cols].T @ Jw[:, cols])
    _held_notes(fwd, fit, kept, held, null, G, Jw, cov, notes)
    names = [b.names[j] for j in kept]
    units = {b.names[j]: b.params[j].unit for j in kept}
    for name, src in fit.error_model.nuisance:
        size = int(np.prod((*src.shape, *src.distribution.event_shape), dtype=np.int64))
        el = [name] if size == 1 else [f"{name}[{i}]" for i in range(size)]
        names += el
        units.update(dict.fromkeys(el, _internal_unit(fwd.setup, name)))
    center = np.concatenate([fit.theta[kept], fit.nuis])
    free = fit.error_model.Dn is not None
    if free:
        _check_noise_dof(fwd, fit, len(cols))
        ns = proc.readings.noise_source
        names.append(f"sigma_{ns}")
        units[f"sigma_{ns}"] = _internal_unit(fwd.setup, ns)
        info = fit.error_model.gaussian().fisher_log_sigma(fit.sigma)
        cov = np.block([[cov, np.zeros((cov.shape[0], 1))],
                        [np.zeros((1, cov.shape[0])), np.array([[1.0 / info]])]])
        center = np.append(center, math.log(fit.sigma))
    held_values = {b.names[j]: float(fit.theta[j]) for j in held}
    b.varying = kept  # the held ones are constant from here on
    return _Space(kept, held_values, names, units, center, cov, free)


def _check_noise_dof(fwd, fit: _Fit, n_sampled: int) -> None:
    proc = fwd.proc
    rank = fit.error_model.gaussian().rank
    dof = rank - n_sampled
    if dof >= MIN_NOISE_DOF:
        return
    from mtplan.models.protocol import fields_info

    ns = proc.readings.noise_source
    fld = next((i.name for i in fields_info(type(fwd.setup)) if i.name.startswith(ns + "_")),
               ns)
    raise InvalidInput([
        f"The noise of {proc.name} cannot be left free: {rank} reading(s) with noise and "
        f"{n_sampled} sampled parameter(s) leave {dof} degree(s) of freedom, and a free noise "
        f"needs at least {MIN_NOISE_DOF} (fewer give it no finite posterior variance); give "
        f"the noise (--noise SIGMA, the standard deviation of {ns} in "
        f"{_internal_unit(fwd.setup, ns)}) or keep the set-up's ({fld} = "
        f"{getattr(fwd.setup, fld, '?')})"])


# --------------------------------------------------------------------------- likelihood
class _LogPosterior:
    """Vectorised log-posterior of the sampled coordinates (n_walkers, ndim) -> (n_walkers,)."""

    def __init__(self, fwd, fit: _Fit, space: _Space, priors: Mapping):
        self.fwd, self.fit, self.space = fwd, fit, space
        self.gauss = fit.error_model.gaussian()
        self.pk, self.q = len(space.kept), nuisance_priors(fit.error_model).shape[0]
        self.nuis = nuisance_priors(fit.error_model)
        se = np.sqrt(np.clip(np.diag(space.cov)[:self.pk], 1e-300, None))
        self.mu, self.sd = space.center[:self.pk], PRIOR_WIDTH * se
        self.user = [(space.names.index(k), v) for k, v in priors.items()]
        self.default = np.array([n not in priors for n in space.names[:self.pk]], dtype=bool)
        self.nuis_default = np.array([n not in priors for n in
                                      space.names[self.pk:self.pk + self.q]], dtype=bool)
        if space.free_noise:
            ls = space.center[-1]
            self.log_sigma = (ls - math.log(NOISE_RANGE), ls + math.log(NOISE_RANGE))
            self.sigma_default = space.names[-1] not in priors

    def theta(self, coords: np.ndarray) -> np.ndarray:
        """Every free parameter for sampled rows: the held ones at their values."""
        th = np.repeat(self.fit.theta[None, :], coords.shape[0], axis=0)
        th[:, self.space.kept] = coords[:, :self.pk]
        return th

    def prior_text(self) -> dict:
        out = {}
        for i, name in enumerate(self.space.names[:self.pk]):
            out[name] = (f"normal(mean {self.mu[i]:.6g}, std {self.sd[i]:.3g}) = least-squares "
                         f"estimate +- {PRIOR_WIDTH:g} standard errors, within the field's range")
        for name, (mean, sd, lo, hi) in zip(self.space.names[self.pk:self.pk + self.q], self.nuis,
                                            strict=True):
            out[name] = (f"the set-up's: uniform on [{lo:.4g}, {hi:.4g}]" if np.isfinite(lo)
                         else f"the set-up's: normal(mean {mean:.4g}, std {sd:.4g})")
        if self.space.free_noise:
            lo, hi = (math.exp(v) for v in self.log_sigma)
            out[self.space.names[-1]] = (f"log-uniform on [{lo:.3g}, {hi:.3g}] (Jeffreys; "
                                         f"maximum-likelihood value x/÷ {NOISE_RANGE:g})")
        for i, dist in self.user:
            out[self.space.names[i]] = f"user: {dist!r}"
        return out

    def __call__(self, coords: np.ndarray) -> np.ndarray:
        coords = np.atleast_2d(coords)
        m, pk, q = coords.shape[0], self.pk, self.q
        out = np.full(m, -np.inf)
        th = self.theta(coords)
        nu = coords[:, pk:pk + q]
        ok = self.fwd.builder.valid(th) & np.all(np.isfinite(coords), axis=1)
        lp = -0.5 * np.sum(np.where(self.default, ((coords[:, :pk] - self.mu) / self.sd) ** 2, 0.0),
                           axis=1)
        if q:
            mean, sd, lo, hi = self.nuis.T
            normal = ~np.isfinite(lo)
            lp -= 0.5 * np.sum(np.where(self.nuis_default & normal, ((nu - mean) / sd) ** 2, 0.0),
                               axis=1)
            ok &= np.all(~self.nuis_default | normal | ((nu >= lo) & (nu <= hi)), axis=1)
        log_sigma = None
        if self.space.free_noise:
            log_sigma = coords[:, -1]
            if self.sigma_default:
                ok &= (log_sigma >= self.log_sigma[0]) & (log_sigma <= self.log_sigma[1])
        for i, dist in self.user:
            x = np.exp(coords[:, i]) if self.space.free_noise and i == coords.shape[1] - 1 \
                else coords[:, i]
            with np.errstate(all="ignore"):
                lp = lp + np.asarray(dist.logpdf(x), dtype=float)
                if self.space.free_noise and i == coords.shape[1] - 1:
                    lp = lp + coords[:, i]  # Jacobian of sigma = exp(log sigma)
        idx = np.flatnonzero(ok & np.isfinite(lp))
        if idx.size == 0:
            return out
        pred, good = self.fwd.predict(th[idx], nu[idx] if q else None)
        res = self.fwd.y - pred
        res -= self.fit.correction  # in place: (m, readings) arrays are megabytes
        ll = self.gauss.loglike(res, None if log_sigma is None else log_sigma[idx])
        good &= np.isfinite(ll)
        out[idx[good]] = lp[idx[good]] + ll[good]
        return out


# --------------------------------------------------------------------------- the run
def _run(logpost: _LogPosterior, space: _Space, root, o: PosteriorOptions, label: str):
    """Walkers from the Laplace approximation; independence + stretch moves; run_ensembles."""
    ndim = len(space.names)
    n_walkers = 16 if o.n_walkers is None else o.n_walkers
    least = 2 * ndim if o.moves is not None else 4  # the stretch move needs 2 ndim
    p = Problems("sample_posterior")
    if p.number("n_walkers", n_walkers, integer=True, low=least) and int(n_walkers) % 2:
        p.add("n_walkers", n_walkers, f"an even int >= {least}")
    p.raise_if_any()
    factor = psd_factor(space.cov)  # positive definite by construction
    cov = factor @ factor.T
    moves = o.moves if o.moves is not None else mixed_moves(space.center, cov)
    sampler = o.sampler(label).replace(n_walkers=int(n_walkers),
                                       n_ensembles=int(o.n_ensembles),
                                       max_steps=int(o.max_steps))
    run = run_ensembles(logpost, space.center, factor, root=root, moves=moves, options=sampler)
    return run, int(n_walkers)


# --------------------------------------------------------------------------- diagnostics
def _natural(chains: np.ndarray, space: _Space) -> np.ndarray:
    """Chains in the parameters' own units: a free noise is sampled as log sigma."""
    out = chains.copy()
    if space.free_noise:
        out[..., -1] = np.exp(out[..., -1])
    return out


def _diagnostics(fwd, logpost: _LogPosterior, space: _Space, run, burn_tau, coverage) -> dict:
    """Kept samples of parameters and measurands, their statistics, tau, R-hat and ESS."""
    discard, thin = run.burn_and_thin(burn_tau)
    kept = run.chains[:, discard::thin]  # (E, s, W, D)
    values = _natural(kept, space)
    rows = logpost.theta(kept.reshape(-1, kept.shape[-1]))
    mvals = fwd.measurand_values(rows)
    mchains = mvals.reshape(*kept.shape[:3], len(fwd.measurands))
    all_chains = np.concatenate([values, mchains], axis=-1)
    all_names = list(space.names) + [m.name for m in fwd.measurands]
    rhat_all = split_rhat(all_chains)
    draws = kept.shape[1] * kept.shape[2]
    tau_kept = np.array([integrated_time(all_chains[e]) for e in range(all_chains.shape[0])])
    ess_all = np.sum(draws / np.maximum(tau_kept, 1.0), axis=0)
    tau_max = run.tau.max(axis=0)
    tau = {n: float(tau_max[i]) for i, n in enumerate(space.names)}
    for j, m in enumerate(fwd.measurands):
        tau[m.name] = float(np.max(tau_kept[:, len(space.names) + j]) * thin)
    a = (1 - coverage) / 2
    out = {"samples": {}, "mean": {}, "std": {}, "low": {}, "high": {}, "rhat": {}, "ess": {},
           "tau": tau, "discard": discard, "thin": thin}
    for i, name in enumerate(all_names):
        x = all_chains[..., i].reshape(-1)
        out["samples"][name] = x
        out["mean"][name] = float(np.mean(x))
        out["std"][name] = float(np.std(x, ddof=1)) if x.size > 1 else math.nan
        out["low"][name], out["high"][name] = (float(v) for v in np.quantile(x, [a, 1 - a]))
        out["rhat"][name] = float(rhat_all[i])
        out["ess"][name] = float(ess_all[i])
    return out


# --------------------------------------------------------------------------- result
def _result(fwd, fit: _Fit, space: _Space, logpost, run, diag, *, mode, root, n_walkers,
            coverage, t_start, notes) -> PosteriorResult:
    proc = fwd.proc
    units = {m.name: m.unit for m in fwd.measurands} | space.units
    start = dict(zip(space.names, _natural(space.center[None], space)[0].tolist(), strict=True))
    ns = proc.readings.noise_source
    sigma = fit.sigma if fit.sigma is not None else (
        float(np.max(np.asarray(fwd.sources[ns].distribution.std))) if ns else None)
    seed = root.entropy if isinstance(root.entropy, int) else list(root.entropy)
    return PosteriorResult(
        procedure=proc, setup=fwd.setup, measurands=fwd.measurands,
        parameters=tuple(space.names), samples=diag["samples"], mean=diag["mean"],
        std=diag["std"], low=diag["low"], high=diag["high"], coverage=float(coverage),
        tau=diag["tau"], rhat=diag["rhat"], ess=diag["ess"], acceptance=run.acceptance,
        converged=run.converged, chains=_natural(run.chains, space), log_prob=run.log_prob,
        discard=diag["discard"], thin=diag["thin"], start=start, priors=logpost.prior_text(),
        noise={"source": ns, "mode": {"known": "given"}.get(mode, mode), "sigma": sigma},
        budget=dict(fit.error_model.how), held=dict(space.held), units=units, seed=seed,
        n_walkers=n_walkers, n_steps=run.steps, wall_s=time.perf_counter() - t_start,
        notes=notes)


def _check_converged(result: PosteriorResult, run, o: PosteriorOptions) -> None:
    """Raise NotConvergedError carrying the result (or warn, when allowed) if not converged."""
    if run.converged:
        return
    why = (f"its time budget of {o.max_seconds:g} s" if run.stopped == "max_seconds"
           else f"{run.steps} steps per ensemble")
    msg = (f"The posterior of {result.procedure.name} did not converge in {why} (needs > "
           f"{o.n_tau:g} tau with tau settled and R-hat < {o.rhat_max:g}; tau max "
           f"{float(np.max(run.tau.max(axis=0))):.1f} steps, R-hat max "
           f"{float(np.max(run.rhat)):.4f}); raise max_steps (--max-steps) or the time budget, "
           "or pass allow_unconverged=True for the flagged partial result.")
    result.notes.append("NOT CONVERGED: " + msg)
    if not o.allow_unconverged:
        raise NotConvergedError(msg, result)
    warnings.warn(msg, UnconvergedWarning, stacklevel=3)


def _check_priors(priors, names) -> dict:
    priors = dict(priors or {})
    p = Problems("sample_posterior")
    unknown = [k for k in priors if k not in names]
    if unknown:
        p.add_text(f"The 'priors' parameter of sample_posterior names {unknown}; the sampled "
                   f"parameters are {names}.")
    for k, v in priors.items():
        if not hasattr(v, "logpdf"):
            p.add_text(f"The prior of {k!r} must have a logpdf method (a scipy.stats "
                       f"distribution). Got {type(v).__name__} instead.")
    p.raise_if_any()
    return priors


# --------------------------------------------------------------------------- main entry
def sample_posterior(
    procedure,
    setup,
    readings,
    *,
    options: PosteriorOptions | None = None,
    **option_overrides,
) -> PosteriorResult:
    """Sample the posterior of a procedure's measurands given one set of readings.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
        The set-up the readings were taken with; its error sources (sizes and
        distributions) are the likelihood's error budget.
    readings : dict of str to array
        A batch of one (leading axis 1), as ``procedure.readings.from_frame`` returns.
    options : PosteriorOptions, optional
        What is sampled (free fields, noise, priors, start, truth), the sampler's walkers
        and stopping rules, the coverage, the seed (:class:`PosteriorOptions`); any of its
        fields may be given as a keyword instead (``noise="free", rng=0, max_steps=2000``).

    Returns
    -------
    PosteriorResult
    """
    import sys

    from mtplan._parallel import one_blas_thread
    from mtplan.models import get

    t_start = time.perf_counter()
    o = PosteriorOptions.of(options, **option_overrides)
    proc = get(procedure)
    o = o.replace(progress=sys.stderr.isatty() if o.progress is None else bool(o.progress))
    mode, sigma = _check_arguments(proc, setup, readings, o)
    base = proc.Truth() if o.truth is None else o.truth
    if not isinstance(base, proc.Truth):
        raise InvalidInput([f"The 'truth' parameter of sample_posterior must be a {proc.name} "
                            f"Truth. Got {type(base).__name__} instead."])
    root = as_seed_sequence(o.rng)
    notes: list[str] = []
    builder = TruthBuilder(base, truth_parameters(proc, base, o.fields))
    fwd = Forward(proc, setup, readings, builder, batch=o.batch)
    if not fwd.mask.all():
        notes.append(f"{int((~fwd.mask).sum())} reading(s) missing from the file (NaN) are left "
                     "out of the likelihood")
    # one BLAS thread: the matrices are small and many, and threads only wait for each other
    with one_blas_thread():
        theta0 = initial_theta(proc, setup, readings, builder, o.start, o.estimator, notes)
        fit = start_fit(fwd, theta0, mode, sigma, notes)
        space = identify(fwd, fit, notes)
        logpost = _LogPosterior(fwd, fit, space, _check_priors(o.priors, space.names))
        run, n_walkers = _run(logpost, space, root, o, proc.name)
        diag = _diagnostics(fwd, logpost, space, run, o.burn_tau, o.coverage)
    result = _result(fwd, fit, space, logpost, run, diag, mode=mode, root=root,
                     n_walkers=n_walkers, coverage=o.coverage, t_start=t_start, notes=notes)
    _check_converged(result, run, o)
    return result
