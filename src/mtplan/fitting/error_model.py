"""The error model of a posterior's likelihood: how it holds every active error source.

For every element of every active error source the forward model is evaluated at
the least-squares estimate with that element at its mean plus and minus one standard
deviation (all other sources at their means). Half the difference is the element's
*secant* effect on the readings (a standard deviation's worth, so its outer product
is the element's contribution to the readings' covariance, exact for an effect
linear over +-1 sigma and the best linear one otherwise); the half sum minus the
prediction is its *curvature* (the second-order term, whose sum over the elements is
the shift of the readings' mean, added to the prediction). Then, per source:

- **covariance** (linear sources): marginalised analytically. The readings'
  covariance is ``C = D + U U^T``: ``D`` collects the elements that touch one reading
  each (reading noise, per-reading positioning), ``U`` those that touch several (a
  scale error, a drift, a form error, an error motion per position). Up to
  ``DENSE_MAX`` readings ``C`` is formed and factored (Cholesky); above, it stays
  diagonal plus low rank and is solved by Woodbury (a thin SVD of ``D^-1/2 U``), so
  thousands of readings cost ``n k`` per walker, not ``n^2``.
- **nuisance** (non-linear sources, at most ``MAX_NUISANCE`` elements in all): the
  elements are sampled with the set-up's distribution as their prior and run
  through the forward model exactly. A source is non-linear when the curvature of
  one of its elements, or (sources of few elements) the change of its secant
  between +-1 and +-2 standard deviations, in units of the readings' independent
  scatter (the diagonal ``D``; the whole variance where ``D`` is 0), has a norm
  above ``NONLINEAR``.
- **absorbed**: a source whose effect the free parameters on which no measurand
  depends reproduce exactly (circle_centre's start scatter is a move of the start
  point, which is free) is left out: in the linear case the measurands' posterior
  is exactly the same with or without it.

The noise source (``procedure.readings.noise_source``) may instead have a given standard
deviation or a free one (Jeffreys prior): then ``C(sigma) = sigma^2 C_n + C_0`` is
diagonalised once (generalised eigenproblem, or a thin SVD above ``DENSE_MAX``
readings), so that every walker's ``sigma`` costs ``n`` more operations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from mtplan._validate import InvalidInput
from mtplan.fitting.effects import Effect, effect

__all__ = ["ErrorModel", "Gaussian", "error_model", "DENSE_MAX", "NONLINEAR", "MAX_NUISANCE"]

_LOG_2PI = math.log(2 * math.pi)
DENSE_MAX = 2000  # readings: dense covariance up to this count
LOCAL_MAX = 512  # readings: elements within blocks of at most this many join the base
NONLINEAR = 0.1  # curvature norm [readings' independent scatter] above which a source is sampled
MAX_NUISANCE = 16  # at most this many source elements are sampled as nuisance parameters
_ABSORBED = 1e-5  # relative residual below which a source is reproduced by free parameters
_ODD_CHECK = 64  # sources with at most this many elements are also checked at +-2 sigma
_NEGLIGIBLE = 1e-6  # an element whose effect is below this in the readings' scatter (or 1e-8
# of its source's largest) is round-off, no effect


# --------------------------------------------------------------------------- the Gaussian
def _thin_svd(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left singular vectors (n, r) and singular values (r,) of a tall ``a`` (n, k), the
    directions whose singular value is above 1e-7 of the largest only.

    From the eigen-decomposition of ``a^T a`` (k, k): a third of the cost of LAPACK's thin
    SVD of ``a`` at 15 600 x 200. Squaring limits the singular values' relative accuracy
    to about 1e-8 of the largest; a direction below the cut changes the covariance by
    less than 1e-14 of its largest part (dropped: its weight and log-determinant terms are
    below that too).
    """
    if a.shape[1] == 0:
        return np.zeros((a.shape[0], 0)), np.zeros(0)
    lam, v = np.linalg.eigh(a.T @ a)
    lam, v = lam[::-1], v[:, ::-1]
    keep = lam > 1e-14 * max(float(lam[0]), 1e-300)
    s = np.sqrt(lam[keep])
    return (a @ v[:, keep]) / s, s


