"""Named, validated simulation scenarios (paper B's numbers are illegible: documented defaults).

Three built-ins:

- ``geo-smallsat`` — a 150 kg GEO smallsat (J ≈ diag(14, 12, 10) kg·m²) with
  three orthogonal RW90 wheels (the wheel on our testbed: 0.34 N·m·s,
  7800 rpm, 0.015 N·m), 1.5 m² of arrays;
- ``geo-smallsat-pyramid`` — the same with four RW90 in a pyramid (54.74° from z);
- ``geo-comsat`` — a comsat (J = diag(1200, 1000, 1500) kg·m², as in the
  Basilisk peer scenario) with three HR16-class wheels (50 N·m·s, 0.2 N·m,
  6000 rpm) and 30 m² of arrays.

Sensors: sun sensor 0.02°, earth sensor 0.05° (1σ, typical units); the filter
assumes 30 % more (paper B). Two more built-ins fly the sensors real GEO comsats
carry through the eclipses (``rwlab.attitude.sensors``): ``geo-comsat-gyro``
(gyros drive the filter: the Lefferts–Markley–Shuster MEKF) and
``geo-comsat-star`` (gyros and a star tracker).

A :class:`Scenario` is a name and eight sections — :class:`Spacecraft`,
:class:`Wheels`, :class:`Sensors`, :class:`Sky`, :class:`FilterDesign`,
:class:`ControlDesign`, :class:`Momentum`, :class:`RunSettings` — reached as
``sc.wheels.max_torque``; ``sc.with_(**{"wheels.max_torque": 0.1})`` changes
fields by their dotted names. A scenario file is TOML with one table per section::

    [scenario]
    base = "geo-comsat"          # the built-in to start from
    name = "my-comsat"
    [wheels]
    max_torque = 0.1
    [spacecraft.disturbances]
    constant_torque = [1e-3, 0.0, 0.0]
    [sensors.gyro]               # gyros fly (their keys over GyroModel's defaults)

Unknown keys and bad values are errors. The flat files of rwlab ≤ 0.x (every
field under ``[scenario]``, plus ``[disturbances]``, ``[gyro]``,
``[star_tracker]``) are still read, with a :class:`rwlab.errors.FormatWarning`
naming where each key goes; :func:`convert_scenario_file` writes the sections.
"""

from __future__ import annotations

import json
import math
import tomllib
import warnings
from dataclasses import dataclass, field, fields, is_dataclass, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.sensors import GyroModel, StarTrackerModel
from rwlab.errors import ConfigError, FormatWarning

__all__ = [
    "LEGACY_NAMES",
    "SCENARIOS",
    "SECTIONS",
    "ControlDesign",
    "FilterDesign",
    "Momentum",
    "RunSettings",
    "Scenario",
    "Sensors",
    "Sky",
    "Spacecraft",
    "Wheels",
    "convert_scenario_file",
    "load_scenario",
]


@dataclass(frozen=True)
class Spacecraft:
    """The satellite body.

    Attributes
    ----------
    inertia : tuple of 3 or 9 floats
        Inertia, kg·m² (3: the diagonal).
    process_noise_torque : float
        1σ of an unmodelled white torque, N·m·√s (also the filter's).
    disturbances : DisturbanceModel
        SRP, tides, J2 and a constant torque.
    """

    inertia: tuple = (1200.0, 1000.0, 1500.0)
    process_noise_torque: float = 1e-5
    disturbances: DisturbanceModel = field(default_factory=DisturbanceModel)


@dataclass(frozen=True)
class Wheels:
    """The reaction wheels.

    Attributes
    ----------
    axes : {'orthogonal', 'pyramid'}
        3 wheels on the body axes, or 4 at 54.74° from z.
    inertia, max_torque, max_momentum, max_speed_rpm : float
        Rotor inertia (kg·m²), torque (N·m), momentum (N·m·s) and speed limits.
    model : {'ideal', 'physics', 'identified'}
        The wheel model flown.
    model_file : str or None
        The model.json of ``"identified"``.
    faults : tuple of dict
        For ``"physics"``: tables ``{wheel = 1..N, at_s = s, friction = factor,
        torque_constant = factor, current_limit = A}`` (any of the last three).
    torque_scale : float
        Realised wheel torque over the command (1: exact).
    stiction : bool
        For ``"physics"``: the twin's friction law at low speed (breakaway + Stribeck +
        Coulomb + viscous, stuck at rest until the motor beats the breakaway torque;
        ``rwlab.attitude.wheels``); False: Coulomb + viscous only.
    friction_factor : float
        The true friction over what the drive's feed-forward assumes (a worn or cold
        bearing; ``"physics"`` wheels).
    """

    axes: str = "orthogonal"
    inertia: float = 0.08
    max_torque: float = 0.2
    max_momentum: float = 50.0
    max_speed_rpm: float = 6000.0
    model: str = "ideal"
    model_file: str | None = None
    faults: tuple = ()
    torque_scale: float = 1.0
    stiction: bool = True
    friction_factor: float = 1.0


