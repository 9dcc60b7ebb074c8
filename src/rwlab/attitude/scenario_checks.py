"""The checks a scenario passes when it is built: types, ranges, and the sections together.

Called by :class:`rwlab.attitude.scenario.Scenario` itself; every error is a
``ConfigError`` naming the field by its dotted name (``wheels.max_torque``).
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any, Protocol, TypeGuard

import numpy as np

from rwlab._toml import unknown_keys
from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.sections import SECTIONS, Momentum, RunSettings, Sensors, Sky, Wheels
from rwlab.attitude.sensors import GyroModel, StarTrackerModel
from rwlab.errors import ConfigError

__all__ = ["check", "is_number"]


class CheckedScenario(Protocol):
    """What the checks read of a scenario: :class:`rwlab.attitude.scenario.Scenario` has
    it (typed by shape, so that the checks do not depend on the module that calls them)."""

    @property
    def name(self) -> str: ...

    @property
    def wheels(self) -> Wheels: ...

    @property
    def sensors(self) -> Sensors: ...

    @property
    def sky(self) -> Sky: ...

    @property
    def momentum(self) -> Momentum: ...

    @property
    def run(self) -> RunSettings: ...

    @property
    def n_wheels(self) -> int: ...

    @property
    def inertia_matrix(self) -> np.ndarray: ...

    @property
    def filter_inertia_matrix(self) -> np.ndarray: ...

    def get(self, name: str) -> Any: ...


def check(sc: CheckedScenario) -> None:
    """Every field of the type and in the range its meaning allows, the sections consistent.

    Parameters
    ----------
    sc : Scenario
        The scenario being built.

    Raises
    ------
    ConfigError
        Naming the field by its dotted name.
    """
    for section, cls in SECTIONS.items():
        if not isinstance(getattr(sc, section), cls):
            raise ConfigError(f"{sc.name}: {section} must be a {cls.__name__}")
    if not isinstance(sc.name, str):
        raise ConfigError(f"scenario name must be a string, got {sc.name!r}")
    _check_types(sc)
    _check_attitude_sensors(sc)
    _check_inertia(sc)
    for name, allowed in (
        ("wheels.axes", ("orthogonal", "pyramid")),
        ("wheels.model", ("ideal", "physics", "identified")),
        ("sky.sun", ("fixed", "moving")),
        ("filter.disturbance_state", ("torque+srp", "srp", "torque", "none")),
    ):
        if sc.get(name) not in allowed:
            raise ConfigError(f"{sc.name}: {name} must be one of {allowed}, got {sc.get(name)!r}")
    w = sc.wheels
    if w.model == "identified" and not w.model_file:
        raise ConfigError("wheels.model 'identified' needs wheels.model_file = model.json")
    _check_wheel_faults(sc)
    _check_ranges(sc)
    h_speed = w.inertia * w.max_speed_rpm * math.pi / 30
    if w.max_momentum > h_speed * (1 + 1e-9):
        raise ConfigError(
            f"{sc.name}: wheels.max_momentum exceeds wheels.inertia × wheels.max_speed_rpm"
        )
    if w.max_torque * sc.run.dt > w.max_momentum:
        raise ConfigError(
            f"{sc.name}: wheels.max_torque × run.dt exceeds wheels.max_momentum "
            "(the wheel would saturate within one step)"
        )
    _check_sky(sc)
    _check_jitter(sc)
    ratio = sc.sensors.period / sc.run.dt
    if abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(f"{sc.name}: sensors.period must be a whole number of run.dt")


JITTER_STEP_RAD = 0.5  # the most a wheel may turn in one step with its imbalance on


def _check_jitter(sc: CheckedScenario) -> None:
    """Imbalances ≥ 0, one value or one per wheel; positions (N, 3); and a step that
    resolves the imbalance's rotation at the wheels' top speed (the plant's RK4 samples
    it at each stage: more than ``JITTER_STEP_RAD`` a step and it aliases)."""
    from rwlab.attitude.wheels import jitter_arrays

    imbalance, _ = jitter_arrays(sc)  # raises on a bad shape or value
    if not sc.wheels.jitter or not imbalance.any():
        return
    top = sc.wheels.max_momentum / sc.wheels.inertia  # rad/s
    if top * sc.run.dt > JITTER_STEP_RAD:
        raise ConfigError(
            f"{sc.name}: wheel imbalance turns {top * sc.run.dt:.3g} rad a step at the wheels' "
            f"top speed ({top:.4g} rad/s); set run.dt ≤ {JITTER_STEP_RAD / top:.3g} s, "
            "or wheels.jitter = false"
        )


def _check_sky(sc: CheckedScenario) -> None:
    epoch = sc.sky.epoch
    if epoch is not None:
        from rwlab.attitude.ephemeris import parse_epoch

        if not isinstance(epoch, str):
            raise ConfigError(f"{sc.name}: sky.epoch must be an ISO 8601 string")
        parse_epoch(epoch)
    if not -180 <= sc.sky.station_longitude_deg <= 360:
        raise ConfigError(f"{sc.name}: sky.station_longitude_deg must be in [-180, 360]")
    if sc.sensors.sun_noise_incidence and sc.sensors.sun_fov_deg >= 90:
        raise ConfigError(f"{sc.name}: sensors.sun_noise_incidence needs sensors.sun_fov_deg < 90")


_POSITIVE = (
    "wheels.torque_scale",
    "wheels.friction_factor",
    "wheels.inertia",
    "wheels.max_torque",
    "wheels.max_momentum",
    "wheels.max_speed_rpm",
    "filter.torque_drift_s",
    "filter.srp_drift_s",
    "filter.noise_margin",
    "filter.disturbance_budget_deg",
    "filter.ltr_bandwidth_factor",
    "sensors.sun_noise_deg",
    "sensors.earth_noise_deg",
    "sensors.period",
    "sensors.sun_fov_deg",
    "run.dt",
    "run.duration",
    "control.pointing_requirement_deg",
    "control.lqr_attitude_deg",
    "control.lqr_rate_deg_s",
    "momentum.thruster_torque",
    "momentum.thruster_min_pulse_s",
    "momentum.unload_pulse_period_s",
    "momentum.unload_recovery_s",
)
_NON_NEGATIVE = (
    "spacecraft.process_noise_torque",
    "run.initial_error_deg",
    "filter.initial_error_deg",
    "filter.torque_bound",
    "filter.innovation_gate",
    "sensors.earth_sensor_sun_exclusion_deg",
    "sensors.earth_sensor_moon_exclusion_deg",
)
_FRACTIONS = (
    "control.lqr_torque_fraction",
    "control.slew_torque_fraction",
    "control.slew_momentum_fraction",
    "momentum.unload_start_fraction",
    "momentum.unload_stop_fraction",
)
_VECTORS = {
    "spacecraft.inertia": (3, 9),
    "filter.inertia": (0, 3, 9),
    "run.initial_axis": (3,),
    "run.initial_rate": (3,),
    "sensors.sun_sensor_bias_deg": (2,),
    "sensors.sun_sensor_misalignment_deg": (3,),
    "sensors.earth_sensor_bias_deg": (2,),
    "sensors.earth_sensor_misalignment_deg": (3,),
}


def _check_ranges(sc: CheckedScenario) -> None:
    """Positive numbers, non-negative numbers and fractions where the physics needs them."""
    for name in _POSITIVE:
        value = sc.get(name)
        if not math.isfinite(value) or value <= 0:
            raise ConfigError(f"{sc.name}: {name} must be a positive number, got {value!r}")
    for name in _NON_NEGATIVE:
        if not math.isfinite(sc.get(name)) or sc.get(name) < 0:
            raise ConfigError(f"{sc.name}: {name} must be ≥ 0")
    for name in _FRACTIONS:
        value = sc.get(name)
        if not 0 < value <= 1:
            raise ConfigError(f"{sc.name}: {name} must be in (0, 1], got {value!r}")
    m = sc.momentum
    if not m.unload_stop_fraction < m.unload_start_fraction:
        raise ConfigError(
            f"{sc.name}: momentum.unload_stop_fraction must be < momentum.unload_start_fraction"
        )
    if np.linalg.norm(sc.run.initial_axis) == 0:
        raise ConfigError(f"{sc.name}: run.initial_axis must not be the zero vector")
    room = (1 - m.unload_start_fraction) * sc.wheels.max_momentum  # bias + a window's swing
    if not (math.isfinite(m.bias) and abs(m.bias) < room):
        raise ConfigError(
            f"{sc.name}: momentum.bias must be a number (N·m·s) below (1 − "
            f"momentum.unload_start_fraction) × wheels.max_momentum ({room:g}), got {m.bias!r}"
        )


def _check_inertia(sc: CheckedScenario) -> None:
    """The truth's and the filter's inertia symmetric positive definite, a physical body."""
    J = sc.inertia_matrix
    if not np.allclose(J, J.T) or np.any(np.linalg.eigvalsh(J) <= 0):
        raise ConfigError(f"{sc.name}: spacecraft.inertia must be symmetric positive definite")
    Jf = sc.filter_inertia_matrix
    if not np.allclose(Jf, Jf.T) or np.any(np.linalg.eigvalsh(Jf) <= 0):
        raise ConfigError(f"{sc.name}: filter.inertia must be symmetric positive definite")
    ev = np.linalg.eigvalsh(J)
    if ev[2] > ev[0] + ev[1] + 1e-9:
        raise ConfigError(f"{sc.name}: spacecraft.inertia violates the triangle inequality")


_FAULT_KEYS = {
    "friction": "a factor > 0",
    "torque_constant": "a factor ≥ 0",
    "current_limit": "A ≥ 0",
}


def _check_wheel_faults(sc: CheckedScenario) -> None:
    """Each fault names an existing wheel, a start time and at least one known change."""
    faults = sc.wheels.faults
    if not isinstance(faults, (tuple, list)):
        raise ConfigError(f"{sc.name}: wheels.faults must be a list of tables")
    if faults and sc.wheels.model != "physics":
        raise ConfigError(f"{sc.name}: wheels.faults need wheels.model = 'physics'")
    for f in faults:
        if not isinstance(f, dict):
            raise ConfigError(f"{sc.name}: each wheel fault must be a table, got {f!r}")
        unknown = unknown_keys(f, {"wheel", "at_s", *_FAULT_KEYS})
        wheel = f.get("wheel")
        if unknown:
            raise ConfigError(f"{sc.name}: wheel fault has unknown key(s) {unknown}")
        if isinstance(wheel, bool) or not isinstance(wheel, int) or not 1 <= wheel <= sc.n_wheels:
            raise ConfigError(f"{sc.name}: wheel fault needs wheel = 1..{sc.n_wheels}")
        at = f.get("at_s")
        if not (is_number(at) and at >= 0):
            raise ConfigError(f"{sc.name}: wheel fault needs at_s = a time ≥ 0 (s)")
        if not set(f) & set(_FAULT_KEYS):
            raise ConfigError(
                f"{sc.name}: wheel fault changes nothing: give one of {list(_FAULT_KEYS)}"
            )
        for key, what in _FAULT_KEYS.items():
            v = f.get(key, 1.0)
            if not (is_number(v) and (v > 0 if key == "friction" else v >= 0)):
                raise ConfigError(f"{sc.name}: wheel fault {key} must be {what}, got {v!r}")


def _check_attitude_sensors(sc: CheckedScenario) -> None:
    """Gyros and a star tracker: of their model types, the tracker on the sensors' clock."""
    gyro, st = sc.sensors.gyro, sc.sensors.star_tracker
    if gyro is not None and not isinstance(gyro, GyroModel):
        raise ConfigError(
            f"{sc.name}: sensors.gyro must be a GyroModel (a [sensors.gyro] table) or absent"
        )
    if st is None:
        return
    if not isinstance(st, StarTrackerModel):
        raise ConfigError(f"{sc.name}: sensors.star_tracker must be a StarTrackerModel or absent")
    ratio = st.period_s / sc.sensors.period
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(
            f"{sc.name}: sensors.star_tracker.period_s must be a whole multiple of "
            f"sensors.period ({sc.sensors.period:g} s), got {st.period_s:g}"
        )


