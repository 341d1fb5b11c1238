"""Linear least squares of rank-deficient models.

A model whose readings do not determine every parameter (a plate that can take up an
axis's roll, a function with no lever arm) has a Jacobian of lower rank than its
parameters. Here:

- :func:`truncated_pinv`: its rank-truncated pseudo-inverse in scaled columns, with a
  convention for the undetermined part (:func:`null_convention`: what nuisance
  parameters can absorb goes there) and :func:`restricted_pinv` (away from the
  linearisation point, on the directions determined there only).
- :func:`function_status`: which linear functions of the parameters the readings
  determine, which parameters share the null space with them, and (for an estimator
  that is not the least-squares one) which true parameters bias them at first order.

The first-order responses by finite differences (an estimator's to its readings or to
the error sources) are :mod:`mtplan.fitting.effects`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["truncated_pinv", "null_convention", "restricted_pinv", "filter_whitening",
           "gls_pinv", "function_status", "null_space_table"]


# --------------------------------------------------------------------------- pseudo-inverse
def truncated_pinv(a: np.ndarray, scale: np.ndarray, free: np.ndarray | None = None, *,
                   rank_tol: float = 1e-7):
    """Rank-truncated pseudo-inverse of ``a @ diag(1/scale)`` in scaled columns.

    The data do not determine the null-space part of the solution; by default it is the
    minimum-norm one (scaled units). With `free` (a boolean mask of nuisance parameters)
    the null-space part is chosen to minimise the other parameters' norm instead
    (:func:`null_convention`): what the nuisance parameters can absorb goes there.

    Parameters
    ----------
    a : array (n, p)
        The Jacobian [reading unit per parameter unit].
    scale : array (p,)
        Typical size of each parameter; singular values are those of ``a * scale``.
    free : bool array (p,), optional
    rank_tol : float
        Singular values below ``rank_tol`` times the largest count as zero.

    Returns
    -------
    pinv : array (p, n), in the parameters' units
    rank : int
    sv : array (min(n, p),)
        Singular values of the scaled Jacobian.
    vt : array (p, p) or (min(n, p), p)
        Its right singular vectors (rows; those past `rank` span the null space).
    """
    a_s = a * scale
    if a_s.shape[0] > a_s.shape[1]:  # tall: the SVD of the QR's R (same S and V), then
        # pinv = V S^-2 V^T A^T, never the (readings x parameters) U
        _, sv, vt = np.linalg.svd(np.linalg.qr(a_s, mode="r"))
        rank = int(np.sum(sv > rank_tol * sv[0])) if sv.size and sv[0] > 0 else 0
        pinv = ((vt[:rank].T / sv[:rank] ** 2) @ vt[:rank]) @ a_s.T
    else:
        u, sv, vt = np.linalg.svd(a_s, full_matrices=False)
        rank = int(np.sum(sv > rank_tol * sv[0])) if sv.size and sv[0] > 0 else 0
        pinv = (vt[:rank].T / sv[:rank]) @ u[:, :rank].T
    if free is not None and rank < a.shape[1]:
        pinv = null_convention(pinv, vt[rank:].T, free)
    return scale[:, None] * pinv, rank, sv, vt


def null_convention(pinv_s: np.ndarray, null: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Shift a scaled solution map's null-space part so that it minimises the norm of the
    parameters other than the `free` ones; null (p, k) scaled."""
    w = np.where(free, 1e-6, 1.0)[:, None]
    return pinv_s - null @ np.linalg.solve(null.T @ (w * null), null.T @ (w * pinv_s))


def restricted_pinv(jac: np.ndarray, scale: np.ndarray, vt: np.ndarray, rank: int,
                    free: np.ndarray | None = None) -> np.ndarray:
    """Pseudo-inverse of a Jacobian away from the linearisation point, on the parameter
    directions the data determine there (the first `rank` rows of `vt`, scaled): second-
    order effects of undetermined parameters never become (ill-determined) information."""
    basis = vt[:rank].T  # (p, r) scaled
    pinv = basis @ np.linalg.pinv((jac * scale) @ basis)
    if free is not None and rank < jac.shape[1]:
        pinv = null_convention(pinv, vt[rank:].T, free)
    return scale[:, None] * pinv


