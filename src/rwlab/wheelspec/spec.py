"""The datasheet of a reaction-wheel model: :class:`WheelSpec`, the record every layer reads.

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

A ``source`` is a datasheet or ICD page, or ``"assumed, because …"``. The files are
read and written by :mod:`rwlab.wheelspec.files` (keys, JSON Schema), the numbers
checked by :mod:`rwlab.wheelspec.checks` (ranges, and whether they make a wheel that
reaches its speed and delivers its torque). Every failure is a
:class:`~rwlab.errors.ConfigError` naming the file and the key.

The spec sits at the bottom layer so that every layer reads the same numbers:
the twin (:meth:`rwlab.wheel.WheelParams.from_spec`), identification's
saturations, ``model.json``, the attitude loop, HIL's twin nodes, diagnosis.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any, ClassVar

from rwlab.errors import ConfigError
from rwlab.wheelspec import files
from rwlab.wheelspec.checks import check_ranges
from rwlab.wheelspec.fields import FORMAT, KINDS, OPTIONAL, RPM, SECTIONS, TWIN_NAMES

__all__ = ["Tolerance", "WheelSpec"]


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
        check_ranges(self)

    def __reduce__(self) -> tuple:
        # pickled by its fields, the read-only mappings as dicts (a mappingproxy does not
        # pickle): rwlab identify hands a record's spec to its forked child this way
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values |= {"tolerances": dict(self.tolerances), "sources": dict(self.sources)}
        return _from_fields, (type(self), values)

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
            A preset name (:func:`rwlab.wheelspec.preset_names`) or a spec file.

        Returns
        -------
        WheelSpec
            Checked: ranges, structure and physics (:mod:`rwlab.wheelspec.checks`).
        """
        return files.load(cls, name_or_path)

    @classmethod
    def from_toml_text(
        cls, text: str, where: str = "the wheel spec", *, validate: bool = True
    ) -> WheelSpec:
        """Parse and check a spec file's text (:func:`rwlab.wheelspec.files.load_text`).

        Parameters
        ----------
        text : str
            The TOML.
        where : str
            The file's name, for messages.
        validate : bool
            Check the keys and the structure against the JSON Schema.

        Returns
        -------
        WheelSpec
        """
        return files.load_text(cls, text, where, validate=validate)

    @classmethod
    def from_dict(
        cls, raw: Any, where: str = "the wheel spec", *, validate: bool = True
    ) -> WheelSpec:
        """A spec from its file's parsed form (or :meth:`to_dict`'s output), as carried by a
        record or ``model.json``: ranges checked, the physics not (the wheel as it was).

        Parameters
        ----------
        raw : dict
            ``format``, ``name``, ``title``, ``documents``, the sections, ``tolerances``.
        where : str
            The file's name, for messages.
        validate : bool
            Check the keys and the structure against the JSON Schema first.

        Returns
        -------
        WheelSpec
        """
        return files.from_dict(cls, raw, where, validate=validate)

    def to_toml(self) -> str:
        """The spec as a whole TOML file that :meth:`load` reads back to the same spec.

        Returns
        -------
        str
        """
        return files.to_toml(self)

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

    def is_preset(self) -> bool:
        """Whether this is a shipped preset's own spec: its name and the same hash (a unit's
        spec edited from a preset's keeps the name, not the numbers).

        Returns
        -------
        bool
        """
        return self.name in files.preset_names() and self.hash == self.load(self.name).hash

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
        unknown = sorted(set(changes) - set(KINDS))
        if unknown:
            raise ConfigError(f"unknown wheel spec field(s) {unknown}; known: {sorted(KINDS)}")
        sources = dict(self.sources)
        for name in changes:
            sources[name] = f"changed from {getattr(self, name)!r} ({sources[name]})"
        return replace(self, sources=MappingProxyType(sources), **changes)


def _from_fields(cls: type, values: dict) -> WheelSpec:
    """A pickled spec rebuilt (:meth:`WheelSpec.__reduce__`)."""
    return cls(**values)