@dataclass(frozen=True)
class Sensors:
    """The attitude sensors as hardware.

    Attributes
    ----------
    period : float
        s between sun/earth-sensor measurements (a whole number of ``run.dt``).
    sun_noise_deg, earth_noise_deg : float
        Sensor noise, 1σ, degrees.
    sun_fov_deg : float
        Sun-sensor half cone angle around its boresight (−x body).
    sun_noise_incidence : bool
        The sun-sensor noise grows as 1/cos of the incidence angle (``sun_noise_deg``
        at normal incidence; needs ``sun_fov_deg`` < 90).
    earth_sensor_sun_exclusion_deg, earth_sensor_moon_exclusion_deg : float
        The earth sensor (boresight +z body) is blinded while a visible Sun / Moon lies
        within this angle of its boresight (0: never).
    sun_sensor_bias_deg, earth_sensor_bias_deg : tuple of 2 floats
        Constant errors of each two-axis sensor's output angles (about its transverse
        axes: y, z for the sun sensor, x, y for the earth sensor).
    sun_sensor_misalignment_deg, earth_sensor_misalignment_deg : tuple of 3 floats
        The sensor head's mounting error, a small rotation (x, y, z body), unknown to
        the filter.
    gyro : GyroModel or None
        Gyros; with them the filter is the gyro-driven MEKF (Lefferts–Markley–Shuster:
        attitude + gyro bias), the dynamics model unused.
    star_tracker : StarTrackerModel or None
        A star tracker's attitude updates.
    """

    period: float = 0.5
    sun_noise_deg: float = 0.02
    earth_noise_deg: float = 0.05
    sun_fov_deg: float = 180.0
    sun_noise_incidence: bool = False
    earth_sensor_sun_exclusion_deg: float = 12.0
    earth_sensor_moon_exclusion_deg: float = 10.0
    sun_sensor_bias_deg: tuple = (0.0, 0.0)
    sun_sensor_misalignment_deg: tuple = (0.0, 0.0, 0.0)
    earth_sensor_bias_deg: tuple = (0.0, 0.0)
    earth_sensor_misalignment_deg: tuple = (0.0, 0.0, 0.0)
    gyro: GyroModel | None = None
    star_tracker: StarTrackerModel | None = None


@dataclass(frozen=True)
class Sky:
    """The Sun, the Moon and the slot (``attitude.ephemeris``).

    Attributes
    ----------
    sun : {'fixed', 'moving'}
        Paper B: fixed in the orbital frame; or turning once a day.
    sun_declination_deg, sun_phase_deg : float
        The Sun's direction (season and time of day) without an epoch.
    epoch : str or None
        UTC instant of t = 0, ISO 8601; None (paper B): the vectors above and a fixed
        Moon. With an epoch the Sun and Moon come from the ephemerides and the Earth's
        shadow is real.
    station_longitude_deg : float
        The GEO slot, degrees east.
    """

    sun: str = "fixed"
    sun_declination_deg: float = 10.0
    sun_phase_deg: float = 40.0
    epoch: str | None = None
    station_longitude_deg: float = 0.0


@dataclass(frozen=True)
class FilterDesign:
    """The attitude filter and what its designer assumes.

    Attributes
    ----------
    noise_margin : float
        Factor on the sensor noise the filter assumes (paper B: 1.3).
    initial_error_deg : float
        Initial error of the filter's estimate, degrees.
    innovation_gate : float
        χ² bound on a measurement's normalised innovation; beyond it the filter rejects
        the measurement (0, the default: no gate — a filter that lags an unmodelled
        torque sees large innovations, and a gate then rejects most of its
        measurements: LQG on unknown-torque.toml 0.46° → 1.38°).
    innovation_gate_max_rejections : int
        After this many rejections in a row a sensor's next measurement is taken
        whatever its innovation (a drifted filter must not lock its sensors out).
    disturbances_known : bool
        False (paper B): SRP, tides and J2 are unknown to the filter and enter as
        process noise.
    disturbance_budget_deg : float
        The filter's lag on the worst-case unknown torque allowed by its process noise
        (see ``sim.default_filter_psd``).
    torque_bound : float
        That worst-case torque, N·m, as the designer assumes it; 0 derives it from the
        disturbance model (SRP, tides, constant torque).
    disturbance_state : {'torque+srp', 'srp', 'torque', 'none'}
        What the filter estimates of the torque it does not model, as a random walk
        that its model adds and the controller cancels (disturbance accommodation, see
        ``ekf``): ``"srp"`` solar pressure through an unknown centre of pressure;
        ``"torque"`` a constant body torque; ``"torque+srp"`` both (12 states);
        ``"none"`` the 6-state filter with the unknown torque as inflated rate noise.
    torque_drift_s, srp_drift_s : float
        The time over which each of those random walks may drift by the designer's
        torque bound, s (a year and a day; see ``sim.disturbance_psd``).
    ltr_bandwidth_factor : float
        LTR's fictitious noise puts the filter's bandwidth at this multiple of the LQR
        loop's crossover at ρ = 1.
    inertia : tuple of 0, 3 or 9 floats
        The inertia the filter's dynamics model uses (empty: the truth's), kg·m².
    sun_sensor_alignment : bool
        With gyros, the filter also estimates the sun sensor's misalignment relative to
        the earth sensor (in-flight calibration; about z it stays at its prior).
    earth_sensor_alignment : bool
        With the above, the earth sensor's turn too, as consider states at their prior.
    """

    noise_margin: float = 1.3
    initial_error_deg: float = 1.0
    innovation_gate: float = 0.0
    innovation_gate_max_rejections: int = 10
    disturbances_known: bool = False
    disturbance_budget_deg: float = 0.02
    torque_bound: float = 0.0
    disturbance_state: str = "torque+srp"
    torque_drift_s: float = 3.156e7
    srp_drift_s: float = 86400.0
    ltr_bandwidth_factor: float = 2.5
    inertia: tuple = ()
    sun_sensor_alignment: bool = True
    earth_sensor_alignment: bool = True


