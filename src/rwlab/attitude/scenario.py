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
``geo-comsat-star`` (gyros and a star tracker); ``[gyro]`` and
``[star_tracker]`` tables in a scenario file do the same. A scenario file is
TOML with the same keys; unknown keys and bad values are errors.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from datetime import datetime
from pathlib import Path

import numpy as np

from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.sensors import GyroModel, StarTrackerModel
from rwlab.errors import ConfigError

__all__ = ["SCENARIOS", "Scenario", "load_scenario"]


@dataclass(frozen=True)
class Scenario:
    """Everything one attitude simulation needs.

    Attributes (SI units unless the name says otherwise)
    ----------------------------------------------------
    inertia : tuple of 3 or 9 floats — satellite inertia, kg·m².
    wheel_axes : str — "orthogonal" (3 wheels) or "pyramid" (4, 54.74° from z).
    wheel_inertia, wheel_max_torque, wheel_max_momentum, wheel_max_speed_rpm.
    wheel_model : "ideal" | "physics" | "identified".
    wheel_model_file : path to model.json for "identified".
    wheel_faults : for "physics": a list of tables ``{wheel = 1..N, at_s = s, friction =
        factor, torque_constant = factor, current_limit = A}`` (any of the last three).
    disturbances : DisturbanceModel.
    sun : "fixed" (paper B: fixed in the orbital frame) or "moving" (turns once a day).
    sun_declination_deg, sun_phase_deg : the Sun's direction (season and time of day).
    sun_noise_deg, earth_noise_deg : sensor noise, 1σ.
    sun_fov_deg : sun-sensor half cone angle around its boresight (−x body).
    noise_margin : factor on the sensor noise the filter assumes (paper B: 1.3).
    process_noise_torque : 1σ of an unmodelled white torque, N·m·√s (also the filter's).
    dt : physics/control step, s.  sensor_period : s between measurements.
    initial_error_deg, initial_axis : initial attitude error; initial_rate : rad/s (body-orbital).
    estimator_error_deg : initial error of the filter's estimate.
    duration : default run length, s.  seed : noise seed.

    The sky (``attitude.ephemeris``) and the sensors as hardware:
    epoch : UTC instant of t = 0, ISO 8601; None (paper B): the fixed or
        ``sun``-turning vectors above and a fixed Moon.  With an epoch the Sun
        and Moon come from the ephemerides and the Earth's shadow is real.
    station_longitude_deg : the GEO slot, degrees east.
    sun_noise_incidence : the sun-sensor noise grows as 1/cos of the incidence
        angle (``sun_noise_deg`` at normal incidence; needs ``sun_fov_deg`` < 90).
    earth_sensor_sun_exclusion_deg, earth_sensor_moon_exclusion_deg : the earth
        sensor (boresight +z body) is blinded while a visible Sun / Moon lies
        within this angle of its boresight (0: never).
    sun_sensor_bias_deg, earth_sensor_bias_deg : constant errors of each two-axis
        sensor's output angles (about its transverse axes: y, z for the sun
        sensor, x, y for the earth sensor).
    sun_sensor_misalignment_deg, earth_sensor_misalignment_deg : the sensor
        head's mounting error, a small rotation (x, y, z body), unknown to the filter.
    innovation_gate : χ² bound on a measurement's normalised innovation; beyond
        it the filter rejects the measurement (0, the default: no gate — a filter
        that lags an unmodelled torque sees large innovations, and a gate then
        rejects most of its measurements: LQG on unknown-torque.toml 0.46° → 1.38°).
    innovation_gate_max_rejections : after this many rejections in a row a sensor's
        next measurement is taken whatever its innovation (a drifted filter must
        not lock its sensors out).

    Design (paper B's weights, from the requirement and the actuator):
    pointing_requirement_deg : the pointing requirement (paper B: ±0.1°).
    lqr_attitude_deg, lqr_rate_deg_s : Bryson scales of the attitude and rate errors.
    lqr_torque_fraction : Bryson torque scale as a fraction of the wheels' maximum
        torque: the proportional torque at ``lqr_attitude_deg`` of error.
    slew_torque_fraction, slew_momentum_fraction : the rate limit of a large-angle
        slew leaves this share of the torque (and of the momentum) to the wheels.
    disturbances_known_to_filter : False (paper B): SRP, tides and J2 are unknown
        to the filter and enter as process noise.
    filter_disturbance_budget_deg : the filter's lag on the worst-case unknown
        torque allowed by its process noise (see ``sim.default_filter_psd``).
    filter_torque_bound : that worst-case torque, N·m, as the designer assumes it;
        0 derives it from the disturbance model (SRP, tides, constant torque).
    filter_disturbance_state : what the filter estimates of the torque it does not
        model, as a random walk that its model adds and the controller cancels
        (disturbance accommodation, see ``ekf``): ``"srp"`` solar pressure through
        an unknown centre of pressure (a lever arm, N·m, acting with the Sun's
        direction and the sunlit fraction); ``"torque"`` a constant body torque;
        ``"torque+srp"`` both (12 states); ``"none"`` the 6-state filter with the
        unknown torque as inflated rate noise (paper B).
    filter_torque_drift_s, filter_srp_drift_s : the time over which each of those
        random walks may drift by the designer's torque bound, s (a year and a
        day; see ``sim.disturbance_psd``).
    ltr_bandwidth_factor : LTR's fictitious noise puts the filter's bandwidth at
        this multiple of the LQR loop's crossover at ρ = 1.

    Momentum management (thrusters; magnetic torquers are too weak at GEO):
    momentum_unloading : on/off.  thruster_torque : N·m about each axis.
    thruster_min_pulse_s : minimum impulse bit as an on-time, s.
    unload_start_fraction, unload_stop_fraction : wheel momentum (share of the
        limit) that starts and ends an unloading window.
    unload_pulse_period_s : s between pulses.  unload_recovery_s : s after a
        window still counted as "during desaturation".

    Sensors GEO satellites fly besides sun and earth sensors (``rwlab.attitude.sensors``):
    gyro : GyroModel or None — gyros; with them the filter is the gyro-driven MEKF
        (Lefferts–Markley–Shuster: attitude + gyro bias), the dynamics model unused.
    star_tracker : StarTrackerModel or None — a star tracker's attitude updates.
    filter_sun_sensor_alignment : with gyros, the filter also estimates the sun sensor's
        misalignment relative to the earth sensor (the pointing reference) — in-flight
        calibration; about z it cannot be told from yaw and stays at its prior (carried
        as uncertainty).
    filter_earth_sensor_alignment : with the above, the earth sensor's turn too, as
        consider states at their prior (it is the pointing reference: unobservable, but
        the filter's covariance then carries its bias instead of being overconfident).
    filter_inertia : the inertia the filter's dynamics model uses (3 or 9 values;
        empty: the truth's) — the model error of a flight filter.
    wheel_torque_scale : realised wheel torque over the command (1: exact).

    r4sky additions (wheels, momentum):
    wheel_stiction : for the "physics" wheels, the twin's friction law at low speed
        (breakaway + Stribeck + Coulomb + viscous, stuck at rest until the motor beats
        the breakaway torque; ``rwlab.attitude.wheels``); False: Coulomb + viscous only.
    wheel_friction_factor : the true friction over what the drive's feed-forward assumes
        (a worn or cold bearing; "physics" wheels).
    momentum_bias : N·m·s the wheels are held at, off zero speed (0: none): with four
        wheels along the null vector of G (no body momentum, no torque; a slow null-space
        loop holds it), with three orthogonal wheels on the pitch wheel (the target the
        unloading steers to); see ``sim.bias_momenta``.
    """

    name: str = "custom"
    inertia: tuple = (1200.0, 1000.0, 1500.0)
    wheel_axes: str = "orthogonal"
    wheel_inertia: float = 0.08
    wheel_max_torque: float = 0.2
    wheel_max_momentum: float = 50.0
    wheel_max_speed_rpm: float = 6000.0
    wheel_model: str = "ideal"
    wheel_model_file: str | None = None
    wheel_faults: tuple = ()
    disturbances: DisturbanceModel = field(default_factory=DisturbanceModel)
    sun: str = "fixed"
    sun_declination_deg: float = 10.0
    sun_phase_deg: float = 40.0
    sun_noise_deg: float = 0.02
    earth_noise_deg: float = 0.05
    sun_fov_deg: float = 180.0
    noise_margin: float = 1.3
    process_noise_torque: float = 1e-5
    dt: float = 0.1
    sensor_period: float = 0.5
    initial_error_deg: float = 2.0
    initial_axis: tuple = (1.0, 0.5, -0.3)
    initial_rate: tuple = (1e-4, 0.0, 0.0)
    estimator_error_deg: float = 1.0
    duration: float = 3600.0
    seed: int = 0
    epoch: str | None = None
    station_longitude_deg: float = 0.0
    sun_noise_incidence: bool = False
    earth_sensor_sun_exclusion_deg: float = 12.0
    earth_sensor_moon_exclusion_deg: float = 10.0
    sun_sensor_bias_deg: tuple = (0.0, 0.0)
    sun_sensor_misalignment_deg: tuple = (0.0, 0.0, 0.0)
    earth_sensor_bias_deg: tuple = (0.0, 0.0)
    earth_sensor_misalignment_deg: tuple = (0.0, 0.0, 0.0)
    innovation_gate: float = 0.0
    innovation_gate_max_rejections: int = 10
    pointing_requirement_deg: float = 0.1
    lqr_attitude_deg: float = 0.1
    lqr_rate_deg_s: float = 0.05
    lqr_torque_fraction: float = 0.1
    slew_torque_fraction: float = 0.5
    slew_momentum_fraction: float = 0.25
    disturbances_known_to_filter: bool = False
    filter_disturbance_budget_deg: float = 0.02
    filter_torque_bound: float = 0.0
    filter_disturbance_state: str = "torque+srp"
    filter_torque_drift_s: float = 3.156e7
    filter_srp_drift_s: float = 86400.0
    ltr_bandwidth_factor: float = 2.5
    momentum_unloading: bool = True
    thruster_torque: float = 1.2  # a 1 N hydrazine thruster at 1.2 m
    thruster_min_pulse_s: float = 0.015
    unload_start_fraction: float = 0.5
    unload_stop_fraction: float = 0.1
    unload_pulse_period_s: float = 2.0
    unload_recovery_s: float = 300.0
    gyro: GyroModel | None = None
    star_tracker: StarTrackerModel | None = None
    filter_inertia: tuple = ()
    wheel_torque_scale: float = 1.0
    filter_sun_sensor_alignment: bool = True
    filter_earth_sensor_alignment: bool = True
    # r4sky additions (section: wheels)
    wheel_stiction: bool = True
    wheel_friction_factor: float = 1.0
    # r4sky additions (section: momentum)
    momentum_bias: float = 0.0

    def __post_init__(self) -> None:
        _check_types(self)
        _check_r4sky(self)
        _check_attitude_sensors(self)
        J = self.inertia_matrix
        if not np.allclose(J, J.T) or np.any(np.linalg.eigvalsh(J) <= 0):
            raise ConfigError(f"{self.name}: inertia must be symmetric positive definite")
        Jf = self.filter_inertia_matrix
        if not np.allclose(Jf, Jf.T) or np.any(np.linalg.eigvalsh(Jf) <= 0):
            raise ConfigError(f"{self.name}: filter_inertia must be symmetric positive definite")
        ev = np.linalg.eigvalsh(J)
        if ev[2] > ev[0] + ev[1] + 1e-9:
            raise ConfigError(f"{self.name}: inertia violates the triangle inequality")
        for name, allowed in (
            ("wheel_axes", ("orthogonal", "pyramid")),
            ("wheel_model", ("ideal", "physics", "identified")),
            ("sun", ("fixed", "moving")),
            ("filter_disturbance_state", ("torque+srp", "srp", "torque", "none")),
        ):
            if getattr(self, name) not in allowed:
                raise ConfigError(
                    f"{self.name}: {name} must be one of {allowed}, got {getattr(self, name)!r}"
                )
        if self.wheel_model == "identified" and not self.wheel_model_file:
            raise ConfigError("wheel_model 'identified' needs wheel_model_file = model.json")
        _check_wheel_faults(self)
        for name in _POSITIVE:
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ConfigError(f"{self.name}: {name} must be a positive number, got {value!r}")
        for name in _FRACTIONS:
            value = getattr(self, name)
            if not 0 < value <= 1:
                raise ConfigError(f"{self.name}: {name} must be in (0, 1], got {value!r}")
        if not self.unload_stop_fraction < self.unload_start_fraction:
            raise ConfigError(f"{self.name}: unload_stop_fraction must be < unload_start_fraction")
        for name in (
            "process_noise_torque",
            "initial_error_deg",
            "estimator_error_deg",
            "filter_torque_bound",
        ):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ConfigError(f"{self.name}: {name} must be ≥ 0")
        if np.linalg.norm(self.initial_axis) == 0:
            raise ConfigError(f"{self.name}: initial_axis must not be the zero vector")
        h_speed = self.wheel_inertia * self.wheel_max_speed_rpm * math.pi / 30
        if self.wheel_max_momentum > h_speed * (1 + 1e-9):
            raise ConfigError(
                f"{self.name}: wheel_max_momentum exceeds wheel_inertia × wheel_max_speed_rpm"
            )
        if self.wheel_max_torque * self.dt > self.wheel_max_momentum:
            raise ConfigError(
                f"{self.name}: wheel_max_torque × dt exceeds wheel_max_momentum "
                "(the wheel would saturate within one step)"
            )
        self._check_sky()
        if abs(self.sensor_period / self.dt - round(self.sensor_period / self.dt)) > 1e-9:
            raise ConfigError("sensor_period must be a whole number of dt")

    def _check_sky(self) -> None:
        if self.epoch is not None:
            from rwlab.attitude.ephemeris import parse_epoch

            if not isinstance(self.epoch, str):
                raise ConfigError(f"{self.name}: epoch must be an ISO 8601 string")
            parse_epoch(self.epoch)
        if not -180 <= self.station_longitude_deg <= 360:
            raise ConfigError(f"{self.name}: station_longitude_deg must be in [-180, 360]")
        for name in (
            "earth_sensor_sun_exclusion_deg",
            "earth_sensor_moon_exclusion_deg",
            "innovation_gate",
        ):
            if getattr(self, name) < 0:
                raise ConfigError(f"{self.name}: {name} must be ≥ 0")
        if self.sun_noise_incidence and self.sun_fov_deg >= 90:
            raise ConfigError(f"{self.name}: sun_noise_incidence needs sun_fov_deg < 90")

    @property
    def filter_inertia_matrix(self) -> np.ndarray:
        """The inertia the filter's model uses, kg·m²: ``filter_inertia``, else the truth's."""
        if not self.filter_inertia:
            return self.inertia_matrix
        v = np.asarray(self.filter_inertia, dtype=float)
        return np.diag(v) if v.size == 3 else v.reshape(3, 3)

    @property
    def inertia_matrix(self) -> np.ndarray:
        v = np.asarray(self.inertia, dtype=float)
        if v.size == 3:
            return np.diag(v)
        if v.size == 9:
            return v.reshape(3, 3)
        raise ConfigError(f"inertia needs 3 (diagonal) or 9 values, got {v.size}")

    @property
    def wheel_matrix(self) -> np.ndarray:
        """G (3×N): the wheels' spin axes in body axes."""
        if self.wheel_axes == "orthogonal":
            return np.eye(3)
        c = 1 / math.sqrt(3)  # pyramid: each axis 54.74° from +z
        return np.array([[c, -c, -c, c], [c, c, -c, -c], [c, c, c, c]])

    @property
    def n_wheels(self) -> int:
        return self.wheel_matrix.shape[1]

    def with_(self, **changes) -> Scenario:
        return replace(self, **changes)


