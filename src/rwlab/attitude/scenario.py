"""Named, validated simulation scenarios (paper B's numbers are illegible: documented defaults).

Two built-ins:

- ``geo-smallsat`` — a 150 kg GEO smallsat (J ≈ diag(14, 12, 10) kg·m²) with
  three orthogonal RW90 wheels (the wheel on our testbed: 0.34 N·m·s,
  7800 rpm, 0.015 N·m), 1.5 m² of arrays;
- ``geo-comsat`` — a comsat (J = diag(1200, 1000, 1500) kg·m², as in the
  Basilisk peer scenario) with three HR16-class wheels (50 N·m·s, 0.2 N·m,
  6000 rpm) and 30 m² of arrays.

Sensors: sun sensor 0.02°, earth sensor 0.05° (1σ, typical units); the filter
assumes 30 % more (paper B). A scenario file is TOML with the same keys; unknown
keys and bad values are errors.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from rwlab.attitude.plant import DisturbanceModel
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

    def __post_init__(self) -> None:
        J = self.inertia_matrix
        if not np.allclose(J, J.T) or np.any(np.linalg.eigvalsh(J) <= 0):
            raise ConfigError(f"{self.name}: inertia must be symmetric positive definite")
        ev = np.linalg.eigvalsh(J)
        if ev[2] > ev[0] + ev[1] + 1e-9:
            raise ConfigError(f"{self.name}: inertia violates the triangle inequality")
        if self.wheel_axes not in ("orthogonal", "pyramid"):
            raise ConfigError(
                f"wheel_axes must be 'orthogonal' or 'pyramid', got {self.wheel_axes!r}"
            )
        if self.wheel_model not in ("ideal", "physics", "identified"):
            raise ConfigError(
                f"wheel_model must be ideal, physics or identified, got {self.wheel_model!r}"
            )
        if self.wheel_model == "identified" and not self.wheel_model_file:
            raise ConfigError("wheel_model 'identified' needs wheel_model_file = model.json")
        if self.sun not in ("fixed", "moving"):
            raise ConfigError(f"sun must be 'fixed' or 'moving', got {self.sun!r}")
        for name in (
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
        ):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"{self.name}: {name} must be a positive number, got {value!r}")
        if self.process_noise_torque < 0:
            raise ConfigError("process_noise_torque must be ≥ 0")
        if abs(self.sensor_period / self.dt - round(self.sensor_period / self.dt)) > 1e-9:
            raise ConfigError("sensor_period must be a whole number of dt")

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
    ),
    "geo-comsat": Scenario(name="geo-comsat"),
}


def load_scenario(name_or_path: str, **overrides) -> Scenario:
    """A built-in scenario by name, or a TOML file (``[scenario]`` and ``[disturbances]``)."""
    if name_or_path in SCENARIOS:
        base = SCENARIOS[name_or_path]
        return replace(base, **overrides) if overrides else base
    path = Path(name_or_path)
    if not path.is_file():
        raise ConfigError(
            f"unknown scenario {name_or_path!r}: not one of {sorted(SCENARIOS)} and no such file"
        )
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    table = dict(raw.get("scenario", {}))
    base = SCENARIOS.get(table.pop("base", ""), Scenario())
    known = {f.name for f in fields(Scenario)} - {"disturbances"}
    unknown = sorted(set(table) - known)
    dist = raw.get("disturbances", {})
    dist_known = {f.name for f in fields(DisturbanceModel)}
    unknown += sorted(f"disturbances.{k}" for k in set(dist) - dist_known)
    extra = sorted(set(raw) - {"scenario", "disturbances"})
    if unknown or extra:
        raise ConfigError(f"{path}: unknown key(s) {unknown + extra}")
    for key in ("inertia", "initial_axis", "initial_rate"):
        if key in table:
            table[key] = tuple(table[key])
    for key in ("srp_offset", "constant_torque"):
        if key in dist:
            dist[key] = tuple(dist[key])
    return replace(
        base,
        name=table.pop("name", path.stem),
        disturbances=replace(base.disturbances, **dist),
        **table,
        **overrides,
    )
