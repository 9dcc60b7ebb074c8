"""What makes the twin misbehave like a real wheel: friction laws, Hall-sensor speed, unit spread.

Each imperfection is a named field of :class:`rwlab.wheel.WheelParams` (and so of
the wheel TOML); this module holds the pieces that are more than one line:

- :func:`stribeck_friction` — Coulomb + viscous + Stribeck friction, the sliding
  law of Armstrong & Canudas de Wit (*Friction Modeling and Compensation*, The
  Control Handbook, 1995), the form Basilisk's reaction-wheel state effector and
  Simscape's Rotational Friction use; the stuck state at zero speed (breakaway)
  is handled by :class:`rwlab.wheel.WheelPhysics`;
- :class:`HallSpeedSensor` — the speed a BLDC wheel's firmware computes from the
  times of its Hall-sensor edges (hand-written: no library models a sensor's
  edge timing);
- :data:`TOLERANCES` and :func:`draw_unit` — unit-to-unit variation: a unit seed
  draws every manufacturing-dependent parameter within datasheet-like tolerances.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import Field, replace
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np

from rwlab.errors import ConfigError
from rwlab.wheelspec import Tolerance, WheelSpec


class UnitParams(Protocol):
    """What :func:`draw_unit` needs of a wheel's parameters: a frozen dataclass (the
    toleranced fields are read by name) with the friction levels it keeps ordered.
    :class:`rwlab.wheel.WheelParams` is one; typed by shape so that this module does not
    depend on the module that calls it."""

    __dataclass_fields__: ClassVar[dict[str, Field[Any]]]

    @property
    def coulomb_friction(self) -> float: ...

    @property
    def breakaway_friction(self) -> float: ...


class HallParams(Protocol):
    """The sensor fields :class:`HallSpeedSensor` reads (:class:`rwlab.wheel.WheelParams`
    has them)."""

    @property
    def pole_pairs(self) -> int: ...

    @property
    def hall_misalignment_deg(self) -> float: ...

    @property
    def hall_jitter_s(self) -> float: ...

    @property
    def hall_timer_hz(self) -> float: ...

    @property
    def hall_window_s(self) -> float: ...

    @property
    def hall_pattern_seed(self) -> int: ...

    @property
    def min_measurable_rpm(self) -> float: ...


P = TypeVar("P", bound=UnitParams)

__all__ = ["TOLERANCES", "HallSpeedSensor", "Tolerance", "draw_unit", "stribeck_friction"]


def stribeck_friction(
    speed: float, coulomb: float, breakaway: float, stribeck_speed: float, viscous: float
) -> float:
    """Sliding friction torque opposing ``speed``, N·m.

    ``sign(ω)·(τ_c + (τ_brk − τ_c)·exp(−(ω/ω_s)²)) + b·ω``: the breakaway torque
    at the first motion, falling to Coulomb over a few ``ω_s`` (the Stribeck
    effect), plus viscous drag.

    Parameters
    ----------
    speed : float
        Rotor speed ω, rad/s (0 gives 0: the stuck state is the caller's).
    coulomb, breakaway : float
        τ_c and τ_brk ≥ τ_c, N·m.
    stribeck_speed : float
        ω_s, rad/s (> 0).
    viscous : float
        b, N·m·s/rad.

    Returns
    -------
    float
        Friction torque, N·m, with the sign of ``speed``.
    """
    if speed == 0.0:
        return 0.0
    drop = (breakaway - coulomb) * math.exp(-((speed / stribeck_speed) ** 2))
    return math.copysign(coulomb + drop, speed) + viscous * speed


TOLERANCES: dict[str, Tolerance] = WheelSpec.load("rw90").twin_tolerances()
"""The RW90's unit-to-unit tolerances (uniform within ±), from its spec file; each wheel
model's are in its spec (``[tolerances]``). Parameters not listed are the same on
every unit: the firmware's (loop gains, limits, fault thresholds), the supply's
and the sensor electronics'. The Hall sensors' placement pattern is drawn per unit
too (``hall_pattern_seed``)."""


def draw_unit(params: P, unit: int, tolerances: Mapping[str, Tolerance] | None = None) -> P:
    """Another wheel of the same model: every toleranced parameter drawn around ``params``.

    Parameters
    ----------
    params : WheelParams
        The nominal wheel.
    unit : int
        Unit seed ≥ 0; the same seed always gives the same wheel.
    tolerances : mapping of str to Tolerance, optional
        The wheel model's tolerances by twin field name
        (:meth:`rwlab.wheelspec.WheelSpec.twin_tolerances`); default the RW90's.

    Returns
    -------
    WheelParams
        The unit's parameters (``params`` itself is not changed).
    """
    if isinstance(unit, bool) or not isinstance(unit, int) or unit < 0:
        raise ConfigError(f"wheel unit must be an integer ≥ 0, got {unit!r}")
    rng = np.random.default_rng([unit, 0x52573930])  # "RW90": a stream of its own
    drawn: dict = {}  # field name → value; mixed types, checked by WheelParams
    for name, tol in (TOLERANCES if tolerances is None else tolerances).items():
        nominal = getattr(params, name)
        u = rng.uniform(-1.0, 1.0)
        drawn[name] = nominal * (1 + tol.relative * u) + tol.absolute * u
    if "breakaway_friction" in drawn or "coulomb_friction" in drawn:
        coulomb = drawn.get("coulomb_friction", params.coulomb_friction)
        drawn["breakaway_friction"] = max(
            drawn.get("breakaway_friction", params.breakaway_friction), coulomb
        )
    drawn["hall_pattern_seed"] = int(rng.integers(0, 2**31))
    return replace(params, **drawn)


class HallSpeedSensor:
    """Speed from the times of Hall-sensor edges, as a BLDC wheel's firmware computes it.

    Three Hall sensors give ``6·p`` edges per revolution (``p`` pole pairs), each
    misplaced by a fixed angle of its own (``hall_misalignment_deg``, electrical,
    drawn once per unit). The firmware captures each edge's time with a timer of
    ``hall_timer_hz`` (plus a capture jitter ``hall_jitter_s``) and, at each edge,
    computes ``n·Δθ / (t_last − t_first)`` over the last ``n`` edges: a whole
    revolution when one fits in ``hall_window_s`` (the placement errors cancel:
    fine at high speed), else the edges within the window, at least one interval
    (the placement error of one interval shows: coarse at low speed). When the
    next edge is overdue by half an interval the estimate becomes ``Δθ / (time
    since the last edge)``, so a stopping wheel reads a falling speed; no edge
    for longer than one edge interval at ``min_measurable_rpm`` reads 0. A
    reversal restarts the estimate.

    Parameters
    ----------
    params : WheelParams
        Sensor fields: ``pole_pairs``, ``hall_misalignment_deg``, ``hall_jitter_s``,
        ``hall_timer_hz``, ``hall_window_s``, ``hall_pattern_seed``,
        ``min_measurable_rpm``.
    """

    def __init__(self, params: HallParams) -> None:
        from rwlab.wheel import kernel_layout as K

        self.edges_per_rev = 6 * int(params.pole_pairs)
        self.pitch = 2 * math.pi / self.edges_per_rev  # rad between nominal edges
        rng = np.random.default_rng([int(params.hall_pattern_seed), 0x48414C4C])
        misplace = math.radians(params.hall_misalignment_deg) / params.pole_pairs  # mechanical
        offsets = misplace * rng.standard_normal(self.edges_per_rev)
        self.offsets = offsets - offsets.mean()  # a pattern around nominal edges, rad
        self.jitter = params.hall_jitter_s * rng.standard_normal(4096)  # per edge, s
        self.tick = 1.0 / params.hall_timer_hz
        self.window = params.hall_window_s
        min_speed = params.min_measurable_rpm * 2 * math.pi / 60
        self.timeout = self.pitch / min_speed if min_speed > 0 else math.inf
        # the firmware's state, in the compiled step's layout (rwlab.wheel.kernel.H_*):
        # the last edges' captured times (a ring of a revolution and one), the direction,
        # the last edge at or below the rotor angle, the last record's time and angle,
        # the estimate at the last edge (rad/s) and that edge's time
        self.edges = np.zeros(self.edges_per_rev + 1)
        self.state = np.zeros(K.N_HALL)
        self.state[K.H_LAST_EDGE] = -math.inf
        self.state[K.H_EDGES_PER_REV] = self.edges_per_rev
        self.state[K.H_PITCH] = self.pitch
        self.state[K.H_TICK] = self.tick
        self.state[K.H_WINDOW] = self.window
        self.state[K.H_TIMEOUT] = self.timeout

    def record(self, t: float, theta: float) -> None:
        """Log the rotor angle ``theta`` (rad, unwrapped) at time ``t`` (s), every step."""
        from rwlab.wheel.kernel import hall_record

        hall_record(self.state, self.edges, self.offsets, self.jitter, float(t), float(theta))

    def read(self) -> float:
        """The firmware's speed now, rad/s (0 when no edge came within the timeout)."""
        from rwlab.wheel.kernel import hall_read

        return float(hall_read(self.state))
