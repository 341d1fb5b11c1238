"""What would decide a measurand that has no pass, computed from its uncertainty budget.

A value in the guard band is decided by a smaller U; which U is reachable, and by whom, is
in the budget: each error source carries a share of u², and each source has an owner (the
set-up field that sizes it declares it, :data:`~mtplan.models.protocol.OWNERS`). Only the
owners the laboratory can act on reduce U: an instrument or an artefact by a calibration
(or a better one), the method by another set-up, the environment by tighter conditions.
The machine's own errors (its repeatability, its short-wave path deviation) and the
workpiece's are what is measured, not what a better instrument removes.

- :func:`source_effects`: per source its owner, its share of u², and U without it and with
  it halved (``U sqrt(1 - s)``, ``U sqrt(1 - 3 s / 4)``).
- :func:`budget_action`: the fewest sources, largest share first, among those the
  laboratory can act on, whose halving, else whose removal, brings U below the U needed;
  the repeats that would (only where the random share allows it); else the floor that no
  such action passes.

Numbers only; the documents phrase them (:mod:`mtplan.reports.actions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mtplan.plans.decisions import random_share, repeated_U, repeats_needed

__all__ = ["ACTIONABLE", "SourceEffect", "BudgetAction", "source_owners", "owner_of",
           "source_effects", "budget_action", "after"]

#: the owners whose share of u² the laboratory can reduce, and how
ACTIONABLE = {"instrument": "calibration", "artefact": "calibration", "method": "set-up",
              "environment": "conditions"}


@dataclass
class SourceEffect:
    """One error source of one measurand's budget (display units)."""

    source: str
    owner: str          # an OWNERS entry, or "not declared"
    share: float        # of u², the budget's shares normalised to 1
    U_without: float    # noqa: N815 - U with the source removed
    U_halved: float     # noqa: N815 - U with the source's standard uncertainty halved


@dataclass
class BudgetAction:
    """What would bring a measurand's U below the U needed (display units).

    ``kind``: "calibration", "set-up" or "conditions" (the owner of the sources acted on;
    "mixed" for several), "repeat", or "none" (nothing the laboratory can act on reaches).
    ``acted``: the sources acted on, ``how`` "halved" or "removed", ``U_after`` the U then;
    ``floor``: U with every source the laboratory can act on removed; ``repeats``: the
    number of repeats whose average reaches ``needed`` (None where none up to 50 does).
    """

    measurand: str
    U: float            # noqa: N815
    needed: float
    kind: str
    effects: list = field(default_factory=list)
    acted: list = field(default_factory=list)
    how: str = ""
    U_after: float = math.nan   # noqa: N815
    floor: float = math.nan
    repeats: int | None = None
    random: float = 0.0


def source_owners(procedure) -> dict:
    """{source name: owner} of a procedure: each source's owner is the one that the set-up
    field sizing it (its ``Source.field``) declares."""
    from mtplan.models.protocol import fields_info

    by_field = {f.name: f.owner for f in fields_info(procedure.Setup) if f.owner}
    return {name: by_field[src.field]
            for name, src in procedure.sources(procedure.Setup()).items()
            if src.field in by_field}


def owner_of(owners: dict, source: str) -> str:
    """The owner of the source named ``source`` ("not declared" where its field names none)."""
    return owners.get(source, "not declared")


def after(U: float, removed_share: float) -> float:  # noqa: N803
    """U once ``removed_share`` of u² is gone (``U sqrt(1 - s)``)."""
    return U * math.sqrt(max(1.0 - removed_share, 0.0))


def source_effects(budget, measurand: str, U: float, owners: dict) -> list:  # noqa: N803
    """The sources of ``measurand`` in its budget (columns ``input``, ``output``,
    ``share``), largest share first, each with its owner and U without it and halved;
    [] without budget rows for it."""
    if budget is None or not len(budget):
        return []
    rows = budget[budget["output"] == measurand]
    total = float(rows["share"].sum()) if len(rows) else 0.0
    if not total > 0:
        return []
    out = []
    for r in rows.sort_values("share", ascending=False).itertuples():
        s = float(r.share) / total
        out.append(SourceEffect(str(r.input), owner_of(owners, str(r.input)), s, after(U, s),
                                after(U, 0.75 * s)))
    return out


def budget_action(budget, measurand: str, U: float, needed: float, owners: dict,  # noqa: N803
                  *, least: float = 0.01) -> BudgetAction | None:
    """What brings U below ``needed`` (see the module notes); None without a budget.

    The sources considered carry at least ``least`` of u² and have an owner in
    :data:`ACTIONABLE`; halving them, largest first, is tried before removing them.
    """
    effects = source_effects(budget, measurand, U, owners)
    if not effects:
        return None
    act = BudgetAction(measurand, U, needed, "none", effects=effects)
    found = random_share(budget, measurand)
    act.random = found[0] if found else 0.0
    usable = [e for e in effects if e.owner in ACTIONABLE and e.share >= least]
    act.floor = after(U, sum(e.share for e in usable))
    n = repeats_needed(U, needed, act.random)
    act.repeats = n if n is not None and n > 1 else None
    for how, factor in (("halved", 0.75), ("removed", 1.0)):
        taken = 0.0
        for j, e in enumerate(usable):
            taken += factor * e.share
            if after(U, taken) < needed:
                act.acted, act.how, act.U_after = usable[:j + 1], how, after(U, taken)
                kinds = {ACTIONABLE[x.owner] for x in act.acted}
                act.kind = kinds.pop() if len(kinds) == 1 else "mixed"
                return act
    if act.repeats is not None:
        act.kind, act.U_after = "repeat", repeated_U(U, act.random, act.repeats)
    return act