@dataclass(frozen=True)
class ControlDesign:
    """Paper B's weights, from the requirement and the actuator.

    Attributes
    ----------
    pointing_requirement_deg : float
        The pointing requirement (paper B: ±0.1°).
    lqr_attitude_deg, lqr_rate_deg_s : float
        Bryson scales of the attitude (°) and rate (°/s) errors.
    lqr_torque_fraction : float
        Bryson torque scale as a fraction of the wheels' maximum torque: the
        proportional torque at ``lqr_attitude_deg`` of error.
    slew_torque_fraction, slew_momentum_fraction : float
        The rate limit of a large-angle slew leaves this share of the torque (and of
        the momentum) to the wheels.
    """

    pointing_requirement_deg: float = 0.1
    lqr_attitude_deg: float = 0.1
    lqr_rate_deg_s: float = 0.05
    lqr_torque_fraction: float = 0.1
    slew_torque_fraction: float = 0.5
    slew_momentum_fraction: float = 0.25


@dataclass(frozen=True)
class Momentum:
    """Momentum management by thrusters (magnetic torquers are too weak at GEO).

    Attributes
    ----------
    unloading : bool
        On/off.
    thruster_torque : float
        N·m about each axis.
    thruster_min_pulse_s : float
        Minimum impulse bit as an on-time, s.
    unload_start_fraction, unload_stop_fraction : float
        Wheel momentum (share of the limit) that starts and ends an unloading window.
    unload_pulse_period_s : float
        s between pulses.
    unload_recovery_s : float
        s after a window still counted as "during desaturation".
    bias : float
        N·m·s the wheels are held at, off zero speed (0: none): with four wheels along
        the null vector of the wheel matrix (no body momentum, no torque; a slow
        null-space loop holds it), with three orthogonal wheels on the pitch wheel (the
        target the unloading steers to); see ``sim.bias_momenta``.
    """

    unloading: bool = True
    thruster_torque: float = 1.2  # a 1 N hydrazine thruster at 1.2 m
    thruster_min_pulse_s: float = 0.015
    unload_start_fraction: float = 0.5
    unload_stop_fraction: float = 0.1
    unload_pulse_period_s: float = 2.0
    unload_recovery_s: float = 300.0
    bias: float = 0.0


@dataclass(frozen=True)
class RunSettings:
    """The run: step, length, seed and initial state.

    Attributes
    ----------
    dt : float
        Physics/control step, s.
    duration : float
        Default run length, s.
    seed : int
        Noise seed.
    initial_error_deg : float
        Initial attitude error, degrees, about ``initial_axis``.
    initial_axis : tuple of 3 floats
        Axis of the initial error (body).
    initial_rate : tuple of 3 floats
        Initial body rate relative to the orbital frame, rad/s.
    """

    dt: float = 0.1
    duration: float = 3600.0
    seed: int = 0
    initial_error_deg: float = 2.0
    initial_axis: tuple = (1.0, 0.5, -0.3)
    initial_rate: tuple = (1e-4, 0.0, 0.0)


#: Section name → its class, in the order of a scenario file.
SECTIONS: dict[str, type] = {
    "spacecraft": Spacecraft,
    "wheels": Wheels,
    "sensors": Sensors,
    "sky": Sky,
    "filter": FilterDesign,
    "control": ControlDesign,
    "momentum": Momentum,
    "run": RunSettings,
}


