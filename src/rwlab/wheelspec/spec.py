"""The datasheet of a reaction-wheel model: :class:`WheelSpec`, its TOML file and loader.

One TOML file per wheel model (``presets/<name>.toml`` for the shipped ones, or a
lab's own file). Every number is an inline table with its value and where it comes
from::

    format = "rwlab.WheelSpec/1"
    name = "rw90"
    title = "RW90 reaction wheel (paper A's testbed wheel)"
    documents = ["paper A: ..., Table 1"]

    [rotor]
    inertia_kg_m2 = { value = 1.0e-3, source = "the data sheet, table 2" }

    [tolerances]
    inertia_kg_m2 = { relative = 0.02, source = "rotor machining, ±2 %" }

A ``source`` is a datasheet or ICD page, or ``"assumed, because …"``. The file's
structure is the JSON Schema ``rwlab/schemas/wheelspec.schema.json`` (checked with
``jsonschema``); the values' ranges and their consistency (a torque the current
limit can give, faults above limits) are checked here. Every failure is a
:class:`~rwlab.errors.ConfigError` naming the file and the key.

The spec sits at the bottom layer so that every layer reads the same numbers:
the twin (:meth:`rwlab.wheel.WheelParams.from_spec`), identification's
saturations, ``model.json``, the attitude loop, HIL's twin nodes, diagnosis.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tomllib
from dataclasses import dataclass, field, fields, replace
from functools import cache
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any, ClassVar

from rwlab.errors import ConfigError

__all__ = [
    "FORMAT",
    "SECTIONS",
    "TWIN_NAMES",
    "Tolerance",
    "WheelSpec",
    "preset_names",
]

KIND = "WheelSpec"
VERSION = 1
FORMAT = f"rwlab.{KIND}/{VERSION}"
RPM = 2 * math.pi / 60  # rad/s per rpm

# section → (field, kind); the order of a spec file and of the dataclass
SECTIONS: dict[str, tuple[tuple[str, type], ...]] = {
    "rotor": (
        ("inertia_kg_m2", float),
        ("static_imbalance_kg_m", float),
        ("dynamic_imbalance_kg_m2", float),
    ),
    "limits": (
        ("max_speed_rpm", float),
        ("nominal_speed_rpm", float),
        ("max_torque_nm", float),
        ("max_accel_rpm_s", float),
        ("current_limit_a", float),
        ("overspeed_fault_rpm", float),
        ("overcurrent_fault_a", float),
        ("overtemp_fault_c", float),
    ),
    "motor": (
        ("torque_constant_nm_a", float),
        ("winding_resistance_ohm", float),
        ("pole_pairs", int),
        ("torque_constant_temp_coeff", float),
        ("resistance_temp_coeff", float),
        ("cogging_torque_nm", float),
        ("cogging_periods", int),
        ("torque_ripple", float),
        ("back_emf", bool),
    ),
    "supply": (
        ("bus_voltage_v", float),
        ("bus_source_resistance_ohm", float),
        ("driver_max_duty", float),
    ),
    "friction": (
        ("coulomb_friction_nm", float),
        ("viscous_friction_nm_s", float),
        ("stiction", bool),
        ("breakaway_friction_nm", float),
        ("stribeck_speed_rpm", float),
        ("viscous_temp_coeff", float),
        ("friction_drift", float),
    ),
    "controller": (
        ("controller_mode", str),
        ("speed_kp", float),
        ("speed_ki", float),
        ("speed_setpoint_weight", float),
        ("control_rate_hz", float),
    ),
    "telemetry": (
        ("telemetry_rate_hz", float),
        ("speed_resolution_rpm", float),
        ("speed_noise_rpm", float),
        ("min_measurable_rpm", float),
        ("current_noise_a", float),
        ("current_lsb_a", float),
        ("current_offset_a", float),
        ("bus_voltage_noise_v", float),
        ("hall_speed", bool),
        ("hall_misalignment_deg", float),
        ("hall_jitter_s", float),
        ("hall_timer_hz", float),
        ("hall_window_s", float),
        ("telemetry_jitter_s", float),
        ("frame_loss_rate", float),
    ),
    "thermal": (
        ("thermal_resistance_k_w", float),
        ("thermal_time_constant_s", float),
        ("ambient_c", float),
    ),
}
_KINDS = {name: kind for section in SECTIONS.values() for name, kind in section}
_SECTION_OF = {name: s for s, section in SECTIONS.items() for name, _ in section}

# spec field → the twin's (WheelParams) field; fields of the same name map to themselves,
# the spec-only ones (imbalance, controller mode and rate, telemetry rate) are absent
TWIN_NAMES: MappingProxyType[str, str] = MappingProxyType(
    {
        **{
            name: name
            for name in _KINDS
            if name
            not in {
                "static_imbalance_kg_m",
                "dynamic_imbalance_kg_m2",
                "controller_mode",
                "control_rate_hz",
                "telemetry_rate_hz",
            }
        },
        "inertia_kg_m2": "inertia",
        "max_torque_nm": "nominal_torque",
        "current_limit_a": "current_limit",
        "overcurrent_fault_a": "overcurrent_fault",
        "torque_constant_nm_a": "torque_constant",
        "winding_resistance_ohm": "winding_resistance",
        "cogging_torque_nm": "cogging_torque",
        "bus_voltage_v": "bus_voltage",
        "bus_source_resistance_ohm": "bus_source_resistance",
        "coulomb_friction_nm": "coulomb_friction",
        "viscous_friction_nm_s": "viscous_friction",
        "breakaway_friction_nm": "breakaway_friction",
        "thermal_resistance_k_w": "thermal_resistance",
        "thermal_time_constant_s": "thermal_time_constant",
    }
)

# may be ≤ 0 (an offset, a temperature); every other number must be ≥ 0
_SIGNED = {"current_offset_a", "ambient_c", "overtemp_fault_c"}
# fields a spec file written before them may lack: the value they had implicitly then
OPTIONAL: MappingProxyType[str, dict[str, Any]] = MappingProxyType(
    {
        "speed_setpoint_weight": {
            "value": 1.0,
            "source": "assumed, because the file states none: a plain PI (setpoint weight 1)",
        },
    }
)
_ZERO_ALLOWED = {  # physical zeros a datasheet may state: none, off, perfect
    "static_imbalance_kg_m",
    "dynamic_imbalance_kg_m2",
    "torque_constant_temp_coeff",
    "resistance_temp_coeff",
    "cogging_torque_nm",
    "torque_ripple",
    "bus_source_resistance_ohm",
    "viscous_friction_nm_s",
    "coulomb_friction_nm",
    "breakaway_friction_nm",
    "viscous_temp_coeff",
    "friction_drift",
    "speed_ki",
    "speed_setpoint_weight",
    "speed_resolution_rpm",
    "speed_noise_rpm",
    "min_measurable_rpm",
    "current_noise_a",
    "current_lsb_a",
    "bus_voltage_noise_v",
    "hall_misalignment_deg",
    "hall_jitter_s",
    "telemetry_jitter_s",
    "frame_loss_rate",
}
CONTROLLER_MODES = ("speed", "torque")


@dataclass(frozen=True)
class Tolerance:
    """How far one parameter of a unit may differ from the model's nominal value.

    Attributes
    ----------
    relative : float
        Half-width of a uniform spread, a fraction of nominal (0.05: ±5 %).
    absolute : float
        Half-width of an additive uniform spread, in the parameter's unit.
    source : str
        Where the tolerance comes from.
    """

    relative: float
    absolute: float
    source: str


@dataclass(frozen=True)
class WheelSpec:
    """The datasheet of one reaction-wheel model: what every layer of rwlab reads.

    Attributes
    ----------
    name : str
        The model's short name (a preset's file name, e.g. ``"rw90"``).
    title : str
        What the wheel is, in words.
    documents : tuple of str
        The datasheets and ICDs the numbers come from.
    inertia_kg_m2 : float
        Rotor inertia about the spin axis, kg·m².
    static_imbalance_kg_m, dynamic_imbalance_kg_m2 : float
        Static (U_s, kg·m) and dynamic (U_d, kg·m²) imbalance, Basilisk's units.
    max_speed_rpm, nominal_speed_rpm : float
        Speed limit of the wheel's controller and nominal speed, rpm.
    max_torque_nm : float
        Rated (maximum commandable) motor torque, N·m.
    max_accel_rpm_s : float
        Acceleration limit of the inner controller, rpm/s.
    current_limit_a : float
        Motor current limit, A.
    overspeed_fault_rpm, overcurrent_fault_a, overtemp_fault_c : float
        Latched fault thresholds: rpm, A, °C.
    torque_constant_nm_a : float
        k_t, N·m/A.
    winding_resistance_ohm : float
        Ω at ``ambient_c``.
    pole_pairs, cogging_periods : int
        Motor pole pairs; cogging periods per revolution.
    torque_constant_temp_coeff, resistance_temp_coeff : float
        Temperature coefficients of k_t (fall) and R (rise), 1/K.
    cogging_torque_nm, torque_ripple : float
        Detent torque amplitude (N·m) and commutation ripple (fraction).
    back_emf : bool
        The current is limited by the voltage left after the back-EMF.
    bus_voltage_v, bus_source_resistance_ohm, driver_max_duty : float
        Supply voltage (V), its source resistance (Ω), largest PWM duty.
    coulomb_friction_nm, viscous_friction_nm_s, breakaway_friction_nm : float
        The friction law: τ_c (N·m), b (N·m·s/rad), τ_brk (N·m).
    stiction : bool
        Breakaway + Stribeck at low speed (else Coulomb + viscous only).
    stribeck_speed_rpm, viscous_temp_coeff, friction_drift : float
        Stribeck speed (rpm), fall of b per K (1/K), σ of friction's walk per √h.
    controller_mode : {"speed", "torque"}
        The mode the wheel is flown in by an attitude controller.
    speed_kp, speed_ki : float
        The inner PI speed loop: acceleration request per speed error (1/s, 1/s²).
    speed_setpoint_weight : float
        The inner loop's setpoint weight β (a 2-DOF PI's proportional part acts on
        β·setpoint − speed; 1: a plain PI). A file without it reads 1, said in its
        source.
    control_rate_hz : float
        Rate of the wheel's own control loop, Hz.
    telemetry_rate_hz : float
        Rate the wheel's speed telemetry is read at, Hz.
    speed_resolution_rpm, speed_noise_rpm, min_measurable_rpm : float
        Reported speed's quantum, white noise σ and slowest non-zero reading, rpm.
    current_noise_a, current_lsb_a, current_offset_a, bus_voltage_noise_v : float
        The current and bus-voltage measurements: σ, quantum, offset (A) and σ (V).
    hall_speed : bool
        Speed computed from Hall-edge times (else true speed plus noise).
    hall_misalignment_deg, hall_jitter_s, hall_timer_hz, hall_window_s : float
        The Hall sensors: edge misplacement σ (electrical °), capture jitter σ (s),
        capture clock (Hz) and averaging window (s).
    telemetry_jitter_s, frame_loss_rate : float
        Frame lateness (s, uniform) and the fraction of frames lost.
    thermal_resistance_k_w, thermal_time_constant_s, ambient_c : float
        First-order motor thermal model (K/W, s) and ambient (°C).
    tolerances : mapping of str to Tolerance
        Unit-to-unit spread of the manufacturing-dependent fields (by spec field name).
    sources : mapping of str to str
        Where each number comes from (every field above has one).
    origin : str
        What :meth:`load` read: the preset's name or the file's path ("" when built
        otherwise); not part of the spec's content (nor of its hash).
    """

    name: str
    title: str
    documents: tuple[str, ...]
    inertia_kg_m2: float
    static_imbalance_kg_m: float
    dynamic_imbalance_kg_m2: float
    max_speed_rpm: float
    nominal_speed_rpm: float
    max_torque_nm: float
    max_accel_rpm_s: float
    current_limit_a: float
    overspeed_fault_rpm: float
    overcurrent_fault_a: float
    overtemp_fault_c: float
    torque_constant_nm_a: float
    winding_resistance_ohm: float
    pole_pairs: int
    torque_constant_temp_coeff: float
    resistance_temp_coeff: float
    cogging_torque_nm: float
    cogging_periods: int
    torque_ripple: float
    back_emf: bool
    bus_voltage_v: float
    bus_source_resistance_ohm: float
    driver_max_duty: float
    coulomb_friction_nm: float
    viscous_friction_nm_s: float
    stiction: bool
    breakaway_friction_nm: float
    stribeck_speed_rpm: float
    viscous_temp_coeff: float
    friction_drift: float
    controller_mode: str
    speed_kp: float
    speed_ki: float
    speed_setpoint_weight: float
    control_rate_hz: float
    telemetry_rate_hz: float
    speed_resolution_rpm: float
    speed_noise_rpm: float
    min_measurable_rpm: float
    current_noise_a: float
    current_lsb_a: float
    current_offset_a: float
    bus_voltage_noise_v: float
    hall_speed: bool
    hall_misalignment_deg: float
    hall_jitter_s: float
    hall_timer_hz: float
    hall_window_s: float
    telemetry_jitter_s: float
    frame_loss_rate: float
    thermal_resistance_k_w: float
    thermal_time_constant_s: float
    ambient_c: float
    tolerances: MappingProxyType[str, Tolerance] = field(
        default_factory=lambda: MappingProxyType({})
    )
    sources: MappingProxyType[str, str] = field(default_factory=lambda: MappingProxyType({}))
    origin: str = field(default="", compare=False)
    # the files module builds a spec's tolerances with it (it does not import this one)
    tolerance_class: ClassVar[type] = Tolerance

    def __post_init__(self) -> None:
        # a plain dict given by a caller becomes read-only, like the rest
        object.__setattr__(self, "tolerances", MappingProxyType(dict(self.tolerances)))
        object.__setattr__(self, "sources", MappingProxyType(dict(self.sources)))
        object.__setattr__(self, "documents", tuple(self.documents))
        _check(self)

    # -- derived limits --------------------------------------------------------------
    @property
    def max_speed_rad_s(self) -> float:
        """The speed limit, rad/s."""
        return self.max_speed_rpm * RPM

    @property
    def momentum_capacity_nms(self) -> float:
        """Angular momentum at the speed limit, N·m·s."""
        return self.inertia_kg_m2 * self.max_speed_rad_s

    @property
    def motor_torque_nm(self) -> float:
        """The torque the current limit allows, k_t·i_max, N·m."""
        return self.torque_constant_nm_a * self.current_limit_a

    @property
    def accel_torque_nm(self) -> float:
        """The torque the controller's acceleration limit allows, I·α_max, N·m."""
        return self.inertia_kg_m2 * self.max_accel_rpm_s * RPM

    def source(self, name: str) -> str:
        """Where the number ``name`` comes from.

        Parameters
        ----------
        name : str
            A field name, e.g. ``"max_torque_nm"``.

        Returns
        -------
        str
            ``"<spec name> spec: <source>"``.
        """
        return f"{self.name} spec: {self.sources.get(name, 'no source given')}"

    # -- the twin ----------------------------------------------------------------------
    def twin_fields(self) -> dict[str, Any]:
        """The twin's (:class:`rwlab.wheel.WheelParams`) fields, by their names there.

        Returns
        -------
        dict
            WheelParams field name → value.
        """
        return {twin: getattr(self, name) for name, twin in TWIN_NAMES.items()}

    def twin_tolerances(self) -> dict[str, Tolerance]:
        """The unit-to-unit tolerances keyed by the twin's field names.

        Returns
        -------
        dict of str to Tolerance
        """
        return {TWIN_NAMES[name]: tol for name, tol in self.tolerances.items()}

    # -- files -------------------------------------------------------------------------
    @classmethod
    def load(cls, name_or_path: str | os.PathLike) -> WheelSpec:
        """A shipped preset by name (``"rw90"``, ``"nrwa-t6"``, ``"rw-0.01"``) or a TOML file.

        Parameters
        ----------
        name_or_path : str or path-like
            A preset name (:func:`preset_names`) or a spec file.

        Returns
        -------
        WheelSpec
        """
        if isinstance(name_or_path, str) and name_or_path in preset_names():
            return _preset(name_or_path)
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(
                f"unknown wheel model {str(name_or_path)!r}: not one of {list(preset_names())} "
                "and no such file (a wheel spec TOML; see `rwlab wheel models`)"
            )
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read the wheel spec ({exc})") from None
        return replace(cls.from_toml_text(text, str(path)), origin=str(path))

    @classmethod
    def from_toml_text(
        cls, text: str, where: str = "the wheel spec", *, validate: bool = True
    ) -> WheelSpec:
        """Parse and check a spec file's text.

        Parameters
        ----------
        text : str
            The TOML.
        where : str
            The file's name, for messages.
        validate : bool
            Check the structure against the JSON Schema (the shipped presets are
            checked by the tests instead, to keep ``import rwlab.wheel`` fast).

        Returns
        -------
        WheelSpec
        """
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{where}: not valid TOML ({exc})") from None
        return cls.from_dict(raw, where, validate=validate)

    @classmethod
    def from_dict(
        cls, raw: Any, where: str = "the wheel spec", *, validate: bool = True
    ) -> WheelSpec:
        """A spec from its file's parsed form (or :meth:`to_dict`'s output).

        Parameters
        ----------
        raw : dict
            ``format``, ``name``, ``title``, ``documents``, the sections, ``tolerances``.
        where : str
            The file's name, for messages.
        validate : bool
            Check the structure against the JSON Schema first.

        Returns
        -------
        WheelSpec
        """
        if validate:
            _validate_schema(raw, where)
        values: dict[str, Any] = {}
        sources: dict[str, str] = {}
        for section, items in SECTIONS.items():
            table = raw[section]
            for name, kind in items:
                entry = table.get(name, OPTIONAL.get(name))
                if entry is None:  # the schema passed it (or validate=False): say which
                    raise ConfigError(f"{where}: [{section}] has no {name}")
                value = entry["value"]
                if kind is float and isinstance(value, int) and not isinstance(value, bool):
                    value = float(value)
                values[name] = value
                sources[name] = entry["source"]
        tolerances = {
            name: Tolerance(float(t.get("relative", 0)), float(t.get("absolute", 0)), t["source"])
            for name, t in raw.get("tolerances", {}).items()
        }
        try:
            return cls(
                name=raw["name"],
                title=raw["title"],
                documents=tuple(raw["documents"]),
                tolerances=MappingProxyType(tolerances),
                sources=MappingProxyType(sources),
                **values,
            )
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    def to_dict(self) -> dict:
        """The file's form: what :meth:`from_dict` reads back (and ``model.json`` carries).

        Returns
        -------
        dict
            ``format``, ``name``, ``title``, ``documents``, one table per section, the
            ``tolerances``.
        """
        out: dict[str, Any] = {
            "format": FORMAT,
            "name": self.name,
            "title": self.title,
            "documents": list(self.documents),
        }
        for section, items in SECTIONS.items():
            out[section] = {
                name: {"value": getattr(self, name), "source": self.sources[name]}
                for name, _ in items
                if not self._implicit(name)
            }
        out["tolerances"] = {
            name: {"relative": t.relative, "absolute": t.absolute, "source": t.source}
            for name, t in self.tolerances.items()
        }
        return out

    def _implicit(self, name: str) -> bool:
        """A field its file did not state (:data:`OPTIONAL`'s value and source): left out
        of the file's form, so a spec (and ``model.json``) written before the field keeps
        its hash."""
        default = OPTIONAL.get(name)
        return default is not None and (getattr(self, name), self.sources.get(name)) == (
            default["value"],
            default["source"],
        )

    @property
    def hash(self) -> str:
        """SHA-256 (first 16 hex digits) of the spec's canonical JSON: every value,
        source and tolerance; two files with the same numbers have the same hash."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]

    def limits(self) -> dict[str, Any]:
        """The headline limits, as ``rwlab wheel models --json`` lists them.

        Returns
        -------
        dict
            name, title, hash, inertia_kg_m2, max_speed_rpm, max_torque_nm,
            max_accel_rpm_s, current_limit_a, momentum_capacity_nms, controller_mode.
        """
        return {
            "name": self.name,
            "title": self.title,
            "hash": self.hash,
            "inertia_kg_m2": self.inertia_kg_m2,
            "max_speed_rpm": self.max_speed_rpm,
            "max_torque_nm": self.max_torque_nm,
            "max_accel_rpm_s": self.max_accel_rpm_s,
            "current_limit_a": self.current_limit_a,
            "momentum_capacity_nms": self.momentum_capacity_nms,
            "controller_mode": self.controller_mode,
        }

    def with_(self, **changes: Any) -> WheelSpec:
        """A copy with some numbers changed (their source says so).

        Parameters
        ----------
        **changes
            Field name → new value.

        Returns
        -------
        WheelSpec
        """
        unknown = sorted(set(changes) - set(_KINDS))
        if unknown:
            raise ConfigError(f"unknown wheel spec field(s) {unknown}; known: {sorted(_KINDS)}")
        sources = dict(self.sources)
        for name in changes:
            sources[name] = f"changed from {getattr(self, name)!r} ({sources[name]})"
        return replace(self, sources=MappingProxyType(sources), **changes)


@cache
def _preset(name: str) -> WheelSpec:
    text = (resources.files(__package__) / "presets" / f"{name}.toml").read_text(encoding="utf-8")
    spec = WheelSpec.from_toml_text(text, f"wheel preset {name!r}", validate=False)
    return replace(spec, origin=name)


@cache
def preset_names() -> tuple[str, ...]:
    """The shipped wheel models, sorted.

    Returns
    -------
    tuple of str
    """
    folder = resources.files(__package__) / "presets"
    return tuple(sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml")))


@cache
def _validator() -> Any:
    import jsonschema

    from rwlab.schemas import schema

    return jsonschema.Draft202012Validator(schema("wheelspec"))


def _validate_schema(raw: Any, where: str) -> None:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: a wheel spec is a TOML table")
    tag = raw.get("format")
    if isinstance(tag, str) and tag.startswith(f"rwlab.{KIND}/") and tag != FORMAT:
        raise ConfigError(f"{where}: {tag} is not {FORMAT}, the version this rwlab reads")
    validator = _validator()
    errors = sorted(validator.iter_errors(raw), key=lambda e: list(e.absolute_path))
    if errors:
        first = errors[0]
        path = ".".join(str(p) for p in first.absolute_path) or "(top level)"
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ConfigError(
            f"{where}: {path}: {first.message}{more}; every number is "
            '{ value = ..., source = "..." } in its section (see rwlab/wheelspec/presets/rw90.toml)'
        )


def _check(spec: WheelSpec) -> None:
    """The ranges and the consistency of a spec's numbers, each failure a ConfigError."""
    for f in fields(spec):
        kind = _KINDS.get(f.name)
        if kind is None:
            continue
        value = getattr(spec, f.name)
        if kind is bool:
            if not isinstance(value, bool):
                raise ConfigError(f"{f.name} must be true or false, got {value!r}")
            continue
        if kind is str:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{f.name} must be a number, got {value!r}")
        if kind is int and not isinstance(value, int):
            raise ConfigError(f"{f.name} must be an integer, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{f.name} must be finite, got {value!r}")
        if f.name in _SIGNED:
            continue
        if value < 0 or (value == 0 and f.name not in _ZERO_ALLOWED):
            raise ConfigError(f"{f.name} must be > 0, got {value!r}")
    if spec.controller_mode not in CONTROLLER_MODES:
        raise ConfigError(
            f"controller_mode must be one of {CONTROLLER_MODES}, got {spec.controller_mode!r}"
        )
    pairs = (
        ("max_speed_rpm", "overspeed_fault_rpm", "the overspeed fault must be above the limit"),
        ("current_limit_a", "overcurrent_fault_a", "the overcurrent fault must be above the limit"),
        ("nominal_speed_rpm", "max_speed_rpm", "the nominal speed must not exceed the limit"),
    )
    for low, high, why in pairs:
        if getattr(spec, low) > getattr(spec, high) or (
            low != "nominal_speed_rpm" and getattr(spec, low) == getattr(spec, high)
        ):
            lo, hi = getattr(spec, low), getattr(spec, high)
            raise ConfigError(f"{low} ({lo}) vs {high} ({hi}): {why}")
    if spec.max_torque_nm > spec.motor_torque_nm * (1 + 1e-9):
        raise ConfigError(
            f"max_torque_nm ({spec.max_torque_nm}) exceeds what the current limit gives, "
            f"torque_constant_nm_a × current_limit_a = {spec.motor_torque_nm:.4g} N·m"
        )
    if spec.stiction and spec.breakaway_friction_nm < spec.coulomb_friction_nm:
        raise ConfigError(
            f"breakaway_friction_nm ({spec.breakaway_friction_nm}) must be ≥ "
            f"coulomb_friction_nm ({spec.coulomb_friction_nm})"
        )
    if spec.driver_max_duty > 1 or spec.frame_loss_rate >= 1:
        raise ConfigError("driver_max_duty must be ≤ 1 and frame_loss_rate < 1")
    missing = sorted(set(_KINDS) - set(spec.sources))
    if spec.sources and missing:
        raise ConfigError(f"no source for {missing}: every number says where it comes from")
    for name, tol in spec.tolerances.items():
        if name not in TWIN_NAMES or _KINDS[name] is not float:
            raise ConfigError(f"tolerance for {name!r}: not a numeric field of the twin")
        if not (0 <= tol.relative < 1 and tol.absolute >= 0):
            raise ConfigError(f"tolerance for {name!r}: relative must be in [0, 1), absolute ≥ 0")
