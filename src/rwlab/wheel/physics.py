"""Reaction-wheel physics: BLDC motor, flywheel, friction, inner speed loop, Hall sensing.

The model (SI inside; rpm only in names that say so):

    I ω̇ = τ_m − b ω − τ_c sign(ω),      τ_m = k_t i,   |i| ≤ i_max

The wheel's own controller turns the command into a current:

- speed mode: a PI loop on speed gives an acceleration request, clipped to
  ±α_max (the RW90's makes a 0 → 6000 rpm step take ~20 s);
- acceleration mode: the acceleration request is the command, clipped the same;
- in both, the current is I·α_req/k_t plus friction feed-forward, clipped to
  ±i_max, and cut when it would push past the speed limit.

Speed is measured like a Hall-sensor wheel: quantised (``speed_resolution_rpm``)
with noise, reading 0 below the slowest speed that still produces Hall edges.
Faults latch (overspeed, overcurrent, overtemperature) and clear only on an
explicit clear-fault command; a latched fault idles the motor.

Why this module is long: the wheel is one set of coupled equations (motor, flywheel,
friction, speed loop, Hall sensing) integrated together; split, the state vector's
layout would be shared across files.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from rwlab.errors import ConfigError
from rwlab.wheel import kernel_layout as K
from rwlab.wheelspec import TWIN_NAMES, WheelSpec, preset_names

__all__ = [
    "IDEAL",
    "PRESETS",
    "RW90",
    "Fault",
    "Mode",
    "WheelParams",
    "WheelPhysics",
    "rad_s_to_rpm",
    "rpm_to_rad_s",
]

RPM = 2 * math.pi / 60  # rad/s per rpm
# the RW90's numbers live in its spec file (rwlab/wheelspec/presets/rw90.toml) and only
# there: WheelParams' defaults are read from it
_RW90_SPEC = WheelSpec.load("rw90")
_NOMINAL: dict[str, Any] = _RW90_SPEC.twin_fields()


def rpm_to_rad_s(rpm):
    """Convert rpm to rad/s.

    Parameters
    ----------
    rpm : float or array_like
        Angular rate, rpm.

    Returns
    -------
    float or numpy.ndarray
        The same rate, rad/s.
    """
    return rpm * RPM


def rad_s_to_rpm(rad_s):
    """Convert rad/s to rpm.

    Parameters
    ----------
    rad_s : float or array_like
        Angular rate, rad/s.

    Returns
    -------
    float or numpy.ndarray
        The same rate, rpm.
    """
    return rad_s / RPM


class Mode(enum.IntEnum):
    """Command modes, as on the wire."""

    IDLE = 0
    SPEED = 1
    ACCELERATION = 2
    CLEAR_FAULT = 3


class Fault(enum.IntFlag):
    """Latched fault bits, as on the wire."""

    NONE = 0
    OVERSPEED = 1
    OVERCURRENT = 2
    WATCHDOG = 4
    OVERTEMP = 8


@dataclass(frozen=True)
class WheelParams:
    """Reaction-wheel parameters: the twin's configuration of one wheel model.

    Build one from a wheel model's datasheet with :meth:`from_spec` (or
    :meth:`preset`); the defaults are the RW90's spec
    (``rwlab/wheelspec/presets/rw90.toml``, paper A's Table 1), read from that file.

    Attributes
    ----------
    inertia : float
        Rotor moment of inertia, kg·m².
    nominal_speed_rpm, max_speed_rpm : float
        Nominal and maximum speed, rpm (both directions).
    nominal_torque : float
        Nominal motor torque, N·m.
    max_accel_rpm_s : float
        Acceleration limit of the inner controller, rpm/s.
    current_limit : float
        Motor current limit, A (the paper mentions 700 mA).
    torque_constant : float
        Motor torque constant k_t, N·m/A.
    viscous_friction : float
        b, N·m·s/rad.
    coulomb_friction : float
        τ_c, N·m.
    speed_kp, speed_ki : float
        Inner PI speed loop: acceleration request per speed error (1/s, 1/s²).
    speed_setpoint_weight : float
        Weight β of the command in the proportional term, kp·(β·ω_cmd − ω) (default 1:
        a plain PI on the error; 0: an I-P loop, no proportional kick on a command
        step). Åström & Hägglund, *Advanced PID Control* (2006), §3.4.
    speed_resolution_rpm, speed_noise_rpm, min_measurable_rpm : float
        Reported speed: quantum (default 0.1), added white noise σ (default 0: the
        Hall model makes the noise) and the slowest speed read as non-zero (default 5),
        rpm.
    overspeed_fault_rpm : float
        Hard overspeed fault threshold, rpm.
    overcurrent_fault : float
        Hard overcurrent fault threshold, A.
    thermal_resistance, thermal_time_constant, overtemp_fault_c, ambient_c : float
        First-order motor thermal model (K/W, s) and its fault threshold (°C).
    winding_resistance : float
        Ω at ``ambient_c``, for copper losses, the back-EMF limit and the thermal model.

    The imperfections (issue 22). Each is on by default, at a typical value with
    its source; :data:`IDEAL` turns them off (the twin before issue 22: only the
    white speed noise and quantum). A unit seed (:meth:`for_unit`, ``unit`` in the
    TOML) draws the manufacturing-dependent ones within
    :data:`rwlab.wheel.imperfections.TOLERANCES`.

    stiction : bool
        Friction law: breakaway + Stribeck + Coulomb + viscous, stuck at zero speed
        until the motor torque exceeds the breakaway torque (Armstrong & Canudas de
        Wit 1995; Basilisk's reaction-wheel friction model). False: the plain
        Coulomb + viscous law, no stuck state.
    breakaway_friction : float
        τ_brk, N·m (default 3e-4: 1.5× Coulomb; ball bearings 1.2–2×).
    stribeck_speed_rpm : float
        Speed over which friction falls from breakaway to Coulomb, rpm (default 10).
    viscous_temp_coeff : float
        Fall of viscous friction per K above ``ambient_c``, 1/K (default 0.02: a
        bearing oil's viscosity halves over ~35 K).
    friction_drift : float
        σ of the friction factor's random walk per √hour (default 0.05: lubricant
        redistribution and run-in drift friction by a few % within a record).
    cogging_torque : float
        Amplitude of the detent torque, N·m, sinusoidal in rotor angle (default 1e-4:
        under 1 % of the rated torque, a slotted small BLDC).
    cogging_periods : int
        Cogging periods per revolution (default 24 = lcm(12 slots, 8 poles)).
    torque_ripple : float
        Commutation ripple, a fraction of the motor torque at 6 per electrical
        revolution (default 0.05; trapezoidal drives 5–15 %).
    pole_pairs : int
        Motor pole pairs p (default 4): 6p Hall edges and ripple periods per revolution.
    torque_constant_temp_coeff : float
        Fall of k_t per K above ambient, 1/K (default 0.0012: NdFeB magnets −0.12 %/K).
    resistance_temp_coeff : float
        Rise of the winding resistance per K, 1/K (default 0.0039: copper).
    back_emf : bool
        Limit the current by the voltage left after the back-EMF k_t·ω:
        |R·i + k_t·ω| ≤ duty·V_bus. False: an unlimited supply.
    bus_voltage : float
        Supply voltage, V (default 24; small-satellite buses 12–28 V, not given in
        paper A). Sags by ``bus_source_resistance`` × the supply current.
    bus_source_resistance : float
        Ω (default 0.3: harness and supply).
    driver_max_duty : float
        Largest PWM duty cycle (default 0.95: bootstrap and dead time).
    bus_voltage_noise_v : float
        σ of the bus-voltage measurement, V (default 0.05).
    current_noise_a : float
        σ of the motor-current measurement, A (default 0.004: shunt amplifier noise
        and aliased PWM ripple).
    current_lsb_a : float
        ADC quantum of the current measurement, A (default 0.002: 11 bits over ±2 A);
        0 for none.
    current_offset_a : float
        Offset of the current measurement, A (default 0; drawn ±5 mA per unit).
    hall_speed : bool
        Speed from Hall-edge timing (:class:`rwlab.wheel.imperfections.HallSpeedSensor`).
        False: true speed plus ``speed_noise_rpm``, quantised, 0 below ``min_measurable_rpm``.
    hall_misalignment_deg : float
        σ of each Hall edge's misplacement, electrical degrees (default 3: sensor
        placement ±0.2 mm and magnet pole-pitch errors); a fixed pattern per unit.
    hall_jitter_s : float
        σ of the edge-capture time, s (default 5e-7: input capture on an 8 MHz ARM).
    hall_timer_hz : float
        Capture timer clock, Hz (default 1e6).
    hall_window_s : float
        Averaging window of the firmware's speed estimate, s (default 0.1).
    hall_pattern_seed : int
        Seed of the Hall misplacement pattern and capture jitter (drawn per unit).
    telemetry_jitter_s : float
        Telemetry frames leave up to this late, uniformly, s (default 5e-4: the
        firmware's main loop and CAN arbitration); on the simulated clock too.
    frame_loss_rate : float
        Fraction of the wheel's frames lost (default 1e-4: adapter overruns and
        error frames beyond retransmission).
    model : str
        The wheel model's spec: a preset name (``"rw90"``) or a spec file; its
        tolerances draw a unit (:meth:`for_unit`).
    """

    inertia: float = _NOMINAL["inertia"]
    nominal_speed_rpm: float = _NOMINAL["nominal_speed_rpm"]
    max_speed_rpm: float = _NOMINAL["max_speed_rpm"]
    nominal_torque: float = _NOMINAL["nominal_torque"]
    max_accel_rpm_s: float = _NOMINAL["max_accel_rpm_s"]
    current_limit: float = _NOMINAL["current_limit"]
    torque_constant: float = _NOMINAL["torque_constant"]
    viscous_friction: float = _NOMINAL["viscous_friction"]
    coulomb_friction: float = _NOMINAL["coulomb_friction"]
    speed_kp: float = _NOMINAL["speed_kp"]
    speed_ki: float = _NOMINAL["speed_ki"]
    speed_setpoint_weight: float = _NOMINAL["speed_setpoint_weight"]
    speed_resolution_rpm: float = _NOMINAL["speed_resolution_rpm"]
    speed_noise_rpm: float = _NOMINAL["speed_noise_rpm"]
    min_measurable_rpm: float = _NOMINAL["min_measurable_rpm"]
    overspeed_fault_rpm: float = _NOMINAL["overspeed_fault_rpm"]
    overcurrent_fault: float = _NOMINAL["overcurrent_fault"]
    thermal_resistance: float = _NOMINAL["thermal_resistance"]
    thermal_time_constant: float = _NOMINAL["thermal_time_constant"]
    overtemp_fault_c: float = _NOMINAL["overtemp_fault_c"]
    ambient_c: float = _NOMINAL["ambient_c"]
    winding_resistance: float = _NOMINAL["winding_resistance"]
    # -- imperfections (issue 22): the defaults misbehave like a real wheel; IDEAL turns
    # each one off. Source and typical value of each in the class docstring.
    stiction: bool = _NOMINAL["stiction"]
    breakaway_friction: float = _NOMINAL["breakaway_friction"]
    stribeck_speed_rpm: float = _NOMINAL["stribeck_speed_rpm"]
    viscous_temp_coeff: float = _NOMINAL["viscous_temp_coeff"]
    friction_drift: float = _NOMINAL["friction_drift"]
    cogging_torque: float = _NOMINAL["cogging_torque"]
    cogging_periods: int = _NOMINAL["cogging_periods"]
    torque_ripple: float = _NOMINAL["torque_ripple"]
    pole_pairs: int = _NOMINAL["pole_pairs"]
    torque_constant_temp_coeff: float = _NOMINAL["torque_constant_temp_coeff"]
    resistance_temp_coeff: float = _NOMINAL["resistance_temp_coeff"]
    back_emf: bool = _NOMINAL["back_emf"]
    bus_voltage: float = _NOMINAL["bus_voltage"]
    bus_source_resistance: float = _NOMINAL["bus_source_resistance"]
    driver_max_duty: float = _NOMINAL["driver_max_duty"]
    bus_voltage_noise_v: float = _NOMINAL["bus_voltage_noise_v"]
    current_noise_a: float = _NOMINAL["current_noise_a"]
    current_lsb_a: float = _NOMINAL["current_lsb_a"]
    current_offset_a: float = _NOMINAL["current_offset_a"]
    hall_speed: bool = _NOMINAL["hall_speed"]
    hall_misalignment_deg: float = _NOMINAL["hall_misalignment_deg"]
    hall_jitter_s: float = _NOMINAL["hall_jitter_s"]
    hall_timer_hz: float = _NOMINAL["hall_timer_hz"]
    hall_window_s: float = _NOMINAL["hall_window_s"]
    hall_pattern_seed: int = 0
    telemetry_jitter_s: float = _NOMINAL["telemetry_jitter_s"]
    frame_loss_rate: float = _NOMINAL["frame_loss_rate"]
    model: str = _RW90_SPEC.name

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "model":
                _check_field(f.name, f.type, getattr(self, f.name))
        if not isinstance(self.model, str) or not self.model:
            raise ConfigError(f"wheel parameter model must name a wheel spec, got {self.model!r}")
        if self.max_speed_rpm >= self.overspeed_fault_rpm:
            raise ConfigError("overspeed_fault_rpm must be above max_speed_rpm")
        if self.current_limit >= self.overcurrent_fault:
            raise ConfigError("overcurrent_fault must be above current_limit")
        if self.stiction and self.breakaway_friction < self.coulomb_friction:
            raise ConfigError(
                f"breakaway_friction ({self.breakaway_friction}) must be ≥ coulomb_friction "
                f"({self.coulomb_friction}): a wheel needs more torque to start than to keep going"
            )
        for name, most in (("pole_pairs", 64), ("cogging_periods", 10_000)):
            if getattr(self, name) > most:
                raise ConfigError(f"{name} must be at most {most}, got {getattr(self, name)}")
        if not self.driver_max_duty <= 1:
            raise ConfigError(f"driver_max_duty must be in (0, 1], got {self.driver_max_duty}")
        if not self.frame_loss_rate < 1:
            raise ConfigError(f"frame_loss_rate must be in [0, 1), got {self.frame_loss_rate}")

    @property
    def max_speed(self) -> float:
        """Maximum speed, rad/s."""
        return rpm_to_rad_s(self.max_speed_rpm)

    @property
    def max_accel(self) -> float:
        """Acceleration limit, rad/s²."""
        return rpm_to_rad_s(self.max_accel_rpm_s)

    @property
    def max_torque(self) -> float:
        """Largest motor torque the current limit allows, N·m."""
        return self.torque_constant * self.current_limit

    @property
    def momentum_capacity(self) -> float:
        """Angular momentum at maximum speed, N·m·s."""
        return self.inertia * self.max_speed

    def for_unit(self, unit: int) -> WheelParams:
        """Another wheel of the same model: parameters drawn within their tolerances.

        Parameters
        ----------
        unit : int
            Unit seed ≥ 0 (the same seed, the same wheel).

        Returns
        -------
        WheelParams
            See :func:`rwlab.wheel.imperfections.draw_unit`; the tolerances are those
            of the wheel model's spec (``model``).
        """
        from rwlab.wheel.imperfections import draw_unit

        return draw_unit(self, unit, WheelSpec.load(self.model).twin_tolerances())

    def spec(self) -> WheelSpec:
        """The wheel model's spec with this wheel's numbers: the ``model``'s spec, each
        field that differs here changed (its source says from what).

        Returns
        -------
        WheelSpec
        """
        base = WheelSpec.load(self.model)
        changes = {
            name: getattr(self, twin)
            for name, twin in TWIN_NAMES.items()
            if getattr(self, twin) != getattr(base, name)
        }
        motor = self.torque_constant * self.current_limit
        if self.nominal_torque > motor:  # a driver set below the rated current: its torque
            changes["max_torque_nm"] = motor
        return base.with_(**changes) if changes else base

    @classmethod
    def from_spec(cls, spec: WheelSpec, *, unit: int | None = None) -> WheelParams:
        """The twin of a wheel model: every field from its datasheet.

        Parameters
        ----------
        spec : WheelSpec
            The wheel model (:meth:`rwlab.wheelspec.WheelSpec.load`).
        unit : int, optional
            Draw this unit within the spec's tolerances; None: the nominal wheel.

        Returns
        -------
        WheelParams
        """
        from rwlab.wheel.imperfections import draw_unit

        params = cls(**spec.twin_fields(), model=spec.origin or spec.name)
        return params if unit is None else draw_unit(params, unit, spec.twin_tolerances())

    @classmethod
    def preset(cls, name: str) -> WheelParams:
        """A named wheel model's twin: a spec preset (``'rw90'``, ``'nrwa-t6'``,
        ``'rw-0.01'``, :func:`rwlab.wheelspec.preset_names`) or ``'ideal'`` (the RW90
        without imperfections).

        Parameters
        ----------
        name : str

        Returns
        -------
        WheelParams
        """
        if isinstance(name, str) and name == "ideal":
            return IDEAL
        if not isinstance(name, str) or name not in preset_names():
            raise ConfigError(
                f"unknown wheel preset {name!r}; choose from {sorted(PRESET_NAMES)} "
                "or give a wheel spec file"
            )
        return cls.from_spec(WheelSpec.load(name))

    @classmethod
    def load(cls, name_or_path: str | Path, *, draw_unit: bool = True) -> WheelParams:
        """A wheel by preset name, a wheel spec file (``format = "rwlab.WheelSpec/1"``)
        or a wheel parameter file (:meth:`from_toml`).

        Parameters
        ----------
        name_or_path : str or Path
        draw_unit : bool
            For a parameter file with ``unit = N``: draw that unit.

        Returns
        -------
        WheelParams
        """
        text = str(name_or_path)
        if text == "ideal" or text in preset_names():
            return cls.preset(text)
        if is_spec_file(name_or_path):
            return cls.from_spec(WheelSpec.load(name_or_path))
        if text.lower().endswith(".toml"):
            return cls.from_toml(name_or_path, draw_unit=draw_unit)
        raise ConfigError(
            f"wheel must be a preset ({', '.join(sorted(PRESET_NAMES))}), a wheel spec "
            f"or a wheel TOML file (*.toml), got {text!r}"
        )

    @classmethod
    def from_toml(cls, path: str | Path, *, draw_unit: bool = True) -> WheelParams:
        """Load parameters from a TOML file (a ``[wheel]`` table or top-level keys).

        Unknown keys are an error; missing keys keep the values of ``preset``
        (a wheel model: ``'rw90'`` by default, ``'nrwa-t6'``, ``'rw-0.01'`` or ``'ideal'``;
        or a wheel spec file). ``unit = N`` then draws
        unit N around them (:meth:`for_unit`) unless ``draw_unit`` is False (the
        nominal wheel: the settings a lab configured, before unit tolerances).
        """
        from rwlab._toml import read_table, unknown_keys

        table = read_table(path, "wheel", "wheel parameter")
        preset = table.pop("preset", "rw90")
        unit = table.pop("unit", None)
        known = {f.name for f in fields(cls)}
        unknown = unknown_keys(table, known)
        if unknown:
            raise ConfigError(
                f"{path}: unknown wheel parameter(s) {unknown}; known: "
                f"{sorted(known | {'preset', 'unit'})}"
            )
        base = (
            cls.from_spec(WheelSpec.load(preset))
            if isinstance(preset, str) and is_spec_file(preset)
            else cls.preset(preset)
        )
        params = replace(base, **table)
        return params if unit is None or not draw_unit else params.for_unit(unit)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


_STRICTLY_POSITIVE = {
    "stribeck_speed_rpm",
    "pole_pairs",
    "cogging_periods",
    "bus_voltage",
    "driver_max_duty",
    "hall_timer_hz",
    "hall_window_s",
    "inertia",
    "max_speed_rpm",
    "max_accel_rpm_s",
    "current_limit",
    "torque_constant",
    "nominal_speed_rpm",
    "overspeed_fault_rpm",
    "overcurrent_fault",
    "thermal_time_constant",
}


def _check_field(name: str, kind, value) -> None:
    if kind in ("bool", bool):
        if not isinstance(value, bool):
            raise ConfigError(f"wheel parameter {name} must be true or false, got {value!r}")
        return
    if kind in ("int", int) and (isinstance(value, bool) or not isinstance(value, int)):
        raise ConfigError(f"wheel parameter {name} must be an integer, got {value!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"wheel parameter {name} must be a finite number, got {value!r}")
    if name == "current_offset_a":
        return  # a sensor offset has either sign
    if value < 0 or (value == 0 and name in _STRICTLY_POSITIVE):
        raise ConfigError(f"wheel parameter {name} must be > 0, got {value}")


RW90 = WheelParams.from_spec(_RW90_SPEC)
"""The RW90 wheel of paper A (Table 1), with a real wheel's imperfections (its spec)."""