#: The flat field names of the old scenario format → their dotted names in the sections.
LEGACY_NAMES: dict[str, str] = {
    "inertia": "spacecraft.inertia",
    "process_noise_torque": "spacecraft.process_noise_torque",
    "disturbances": "spacecraft.disturbances",
    "wheel_axes": "wheels.axes",
    "wheel_inertia": "wheels.inertia",
    "wheel_max_torque": "wheels.max_torque",
    "wheel_max_momentum": "wheels.max_momentum",
    "wheel_max_speed_rpm": "wheels.max_speed_rpm",
    "wheel_model": "wheels.model",
    "wheel_model_file": "wheels.model_file",
    "wheel_faults": "wheels.faults",
    "wheel_torque_scale": "wheels.torque_scale",
    "wheel_stiction": "wheels.stiction",
    "wheel_friction_factor": "wheels.friction_factor",
    "sensor_period": "sensors.period",
    "sun_noise_deg": "sensors.sun_noise_deg",
    "earth_noise_deg": "sensors.earth_noise_deg",
    "sun_fov_deg": "sensors.sun_fov_deg",
    "sun_noise_incidence": "sensors.sun_noise_incidence",
    "earth_sensor_sun_exclusion_deg": "sensors.earth_sensor_sun_exclusion_deg",
    "earth_sensor_moon_exclusion_deg": "sensors.earth_sensor_moon_exclusion_deg",
    "sun_sensor_bias_deg": "sensors.sun_sensor_bias_deg",
    "sun_sensor_misalignment_deg": "sensors.sun_sensor_misalignment_deg",
    "earth_sensor_bias_deg": "sensors.earth_sensor_bias_deg",
    "earth_sensor_misalignment_deg": "sensors.earth_sensor_misalignment_deg",
    "gyro": "sensors.gyro",
    "star_tracker": "sensors.star_tracker",
    "sun": "sky.sun",
    "sun_declination_deg": "sky.sun_declination_deg",
    "sun_phase_deg": "sky.sun_phase_deg",
    "epoch": "sky.epoch",
    "station_longitude_deg": "sky.station_longitude_deg",
    "noise_margin": "filter.noise_margin",
    "estimator_error_deg": "filter.initial_error_deg",
    "innovation_gate": "filter.innovation_gate",
    "innovation_gate_max_rejections": "filter.innovation_gate_max_rejections",
    "disturbances_known_to_filter": "filter.disturbances_known",
    "filter_disturbance_budget_deg": "filter.disturbance_budget_deg",
    "filter_torque_bound": "filter.torque_bound",
    "filter_disturbance_state": "filter.disturbance_state",
    "filter_torque_drift_s": "filter.torque_drift_s",
    "filter_srp_drift_s": "filter.srp_drift_s",
    "ltr_bandwidth_factor": "filter.ltr_bandwidth_factor",
    "filter_inertia": "filter.inertia",
    "filter_sun_sensor_alignment": "filter.sun_sensor_alignment",
    "filter_earth_sensor_alignment": "filter.earth_sensor_alignment",
    "pointing_requirement_deg": "control.pointing_requirement_deg",
    "lqr_attitude_deg": "control.lqr_attitude_deg",
    "lqr_rate_deg_s": "control.lqr_rate_deg_s",
    "lqr_torque_fraction": "control.lqr_torque_fraction",
    "slew_torque_fraction": "control.slew_torque_fraction",
    "slew_momentum_fraction": "control.slew_momentum_fraction",
    "momentum_unloading": "momentum.unloading",
    "thruster_torque": "momentum.thruster_torque",
    "thruster_min_pulse_s": "momentum.thruster_min_pulse_s",
    "unload_start_fraction": "momentum.unload_start_fraction",
    "unload_stop_fraction": "momentum.unload_stop_fraction",
    "unload_pulse_period_s": "momentum.unload_pulse_period_s",
    "unload_recovery_s": "momentum.unload_recovery_s",
    "momentum_bias": "momentum.bias",
    "dt": "run.dt",
    "duration": "run.duration",
    "seed": "run.seed",
    "initial_error_deg": "run.initial_error_deg",
    "initial_axis": "run.initial_axis",
    "initial_rate": "run.initial_rate",
}


