"""Input checking that reports every problem at once.

Every public entry point of mtplan validates its input through :class:`Problems`
and raises a single :class:`InvalidInput` naming each field, its value and what
is allowed, in the style of scikit-learn's parameter validation::

    The 'std' parameter of Normal must be a finite number >= 0. Got -1.0 instead.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable

import numpy as np

__all__ = ["InvalidInput", "Problems"]


class InvalidInput(ValueError, TypeError):
    """Bad input: a ``ValueError`` (and ``TypeError``) listing every problem.

    Attributes
    ----------
    problems : list of str
        One sentence per problem, each naming the field, its value and what is allowed.
    """

    def __init__(self, problems: Iterable[str]):
        self.problems = list(problems)
        super().__init__(" ".join(self.problems))


def _show(value) -> str:
    if isinstance(value, float | np.floating):
        return repr(float(value))
    if isinstance(value, np.ndarray):
        return np.array2string(value, threshold=6)
    if isinstance(value, tuple | list) and len(value) > 6:  # never the repr of a long list
        return f"({', '.join(_show(v) for v in value[:3])}, ... {len(value)} elements)"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def is_real(value) -> bool:
    """True for a real scalar (bool excluded)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


class Problems:
    """Collects problems with the parameters of one owner, then raises them together.

    Parameters
    ----------
    owner : str
        What the parameters belong to, e.g. ``"Normal"`` or ``"rotary_axis"``.
    """

    def __init__(self, owner: str):
        self.owner = owner
        self.items: list[str] = []

    def add(self, name: str, value, allowed: str) -> None:
        """Record that parameter `name` has `value` where `allowed` was expected."""
        self.items.append(
            f"The '{name}' parameter of {self.owner} must be {allowed}. Got {_show(value)} instead."
        )

    def add_text(self, text: str) -> None:
        """Record a problem that is not about one parameter (a cross-field rule)."""
        self.items.append(text if text.endswith(".") else text + ".")

    def number(
        self,
        name: str,
        value,
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
        high_open: bool = False,
        integer: bool = False,
        finite: bool = True,
    ) -> bool:
        """Check a real (or integer) scalar against a range; return whether it passed."""
        kind = "an int" if integer else ("a finite number" if finite else "a number")
        bounds = []
        if low is not None:
            bounds.append(f"{'>' if low_open else '>='} {low:g}")
        if high is not None:
            bounds.append(f"{'<' if high_open else '<='} {high:g}")
        allowed = kind + (" " + " and ".join(bounds) if bounds else "")
        ok = is_real(value) and (not integer or float(value).is_integer())
        if ok:
            v = float(value)
            if math.isnan(v) or (finite and math.isinf(v)):
                ok = False
            elif low is not None and (v < low or (low_open and v == low)):
                ok = False
            elif high is not None and (v > high or (high_open and v == high)):
                ok = False
        if not ok:
            self.add(name, value, allowed)
        return ok

    def choice(self, name: str, value, choices: Iterable) -> bool:
        """Check that `value` is one of `choices`."""
        choices = list(choices)
        if value not in choices:
            self.add(name, value, "one of " + ", ".join(repr(c) for c in choices))
            return False
        return True

    def require(self, condition: bool, name: str, value, allowed: str) -> bool:
        """Record a problem unless `condition` holds."""
        if not condition:
            self.add(name, value, allowed)
        return bool(condition)

    def __bool__(self) -> bool:
        return bool(self.items)

    def raise_if_any(self) -> None:
        """Raise :class:`InvalidInput` with every recorded problem, if any."""
        if self.items:
            raise InvalidInput(self.items)
