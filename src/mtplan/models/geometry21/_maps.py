"""geometry21's first-order maps in closed form: the patent estimator's derivative with
respect to the readings, and the readings' response to each error source's elements.

The patent's map was central differences of its two steps (2 evaluations per reading),
which took most of a first-order budget's time; here it is the chain rule of the same
steps, exact to rounding, and the tests hold it to the central differences (relative 1e-6
of its largest entry, the differences' own truncation and rounding error being about
1e-8). The readings' Jacobian at zero error is :mod:`._jacobian`'s.
"""
from __future__ import annotations

import numpy as np

from mtplan.models.geometry21._layout import geometry, grid_basis, plane_slices
from mtplan.models.geometry21._model import readings_matrix
from mtplan.models.geometry21._patent import patent_design
from mtplan.models.geometry21._path import FIELDS, residual_basis, residual_response
from mtplan.models.geometry21._physics import forward_matrix, sources
from mtplan.models.geometry21._setup import Setup, sizeless

def patent_map(setup: Setup, readings: np.ndarray) -> np.ndarray:
    """A (P, 2M): the derivative of the patent's stepwise estimate (``theta_patent``) with
    respect to the readings, at `readings` (2M,) (flattened as ``readings_matrix``).

    Step 1 is linear; step 2 brings each reading back to the nominal plate frame with the
    step-1 mounting (a rotation by phi and a shift) and takes the circles' radii, less the
    step-1 errors' first-order effect: its derivative is the direct one plus the mounting's
    and the step-1 errors', through the step-1 map."""
    pd_ = patent_design(setup)
    geo = pd_["geo"]
    r = readings_matrix(setup, {"plate_mm": np.asarray(readings, float).reshape(1, -1, 2)})[0]
    n2 = r.size
    lin1 = np.zeros((geo.n_par, n2))  # step 1, with its overwrites in the same order
    for pl in pd_["planes"]:
        kc = pl["c1"][pl["keep"]]
        lin1[kc] = 0.0
        lin1[np.ix_(kc, pl["rows"])] = pl["a1"][pl["keep"]]
        lin1[pl["nuis"]] = 0.0
        lin1[np.ix_(pl["nuis"], pl["rows"])] = pl["a1"][-3:]
    theta1 = lin1 @ (r - pd_["r0"])
    r3 = r.reshape(-1, 2)
    a2, c2 = pd_["a2"], pd_["c2"]
    step2 = np.zeros((c2.size, n2))  # a2 @ (d deviations / d readings), term by term
    row = 0
    for pl in pd_["planes"]:
        o_u, o_v, phi = theta1[pl["nuis"]]
        c, s = np.cos(phi), np.sin(phi)
        first = row
        for idx, radial in ((pl["circ"], True), (pl["xlines"], False)):
            ru, rv = r3[idx, 0], r3[idx, 1]
            lu, lv = c * ru - s * rv + o_u, s * ru + c * rv + o_v
            one, zero = np.ones(idx.size), np.zeros(idx.size)
            # d(lu, lv) / d(ru, rv, o_u, o_v, phi), per point: (n, 2, 5)
            d = np.stack([np.column_stack([c * one, -s * one, one, zero, -(lv - o_v)]),
                          np.column_stack([s * one, c * one, zero, one, lu - o_u])], axis=1)
            if radial:  # the radius: the unit radial vector times that
                unit = np.column_stack([lu, lv]) / np.hypot(lu, lv)[:, None]
                d = np.einsum("nc,ncj->nj", unit, d)[:, None]
            npt, ndv = d.shape[:2]
            block = a2[:, row: row + npt * ndv]
            row += npt * ndv
            per_point = block.reshape(c2.size, npt, ndv)
            for comp in range(2):  # each deviation depends on its own reading directly
                step2[:, 2 * idx + comp] += np.einsum("cpd,pd->cp", per_point, d[:, :, comp])
            step2 += (block @ d[:, :, 2:].reshape(-1, 3)) @ lin1[pl["nuis"]]
        step2 -= (a2[:, first:row] @ pl["q1"]) @ lin1[pd_["c1_all"]]
    out = lin1.copy()
    out[c2] += step2
    return out


