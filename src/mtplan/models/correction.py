"""The correction model a procedure states: what is corrected, in which frame, with which sign.

Part of the procedure contract (:class:`~mtplan.models.protocol.Procedure`'s ``correction``):
each corrected quantity is a linear function of the procedure's measurands, so the
correction's covariance follows exactly from the result's (:mod:`mtplan.compensation`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

__all__ = ["CorrectionTerm", "CorrectionModel", "NO_CORRECTION"]


@dataclass(frozen=True)
class CorrectionTerm:
    """One corrected quantity: ``value = sum(weight * measurand)`` in `unit`.

    Parameters
    ----------
    name : str
        The quantity's name in the neutral table: the ISO 230-1 / ISO 230-7 name where one
        exists (``EX0C``), otherwise a plain one (``work_offset_x``).
    weights : mapping of str to float
        Measurand name -> weight [term unit per measurand unit].
    unit : str
        Display unit of the value and its U (um or urad).
    description : str
        What the controller entry is, in plain words.
    argument : tuple
        ``(axis, position [mm])`` for a value of an error that is a function of position
        (a compensation table's point); ``()`` for a constant.
    extrapolated : bool
        The position lies outside the measured travel.
    """

    name: str
    weights: Mapping[str, float]
    unit: str
    description: str
    argument: tuple = ()
    extrapolated: bool = False


def _no_terms(setup: Mapping, names: tuple) -> tuple:
    return ()


def _no_nominal(setup: Mapping) -> dict:
    return {}


def _nothing_unseen(setup: Mapping) -> dict:
    return {}


def _restates_none(setup: Mapping) -> dict:
    return {}


def _no_grid(setup) -> dict:
    return {}


def _nothing_realised(setup, errors: Mapping) -> dict:
    return {}


@dataclass(frozen=True)
class CorrectionModel:
    """How a procedure's result becomes a correction a controller takes.

    Parameters
    ----------
    kind : str
        What is corrected: ``kinematic location`` (a rotary axis's place in the kinematic
        model), ``work offset``, ``frame``, ``sensor rotation``; "" when the procedure
        states no correction.
    frame : str
        The frame the values are expressed in, in words.
    sign : str
        The sign convention: what a positive value means and what the controller does
        with it, in words.
    terms : callable
        ``terms(setup, names) -> tuple of CorrectionTerm``: the corrected quantities at the
        result's set-up (a dict of its fields as the result document holds them), given
        the names of the measurands the result holds (a function the test does not
        determine is not corrected).
    nominal : callable
        ``nominal(setup) -> {term: value}``: the nominal value [internal unit: mm, rad] a
        term is the deviation from, where a controller's entry is absolute (a frame's
        nominal origin); terms it leaves out are deviations from zero.
    unseen : callable
        ``unseen(setup) -> {measurand or function: (u, what)}``: the standard uncertainty
        [the measurand's display unit] of what stays after a correction of that measurand
        although the test cannot see it (a machine's repeatable short-wave deviation
        between a table's points), and what it is in words; a function's name (``EXX``)
        stands for all its measurands (``EXX``, ``EXX@-50``, ...). Part of the residual
        predicted after compensation, and of a plan's residual target.
    restates : callable
        ``restates(setup) -> {measurand: measurand}``: a measurand that is the same quantity
        as another one a term corrects (geometry21's EXX, the function at the travel's end,
        is ``EXX@50`` of the table), so that the documents give its residual after
        compensation; {} where none is.
    realised : callable
        ``realised(setup, errors) -> {measurand: value}``: the value [display unit] that
        what ``unseen`` names takes on a simulated machine, for the source errors
        (``Procedure.draw_errors``) its test was simulated with, at the procedure's
        ``Setup``; with the measurand's true value, the error the machine really has
        there (what a closed loop of the compensation compares the written value with).
        Measurands it leaves out have nothing unseen.
    grid : callable
        ``grid(setup) -> {setup field: positions [mm]}``: where a table of this correction
        is stated when the user names no positions (a study's ``[procedure.readings]
        along``): the errors that are functions of position along the travel (``EXX@-50``)
        at those positions, for the table and the report's figures along the travel; {}
        where the correction holds no function of position, or the set-up states its own.
    """

    kind: str = ""
    frame: str = ""
    sign: str = ""
    terms: Callable[[Mapping, tuple], tuple] = _no_terms
    nominal: Callable[[Mapping], dict] = _no_nominal
    unseen: Callable[[Mapping], dict] = _nothing_unseen
    restates: Callable[[Mapping], dict] = _restates_none
    realised: Callable[[object, Mapping], dict] = _nothing_realised
    grid: Callable[[object], dict] = _no_grid

    def unseen_of(self, setup: Mapping, measurand: str) -> tuple[float, str]:
        """(u, what) that stays unseen after correcting `measurand` ((0, "") for none)."""
        table = self.unseen(setup)
        return table.get(measurand, table.get(measurand.split("@")[0], (0.0, "")))


#: the model of a procedure that states no correction (``mtplan compensate`` refuses it)
NO_CORRECTION = CorrectionModel()