@dataclass(frozen=True)
class Scenario:
    """Everything one attitude simulation needs: a name and eight sections.

    Attributes
    ----------
    name : str
        The scenario's name (reports, outputs).
    spacecraft : Spacecraft
    wheels : Wheels
    sensors : Sensors
    sky : Sky
    filter : FilterDesign
    control : ControlDesign
    momentum : Momentum
    run : RunSettings

    Every section is validated together when the scenario is built (``ConfigError``).
    """

    name: str = "custom"
    spacecraft: Spacecraft = field(default_factory=Spacecraft)
    wheels: Wheels = field(default_factory=Wheels)
    sensors: Sensors = field(default_factory=Sensors)
    sky: Sky = field(default_factory=Sky)
    filter: FilterDesign = field(default_factory=FilterDesign)
    control: ControlDesign = field(default_factory=ControlDesign)
    momentum: Momentum = field(default_factory=Momentum)
    run: RunSettings = field(default_factory=RunSettings)

    def __post_init__(self) -> None:
        for section, cls in SECTIONS.items():
            if not isinstance(getattr(self, section), cls):
                raise ConfigError(f"{self.name}: {section} must be a {cls.__name__}")
        if not isinstance(self.name, str):
            raise ConfigError(f"scenario name must be a string, got {self.name!r}")
        _check_types(self)
        _check_attitude_sensors(self)
        _check_inertia(self)
        for name, allowed in (
            ("wheels.axes", ("orthogonal", "pyramid")),
            ("wheels.model", ("ideal", "physics", "identified")),
            ("sky.sun", ("fixed", "moving")),
            ("filter.disturbance_state", ("torque+srp", "srp", "torque", "none")),
        ):
            if self.get(name) not in allowed:
                raise ConfigError(
                    f"{self.name}: {name} must be one of {allowed}, got {self.get(name)!r}"
                )
        w = self.wheels
        if w.model == "identified" and not w.model_file:
            raise ConfigError("wheels.model 'identified' needs wheels.model_file = model.json")
        _check_wheel_faults(self)
        _check_ranges(self)
        h_speed = w.inertia * w.max_speed_rpm * math.pi / 30
        if w.max_momentum > h_speed * (1 + 1e-9):
            raise ConfigError(
                f"{self.name}: wheels.max_momentum exceeds wheels.inertia × wheels.max_speed_rpm"
            )
        if w.max_torque * self.run.dt > w.max_momentum:
            raise ConfigError(
                f"{self.name}: wheels.max_torque × run.dt exceeds wheels.max_momentum "
                "(the wheel would saturate within one step)"
            )
        self._check_sky()
        ratio = self.sensors.period / self.run.dt
        if abs(ratio - round(ratio)) > 1e-9:
            raise ConfigError(f"{self.name}: sensors.period must be a whole number of run.dt")

    def _check_sky(self) -> None:
        epoch = self.sky.epoch
        if epoch is not None:
            from rwlab.attitude.ephemeris import parse_epoch

            if not isinstance(epoch, str):
                raise ConfigError(f"{self.name}: sky.epoch must be an ISO 8601 string")
            parse_epoch(epoch)
        if not -180 <= self.sky.station_longitude_deg <= 360:
            raise ConfigError(f"{self.name}: sky.station_longitude_deg must be in [-180, 360]")
        if self.sensors.sun_noise_incidence and self.sensors.sun_fov_deg >= 90:
            raise ConfigError(
                f"{self.name}: sensors.sun_noise_incidence needs sensors.sun_fov_deg < 90"
            )

    def get(self, name: str) -> Any:
        """A field by its dotted name, e.g. ``sc.get("wheels.max_torque")``.

        Parameters
        ----------
        name : str
            ``section.field`` (``spacecraft.disturbances.srp_area`` one level deeper).

        Returns
        -------
        object
            The field's value.
        """
        obj: Any = self
        for part in name.split("."):
            if not is_dataclass(obj) or part not in {f.name for f in fields(obj)}:
                raise ConfigError(f"unknown scenario field {name!r}; {_FIELD_HINT}")
            obj = getattr(obj, part)
        return obj

    @property
    def filter_inertia_matrix(self) -> np.ndarray:
        """The inertia the filter's model uses, kg·m²: ``filter.inertia``, else the truth's."""
        if not self.filter.inertia:
            return self.inertia_matrix
        v = np.asarray(self.filter.inertia, dtype=float)
        return np.diag(v) if v.size == 3 else v.reshape(3, 3)

    @property
    def inertia_matrix(self) -> np.ndarray:
        """The satellite's inertia as a 3×3 matrix, kg·m²."""
        v = np.asarray(self.spacecraft.inertia, dtype=float)
        if v.size == 3:
            return np.diag(v)
        if v.size == 9:
            return v.reshape(3, 3)
        raise ConfigError(f"spacecraft.inertia needs 3 (diagonal) or 9 values, got {v.size}")

    @property
    def wheel_matrix(self) -> np.ndarray:
        """G (3×N): the wheels' spin axes in body axes."""
        if self.wheels.axes == "orthogonal":
            return np.eye(3)
        c = 1 / math.sqrt(3)  # pyramid: each axis 54.74° from +z
        return np.array([[c, -c, -c, c], [c, c, -c, -c], [c, c, c, c]])

    @property
    def n_wheels(self) -> int:
        """The number of wheels."""
        return self.wheel_matrix.shape[1]

    def with_(self, **changes: Any) -> Scenario:
        """A copy with fields changed by their dotted names (validated: ``ConfigError``).

        Parameters
        ----------
        **changes
            ``name``, a whole section (``wheels=Wheels(...)``) or a field by its dotted
            name: ``sc.with_(**{"wheels.max_torque": 0.1, "run.seed": 3})``.

        Returns
        -------
        Scenario
            The new scenario (``self`` is unchanged).
        """
        top: dict[str, Any] = {s: getattr(self, s) for s in SECTIONS}
        top["name"] = self.name
        for key in sorted(changes, key=lambda k: k.count(".")):  # whole sections first
            head, _, rest = key.partition(".")
            if head not in top or (head == "name" and rest):
                raise ConfigError(f"unknown scenario field {key!r}; {_FIELD_HINT}")
            top[head] = _set_path(top[head], rest, changes[key], key) if rest else changes[key]
        return replace(self, **top)


