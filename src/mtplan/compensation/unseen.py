"""What the test cannot see, and what it moved in the estimate: the unseen part's covariance.

A procedure's correction model states what stays after a correction although the test cannot
see it (``unseen``: geometry21's short-wave path residual and medium-wave field at a table's
point) and its value on a simulated machine (``realised``, linear in the source draws). The
same field also moved the readings, and through them the estimate: the residual after
compensation at a point,

    r = true + f - estimate = f - e,        e = estimate - true,

has the variance ``var(e) + var(f) - 2 cov(e, f)``, not the quadrature sum. Here, over the
sources that ``realised`` reads (z, independent elements of unit variance after scaling by
their standard deviations), ``f = A z`` (``A``: ``realised``'s map, exact by its linearity)
and the estimate's share ``e_z = J z`` (``J``: the first-order service's sensitivities,
:func:`mtplan.evaluation.first_order.first_order`, for the result's estimator at its
set-up), so the unseen part adds

    D = A A^T - J A^T - A J^T

to the result's covariance of the measurands (the covariance of ``f - e`` is
``C - J J^T + (A - J)(A - J)^T``, C the result's). ``D`` covers every pair of measurands, so a
function's table points are joint (their simultaneous band needs no independence).
"""

from __future__ import annotations

import numpy as np

from mtplan.fitting.effects import element_moments

__all__ = ["unseen_covariance"]


def _rows(procedure, setup, active: dict, n: int, writable: tuple) -> dict:
    """`n` error rows with every active source at its mean (the others zero): the sources
    `writable` as arrays, the rest as read-only views of one row (no copies of the
    readings-sized sources)."""
    errors = procedure.zero_errors(setup, 1)
    for name, src in active.items():
        mean, _std, shape = element_moments(src)
        errors[name] = mean.reshape((1, *shape))
    return {name: np.repeat(row, n, axis=0) if name in writable
            else np.broadcast_to(row, (n, *row.shape[1:])) for name, row in errors.items()}


def _realised(procedure, setup, errors: dict, names: tuple) -> np.ndarray:
    """(rows, names) of ``realised`` [display unit], 0 for a measurand it leaves out."""
    out = procedure.correction.realised(setup, errors)
    n = next(iter(errors.values())).shape[0]
    return np.column_stack([np.broadcast_to(np.asarray(out.get(m, 0.0), float).reshape(-1), (n,))
                            for m in names]) if names else np.zeros((n, 0))


def _read_sources(procedure, setup, active: dict, names: tuple) -> tuple:
    """The active sources ``realised`` reads: each one drawn alone (one row each, a fixed
    seed: the detection does not depend on the draw) moves it off its value at the means."""
    order = tuple(active)
    errors = _rows(procedure, setup, active, 1 + len(order), order)
    draw = procedure.draw_errors(setup, 1, np.random.SeedSequence(0))
    for i, name in enumerate(order, start=1):
        errors[name][i] = draw[name][0]
    values = _realised(procedure, setup, errors, names)
    moved = np.any(values[1:] != values[0], axis=1)
    return tuple(name for name, m in zip(order, moved) if m)


def unseen_covariance(procedure, doc: dict) -> tuple[tuple, np.ndarray] | None:
    """``(names, D)``: the unseen part's contribution ``D`` [display units squared] to the
    covariance of the residual ``true + f - estimate`` over the procedure's measurands
    `names` (also where ``realised`` leaves one out: its estimate's error may share the
    field), for the result `doc` (``estimate --json``: its set-up and
    estimator); None where the model states nothing unseen or realises nothing (then the residual takes ``unseen``
    as independent of the estimate)."""
    model = procedure.correction
    if doc.get("procedure") != procedure.name or not model.unseen(doc.get("setup") or {}):
        return None
    setup = procedure.setup(doc.get("setup") or {})
    names = tuple(m.name for m in procedure.measurands(setup))
    active = procedure.active_sources(setup)
    read = _read_sources(procedure, setup, active, names) if active else ()
    if not read:
        return None
    from mtplan.evaluation.first_order import first_order

    # A: realised's change per one standard deviation of each element (central: exact for a
    # linear map), the elements in the first-order service's order
    moments = {name: element_moments(active[name]) for name in read}
    sizes = [mean.size for mean, _, _ in moments.values()]
    k = sum(sizes)
    errors = _rows(procedure, setup, active, 2 * k, read)
    col = 0
    for name, (mean, std, shape) in moments.items():
        flat = errors[name].reshape(2 * k, -1)
        j = np.arange(mean.size)
        flat[2 * (col + j), j] += std
        flat[2 * (col + j) + 1, j] -= std
        errors[name] = flat.reshape((2 * k, *shape))
        col += mean.size
    values = _realised(procedure, setup, errors, names)
    a = 0.5 * (values[0::2] - values[1::2]).T  # (names, k)
    gum = first_order(procedure, setup, estimator=doc.get("estimator"), sources=read)
    jac = np.asarray(gum.sensitivity, float) * np.asarray(gum.input_std, float)  # per sd
    j = jac[[gum.names.index(n) for n in names]]
    d = a @ a.T - j @ a.T - a @ j.T
    return names, 0.5 * (d + d.T)
