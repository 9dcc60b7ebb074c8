"""The checks on a wheel spec's numbers: their ranges, and whether they make one wheel.

:func:`check_ranges` runs on every :class:`~rwlab.wheelspec.WheelSpec` built (kinds,
signs, faults above limits, a rated torque the current limit gives).
:func:`check_physics` runs on every spec *file* read (a preset, a lab's TOML): the
numbers must make a wheel that works — the motor reaches the speed limit against its
back-EMF on the bus, and the inner loop's acceleration limit lets the rated torque
reach the spacecraft. It is not run on a spec a record or ``model.json`` carries:
that is the wheel as it was configured then, kept as it was. Every failure is a
:class:`~rwlab.errors.ConfigError` naming the field and the number.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

from rwlab.errors import ConfigError
from rwlab.wheelspec.fields import (
    CONTROLLER_MODES,
    KINDS,
    RPM,
    SIGNED,
    TWIN_NAMES,
    ZERO_ALLOWED,
)

# a WheelSpec (not imported: the record imports its checks)
WheelSpec = Any

__all__ = ["check_physics", "check_ranges"]


def check_ranges(spec: WheelSpec) -> None:
    """The kinds, ranges and simple consistency of a spec's numbers.

    Parameters
    ----------
    spec : WheelSpec
        The spec.

    Raises
    ------
    ConfigError
        The first number out of range, named with its value.
    """
    for f in fields(spec):
        kind = KINDS.get(f.name)
        if kind is not None:
            _check_value(f.name, kind, getattr(spec, f.name))
    if spec.controller_mode not in CONTROLLER_MODES:
        raise ConfigError(
            f"controller_mode must be one of {CONTROLLER_MODES}, got {spec.controller_mode!r}"
        )
    pairs = (
        ("max_speed_rpm", "overspeed_fault_rpm", "the overspeed fault must be above the limit"),
        ("current_limit_a", "overcurrent_fault_a", "the overcurrent fault must be above the limit"),
        ("nominal_speed_rpm", "max_speed_rpm", "the nominal speed must not exceed the limit"),
    )
    for low, high, why in pairs:
        lo, hi = getattr(spec, low), getattr(spec, high)
        if lo > hi or (low != "nominal_speed_rpm" and lo == hi):
            raise ConfigError(f"{low} ({lo}) vs {high} ({hi}): {why}")
    if spec.max_torque_nm > spec.motor_torque_nm * (1 + 1e-9):
        raise ConfigError(
            f"max_torque_nm ({spec.max_torque_nm}) exceeds what the current limit gives, "
            f"torque_constant_nm_a × current_limit_a = {spec.motor_torque_nm:.4g} N·m"
        )
    if spec.stiction and spec.breakaway_friction_nm < spec.coulomb_friction_nm:
        raise ConfigError(
            f"breakaway_friction_nm ({spec.breakaway_friction_nm}) must be ≥ "
            f"coulomb_friction_nm ({spec.coulomb_friction_nm})"
        )
    if spec.driver_max_duty > 1 or spec.frame_loss_rate >= 1:
        raise ConfigError("driver_max_duty must be ≤ 1 and frame_loss_rate < 1")
    missing = sorted(set(KINDS) - set(spec.sources))
    if spec.sources and missing:
        raise ConfigError(f"no source for {missing}: every number says where it comes from")
    for name, tol in spec.tolerances.items():
        if name not in TWIN_NAMES or KINDS[name] is not float:
            raise ConfigError(f"tolerance for {name!r}: not a numeric field of the twin")
        if not (0 <= tol.relative < 1 and tol.absolute >= 0):
            raise ConfigError(f"tolerance for {name!r}: relative must be in [0, 1), absolute ≥ 0")


def _check_value(name: str, kind: type, value: object) -> None:
    """One field's kind and sign."""
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} must be true or false, got {value!r}")
        return
    if kind is str:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    if kind is int and not isinstance(value, int):
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    if name not in SIGNED and (value < 0 or (value == 0 and name not in ZERO_ALLOWED)):
        raise ConfigError(f"{name} must be > 0, got {value!r}")


def check_physics(spec: WheelSpec) -> None:
    """Whether the numbers make a wheel that reaches its speed and delivers its torque.

    - Speed: with back-EMF on, the drive's largest voltage (``driver_max_duty`` ×
      ``bus_voltage_v``) must exceed the back-EMF at the speed limit
      (``torque_constant_nm_a`` × ω_max, k_e = k_t in SI units) plus the winding's drop at
      the current that holds the friction there: else the motor cannot reach the limit.
    - Torque: the spacecraft receives the rotor's I·α, so the inner loop's acceleration
      limit × inertia must reach ``max_torque_nm``: else the rated torque is never
      delivered.

    Parameters
    ----------
    spec : WheelSpec
        The spec.

    Raises
    ------
    ConfigError
        Naming the field, its number and the number it had to reach.
    """
    if spec.back_emf:
        w = spec.max_speed_rad_s
        emf = spec.torque_constant_nm_a * w
        hold = (spec.coulomb_friction_nm + spec.viscous_friction_nm_s * w) / (
            spec.torque_constant_nm_a
        )
        need = emf + spec.winding_resistance_ohm * hold
        drive = spec.driver_max_duty * spec.bus_voltage_v
        if need >= drive:
            top = (drive - spec.winding_resistance_ohm * hold) / spec.torque_constant_nm_a / RPM
            raise ConfigError(
                f"max_speed_rpm ({spec.max_speed_rpm:g}) is out of the motor's reach: its "
                f"back-EMF there, torque_constant_nm_a {spec.torque_constant_nm_a:g} × "
                f"{w:.1f} rad/s = {emf:.2f} V, plus {spec.winding_resistance_ohm * hold:.2f} V "
                f"over the winding at the friction's current, needs {need:.2f} V, and "
                f"driver_max_duty × bus_voltage_v gives {drive:.2f} V (top speed "
                f"{max(top, 0.0):.0f} rpm); lower torque_constant_nm_a or max_speed_rpm, or "
                "raise bus_voltage_v"
            )
    if spec.accel_torque_nm < spec.max_torque_nm * (1 - 1e-9):
        raise ConfigError(
            f"max_torque_nm ({spec.max_torque_nm:g} N·m) cannot reach the spacecraft: "
            f"max_accel_rpm_s {spec.max_accel_rpm_s:g} × inertia_kg_m2 "
            f"{spec.inertia_kg_m2:g} gives {spec.accel_torque_nm:.4g} N·m; raise "
            f"max_accel_rpm_s to ≥ {spec.max_torque_nm / spec.inertia_kg_m2 / RPM:.4g} or "
            "lower max_torque_nm to it"
        )