def _local_blocks(U: np.ndarray) -> tuple[np.ndarray, list]:
    """The columns of U confined to small blocks of readings, and the blocks.

    Columns are taken in order of their support (fewest readings first); one joins the
    blocks when the readings it links (with the blocks they already belong to) number
    ``LOCAL_MAX`` at most and the merged block's size squared grows by no more than the
    readings' count (what the column costs in the low-rank part), else it stays there.
    Returns (mask of the blocks' columns, list of (rows, columns) per block)."""
    import scipy.sparse as sp

    nz = U != 0
    count = nz.sum(axis=0)
    csc = sp.csc_matrix(nz)
    ptr, idx = csc.indptr.tolist(), csc.indices.tolist()
    local = np.zeros(U.shape[1], dtype=bool)
    parent = list(range(U.shape[0]))
    size = [1] * U.shape[0]

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for j in np.argsort(count, kind="stable"):
        if count[j] > LOCAL_MAX:
            break
        if not count[j]:  # no effect: left in the low-rank part, where it drops out
            continue
        roots = {root(i) for i in idx[ptr[j]: ptr[j + 1]]}
        merged = sum(size[r] for r in roots)
        if merged > LOCAL_MAX or merged**2 - sum(size[r] ** 2 for r in roots) > U.shape[0]:
            continue
        local[j] = True
        first, *rest = roots
        for r in rest:
            parent[r] = first
            size[first] += size[r]
    if not np.any(local):
        return local, []
    label = np.array([root(i) for i in range(U.shape[0])])
    cols = np.flatnonzero(local)
    owner = label[np.argmax(nz[:, cols], axis=0)]
    order = np.argsort(owner, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(owner[order])) + 1)
    return local, [(np.flatnonzero(label == owner[g[0]]), cols[g]) for g in groups]


def _block_whitening(D: np.ndarray, U: np.ndarray, blocks: list):
    """Sparse whitening W (``W^T W = (diag D + U U^T)^-1``, block lower-triangular) and the
    log-determinant of ``diag D + U U^T``, for U's columns confined to the `blocks`
    (rows, columns of the full U, of which `U` holds the local ones in order)."""
    import scipy.sparse as sp

    n = D.size
    logdet = float(np.sum(np.log(D)))
    local_cols = np.sort(np.concatenate([c for _, c in blocks]))
    full = np.zeros(n, dtype=bool)
    rows, cols, vals = [], [], []
    for rows_b, cols_b in blocks:
        full[rows_b] = True
        ub = U[np.ix_(rows_b, np.searchsorted(local_cols, cols_b))]
        sb = np.sqrt(D[rows_b])
        chol = np.linalg.cholesky((np.diag(D[rows_b]) + ub @ ub.T) / np.outer(sb, sb))
        logdet += 2.0 * float(np.sum(np.log(np.diag(chol))))  # scaled: D's part is in
        wb = np.linalg.solve(chol, np.eye(rows_b.size)) / sb[None, :]
        i, j = np.nonzero(wb)
        rows.append(rows_b[i])
        cols.append(rows_b[j])
        vals.append(wb[i, j])
    rest = np.flatnonzero(~full)
    rows.append(rest)
    cols.append(rest)
    vals.append(1.0 / np.sqrt(D[rest]))
    w = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n))
    return w, logdet


