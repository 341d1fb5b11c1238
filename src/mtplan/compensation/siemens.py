"""A SINUMERIK settable frame per sub-machine: ``$P_UIFR[n] = CTRANS(...):CROT(...)``.

A settable frame (G54 ... G599: ``$P_UIFR[n]``) places the workpiece coordinate system in
the basic coordinate system: a point programmed at ``p`` is approached at ``T + R p``, with
the translation ``CTRANS(X, tx, Y, ty, Z, tz)`` and the rotation ``CROT(Z, c, Y, b, X, a)``
[deg] chained after it (``:``). With the rotation angles entered as RPY (machine data
MD10600 $MN_FRAME_ANGLE_INPUT_MODE = 1), ``R = Rz(c) Ry(b) Rx(a)``, the same convention as
the frames' measurands. The frame written is the one that runs programs in the common
(global) coordinates on the sub-machine: ``p_sub = R_k^T (p - t_k)``, so ``R = R_k^T`` and
``T = -R_k^T t_k``, computed exactly from the nominal origin and the measured deviations.
"""

from __future__ import annotations

import math
import re

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.compensation.formats import CompensationFormat, FormatOption

__all__ = ["FORMAT", "frame_of", "rpy_angles", "rotation"]

_TERM = re.compile(r"(origin|rot)_([xyz])_(\d+)$")


def rotation(a: float, b: float, c: float) -> np.ndarray:
    """``Rz(c) Ry(b) Rx(a)`` [rad]."""
    ca, sa, cb, sb, cc, sc = (math.cos(a), math.sin(a), math.cos(b), math.sin(b),
                              math.cos(c), math.sin(c))
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rpy_angles(r: np.ndarray) -> tuple[float, float, float]:
    """(a, b, c) [rad] with ``r = Rz(c) Ry(b) Rx(a)``, b in [-90, 90] deg."""
    b = -math.asin(max(-1.0, min(1.0, r[2, 0])))
    return math.atan2(r[2, 1], r[2, 2]), b, math.atan2(r[1, 0], r[0, 0])


def frame_of(correction) -> dict:
    """{sub-machine: (t [mm], R)}: each frame's pose in the global frame, from the nominal
    origin and the measured deviations (exact, no small-angle shortcut)."""
    parts: dict = {}
    for name in correction.names:
        m = _TERM.match(name)
        if not m:
            raise InvalidInput([f"format 'siemens-frame' writes frames from origin_x_k ... "
                                f"rot_z_k; it has no entry for {name!r}"])
        value, _ = correction.internal(name)
        nominal = float(correction.nominal[correction.names.index(name)])
        parts.setdefault(int(m[3]), {})[(m[1], m[2])] = nominal + value
    out = {}
    for k, p in sorted(parts.items()):
        missing = [f"{kind}_{ax}_{k}" for kind in ("origin", "rot") for ax in "xyz"
                   if (kind, ax) not in p]
        if missing:
            raise InvalidInput([f"sub-machine {k}'s frame needs {', '.join(missing)}"])
        t = np.array([p[("origin", ax)] for ax in "xyz"])
        out[k] = (t, rotation(*(p[("rot", ax)] for ax in "xyz")))
    return out


def _render(correction, options) -> dict:
    files = {}
    n = options["frame"]
    for k, (t, r) in frame_of(correction).items():
        rt = r.T
        tx, ty, tz = -rt @ t
        a, b, c = (math.degrees(v) for v in rpy_angles(rt))
        src = correction.source
        lines = [
            f"; mtplan frame of sub-machine {k} ({correction.procedure}, estimator "
            f"{src.get('estimator')}, result {src.get('file')})",
            "; runs programs in the common (global) coordinates on this sub-machine; "
            "rotation angles as RPY (MD10600 $MN_FRAME_ANGLE_INPUT_MODE = 1), degrees",
            "; U (k = 2) and the predicted residual of every deviation: correction.csv "
            "beside this file",
            f"$P_UIFR[{n}]=CTRANS(X,{tx:.6f},Y,{ty:.6f},Z,{tz:.6f}):"
            f"CROT(Z,{c:.9f},Y,{b:.9f},X,{a:.9f})",
            "M17",
        ]
        files[f"frame_submachine_{k}.spf"] = "\n".join(lines) + "\n"
    return files


def _frame(text: str) -> int:
    n = int(text) if text.isdigit() else -1
    if not 0 <= n <= 99:
        raise ValueError(f"must be a settable frame 0 to 99 (1: G54). Got {text!r} instead.")
    return n


FORMAT = CompensationFormat(
    name="siemens-frame",
    title="SINUMERIK settable frame $P_UIFR[n] (CTRANS:CROT) per sub-machine",
    source="SINUMERIK 840D sl Programming Manual Job Planning, 'Coordinate transformations "
           "(frames)': frame variables $P_UIFR[n], CTRANS, CROT, chaining with ':'; Function "
           "Manual Basic Functions (K2), settable frames and MD10600 "
           "$MN_FRAME_ANGLE_INPUT_MODE (RPY)",
    kinds=("frame",),
    render=_render,
    options=(FormatOption("frame", 1, "the settable frame n of $P_UIFR[n] (1: G54)", _frame),),
)