_FIELD_HINT = (
    "fields are named section.field with the sections "
    + ", ".join(SECTIONS)
    + " (see rwlab.attitude.scenario)"
)


def _set_path(obj: Any, path: str, value: Any, full: str) -> Any:
    """``obj`` (a frozen dataclass) with the field at dotted ``path`` set to ``value``."""
    head, _, rest = path.partition(".")
    if not is_dataclass(obj) or head not in {f.name for f in fields(obj)}:
        raise ConfigError(f"unknown scenario field {full!r}; {_FIELD_HINT}")
    new = _set_path(getattr(obj, head), rest, value, full) if rest else value
    return replace(obj, **{head: new})  # type: ignore[type-var]


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


def _check_ranges(sc: Scenario) -> None:
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


def _check_inertia(sc: Scenario) -> None:
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


def _check_wheel_faults(sc: Scenario) -> None:
    """Each fault names an existing wheel, a start time and at least one known change."""
    faults = sc.wheels.faults
    if not isinstance(faults, (tuple, list)):
        raise ConfigError(f"{sc.name}: wheels.faults must be a list of tables")
    if faults and sc.wheels.model != "physics":
        raise ConfigError(f"{sc.name}: wheels.faults need wheels.model = 'physics'")
    for f in faults:
        if not isinstance(f, dict):
            raise ConfigError(f"{sc.name}: each wheel fault must be a table, got {f!r}")
        unknown = sorted(set(f) - {"wheel", "at_s", *_FAULT_KEYS})
        wheel = f.get("wheel")
        if unknown:
            raise ConfigError(f"{sc.name}: wheel fault has unknown key(s) {unknown}")
        if isinstance(wheel, bool) or not isinstance(wheel, int) or not 1 <= wheel <= sc.n_wheels:
            raise ConfigError(f"{sc.name}: wheel fault needs wheel = 1..{sc.n_wheels}")
        at = f.get("at_s")
        if not (_is_number(at) and at >= 0):
            raise ConfigError(f"{sc.name}: wheel fault needs at_s = a time ≥ 0 (s)")
        if not set(f) & set(_FAULT_KEYS):
            raise ConfigError(
                f"{sc.name}: wheel fault changes nothing: give one of {list(_FAULT_KEYS)}"
            )
        for key, what in _FAULT_KEYS.items():
            v = f.get(key, 1.0)
            if not (_is_number(v) and (v > 0 if key == "friction" else v >= 0)):
                raise ConfigError(f"{sc.name}: wheel fault {key} must be {what}, got {v!r}")


def _check_attitude_sensors(sc: Scenario) -> None:
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


def _check_types(sc: Scenario) -> None:
    """Every field of the type its default has (numbers finite), vectors of the right length."""
    for section in SECTIONS:
        for f in fields(getattr(sc, section)):
            name = f"{section}.{f.name}"
            _check_type(sc.name, name, getattr(getattr(sc, section), f.name), f.default)


def _check_type(where: str, name: str, value: Any, default: Any) -> None:
    if name in _VECTORS:
        ok = isinstance(value, (tuple, list)) and len(value) in _VECTORS[name]
        if not (ok and all(_is_number(v) for v in value)):
            sizes = " or ".join(str(n) for n in _VECTORS[name])
            raise ConfigError(f"{where}: {name} must be a list of {sizes} numbers")
    elif isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {name} must be true or false, got {value!r}")
    elif isinstance(default, float):
        if not _is_number(value):
            raise ConfigError(f"{where}: {name} must be a number, got {value!r}")
    elif isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(f"{where}: {name} must be a whole number ≥ 0, got {value!r}")
    elif isinstance(default, str) and not isinstance(value, str):
        raise ConfigError(f"{where}: {name} must be a string, got {value!r}")
    elif name == "spacecraft.disturbances" and not isinstance(value, DisturbanceModel):
        raise ConfigError(f"{where}: {name} must be a DisturbanceModel")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