IDEAL = replace(
    RW90,
    speed_resolution_rpm=0.5,
    speed_noise_rpm=0.5,
    min_measurable_rpm=2.0,
    stiction=False,
    breakaway_friction=RW90.coulomb_friction,
    viscous_temp_coeff=0.0,
    friction_drift=0.0,
    cogging_torque=0.0,
    torque_ripple=0.0,
    torque_constant_temp_coeff=0.0,
    resistance_temp_coeff=0.0,
    back_emf=False,
    bus_voltage_noise_v=0.0,
    current_noise_a=0.0,
    current_lsb_a=0.0,
    hall_speed=False,
    telemetry_jitter_s=0.0,
    frame_loss_rate=0.0,
)
"""The RW90 without imperfections (the twin before issue 22), for tests that need exact
truth: dynamics exactly ``I ω̇ = k_t i − b ω − τ_c sign ω``, current reported exactly,
speed with 0.5 rpm white noise and a 0.5 rpm quantum, no timing jitter or frame loss."""

PRESET_NAMES = (*preset_names(), "ideal")
"""The names :meth:`WheelParams.preset` knows: the wheel-spec presets and ``'ideal'``."""
PRESETS = {"rw90": RW90, "ideal": IDEAL}
"""The RW90 and its ideal twin, built at import (other models: :meth:`WheelParams.preset`)."""


