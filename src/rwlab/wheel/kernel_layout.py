"""The layout of the twin's state and parameter vectors (:mod:`rwlab.wheel.kernel`'s
arrays): column names, and the parameter vector of a wheel. Apart from the compiled
step so that using the names does not import numba."""

from __future__ import annotations

import math

import numpy as np

RPM = 2 * math.pi / 60  # rad/s per rpm

# state columns
(
    X_TIME,
    X_ANGLE,
    X_BUS_VOLTAGE,
    X_DRIFT,
    X_DRIFT_CLOCK,
    X_SPEED,
    X_CURRENT,
    X_TEMPERATURE,
    X_MODE,
    X_SETPOINT,
    X_FAULTS,
    X_SPEED_LIMITED,
    X_INTEGRAL,
    X_FORCED_CURRENT,  # NaN: none
    X_FRICTION_FACTOR,
    X_TORQUE_CONSTANT_FACTOR,
    X_CURRENT_LIMIT,
) = range(17)
N_STATE = 17

# parameter columns (booleans as 0/1)
(
    P_INERTIA,
    P_MAX_SPEED,
    P_MAX_ACCEL,
    P_TORQUE_CONSTANT,
    P_VISCOUS,
    P_COULOMB,
    P_KP,
    P_KI,
    P_SETPOINT_WEIGHT,
    P_OVERSPEED_RPM,
    P_OVERCURRENT,
    P_THERMAL_RESISTANCE,
    P_THERMAL_TAU,
    P_OVERTEMP_C,
    P_AMBIENT_C,
    P_WINDING_RESISTANCE,
    P_STICTION,
    P_BREAKAWAY,
    P_STRIBECK_SPEED,  # rad/s
    P_VISCOUS_TEMP_COEFF,
    P_FRICTION_DRIFT,
    P_COGGING,
    P_COGGING_PERIODS,
    P_RIPPLE,
    P_RIPPLE_PERIODS,  # 6 × pole pairs
    P_KT_TEMP_COEFF,
    P_R_TEMP_COEFF,
    P_BACK_EMF,
    P_BUS_VOLTAGE,
    P_BUS_SOURCE_RESISTANCE,
    P_MAX_DUTY,
    P_HALL,
    P_TWO,  # 2.0: the exponent of x ** 2 (see the module docstring)
) = range(33)
N_PARAMS = 33

# Hall sensor state columns; its captured edge times are a ring buffer of their own
(
    H_DIRECTION,
    H_K,
    H_HAS_K,
    H_T,
    H_THETA,
    H_ESTIMATE,
    H_LAST_EDGE,
    H_COUNT,  # edges in the ring
    H_HEAD,  # index of the oldest
    H_EDGES_PER_REV,
    H_PITCH,
    H_TICK,
    H_WINDOW,
    H_TIMEOUT,
) = range(14)
N_HALL = 14
IDLE, SPEED, ACCELERATION = 0, 1, 2  # Mode's values
OVERSPEED, OVERCURRENT, OVERTEMP = 1, 2, 8  # Fault's bits


def params_vector(params) -> np.ndarray:
    """The parameter columns of a :class:`~rwlab.wheel.WheelParams`, shape (N_PARAMS,)."""
    p = np.zeros(N_PARAMS)
    p[P_INERTIA] = params.inertia
    p[P_MAX_SPEED] = params.max_speed
    p[P_MAX_ACCEL] = params.max_accel
    p[P_TORQUE_CONSTANT] = params.torque_constant
    p[P_VISCOUS] = params.viscous_friction
    p[P_COULOMB] = params.coulomb_friction
    p[P_KP] = params.speed_kp
    p[P_KI] = params.speed_ki
    p[P_SETPOINT_WEIGHT] = params.speed_setpoint_weight
    p[P_OVERSPEED_RPM] = params.overspeed_fault_rpm
    p[P_OVERCURRENT] = params.overcurrent_fault
    p[P_THERMAL_RESISTANCE] = params.thermal_resistance
    p[P_THERMAL_TAU] = params.thermal_time_constant
    p[P_OVERTEMP_C] = params.overtemp_fault_c
    p[P_AMBIENT_C] = params.ambient_c
    p[P_WINDING_RESISTANCE] = params.winding_resistance
    p[P_STICTION] = float(params.stiction)
    p[P_BREAKAWAY] = params.breakaway_friction
    p[P_STRIBECK_SPEED] = params.stribeck_speed_rpm * RPM
    p[P_VISCOUS_TEMP_COEFF] = params.viscous_temp_coeff
    p[P_FRICTION_DRIFT] = params.friction_drift
    p[P_COGGING] = params.cogging_torque
    p[P_COGGING_PERIODS] = params.cogging_periods
    p[P_RIPPLE] = params.torque_ripple
    p[P_RIPPLE_PERIODS] = 6 * params.pole_pairs
    p[P_KT_TEMP_COEFF] = params.torque_constant_temp_coeff
    p[P_R_TEMP_COEFF] = params.resistance_temp_coeff
    p[P_BACK_EMF] = float(params.back_emf)
    p[P_BUS_VOLTAGE] = params.bus_voltage
    p[P_BUS_SOURCE_RESISTANCE] = params.bus_source_resistance
    p[P_MAX_DUTY] = params.driver_max_duty
    p[P_HALL] = float(params.hall_speed)
    p[P_TWO] = 2.0
    return p
