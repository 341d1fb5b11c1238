"""The interface of a writer of corrections in a controller's format, and the residual.

A format is a :class:`CompensationFormat`: its name, the public document it follows, the
kinds of correction it can hold, its options and limits, and ``render(correction,
options) -> {file name: text}``. The registry (:mod:`mtplan.compensation.registry`) holds
the built-in formats and those that installed packages add through the entry point group
``mtplan.compensation_formats`` (a ``CompensationFormat`` instance), as procedures are added.

Every format writes the values of :class:`~mtplan.compensation.model.Correction` rounded to
its resolution; the predicted residual after compensation (:func:`residual`) includes that
rounding, which is known exactly once the file is written.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.compensation.model import Correction

__all__ = ["FormatOption", "CompensationFormat", "residual", "Residual", "rounded", "decimals"]

#: two-sided 95 % factor of the normal distribution
_Z95 = 1.959963984540054


@dataclass(frozen=True)
class FormatOption:
    """An option of a format (``--option NAME=VALUE``): its default, what it means and the
    values it allows (``parse(text) -> value``, raising ValueError with the allowed values)."""

    name: str
    default: object
    doc: str
    parse: Callable[[str], object] = str


@dataclass(frozen=True)
class CompensationFormat:
    """A controller's format for corrections.

    Parameters
    ----------
    name : str
        The name ``mtplan compensate --format`` takes.
    title : str
        One line: the controller and the table or entry.
    source : str
        The public document whose layout, names, units and limits the writer follows.
    kinds : tuple of str
        The correction kinds it can hold (:attr:`CorrectionModel.kind`); ``("*",)`` for all.
    render : callable
        ``render(correction, options) -> {file name: text}``: the files, written together
        or not at all. Raises :class:`InvalidInput` where the correction exceeds the
        format's documented limits, naming them.
    options : tuple of FormatOption
    resolution : callable
        ``resolution(correction, options) -> array``: the step [display unit] in which each
        term's value is written (0: written to full precision).
    """

    name: str
    title: str
    source: str
    kinds: tuple
    render: Callable
    options: tuple = ()
    resolution: Callable = field(default=lambda correction, options:
                                 np.zeros(len(correction.names)))

    def holds(self, correction: Correction) -> bool:
        return "*" in self.kinds or correction.kind in self.kinds

    def parse_options(self, given: Mapping[str, str]) -> dict:
        """The format's options from ``NAME=VALUE`` texts, defaults for the rest; every
        problem at once."""
        known = {o.name: o for o in self.options}
        problems, out = [], {o.name: o.default for o in self.options}
        for key, text in given.items():
            if key not in known:
                allowed = ", ".join(known) or "none"
                problems.append(f"format {self.name!r} has no option {key!r} (its options: "
                                f"{allowed})")
                continue
            try:
                out[key] = known[key].parse(text)
            except ValueError as exc:
                problems.append(f"option {key!r} of format {self.name!r}: {exc}")
        if problems:
            raise InvalidInput(problems)
        return out

    def write_files(self, correction: Correction, options: Mapping) -> dict:
        """``{file name: text}`` of `correction`, refused where the format cannot hold it."""
        if not self.holds(correction):
            raise InvalidInput([f"format {self.name!r} holds {', '.join(self.kinds)} "
                                f"corrections; {correction.procedure}'s result is a "
                                f"{correction.kind} correction"])
        return self.render(correction, options)


@dataclass(frozen=True)
class Residual:
    """The error that remains of each corrected term once the written correction is
    applied, predicted from the result's state of knowledge: its 95 % interval ``low``,
    ``high`` [display unit], ``how`` it was formed per term, and ``shift`` (the rounding of
    the written value, known exactly)."""

    names: tuple
    units: tuple
    low: np.ndarray
    high: np.ndarray
    shift: np.ndarray
    how: tuple

    def rows(self) -> list[dict]:
        return [{"term": n, "unit": un, "residual_low": float(lo), "residual_high": float(hi),
                 "rounding": float(sh), "how": how}
                for n, un, lo, hi, sh, how in zip(self.names, self.units, self.low, self.high,
                                                 self.shift, self.how)]


def rounded(value: np.ndarray, step: np.ndarray) -> np.ndarray:
    """`value` rounded to `step` (unchanged where the step is 0)."""
    value, step = np.asarray(value, float), np.asarray(step, float)
    safe = np.where(step > 0, step, 1.0)
    return np.where(step > 0, np.round(value / safe) * safe, value)


def residual(correction: Correction, step=None) -> Residual:
    """The residual after compensation of each term, with its 95 % interval.

    The controller removes the written value ``w = round(estimate, step)``; what remains of
    the true error is ``true - w``. Where the result states the term's 95 % coverage
    interval (a term that scales one measurand: the Monte Carlo's own interval, whatever
    its shape), the residual's interval is that interval less ``w``; where a term combines
    measurands, it is normal with the term's covariance, ``estimate - w +- 1.96 u``. What the
    test cannot see (the correction model's ``unseen``) widens it, normal, by its variance
    less twice its covariance with the estimate's error where the model states its value
    (``Correction.residual_covariance``: the same field moved the readings). It does not
    include what the measurement cannot see (a repeatable error between the
    measured points, the temperature at which the machine is used): docs/compensation.md
    lists what each procedure's residual leaves out.
    """
    n = len(correction.names)
    step = np.zeros(n) if step is None else np.asarray(step, float)
    written = rounded(correction.value, step)
    shift = correction.value - written
    unseen = correction.unseen_u if correction.unseen_u.size else np.zeros(n)
    total = np.sqrt(np.clip(np.diag(correction.residual_covariance), 0.0, None))
    normal = np.stack([shift - _Z95 * total, shift + _Z95 * total], axis=1)
    stated = (np.isfinite(correction.interval).all(axis=1) if correction.interval.size
              else np.zeros(n, bool)) & (unseen == 0)
    bounds = np.where(stated[:, None], correction.interval - written[:, None], normal)
    how = tuple("the result's 95 % interval" if ok else
                "normal, 1.96 u with what the test cannot see" if us > 0 else "normal, 1.96 u"
                for ok, us in zip(stated, unseen))
    return Residual(correction.names, correction.units, bounds[:, 0], bounds[:, 1], shift, how)


def decimals(step_mm: float) -> int:
    """Decimal places that show a step [mm] exactly (0.001 -> 3)."""
    return max(0, -int(math.floor(math.log10(step_mm) + 1e-9)))
