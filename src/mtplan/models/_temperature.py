"""Temperatures measured or assumed, for the procedures whose readings depend on them.

ISO 1 states lengths at 20 degC. A procedure declares, per temperature ``NAME``, three
set-up fields: the measured value ``NAME_c`` [degC] (None: not measured), its thermometer's
standard uncertainty ``NAME_u_k`` and the half-width ``NAME_halfwidth_k`` assumed when
nothing was measured. Measured, the estimators correct the result to 20 degC with it and the
thermometer's error is a normal source ``NAME_u``; assumed, the temperature is 20 degC
within a rectangular half-width (source ``NAME_halfwidth``), nothing is corrected, and the
set-up's notes say so. Either source is the actual value minus the reference the estimators
correct with (:func:`deviation`), so it is zero-mean and zero errors give the truth.

A vertical gradient of the air's temperature ``NAME_k_per_m`` (None: not measured) bends
optical beams; measured, its error ``NAME_u`` (``NAME_u_k_per_m``) is normal; assumed, it is
uniform between 0 and ``NAME_range_k_per_m`` (``NAME_range``): warm air lies above, so its
mean is signed, a bias of the uncorrected estimates.

A horizontal gradient ``NAME_x_k_per_m``, ``NAME_y_k_per_m`` (its components along the
instrument's x and y axes; None: not measured) swerves the beams sideways by the same law;
measured, each component's error is normal (``NAME_x_u``, ``NAME_y_u`` from
``NAME_horizontal_u_k_per_m``); assumed, each component is uniform within
+-``NAME_horizontal_range_k_per_m`` (``NAME_x_range``, ``NAME_y_range``): nothing says on which
side the warm air lies, so its mean is zero.
"""

from __future__ import annotations

import numpy as np

from mtplan.models.protocol import Source
from mtplan.uncertainty import Normal, Rectangular

__all__ = ["DN_DT", "deviation", "temperature_sources", "assumed_note", "gradient",
           "gradient_sources", "bending", "unbend",
           "horizontal_gradient", "horizontal_gradient_sources", "swerve", "unswerve"]

#: change of the air's refractive index per kelvin (Edlen) [1/K]
DN_DT = 0.93e-6


def deviation(setup, name: str, default: float = 0.0) -> float:
    """The measured ``NAME_c`` minus 20 degC [K], or `default` where it was not measured."""
    measured = getattr(setup, f"{name}_c")
    return default if measured is None else measured - 20.0


def temperature_sources(setup, name: str, *, measured: str, assumed: str) -> dict:
    """The sources ``NAME_u`` (active where measured) and ``NAME_halfwidth`` (where not), in
    K, with their descriptions `measured` and `assumed`."""
    is_measured = getattr(setup, f"{name}_c") is not None
    u = getattr(setup, f"{name}_u_k") if is_measured else 0.0
    hw = 0.0 if is_measured else getattr(setup, f"{name}_halfwidth_k")
    return {f"{name}_u": Source(Normal(0.0, u), (), measured, field=f"{name}_u_k"),
            f"{name}_halfwidth": Source(Rectangular(-hw, hw), (), assumed,
                                        field=f"{name}_halfwidth_k")}


def assumed_note(setup, name: str, what: str, about: str = "20 degC") -> list[str]:
    """The note that ``NAME`` was assumed, not measured (empty where it was measured)."""
    if getattr(setup, f"{name}_c") is not None:
        return []
    return [f"temperature: {what} was assumed ({about} +- "
            f"{getattr(setup, f'{name}_halfwidth_k'):g} K, rectangular), not measured "
            f"(state {name}_c)"]


def gradient(setup, name: str) -> float:
    """The measured gradient ``NAME_k_per_m`` [K/m], 0 where it was not measured."""
    measured = getattr(setup, f"{name}_k_per_m")
    return 0.0 if measured is None else float(measured)


