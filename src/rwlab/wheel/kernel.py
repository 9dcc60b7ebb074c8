"""The twin's per-step physics, compiled: :class:`rwlab.wheel.WheelPhysics` runs its steps here.

The equations are those of :mod:`rwlab.wheel.physics` (its docstring has the model);
this module holds them as functions of flat arrays so that numba runs a whole span of
1 ms steps without Python (the twin ran ~130 k steps/s interpreted, the demo's 2.4 M
steps were half its CPU). The arrays' layouts are the ``X_*``, ``P_*`` and ``H_*``
column names below; :class:`WheelPhysics` and :class:`~rwlab.wheel.imperfections.HallSpeedSensor`
own them and give them names.

Bit for bit the interpreted twin's numbers (``tests/test_wheel_physics_compiled.py``):
every expression keeps the interpreted one's order of operations, and ``x ** 2`` is
``pow(x, two)`` with ``two`` read from the parameters: Python's ``x ** 2`` calls libm's
``pow``, which differs from ``x * x`` in the last bit about once in a thousand, and a
constant exponent would let LLVM fold the call into ``x * x`` (the golden traces
happen not to show it: such a last bit is lost in the temperature or an exponential of
~0; the precaution costs nothing).

Hand-written: no library integrates this wheel model; numba only compiles it.
"""

from __future__ import annotations

import math

from numba import njit

from rwlab.wheel.kernel_layout import (
    ACCELERATION,
    H_COUNT,
    H_DIRECTION,
    H_EDGES_PER_REV,
    H_ESTIMATE,
    H_HAS_K,
    H_HEAD,
    H_K,
    H_LAST_EDGE,
    H_PITCH,
    H_T,
    H_THETA,
    H_TICK,
    H_TIMEOUT,
    H_WINDOW,
    IDLE,
    OVERCURRENT,
    OVERSPEED,
    OVERTEMP,
    P_AMBIENT_C,
    P_BACK_EMF,
    P_BREAKAWAY,
    P_BUS_SOURCE_RESISTANCE,
    P_BUS_VOLTAGE,
    P_COGGING,
    P_COGGING_PERIODS,
    P_COULOMB,
    P_FRICTION_DRIFT,
    P_HALL,
    P_INERTIA,
    P_KI,
    P_KP,
    P_KT_TEMP_COEFF,
    P_MAX_ACCEL,
    P_MAX_DUTY,
    P_MAX_SPEED,
    P_OVERCURRENT,
    P_OVERSPEED_RPM,
    P_OVERTEMP_C,
    P_R_TEMP_COEFF,
    P_RIPPLE,
    P_RIPPLE_PERIODS,
    P_SETPOINT_WEIGHT,
    P_STICTION,
    P_STRIBECK_SPEED,
    P_THERMAL_RESISTANCE,
    P_THERMAL_TAU,
    P_TORQUE_CONSTANT,
    P_TWO,
    P_VISCOUS,
    P_VISCOUS_TEMP_COEFF,
    P_WINDING_RESISTANCE,
    RPM,
    SPEED,
    X_ANGLE,
    X_BUS_VOLTAGE,
    X_CURRENT,
    X_CURRENT_LIMIT,
    X_DRIFT,
    X_DRIFT_CLOCK,
    X_FAULTS,
    X_FORCED_CURRENT,
    X_FRICTION_FACTOR,
    X_INTEGRAL,
    X_MODE,
    X_SETPOINT,
    X_SPEED,
    X_SPEED_LIMITED,
    X_TEMPERATURE,
    X_TIME,
    X_TORQUE_CONSTANT_FACTOR,
)


@njit(cache=True, inline="always")
def _clip(x, limit):
    return -limit if x < -limit else (limit if x > limit else x)


@njit(cache=True, inline="always")
def _ring(hs, edges, i):
    """The i-th captured edge time, oldest first (negative i: from the newest)."""
    n = int(hs[H_COUNT])
    j = i if i >= 0 else n + i
    return edges[(int(hs[H_HEAD]) + j) % edges.size]


