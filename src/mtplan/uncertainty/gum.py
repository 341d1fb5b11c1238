"""GUM law of propagation of uncertainty (JCGM 100) and its validation (JCGM 101 clause 8).

The model is linearised at the input estimates with numerical sensitivity
coefficients: central differences with steps of ``1e-3 u(x_i)`` and ``2e-3 u(x_i)``
combined by Richardson extrapolation (error of order h**4), all perturbed points in
one vectorised call of the model. A step proportional to the input's own
uncertainty keeps the derivative local (the GUM's first-order view) while staying
far above rounding noise.

Standard uncertainties follow the GUM's conventions: a scaled and shifted t input
``StudentT(loc, scale, dof)`` contributes ``u = scale`` with ``dof`` degrees of
freedom (the Type A evaluation behind it), whereas the Monte Carlo method draws it
with its full variance ``scale**2 dof/(dof-2)``; that is why JCGM 101 9.5 finds a
larger u by Monte Carlo. Other inputs contribute their standard deviation with
infinite degrees of freedom unless `dof` says otherwise. The coverage factor is the
normal one, or Student's t at the Welch-Satterthwaite effective degrees of freedom
when some input has finite degrees of freedom.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from mtplan.uncertainty.coverage import K, normal_coverage
from mtplan._validate import Problems
from mtplan.uncertainty.distributions import Distribution, MultivariateNormal, StudentT
from mtplan.uncertainty.montecarlo import (
    INTERVALS,
    MCResult,
    as_outputs,
    check_inputs,
    numerical_tolerance,
)

__all__ = ["GUMResult", "Cost", "PATHS", "linearize", "validate", "sensitivities",
           "ValidationResult"]

_REL_STEP = 1e-3


#: How a propagation found its sensitivities (``GUMResult.path``): the procedure's closed
#: form (its derivative hook), the whole chain (model, or forward model and estimator, by
#: Richardson central differences per input), or the chain rule (the readings' effects
#: times the estimator's map, :mod:`mtplan.evaluation.first_order`).
PATHS = ("closed form", "whole chain", "chain rule")


@dataclass(frozen=True)
class Cost:
    """What finding a propagation's sensitivities took: ``seconds`` of wall time and
    ``cpu_seconds`` of the computing thread's CPU time (what it takes on an idle machine,
    whatever else the machine is doing)."""

    seconds: float
    cpu_seconds: float


@dataclass(eq=False)
class GUMResult:
    """Result of the GUM law of propagation (first order): the one result of every
    linearisation, of a generic model (:func:`linearize`) and of a procedure's set-up
    (:func:`mtplan.evaluation.first_order.first_order`).

    Attributes
    ----------
    names : tuple of str
        Output (measurand) names.
    inputs : tuple of str
        Input component names (``name`` or ``name[j]`` for vector inputs).
    groups : tuple of str
        For each input component, the input (or error source) it belongs to.
    sensitivity : array (n_outputs, n_components)
        Sensitivity coefficients c_ij = df_i/dx_j.
    input_std : array (n_components,)
        Standard uncertainty of each input component.
    input_cov : array (n_components, n_components), optional
        Covariance of the input components where they correlate (None: independent, the
        covariance is ``diag(input_std**2)``, never formed).
    dof : array (n_outputs,)
        Welch-Satterthwaite effective degrees of freedom (inf when all inputs are exact).
    coverage : float
        Coverage probability of the interval ``value +- k u``.
    units : tuple of str
        Each output's unit ("" where the model does not say).
    path : str
        How the sensitivities were found, one of :data:`PATHS`; ``method`` says it in
        words for a reader.
    cost : Cost
        What finding them took.
    value : array (n_outputs,)
        Model value at the input estimates (where the propagation did not need it, taken
        when first asked for, from ``value_of``).
    """

    names: tuple
    inputs: tuple
    groups: tuple
    sensitivity: np.ndarray
    input_std: np.ndarray
    dof: np.ndarray
    coverage: float = 0.95
    input_cov: np.ndarray | None = None
    units: tuple = ()
    path: str = "whole chain"
    method: str = "GUM law of propagation"
    cost: Cost = field(default_factory=lambda: Cost(0.0, 0.0))
    value_of: Callable | None = field(default=None, repr=False)
    _value: np.ndarray | None = field(default=None, repr=False)
    _cov: np.ndarray | None = field(default=None, init=False, repr=False)
    _k: np.ndarray | None = field(default=None, init=False, repr=False)

    @property
    def value(self) -> np.ndarray:
        if self._value is None:
            self._value = np.asarray(self.value_of(), dtype=float)
        return self._value

    def __getstate__(self) -> dict:
        """The state to pickle (a worker's result sent back, a study's cache): the value
        taken, never the closure that would compute it (a local function, not picklable)."""
        state = self.__dict__.copy()
        if state.get("_value") is None and state.get("value_of") is not None:
            state["_value"] = np.asarray(self.value_of(), dtype=float)
        state["value_of"] = None
        return state

    @property
    def mean(self) -> np.ndarray:
        """The estimate y = f(x) (alias of ``value``, to match :class:`MCResult`)."""
        return self.value

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the outputs (n_outputs, n_outputs), C V C^T."""
        if self._cov is None:
            c = self.sensitivity
            self._cov = (c @ self.input_cov @ c.T if self.input_cov is not None
                         else (c * self.input_std**2) @ c.T)
        return self._cov

    @property
    def variance(self) -> np.ndarray:
        """u(y)^2 per output: the covariance's diagonal, without forming the covariance
        (m x n work, not m^2 x n: thousands of outputs, a set-up's errors at every position
        along the travel) unless it is formed already or the inputs are correlated."""
        if self._cov is None and self.input_cov is None:
            c = self.sensitivity
            return ((c * self.input_std**2) * c).sum(axis=1)
        return np.diag(self.cov)

    @property
    def std(self) -> np.ndarray:
        """Combined standard uncertainty u(y) per output."""
        return np.sqrt(self.variance)

    @property
    def k(self) -> np.ndarray:
        """Coverage factor per output for `coverage` (normal, or Student's t at ``dof``)."""
        if self._k is None:
            self._k = coverage_factor(self.dof, self.coverage)
        return self._k

    @property
    def U_coverage(self) -> np.ndarray:  # noqa: N802 - U of the GUM
        """The coverage of ``value ± U``, U = 2u (:mod:`mtplan.uncertainty.coverage`), that
        a first-order result can give: a normal distribution's (Student's t at ``dof``),
        assumed, not shown."""
        return np.broadcast_to(normal_coverage(K, self.dof), (len(self.names),))

    @property
    def low(self) -> np.ndarray:
        return self.value - self.k * self.std

    @property
    def high(self) -> np.ndarray:
        return self.value + self.k * self.std

    @property
    def sources(self) -> tuple:
        """The inputs (error sources) the components belong to, in order."""
        return tuple(dict.fromkeys(self.groups))

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"No output named {name!r}; outputs are {', '.join(self.names)}") from None

    def u(self) -> dict:
        """{output: standard uncertainty}."""
        return {n: float(s) for n, s in zip(self.names, self.std, strict=True)}

    def summary(self):
        """DataFrame indexed by output: mean, std, low, high, k, dof."""
        import pandas as pd

        return pd.DataFrame(
            {"mean": self.value, "std": self.std, "low": self.low, "high": self.high,
             "k": self.k, "dof": self.dof},
            index=pd.Index(self.names, name="output"),
        )

    def group_variance(self) -> tuple[tuple, np.ndarray]:
        """(groups, V) with V[i, g] the variance of output i due to group g alone."""
        groups = self.sources
        gidx = np.array([groups.index(g) for g in self.groups])
        var = np.zeros((len(self.names), len(groups)))
        for g in range(len(groups)):
            sel = np.flatnonzero(gidx == g)
            if sel[-1] - sel[0] + 1 == sel.size:  # a run of inputs: views, no copy
                run = slice(sel[0], sel[-1] + 1)
                c = self.sensitivity[:, run]
                v = None if self.input_cov is None else self.input_cov[run, run]
                u2 = self.input_std[run] ** 2
            else:
                c = self.sensitivity[:, sel]
                v = None if self.input_cov is None else self.input_cov[np.ix_(sel, sel)]
                u2 = self.input_std[sel] ** 2
            var[:, g] = (((c @ v) if v is not None else c * u2) * c).sum(axis=1)
        return groups, var

    def by_source(self) -> dict:
        """{output: {source: {"u": its part of u, "share": its share of u^2}}}: the
        budget (:meth:`budget`) as plain numbers, keyed by output and source."""
        groups, var = self.group_variance()
        total = self.variance
        return {out: {src: {"u": float(np.sqrt(max(var[i, j], 0.0))),
                            "share": float(var[i, j] / total[i]) if total[i] > 0 else 0.0}
                      for j, src in enumerate(groups)} for i, out in enumerate(self.names)}

    def budget(self):
        """The uncertainty budget: one row per output and input (or error source).

        Columns: ``output``, ``input``, ``u_input`` (root of the group's summed input
        variance), ``sensitivity`` (for scalar inputs; NaN for groups), ``contribution``
        (the standard uncertainty of the output due to that input alone) and
        ``share`` (its fraction of u(y)**2; shares add to 1 for uncorrelated inputs).
        """
        import pandas as pd

        groups, var = self.group_variance()
        gidx = np.array([groups.index(g) for g in self.groups])
        rows = []
        total = self.variance
        for i, out in enumerate(self.names):
            for g, name in enumerate(groups):
                sel = np.flatnonzero(gidx == g)
                u_in = math.sqrt(float(np.trace(self.input_cov[np.ix_(sel, sel)]))
                                 if self.input_cov is not None
                                 else float(np.sum(self.input_std[sel] ** 2)))
                sens = float(self.sensitivity[i, sel[0]]) if sel.size == 1 else math.nan
                share = var[i, g] / total[i] if total[i] > 0 else 0.0
                rows.append((out, name, u_in, sens, math.sqrt(max(var[i, g], 0.0)), share))
        return pd.DataFrame(
            rows, columns=["output", "input", "u_input", "sensitivity", "contribution", "share"]
        )