class Gaussian:
    """Log-likelihood of residuals under ``C = D + U U^T`` (known) or ``sigma^2 C_n + C_0``."""

    def __init__(self, n: int):
        self.n = n
        self.free = False
        self.wb = None

    @classmethod
    def known(cls, D, U) -> Gaussian:
        g = cls(D.size)
        if g.n <= DENSE_MAX:
            return cls.dense(np.diag(D) + U @ U.T)
        if not np.all(D > 0):
            raise InvalidInput([f"With {g.n} readings the posterior needs every reading to have "
                                "its own noise (an error source of the set-up that touches it "
                                "alone); some have none."])
        g.rs, g.wb, logdet, U = 1.0 / np.sqrt(D), None, float(np.sum(np.log(D))), U
        local, blocks = _local_blocks(U)
        if blocks:  # elements within small blocks of readings (a path's correlated scatter)
            g.wb, logdet = _block_whitening(D, U[:, local], blocks)
            U = U[:, ~local]
            # the readings in blocks, and their part of the whitening; the others' is its
            # diagonal (most of them where a few passes are correlated: line_laser's 1 324
            # of 15 600), applied as a product by :meth:`base` instead of a sparse one
            coo = g.wb.tocoo()
            off = coo.row != coo.col
            g.blk = np.union1d(coo.row[off], coo.col[off])
            g.wdiag = g.wb.diagonal()
            g.wdiag[g.blk] = 0.0
            g.wblk = g.wb[g.blk][:, g.blk].tocsr()
        q, s = _thin_svd(g.base(U.T).T)
        keep = s > 1e-12 * (s[0] if s.size else 1.0)
        g.q, g.shrink = q[:, keep], 1.0 - 1.0 / np.sqrt(1.0 + s[keep] ** 2)
        g.logdet = logdet + float(np.sum(np.log1p(s[keep] ** 2)))
        g.mode = "woodbury"
        return g

    def base(self, R: np.ndarray) -> np.ndarray:
        """Rows R (m, n) whitened by the base of a Woodbury Gaussian: ``D^-1/2``, or the
        block whitening of D and the elements confined to small blocks of readings."""
        if self.wb is None:
            return R * self.rs
        w = R * self.wdiag
        if self.blk.size:
            w[:, self.blk] = (self.wblk @ R[:, self.blk].T).T
        return w

    def base_t(self, V: np.ndarray) -> np.ndarray:
        """``B^T V`` (n, m) for the base whitening B of :meth:`base`."""
        return self.rs[:, None] * V if self.wb is None else np.asarray(self.wb.T @ V)

    @classmethod
    def dense(cls, cov) -> Gaussian:
        """A known covariance (n, n), formed: Cholesky of it scaled to unit diagonal
        (readings in mm and rad differ by 1e4 and more)."""
        g = cls(cov.shape[0])
        s = np.sqrt(np.diag(cov))
        # numpy's LAPACK throughout: scipy's costs milliseconds per call in thread start-up
        # on small systems of a loaded machine
        try:
            if not np.all(s > 0):
                raise np.linalg.LinAlgError
            chol = np.linalg.cholesky(cov / np.outer(s, s))
        except np.linalg.LinAlgError:
            raise InvalidInput(["The readings' covariance from the set-up's error sources is "
                                "singular; switch on a noise source of the readings."]) from None
        g.logdet = 2.0 * float(np.sum(np.log(np.diag(chol))) + np.sum(np.log(s)))
        # W = L^-1 S^-1: |W r|^2 = r^T C^-1 r
        g.white = np.linalg.solve(chol, np.eye(g.n)) / s[None, :]
        g.mode = "dense"
        return g

    @classmethod
    def free_noise(cls, D0, U0, Dn, Un) -> Gaussian:
        """``sigma^2 (diag Dn + Un Un^T) + diag D0 + U0 U0^T``, diagonalised once."""
        g = cls(D0.size)
        g.free, g.n_perp = True, 0
        diag_noise = Un.shape[1] == 0 and np.all(Dn > 0)
        if g.n <= DENSE_MAX and diag_noise:
            rs = 1.0 / np.sqrt(Dn)
            lam, vec = np.linalg.eigh(np.diag(D0 / Dn) + (U0 * rs[:, None]) @ (U0 * rs[:, None]).T)
            g.T, g.a, g.b = vec.T * rs[None, :], np.ones(g.n), np.clip(lam, 0.0, None)
            g.const, g.rank = float(np.sum(np.log(Dn))), g.n
        elif g.n <= DENSE_MAX:
            try:
                l0 = np.linalg.cholesky(np.diag(D0) + U0 @ U0.T)
            except np.linalg.LinAlgError:
                raise InvalidInput(["The noise cannot be left free here: the other error sources "
                                    "do not touch every reading; give the noise."]) from None
            inv = np.linalg.solve(l0, np.eye(g.n))
            cn = np.diag(Dn) + Un @ Un.T
            lam, vec = np.linalg.eigh(inv @ cn @ inv.T)
            lam = np.clip(lam, 0.0, None)
            g.T, g.a, g.b = vec.T @ inv, lam, np.ones(g.n)
            g.const = 2.0 * float(np.sum(np.log(np.diag(l0))))
            g.rank = int(np.sum(lam > 1e-9 * max(float(lam.max()), 1e-300)))
        elif diag_noise and not np.any(D0):
            rs = 1.0 / np.sqrt(Dn)
            q, s = _thin_svd(U0 * rs[:, None])
            keep = s > 1e-12 * (s[0] if s.size else 1.0)  # the rest: noise-only directions
            q, s = q[:, keep], s[keep]
            g.rs, g.T, g.a, g.b = rs, q.T * rs[None, :], np.ones(s.size), s**2
            g.n_perp, g.const, g.rank = g.n - s.size, float(np.sum(np.log(Dn))), g.n
        else:
            raise InvalidInput([f"With {g.n} readings a free noise needs every other error source "
                                "to act on several readings at once; give the noise."])
        return g

    def whiten(self, R: np.ndarray) -> np.ndarray:
        """Whitened residuals (m, n) of a known covariance: ``|w|^2 = r^T C^-1 r``."""
        R = np.atleast_2d(R)
        if self.mode == "dense":
            return R @ self.white.T
        w = self.base(R)
        return w - ((w @ self.q) * self.shrink) @ self.q.T

    def inverse_times(self, R: np.ndarray) -> np.ndarray:
        """Rows ``R C^-1`` (m, n) of rows R (m, n) (a known covariance): ``W^T W`` applied,
        W the whitening of :meth:`whiten`."""
        w = self.whiten(R)
        if self.mode == "dense":
            return w @ self.white
        return self.base_t((w - ((w @ self.q) * self.shrink) @ self.q.T).T).T

    def loglike(self, R: np.ndarray, log_sigma=None) -> np.ndarray:
        """Gaussian log-likelihood of residual rows R (m, n); `log_sigma` (m,) when free."""
        R = np.atleast_2d(R)
        if not self.free:
            if self.mode == "dense":
                w = self.whiten(R)
                quad = np.einsum("ij,ij->i", w, w)
            else:  # r^T C^-1 r = |w|^2 - sum_j (w . q_j)^2 s_j^2 / (1 + s_j^2), w = D^-1/2 r
                w = self.base(R)
                p = w @ self.q
                damp = 1.0 - (1.0 - self.shrink) ** 2
                quad = np.einsum("ij,ij->i", w, w) - (p * p) @ damp
            return -0.5 * (quad + self.logdet + self.n * _LOG_2PI)
        s2 = np.exp(2.0 * np.asarray(log_sigma, dtype=float))
        z = R @ self.T.T
        den = self.a[None, :] * s2[:, None] + self.b[None, :]
        quad = np.sum(z * z / den, axis=1)
        logdet = self.const + np.sum(np.log(den), axis=1)
        if self.n_perp:
            w = R * self.rs
            quad += (np.einsum("ij,ij->i", w, w) - np.einsum("ij,ij->i", z, z)) / s2
            logdet += self.n_perp * np.log(s2)
        return -0.5 * (quad + logdet + self.n * _LOG_2PI)

    def fisher_log_sigma(self, sigma: float) -> float:
        """Fisher information of log sigma at `sigma` (free noise)."""
        s2 = sigma * sigma
        frac = self.a * s2 / (self.a * s2 + self.b)
        return float(2.0 * np.sum(frac**2) + 2.0 * self.n_perp)