def is_spec_file(path: str | Path) -> bool:
    """Whether ``path`` is a wheel spec (a TOML file with ``format = "rwlab.WheelSpec/…"``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    import tomllib

    p = Path(path)
    if not p.is_file() or p.suffix.lower() != ".toml":
        return False
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return str(raw.get("format", "")).startswith("rwlab.WheelSpec/")


def _clip(x: float, limit: float) -> float:
    return -limit if x < -limit else (limit if x > limit else x)


T = TypeVar("T")


class _Column(Generic[T]):
    """An attribute of :class:`WheelPhysics` kept in its state vector, the compiled
    step's layout (:mod:`rwlab.wheel.kernel`), read back as ``kind``."""

    def __init__(self, index: int, kind: Callable[[float], T]) -> None:
        self.index, self.kind = index, kind

    def __get__(self, wheel: WheelPhysics, owner: type | None = None) -> T:
        return self.kind(wheel._x[self.index])

    def __set__(self, wheel: WheelPhysics, value: T) -> None:
        wheel._x[self.index] = float(value)  # type: ignore[arg-type]


def _optional(value: float) -> float | None:
    return None if math.isnan(value) else value


def _float(value: float) -> float:
    return float(value)


class _OptionalColumn(_Column[float | None]):
    def __set__(self, wheel: WheelPhysics, value: float | None) -> None:
        wheel._x[self.index] = math.nan if value is None else float(value)