_POSITIVE = (
    "wheel_torque_scale",
    "filter_torque_drift_s",
    "filter_srp_drift_s",
    "wheel_inertia",
    "wheel_max_torque",
    "wheel_max_momentum",
    "wheel_max_speed_rpm",
    "sun_noise_deg",
    "earth_noise_deg",
    "noise_margin",
    "dt",
    "sensor_period",
    "duration",
    "sun_fov_deg",
    "pointing_requirement_deg",
    "lqr_attitude_deg",
    "lqr_rate_deg_s",
    "filter_disturbance_budget_deg",
    "ltr_bandwidth_factor",
    "thruster_torque",
    "thruster_min_pulse_s",
    "unload_pulse_period_s",
    "unload_recovery_s",
)
_FRACTIONS = (
    "lqr_torque_fraction",
    "slew_torque_fraction",
    "slew_momentum_fraction",
    "unload_start_fraction",
    "unload_stop_fraction",
)
_VECTORS = {
    "inertia": (3, 9),
    "filter_inertia": (0, 3, 9),
    "initial_axis": (3,),
    "initial_rate": (3,),
    "sun_sensor_bias_deg": (2,),
    "sun_sensor_misalignment_deg": (3,),
    "earth_sensor_bias_deg": (2,),
    "earth_sensor_misalignment_deg": (3,),
}


