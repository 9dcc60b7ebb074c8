"""The fields of a wheel spec: its file's sections, each number's kind, and the rules on them.

What a :class:`~rwlab.wheelspec.WheelSpec` holds and how its file is laid out, shared by
the record (:mod:`rwlab.wheelspec.spec`), its checks (:mod:`rwlab.wheelspec.checks`) and
its files (:mod:`rwlab.wheelspec.files`): the sections and their fields in file order,
each field's kind, the twin's name for it, which may be zero or negative, and the
fields an older file may lack.
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Any

__all__ = [
    "CONTROLLER_MODES",
    "FORMAT",
    "KIND",
    "KINDS",
    "OPTIONAL",
    "RPM",
    "SECTIONS",
    "SECTION_OF",
    "SIGNED",
    "TWIN_NAMES",
    "ZERO_ALLOWED",
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
KINDS = {name: kind for section in SECTIONS.values() for name, kind in section}
SECTION_OF = {name: s for s, section in SECTIONS.items() for name, _ in section}

# spec field → the twin's (WheelParams) field; fields of the same name map to themselves,
# the spec-only ones (imbalance, controller mode and rate, telemetry rate) are absent
TWIN_NAMES: MappingProxyType[str, str] = MappingProxyType(
    {
        **{
            name: name
            for name in KINDS
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
SIGNED = {"current_offset_a", "ambient_c", "overtemp_fault_c"}
# fields a spec file written before them may lack: the value they had implicitly then
OPTIONAL: MappingProxyType[str, dict[str, Any]] = MappingProxyType(
    {
        "speed_setpoint_weight": {
            "value": 1.0,
            "source": "assumed, because the file states none: a plain PI (setpoint weight 1)",
        },
    }
)
ZERO_ALLOWED = {  # physical zeros a datasheet may state: none, off, perfect
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
