"""The patent's stepwise estimator of geometry21: step 1 fits each plane's first-head
lines (the patent's assignment of errors, and the plate's mounting), step 2 the three
circles and the extra heads' lines with the step-1 mounting removed exactly (the angular
errors and the heads' settings). Re-exported by :mod:`mtplan.models.geometry21`."""

from __future__ import annotations

import functools

import numpy as np

from mtplan.models.geometry21._model import joint_ident, readings_matrix, tpinv
from mtplan.models.geometry21._setup import KIND, NAMES, PLANES, STEP1, Setup, sizeless


@functools.lru_cache(maxsize=8)
def patent_design(setup: Setup) -> dict:
    if (key := sizeless(setup)) != setup:  # the geometry's, for every size of the sources
        return patent_design(key)
    ji = joint_ident(setup)
    geo, jac, s = ji["geo"], ji["jac"], ji["scale"]
    m = geo.plane.size
    j3 = jac.reshape(m, 2, geo.n_par)

    def cols(names):
        return np.concatenate([np.arange(geo.n_par)[geo.layout[n][1]] for n in names])

    c1_all = cols([n for pl in STEP1.values() for n in pl])
    planes = []
    for k, (pl, a, b, _c) in enumerate(PLANES):
        A, B = "XYZ"[a], "XYZ"[b]
        sq = {"XY": "EC0Y", "XZ": "EB0Z", "YZ": "EA0Z"}[pl]
        fit = [f"E{A}{A}", f"E{B}{B}", f"E{B}{A}", f"E{A}{B}", sq]
        c1 = np.concatenate([cols(fit), geo.n_coef + 3 * k + np.arange(3)])
        lines = np.flatnonzero((geo.plane == k) & (geo.test < 2) & (geo.head == 0))
        rows = (2 * lines[:, None] + np.arange(2)).ravel()
        a1, rank1, _, _ = tpinv(jac[np.ix_(rows, c1)], s[c1])
        circ = np.flatnonzero((geo.plane == k) & (geo.test == 2))
        er = geo.local[circ] / setup.circle_radius_mm  # (Mc, 2) radial unit vectors
        jrad = np.einsum("mc,mcp->mp", er, j3[circ])  # first-order radial model (Mc, P)
        # the extra heads' lines; with extra heads, the first head's lines again, for the
        # plate's mounting that step 2 re-estimates from every head (below)
        more = np.any((geo.plane == k) & (geo.head > 0))
        xlines = np.flatnonzero((geo.plane == k) & (geo.test < 2) & ((geo.head > 0) | more))
        jlin = j3[xlines].reshape(-1, geo.n_par)  # extra heads' lines, both components
        keep = np.isin(c1, cols(STEP1[pl]))
        planes.append(dict(rows=rows, c1=c1, a1=a1, keep=keep, circ=circ, xlines=xlines,
                           q1=np.concatenate([jrad, jlin])[:, c1_all],
                           q2=np.concatenate([jrad, jlin]), rank1=rank1,
                           nuis=geo.n_coef + 3 * k + np.arange(3)))
    # step 2: the three circles stacked with the extra heads' lines: the angular errors
    # and the extra heads' settings (see the module docstring)
    # where extra heads read a plate, step 2 corrects that plate's mounting too: step 1 took
    # into it what it could not tell from it (the X roll and the other axes' errors at
    # the plate's fixed coordinate), which step 2 subtracts again with the step-1 errors
    mounts = [geo.n_coef + 3 * k + j for k in range(3) if np.any((geo.plane == k) & (geo.head > 0))
              for j in range(3)]
    c2 = np.concatenate([cols([n for n in NAMES if KIND[n] == "ang"]), mounts,
                         np.arange(geo.n_coef + 9, geo.n_par)]).astype(int)
    q2 = np.concatenate([pl["q2"][:, c2] for pl in planes])
    a2, rank2, _, _ = tpinv(q2, s[c2])
    return {"geo": geo, "planes": planes, "c1_all": c1_all, "c2": c2, "a2": a2, "rank2": rank2,
            "r0": ji["r0"]}


def theta_patent(setup: Setup, readings: dict) -> np.ndarray:
    pd_ = patent_design(setup)
    geo = pd_["geo"]
    r = readings_matrix(setup, readings)
    dr = r - pd_["r0"]
    n = r.shape[0]
    theta = np.zeros((n, geo.n_par))
    # step 1: the first head's line records of each plane -> 12 errors (patent's assignment)
    # + mounting
    for pl in pd_["planes"]:
        est = dr[:, pl["rows"]] @ pl["a1"].T  # one product for the batch
        theta[:, pl["c1"][pl["keep"]]] = est[:, pl["keep"]]
        theta[:, pl["nuis"]] = est[:, -3:]
    # step 2: every other reading back in the nominal plate frame (step-1 mounting removed
    # exactly), less the step-1 errors' first-order effect -> angular errors, head settings
    r3 = r.reshape(n, -1, 2)
    es = []
    for pl in pd_["planes"]:
        o_u, o_v, phi = (theta[:, pl["nuis"][j]][:, None] for j in range(3))
        c, sn = np.cos(phi), np.sin(phi)
        parts = []
        for idx in (pl["circ"], pl["xlines"]):
            rc = r3[:, idx, :]
            lu = c * rc[..., 0] - sn * rc[..., 1] + o_u
            lv = sn * rc[..., 0] + c * rc[..., 1] + o_v
            parts.append((lu, lv))
        (cu, cv), (xu, xv) = parts
        dev = np.concatenate([np.hypot(cu, cv) - setup.circle_radius_mm,
                              np.stack([xu, xv], axis=-1).reshape(n, -1)
                              - geo.local[pl["xlines"]].ravel()], axis=1)
        es.append(dev - theta[:, pd_["c1_all"]] @ pl["q1"].T)
    theta[:, pd_["c2"]] += np.concatenate(es, axis=1) @ pd_["a2"].T  # rotations: corrections
    return theta