class WheelPhysics:
    """One wheel's state over time, stepped with a fixed time step.

    The steps run compiled (:mod:`rwlab.wheel.kernel`, the same numbers as the
    equations interpreted); the state lives in one vector, each part an attribute.

    Parameters
    ----------
    params : WheelParams
    seed : int or numpy.random.Generator
        For the measurement noise and the friction drift.
    """

    time = _Column(K.X_TIME, _float)  # s since start
    angle = _Column(K.X_ANGLE, _float)  # rotor angle, rad (unwrapped)
    bus_voltage = _Column(K.X_BUS_VOLTAGE, _float)  # at the driver, after the source's drop, V
    _drift = _Column(K.X_DRIFT, _float)  # log of the friction factor's random walk
    _drift_clock = _Column(K.X_DRIFT_CLOCK, _float)
    speed = _Column(K.X_SPEED, _float)  # rad/s
    current = _Column(K.X_CURRENT, _float)  # A
    temperature = _Column(K.X_TEMPERATURE, _float)  # °C
    mode = _Column(K.X_MODE, lambda v: Mode(int(v)))
    setpoint = _Column(K.X_SETPOINT, _float)  # rad/s (speed mode) or rad/s² (acceleration)
    faults = _Column(K.X_FAULTS, lambda v: Fault(int(v)))
    speed_limited = _Column(K.X_SPEED_LIMITED, bool)
    _integral = _Column(K.X_INTEGRAL, _float)
    # fault injection: a stalled/shorted driver's current, A
    forced_current = _OptionalColumn(K.X_FORCED_CURRENT, _optional)
    # Degradations of the rotor and driver (fault injection). The wheel's own
    # controller does not know them: it keeps computing with ``params``.
    friction_factor = _Column(K.X_FRICTION_FACTOR, _float)  # bearing wear: true = this × nominal
    torque_constant_factor = _Column(K.X_TORQUE_CONSTANT_FACTOR, _float)  # a weakened motor
    current_limit = _Column(K.X_CURRENT_LIMIT, _float)  # the driver's current clamp, A

    def __init__(self, params: WheelParams = RW90, seed=0) -> None:
        from rwlab.wheel.imperfections import HallSpeedSensor

        self.params = params
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        # a stream of its own, so that the ideal twin's speed noise is what it was
        self._imp_rng = self.rng.spawn(1)[0]
        self._x = np.zeros(K.N_STATE)
        self._p = K.params_vector(params)
        self.bus_voltage = params.bus_voltage
        self.temperature = params.ambient_c
        self.forced_current = None
        self.friction_factor = 1.0
        self.torque_constant_factor = 1.0
        self.current_limit = params.current_limit
        self.hall = HallSpeedSensor(params) if params.hall_speed else None
        # the compiled step's Hall arrays (unused placeholders without a Hall sensor)
        self._hall_arrays = (
            (self.hall.state, self.hall.edges, self.hall.offsets, self.hall.jitter)
            if self.hall is not None
            else (np.zeros(K.N_HALL), np.zeros(1), np.zeros(1), np.zeros(1))
        )

    # -- commands ----------------------------------------------------------------
    def command(self, mode: Mode, setpoint_rpm: float) -> None:
        """Apply a command; setpoint in rpm (speed mode) or rpm/s (acceleration mode)."""
        mode = Mode(mode)
        if mode == Mode.CLEAR_FAULT:
            self.faults = Fault.NONE
            self.forced_current = None
            self.mode, self.setpoint = Mode.IDLE, 0.0
            return
        if self.faults and mode != Mode.IDLE:
            return  # a latched fault keeps the wheel idle until cleared
        if mode != self.mode:
            self._integral = 0.0
        self.mode = mode
        self.setpoint = rpm_to_rad_s(setpoint_rpm) if mode != Mode.IDLE else 0.0

    def latch(self, fault: Fault) -> None:
        """Latch a fault and idle the motor."""
        self.faults |= fault
        self.mode, self.setpoint, self._integral = Mode.IDLE, 0.0, 0.0

    # -- dynamics ----------------------------------------------------------------
    def feedback_speed(self) -> float:
        """The speed the wheel's own controller sees, rad/s.

        With ``hall_speed`` the firmware's Hall estimate (it has no other speed
        sensor: coarse and late at low speed, 0 near standstill); else the true speed.
        """
        return self.hall.read() if self.hall is not None else self.speed

    def _accel_request(self, dt: float, speed: float) -> float:
        """The inner loop's acceleration request at the sensed ``speed`` (rad/s), rad/s²;
        integrates the speed loop over ``dt`` s."""
        from rwlab.wheel.kernel import accel_request

        return float(accel_request(self._x, self._p, float(dt), float(speed)))

    def friction_torque(self, speed: float) -> float:
        """Nominal friction torque opposing the rotation, N·m (the controller's feed-forward)."""
        p = self.params
        return p.viscous_friction * speed + p.coulomb_friction * math.copysign(1.0, speed) * (
            abs(speed) > 1e-9
        )

    def bearing_friction(self, speed: float) -> float:
        """The true friction torque while sliding at ``speed`` (rad/s), N·m.

        Stribeck law (:func:`rwlab.wheel.imperfections.stribeck_friction`) with
        stiction on, else Coulomb + viscous; the viscous part falls with
        temperature; both scaled by the drift and any injected wear.
        """
        from rwlab.wheel.kernel import bearing_friction

        return float(bearing_friction(self._x, self._p, float(speed)))

    def _torque_constant(self) -> float:
        """The true k_t now (injected weakening, magnet temperature), N·m/A."""
        p = self.params
        warm = 1 - p.torque_constant_temp_coeff * (self.temperature - p.ambient_c)
        return self.torque_constant_factor * p.torque_constant * warm

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds (use ≤ 1 ms for the inner loop's accuracy)."""
        self.run(dt, 1)

    def run(self, dt: float, steps: int) -> None:
        """Advance by ``steps`` steps of ``dt`` seconds each, compiled.

        Parameters
        ----------
        dt : float
            Step, s (≤ 1 ms for the inner loop's accuracy).
        steps : int
            Number of steps (0: nothing).
        """
        from rwlab.wheel.kernel import advance

        p = self.params
        state, edges, offsets, jitter = self._hall_arrays
        while steps > 0:
            steps -= advance(self._x, self._p, state, edges, offsets, jitter, float(dt), int(steps))
            while self._drift_clock >= 1.0:  # a random walk in 1 s steps
                self._drift_clock -= 1.0
                self._drift += p.friction_drift / 60 * self._imp_rng.standard_normal()

    # -- measurement -----------------------------------------------------------------
    def measured_speed_rpm(self) -> float:
        """Speed as the wheel reports it, rpm.

        From Hall-edge timing when ``hall_speed`` (coarse at low speed, 0 below
        ``min_measurable_rpm``), else the true speed; then ``speed_noise_rpm`` white
        noise and the ``speed_resolution_rpm`` quantum.
        """
        p = self.params
        rpm = rad_s_to_rpm(self.hall.read() if self.hall is not None else self.speed)
        if abs(rpm) < p.min_measurable_rpm:
            return 0.0
        if p.speed_noise_rpm:
            rpm += p.speed_noise_rpm * self.rng.standard_normal()
        return round(rpm / p.speed_resolution_rpm) * p.speed_resolution_rpm

    def measured_current(self) -> float:
        """Motor current as the wheel reports it (offset, noise, ADC quantum), A."""
        p = self.params
        value = self.current + p.current_offset_a
        if p.current_noise_a:
            value += p.current_noise_a * self._imp_rng.standard_normal()
        return round(value / p.current_lsb_a) * p.current_lsb_a if p.current_lsb_a else value

    def measured_bus_voltage(self) -> float:
        """Bus voltage at the driver as the wheel reports it, V."""
        p = self.params
        if not p.bus_voltage_noise_v:
            return self.bus_voltage
        return self.bus_voltage + p.bus_voltage_noise_v * self._imp_rng.standard_normal()

    @property
    def momentum(self) -> float:
        """Wheel angular momentum I·ω, N·m·s."""
        return self.params.inertia * self.speed

    @property
    def motor_torque(self) -> float:
        """Motor torque on the rotor, N·m (the satellite feels its negative; ripple left out)."""
        return self._torque_constant() * self.current


def simulate_speed_command(
    command_rpm: np.ndarray,
    Ts: float,
    params: WheelParams = RW90,
    *,
    mode: Mode = Mode.SPEED,
    dt: float = 2e-3,
    seed=0,
) -> np.ndarray:
    """Play a command sampled at ``Ts`` into the wheel (no bus) and sample measured speed, rpm.

    The command is held over each interval (ZOH); the speed is measured at the
    end of each interval, so ``speed[k]`` responds to ``command[k]`` one sample
    later — the delay nk = 1 that the identification finds.
    """
    wheel = WheelPhysics(params, seed)
    substeps = max(1, round(Ts / dt))
    h = Ts / substeps
    out = np.empty(len(command_rpm))
    for k, c in enumerate(np.asarray(command_rpm, dtype=float)):
        out[k] = wheel.measured_speed_rpm()
        wheel.command(mode, c)
        wheel.run(h, substeps)
    return out