@njit(cache=True, inline="always")
def _edge_angle(hs, offsets, k):
    return k * hs[H_PITCH] + offsets[k % int(hs[H_EDGES_PER_REV])]


@njit(cache=True)
def hall_edge(hs, edges, offsets, jitter, k, direction, t, theta):
    """Capture edge ``k`` passed going ``direction`` (±1) between the last record and now."""
    a = _edge_angle(hs, offsets, k)
    frac = (a - hs[H_THETA]) / (theta - hs[H_THETA])
    exact = hs[H_T] + frac * (t - hs[H_T])
    tick = hs[H_TICK]
    captured = round((exact + jitter[k % jitter.size]) / tick) * tick
    if direction != hs[H_DIRECTION]:
        hs[H_COUNT] = 0.0  # a reversal: intervals across it mean nothing
        hs[H_DIRECTION] = direction
    count = int(hs[H_COUNT])
    head = int(hs[H_HEAD])
    if count == edges.size:  # full: the oldest goes
        edges[head] = captured
        hs[H_HEAD] = (head + 1) % edges.size
    else:
        edges[(head + count) % edges.size] = captured
        count += 1
        hs[H_COUNT] = count
    hs[H_LAST_EDGE] = captured
    if count < 2:
        hs[H_ESTIMATE] = 0.0
        return
    n = count - 1
    window = hs[H_WINDOW]
    if n < int(hs[H_EDGES_PER_REV]) or captured - _ring(hs, edges, 0) > window:
        n = 1  # fewer edges: those within the window, at least one interval
        while n + 1 < count and captured - _ring(hs, edges, -n - 2) <= window:
            n += 1
    span = captured - _ring(hs, edges, -n - 1)
    if tick > span:
        span = tick
    hs[H_ESTIMATE] = direction * n * hs[H_PITCH] / span


@njit(cache=True)
def hall_record(hs, edges, offsets, jitter, t, theta):
    """Log the rotor angle ``theta`` (rad, unwrapped) at time ``t`` (s)."""
    if hs[H_HAS_K] == 0.0:
        k = math.floor(theta / hs[H_PITCH])
        k = k if _edge_angle(hs, offsets, k) <= theta else k - 1
    else:
        k = int(hs[H_K])
        while _edge_angle(hs, offsets, k + 1) <= theta:  # edges passed going forward
            k += 1
            hall_edge(hs, edges, offsets, jitter, k, 1.0, t, theta)
        while _edge_angle(hs, offsets, k) > theta:  # going backward
            hall_edge(hs, edges, offsets, jitter, k, -1.0, t, theta)
            k -= 1
    hs[H_K] = k
    hs[H_HAS_K] = 1.0
    hs[H_T] = t
    hs[H_THETA] = theta


@njit(cache=True)
def hall_read(hs):
    """The firmware's speed now, rad/s (0 when no edge came within the timeout)."""
    since = hs[H_T] - hs[H_LAST_EDGE]
    if since > hs[H_TIMEOUT]:
        return 0.0
    estimate = hs[H_ESTIMATE]
    if abs(estimate) * since > 1.5 * hs[H_PITCH]:  # an edge is well overdue:
        return math.copysign(hs[H_PITCH] / since, estimate)  # slower than it was
    return estimate


@njit(cache=True, inline="always")
def _nominal_friction(p, speed):
    return p[P_VISCOUS] * speed + p[P_COULOMB] * math.copysign(1.0, speed) * (abs(speed) > 1e-9)