def gradient_sources(setup, name: str, *, measured: str, assumed: str) -> dict:
    """The sources ``NAME_u`` (normal, where measured) and ``NAME_range`` (uniform from 0 to
    the range, where not), in K/m."""
    is_measured = getattr(setup, f"{name}_k_per_m") is not None
    u = getattr(setup, f"{name}_u_k_per_m") if is_measured else 0.0
    top = 0.0 if is_measured else getattr(setup, f"{name}_range_k_per_m")
    return {f"{name}_u": Source(Normal(0.0, u), (), measured, field=f"{name}_u_k_per_m"),
            f"{name}_range": Source(Rectangular(0.0, top), (), assumed,
                                    field=f"{name}_range_k_per_m")}


def bending(grad, horiz):
    """Elevation error [rad] of a beam bent by the vertical gradient `grad` [K/m] over the
    horizontal distance `horiz` [mm]: the target seen raised by 0.93e-6 G D^2 / 2."""
    return (DN_DT * 1e-3 / 2) * grad * horiz


def unbend(elevation, distance, grad):
    """The elevation [rad] a beam bent by `grad` [K/m] would have without bending: the fixed
    point of ``read = el + bending(grad, distance cos el)`` (two steps: 1e-15 rad)."""
    read = np.asarray(elevation, dtype=float)
    el = read
    for _ in range(2):
        el = read - bending(grad, distance * np.cos(el))
    return el


def horizontal_gradient(setup, name: str) -> tuple[float, float]:
    """The measured horizontal gradient ``(NAME_x_k_per_m, NAME_y_k_per_m)`` [K/m] along the
    instrument's x and y axes, (0, 0) where it was not measured."""
    gx, gy = (getattr(setup, f"{name}_{ax}_k_per_m") for ax in "xy")
    return (0.0, 0.0) if gx is None else (float(gx), float(gy))


def horizontal_gradient_sources(setup, name: str, *, measured: str, assumed: str) -> dict:
    """The sources ``NAME_x_u``, ``NAME_y_u`` (normal, where measured) and ``NAME_x_range``,
    ``NAME_y_range`` (uniform within +-the range, where not), in K/m."""
    is_measured = getattr(setup, f"{name}_x_k_per_m") is not None
    u = getattr(setup, f"{name}_horizontal_u_k_per_m") if is_measured else 0.0
    top = 0.0 if is_measured else getattr(setup, f"{name}_horizontal_range_k_per_m")
    out = {}
    for ax in "xy":
        out[f"{name}_{ax}_u"] = Source(Normal(0.0, u), (), measured.replace("{axis}", ax),
                                       field=f"{name}_horizontal_u_k_per_m")
        out[f"{name}_{ax}_range"] = Source(Rectangular(-top, top), (),
                                           assumed.replace("{axis}", ax),
                                           field=f"{name}_horizontal_range_k_per_m")
    return out


def swerve(gx, gy, azimuth, distance, horiz):
    """Azimuth error [rad] of a beam of length `distance` [mm] at `azimuth` [rad] (horizontal
    length `horiz` [mm]) swerved by the horizontal gradient (`gx`, `gy`) [K/m]: the target is
    seen moved towards the warm side by 0.93e-6 G D^2 / 2, G the gradient's component across
    the beam, as :func:`bending` raises it for a vertical gradient."""
    across = -np.asarray(gx) * np.sin(azimuth) + np.asarray(gy) * np.cos(azimuth)
    return (DN_DT * 1e-3 / 2) * across * distance**2 / horiz


def unswerve(azimuth, distance, horiz, gx, gy):
    """The azimuth [rad] a beam swerved by (`gx`, `gy`) [K/m] would have without swerving: the
    fixed point of ``read = az + swerve(gx, gy, az, distance, horiz)`` (two steps)."""
    read = np.asarray(azimuth, dtype=float)
    az = read
    for _ in range(3):
        az = read - swerve(gx, gy, az, distance, horiz)
    return az
