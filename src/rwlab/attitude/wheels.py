"""Every wheel model of the attitude loop, compiled: commanded torques → realised torques.

The closed loop asks each wheel for a torque (N·m, along its axis); what the
wheel delivers depends on the model (``Scenario.wheels.model``):

- ``ideal``: the command, clipped to the rated torque.
- ``physics``: the RW physics of :class:`rwlab.wheel.physics.WheelPhysics` in
  acceleration mode — the motor torque needed for the commanded acceleration
  plus the drive's Coulomb + viscous feed-forward, limited by the current limit,
  and no drive beyond the maximum speed. The rotor feels the twin's friction law
  (:func:`rwlab.wheel.imperfections.stribeck_friction`, compiled here from the same
  function): breakaway + Stribeck + Coulomb + viscous, and at rest it stays stuck
  until the motor torque exceeds the breakaway torque — what a wheel meets at
  every zero crossing, and what the drive's feed-forward does not cancel.
  ``wheels.stiction = false`` gives the plain Coulomb + viscous law (no
  Stribeck rise, no stuck state); ``wheel_friction_factor`` scales the true
  friction the drive does not know of. Per-wheel faults (friction or
  torque-constant factors, a lower current limit) switch on at a time.
- ``identified``: the model ``rwlab identify`` chose (``model.json``: the linear
  model with its saturations, or the nonlinear servo model where it validates
  better), as :class:`rwlab.wheel.identified.IdentifiedWheel` steps it: the commanded
  accelerations are integrated into a speed command (rpm) that drives the
  identified speed loop at its own sample time Ts; the realised torque over
  each model sample is I·Δspeed/Ts.

:func:`wheel_setup` packs a scenario's model into flat arrays once;
:func:`realise` runs inside the kernel's step (scalar, allocation-free). Tests
hold each model equal to the Python class it compiles.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from numba import njit

from rwlab.ident.nonlinear import servo_advance
from rwlab.wheel.imperfections import stribeck_friction
from rwlab.wheel.physics import IDEAL as IDEAL_PARAMS
from rwlab.wheel.physics import WheelParams, rad_s_to_rpm

__all__ = ["IDEAL", "IDENTIFIED", "PHYSICS", "WheelArrays", "realise", "wheel_setup"]

IDEAL, PHYSICS, IDENTIFIED = 0, 1, 2
RPM = 30.0 / math.pi  # rad/s → rpm

# physics parameter columns (per wheel): inertia, torque constant, current limit,
# viscous and Coulomb friction, maximum speed (rad/s), breakaway friction (N·m), Stribeck
# speed (rad/s), 1 with stiction (the stuck state and the Stribeck law)
P_I, P_KT, P_ILIM, P_VISC, P_COUL, P_WMAX, P_BRK, P_WS, P_STICK = range(9)
# below this speed (rad/s) a wheel with stiction is at rest: the loop's wheel speed is
# h_w/J_s, which a wheel at rest on the body leaves at gᵀω (≤ 7.3e-5 rad/s at GEO)
AT_REST = 1e-9
# the twin's law, compiled from the same function (no copy): the rotor's true friction
_stribeck = njit(cache=True, inline="always")(stribeck_friction)
# identified state columns (per wheel): speed command (rpm), time since the last model
# sample (s), model speed (rpm), realised torque (N·m), then the model's states (linear:
# x, then n scratch; servo: the loop's integral and the last command)
S_CMD, S_CLOCK, S_SPEED, S_TORQUE, S_X = range(5)
# identified parameters: D, u0, y0, Ts, speed limit (rpm), acceleration limit (rpm/s),
# wheel inertia (kg·m²), 1 for the servo model (then ``servo`` holds its vector)
I_D, I_U0, I_Y0, I_TS, I_SPEED, I_ACCEL, I_INERTIA, I_SERVO = range(8)


class WheelArrays(NamedTuple):
    """A scenario's wheel model as the kernel reads it (a named tuple: numba compiles it).

    Attributes
    ----------
    kind : int
        IDEAL, PHYSICS or IDENTIFIED.
    healthy, faulty : (N, 9) arrays
        The true physics parameters before and after each wheel's fault (columns P_*).
    nominal : (N, 9) array
        What the drive assumes (its friction feed-forward and motor constant).
    fault_s : (N,) array
        When each wheel's fault starts, s (inf: never).
    state : (N, 4 + 2n) array
        The identified model's per-wheel state (columns S_*, then n scratch), updated in place.
    A, B, C : (n, n), (n,), (n,) arrays
        The identified linear model (command clip → linear step → rate limit → speed clip).
    ident : (8,) array
        Its scalars (columns I_*).
    servo : (12,) array
        The nonlinear servo model's vector (``ServoModel.vector``) when ident[I_SERVO] = 1.
    """

    kind: int
    healthy: np.ndarray
    faulty: np.ndarray
    fault_s: np.ndarray
    state: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    ident: np.ndarray
    servo: np.ndarray
    nominal: np.ndarray


def physics_params(sc) -> WheelParams:
    """The RW physics of the scenario's wheel model (its spec), as the compiled kernel flies it.

    The wheel model's motor (k_t, current limit) and friction law (Coulomb, viscous,
    breakaway, Stribeck speed: ``sc.wheels.wheel_spec``) on the ideal twin
    (:data:`rwlab.wheel.physics.IDEAL`: no drift, cogging, ripple or temperature
    effects); ``wheels.stiction = false`` gives the plain Coulomb + viscous law.
    Inertia, speed and torque limits are ``sc.wheels``' (the spec's unless a
    dispersion moved them: the current limit then scales with the torque). The
    compiled kernel here is that law, exactly (tested against
    :class:`rwlab.wheel.physics.WheelPhysics`).
    """
    spec = sc.wheels.wheel_spec
    w = sc.wheels
    current = spec.current_limit_a * w.max_torque / spec.max_torque_nm
    return replace(
        IDEAL_PARAMS,
        model=spec.origin or spec.name,
        inertia=w.inertia,
        max_speed_rpm=w.max_speed_rpm,
        overspeed_fault_rpm=w.max_speed_rpm * spec.overspeed_fault_rpm / spec.max_speed_rpm,
        max_accel_rpm_s=rad_s_to_rpm(w.max_torque / w.inertia),
        nominal_torque=w.max_torque,
        torque_constant=spec.torque_constant_nm_a,
        current_limit=current,
        overcurrent_fault=current * spec.overcurrent_fault_a / spec.current_limit_a,
        viscous_friction=spec.viscous_friction_nm_s,
        coulomb_friction=spec.coulomb_friction_nm,
        stiction=w.stiction,
        breakaway_friction=spec.breakaway_friction_nm if w.stiction else spec.coulomb_friction_nm,
        stribeck_speed_rpm=spec.stribeck_speed_rpm,
    )


def _physics_row(p: WheelParams) -> np.ndarray:
    return np.array(
        [
            p.inertia,
            p.torque_constant,
            p.current_limit,
            p.viscous_friction,
            p.coulomb_friction,
            p.max_speed,
            p.breakaway_friction,
            p.stribeck_speed_rpm * math.pi / 30,
            float(p.stiction),
        ]
    )


def wheel_setup(sc, hw0: np.ndarray) -> WheelArrays:
    """Pack the scenario's wheel model, starting from wheel momenta ``hw0`` (N·m·s).

    Parameters
    ----------
    sc : Scenario
        Its wheel fields.
    hw0 : numpy.ndarray, shape (N,)
        Initial wheel momenta, N·m·s.

    Returns
    -------
    WheelArrays
        The arrays the compiled kernel steps.
    """
    nw = sc.n_wheels
    kind = {"ideal": IDEAL, "physics": PHYSICS, "identified": IDENTIFIED}[sc.wheels.model]
    nominal = np.tile(_physics_row(physics_params(sc)), (nw, 1))
    healthy = nominal.copy()  # the true wheel: its friction off the drive's by a factor
    healthy[:, [P_VISC, P_COUL, P_BRK]] *= sc.wheels.friction_factor
    faulty = healthy.copy()
    fault_s = np.full(nw, math.inf)
    for f in sc.wheels.faults:
        i = f["wheel"] - 1
        fault_s[i] = f["at_s"]
        faulty[i, [P_VISC, P_COUL, P_BRK]] *= f.get("friction", 1.0)
        faulty[i, P_KT] *= f.get("torque_constant", 1.0)
        faulty[i, P_ILIM] = f.get("current_limit", faulty[i, P_ILIM])
    A = np.zeros((0, 0))
    B = C = np.zeros(0)
    ident = np.zeros(8)
    servo = np.zeros(12)
    state = np.zeros((nw, S_X))
    if kind == IDENTIFIED:
        from rwlab.wheel.identified import IdentifiedWheel

        unit = IdentifiedWheel.from_json(sc.wheels.model_file)
        A, B, C, D = unit.state_space()
        ident = np.array(
            [
                D,
                unit.u0,
                unit.y0,
                unit.Ts,
                unit.speed_limit_rpm,
                unit.accel_limit_rpm_s,
                sc.wheels.inertia,
                float(unit.servo is not None),
            ]
        )
        if unit.servo is not None:
            servo = unit.servo.vector
        state = np.zeros((nw, S_X + max(2 * A.shape[0], 2)))
        for i, h in enumerate(hw0):
            unit.reset(rad_s_to_rpm(h / sc.wheels.inertia))
            state[i, S_CMD] = state[i, S_SPEED] = unit.speed_rpm
            x = unit.model_state()
            state[i, S_X : S_X + x.size] = x
    return WheelArrays(kind, healthy, faulty, fault_s, state, A, B, C, ident, servo, nominal)


@njit(cache=True, inline="always")
def _friction(p, w):
    return p[P_VISC] * w + (p[P_COUL] * math.copysign(1.0, w) if abs(w) > 1e-9 else 0.0)


@njit(cache=True, inline="always")
def _physics(nominal, true, cmd, h, dt):
    """WheelPhysics.step in acceleration mode, as the torque it puts on the rotor, N·m.

    The drive computes its current from the ``nominal`` motor and its Coulomb + viscous
    feed-forward (it knows neither a fault nor the Stribeck rise); the rotor feels the
    ``true`` motor and friction, and the true current limit clamps. With stiction
    (``WheelPhysics._stick_slip``): a wheel at rest stays there until the motor torque
    exceeds the breakaway torque, and a wheel that would reverse within the step stops.
    """
    w = h / nominal[P_I]
    fr = _friction(nominal, w)
    lim = true[P_ILIM]
    current = min(max((cmd + fr) / nominal[P_KT], -lim), lim)
    if abs(w) >= nominal[P_WMAX] and current * w > 0:  # never drive beyond the maximum speed
        current = min(max(fr / nominal[P_KT], -lim), lim)
    motor = true[P_KT] * current
    if true[P_STICK] == 0.0:
        return motor - _friction(true, w)
    if abs(w) < AT_REST:
        if abs(motor) <= true[P_BRK]:
            return -h / dt  # held at rest by the bearing: no wheel torque reaches the body
        return motor - math.copysign(true[P_BRK], motor)
    tau = motor - _stribeck(w, true[P_COUL], true[P_BRK], true[P_WS], true[P_VISC])
    if (h + tau * dt) * h < 0.0:
        return -h / dt  # stops within the step; the breakaway torque decides the next one
    return tau


@njit(cache=True)
def _identified_tick(s, A, B, C, ident, servo):
    """One sample of IdentifiedWheel.step on the state row ``s`` (in place); the new speed."""
    if ident[I_SERVO] > 0:
        w, s[S_X] = servo_advance(s[S_SPEED], s[S_X], s[S_X + 1], s[S_CMD], servo)
        s[S_X + 1] = s[S_CMD]
        return w
    D, u0, y0, Ts = ident[I_D], ident[I_U0], ident[I_Y0], ident[I_TS]
    speed_lim, accel_lim = ident[I_SPEED], ident[I_ACCEL]
    u = min(max(s[S_CMD], -speed_lim), speed_lim) - u0
    n = A.shape[0]
    y = y0 + D * u
    for r in range(n):  # x ← A x + B u, column by column into the spare tail of the row
        acc = B[r] * u
        for c in range(n):
            acc += A[r, c] * s[S_X + c]
        s[S_X + n + r] = acc
    for r in range(n):
        s[S_X + r] = s[S_X + n + r]
        y += C[r] * s[S_X + r]
    step = accel_lim * Ts
    speed = s[S_SPEED] + min(max(y - s[S_SPEED], -step), step)
    return min(max(speed, -speed_lim), speed_lim)


@njit(cache=True)
def realise(kind, t, dt, cmd, x, healthy, faulty, fault_s, state, model, nominal, out):
    """Realised wheel torques ``out`` (N,) for the commands ``cmd`` (N,) over one step.

    ``cmd`` is already clipped to the rated torque; ``x`` is the plant state (wheel
    momenta from x[7], N·m·s); ``model`` is the identified model's arrays
    ``(A, B, C, ident, servo)`` (see :class:`WheelArrays`).
    """
    A, B, C, ident, servo = model
    nw = cmd.shape[0]
    if kind == PHYSICS:
        for i in range(nw):
            true = faulty[i] if t >= fault_s[i] else healthy[i]
            out[i] = _physics(nominal[i], true, cmd[i], x[7 + i], dt)
    elif kind == IDENTIFIED:
        inertia, Ts = ident[I_INERTIA], ident[I_TS]
        for i in range(nw):
            s = state[i]
            s[S_CMD] += cmd[i] / inertia * RPM * dt
            s[S_CLOCK] += dt
            ticks = 0
            before = s[S_SPEED]
            while s[S_CLOCK] >= Ts - 1e-9:
                s[S_CLOCK] -= Ts
                s[S_SPEED] = _identified_tick(s, A, B, C, ident, servo)
                ticks += 1
            if ticks:
                s[S_TORQUE] = inertia * (s[S_SPEED] - before) / RPM / (ticks * Ts)
            out[i] = s[S_TORQUE]
    else:
        for i in range(nw):
            out[i] = cmd[i]


def jitter_arrays(sc) -> tuple[np.ndarray, np.ndarray]:
    """Each wheel's imbalance [U_s kg·m, U_d kg·m²] (N, 2) (zeros with ``wheels.jitter``
    off) and centre relative to the centre of mass (N, 3), m, from the scenario.

    Parameters
    ----------
    sc : Scenario

    Returns
    -------
    imbalance : numpy.ndarray, shape (N, 2)
    positions : numpy.ndarray, shape (N, 3)

    Raises
    ------
    ConfigError
        A value that is not a number ≥ 0, or not one per wheel.
    """
    from rwlab.errors import ConfigError

    nw, w = sc.n_wheels, sc.wheels
    cols = []
    for name in ("static_imbalance_kg_m", "dynamic_imbalance_kg_m2"):
        try:
            v = np.broadcast_to(np.asarray(getattr(w, name), dtype=float), (nw,)).copy()
        except (TypeError, ValueError):
            raise ConfigError(
                f"{sc.name}: wheels.{name} must be one number or {nw} (one per wheel)"
            ) from None
        if not np.all(np.isfinite(v) & (v >= 0)):
            raise ConfigError(f"{sc.name}: wheels.{name} must be ≥ 0")
        cols.append(v)
    try:
        pos = np.zeros((nw, 3)) if len(w.positions_m) == 0 else np.array(w.positions_m, float)
    except (TypeError, ValueError):
        pos = np.empty(0)
    if pos.shape != (nw, 3) or not np.all(np.isfinite(pos)):
        raise ConfigError(f"{sc.name}: wheels.positions_m must be {nw} points [x, y, z] in m")
    imbalance = np.column_stack(cols) if w.jitter else np.zeros((nw, 2))
    return imbalance, pos


def transverse_axes(G: np.ndarray) -> np.ndarray:
    """Each wheel's rotor axes at angle 0 (N, 2, 3): ŵ₂ ⟂ its spin axis ĝ (towards the body
    axis least aligned with ĝ, made orthogonal) and ŵ₃ = ĝ × ŵ₂ (Basilisk's w2Hat0, w3Hat0).

    Parameters
    ----------
    G : numpy.ndarray, shape (3, N)
        Spin axes (unit columns), body axes.

    Returns
    -------
    numpy.ndarray, shape (N, 2, 3)
    """
    out = np.empty((G.shape[1], 2, 3))
    for i, g in enumerate(G.T):
        e = np.eye(3)[int(np.argmin(np.abs(g)))]
        w2 = e - (e @ g) * g
        w2 /= np.linalg.norm(w2)
        out[i] = w2, np.cross(g, w2)
    return out
