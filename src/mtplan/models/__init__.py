"""Measurement procedures: the registry, the procedure contract, and the built-in procedures.

A procedure is registered through the entry-point group ``mtplan.procedures``
(:data:`ENTRY_POINT_GROUP`): each entry point names a :class:`~mtplan.models.protocol.Procedure`
object, and its name is the procedure's name::

    [project.entry-points."mtplan.procedures"]
    edge_line = "mtplan_edge_line:PROCEDURE"

mtplan's own procedures are registered so in its ``pyproject.toml``, and an installed package
adds one the same way, without a change to mtplan (``docs/adding_a_procedure.md``).

A plug-in that gives no procedure (its import fails, it names something that is not a
Procedure, its name differs from the procedure's or is already taken) is left out, and
:func:`broken` says why: the other procedures work as before, ``mtplan procedures`` names it
on stderr, and asking for it by name raises that reason.

An mtplan installed before its own entry points were declared (an editable install made
earlier) declares none: the built-in procedures are then found as the modules of this
package that define ``PROCEDURE``, their registration before entry points, until mtplan is
installed again (``pip install -e .``).
"""

from __future__ import annotations

import importlib
import pkgutil
from importlib.metadata import EntryPoint, entry_points

from mtplan._validate import InvalidInput
from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Measurand,
    Procedure,
    Readings,
    ReadingsFormat,
    SetupBase,
    Source,
    SourceMethod,
    distributions_field,
    param,
)

__all__ = ["Capabilities", "Estimator", "Measurand", "Procedure", "Readings", "ReadingsFormat",
           "SetupBase", "Source", "SourceMethod", "param", "distributions_field", "registry",
           "get", "broken", "ENTRY_POINT_GROUP"]

#: the entry-point group through which installed packages register procedures
ENTRY_POINT_GROUP = "mtplan.procedures"

_REGISTRY: dict[str, Procedure] | None = None
#: built-in procedures :func:`get` loaded alone before the registry was (looking an entry
#: point up reads every installed package's metadata: tens of milliseconds a call)
_ALONE: dict[str, Procedure] = {}
#: (entry point's name, why it gave no procedure), from the last :func:`registry` scan
_BROKEN: list[tuple[str, str]] = []


def _distribution(point: EntryPoint) -> str:
    """The installed package that declares `point`, normalised (``My_Pkg`` -> ``my-pkg``)."""
    dist = getattr(point, "dist", None)
    return dist.name.lower().replace("_", "-") if dist is not None and dist.name else ""


def _origin(point: EntryPoint) -> str:
    dist = getattr(point, "dist", None)
    package = f"package {dist.name} {dist.version}" if dist is not None else "an unknown package"
    return f"the entry point {point.name} = {point.value!r} of {package}"


def _load(point: EntryPoint, taken: dict[str, Procedure]) -> tuple[Procedure | None, str]:
    """The procedure `point` names, or None and why not."""
    if point.name in taken:
        return None, (f"{_origin(point)} was left out: the procedure {point.name!r} is "
                      "already registered")
    try:
        proc = point.load()
    except Exception as exc:  # noqa: BLE001 - any failure of a plug-in's import is reported
        return None, f"{_origin(point)} could not be loaded: {type(exc).__name__}: {exc}"
    if not isinstance(proc, Procedure):
        return None, (f"{_origin(point)} names a {type(proc).__name__}, not an "
                      "mtplan.models.Procedure")
    if proc.name != point.name:
        return None, (f"{_origin(point)} names the procedure {proc.name!r}: an entry point's "
                      "name must be its procedure's name")
    return proc, ""


def registry() -> dict[str, Procedure]:
    """Every registered procedure, by name, in the order of their names.

    Loaded once: the entry points of :data:`ENTRY_POINT_GROUP`, mtplan's own first (a
    plug-in cannot replace a built-in procedure); those that give no procedure are listed
    by :func:`broken`.
    """
    global _REGISTRY, _BROKEN
    if _REGISTRY is None:
        points = list(entry_points(group=ENTRY_POINT_GROUP))
        found: dict[str, Procedure] = {}
        if not any(_distribution(p) == "mtplan" for p in points):
            # an mtplan installed without its entry points (see the module's docstring)
            for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
                if info.name.startswith("_"):
                    continue
                module = importlib.import_module(f"{__name__}.{info.name}")
                proc = getattr(module, "PROCEDURE", None)
                if isinstance(proc, Procedure):
                    found[proc.name] = proc
        problems = []
        for point in sorted(points, key=lambda p: (_distribution(p) != "mtplan", p.name,
                                                   _distribution(p))):
            proc, why = _load(point, found)
            if proc is None:
                problems.append((point.name, why))
            else:
                found[proc.name] = proc
        _REGISTRY, _BROKEN = dict(sorted(found.items())), problems
    return _REGISTRY


def broken() -> list[str]:
    """Why each installed entry point of :data:`ENTRY_POINT_GROUP` that gave no procedure
    was left out (naming the entry point and its package); empty when all loaded."""
    registry()
    return [why for _, why in _BROKEN]


def get(name) -> Procedure:
    """The procedure called `name` (a Procedure passes through)."""
    if isinstance(name, Procedure):
        return name
    if _REGISTRY is None:  # a built-in procedure alone, without importing the others
        if name not in _ALONE:
            point = next((p for p in entry_points(group=ENTRY_POINT_GROUP, name=name)
                          if _distribution(p) == "mtplan"), None)
            proc = None if point is None else _load(point, {})[0]
            if proc is not None:  # the object registry() gives: a built-in is never replaced
                _ALONE[name] = proc
        if name in _ALONE:
            return _ALONE[name]
    procs = registry()
    if name not in procs:
        reasons = [why for point, why in _BROKEN if point == name]
        if reasons:
            raise InvalidInput([f"The procedure {name!r} is installed but unusable: "
                                + " ".join(reasons)])
        raise InvalidInput(
            [f"Unknown procedure {name!r}; the procedures are: {', '.join(procs) or '(none)'}."]
        )
    return procs[name]