def filter_whitening(f, ratio: float, components: int = 1):
    """Sparse whitening W of readings whose scatter is a filtered white process plus white
    noise: per component the covariance ``F F^T + ratio^2 I`` (up to a common factor),
    the components alike and independent, interleaved (reading i's components are rows
    ``components i + c``). ``W^T W`` is the inverse covariance (the same factor).

    W = L^-1, L the Cholesky factor: where F is block-diagonal (independent passes of a
    path), so are L and W; entries below 1e-14 of the largest are dropped.

    Parameters
    ----------
    f : sparse or dense array (m, m)
        The filter from innovations (unit variance) to the process.
    ratio : float
        The white noise's standard deviation over the innovations'.
    components : int
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    fs = sp.csr_matrix(f, dtype=float)
    m = fs.shape[0]
    # the covariance is block-diagonal over the connected components of F's pattern: the
    # Cholesky factor and its inverse are too, so each block is factorised alone
    _, label = connected_components(abs(fs) + abs(fs.T), directed=False)
    blocks, big, seen = [], 0.0, {}
    for idx in _groups(label):
        if idx[-1] - idx[0] + 1 == idx.size:  # contiguous (a path's pass): a slice
            fd = fs[idx[0]: idx[-1] + 1, idx[0]: idx[-1] + 1].toarray()
        else:
            fd = fs[idx].toarray()[:, idx]
        key = (fd.shape, fd.tobytes())
        if key not in seen:  # passes alike share their factor
            low = np.linalg.cholesky(fd @ fd.T + ratio**2 * np.eye(idx.size))
            seen[key] = np.linalg.solve(low, np.eye(idx.size))
        wb = seen[key]
        big = max(big, float(np.abs(wb).max()))
        blocks.append((idx, wb))
    rows, cols, vals = [], [], []
    for idx, wb in blocks:
        i, j = np.nonzero(np.abs(wb) >= 1e-14 * big)
        rows.append(idx[i])
        cols.append(idx[j])
        vals.append(wb[i, j])
    w = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(m, m))
    return sp.kron(w, sp.eye(components), format="csr")


def _groups(label: np.ndarray) -> list[np.ndarray]:
    """Indices of each label's members, in increasing order."""
    order = np.argsort(label, kind="stable")
    cuts = np.flatnonzero(np.diff(label[order])) + 1
    return np.split(order, cuts)


def gls_pinv(jac: np.ndarray, scale: np.ndarray, vt: np.ndarray, rank: int,
             free: np.ndarray | None, w) -> np.ndarray:
    """The generalised least-squares map (p, n) of readings whitened by `w` (n, n): the
    :func:`restricted_pinv` of the whitened Jacobian on the directions the unweighted fit
    determines (`vt`, `rank`: the same ones, the whitening being invertible), times `w`."""
    return np.asarray((w.T @ restricted_pinv(np.asarray(w @ jac), scale, vt, rank, free).T).T)


# --------------------------------------------------------------------------- identifiability
def function_status(g: np.ndarray, scale: np.ndarray, null: np.ndarray, owner: Sequence[str],
                    *, no_effect: np.ndarray, unit: np.ndarray, bias_map: np.ndarray | None = None,
                    order: Callable | None = None) -> list[dict]:
    """Whether the readings determine each linear function ``g[i] @ theta``.

    Parameters
    ----------
    g : array (m, p)
        The functions (measurands) as rows over the parameters.
    scale : array (p,)
        Typical size of each parameter (the null space is in scaled units).
    null : array (k, p)
        Scaled null space of the Jacobian (rows).
    owner : sequence of str (p,)
        Which function (or nuisance group) each parameter belongs to.
    no_effect : bool array (m,)
        Functions whose parameters do not move the readings at all.
    unit : array (m,)
        Display factor of each function (1e6 for urad from rad, ...).
    bias_map : array (p, p), optional
        An estimator's first-order response of the estimated to the true parameters;
        functions it does not reproduce are "biased".
    order : callable, optional
        Sort key of the owners named as partners.

    Returns
    -------
    list of dict, one per function: ``status`` ("identified", "unidentifiable",
    "no effect", "biased"), ``listed`` (determined by the readings),
    ``confounded_with`` (partners in the null space, or the true parameters' owners
    that bias the estimate) and ``first_order_bias`` (the largest bias from one typical
    error of a partner, display unit).
    """
    gs = g * scale
    resid = (np.linalg.norm(gs @ null.T, axis=1) / np.linalg.norm(gs, axis=1) if null.size
             else np.zeros(len(g)))
    owner = np.asarray(owner, dtype=object)
    rows = []
    for i in range(len(g)):
        estimable = bool(resid[i] < 1e-6)
        row = {"status": "identified", "listed": estimable, "confounded_with": "",
               "first_order_bias": 0.0}
        if no_effect[i] and not estimable:
            row["status"] = "no effect"
        elif not estimable:
            row["status"] = "unidentifiable"
            cols = np.flatnonzero(g[i] != 0)
            w = np.abs(null[:, cols]).max(axis=1) if null.size else np.zeros(0)
            partners = {owner[j] for v in null[w > 1e-6] for j in np.flatnonzero(np.abs(v) > 1e-3)}
            partners.discard(owner[cols[0]] if cols.size else None)
            row["confounded_with"] = ", ".join(sorted(partners, key=order))
        elif bias_map is not None:
            dev = (g[i] @ bias_map - g[i]) * scale * unit[i]  # display units per typical error
            worst = {}
            for j in np.flatnonzero(np.abs(dev) > 1e-6 * max(1.0, np.abs(gs[i] * unit[i]).max())):
                worst[owner[j]] = max(worst.get(owner[j], 0.0), abs(dev[j]))
            if worst:
                row["status"] = "biased"
                row["confounded_with"] = ", ".join(sorted(worst, key=lambda n: -worst[n]))
                row["first_order_bias"] = float(max(worst.values()))
        rows.append(row)
    return rows


def null_space_table(null: np.ndarray, names: Sequence[str], tol: float = 1e-3) -> list[dict]:
    """Each null direction (rows of `null`) as parameter name -> weight, largest 1, weights
    above `tol` only."""
    out = []
    for v in null:
        v = v / np.abs(v).max()
        out.append({names[j]: float(v[j]) for j in np.flatnonzero(np.abs(v) > tol)})
    return out