@njit(cache=True)
def bearing_friction(x, p, speed):
    """The true sliding friction at ``speed`` (rad/s), N·m (``WheelPhysics.bearing_friction``)."""
    viscous = p[P_VISCOUS] * math.exp(
        -p[P_VISCOUS_TEMP_COEFF] * (x[X_TEMPERATURE] - p[P_AMBIENT_C])
    )
    if p[P_STICTION] != 0.0:
        if speed == 0.0:
            law = 0.0
        else:  # the Stribeck law of rwlab.wheel.imperfections.stribeck_friction
            coulomb = p[P_COULOMB]
            ratio = speed / p[P_STRIBECK_SPEED]
            drop = (p[P_BREAKAWAY] - coulomb) * math.exp(-(ratio ** p[P_TWO]))
            law = math.copysign(coulomb + drop, speed) + viscous * speed
    else:
        law = viscous * speed + p[P_COULOMB] * math.copysign(1.0, speed) * (abs(speed) > 1e-9)
    return x[X_FRICTION_FACTOR] * math.exp(x[X_DRIFT]) * law


@njit(cache=True, inline="always")
def _torque_constant(x, p):
    warm = 1 - p[P_KT_TEMP_COEFF] * (x[X_TEMPERATURE] - p[P_AMBIENT_C])
    return x[X_TORQUE_CONSTANT_FACTOR] * p[P_TORQUE_CONSTANT] * warm


@njit(cache=True, inline="always")
def _resistance(x, p):
    rise = x[X_TEMPERATURE] - p[P_AMBIENT_C]
    return p[P_WINDING_RESISTANCE] * (1 + p[P_R_TEMP_COEFF] * rise)


@njit(cache=True, inline="always")
def accel_request(x, p, dt, speed):
    mode = x[X_MODE]
    if mode == SPEED:
        target = _clip(x[X_SETPOINT], p[P_MAX_SPEED])
        error = target - speed
        request = p[P_KP] * (p[P_SETPOINT_WEIGHT] * target - speed) + x[X_INTEGRAL]
        if abs(request) < p[P_MAX_ACCEL]:  # anti-windup: integrate only when unsaturated
            x[X_INTEGRAL] += p[P_KI] * error * dt
        return _clip(request, p[P_MAX_ACCEL])
    if mode == ACCELERATION:
        return _clip(x[X_SETPOINT], p[P_MAX_ACCEL])
    return 0.0


@njit(cache=True, inline="always")
def _latch(x, fault):
    x[X_FAULTS] = float(int(x[X_FAULTS]) | fault)
    x[X_MODE] = IDLE
    x[X_SETPOINT] = 0.0
    x[X_INTEGRAL] = 0.0


