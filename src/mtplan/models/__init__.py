"""Measurement procedures: forward models and estimators, one module each.

Every module ``mtplan/models/<name>.py`` whose name does not start with ``_`` and
that defines ``PROCEDURE`` (a :class:`~mtplan.models.protocol.Procedure`) is
registered under ``PROCEDURE.name``; see :mod:`mtplan.models.protocol`.
"""

from __future__ import annotations

import importlib
import pkgutil

from mtplan._validate import InvalidInput
from mtplan.models.protocol import Measurand, Procedure, SetupBase, Source, param

__all__ = ["Measurand", "Procedure", "SetupBase", "Source", "param", "registry", "get"]

_REGISTRY: dict[str, Procedure] | None = None


def registry() -> dict[str, Procedure]:
    """All registered procedures, by name, in module order."""
    global _REGISTRY
    if _REGISTRY is None:
        found = {}
        for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
            if info.name.startswith("_"):
                continue
            module = importlib.import_module(f"{__name__}.{info.name}")
            proc = getattr(module, "PROCEDURE", None)
            if isinstance(proc, Procedure):
                found[proc.name] = proc
        _REGISTRY = found
    return _REGISTRY


def get(name) -> Procedure:
    """The procedure called `name` (a Procedure passes through)."""
    if isinstance(name, Procedure):
        return name
    procs = registry()
    if name not in procs:
        raise InvalidInput(
            [f"Unknown procedure {name!r}; the procedures are: {', '.join(procs) or '(none)'}."]
        )
    return procs[name]