# --------------------------------------------------------------------------- the error model
@dataclass
class ErrorModel:
    """What became of every error source, and the covariance parts of the linear ones.

    Attributes
    ----------
    how : dict of str to str
        Per source of the set-up: "covariance", "nuisance", "absorbed by ...",
        "no effect on the readings", "off" (size 0), or "free noise"/"given noise".
    D0, U0 : arrays (n,), (n, k)
        Linear sources (the noise too, unless free).
    Dn, Un : arrays (n,), (n, k_n), or None
        The noise source per unit of its standard deviation, when it is free.
    correction : array (n,)
        Second-order shift of the readings' mean from the linear sources.
    nuisance : list of (name, Source)
        Sources sampled as parameters (all their elements).
    nonlinearity : dict of str to float
    notes : list of str
    """

    how: dict
    D0: np.ndarray
    U0: np.ndarray
    Dn: np.ndarray | None
    Un: np.ndarray | None
    correction: np.ndarray
    nuisance: list
    nonlinearity: dict
    notes: list = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False)

    def gaussian(self, sigma=None) -> Gaussian:
        """The readings' Gaussian: known, or with the free noise at `sigma` (for fits)."""
        key = None if self.Dn is None else sigma
        if key not in self._cache:
            if self.Dn is None:
                g = Gaussian.known(self.D0, self.U0)
            elif sigma is None:
                g = Gaussian.free_noise(self.D0, self.U0, self.Dn, self.Un)
            else:
                g = Gaussian.known(self.D0 + sigma**2 * self.Dn,
                                   np.hstack([self.U0, sigma * self.Un]))
            self._cache = {**self._cache, key: g}
        return self._cache[key]