@njit(cache=True)
def _step(x, p, hs, edges, offsets, jitter, dt):
    hall = p[P_HALL] != 0.0
    sensed = hall_read(hs) if hall else x[X_SPEED]
    alpha = accel_request(x, p, dt, sensed)
    if x[X_MODE] == IDLE:
        current = 0.0
    else:
        torque = p[P_INERTIA] * alpha + _nominal_friction(p, sensed)
        current = _clip(torque / p[P_TORQUE_CONSTANT], x[X_CURRENT_LIMIT])
    speed = x[X_SPEED]
    limited = abs(speed) >= p[P_MAX_SPEED] and current * speed > 0
    x[X_SPEED_LIMITED] = 1.0 if limited else 0.0
    if limited:  # speed limit: never drive further beyond the maximum speed
        current = _clip(_nominal_friction(p, speed) / p[P_TORQUE_CONSTANT], x[X_CURRENT_LIMIT])
    if p[P_BACK_EMF] != 0.0:  # what the bus drives against the back-EMF
        volts = p[P_MAX_DUTY] * x[X_BUS_VOLTAGE]
        emf = _torque_constant(x, p) * speed
        r = _resistance(x, p)
        low = (-volts - emf) / r
        if low > current:
            current = low
        high = (volts - emf) / r
        if high < current:
            current = high
    if not math.isnan(x[X_FORCED_CURRENT]):
        current = x[X_FORCED_CURRENT]
    x[X_CURRENT] = current
    motor = _torque_constant(x, p) * current  # the true motor, not the model
    angle = x[X_ANGLE]
    if p[P_RIPPLE] != 0.0:  # the mean of cos(nθ) over the step
        a0 = p[P_RIPPLE_PERIODS] * angle
        span = p[P_RIPPLE_PERIODS] * speed * dt
        mean = math.cos(a0) if abs(span) < 1e-6 else (math.sin(a0 + span) - math.sin(a0)) / span
        motor *= 1 + p[P_RIPPLE] * mean
    if p[P_COGGING] != 0.0:  # the mean of sin(nθ) over the step
        a0 = p[P_COGGING_PERIODS] * angle
        span = p[P_COGGING_PERIODS] * speed * dt
        mean = math.sin(a0) if abs(span) < 1e-6 else (math.cos(a0) - math.cos(a0 + span)) / span
        motor += p[P_COGGING] * mean
    if p[P_STICTION] != 0.0:
        if speed == 0.0:  # stuck until the motor beats the breakaway torque
            breakaway = x[X_FRICTION_FACTOR] * math.exp(x[X_DRIFT]) * p[P_BREAKAWAY]
            if abs(motor) <= breakaway:
                new_speed = 0.0
            else:
                new_speed = (motor - math.copysign(breakaway, motor)) / p[P_INERTIA] * dt
        else:
            new_speed = speed + (motor - bearing_friction(x, p, speed)) / p[P_INERTIA] * dt
            if new_speed * speed < 0:
                new_speed = 0.0  # stops; breakaway decides
    else:
        net = motor - bearing_friction(x, p, speed)
        new_speed = speed + net / p[P_INERTIA] * dt
        if x[X_MODE] == IDLE and speed != 0 and new_speed * speed < 0:
            new_speed = 0.0  # friction stops the wheel; it does not reverse it
    x[X_ANGLE] = angle + 0.5 * (speed + new_speed) * dt
    x[X_SPEED] = new_speed
    x[X_TIME] += dt
    if hall:
        hall_record(hs, edges, offsets, jitter, x[X_TIME], x[X_ANGLE])
    # supply and heat
    r = _resistance(x, p)
    heat = r * current ** p[P_TWO]
    x[X_TEMPERATURE] += (
        dt / p[P_THERMAL_TAU] * (p[P_AMBIENT_C] + p[P_THERMAL_RESISTANCE] * heat - x[X_TEMPERATURE])
    )
    if p[P_BACK_EMF] != 0.0:  # the supply current sags the bus through its source resistance
        power = (r * current + _torque_constant(x, p) * x[X_SPEED]) * current
        if 0.0 > power:
            power = 0.0
        drop = p[P_BUS_SOURCE_RESISTANCE] * power / p[P_BUS_VOLTAGE]
        x[X_BUS_VOLTAGE] = p[P_BUS_VOLTAGE] - drop
    if p[P_FRICTION_DRIFT] != 0.0:
        x[X_DRIFT_CLOCK] += dt
    # faults
    if abs(x[X_SPEED] / RPM) > p[P_OVERSPEED_RPM]:
        _latch(x, OVERSPEED)
    if abs(x[X_CURRENT]) > p[P_OVERCURRENT]:
        _latch(x, OVERCURRENT)
        x[X_CURRENT] = 0.0
    if x[X_TEMPERATURE] > p[P_OVERTEMP_C]:
        _latch(x, OVERTEMP)


@njit(cache=True)
def advance(x, p, hs, edges, offsets, jitter, dt, steps):
    """Run up to ``steps`` steps of ``dt`` seconds; stop early after a step that owes the
    friction drift a random draw (``x[X_DRIFT_CLOCK] ≥ 1``, the caller draws).

    Parameters
    ----------
    x : numpy.ndarray
        State, shape (N_STATE,); changed in place.
    p : numpy.ndarray
        Parameters, shape (N_PARAMS,).
    hs, edges, offsets, jitter : numpy.ndarray
        The Hall sensor's state (N_HALL,), captured edge times (ring), edge placement
        errors (rad) and capture jitters (s); unused without a Hall sensor.
    dt : float
        Step, s.
    steps : int
        Steps to run.

    Returns
    -------
    int
        Steps run.
    """
    for i in range(steps):
        _step(x, p, hs, edges, offsets, jitter, dt)
        if x[X_DRIFT_CLOCK] >= 1.0:
            return i + 1
    return steps