_RW90_MOMENTUM = 4.2e-4 * 7800 * 2 * math.pi / 60
SCENARIOS = {
    "geo-smallsat": Scenario(
        name="geo-smallsat",
        spacecraft=Spacecraft(
            inertia=(14.0, 12.0, 10.0),
            process_noise_torque=2e-7,
            disturbances=DisturbanceModel(srp_area=1.5, srp_offset=(0.05, -0.03, 0.08)),
        ),
        wheels=Wheels(
            inertia=4.2e-4, max_torque=0.015, max_momentum=_RW90_MOMENTUM, max_speed_rpm=7800.0
        ),
        # the RW90's torque is ample for 12 kg·m²: the bandwidth is held to ~0.25 rad/s so
        # that the 2 Hz sensors' noise is averaged (0.1 would cross at 0.48 rad/s)
        control=ControlDesign(lqr_torque_fraction=0.03),
        momentum=Momentum(thruster_torque=0.02),  # 50 mN cold gas at 0.4 m
    ),
    "geo-comsat": Scenario(name="geo-comsat"),
    # geo-comsat with the sensors GEO comsats fly for the eclipses: gyros driving the filter
    # (sun and earth sensors as before); and with a star tracker besides
    "geo-comsat-gyro": Scenario(name="geo-comsat-gyro", sensors=Sensors(gyro=GyroModel())),
    "geo-comsat-star": Scenario(
        name="geo-comsat-star",
        sensors=Sensors(gyro=GyroModel(), star_tracker=StarTrackerModel()),
    ),
}
# the smallsat with four RW90 in a pyramid: any three still span the body (a wheel may fail)
SCENARIOS["geo-smallsat-pyramid"] = SCENARIOS["geo-smallsat"].with_(
    **{"name": "geo-smallsat-pyramid", "wheels.axes": "pyramid"}
)
_SUBTABLES = {
    "spacecraft.disturbances": DisturbanceModel,
    "sensors.gyro": GyroModel,
    "sensors.star_tracker": StarTrackerModel,
}


def load_scenario(name_or_path: str, **overrides: Any) -> Scenario:
    """A built-in scenario by name, or a TOML file (a ``[scenario]`` table and sections).

    Parameters
    ----------
    name_or_path : str
        A built-in (``"geo-smallsat"``, ``"geo-comsat"``, ...) or a TOML file.
    **overrides
        Fields to change after loading, by dotted name as in :meth:`Scenario.with_`.

    Returns
    -------
    Scenario
    """
    if name_or_path in SCENARIOS:
        base = SCENARIOS[name_or_path]
        return base.with_(**overrides) if overrides else base
    path = Path(name_or_path)
    raw = _read_toml(path)
    flat = _is_flat(raw)
    if flat:
        raw = _sections_of_flat(raw, path)
    table = raw.get("scenario", {})
    base_name = table.get("base")
    if base_name is not None and base_name not in SCENARIOS:
        raise ConfigError(f"{path}: base = {base_name!r} is not one of {sorted(SCENARIOS)}")
    base = SCENARIOS[base_name] if base_name else Scenario()
    changes = {"name": str(table.get("name", path.stem))}
    for section in SECTIONS:
        changes |= _section_changes(raw.get(section, {}), section, base, path)
    sc = base.with_(**changes, **overrides)
    if flat:  # after the checks: a file refused is one error, not a warning and an error
        warnings.warn(_flat_warning(path, raw), FormatWarning, stacklevel=2)
    return sc


def _read_toml(path: Path) -> dict:
    """The file's tables, checked: not empty, known tables, tables where tables belong."""
    if not path.is_file():
        raise ConfigError(
            f"unknown scenario {str(path)!r}: not one of {sorted(SCENARIOS)} and no such file"
        )
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    if not raw or not any(raw.values()):
        raise ConfigError(
            f"{path}: the scenario file is empty; give a [scenario] table (base = "
            f"{' or '.join(map(repr, sorted(SCENARIOS)))}) and the sections' values that differ"
        )
    extra = sorted(set(raw) - {"scenario", *SECTIONS, *_FLAT_TABLES})
    if extra:
        raise ConfigError(
            f"{path}: unknown table(s) {extra}; the tables are [scenario], "
            + ", ".join(f"[{s}]" for s in SECTIONS)
        )
    for key, value in raw.items():
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: [{key}] must be a table")
    return raw


_FLAT_TABLES = ("disturbances", "gyro", "star_tracker")


def _is_flat(raw: dict) -> bool:
    """The old format: fields under [scenario], or [disturbances], [gyro], [star_tracker]."""
    flat = set(raw.get("scenario", {})) - {"base", "name"} or set(raw) & set(_FLAT_TABLES)
    return bool(flat)