def _check_types(sc: CheckedScenario) -> None:
    """Every field of the type its default has (numbers finite), vectors of the right length."""
    for section in SECTIONS:
        for f in fields(getattr(sc, section)):
            name = f"{section}.{f.name}"
            _check_type(sc.name, name, getattr(getattr(sc, section), f.name), f.default)


# one number or one per wheel: checked by ``_check_jitter``
_PER_WHEEL = ("wheels.static_imbalance_kg_m", "wheels.dynamic_imbalance_kg_m2")


def _check_type(where: str, name: str, value: Any, default: Any) -> None:
    if name in _PER_WHEEL:
        return
    if name in _VECTORS:
        ok = isinstance(value, (tuple, list)) and len(value) in _VECTORS[name]
        if not (ok and all(is_number(v) for v in value)):
            sizes = " or ".join(str(n) for n in _VECTORS[name])
            raise ConfigError(f"{where}: {name} must be a list of {sizes} numbers")
    elif isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {name} must be true or false, got {value!r}")
    elif isinstance(default, float):
        if not is_number(value):
            raise ConfigError(f"{where}: {name} must be a number, got {value!r}")
    elif isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(f"{where}: {name} must be a whole number ≥ 0, got {value!r}")
    elif isinstance(default, str) and not isinstance(value, str):
        raise ConfigError(f"{where}: {name} must be a string, got {value!r}")
    elif name == "spacecraft.disturbances" and not isinstance(value, DisturbanceModel):
        raise ConfigError(f"{where}: {name} must be a DisturbanceModel")


def is_number(v: object) -> TypeGuard[float]:
    """Whether ``v`` is a finite real number (a bool is not one).

    Parameters
    ----------
    v : object
        A value read from a scenario file or set by a caller.

    Returns
    -------
    bool
    """
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