_FAULT_KEYS = {
    "friction": "a factor > 0",
    "torque_constant": "a factor ≥ 0",
    "current_limit": "A ≥ 0",
}


def _check_r4sky(sc: Scenario) -> None:
    """The wheel-friction and momentum-bias fields."""
    f = sc.wheel_friction_factor
    if not _is_number(f) or f <= 0:
        raise ConfigError(f"{sc.name}: wheel_friction_factor must be a number > 0, got {f!r}")
    b = sc.momentum_bias
    room = (1 - sc.unload_start_fraction) * sc.wheel_max_momentum  # bias + the window's swing
    if not _is_number(b) or not abs(b) < room:
        raise ConfigError(
            f"{sc.name}: momentum_bias must be a number (N·m·s) below (1 − unload_start_fraction)"
            f" × wheel_max_momentum ({room:g}), got {b!r}"
        )


def _check_wheel_faults(sc: Scenario) -> None:
    """Each fault names an existing wheel, a start time and at least one known change."""
    if not isinstance(sc.wheel_faults, (tuple, list)):
        raise ConfigError(f"{sc.name}: wheel_faults must be a list of tables")
    if sc.wheel_faults and sc.wheel_model != "physics":
        raise ConfigError(f"{sc.name}: wheel_faults need wheel_model = 'physics'")
    for f in sc.wheel_faults:
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
    if sc.gyro is not None and not isinstance(sc.gyro, GyroModel):
        raise ConfigError(f"{sc.name}: gyro must be a GyroModel (a [gyro] table) or absent")
    st = sc.star_tracker
    if st is None:
        return
    if not isinstance(st, StarTrackerModel):
        raise ConfigError(f"{sc.name}: star_tracker must be a StarTrackerModel or absent")
    ratio = st.period_s / sc.sensor_period
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(
            f"{sc.name}: star_tracker.period_s must be a whole multiple of sensor_period "
            f"({sc.sensor_period:g} s), got {st.period_s:g}"
        )


