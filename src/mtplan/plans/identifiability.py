"""Identifiability of parameters from a sensitivity (Jacobian) matrix, and design criteria.

For a linearised measurement model ``delta_obs = J delta_params`` (``J`` of shape
``(n_obs, n_params)``), the singular value decomposition of ``J`` tells which parameters
the observations determine and how well:

- the numerical rank, with a stated tolerance: a singular value counts as zero when
  ``s_i <= tol * s_1`` (relative tolerance; default ``tol = max(n_obs, n_params) * eps``,
  the convention of ``numpy.linalg.matrix_rank``);
- the condition number ``s_1 / s_L``;
- the null space: parameter combinations that leave every observation unchanged (right
  singular vectors of the zero singular values, plus the directions a short matrix with
  ``n_obs < n_params`` cannot see), reported in the original parameters;
- the observability indices O1-O5, on *scaled* sensitivities (so that they do not depend
  on the units of the parameters): by default each column of ``J`` is scaled to unit
  Euclidean norm; with ``scale`` given, column ``j`` is multiplied by ``scale[j]`` (the
  expected size, or tolerance, of parameter ``j``), so that the indices describe the effect
  of parameter changes of that size.

Observability indices
---------------------
With ``s_1 >= ... >= s_L`` the singular values of the scaled ``J`` (``L = n_params``) and
``m`` the number of poses (measurement configurations; default ``n_obs``):

``O1 = (s_1 s_2 ... s_L)^(1/L) / sqrt(m)``
    Borm and Menq (1991): the geometric mean of the singular values per pose; grows with
    the volume of the confidence ellipsoid's inverse (a D-optimality measure).
``O2 = s_L / s_1``
    Driels and Pathre (1990): the inverse condition number.
``O3 = s_L``
    Nahvi, Hollerbach and Hayward (1994): the minimum singular value (E-optimality).
``O4 = s_L^2 / s_1``
    Nahvi and Hollerbach (1996): the noise amplification index.
``O5 = 1 / (1/s_1 + ... + 1/s_L)``
    Sun and Hollerbach (2008): related to A-optimality (trace of the covariance).

For singular values ``[4, 2, 1]`` and 5 poses: O1 0.8944, O2 0.25, O3 1, O4 0.25,
O5 0.5714. Larger is better for all five; all are 0 for a rank-deficient ``J``.

Design criteria
---------------
For an information matrix ``M = J^T W J``: D (``log det M``, maximise), A
(``trace M^-1``, minimise) and E (smallest eigenvalue, maximise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems

__all__ = [
    "IdentifiabilityReport",
    "identifiability",
    "observability_indices",
    "information_matrix",
    "d_optimality",
    "a_optimality",
    "e_optimality",
]


def _as_matrix(owner, name, value, *, square=False):
    p = Problems(owner)
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        p.add(name, value, "a 2-D array of finite numbers")
        p.raise_if_any()
    if a.ndim != 2 or a.size == 0 or not np.all(np.isfinite(a)):
        p.add(name, a, "a non-empty 2-D array of finite numbers")
    elif square and a.shape[0] != a.shape[1]:
        p.add_text(
            f"The '{name}' parameter of {owner} must be square. Got shape {a.shape} instead"
        )
    p.raise_if_any()
    return a


def observability_indices(singular_values, n_poses: int) -> dict[str, float]:
    """Observability indices O1-O5 from singular values (see the module notes).

    Parameters
    ----------
    singular_values : array_like of shape (L,)
        Singular values of the scaled sensitivity matrix, >= 0 (any order).
    n_poses : int
        Number of poses (measurement configurations) ``m >= 1``, for O1.

    Returns
    -------
    dict
        Keys ``'O1'`` ... ``'O5'``.

    Examples
    --------
    >>> {k: round(v, 4) for k, v in observability_indices([4, 2, 1], 5).items()}
    {'O1': 0.8944, 'O2': 0.25, 'O3': 1.0, 'O4': 0.25, 'O5': 0.5714}
    """
    p = Problems("observability_indices")
    try:
        s = np.asarray(singular_values, dtype=float).ravel()
    except (TypeError, ValueError):
        s = None
    if s is None or s.size == 0 or not np.all(np.isfinite(s)) or np.any(s < 0):
        p.add("singular_values", singular_values, "a non-empty array of finite numbers >= 0")
    p.number("n_poses", n_poses, low=1, integer=True)
    p.raise_if_any()
    s = np.sort(s)[::-1]
    s1, sl = float(s[0]), float(s[-1])
    if sl <= 0.0:
        return {"O1": 0.0, "O2": 0.0, "O3": 0.0, "O4": 0.0, "O5": 0.0}
    o1 = math.exp(float(np.mean(np.log(s)))) / math.sqrt(int(n_poses))
    return {
        "O1": o1,
        "O2": sl / s1,
        "O3": sl,
        "O4": sl * sl / s1,
        "O5": 1.0 / float(np.sum(1.0 / s)),
    }


@dataclass(frozen=True, eq=False)
class IdentifiabilityReport:
    """What a sensitivity matrix can identify.

    Attributes
    ----------
    names : list of str
        Parameter names.
    n_obs, n_params : int
        Shape of the sensitivity matrix.
    rank : int
        Numerical rank of the scaled matrix.
    tol : float
        Relative tolerance: singular values ``<= tol * s_1`` count as zero.
    singular_values : ndarray of shape (min(n_obs, n_params),)
        Singular values of the scaled matrix, descending.
    condition_number : float
        ``s_1 / s_min`` of the scaled matrix (inf when rank deficient).
    column_scale : ndarray of shape (n_params,)
        The factors the columns of ``J`` were multiplied by.
    null_space : ndarray of shape (n_params, n_params - rank)
        Parameter directions (original units) that leave every observation unchanged,
        each normalised to largest absolute coefficient 1.
    null_combinations : list of str
        The same directions as readable combinations, e.g. ``'EX0C - 0.5*EB0C'``.
    observability : dict
        O1-O5 (keys ``'O1'`` ... ``'O5'``) on the scaled matrix.
    n_poses : int
        Poses used for O1.
    determined : dict of str to bool
        For each linear function of the parameters given (``functions``), whether the
        observations determine it (estimable: orthogonal to the null space).
    """

    names: list[str]
    n_obs: int
    n_params: int
    rank: int
    tol: float
    singular_values: np.ndarray
    condition_number: float
    column_scale: np.ndarray
    null_space: np.ndarray
    null_combinations: list[str]
    observability: dict[str, float]
    n_poses: int = field(default=0)
    determined: dict = field(default_factory=dict)

    @property
    def identifiable(self) -> bool:
        """True when every parameter combination is determined (full column rank)."""
        return self.rank == self.n_params

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        cond = self.condition_number
        return {
            "rank": self.rank,
            "n_params": self.n_params,
            "n_obs": self.n_obs,
            "identifiable": self.identifiable,
            "condition_number": cond if math.isfinite(cond) else None,
            "singular_values": self.singular_values.tolist(),
            "null_combinations": list(self.null_combinations),
            "observability": dict(self.observability),
            "tol": self.tol,
            "determined": [k for k, v in self.determined.items() if v],
            "undetermined": [k for k, v in self.determined.items() if not v],
        }


def _combination(vec, names, cutoff=1e-6):
    k = int(np.argmax(np.abs(vec)))
    v = vec / vec[k]
    terms = []
    for c, n in zip(v, names):
        if abs(c) <= cutoff:
            continue
        mag = abs(c)
        body = n if math.isclose(mag, 1.0, rel_tol=1e-9) else f"{mag:.4g}*{n}"
        sign = "-" if c < 0 else "+"
        terms.append((sign, body))
    text = ("-" if terms[0][0] == "-" else "") + terms[0][1]
    for sign, body in terms[1:]:
        text += f" {sign} {body}"
    return text, v


def identifiability(
    J,
    *,
    scale=None,
    names=None,
    tol: float | None = None,
    n_poses: int | None = None,
    functions=None,
) -> IdentifiabilityReport:
    """Rank, conditioning, null space and observability indices of a sensitivity matrix.

    Parameters
    ----------
    J : array_like of shape (n_obs, n_params)
        Sensitivities ``d obs_i / d param_j`` [unit of obs / unit of param].
    scale : array_like of shape (n_params,), optional
        Parameter scales (expected size of each parameter) [unit of param], > 0; column
        ``j`` is multiplied by ``scale[j]``. Default: each column scaled to unit norm (a
        zero column is left as it is and shows in the null space).
    names : sequence of str, optional
        Parameter names; default ``p0, p1, ...``.
    tol : float, optional
        Relative rank tolerance in [0, 1); default ``max(n_obs, n_params) * eps``.
    n_poses : int, optional
        Number of poses for O1; default ``n_obs``.
    functions : mapping of str to array_like of shape (n_params,), optional
        Linear functions of the parameters, ``f . p`` (for example a measurand that the
        parameters are coefficients of: geometry21's error functions at one position).
        The report's ``determined`` says which the observations determine: those
        orthogonal to the null space (relative tolerance 1e-6 on the scaled parameters);
        a function that is not determined has no value the data could give, however
        many readings are taken.

    Returns
    -------
    IdentifiabilityReport
    """
    a = _as_matrix("identifiability", "J", J)
    n_obs, n_par = a.shape
    p = Problems("identifiability")
    col = None
    if scale is not None:
        try:
            col = np.asarray(scale, dtype=float).ravel()
        except (TypeError, ValueError):
            col = None
        if col is None or col.shape != (n_par,) or not np.all(np.isfinite(col)) or np.any(col <= 0):
            p.add("scale", scale, f"None or {n_par} finite numbers > 0 (one per column of J)")
    if names is None:
        names = [f"p{j}" for j in range(n_par)]
    else:
        names = list(names) if not isinstance(names, str) else [names]
        if len(names) != n_par or not all(isinstance(n, str) and n for n in names):
            p.add("names", names, f"None or {n_par} non-empty strings (one per column of J)")
    if tol is not None:
        p.number("tol", tol, low=0, high=1, high_open=True)
    if n_poses is not None:
        p.number("n_poses", n_poses, low=1, integer=True)
    rows = {}
    for fname, f in dict(functions or {}).items():
        try:
            row = np.asarray(f, dtype=float).ravel()
        except (TypeError, ValueError):
            row = None
        if row is None or row.shape != (n_par,) or not np.all(np.isfinite(row)):
            p.add(f"functions[{fname!r}]", f, f"{n_par} finite numbers (one per column of J)")
        else:
            rows[str(fname)] = row
    p.raise_if_any()
    if col is None:
        norms = np.linalg.norm(a, axis=0)
        col = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    rtol = float(max(n_obs, n_par) * np.finfo(float).eps) if tol is None else float(tol)
    js = a * col
    if n_obs > n_par:  # tall: the SVD of the QR's R has the same S and V, and no U to form
        _, s, vt = np.linalg.svd(np.linalg.qr(js, mode="r"))
    else:  # the full V^T, which a short matrix needs for its null space
        _, s, vt = np.linalg.svd(js, full_matrices=True)
    s1 = float(s[0]) if s.size else 0.0
    rank = int(np.sum(s > rtol * s1)) if s1 > 0 else 0
    null_scaled = vt[rank:].T  # (n_par, n_par - rank), orthonormal in scaled parameters
    null = col[:, None] * null_scaled  # back to original parameters: J (D v) = J_s v
    combos, vecs = [], []
    for k in range(null.shape[1]):
        text, v = _combination(null[:, k], names)
        combos.append(text)
        vecs.append(v)
    null = np.column_stack(vecs) if vecs else np.zeros((n_par, 0))
    s_all = np.zeros(n_par)
    s_all[: s.size] = s  # n_obs < n_params: the missing singular values are zero
    smin = float(s_all[-1])
    cond = s1 / smin if smin > rtol * s1 and smin > 0 else math.inf
    m = n_obs if n_poses is None else int(n_poses)
    obs = observability_indices(np.where(s_all > rtol * s1, s_all, 0.0), m)
    determined = {}
    for fname, row in rows.items():
        fs = row * col  # in the scaled parameters q (p = col q): f . p = (f col) . q
        nf = np.linalg.norm(fs)
        determined[fname] = bool(nf == 0 or np.linalg.norm(null_scaled.T @ fs) <= 1e-6 * nf)
    return IdentifiabilityReport(
        names=names,
        n_obs=n_obs,
        n_params=n_par,
        rank=rank,
        tol=rtol,
        singular_values=s,
        condition_number=cond,
        column_scale=col,
        null_space=null,
        null_combinations=combos,
        observability=obs,
        n_poses=m,
        determined=determined,
    )


def information_matrix(J, *, sigma=None) -> np.ndarray:
    """Fisher information ``M = J^T W J`` of a linearised model with independent noise.

    Parameters
    ----------
    J : array_like of shape (n_obs, n_params)
        Sensitivities.
    sigma : float or array_like of shape (n_obs,), optional
        Standard deviation of each observation's noise, > 0 [unit of obs]; ``W =
        diag(1/sigma^2)``. Default 1.

    Returns
    -------
    ndarray of shape (n_params, n_params)
    """
    a = _as_matrix("information_matrix", "J", J)
    if sigma is None:
        w = np.ones(a.shape[0])
    else:
        p = Problems("information_matrix")
        try:
            sg = np.broadcast_to(np.asarray(sigma, dtype=float), (a.shape[0],))
        except (TypeError, ValueError):
            sg = None
        if sg is None or not np.all(np.isfinite(sg)) or np.any(sg <= 0):
            p.add("sigma", sigma, f"a number > 0 or {a.shape[0]} numbers > 0 (one per row of J)")
        p.raise_if_any()
        w = 1.0 / sg**2
    m = (a * w[:, None]).T @ a
    return 0.5 * (m + m.T)


def _info(owner, M):
    m = _as_matrix(owner, "M", M, square=True)
    if not np.allclose(m, m.T, rtol=1e-10, atol=1e-12 * max(np.abs(m).max(), 1e-300)):
        raise InvalidInput(
            [f"The 'M' parameter of {owner} must be a symmetric matrix. Got an asymmetric one."]
        )
    return 0.5 * (m + m.T)


def d_optimality(M) -> float:
    """D criterion ``log det M`` of an information matrix (maximise); ``-inf`` when
    singular or not positive definite."""
    m = _info("d_optimality", M)
    sign, logdet = np.linalg.slogdet(m)
    return float(logdet) if sign > 0 else -math.inf


def a_optimality(M) -> float:
    """A criterion ``trace(M^-1)`` of an information matrix (minimise): the sum of the
    parameter variances; ``inf`` when singular or not positive definite."""
    m = _info("a_optimality", M)
    ev = np.linalg.eigvalsh(m)
    if ev[0] <= max(ev[-1], 0.0) * m.shape[0] * np.finfo(float).eps:
        return math.inf
    return float(np.sum(1.0 / ev))


def e_optimality(M) -> float:
    """E criterion: the smallest eigenvalue of an information matrix (maximise)."""
    m = _info("e_optimality", M)
    return float(np.linalg.eigvalsh(m)[0])