def _sections_of_flat(raw: dict, path: Path) -> dict:
    """An old flat file's tables rearranged into sections (the values untouched)."""
    mixed = sorted(set(raw) & set(SECTIONS))
    if mixed:
        raise ConfigError(
            f"{path}: mixes the flat format (fields under [scenario]) with section tables "
            f"{mixed}; write every field in its section"
        )
    scenario = dict(raw.get("scenario", {}))
    out: dict[str, dict] = {
        "scenario": {k: scenario.pop(k) for k in ("base", "name") if k in scenario}
    }
    unknown = sorted(set(scenario) - set(LEGACY_NAMES))
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}")
    for flat, value in [*scenario.items(), *((t, raw[t]) for t in _FLAT_TABLES if t in raw)]:
        section, _, name = LEGACY_NAMES[flat].partition(".")
        out.setdefault(section, {})[name] = value
    return out


def _flat_warning(path: Path, sections: dict) -> str:
    moved = []
    for s in SECTIONS:
        plain = [k for k in sections.get(s, {}) if f"{s}.{k}" not in _SUBTABLES]
        moved += [f"[{s}] " + ", ".join(plain)] if plain else []
        moved += [f"[{s}.{k}]" for k in sections.get(s, {}) if f"{s}.{k}" in _SUBTABLES]
    return (
        f"{path}: a flat scenario file (fields under [scenario]) is read as before but is "
        f"deprecated; write its fields in section tables ({'; '.join(moved)}), e.g. with "
        "rwlab.attitude.scenario.convert_scenario_file (rwlab attitude convert-scenario)"
    )


def _section_changes(table: dict, section: str, base: Scenario, path: Path) -> dict:
    """One section table of a file → ``with_`` changes; anything unknown is an error."""
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: [{section}] must be a table")
    known = {f.name for f in fields(SECTIONS[section])}
    unknown = sorted(f"{section}.{k}" for k in set(table) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}")
    changes: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{section}.{key}"
        if name in _SUBTABLES:
            changes[name] = _subtable(value, name, base, path)
        elif name == "sky.epoch" and isinstance(value, datetime):  # TOML's date-time type
            changes[name] = value.isoformat()
        elif name == "wheels.model_file" and isinstance(value, str):
            changes[name] = str(path.parent / value)  # relative to the file (or absolute)
        else:
            changes[name] = tuple(value) if isinstance(value, list) else value
    return changes


def _subtable(table: Any, name: str, base: Scenario, path: Path) -> Any:
    """[spacecraft.disturbances], [sensors.gyro], [sensors.star_tracker]: their keys over
    the base's (a sensor over its defaults when the base has none; ``fly = false``
    removes the base's sensor)."""
    cls = _SUBTABLES[name]
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: [{name}] must be a table")
    table = dict(table)
    if cls is not DisturbanceModel and table.pop("fly", True) is False:
        return None
    unknown = sorted(set(table) - {f.name for f in fields(cls)})
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {[f'{name}.{k}' for k in unknown]}")
    current = base.get(name) or cls()
    for key, value in table.items():
        default = getattr(current, key)
        if isinstance(value, list):
            if isinstance(default, tuple) and not (
                len(value) == len(default) and all(map(_is_number, value))
            ):
                raise ConfigError(f"{path}: {name}.{key} must be a list of {len(default)} numbers")
            table[key] = tuple(value)
        elif cls is DisturbanceModel and isinstance(default, bool) != isinstance(value, bool):
            raise ConfigError(f"{path}: {name}.{key} must be true or false")
        elif cls is DisturbanceModel and isinstance(default, float):
            if not (_is_number(value) and value >= 0):
                raise ConfigError(f"{path}: {name}.{key} must be a number ≥ 0")
    try:
        return replace(current, **table)
    except TypeError as exc:
        raise ConfigError(f"{path}: [{name}]: {exc}") from None


def convert_scenario_file(path: str | Path) -> str:
    """The text of a flat (old-format) scenario file written in section tables.

    Parameters
    ----------
    path : str or os.PathLike
        The old file (a file already in sections is returned rearranged the same way).

    Returns
    -------
    str
        TOML text with the same values (comments are not carried over).
    """
    path = Path(path)
    raw = _read_toml(path)
    if _is_flat(raw):
        raw = _sections_of_flat(raw, path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FormatWarning)
        load_scenario(str(path))  # the values must be valid before they are rewritten
    lines = [f"# {path.name} in section tables (rwlab.attitude.scenario)"]
    for table in ("scenario", *SECTIONS):
        values = dict(raw.get(table, {}))
        subtables = {k: values.pop(k) for k in list(values) if f"{table}.{k}" in _SUBTABLES}
        if values or table == "scenario":
            lines += ["", f"[{table}]", *(f"{k} = {_toml(v)}" for k, v in values.items())]
        for key, sub in subtables.items():
            lines += ["", f"[{table}.{key}]", *(f"{k} = {_toml(v)}" for k, v in sub.items())]
    return "\n".join(lines) + "\n"


def _toml(value: Any) -> str:
    """One TOML value (strings, booleans, numbers, dates, lists, inline tables); hand-written
    because the standard library reads TOML but does not write it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # a JSON string is a TOML basic string
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    return repr(value)
