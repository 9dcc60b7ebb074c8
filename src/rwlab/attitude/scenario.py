"""Named, validated simulation scenarios (paper B's numbers are illegible: documented defaults).

Three built-ins:

- ``geo-smallsat`` — a 150 kg GEO smallsat (J ≈ diag(14, 12, 10) kg·m²) with
  three orthogonal RW90 wheels (the wheel on our testbed, its spec ``rw90``),
  1.5 m² of arrays;
- ``geo-smallsat-pyramid`` — the same with four RW90 in a pyramid (54.74° from z);
- ``geo-comsat`` — a comsat (J = diag(1200, 1000, 1500) kg·m², as in the
  Basilisk peer scenario) with four NRWA-T6-class wheels in a pyramid (spec
  ``nrwa-t6``: ~6 N·m·s, 0.31 N·m, 5000 rpm) and 30 m² of arrays;
- ``geo-cubesat`` — a 12U CubeSat (J = diag(0.25, 0.22, 0.12) kg·m²) with three
  orthogonal RW-0.01 wheels (spec ``rw-0.01``: 18 mN·m·s, 1 mN·m), 0.3 m² of arrays
  and CubeSat-grade sensors: sun 0.1°, earth 0.33° (1σ; datasheet classes cited at
  ``_CUBESAT_SENSORS``).

Each wheel section names its wheel model (``wheels.spec``) and what the mission
needs of it (``wheels.required_torque_nm``, ``wheels.required_momentum_nms``); a
wheel model that cannot deliver that is refused (:mod:`rwlab.attitude.wheel_fit`).

Sensors: sun sensor 0.02°, earth sensor 0.05° (1σ, comsat units; the CubeSat's are
coarser); the filter
assumes 30 % more (paper B). Two more built-ins fly the sensors real GEO comsats
carry through the eclipses (``rwlab.attitude.sensors``): ``geo-comsat-gyro``
(gyros drive the filter: the Lefferts–Markley–Shuster MEKF) and
``geo-comsat-star`` (gyros and a star tracker).

A :class:`Scenario` is a name and eight sections — :class:`Spacecraft`,
:class:`Wheels`, :class:`Sensors`, :class:`Sky`, :class:`FilterDesign`,
:class:`ControlDesign`, :class:`Momentum`, :class:`RunSettings` — reached as
``sc.wheels.max_torque``; ``sc.with_(**{"wheels.spec": "rw90"})`` changes
fields by their dotted names. A scenario file is TOML with one table per section::

    [scenario]
    base = "geo-comsat"          # the built-in to start from
    name = "my-comsat"
    [wheels]
    spec = "my-wheel.toml"       # a wheel model: a preset or a wheel spec file
    axes = "pyramid"
    [spacecraft.disturbances]
    constant_torque = [1e-3, 0.0, 0.0]
    [sensors.gyro]               # gyros fly (their keys over GyroModel's defaults)

Unknown keys and bad values are errors. The flat files of earlier versions (every
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

from rwlab._toml import unknown_keys
from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.scenario_checks import check, is_number
from rwlab.attitude.sections import (
    LEGACY_NAMES,
    SECTIONS,
    ControlDesign,
    FilterDesign,
    Momentum,
    RunSettings,
    Sensors,
    Sky,
    Spacecraft,
    Wheels,
)
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
        check(self)

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
    if not is_dataclass(obj) or isinstance(obj, type) or head not in {f.name for f in fields(obj)}:
        raise ConfigError(f"unknown scenario field {full!r}; {_FIELD_HINT}")
    new = _set_path(getattr(obj, head), rest, value, full) if rest else value
    if isinstance(obj, Wheels) and head == "spec" and new != obj.spec:
        return obj.with_spec(new)
    return replace(obj, **{head: new})


# What each mission needs of its wheels about any axis (the wheel models are checked
# against it: rwlab.attitude.wheel_fit). Momentum: the worst solar-pressure torque,
# 4.56e-6 N/m² × area × reflectivity 1.3 × |centre-of-pressure offset|, held for a
# quarter of a day (21600 s) between unloads.
_COMSAT_WHEELS = Wheels(
    spec="nrwa-t6",
    axes="pyramid",
    required_torque_nm=0.1,
    required_momentum_nms=2.4,
    required_torque_source=(
        "geo-comsat: assumed, because paper B gives none: a 3-t comsat's station-keeping burn "
        "misaligned by ~0.1 N·m"
    ),
    required_momentum_source="geo-comsat: SRP 4.56e-6 × 30 m² × 1.3 × 0.62 m for 21600 s",
)
_SMALLSAT_WHEELS = Wheels(
    spec="rw90",
    axes="orthogonal",
    required_torque_nm=0.005,
    required_momentum_nms=0.02,
    required_torque_source="geo-smallsat: assumed: a 20-mN cold-gas burn misaligned by 0.25 m",
    required_momentum_source="geo-smallsat: SRP 4.56e-6 × 1.5 m² × 1.3 × 0.1 m for 21600 s",
)
_CUBESAT_WHEELS = Wheels(
    spec="rw-0.01",
    axes="orthogonal",
    required_torque_nm=2e-4,
    required_momentum_nms=2e-3,
    required_torque_source="geo-cubesat: assumed: a 1-mN thruster misaligned by 0.2 m",
    required_momentum_source=(
        "geo-cubesat: SRP 4.56e-6 × 0.3 m² × 1.3 × 0.037 m for 21600 s, 40 % margin"
    ),
)
# CubeSat-grade sensors (the comsat's 0.02° / 0.05° are flight units of a 3-t comsat):
# - sun: a CubeSat fine sun sensor, NewSpace Systems NFSS-411 class (datasheet: accuracy
#   < 0.1° RMS over its 140° field, 5 Hz); heads enough for the whole sky, as that
#   datasheet's "four sensors achieve full sky coverage";
# - earth: a thermopile horizon sensor for small satellites, Optical Energy Technologies
#   class (G. Falbel, "A low weight/power/cost infrared Earth sensor", IEEE Aerospace
#   Conference 2004, doi:10.1109/AERO.2004.1368068: ±1° readout accuracy, read as 3σ).
# geo-cubesat flies no gyro (its filter is the dynamics-model EKF): no gyro noise to set.
_CUBESAT_SENSORS = Sensors(sun_noise_deg=0.1, earth_noise_deg=0.33)
SCENARIOS = {
    "geo-smallsat": Scenario(
        name="geo-smallsat",
        spacecraft=Spacecraft(
            inertia=(14.0, 12.0, 10.0),
            process_noise_torque=2e-7,
            disturbances=DisturbanceModel(srp_area=1.5, srp_offset=(0.05, -0.03, 0.08)),
        ),
        wheels=_SMALLSAT_WHEELS,
        # the RW90's torque is ample for 12 kg·m²: the bandwidth is held to ~0.25 rad/s so
        # that the 2 Hz sensors' noise is averaged (0.1 would cross at 0.48 rad/s)
        control=ControlDesign(lqr_torque_fraction=0.03),
        momentum=Momentum(thruster_torque=0.02),  # 50 mN cold gas at 0.4 m
    ),
    # four NRWA-T6-class wheels in a pyramid (any three still span the body)
    "geo-comsat": Scenario(name="geo-comsat", wheels=_COMSAT_WHEELS),
    # geo-comsat with the sensors GEO comsats fly for the eclipses: gyros driving the filter
    # (sun and earth sensors as before); and with a star tracker besides
    "geo-comsat-gyro": Scenario(
        name="geo-comsat-gyro", wheels=_COMSAT_WHEELS, sensors=Sensors(gyro=GyroModel())
    ),
    "geo-comsat-star": Scenario(
        name="geo-comsat-star",
        wheels=_COMSAT_WHEELS,
        sensors=Sensors(gyro=GyroModel(), star_tracker=StarTrackerModel()),
    ),
    # a 12U CubeSat (~20 kg) in GEO on three RW-0.01 wheels, its arrays 0.3 m²
    "geo-cubesat": Scenario(
        name="geo-cubesat",
        spacecraft=Spacecraft(
            inertia=(0.25, 0.22, 0.12),
            process_noise_torque=3e-9,
            disturbances=DisturbanceModel(srp_area=0.3, srp_offset=(0.02, -0.01, 0.03)),
        ),
        wheels=_CUBESAT_WHEELS,
        sensors=_CUBESAT_SENSORS,
        # the same ~0.25 rad/s bandwidth as the smallsat's for the 2 Hz sensors
        control=ControlDesign(lqr_torque_fraction=0.03),
        momentum=Momentum(thruster_torque=2e-4),  # a 1 mN cold-gas thruster at 0.2 m
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
    unknown = unknown_keys(scenario, [*LEGACY_NAMES, "base", "name"])
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


_WHEEL_LIMITS = ("inertia", "max_torque", "max_momentum", "max_speed_rpm")


def _section_changes(table: dict, section: str, base: Scenario, path: Path) -> dict:
    """One section table of a file → ``with_`` changes; anything unknown is an error."""
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: [{section}] must be a table")
    known = [f"{section}.{f.name}" for f in fields(SECTIONS[section])]
    unknown = unknown_keys((f"{section}.{k}" for k in table), known)
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}")
    changes: dict[str, Any] = {}
    own = sorted(set(table) & set(_WHEEL_LIMITS)) if section == "wheels" else []
    if own:
        warnings.warn(
            f"{path}: [wheels] {', '.join(own)} are the wheel model's numbers: name the model "
            "(wheels.spec = a preset from `rwlab wheel models`, or a wheel spec file) and "
            "leave them out; the values given here override the spec's",
            FormatWarning,
            stacklevel=3,
        )
    for key, value in table.items():
        name = f"{section}.{key}"
        if name in _SUBTABLES:
            changes[name] = _subtable(value, name, base, path)
        elif name == "sky.epoch" and isinstance(value, datetime):  # TOML's date-time type
            changes[name] = value.isoformat()
        elif name in ("wheels.model_file", "wheels.spec") and isinstance(value, str):
            relative = path.parent / value  # a file relative to the scenario (or absolute)
            changes[name] = str(relative) if relative.is_file() else value
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
    known = [f"{name}.{f.name}" for f in fields(cls)]
    unknown = unknown_keys((f"{name}.{k}" for k in table), known)
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}")
    current = base.get(name) or cls()
    for key, value in table.items():
        default = getattr(current, key)
        if isinstance(value, list):
            if isinstance(default, tuple) and not (
                len(value) == len(default) and all(map(is_number, value))
            ):
                raise ConfigError(f"{path}: {name}.{key} must be a list of {len(default)} numbers")
            table[key] = tuple(value)
        elif cls is DisturbanceModel and isinstance(default, bool) != isinstance(value, bool):
            raise ConfigError(f"{path}: {name}.{key} must be true or false")
        elif cls is DisturbanceModel and isinstance(default, float):
            if not (is_number(value) and value >= 0):
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
    if str(path) in SCENARIOS and not path.is_file():
        raise ConfigError(
            f"{path} is a built-in scenario, already in sections; convert-scenario takes a "
            "scenario TOML file"
        )
    raw = _read_toml(path)
    if _is_flat(raw):
        raw = _sections_of_flat(raw, path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FormatWarning)
        load_scenario(str(path))  # the values must be valid before they are rewritten
    raw.setdefault("scenario", {}).setdefault("name", path.stem)  # the same name as before
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
