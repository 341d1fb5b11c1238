"""tracker_frame's correction: each sub-machine's frame, as the transform that gives the
sub-machine the common (global) coordinate basis."""

from __future__ import annotations

from mtplan.models.correction import CorrectionModel, CorrectionTerm
from mtplan.models.tracker_frame._layout import nominal_origins
from mtplan.models.tracker_frame._setup import Setup


def _terms(setup, names) -> tuple:
    out = []
    for k in range(1, int(setup.get("n_submachines", 2)) + 1):
        for ax in "xyz":
            out.append(CorrectionTerm(
                f"origin_{ax}_{k}", {f"origin_{ax}_{k}": 1.0}, "um",
                f"sub-machine {k}'s origin minus nominal, global {ax.upper()}"))
        for ax in "xyz":
            out.append(CorrectionTerm(
                f"rot_{ax}_{k}", {f"rot_{ax}_{k}": 1.0}, "urad",
                f"sub-machine {k}'s frame turned about global {ax.upper()} "
                "(R = Rz Ry Rx)"))
    return tuple(out)


def _nominal(setup) -> dict:
    """The nominal origins [mm] (the model's, :func:`._layout.nominal_origins`)."""
    keys = ("n_submachines", "submachine_spacing_mm", "origin_height_mm")
    origins = nominal_origins(Setup(**{k: setup[k] for k in keys if k in setup}))
    return {f"origin_{ax}_{k + 1}": float(v) for k, row in enumerate(origins)
            for ax, v in zip("xyz", row)}


CORRECTION = CorrectionModel(
    kind="frame",
    frame="the global frame set up on the bed's marks (origin at the bed centre, X along "
          "the bed, Z up); sub-machine k's nominal origin at (0, y_k, origin_height_mm) with "
          "the global axes, y_k submachine_spacing_mm apart centred on Y = 0",
    sign="the sub-machine's frame in the global one: p_global = R p_sub + t, t its nominal "
         "origin plus origin_*_k, R = Rz(rot_z_k) Ry(rot_y_k) Rx(rot_x_k) about the fixed "
         "global axes; a control's frame that runs global coordinates on the sub-machine is "
         "its inverse, p_sub = R^T (p_global - t)",
    terms=_terms,
    nominal=_nominal,
)
