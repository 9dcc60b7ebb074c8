"""The sections of an attitude scenario: what each field means, its unit and default.

A :class:`rwlab.attitude.scenario.Scenario` is a name and one frozen record per
section, each a table of a scenario file: :class:`Spacecraft`, :class:`Wheels`,
:class:`Sensors`, :class:`Sky`, :class:`FilterDesign`, :class:`ControlDesign`,
:class:`Momentum` and :class:`RunSettings`. :data:`LEGACY_NAMES` maps the flat
field names of the old format to their places here. The values are checked
together when a scenario is built (``rwlab.attitude.scenario_checks``).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field, replace

from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.sensors import GyroModel, StarTrackerModel
from rwlab.wheelspec import WheelSpec

__all__ = [
    "LEGACY_NAMES",
    "SECTIONS",
    "ControlDesign",
    "FilterDesign",
    "Momentum",
    "RunSettings",
    "Sensors",
    "Sky",
    "Spacecraft",
    "Wheels",
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
    """The reaction wheels: which wheel model, how many, in what geometry.

    Attributes
    ----------
    spec : str
        The wheel model: a preset (``rwlab wheel models``: ``"nrwa-t6"``, ``"rw90"``,
        ``"rw-0.01"``), a wheel spec file, or a ``model.json`` that carries its spec.
        Its datasheet gives each wheel's inertia, torque, momentum and speed limits.
    axes : {'orthogonal', 'pyramid'}
        3 wheels on the body axes, or 4 at 54.74° from z.
    inertia, max_torque, max_momentum, max_speed_rpm : float, optional
        Rotor inertia (kg·m²), torque (N·m), momentum (N·m·s) and speed (rpm) limits:
        the spec's (None: read from it). Set only to disperse them around the spec
        (Monte Carlo); a scenario file that gives them is read with a warning.
    required_torque_nm, required_momentum_nms : float, optional
        What the mission needs of the wheel set about any body axis: torque (N·m) and
        stored momentum (N·m·s). A wheel model that cannot deliver them is refused
        (``rwlab.attitude.wheel_fit``) unless forced. None: no requirement.
    required_torque_source, required_momentum_source : str
        Where each requirement comes from.
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
    static_imbalance_kg_m, dynamic_imbalance_kg_m2 : float or tuple of float
        Each wheel's static imbalance U_s (kg·m) and dynamic imbalance U_d (kg·m²), one
        value for every wheel or one per wheel (Basilisk's simple jitter model: a force
        U_s Ω² and a torque U_d Ω² turning with the rotor; 0: a balanced wheel). None:
        the wheel spec's.
    positions_m : tuple of tuple of float
        Each wheel's centre relative to the spacecraft's centre of mass, body axes, m (the
        static imbalance's force acts there); empty: at the centre of mass.
    jitter : bool
        The imbalances act on the plant (default False: the wheels fly as perfect
        rotors, since resolving the spin needs a step of about 0.5 / Ω_max s; True for
        the relative pointing error at the wheels' spin rate).
    """

    spec: str = "nrwa-t6"
    axes: str = "pyramid"
    inertia: float = None  # type: ignore[assignment]  # None until __post_init__ reads the spec
    max_torque: float = None  # type: ignore[assignment]
    max_momentum: float = None  # type: ignore[assignment]
    max_speed_rpm: float = None  # type: ignore[assignment]
    required_torque_nm: float | None = None
    required_momentum_nms: float | None = None
    required_torque_source: str = ""
    required_momentum_source: str = ""
    model: str = "ideal"
    model_file: str | None = None
    faults: tuple = ()
    torque_scale: float = 1.0
    stiction: bool = True
    friction_factor: float = 1.0
    static_imbalance_kg_m: float | tuple = None  # type: ignore[assignment]
    dynamic_imbalance_kg_m2: float | tuple = None  # type: ignore[assignment]
    positions_m: tuple = ()
    jitter: bool = False

    def __post_init__(self) -> None:
        spec = self.wheel_spec
        for name, value in (
            ("inertia", spec.inertia_kg_m2),
            ("max_torque", spec.max_torque_nm),
            ("max_momentum", spec.momentum_capacity_nms),
            ("max_speed_rpm", spec.max_speed_rpm),
            ("static_imbalance_kg_m", spec.static_imbalance_kg_m),
            ("dynamic_imbalance_kg_m2", spec.dynamic_imbalance_kg_m2),
        ):
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)

    @property
    def wheel_spec(self) -> WheelSpec:
        """The wheel model's spec (:class:`rwlab.wheelspec.WheelSpec`)."""
        return load_wheel_spec(self.spec)

    def with_spec(self, spec: str) -> Wheels:
        """These wheels as another wheel model: its limits, not this one's.

        Parameters
        ----------
        spec : str
            A preset, a wheel spec file or a ``model.json`` (as :attr:`spec`).

        Returns
        -------
        Wheels
            The rest (geometry, model, faults, imbalances) kept.
        """
        new = load_wheel_spec(spec)
        return replace(
            self,
            spec=spec,
            inertia=new.inertia_kg_m2,
            max_torque=new.max_torque_nm,
            max_momentum=new.momentum_capacity_nms,
            max_speed_rpm=new.max_speed_rpm,
        )


def load_wheel_spec(name_or_path: str) -> WheelSpec:
    """A wheel model's spec: a preset name, a spec TOML file, or a ``model.json`` (its spec).

    Parameters
    ----------
    name_or_path : str

    Returns
    -------
    WheelSpec
    """
    from rwlab.errors import ConfigError

    if not isinstance(name_or_path, str):
        raise ConfigError(f"wheels.spec must name a wheel model, got {name_or_path!r}")
    try:  # a file is read again only when it changed (a scenario is rebuilt often)
        stat = os.stat(name_or_path)
    except OSError:
        return WheelSpec.load(name_or_path)  # a preset, or the error naming the presets
    return _load_file_spec(name_or_path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=32)
def _load_file_spec(name_or_path: str, mtime_ns: int, size: int) -> WheelSpec:
    from rwlab.errors import ConfigError

    if name_or_path.lower().endswith(".json"):
        from rwlab.ident.model_file import WheelModelFile

        spec = WheelModelFile.load(name_or_path).wheel_spec
        if spec is None:
            raise ConfigError(
                f"{name_or_path} carries no wheel spec (a version-1 model.json): give the "
                "wheel model it was identified on (wheels.spec = NAME or a spec file)"
            )
        return spec
    return WheelSpec.load(name_or_path)


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
