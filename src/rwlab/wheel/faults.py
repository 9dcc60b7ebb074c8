"""Faults a lab meets, injectable into the simulated wheel by name and time.

A fault is written ``NAME[=VALUE]@SECONDS`` (the CLI's ``--fault``), e.g.
``friction=3@900``: from 900 s after the experiment's first command on, the
bearing friction is three times the nominal. :class:`~rwlab.wheel.WheelNode`
applies it at that instant of its clock; it then stays (faults do not heal).

============================  =========  =============================================
name                          value      what changes
============================  =========  =============================================
``friction``                  factor     rotor friction (viscous and Coulomb) × factor
``torque_constant``           factor     the motor's true k_t × factor (a weak magnet; 0: dead)
``current_limit``             A          the driver clamps the current at this value
``speed_sensor_bias``         rpm        reported speed + bias
``speed_sensor_stuck``        —          reported speed frozen at its current value
``telemetry_dropout``         s          no telemetry frames for that long
============================  =========  =============================================

The wheel's own controller does not know about rotor or driver faults (it
keeps its nominal k_t and friction feed-forward), and its speed loop runs on
the true speed: the sensor faults touch only what the telemetry reports — a
fault of the reporting path (a firmware offset, a frozen telemetry register),
not of the sensor the loop closes on. That choice decides what diagnosis can
see: a bias inside the loop's own sensor is hidden by the loop (the wheel runs
at command − bias and reports the command), so no test on command, speed and
current alone separates it from a healthy wheel; it needs an independent speed
reference (the satellite's gyros, a bench tachometer). With the bias moved into the
loop (an independent check), 1 of 4 biases of 15–20 rpm was detected.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from rwlab.errors import ConfigError

__all__ = ["FAULTS", "ScheduledFault", "parse_fault"]

# name → the unit of its value (None: the fault takes no value)
FAULTS: dict[str, str | None] = {
    "friction": "factor",
    "torque_constant": "factor",
    "current_limit": "A",
    "speed_sensor_bias": "rpm",
    "speed_sensor_stuck": None,
    "telemetry_dropout": "s",
}
_SIGNED = {"speed_sensor_bias"}  # every other value must be > 0 ...
_EXAMPLE = {"friction": 1.5, "torque_constant": 0.8, "current_limit": 0.45}
_EXAMPLE |= {"speed_sensor_bias": 15, "telemetry_dropout": 0.3}  # for messages
_ZERO_OK = {"torque_constant"}  # ... or ≥ 0 for these: torque_constant=0 is a dead motor

_SYNTAX = re.compile(r"^\s*([a-z_]+)\s*(?:=\s*([^@]+?))?\s*@\s*(\S+)\s*$")


@dataclass(frozen=True)
class ScheduledFault:
    """One fault and when it starts.

    Attributes
    ----------
    name : str
        One of :data:`FAULTS`.
    value : float or None
        Factor, A, rpm or s as the name says; None for ``speed_sensor_stuck``.
    t_s : float
        Start, s after the experiment's first command.
    """

    name: str
    value: float | None
    t_s: float

    def __post_init__(self) -> None:
        if self.name not in FAULTS:
            raise ConfigError(f"unknown fault {self.name!r}; known: {', '.join(FAULTS)}")
        unit = FAULTS[self.name]
        if unit is None and self.value is not None:
            raise ConfigError(f"fault {self.name} takes no value (write {self.name}@SECONDS)")
        if unit is not None:
            if self.value is None or not math.isfinite(self.value):
                placeholder = {"factor": "FACTOR", "A": "AMPS", "rpm": "RPM", "s": "SECONDS"}[unit]
                raise ConfigError(
                    f"fault {self.name} needs a finite value in {unit}: write "
                    f"{self.name}={placeholder}@SECONDS (e.g. {self.name}="
                    f"{_EXAMPLE[self.name]}@{self.t_s:g})"
                )
            if self.name in _ZERO_OK and self.value < 0:
                raise ConfigError(f"fault {self.name} needs a value ≥ 0 {unit}, got {self.value}")
            if self.name not in _SIGNED | _ZERO_OK and self.value <= 0:
                raise ConfigError(f"fault {self.name} needs a value > 0 {unit}, got {self.value}")
        if not (math.isfinite(self.t_s) and self.t_s >= 0):
            raise ConfigError(f"fault {self.name}: the start must be ≥ 0 s, got {self.t_s}")

    def __str__(self) -> str:
        value = "" if self.value is None else f"={self.value:g}"
        return f"{self.name}{value}@{self.t_s:g}"


def parse_fault(text: str) -> ScheduledFault:
    """Read ``NAME[=VALUE]@SECONDS`` (e.g. ``friction=3@900``, ``speed_sensor_stuck@600``).

    Parameters
    ----------
    text : str
        The fault, ``NAME[=VALUE]@SECONDS``.

    Returns
    -------
    ScheduledFault

    Raises
    ------
    ConfigError
        Bad syntax, an unknown name, a missing or superfluous value, a negative time.
    """
    match = _SYNTAX.match(text) if isinstance(text, str) else None
    if match is None:
        raise ConfigError(
            f"fault {text!r} is not NAME[=VALUE]@SECONDS (e.g. friction=3@900); "
            f"names: {', '.join(FAULTS)}"
        )
    name, value, start = match.groups()
    try:
        number = None if value is None else float(value)
        t_s = float(start)
    except ValueError:
        raise ConfigError(f"fault {text!r}: value and time must be numbers") from None
    return ScheduledFault(name, number, t_s)