def _negligible(eff: Effect, ref, n: int) -> bool:
    """Every element's effect is below ``_NEGLIGIBLE`` of the readings' scatter (round-off)."""
    return bool(np.sqrt(eff.diag(n)).max(initial=0.0) <= _NEGLIGIBLE * ref.min()
                and np.all(np.linalg.norm(eff.S / ref[:, None], axis=0) <= _NEGLIGIBLE))


def _absorbed(eff: Effect, tangent: Effect | None, ref, J, nuisance_params, names) -> str | None:
    """The free nuisance parameters that reproduce the source's effect, or None."""
    if not nuisance_params or np.any(eff.row >= 0) or not eff.multi.size:
        return None
    cols = (tangent if tangent is not None else eff).S / ref[:, None]
    norms = np.linalg.norm(cols, axis=0)
    cols = cols[:, norms > max(_NEGLIGIBLE, 1e-8 * norms.max(initial=0.0))]
    if not cols.shape[1]:
        return None
    jn = J[:, nuisance_params] / ref[:, None]
    beta, *_ = np.linalg.lstsq(jn, cols, rcond=None)
    resid = np.linalg.norm(cols - jn @ beta, axis=0) / np.maximum(np.linalg.norm(cols, axis=0),
                                                                   1e-300)
    if np.all(resid < _ABSORBED):
        used = np.flatnonzero(np.any(np.abs(beta) > 1e-9 * np.abs(beta).max(), axis=1))
        return ", ".join(names[nuisance_params[i]] for i in used)
    return None