def _components(inputs: Mapping[str, Distribution], dof: Mapping[str, float]):
    names, groups, x, blocks, nus = [], [], [], [], []
    for name, dist in inputs.items():
        if isinstance(dist, MultivariateNormal):
            n = len(dist.mu)
            names += [f"{name}[{j}]" for j in range(n)]
            groups += [name] * n
            x += list(dist.mean)
            blocks.append(dist.covariance)
            nus += [dof.get(name, math.inf)] * n
        else:
            names.append(name)
            groups.append(name)
            if isinstance(dist, StudentT):
                x.append(float(dist.loc))
                u = float(dist.scale)
                nus.append(dof.get(name, float(dist.dof)))
            else:
                x.append(float(dist.mean))
                u = float(dist.std)
                nus.append(dof.get(name, math.inf))
            blocks.append(np.array([[u * u]]))
    size = len(x)
    cov = np.zeros((size, size))
    pos = 0
    for b in blocks:
        n = b.shape[0]
        cov[pos : pos + n, pos : pos + n] = b
        pos += n
    return tuple(names), tuple(groups), np.array(x), cov, np.array(nus, dtype=float)


def sensitivities(
    evaluate: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    u: np.ndarray,
    *,
    max_batch: int = 4096,
) -> tuple[np.ndarray, np.ndarray]:
    """Value and Jacobian of a batch-first function at `x` by Richardson central differences.

    Parameters
    ----------
    evaluate : callable
        Maps an array of shape (m, n) of input points to an array of shape (m, k).
    x : array of shape (n,)
        Expansion point.
    u : array of shape (n,)
        Scale of each input (its standard uncertainty); sets the step. Where it is
        zero the step falls back to ``cbrt(eps) * max(|x|, 1)``.
    max_batch : int
        Largest number of points evaluated in one call.

    Returns
    -------
    value : array (k,)
    jacobian : array (k, n)
    """
    n = x.size
    h = np.where(u > 0, _REL_STEP * u, np.cbrt(np.finfo(float).eps) * np.maximum(np.abs(x), 1.0))
    steps = np.concatenate([[0.0], h, -h, 2 * h, -2 * h])
    cols = np.concatenate([[0], np.tile(np.arange(n), 4)])
    total = 4 * n + 1
    chunks = []
    for s in range(0, total, max_batch):  # build only one chunk of points at a time
        e = min(s + max_batch, total)
        points = np.repeat(x[None, :], e - s, axis=0)
        points[np.arange(e - s), cols[s:e]] += steps[s:e]
        chunks.append(np.asarray(evaluate(points), dtype=float))
    values = np.concatenate(chunks)
    f0 = values[0]
    fp, fm, f2p, f2m = (values[1 + j * n : 1 + (j + 1) * n] for j in range(4))
    d1 = (fp - fm) / (2 * h[:, None])
    d2 = (f2p - f2m) / (4 * h[:, None])
    jac = ((4 * d1 - d2) / 3).T
    return f0, jac


