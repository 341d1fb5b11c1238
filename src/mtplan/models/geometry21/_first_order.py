"""geometry21's first-order uncertainty, identifiability and report extras.

Built on the shared machinery (:mod:`mtplan.fitting.linear`): the joint model's
Jacobian at zero error (:func:`~mtplan.models.geometry21.joint_ident`), its null space
and each estimator's first-order map from readings and error sources to the estimated
coefficients. Every public name here is re-exported by :mod:`mtplan.models.geometry21`.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import Problems
from mtplan.fitting.effects import source_response
from mtplan.fitting.linear import function_status, null_space_table
from mtplan.models.geometry21._estimators import ESTIMATORS, check_estimator, estimate_theta
from mtplan.models.geometry21._layout import Geometry, geometry
from mtplan.models.geometry21._maps import mapped_source_response, patent_map
from mtplan.models.geometry21._model import RANK_TOL, joint_ident, param_names
from mtplan.models.geometry21._path import repeatability_filter
from mtplan.models.geometry21._physics import forward, measurand_map, measurands, sources, true_values
from mtplan.models.geometry21._physics import sources as _sources  # a parameter's name below
from mtplan.models.protocol import active_sources, zero_errors
from mtplan.models.geometry21._setup import (
    AXIS,
    KIND,
    NAMES,
    WHITE,
    Setup,
    Truth,
    sizeless,
    truth_coefficients,
    truth_rows,
)

#: the procedure's name in messages
_OWNER = "geometry21"

if TYPE_CHECKING:  # pandas only where a table is made: not in a Monte Carlo's workers
    import pandas as pd


def _one_blas_thread(fn):
    """Run `fn` with one BLAS thread: its products are small (a few thousand readings by
    ~100 parameters), where threads only wait on each other, and on a loaded machine they
    spin for many times the work (the designer's live numbers)."""
    @functools.wraps(fn)
    def run(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)

    return run


@functools.lru_cache(maxsize=8)
def _patent_response(setup: Setup) -> np.ndarray:
    """B (n_par, n_par): the patent's estimated parameters' first-order response to the
    true ones (its derivative at the noise-free readings times the Jacobian)."""
    ji = joint_ident(setup)
    return patent_map(setup, ji["r0"]) @ ji["jac"]


def _owners(geo: Geometry) -> np.ndarray:
    """The function (or "mounting") each parameter belongs to."""
    owner = np.empty(geo.n_par, dtype=object)
    for name, (_, sl) in geo.layout.items():
        owner[sl] = name
    owner[geo.n_coef:] = "mounting"
    return owner


def _unit(name: str) -> float:
    """Display factor of an error function: urad for angles, um for lengths."""
    return 1e6 if KIND[name] in ("ang", "sq") else 1e3


def identifiability(setup: Setup | None = None, estimator: str = "joint") -> pd.DataFrame:
    """Per-measurand status of all 21 error functions for one estimator, at any set-up.

    Parameters
    ----------
    setup : Setup, optional (defaults)
    estimator : {'joint', 'joint_linear', 'patent'}

    Returns
    -------
    DataFrame indexed by the 21 ISO names with columns ``status`` ('identified',
    'unidentifiable', 'no effect' for the data; for the patent estimator also
    'biased'), ``listed`` (whether it is a measurand at this set-up, i.e. determined by
    the data), ``confounded_with`` (for unidentifiable ones: the functions sharing the null
    space; for biased ones: the true errors that bias the estimate at first order), and
    ``first_order_bias`` (for the patent estimator: the largest first-order bias from
    a typical error of each confounding function [um or urad]); from
    :func:`mtplan.fitting.linear.function_status`.
    """
    import pandas as pd

    setup = Setup() if setup is None else setup
    check_estimator(estimator)
    ji = joint_ident(setup)
    geo = ji["geo"]
    bmat = _patent_response(setup) if estimator == "patent" else None
    rows = function_status(
        ji["g"], ji["scale"], ji["null"], _owners(geo),
        no_effect=np.array([ji["no_effect"][n] for n in NAMES]),
        unit=np.array([_unit(n) for n in NAMES]), bias_map=bmat,
        order=lambda n: (n == "mounting", NAMES.index(n) if n in NAMES else 99))
    return pd.DataFrame(rows, index=pd.Index(NAMES, name="function"))


@_one_blas_thread
def identifiability_report(setup: Setup | None = None) -> dict:
    """Rank, condition number and null space of the joint model's scaled Jacobian.

    The Jacobian's columns are scaled by each parameter's typical size (1 um or
    10 urad at the end of the travel; 1 um and 10 urad for the plates' offsets and
    rotations, 1 um for the extra heads' settings), so the condition number compares
    effects of typical errors.

    Returns
    -------
    dict with ``rank``, ``parameters`` (number of coefficients + mounting parameters),
    ``readings``, ``condition_number`` (of the identified part), ``singular_values``,
    ``null_space`` (a list of dicts: parameter name -> weight in scaled units, weights
    above 1e-3, one per null direction), ``measurands`` (the :func:`identifiability`
    table of the joint estimator), and what a generic analysis needs
    (:func:`mtplan.plans.identifiability.identifiability`): ``jacobian`` (readings x
    parameters [mm per parameter unit]), ``scale``, ``names``, ``functions`` (each of the
    21 measurands as a linear function of the parameters, name -> row) and ``rank_tol``.
    """
    setup = Setup() if setup is None else setup
    ji = joint_ident(setup)
    names = param_names(ji["geo"])
    sv = ji["sv"]
    null = null_space_table(ji["null"], names)
    return {
        "rank": ji["rank"],
        "parameters": ji["geo"].n_par,
        "readings": int(ji["jac"].shape[0]),
        "condition_number": float(sv[0] / sv[ji["rank"] - 1]),
        "singular_values": sv,
        "null_space": null,
        "measurands": identifiability(setup, "joint"),
        "jacobian": ji["jac"],
        "scale": ji["scale"],
        "names": names,
        "functions": dict(zip(NAMES, ji["g"])),
        "rank_tol": RANK_TOL,
    }


def _source_factors(setup: Setup, estimator: str, truth: Truth | None, only) -> dict:
    """Per active source: the first-order factor F with cov(theta) = F F^T (n_par, .).

    The white sources (reading noise, repeatability) through the estimator's first-order
    map from the readings (the joint fits' pseudo-inverse, their derivative to within
    ~1e-4 relative at realistic errors; the patent's derivative at the truth's noise-free
    readings, :func:`mtplan.models.geometry21._maps.patent_map`); the others element by
    element through the forward model (:func:`mtplan.fitting.effects.source_response`) and
    the estimator: the joint fits' whole, the patent's derivative at the readings of the
    sources' means."""
    truth = Truth() if truth is None else truth
    active = active_sources(sources(setup), only, owner=_OWNER)
    srcs = sources(setup)
    resp = _source_response(setup, truth, estimator,
                            tuple(n for n in active if n not in WHITE))
    out, pos = {}, 0
    for name, src in active.items():
        if name in WHITE:
            out[name] = _linear_map(setup, estimator, truth) * float(src.distribution.std)
            f = repeatability_filter(setup) if name == "repeatability" else None
            if f is not None:  # correlated along the path: the map times the filter
                a = out[name].reshape(out[name].shape[0], -1, 2)
                out[name] = np.stack([(f.T @ a[:, :, c].T).T for c in range(2)],
                                     axis=2).reshape(a.shape[0], -1)
        else:
            size = int(np.prod(srcs[name].shape, dtype=np.int64))
            out[name] = resp[:, pos: pos + size]
            pos += size
    return out


def _linear_map(setup: Setup, estimator: str, truth: Truth) -> np.ndarray:
    """A (n_par, 2M): first-order map from the readings to the estimated parameters."""
    if estimator != "patent":
        return joint_ident(setup)["pinv"]
    return _patent_linear_map(sizeless(setup), truth)  # the same for every size


@functools.lru_cache(maxsize=8)
def _patent_linear_map(key: Setup, truth: Truth) -> np.ndarray:
    return patent_map(key, forward(key, truth, zero_errors(sources(key), 1))["plate_mm"])


@functools.lru_cache(maxsize=8)
def _source_response(setup: Setup, truth: Truth, estimator: str, names: tuple) -> np.ndarray:
    def zero(m):
        return zero_errors(sources(setup), m)

    if estimator != "patent":
        return source_response(
            lambda errors: estimate_theta(setup, forward(setup, truth, errors), estimator),
            zero, sources(setup), names)
    srcs = sources(setup)
    at_mean = zero(1)
    for name in names:
        at_mean[name][...] = srcs[name].distribution.mean
    left = patent_map(setup, forward(setup, truth, at_mean)["plate_mm"])
    if truth_rows(truth) is None:
        return mapped_source_response(setup, truth, names, left)
    # one truth per row: the readings' response through the forward model
    readings = source_response(lambda errors: forward(setup, truth, errors)["plate_mm"]
                               .reshape(len(errors["reversal"]), -1), zero, srcs, names)
    return left @ readings


def coefficient_covariance(setup: Setup | None = None, *, estimator: str = "joint",
                           truth: Truth | None = None, sources=None):
    """First-order covariance of the estimated coefficients from every active error source.

    Linearised about the sources' means (the reversal and servo sources have a non-zero
    mean), with the estimator's first-order map from readings to parameters; the plate
    tilts act at second order and contribute nothing here.

    Parameters
    ----------
    sources : iterable of str, optional
        Only these error sources (default: every active one).

    Returns
    -------
    names : list of str, e.g. ``'EBX[2]'`` (function and power)
    cov : array (n_coef, n_coef) [internal units squared]
    """
    setup = Setup() if setup is None else setup
    check_estimator(estimator)
    geo = geometry(setup)
    cov = np.zeros((geo.n_coef, geo.n_coef))
    for f in _source_factors(setup, estimator, truth, sources).values():
        fc = f[: geo.n_coef]
        cov += fc @ fc.T
    return param_names(geo)[: geo.n_coef], cov


@_one_blas_thread
def sensitivities(setup: Setup, truth: Truth | None = None, *, estimator: str = "joint",
                  sources=None):
    """The listed measurands' sensitivity to every element of every active source [display
    unit per internal unit]: the jacobian (q, elements), the columns in the order of the
    first-order service (:func:`mtplan.evaluation.first_order.first_order`: the active
    sources in order, each one's elements flattened); the procedure's
    ``first_order_sensitivities``.

    The same first-order propagation as the generic chain rule, through the estimator's
    linear map (the sources' factors, per unit of each element) instead of
    differentiating the forward model and the estimator per element: a second instead of
    a quarter of a minute at the default set-up. None where a source's factor does not
    have one column per element (then the generic chain rule).
    """
    truth = Truth() if truth is None else truth
    check_estimator(estimator)
    active = active_sources(_sources(setup), sources, owner=_OWNER)
    factors = _source_factors(setup, estimator, truth, sources)
    ms, g = measurand_map(setup)
    g = g * np.array([m.scale for m in ms])[:, None]
    cols = []
    for name, src in active.items():
        shape = (*src.shape, *src.distribution.event_shape)
        size = int(np.prod(shape, dtype=np.int64))
        if factors[name].shape[1] != size:
            return None
        std = np.broadcast_to(np.asarray(src.distribution.std, dtype=float), shape).ravel()
        with np.errstate(divide="ignore", invalid="ignore"):
            cols.append(np.where(std > 0, (g @ factors[name]) / std, 0.0))
    return np.hstack(cols) if cols else np.zeros((len(ms), 0))


def _travel(geo: Geometry, axis: int) -> tuple[float, float]:
    """Range of an axis's commanded position over every reading [mm]: where the plates read
    its errors (the lines and circles, and the fixed coordinates of the plates and heads:
    the YZ plate reads X's errors at its x, 120 mm in the patent)."""
    x = geo.cmd[:, axis]
    return float(x.min()), float(x.max())


def error_functions(setup: Setup | None = None, readings: dict | None = None, *,
                    truth: Truth | None = None, estimator: str = "joint", positions: int = 21,
                    travel: tuple[float, float] | None = None, sources=None) -> pd.DataFrame:
    """The 21 error functions over their travel: estimate, truth and first-order band.

    Each error function is a function of its axis's position; a measurand is its value at
    one stated position. This gives every function along the tested travel of its axis,
    for a report to draw each determined error with its band.

    Parameters
    ----------
    setup : Setup, optional
    readings : dict, optional
        Readings (the first trial is used) whose estimate is shown.
    truth : Truth, optional
        The true functions (simulations); also the point the sources' first-order effect
        is taken at (default the default Truth).
    estimator : str
    positions : int
        Positions per function, evenly over its travel.
    travel : (low, high), optional
        Range of positions [mm] for every axis; default, each axis's range of commanded
        positions over every reading (the tests' travel, the plates' fixed coordinates and
        the heads' offsets: where the plates read the errors).
    sources : iterable of str, optional
        Only these error sources in the band (default every active one).

    Returns
    -------
    DataFrame with one row per function and position: ``function``, ``unit``, ``kind``
    (pos, str, ang, sq), ``axis`` (X, Y, Z), ``position_mm``, ``estimate`` (NaN without
    readings or where the data do not determine the value), ``true`` (NaN without truth),
    ``std`` (first-order standard uncertainty from every active source, display unit;
    ``inf`` where the data do not determine the value, never NaN) and ``status`` (from
    :func:`identifiability`). Squareness errors are constants: one row at position 0.
    """
    import pandas as pd

    setup = Setup() if setup is None else setup
    check_estimator(estimator)
    p = Problems("error_functions")
    p.number("positions", positions, low=2, integer=True)
    if travel is not None and not (len(travel) == 2 and travel[0] < travel[1]):
        p.add("travel", travel, "a pair (low, high) with low < high [mm]")
    p.raise_if_any()
    ji = joint_ident(setup)
    geo, s, null = ji["geo"], ji["scale"], ji["null"]
    _, cov = coefficient_covariance(setup, estimator=estimator, truth=truth, sources=sources)
    status = identifiability(setup, estimator)["status"]
    theta = None if readings is None else estimate_theta(setup, readings, estimator)[0]
    tcoef = None if truth is None else truth_coefficients(truth)
    rows = []
    for name in NAMES:
        powers, sl = geo.layout[name]
        scale = 1e6 if KIND[name] in ("ang", "sq") else 1e3
        if KIND[name] == "sq":
            pts = np.array([0.0])
        else:
            lo, hi = travel if travel is not None else _travel(geo, AXIS[name])
            pts = np.linspace(lo, hi, int(positions))
        for x in pts:
            b = np.zeros(geo.n_par)
            b[sl] = [x**k for k in powers]
            bs = b * s
            nb = np.linalg.norm(bs)
            ok = nb == 0 or not null.size or np.linalg.norm(null @ bs) <= 1e-6 * nb
            var = float(b[: geo.n_coef] @ cov @ b[: geo.n_coef])
            est = float(b @ theta) * scale if theta is not None and ok else math.nan
            if tcoef is None:
                true = math.nan
            else:
                tp, tc = tcoef[name]
                true = float(np.sum(tc * x ** np.array(tp))) * scale
            rows.append((name, "urad" if scale == 1e6 else "um", KIND[name], "XYZ"[AXIS[name]],
                         float(x), est, true, math.sqrt(max(var, 0.0)) * scale if ok else math.inf,
                         status[name]))
    return pd.DataFrame(rows, columns=["function", "unit", "kind", "axis", "position_mm",
                                       "estimate", "true", "std", "status"])


def error_bands(setup: Setup | None = None, *, estimator: str = "joint",
                positions: int = 11) -> pd.DataFrame:
    """Standard uncertainty of each error function over [-line_length/2, +line_length/2].

    Returns
    -------
    DataFrame with columns ``function``, ``unit``, ``position_mm``, ``std`` (first-order
    standard uncertainty of the function's value there from every active error source,
    display unit) and ``status`` (from :func:`identifiability`). Where the data do not
    determine the value, ``std`` is ``inf`` (never NaN) and ``status`` says why.
    Squareness rows have position 0. See :func:`error_functions` for estimates and truth.
    """
    setup = Setup() if setup is None else setup
    half = setup.line_length_mm / 2
    table = error_functions(setup, estimator=estimator, positions=positions, travel=(-half, half))
    return table[["function", "unit", "position_mm", "std", "status"]]


def noise_free_table(setup: Setup | None = None, *, scales=(1.0, 10.0, 100.0),
                     estimators=("patent", "joint", "joint_linear"), truth: Truth | None = None,
                     ) -> pd.DataFrame:
    """Error of each estimator from noise-free readings, angular errors scaled.

    Returns a DataFrame with columns ``measurand``, ``unit``, ``estimator``,
    ``angular_scale``, ``true``, ``error`` (estimate - truth, display unit) and
    ``relative`` (error / true).
    """
    import pandas as pd

    setup = Setup() if setup is None else setup
    base = Truth() if truth is None else truth
    rows = []
    for sc in scales:
        tr = base.replace(angular_scale=float(sc) * base.angular_scale)
        readings = forward(setup, tr, zero_errors(sources(setup), 1))
        true = true_values(setup, tr)
        tv = {m.name: float(true[m.name]) * m.scale for m in measurands(setup)}
        for est in estimators:
            check_estimator(est)
            out = ESTIMATORS[est](setup, readings)
            for m in measurands(setup):
                err = float(np.asarray(out[m.name], dtype=float)[0] * m.scale - tv[m.name])
                rows.append((m.name, m.unit, est, float(sc), tv[m.name], err,
                             err / tv[m.name] if tv[m.name] else math.inf))
    return pd.DataFrame(rows, columns=["measurand", "unit", "estimator", "angular_scale", "true",
                                       "error", "relative"])


def report_extras(setup: Setup, truth: Truth) -> dict:
    """Uncertainty bands of the error functions over the tested travel, for the report.

    A planner asks how well EBX is known anywhere on the axis, not how well its a2 is:
    :func:`error_bands` (first order, all active error sources) for the patent's stepwise
    method and the joint fit; functions the data do not determine are left out.
    :func:`error_functions` has the same with the estimate and truth over each axis's
    whole tested travel.
    """
    bands = {est: error_bands(setup, estimator=est, positions=21) for est in ("patent", "joint")}
    return {"bands": {
        "caption": ("Standard uncertainty of each determined error function over the tested "
                    "travel (first order, every default error source), the patent's stepwise "
                    "method against the joint fit. Squareness errors are constants (not drawn)."),
        "tables": bands,
    }}