def error_model(fwd, truth, noise: str, sigma, J, G, names) -> ErrorModel:
    """Classify the active sources and build the readings' covariance at `truth`.

    Parameters
    ----------
    fwd : Forward
    truth : Truth
        The linearisation point (the least-squares estimate).
    noise : {"setup", "known", "free"}
    sigma : float or None
        The noise source's standard deviation for "known" [its unit].
    J : array (n, n_params)
        The readings' Jacobian over the free parameters at `truth`.
    G : array (n_measurands, n_params)
        The measurands' gradient over the free parameters.
    names : list of str
        The free parameters' names.
    """
    proc, n = fwd.proc, fwd.n
    fwd.slots = []
    f0 = fwd.at(truth, fwd.errors(1))[0]
    active = proc.active_sources(fwd.setup)
    how = {k: "off (size 0)" for k in fwd.sources if k not in active}
    ns = proc.readings.noise_source
    std = {k: np.asarray(s.distribution.std, dtype=float) for k, s in active.items()}
    if noise in ("known", "free"):
        setup_sd = float(np.max(np.asarray(fwd.sources[ns].distribution.std)))
        std[ns] = np.asarray(setup_sd if setup_sd > 0 else 1e-3)
    effects = {k: effect(fwd, truth, k, sd, f0) for k, sd in std.items()}
    var = sum((e.diag(n) + np.sum(e.S**2, axis=1) for e in effects.values()), np.zeros(n))
    diag = sum((e.diag(n) for e in effects.values()), np.zeros(n))
    ref = np.sqrt(np.where(diag > 0, diag, var))
    if np.any(ref <= 0):
        labels = sorted(set(np.asarray(fwd.labels(), dtype=object)[ref <= 0]))
        raise InvalidInput([f"The readings {', '.join(labels)} of {proc.name} are touched by no "
                            "active error source of the set-up, so the likelihood cannot weigh "
                            "them; switch on their noise source."])
    nuis_params = [j for j in range(J.shape[1]) if not np.any(np.abs(G[:, j]) > 0)]
    model = ErrorModel(how, np.zeros(n), np.zeros((n, 0)), None, None, np.zeros(n), [], {})
    n_nuis = 0
    for name, eff in effects.items():
        if not eff.any or _negligible(eff, ref, n):
            how[name] = "no effect on the readings"
            continue
        nl = eff.nonlinearity(ref)
        if eff.std.size <= _ODD_CHECK:  # odd non-linearity: the secant over +-2 sigma differs
            wide = effect(fwd, truth, name, 2.0 * eff.std, f0).dense(n) / 2.0
            odd = np.sqrt(np.sum(((wide - eff.dense(n)) / ref[:, None]) ** 2, axis=0))
            nl = max(nl, float(odd.max(initial=0.0)))
        model.nonlinearity[name] = nl
        if name == ns and noise in ("known", "free"):
            _add_noise(model, name, eff, noise, sigma, n)
            continue
        tangent = effect(fwd, truth, name, eff.std * 1e-4, f0) if nl > NONLINEAR else None
        if tangent is not None:
            tangent.S = tangent.S * 1e4
        by = _absorbed(eff, tangent, ref, J, nuis_params, names)
        if by is not None:
            how[name] = f"absorbed by {by}"
            continue
        if nl > NONLINEAR and n_nuis + eff.std.size <= MAX_NUISANCE:
            how[name] = "nuisance"
            n_nuis += eff.std.size
            model.nuisance.append((name, fwd.sources[name]))
            continue
        if nl > NONLINEAR:
            model.notes.append(
                f"the error source {name} is non-linear (second-order effect {nl:.2g} times the "
                f"readings' scatter at one standard deviation) but has {eff.std.size} elements, "
                "too many to sample: linearised")
        how[name] = "covariance"
        model.D0 = model.D0 + eff.diag(n)
        model.U0 = np.hstack([model.U0, eff.S])
        model.correction = model.correction + eff.curvature(n)
    fwd.slots = [(name, np.arange(int(np.prod((*s.shape, *s.distribution.event_shape),
                                                dtype=np.int64))))
                 for name, s in model.nuisance]
    return model


def _add_noise(model: ErrorModel, name: str, eff: Effect, noise: str, sigma, n: int) -> None:
    """The noise source, per unit of its standard deviation: free, or at the given `sigma`."""
    ref = float(np.max(eff.std))
    d, u = eff.diag(n) / ref**2, eff.S / ref
    if noise == "free":
        model.Dn, model.Un = d, u
        model.how[name] = "free noise (Jeffreys prior)"
        return
    model.how[name] = f"covariance, standard deviation given: {sigma:.4g}"
    model.D0 = model.D0 + sigma**2 * d
    model.U0 = np.hstack([model.U0, sigma * u])