def mapped_source_response(setup: Setup, truth, names, left: np.ndarray) -> np.ndarray:
    """``left @ source_readings_map(setup, truth, names)`` for a map `left` (n, 2M) of the
    readings: the path residual's columns from its basis's factors
    (:func:`._path.residual_response`), the other sources' through their readings map."""
    srcs = sources(setup)
    dense = tuple(name for name in names if name not in FIELDS)
    parts = iter(np.split(left @ source_readings_map(setup, truth, dense), np.cumsum(
        [int(np.prod(srcs[name].shape, dtype=np.int64)) for name in dense])[:-1], axis=1)
        if dense else ())
    cols = [float(srcs[name].distribution.std) * residual_response(sizeless(setup), left, name)
            if name in FIELDS else next(parts) for name in names]
    return np.concatenate(cols, axis=1) if cols else np.zeros((left.shape[0], 0))


def source_readings_map(setup: Setup, truth, names) -> np.ndarray:
    """(2M, K): the readings' first-order response to one standard deviation of each element
    of the named sources (in the order of :func:`mtplan.fitting.effects.source_response`),
    about the sources' means, in closed form: the grid's field, the plates' offsets and the
    extra heads' settings add; the drift, reversal and servo features move the head by
    their patterns (the servo's square by twice the mean following time); a plate's tilt
    and rotation turn the mean head position (``Rinv`` to first order: ``-e x loc``)."""
    srcs = sources(setup)
    geo = geometry(setup)
    m = geo.plane.size
    feat = np.concatenate([np.zeros(9), np.full(3, srcs["servo_lag"].distribution.mean)])
    feat = np.concatenate([feat, feat[9:] ** 2])
    feat[6:9] = srcs["reversal"].distribution.mean
    base = forward_matrix(setup, truth)
    loc = (np.concatenate([[1.0], feat]) @ base).reshape(m, 3)
    pattern = geo.pattern[:, :, :2]  # (15, M, 2): plate-frame u, v per unit feature
    planes = plane_slices(geo)
    sizes = [int(np.prod(srcs[name].shape, dtype=np.int64)) for name in names]
    out = np.zeros((m, 2, sum(sizes)))  # reading, component, element: filled in place
    pos = 0
    for name, size in zip(names, sizes):
        block = out[:, :, pos: pos + size]
        pos += size
        shape = srcs[name].shape
        if name == "grid_error":
            basis = grid_basis(geo)
            for j, (k, c, p) in enumerate(np.ndindex(*shape)):
                block[planes[k], c, j] = basis[planes[k], p]
        elif name == "plate_offset":
            for j, (k, c) in enumerate(np.ndindex(*shape)):
                block[planes[k], c, j] = -1.0
        elif name == "head_setting":
            for j, (e, c) in enumerate(np.ndindex(*shape)):
                block[geo.xslices[e][1], c, j] = 1.0
        elif name in FIELDS:
            block[...] = residual_basis(sizeless(setup), name).reshape(m, 2, -1)
        elif name == "plate_tilt":
            for k, sl in enumerate(planes):
                lu, lv, ln = loc[sl].T
                block[sl, 1, 3 * k] = ln  # about u
                block[sl, 0, 3 * k + 1] = -ln  # about v
                block[sl, :, 3 * k + 2] = np.column_stack([lv, -lu])  # about the normal
        else:
            first = {"thermal_growth": 0, "thermal_drift": 3, "reversal": 6, "servo_lag": 9}[name]
            block[...] = pattern[first: first + 3].transpose(1, 2, 0)
            if name == "servo_lag":
                block += 2.0 * (feat[9:12, None, None] * pattern[12:15]).transpose(1, 2, 0)
        block *= float(srcs[name].distribution.std)
    return out.reshape(2 * m, -1)
