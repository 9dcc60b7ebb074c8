"""Reaction-wheel physics: BLDC motor, flywheel, friction, inner speed loop, Hall sensing.

The model (SI inside; rpm only in names that say so):

    I ω̇ = τ_m − b ω − τ_c sign(ω),      τ_m = k_t i,   |i| ≤ i_max

The wheel's own controller turns the command into a current:

- speed mode: a PI loop on speed gives an acceleration request, clipped to
  ±α_max (the 314 rpm/s limit that makes a 0 → 6000 rpm step take ~20 s);
- acceleration mode: the acceleration request is the command, clipped the same;
- in both, the current is I·α_req/k_t plus friction feed-forward, clipped to
  ±i_max, and cut when it would push past the speed limit.

Speed is measured like a Hall-sensor wheel: quantised (``speed_resolution_rpm``)
with noise, reading 0 below the slowest speed that still produces Hall edges.
Faults latch (overspeed, overcurrent, overtemperature) and clear only on an
explicit clear-fault command; a latched fault idles the motor.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from rwlab.errors import ConfigError

__all__ = ["RW90", "Fault", "Mode", "WheelParams", "WheelPhysics", "rad_s_to_rpm", "rpm_to_rad_s"]

RPM = 2 * math.pi / 60  # rad/s per rpm


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
    """Reaction-wheel parameters (RW90 defaults from paper A, Table 1).

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
    speed_resolution_rpm, speed_noise_rpm, min_measurable_rpm : float
        Hall-sensor speed measurement: quantum, noise σ and dead zone, rpm.
    overspeed_fault_rpm : float
        Hard overspeed fault threshold, rpm.
    overcurrent_fault : float
        Hard overcurrent fault threshold, A.
    thermal_resistance, thermal_time_constant, overtemp_fault_c, ambient_c : float
        First-order motor thermal model (K/W, s) and its fault threshold (°C).
    winding_resistance : float
        Ω, for copper losses in the thermal model.
    """

    inertia: float = 4.2e-4
    nominal_speed_rpm: float = 6000.0
    max_speed_rpm: float = 7800.0
    nominal_torque: float = 0.015
    max_accel_rpm_s: float = 314.0
    current_limit: float = 0.7
    torque_constant: float = 0.0245
    viscous_friction: float = 1.0e-6
    coulomb_friction: float = 2.0e-4
    speed_kp: float = 0.485
    speed_ki: float = 0.123
    speed_resolution_rpm: float = 0.5
    speed_noise_rpm: float = 0.5
    min_measurable_rpm: float = 2.0
    overspeed_fault_rpm: float = 8500.0
    overcurrent_fault: float = 1.5
    thermal_resistance: float = 8.0
    thermal_time_constant: float = 600.0
    overtemp_fault_c: float = 85.0
    ambient_c: float = 20.0
    winding_resistance: float = 4.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(
                    f"wheel parameter {f.name} must be a finite number, got {value!r}"
                )
            if value < 0 or (value == 0 and f.name in _STRICTLY_POSITIVE):
                raise ConfigError(f"wheel parameter {f.name} must be > 0, got {value}")
        if self.max_speed_rpm >= self.overspeed_fault_rpm:
            raise ConfigError("overspeed_fault_rpm must be above max_speed_rpm")
        if self.current_limit >= self.overcurrent_fault:
            raise ConfigError("overcurrent_fault must be above current_limit")

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

    @classmethod
    def from_toml(cls, path: str | Path) -> WheelParams:
        """Load parameters from a TOML file (a ``[wheel]`` table or top-level keys).

        Unknown keys are an error; missing keys keep the RW90 defaults.
        """
        from rwlab._toml import read_table

        table = read_table(path, "wheel", "wheel parameter")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ConfigError(
                f"{path}: unknown wheel parameter(s) {unknown}; known: {sorted(known)}"
            )
        return replace(cls(), **table)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


_STRICTLY_POSITIVE = {
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

RW90 = WheelParams()
"""The RW90 wheel of paper A (Table 1)."""


def _clip(x: float, limit: float) -> float:
    return -limit if x < -limit else (limit if x > limit else x)


class WheelPhysics:
    """One wheel's state over time, stepped with a fixed time step.

    Parameters
    ----------
    params : WheelParams
    seed : int or numpy.random.Generator
        For the speed-measurement noise.
    """

    def __init__(self, params: WheelParams = RW90, seed=0) -> None:
        self.params = params
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.speed = 0.0  # rad/s
        self.current = 0.0  # A
        self.temperature = params.ambient_c  # °C
        self.mode = Mode.IDLE
        self.setpoint = 0.0  # rad/s (speed mode) or rad/s² (acceleration mode)
        self.faults = Fault.NONE
        self.speed_limited = False
        self._integral = 0.0
        self.forced_current: float | None = None  # fault injection: a stalled/shorted driver
        # Degradations of the rotor and driver (fault injection). The wheel's own
        # controller does not know them: it keeps computing with ``params``.
        self.friction_factor = 1.0  # bearing wear: the true friction is this × the nominal
        self.torque_constant_factor = 1.0  # a weakened motor: the true k_t is this × nominal
        self.current_limit = params.current_limit  # the driver's current clamp, A

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
    def _accel_request(self, dt: float) -> float:
        p = self.params
        if self.mode == Mode.SPEED:
            target = _clip(self.setpoint, p.max_speed)
            error = target - self.speed
            request = p.speed_kp * error + self._integral
            if abs(request) < p.max_accel:  # anti-windup: integrate only when unsaturated
                self._integral += p.speed_ki * error * dt
            return _clip(request, p.max_accel)
        if self.mode == Mode.ACCELERATION:
            return _clip(self.setpoint, p.max_accel)
        return 0.0

    def friction_torque(self, speed: float) -> float:
        """Nominal friction torque opposing the rotation, N·m (the controller's feed-forward)."""
        p = self.params
        return p.viscous_friction * speed + p.coulomb_friction * math.copysign(1.0, speed) * (
            abs(speed) > 1e-9
        )

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds (use ≤ 1 ms for the inner loop's accuracy)."""
        p = self.params
        alpha = self._accel_request(dt)
        if self.mode == Mode.IDLE:
            current = 0.0
        else:
            torque = p.inertia * alpha + self.friction_torque(self.speed)
            current = _clip(torque / p.torque_constant, self.current_limit)
        # speed limit: never drive further beyond the maximum speed
        self.speed_limited = abs(self.speed) >= p.max_speed and current * self.speed > 0
        if self.speed_limited:
            current = _clip(
                self.friction_torque(self.speed) / p.torque_constant, self.current_limit
            )
        if self.forced_current is not None:
            current = self.forced_current
        self.current = current
        k_t = self.torque_constant_factor * p.torque_constant  # the true motor, not the model
        net = k_t * current - self.friction_factor * self.friction_torque(self.speed)
        new_speed = self.speed + net / p.inertia * dt
        if self.mode == Mode.IDLE and self.speed != 0 and new_speed * self.speed < 0:
            new_speed = 0.0  # friction stops the wheel; it does not reverse it
        self.speed = new_speed
        heat = p.winding_resistance * current**2
        self.temperature += (
            dt
            / p.thermal_time_constant
            * (p.ambient_c + p.thermal_resistance * heat - self.temperature)
        )
        self._check_faults()

    def _check_faults(self) -> None:
        p = self.params
        if abs(rad_s_to_rpm(self.speed)) > p.overspeed_fault_rpm:
            self.latch(Fault.OVERSPEED)
        if abs(self.current) > p.overcurrent_fault:
            self.latch(Fault.OVERCURRENT)
            self.current = 0.0
        if self.temperature > p.overtemp_fault_c:
            self.latch(Fault.OVERTEMP)

    # -- measurement -----------------------------------------------------------------
    def measured_speed_rpm(self) -> float:
        """Speed as the Hall sensors report it: noisy, quantised, 0 near standstill."""
        p = self.params
        rpm = rad_s_to_rpm(self.speed)
        if abs(rpm) < p.min_measurable_rpm:
            return 0.0
        noisy = rpm + p.speed_noise_rpm * self.rng.standard_normal()
        return round(noisy / p.speed_resolution_rpm) * p.speed_resolution_rpm

    @property
    def momentum(self) -> float:
        """Wheel angular momentum I·ω, N·m·s."""
        return self.params.inertia * self.speed

    @property
    def motor_torque(self) -> float:
        """Motor torque on the rotor, N·m (the satellite feels its negative)."""
        return self.torque_constant_factor * self.params.torque_constant * self.current


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
        for _ in range(substeps):
            wheel.step(h)
    return out