def coverage_factor(dof: np.ndarray, p: float) -> np.ndarray:
    from scipy import stats

    k = np.full(dof.shape, stats.norm.ppf((1 + p) / 2))
    finite = np.isfinite(dof)
    if finite.any():
        k[finite] = stats.t.ppf((1 + p) / 2, dof[finite])
    return k


def welch_satterthwaite(sens: np.ndarray, u: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Effective degrees of freedom per output (GUM G.4.1) for uncorrelated inputs."""
    contrib = (sens * u[None, :]) ** 2  # (k, n)
    total = contrib.sum(axis=1)
    finite = np.isfinite(nu)
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = (contrib[:, finite] ** 2 / nu[finite][None, :]).sum(axis=1)
        out = np.where(denom > 0, total**2 / np.where(denom > 0, denom, 1), np.inf)
    return out


def linearize(
    model: Callable,
    inputs: Mapping[str, Distribution],
    *,
    coverage: float = 0.95,
    dof: Mapping[str, float] | None = None,
) -> GUMResult:
    """GUM law of propagation of uncertainty for a vectorised model.

    Parameters
    ----------
    model : callable
        As for :func:`~mtplan.uncertainty.propagate`.
    inputs : mapping of str to Distribution
        Input quantities; their means are the estimates, their standard deviations
        the standard uncertainties (``scale`` for a StudentT, see the module notes).
    coverage : float
        Coverage probability of the interval y +- k u(y).
    dof : mapping of str to float, optional
        Degrees of freedom of an input's standard uncertainty (overrides the default).

    Returns
    -------
    GUMResult
    """
    p = Problems("linearize")
    check_inputs(p, model, inputs)
    p.number("coverage", coverage, low=0, high=1, low_open=True, high_open=True)
    dof = dict(dof or {})
    for name, nu in dof.items():
        p.require(isinstance(inputs, Mapping) and name in inputs, "dof", name, "keyed by input names")
        p.number(f"dof[{name!r}]", nu, low=0, low_open=True, finite=False)
    p.raise_if_any()
    names, groups, x, cov, nus = _components(inputs, dof)
    slices = {}
    pos = 0
    for name, dist in inputs.items():
        n = len(dist.mu) if isinstance(dist, MultivariateNormal) else 1
        slices[name] = (pos, n)
        pos += n
    out_names: list[str] = []

    def evaluate(points):
        kw = {}
        for name, (s, n) in slices.items():
            dist = inputs[name]
            kw[name] = points[:, s : s + n] if isinstance(dist, MultivariateNormal) else points[:, s]
        outs = as_outputs(model(**kw), points.shape[0])
        if not out_names:
            out_names.extend(outs)
        return np.column_stack(list(outs.values()))

    u = np.sqrt(np.diag(cov))
    start = time.perf_counter(), time.thread_time()
    f0, jac = sensitivities(evaluate, x, u)
    cost = Cost(time.perf_counter() - start[0], time.thread_time() - start[1])
    return GUMResult(
        names=tuple(out_names),
        inputs=names,
        groups=groups,
        sensitivity=jac,
        input_std=u,
        input_cov=cov,
        dof=welch_satterthwaite(jac, u, nus),
        coverage=coverage,
        units=("",) * len(out_names),
        path="whole chain",
        method="GUM law of propagation, sensitivities by Richardson central differences",
        cost=cost,
        _value=f0,
    )


@dataclass
class ValidationResult:
    """Outcome of JCGM 101 clause 8 per output (see :func:`validate`)."""

    table: object  # pandas DataFrame

    @property
    def valid(self) -> bool:
        return bool(self.table["valid"].all())

    def __repr__(self):
        return f"ValidationResult(valid={self.valid})\n{self.table}"


def validate(mc_result: MCResult, gum_result: GUMResult, digits: int = 2) -> ValidationResult:
    """Validate the GUM uncertainty framework against Monte Carlo (JCGM 101 clause 8).

    For each output, d_low = |y - U_p - y_low| and d_high = |y + U_p - y_high| compare
    the end points of the GUM interval y +- U_p with the Monte Carlo interval; the GUM
    result is valid when both are at most the numerical tolerance of u(y) (the GUM's
    u) at `digits` significant digits. The Monte Carlo interval should be the
    probabilistically symmetric one at the same coverage probability.

    Returns
    -------
    ValidationResult
        ``table``: a DataFrame indexed by output with columns ``u_gum``, ``u_mc``,
        ``delta``, ``d_low``, ``d_high`` and ``valid``; ``valid``: all outputs pass.
    """
    import pandas as pd

    p = Problems("validate")
    p.require(isinstance(mc_result, MCResult), "mc_result", type(mc_result).__name__, "an MCResult")
    p.require(isinstance(gum_result, GUMResult), "gum_result", type(gum_result).__name__, "a GUMResult")
    p.number("digits", digits, integer=True, low=1, high=6)
    if not p:
        p.require(set(gum_result.names) <= set(mc_result.names), "gum_result", gum_result.names,
                  f"outputs that the Monte Carlo result has ({', '.join(mc_result.names)})")
        p.require(math.isclose(mc_result.coverage, gum_result.coverage), "coverage",
                  (mc_result.coverage, gum_result.coverage), "the same in both results")
        p.require(mc_result.interval in INTERVALS, "interval", mc_result.interval, "known")
    p.raise_if_any()
    rows = []
    for i, name in enumerate(gum_result.names):
        j = mc_result.index(name)
        y, u, k = gum_result.value[i], gum_result.std[i], gum_result.k[i]
        d_low = abs(y - k * u - mc_result.low[j])
        d_high = abs(y + k * u - mc_result.high[j])
        delta = numerical_tolerance(u, digits)
        rows.append((name, u, mc_result.std[j], delta, d_low, d_high, d_low <= delta and d_high <= delta))
    table = pd.DataFrame(rows, columns=["output", "u_gum", "u_mc", "delta", "d_low", "d_high", "valid"])
    return ValidationResult(table.set_index("output"))