def _check_types(sc: Scenario) -> None:
    """Every field of the type its default has (numbers finite), vectors of the right length."""
    for f in fields(sc):
        value, default = getattr(sc, f.name), f.default
        if f.name in ("gyro", "star_tracker"):
            continue  # _check_attitude_sensors
        if f.name in _VECTORS:
            ok = isinstance(value, (tuple, list)) and len(value) in _VECTORS[f.name]
            ok = ok and all(_is_number(v) for v in value)
            if not ok:
                sizes = " or ".join(str(n) for n in _VECTORS[f.name])
                raise ConfigError(f"{sc.name}: {f.name} must be a list of {sizes} numbers")
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{sc.name}: {f.name} must be true or false, got {value!r}")
        elif isinstance(default, float):
            if not _is_number(value):
                raise ConfigError(f"{sc.name}: {f.name} must be a number, got {value!r}")
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ConfigError(f"{sc.name}: {f.name} must be a whole number ≥ 0, got {value!r}")
        elif isinstance(default, str) and not isinstance(value, str):
            raise ConfigError(f"{sc.name}: {f.name} must be a string, got {value!r}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


SCENARIOS = {
    "geo-smallsat": Scenario(
        name="geo-smallsat",
        inertia=(14.0, 12.0, 10.0),
        wheel_inertia=4.2e-4,
        wheel_max_torque=0.015,
        wheel_max_momentum=4.2e-4 * 7800 * 2 * math.pi / 60,
        wheel_max_speed_rpm=7800.0,
        disturbances=DisturbanceModel(srp_area=1.5, srp_offset=(0.05, -0.03, 0.08)),
        process_noise_torque=2e-7,
        dt=0.1,
        sensor_period=0.5,
        # the RW90's torque is ample for 12 kg·m²: the bandwidth is held to ~0.25 rad/s so
        # that the 2 Hz sensors' noise is averaged (0.1 would cross at 0.48 rad/s)
        lqr_torque_fraction=0.03,
        thruster_torque=0.02,  # 50 mN cold gas at 0.4 m
        unload_pulse_period_s=2.0,
    ),
    "geo-comsat": Scenario(name="geo-comsat"),
    # geo-comsat with the sensors GEO comsats fly for the eclipses: gyros driving the filter
    # (sun and earth sensors as before); and with a star tracker besides
    "geo-comsat-gyro": Scenario(name="geo-comsat-gyro", gyro=GyroModel()),
    "geo-comsat-star": Scenario(
        name="geo-comsat-star", gyro=GyroModel(), star_tracker=StarTrackerModel()
    ),
}
# the smallsat with four RW90 in a pyramid: any three still span the body (a wheel may fail)
SCENARIOS["geo-smallsat-pyramid"] = replace(
    SCENARIOS["geo-smallsat"], name="geo-smallsat-pyramid", wheel_axes="pyramid"
)


def _sensor_tables(raw: dict, base: Scenario, path: Path) -> dict:
    """[gyro] and [star_tracker] tables: the sensor flies, its keys over the defaults (or over
    the base scenario's unit); ``fly = false`` removes the base's."""
    out: dict = {}
    for key, cls in (("gyro", GyroModel), ("star_tracker", StarTrackerModel)):
        if key not in raw:
            continue
        table = raw[key]
        if not isinstance(table, dict):
            raise ConfigError(f"{path}: [{key}] must be a table")
        table = dict(table)
        if table.pop("fly", True) is False:
            out[key] = None
            continue
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ConfigError(f"{path}: unknown key(s) {[f'{key}.{k}' for k in unknown]}")
        for k, v in table.items():
            if isinstance(v, list):
                table[k] = tuple(v)
        current = getattr(base, key) or cls()
        try:
            out[key] = replace(current, **table)
        except TypeError as exc:
            raise ConfigError(f"{path}: [{key}]: {exc}") from None
    return out


def load_scenario(name_or_path: str, **overrides) -> Scenario:
    """A built-in scenario by name, or a TOML file (``[scenario]`` and ``[disturbances]``).

    Parameters
    ----------
    name_or_path : str
        ``"geo-smallsat"``, ``"geo-comsat"`` or a TOML file.
    **overrides
        Fields to change after loading.

    Returns
    -------
    Scenario
    """
    if name_or_path in SCENARIOS:
        base = SCENARIOS[name_or_path]
        return replace(base, **overrides) if overrides else base
    path = Path(name_or_path)
    if not path.is_file():
        raise ConfigError(
            f"unknown scenario {name_or_path!r}: not one of {sorted(SCENARIOS)} and no such file"
        )
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    if not raw or not any(raw.values()):
        raise ConfigError(
            f"{path}: the scenario file is empty; give a [scenario] table (base = "
            f"{' or '.join(map(repr, sorted(SCENARIOS)))} and the values that differ)"
        )
    if not isinstance(raw.get("scenario", {}), dict) or not isinstance(
        raw.get("disturbances", {}), dict
    ):
        raise ConfigError(f"{path}: [scenario] and [disturbances] must be tables")
    table = dict(raw.get("scenario", {}))
    base_name = table.pop("base", None)
    if base_name is not None and base_name not in SCENARIOS:
        raise ConfigError(f"{path}: base = {base_name!r} is not one of {sorted(SCENARIOS)}")
    base = SCENARIOS[base_name] if base_name else Scenario()
    known = {f.name for f in fields(Scenario)} - {"disturbances"}
    unknown = sorted(set(table) - known)
    dist = raw.get("disturbances", {})
    dist_known = {f.name for f in fields(DisturbanceModel)}
    unknown += sorted(f"disturbances.{k}" for k in set(dist) - dist_known)
    extra = sorted(set(raw) - {"scenario", "disturbances", "gyro", "star_tracker"})
    if unknown or extra:
        raise ConfigError(f"{path}: unknown key(s) {unknown + extra}")
    if isinstance(table.get("wheel_faults"), list):
        table["wheel_faults"] = tuple(table["wheel_faults"])
    for key in _VECTORS:
        if isinstance(table.get(key), list):
            table[key] = tuple(table[key])
    if isinstance(table.get("epoch"), datetime):  # TOML's own date-time type
        table["epoch"] = table["epoch"].isoformat()
    for key in ("srp_offset", "constant_torque"):
        if key in dist:
            v = dist[key]
            if not (isinstance(v, list) and len(v) == 3 and all(map(_is_number, v))):
                raise ConfigError(f"{path}: disturbances.{key} must be a list of 3 numbers")
            dist[key] = tuple(dist[key])
    for key, value in dist.items():
        default = getattr(base.disturbances, key)
        if isinstance(default, bool) and not isinstance(value, bool):
            raise ConfigError(f"{path}: disturbances.{key} must be true or false")
        if isinstance(default, float) and not (_is_number(value) and value >= 0):
            raise ConfigError(f"{path}: disturbances.{key} must be a number ≥ 0")
    model_file = table.get("wheel_model_file")
    if isinstance(model_file, str) and not Path(model_file).is_absolute():
        table["wheel_model_file"] = str(path.parent / model_file)  # relative to the file
    sensors = _sensor_tables(raw, base, path)
    return replace(
        base,
        **sensors,
        name=str(table.pop("name", path.stem)),
        disturbances=replace(base.disturbances, **dist),
        **table,
        **overrides,
    )
