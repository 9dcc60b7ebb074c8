"""The compiled closed loop: every wheel model, a gain-matrix controller, the MEKF and thrusters.

One step is two compiled halves with the wheels between them:

- :func:`command_step`: sky (Sun, Moon, eclipses) → gyros (and the gyro filter's
  attitude propagation) → sensor visibility and star tracker → sun and earth sensors
  and the filter's updates → thruster unloading → control law → allocation and
  limits → statistics; it leaves the wheel commands in ``Work.hw_cmd``;
- the wheels realise them (``Work.hw_real``): the wheel models (:func:`run_block`),
  or the wheels on a bus (``hil.Satellite``);
- :func:`finish_step`: log row → the filter's prediction → the plant's RK4 step
  (disturbances, process noise, thrusters) → wheel zero crossings.

``run_block`` runs that step ``steps`` times without returning to Python; HIL calls
the two halves once a control period, so both fly the same code. ``sim.simulate`` calls
``run_block`` once per block (a gain update, or an hour of simulated time), handing it
that block's pre-drawn noise: every noise source has its own random stream, so every
controller sees the same sensor noise and the
same disturbances whatever else it does.

The control law (:func:`control_torque`, also what ``LinearController.torque`` returns) is the
saturation-aware form of a linear law τ = −K s, s = [θ, ω_bo], θ = 2 q_v sign(q4):

    ω_cmd = sat_ω_max(−K_ω⁻¹ K_θ θ),    τ = −K_ω (ω_bo − ω_cmd)

which is exactly −K s while |K_ω⁻¹ K_θ θ| ≤ ω_max, and a rate-limited eigenaxis
slew beyond it, so a large error never asks the wheels for more than they have.

With the filter's disturbance-torque state (``w_hat`` = [ω̂, b̂], P 9×9; see
``ekf``) the filter's model adds b̂ to its known torques and the law feeds it
forward, τ = −K s − b̂ (disturbance accommodation: the integral action LQG
otherwise lacks).

Filter timing: the estimate is propagated with the plant model every step (the
controller needs it); the covariance only once per sensor period, at the
measurement (``ekf.predict_covariance_into``).

Why this module is long: it is one numba-compiled loop. The step functions it calls are
compiled with it (numba inlines and caches them together), and the state and statistics
layouts they share are defined here once.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from rwlab.attitude.ekf import (
    aligned_update_into,
    attitude_error,
    attitude_update_into,
    error_jacobian_into,
    gated_update_into,
    gyro_predict_covariance_into,
    predict_covariance_into,
    propagate_attitude_into,
    skew_into,
)
from rwlab.attitude.plant import rk4_step, rk4_step_forced
from rwlab.attitude.sensors import gyro_sample_into, tracker_visible
from rwlab.attitude.wheels import realise

__all__ = [
    "FLAGS",
    "STATS",
    "Filter",
    "Law",
    "Log",
    "Noise",
    "Plant",
    "Sensors",
    "Sky",
    "State",
    "Work",
    "command_step",
    "control_torque",
    "finish_step",
    "jitter_torque_into",
    "new_stats",
    "new_work",
    "run_block",
    "start_block",
]

# Running statistics the kernel keeps over every step (not only the logged ones).
STATS = (
    "max_error_deg",
    "steady_max_error_deg",
    "steady_max_error_excl_desat_deg",
    "max_error_in_desat_deg",
    "steady_torque_saturated_steps",
    "steady_steps",
    "torque_peak_Nm",
    "steady_torque_sq_sum",
    "steady_error_sq_sum",
    "momentum_peak_fraction",
    "desaturation_count",
    "unloading",
    "unload_end_s",
    "thruster_impulse_Nms",
    "desat_window_steps",
    "steady_excl_desat_steps",
    "eclipse_steps",
    "moon_shadow_steps",
    "steady_eclipse_steps",
    "steady_eclipse_max_error_deg",
    "steady_eclipse_error_sq_sum",
    "steady_outside_eclipse_max_error_deg",
    "steady_outside_eclipse_error_sq_sum",
    "sun_sensor_outages",
    "earth_sensor_blinded",
    "sun_sensor_gated",
    "earth_sensor_gated",
    "no_update_ticks",
    "star_tracker_blinded",
    "steady_torque_jitter_sq_sum",
    "steady_wheel_power_sum",
    "wheel_zero_crossings",
)
_AT = {name: i for i, name in enumerate(STATS)}  # the indices, generated from the list
MAX_ERR, STEADY_MAX = _AT["max_error_deg"], _AT["steady_max_error_deg"]
STEADY_EXCL, DESAT_MAX = _AT["steady_max_error_excl_desat_deg"], _AT["max_error_in_desat_deg"]
SAT_STEPS, STEADY_STEPS = _AT["steady_torque_saturated_steps"], _AT["steady_steps"]
TAU_PEAK, TAU_SQ, ERR_SQ = (
    _AT["torque_peak_Nm"],
    _AT["steady_torque_sq_sum"],
    _AT["steady_error_sq_sum"],
)
H_PEAK, DESAT_COUNT = _AT["momentum_peak_fraction"], _AT["desaturation_count"]
UNLOADING, UNLOAD_END, IMPULSE = _AT["unloading"], _AT["unload_end_s"], _AT["thruster_impulse_Nms"]
DESAT_STEPS, EXCL_STEPS = _AT["desat_window_steps"], _AT["steady_excl_desat_steps"]
ECL_STEPS, MOON_STEPS = _AT["eclipse_steps"], _AT["moon_shadow_steps"]
ECL_STEADY, ECL_MAX = _AT["steady_eclipse_steps"], _AT["steady_eclipse_max_error_deg"]
ECL_SQ = _AT["steady_eclipse_error_sq_sum"]
OUT_MAX = _AT["steady_outside_eclipse_max_error_deg"]
OUT_SQ = _AT["steady_outside_eclipse_error_sq_sum"]
SUN_OUT, EARTH_BLIND = _AT["sun_sensor_outages"], _AT["earth_sensor_blinded"]
SUN_GATED, EARTH_GATED = _AT["sun_sensor_gated"], _AT["earth_sensor_gated"]
NO_UPDATE, TRACKER_BLIND = _AT["no_update_ticks"], _AT["star_tracker_blinded"]
JITTER_SQ, POWER = _AT["steady_torque_jitter_sq_sum"], _AT["steady_wheel_power_sum"]
ZERO_CROSS = _AT["wheel_zero_crossings"]

# The step's entry points are compiled without numba's reference counting: the stages are
# inlined into them and read their arrays from the records, and every such read would
# otherwise cost an atomic increment and decrement (three quarters of the step's time when
# measured). Nothing in them allocates; the functions they call keep the runtime.
_LEAN: dict[str, Any] = {"cache": True, "_nrt": False, "error_model": "numpy"}
# ``command_step`` and ``finish_step`` are also inlined into ``run_block`` (HIL calls them
# from Python as they are): a compiled call passes every record's arrays field by field,
# hundreds of words a call: inlined, the compiled step went from 1.0 to 0.32 µs
# (geo-smallsat, LQR) and from 2.25 to 1.53 µs (geo-comsat, LQG) (measured).
_INLINED: dict[str, Any] = _LEAN | {"inline": "always"}
# Numba's own inlining (``inline="always"``) copies, types and lowers a function again at
# every call site and at every level it is inlined through: it made most of the first
# run's compile (a cold ``simulate`` took a minute). It is kept for what takes the records,
# the stages and the two halves (compiled one by one, each unpacks every record it takes
# and LLVM optimises each again in its caller: measured slower to compile). The
# ``_FORCED`` helpers are compiled once each and inlined by LLVM instead (``forceinline``:
# the same results bit for bit, the same step time; left as plain calls, LLVM kept them
# calls and the step was up to 16 % slower).
_FORCED: dict[str, Any] = _LEAN | {"forceinline": True}

# the filter's modes (``Filter.mode``)
TRUTH, DYNAMICS, GYRO = 0, 1, 2
# the DYNAMICS filter's disturbance state (``Filter.bias_kind``): a body torque alone
TORQUE_STATE = 1


class Plant(NamedTuple):
    """The rigid body and its wheels: ``dt`` (s), orbit rate ``n`` (rad/s), J and J⁻¹ (3, 3),
    the wheel axes G (3, N) and G⁺, momentum limits ``h_max`` (N,), N·m·s, torque limit
    ``tau_max``, N·m, the disturbance vector ``dist`` (``DisturbanceModel.vector``), the
    wheels' spin inertia, kg·m² (for their power), and the factor by which every wheel's
    realised torque differs from its command (motor constant, drive electronics); with
    ``jitter`` the wheels' imbalance [U_s kg·m, U_d kg·m²] (N, 2), their centres (N, 3) m
    and rotor axes ŵ₂, ŵ₃ at angle 0 (N, 2, 3) (:func:`jitter_torque_into`)."""

    dt: float
    n: float
    J: np.ndarray
    J_inv: np.ndarray
    G: np.ndarray
    G_pinv: np.ndarray
    h_max: np.ndarray
    tau_max: float
    dist: np.ndarray
    wheel_inertia: float
    torque_scale: float
    jitter: bool
    imbalance: np.ndarray
    wheel_position: np.ndarray
    rotor_axes: np.ndarray


class Law(NamedTuple):
    """The control law's K_ω (3, 3), K_ω⁻¹ K_θ (3, 3), rate limit ``w_max`` (rad/s), the
    momentum unloading vector ``unload`` (see :func:`run_block`), the wheel momenta the
    unloading steers to, ``hw_target`` (N,) N·m·s (the momentum bias; zeros: none), and the
    wheels' unit null vector ``null`` (N,) (G·null = 0; zeros with three wheels)."""

    K_w: np.ndarray
    M: np.ndarray
    w_max: float
    unload: np.ndarray
    hw_target: np.ndarray
    null: np.ndarray


class Sky(NamedTuple):
    """The sky table of ``ephemeris.sky_table`` (rows, 9), row i at ``t0 + i·step`` s."""

    table: np.ndarray
    t0: float
    step: float


class Sensors(NamedTuple):
    """The true sensors: sun and earth sensors every ``every`` steps (σ rad, alignment
    rotations (3, 3), the sun sensor's field cosine and incidence-noise switch, the earth
    sensor's Sun and Moon exclusion cosines ``blind_cos`` (2,)); gyros when ``gyro`` (par:
    ``GyroModel.vector``, E (3, 3) scale factor and misalignment); a star tracker when
    ``tracker``, every ``tracker_every`` steps (a multiple of ``every``), its frame (3, 3,
    body → tracker), σ (3,) rad and exclusion cosines (3,) (``sensors``)."""

    every: int
    sun_fov_cos: float
    sun_incidence: bool
    sig_sun: float
    sig_earth: float
    sun_align: np.ndarray
    earth_align: np.ndarray
    blind_cos: np.ndarray
    gyro: bool
    gyro_par: np.ndarray
    gyro_E: np.ndarray
    tracker: bool
    tracker_every: int
    tracker_frame: np.ndarray
    tracker_sigma: np.ndarray
    tracker_cos: np.ndarray


class Filter(NamedTuple):
    """The estimator: ``mode`` TRUTH (the controller sees the true state), DYNAMICS (the MEKF
    on the plant model, its disturbance state of kind ``bias_kind``, truth ``bias_true``
    for NEES (unread for the torque state alone, whose truth is the torque the filter does
    not model: :func:`_unmodelled_torque_into`), disturbances it models ``dist_model``)
    or GYRO (the gyro-driven MEKF); its continuous process noise Qc (n, n); the σ it
    assumes for the sun and earth sensors (rad); the innovation ``gate`` (2,); the star
    tracker's covariance ``tracker_R`` (3, 3); the inertia J and J⁻¹ (3, 3) of the
    DYNAMICS filter's model (not necessarily the truth's)."""

    mode: int
    bias_kind: int
    bias_true: np.ndarray
    dist_model: np.ndarray
    Qc: np.ndarray
    r_sun: float
    r_earth: float
    gate: np.ndarray
    tracker_R: np.ndarray
    J: np.ndarray
    J_inv: np.ndarray


class Noise(NamedTuple):
    """A block's pre-drawn noise: process torque (steps, 3) N·m; the sun and earth sensors'
    standard normals (sensor ticks, 6); the gyros' (steps, 9); the tracker's (its ticks, 3)."""

    process: np.ndarray
    sensor: np.ndarray
    gyro: np.ndarray
    tracker: np.ndarray


class Log(NamedTuple):
    """Logging every ``every`` steps into the row arrays; ``steady_from``: the first step of
    the steady-state statistics."""

    every: int
    steady_from: int
    t: np.ndarray
    x: np.ndarray
    est: np.ndarray
    tau: np.ndarray
    nees: np.ndarray
    sky: np.ndarray
    sigma: np.ndarray


class State(NamedTuple):
    """What a block changes in place: the plant x, the estimate q̂ (4,), ŵ (the rest of the
    filter's state: ω̂ [, b̂] or the gyro bias β̂), P (n, n), the gyros' state (9,) =
    [β walk, β Gauss–Markov, ω at the last sample], ``stats`` (:data:`STATS`) and each
    wheel's last sign of spin (N,) (0 before it first turns), for counting zero crossings,
    and each rotor's angle (N,) rad from its ŵ₂ axis (the imbalance's phase)."""

    x: np.ndarray
    q_hat: np.ndarray
    w_hat: np.ndarray
    P: np.ndarray
    gyro: np.ndarray
    stats: np.ndarray
    wheel_sign: np.ndarray
    wheel_angle: np.ndarray


def new_stats() -> np.ndarray:
    """A fresh statistics vector (see :data:`STATS`).

    Returns
    -------
    numpy.ndarray, shape (len(STATS),)
        Zeros, the unloading end at −inf (none yet).
    """
    s = np.zeros(len(STATS))
    s[UNLOAD_END] = -math.inf
    return s


@njit(**_FORCED)
def _sky_at(sky, u, sun, moon):
    """Sun and Moon unit vectors (into ``sun``, ``moon``) and (sunlit, earth_lit,
    moon_visible, srp_scale) at row position ``u`` of the sky table (linear interpolation,
    see ``ephemeris.SKY_COLUMNS``)."""
    i = min(max(int(u), 0), sky.shape[0] - 2)
    f = u - i
    a = sky[i]
    b = sky[i + 1]
    ns = nm = 0.0
    for c in range(3):
        sun[c] = a[c] + f * (b[c] - a[c])
        moon[c] = a[3 + c] + f * (b[3 + c] - a[3 + c])
        ns += sun[c] * sun[c]
        nm += moon[c] * moon[c]
    ns, nm = math.sqrt(ns), math.sqrt(nm)
    for c in range(3):
        sun[c] /= ns
        moon[c] /= nm
    return (
        a[6] + f * (b[6] - a[6]),
        a[7] + f * (b[7] - a[7]),
        a[8] + f * (b[8] - a[8]) > 0.5,
        a[9] + f * (b[9] - a[9]),
    )


@njit(**_FORCED)
def _dcm_into(q, C):
    """C = frames.dcm(q[:4]), element by element (tested equal)."""
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    s = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    C[0, 0], C[1, 1], C[2, 2] = s + 2 * q1 * q1, s + 2 * q2 * q2, s + 2 * q3 * q3
    C[0, 1], C[1, 0] = 2 * (q1 * q2 + q4 * q3), 2 * (q1 * q2 - q4 * q3)
    C[0, 2], C[2, 0] = 2 * (q1 * q3 - q4 * q2), 2 * (q1 * q3 + q4 * q2)
    C[1, 2], C[2, 1] = 2 * (q2 * q3 + q4 * q1), 2 * (q2 * q3 - q4 * q1)


@njit(cache=True)
def _nees(q, q_hat, e, P, L, z):
    """Normalised estimation error squared δxᵀ P⁻¹ δx, δx = [2 (q ⊗ q̂⁻¹)_v, e[3:]] (n,):
    the caller fills ``e[3:]`` with the truth minus the estimate of the rest of the state
    (ω − ω̂, b − b̂ or β − β̂); e[:3] is written here. By a Cholesky factor of P written
    into the (n, n) scratch L (z: (n,) scratch)."""
    e[0], e[1], e[2] = attitude_error(q, q_hat)
    nx = P.shape[0]
    total = 0.0
    for i in range(nx):
        for j in range(i + 1):
            acc = P[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = math.sqrt(acc) if i == j else acc / L[j, j]
        acc = e[i]
        for k in range(i):
            acc -= L[i, k] * z[k]
        z[i] = acc / L[i, i]
        total += z[i] * z[i]
    return total


@njit(**_FORCED)
def _srp_map_into(q, s_orb, sunlit, C, s_body, out):
    """out = ν [ŝ×], ŝ = A(q) s_orb the Sun in body axes: SRP's torque per unit lever arm
    (C (3, 3) and s_body (3,) are scratch)."""
    _dcm_into(q, C)
    _matvec(C, s_orb, s_body)
    skew_into(sunlit * s_body[0], sunlit * s_body[1], sunlit * s_body[2], out)


@njit(cache=True)
def _noisy_into(b, sigma, e0, e1, e2, out):
    """out = unit vector b turned by a small angle: σ times the standard normals e (e × b)."""
    v0 = b[0] + sigma * (e1 * b[2] - e2 * b[1])
    v1 = b[1] + sigma * (e2 * b[0] - e0 * b[2])
    v2 = b[2] + sigma * (e0 * b[1] - e1 * b[0])
    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    out[0], out[1], out[2] = v0 / norm, v1 / norm, v2 / norm


@njit(**_FORCED)
def _matvec(M, v, out):
    """out = M @ v by loops: numba's ``@`` calls BLAS, which costs microseconds on 3×3."""
    for i in range(M.shape[0]):
        acc = 0.0
        for j in range(M.shape[1]):
            acc += M[i, j] * v[j]
        out[i] = acc


@njit(**_FORCED)
def _state_into(qw, n, s):
    """s = [2 q_v sign(q4), ω_bo] for qw = [q, ω] (ω_bo = ω − A(q) (0, −n, 0))."""
    q1, q2, q3, q4 = qw[0], qw[1], qw[2], qw[3]
    sgn = 1.0 if q4 >= 0 else -1.0
    s[0], s[1], s[2] = 2.0 * q1 * sgn, 2.0 * q2 * sgn, 2.0 * q3 * sgn
    c = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    s[3] = qw[4] + n * 2 * (q1 * q2 + q4 * q3)
    s[4] = qw[5] + n * (c + 2 * q2 * q2)
    s[5] = qw[6] + n * 2 * (q2 * q3 - q4 * q1)


@njit(cache=True)
def control_torque(K_w, M, w_max, s):
    """Body torque (3,) of the saturation-aware linear law for s = [θ, ω_bo] (module docstring).

    K_w : (3, 3) rate block of K = [K_θ K_ω]; M : (3, 3) K_ω⁻¹ K_θ; w_max : rate
    limit, rad/s (inf: none).
    """
    tau = np.empty(3)
    _control_into(K_w, M, w_max, s, np.empty(3), tau)
    return tau


@njit(cache=True, inline="always")
def _control_into(K_w, M, w_max, s, work, tau):
    """:func:`control_torque` into ``tau`` with a (3,) ``work`` buffer."""
    _matvec(M, s, work)  # reads s[:3]
    norm = math.sqrt(work[0] * work[0] + work[1] * work[1] + work[2] * work[2])
    scale = w_max / norm if norm > w_max else 1.0
    for i in range(3):
        work[i] = s[3 + i] + scale * work[i]  # ω_bo − ω_cmd, ω_cmd = −sat(M θ)
    _matvec(K_w, work, tau)
    for i in range(3):
        tau[i] = -tau[i]


@njit(**_FORCED)
def _unload_step(stats, unload, hw_target, x, G, h_max, err, t, k, dt, h_body, tau_thr):
    """Momentum unloading: thruster pulses (into ``tau_thr``) against the wheels' body
    momentum off its target G·``hw_target`` (the body momentum into ``h_body``); returns the
    fullest wheel's momentum fraction. Windows start and stop on the wheels' distance from
    ``hw_target`` (the momentum bias), a share of their limits."""
    nw = h_max.shape[0]
    for i in range(3):
        h_body[i] = G[i, 0] * x[7]
        for c in range(1, nw):
            h_body[i] += G[i, c] * x[7 + c]
        tau_thr[i] = 0.0
    h_frac = dev_frac = 0.0
    h_min = h_max[0]
    for i in range(nw):
        h_min = min(h_min, h_max[i])
        h_frac = max(h_frac, abs(x[7 + i]) / h_max[i])
        dev_frac = max(dev_frac, abs(x[7 + i] - hw_target[i]) / h_max[i])
    if unload[0] > 0:
        pointing = err <= unload[6]
        if stats[UNLOADING] == 0 and dev_frac > unload[1] and pointing:
            stats[UNLOADING] = 1
            stats[DESAT_COUNT] += 1
        if stats[UNLOADING] == 1:
            if dev_frac <= unload[2]:
                stats[UNLOADING] = 0
                stats[UNLOAD_END] = t
            elif k % int(unload[4]) == 0 and pointing:  # no pulses during a slew
                fired = False
                for i in range(3):
                    dev = h_body[i]
                    for c in range(nw):
                        dev -= G[i, c] * hw_target[c]
                    if abs(dev) > unload[2] * h_min:
                        tau_thr[i] = -math.copysign(unload[3], dev)
                        stats[IMPULSE] += unload[3] * dt
                        fired = True
                if not fired:  # what is left lies in the wheels' null space
                    stats[UNLOADING] = 0
                    stats[UNLOAD_END] = t
    return h_frac


@njit(**_FORCED)
def _count_zero_crossings(stats, x, h_max, sign):
    """Count the wheels whose spin changed sign since their last non-zero speed (a wheel
    within 1e-9 of its momentum limit of zero is at rest: no sign)."""
    for i in range(h_max.shape[0]):
        h = x[7 + i]
        s = 1.0 if h > 1e-9 * h_max[i] else (-1.0 if h < -1e-9 * h_max[i] else 0.0)
        if s != 0.0:
            if sign[i] != 0.0 and s != sign[i]:
                stats[ZERO_CROSS] += 1
            sign[i] = s


@njit(**_FORCED)
def _steady_stats(stats, err, hw_cmd, hw_prev, x, wheel_inertia, at_limit, in_desat, earth_lit):
    """The steady window's statistics of one step."""
    nw = hw_cmd.shape[0]
    stats[STEADY_MAX] = max(stats[STEADY_MAX], err)
    stats[STEADY_STEPS] += 1
    stats[ERR_SQ] += err * err
    for i in range(nw):
        stats[TAU_SQ] += hw_cmd[i] * hw_cmd[i] / nw
        d = hw_cmd[i] - hw_prev[i]  # white jitter of σ gives E[d²] = 2σ²
        stats[JITTER_SQ] += d * d / (2 * nw)
        stats[POWER] += abs(hw_cmd[i] * x[7 + i] / wheel_inertia)
    if at_limit:
        stats[SAT_STEPS] += 1
    if in_desat:
        stats[DESAT_MAX] = max(stats[DESAT_MAX], err)
        stats[DESAT_STEPS] += 1
    else:
        stats[STEADY_EXCL] = max(stats[STEADY_EXCL], err)
        stats[EXCL_STEPS] += 1
    if earth_lit < 1.0:
        stats[ECL_STEADY] += 1
        stats[ECL_MAX] = max(stats[ECL_MAX], err)
        stats[ECL_SQ] += err * err
    else:
        stats[OUT_MAX] = max(stats[OUT_MAX], err)
        stats[OUT_SQ] += err * err


@njit(cache=True)
def _tracker_measurement(x, frame, sigma, e, out):
    """The tracker's quaternion: the truth turned by its noise (σ·e about its own axes)."""
    v0, v1, v2 = sigma[0] * e[0], sigma[1] * e[1], sigma[2] * e[2]
    for i in range(4):
        out[i] = x[i]
    b0 = frame[0, 0] * v0 + frame[1, 0] * v1 + frame[2, 0] * v2  # body = frameᵀ v
    b1 = frame[0, 1] * v0 + frame[1, 1] * v1 + frame[2, 1] * v2
    b2 = frame[0, 2] * v0 + frame[1, 2] * v1 + frame[2, 2] * v2
    propagate_attitude_into(out, b0, b1, b2, 1.0)


# The step's scalars that outlive a stage (``Work.flags``): the block's sensor and tracker
# noise rows used, the sensors' status (0 used, 1 unavailable, 2 gated) and consecutive
# rejections, the sky at this step, whether the filter measured, the true pointing error (°),
# whether a wheel command hit the torque limit, whether a wheel touched its momentum limit,
# and which measurements reached the filter this step (HIL records them).
FLAGS = (
    "i_sensor",
    "i_tracker",
    "sun_status",
    "earth_status",
    "tracker_status",
    "sun_rejected",
    "earth_rejected",
    "sunlit",
    "earth_lit",
    "moon_visible",
    "srp_scale",
    "measured",
    "error_deg",
    "at_limit",
    "saturated",
    "sun_used",
    "earth_used",
    "tracker_used",
)
_FL = {name: i for i, name in enumerate(FLAGS)}
I_SENSOR, I_TRACKER = _FL["i_sensor"], _FL["i_tracker"]
SUN_STATUS, EARTH_STATUS, TRACKER_STATUS = (
    _FL["sun_status"],
    _FL["earth_status"],
    _FL["tracker_status"],
)
SUN_REJ, EARTH_REJ = _FL["sun_rejected"], _FL["earth_rejected"]
SUNLIT, EARTH_LIT, MOON_VISIBLE, SRP_SCALE = (
    _FL["sunlit"],
    _FL["earth_lit"],
    _FL["moon_visible"],
    _FL["srp_scale"],
)
MEASURED, ERROR, AT_LIMIT, SATURATED = (
    _FL["measured"],
    _FL["error_deg"],
    _FL["at_limit"],
    _FL["saturated"],
)
SUN_USED, EARTH_USED, TRACKER_USED = _FL["sun_used"], _FL["earth_used"], _FL["tracker_used"]


class Work(NamedTuple):
    """The step's working memory, allocated once per run (:func:`new_work`): what one stage
    hands the next (``flags``: :data:`FLAGS`; the wheel commands ``hw_cmd``, the previous
    step's ``hw_prev`` and the realised torques ``hw_real`` (N,) N·m; the torque the wheels
    must make up for besides the law's, ``tau_known`` (3,) N·m (HIL: idled wheels); the
    thruster torque ``tau_thr``; the law's torque ``tau``; the disturbance feed-forward
    ``tau_b``; what the law sees ``est`` = [q, ω] (7,); the Sun and Moon, orbital ``s_orb``,
    ``m_orb`` and body ``sun_b``, ``moon_b``, ``nadir_b``; the measurements that reached
    the filter ``sun_meas``, ``earth_meas`` (3,) and ``q_meas`` (4,); the gyros' mean rate
    ``w_mean`` and measurement ``w_meas``) and scratch for the stages (no stage allocates)."""

    flags: np.ndarray
    hw_cmd: np.ndarray
    hw_prev: np.ndarray
    hw_real: np.ndarray
    tau_known: np.ndarray
    tau_thr: np.ndarray
    tau: np.ndarray
    tau_b: np.ndarray
    est: np.ndarray
    s_orb: np.ndarray
    m_orb: np.ndarray
    sun_b: np.ndarray
    moon_b: np.ndarray
    nadir_b: np.ndarray
    sun_meas: np.ndarray
    earth_meas: np.ndarray
    q_meas: np.ndarray
    w_mean: np.ndarray
    w_meas: np.ndarray
    h_body: np.ndarray
    s: np.ndarray
    v3: np.ndarray
    b_true: np.ndarray
    sun_hat: np.ndarray
    d: np.ndarray
    dm: np.ndarray
    xm: np.ndarray
    rk4: np.ndarray
    F: np.ndarray
    W3: np.ndarray
    Wn: np.ndarray
    C: np.ndarray
    C_hat: np.ndarray
    Bmap: np.ndarray
    e_nees: np.ndarray
    nees_work: np.ndarray
    forcing: np.ndarray


def new_work(plant: Plant, filt: Filter, nx: int) -> Work:
    """The working memory of a run (:class:`Work`) for ``nx`` filter states.

    Parameters
    ----------
    plant : Plant
        The plant record (its wheel count and disturbance vector).
    filt : Filter
        The estimator record (its disturbance kind and model).
    nx : int
        The filter's state size (6, 9 or 12).

    Returns
    -------
    Work
    """
    nw = plant.h_max.shape[0]
    m = 7 + nw
    Bmap = np.zeros((3, max(nx - 6, 3)))  # the filter's torque per unit of its b̂
    if filt.bias_kind != 2:  # the constant torque's columns come first
        Bmap[:, :3] = np.eye(3)

    def v(n: int) -> np.ndarray:
        return np.zeros(n)

    return Work(
        flags=v(len(FLAGS)),
        hw_cmd=v(nw),
        hw_prev=v(nw),
        hw_real=v(nw),
        tau_known=v(3),
        tau_thr=v(3),
        tau=v(3),
        tau_b=v(3),
        est=v(7),
        s_orb=v(3),
        m_orb=v(3),
        sun_b=v(3),
        moon_b=v(3),
        nadir_b=v(3),
        sun_meas=v(3),
        earth_meas=v(3),
        q_meas=v(4),
        w_mean=v(3),
        w_meas=v(3),
        h_body=v(3),
        s=v(6),
        v3=v(3),
        b_true=v(3),
        sun_hat=v(3),
        d=plant.dist.copy(),
        dm=filt.dist_model.copy(),
        xm=v(m),
        rk4=np.zeros((5, m)),
        F=np.zeros((nx, nx)),
        W3=np.zeros((4, 3, 3)),
        Wn=np.zeros((6, nx, nx)),
        C=np.zeros((3, 3)),
        C_hat=np.zeros((3, 3)),
        Bmap=Bmap,
        e_nees=v(nx),
        nees_work=np.zeros((5, 3)),
        forcing=np.zeros((3, 3)),
    )


@njit(**_FORCED)
def _copy_into(a, out):
    """out[:] = a by a loop (a slice assignment needs numba's runtime: see ``_LEAN``)."""
    for i in range(a.shape[0]):
        out[i] = a[i]


@njit(cache=True)
def start_block(work):
    """A block starts: the sensors' rows of its noise from the first, statuses and
    rejection counts afresh."""
    for i in (I_SENSOR, I_TRACKER, SUN_STATUS, EARTH_STATUS, TRACKER_STATUS, SUN_REJ, EARTH_REJ):
        work.flags[i] = 0.0


@njit(cache=True, inline="always")
def _sky_stage(work, stats, sky, k, t):
    """The Sun and Moon at t (into ``work``), and the eclipse counters."""
    f = work.flags
    sunlit, earth_lit, moon_visible, srp_scale = _sky_at(
        sky.table, (t - sky.t0) / sky.step, work.s_orb, work.m_orb
    )
    f[SUNLIT], f[EARTH_LIT] = sunlit, earth_lit
    f[MOON_VISIBLE], f[SRP_SCALE] = 1.0 if moon_visible else 0.0, srp_scale
    if k > 0:  # sample k stands for the step that ends there: steps + 1 samples, steps·dt
        if earth_lit < 1.0:
            stats[ECL_STEPS] += 1
        if sunlit < earth_lit:
            stats[MOON_STEPS] += 1


@njit(cache=True, inline="always")
def _gyro_stage(state, work, sensors, mode, gyro_noise, k, n, dt):
    """The gyros' sample over the last step; the gyro filter propagates q̂ with it."""
    x, gs, w_mean = state.x, state.gyro, work.w_mean
    for c in range(3):  # the angle turned over the last step, as a rate
        w_mean[c] = 0.5 * (gs[6 + c] + x[4 + c])
        gs[6 + c] = x[4 + c]
    gyro_sample_into(w_mean, sensors.gyro_E, sensors.gyro_par, gs, gyro_noise, work.w_meas)
    if mode == GYRO and k > 0:  # q̂ over the last step with ω̂ = ω_m − β̂
        w, C = work.v3, work.C_hat
        for c in range(3):
            w[c] = work.w_meas[c] - state.w_hat[c]
        _dcm_into(state.q_hat, C)
        propagate_attitude_into(
            state.q_hat, w[0] + n * C[0, 1], w[1] + n * C[1, 1], w[2] + n * C[2, 1], dt
        )


@njit(cache=True, inline="always")
def _visibility_stage(state, work, sensors, filt, noise, k):
    """At a sensor tick: what each sensor can see, and the star tracker's update."""
    f, x, C = work.flags, state.x, work.C
    _dcm_into(x, C)
    _matvec(C, work.s_orb, work.sun_b)
    _matvec(C, work.m_orb, work.moon_b)
    for c in range(3):
        work.nadir_b[c] = C[c, 2]
    sunlit, moon_visible = f[SUNLIT], f[MOON_VISIBLE] > 0.5
    # the sun sensor needs the whole disc inside its field; the earth sensor (boresight +z)
    # is blinded by a visible Sun or Moon inside its exclusion cone
    sun_ok = sunlit >= 1.0 and -work.sun_b[0] >= sensors.sun_fov_cos
    earth_ok = not (
        (sunlit > 0.0 and work.sun_b[2] >= sensors.blind_cos[0])
        or (moon_visible and work.moon_b[2] >= sensors.blind_cos[1])
    )
    f[SUN_STATUS] = 0.0 if sun_ok else 1.0
    f[EARTH_STATUS] = 0.0 if earth_ok else 1.0
    f[TRACKER_USED] = 0.0
    if sensors.tracker and k % sensors.tracker_every == 0:
        seen = tracker_visible(
            sensors.tracker_frame,
            work.sun_b,
            work.moon_b,
            work.nadir_b,
            sunlit,
            moon_visible,
            sensors.tracker_cos,
        )
        f[TRACKER_STATUS] = 0.0 if seen else 1.0
        if not seen:
            state.stats[TRACKER_BLIND] += 1
        elif filt.mode != TRUTH:
            e = noise.tracker[int(f[I_TRACKER])]
            _tracker_measurement(x, sensors.tracker_frame, sensors.tracker_sigma, e, work.q_meas)
            attitude_update_into(
                state.q_hat, state.w_hat, state.P, work.q_meas, filt.tracker_R, work.Wn
            )
            f[TRACKER_USED] = 1.0
        f[I_TRACKER] += 1


@njit(cache=True, inline="always")
def _vector_update(state, work, b, ref, r, rejected, filt, at):
    """One vector sensor's gated update (its misalignment states at ``at``; 0: none);
    whether the filter took it. ``rejected``: that sensor's consecutive rejections."""
    g = filt.gate[0] if rejected < filt.gate[1] else 0.0
    if at > 0:
        return aligned_update_into(state.q_hat, state.w_hat, state.P, b, ref, r, g, at, work.Wn)
    return gated_update_into(state.q_hat, state.w_hat, state.P, b, ref, r, g, work.Wn)


@njit(cache=True, inline="always")
def _measure_stage(state, work, sensors, filt, sensor_noise):
    """The sun and earth sensors' measurements and the filter's updates (a sensor tick)."""
    f, stats, nx = work.flags, state.stats, state.P.shape[0]
    e = sensor_noise[int(f[I_SENSOR])]
    f[I_SENSOR] += 1
    f[SUN_USED] = f[EARTH_USED] = 0.0
    if f[SUN_STATUS] == 0.0:
        sun_b = work.sun_b
        cos_i = -sun_b[0] if sensors.sun_incidence else 1.0  # noise ∝ 1/cos(incidence)
        _matvec(sensors.sun_align, sun_b, work.b_true)
        _noisy_into(work.b_true, sensors.sig_sun / cos_i, e[0], e[1], e[2], work.sun_meas)
        b = work.sun_meas
        r = filt.r_sun / max(-b[0], 1e-3) if sensors.sun_incidence else filt.r_sun
        at = 6 if filt.mode == GYRO and nx >= 9 else 0  # the sun sensor's misalignment
        ok = _vector_update(state, work, b, work.s_orb, r, f[SUN_REJ], filt, at)
        f[SUN_USED] = 1.0
        f[SUN_REJ] = 0.0 if ok else f[SUN_REJ] + 1
        if not ok:
            stats[SUN_GATED] += 1
            f[SUN_STATUS] = 2.0
    else:
        stats[SUN_OUT] += 1
    if f[EARTH_STATUS] == 0.0:
        _matvec(sensors.earth_align, work.nadir_b, work.b_true)
        _noisy_into(work.b_true, sensors.sig_earth, e[3], e[4], e[5], work.earth_meas)
        at = 9 if filt.mode == GYRO and nx == 12 else 0
        nadir = work.v3
        nadir[0], nadir[1], nadir[2] = 0.0, 0.0, 1.0
        ok = _vector_update(
            state, work, work.earth_meas, nadir, filt.r_earth, f[EARTH_REJ], filt, at
        )
        f[EARTH_USED] = 1.0
        f[EARTH_REJ] = 0.0 if ok else f[EARTH_REJ] + 1
        if not ok:
            stats[EARTH_GATED] += 1
            f[EARTH_STATUS] = 2.0
    else:
        stats[EARTH_BLIND] += 1
    no_tracker = not sensors.tracker or f[TRACKER_STATUS] != 0.0
    if f[SUN_STATUS] != 0.0 and f[EARTH_STATUS] != 0.0 and no_tracker:
        stats[NO_UPDATE] += 1


@njit(cache=True, inline="always")
def _control_stage(state, work, law, filt, n):
    """What the law sees (the truth, or the estimate) and its torque, less the estimated
    disturbance (disturbance accommodation)."""
    x, est, mode = state.x, work.est, filt.mode
    for i in range(4):
        est[i] = x[i] if mode == TRUTH else state.q_hat[i]
    for i in range(3):
        if mode == TRUTH:
            est[4 + i] = x[4 + i]
        elif mode == GYRO:
            est[4 + i] = work.w_meas[i] - state.w_hat[i]
        else:
            est[4 + i] = state.w_hat[i]
    _state_into(est, n, work.s)
    _control_into(law.K_w, law.M, law.w_max, work.s, work.v3, work.tau)
    if mode == DYNAMICS and state.P.shape[0] > 6:  # cancel the estimated torque
        Bmap = work.Bmap
        if filt.bias_kind >= 2:
            srp_map = Bmap[:, 3:] if filt.bias_kind == 3 else Bmap[:, :3]
            _srp_map_into(
                state.q_hat, work.s_orb, work.flags[SRP_SCALE], work.C_hat, work.sun_hat, srp_map
            )
        _matvec(Bmap, state.w_hat[3:], work.tau_b)
        for i in range(3):
            work.tau[i] -= work.tau_b[i]


@njit(cache=True, inline="always")
def _allocate_stage(state, work, plant, law, h_frac):
    """The wheel commands: the body torque (feedback, plus the known thruster torque and
    ``tau_known`` fed forward) through G⁺, the null-space momentum bias, the torque limit."""
    x, hw_cmd, v, stats, unload = state.x, work.hw_cmd, work.v3, state.stats, law.unload
    nw = hw_cmd.shape[0]
    for i in range(3):
        v[i] = work.tau_thr[i] - work.tau[i] - work.tau_known[i]
    _matvec(plant.G_pinv, v, hw_cmd)
    if unload[7] > 0:  # null-space momentum bias: wheel torques that turn no body
        c = 0.0
        for i in range(nw):
            c += law.null[i] * (law.hw_target[i] - x[7 + i])
        c = min(max(unload[7] * c, -unload[8]), unload[8])
        for i in range(nw):
            hw_cmd[i] += c * law.null[i]
    at_limit = False
    for i in range(nw):
        if abs(hw_cmd[i]) >= plant.tau_max:
            at_limit = True
        hw_cmd[i] = min(max(hw_cmd[i], -plant.tau_max), plant.tau_max)
        stats[TAU_PEAK] = max(stats[TAU_PEAK], abs(hw_cmd[i]))
    stats[H_PEAK] = max(stats[H_PEAK], h_frac)
    work.flags[AT_LIMIT] = 1.0 if at_limit else 0.0
    if h_frac >= 0.999:
        work.flags[SATURATED] = 1.0


@njit(cache=True, inline="always")
def _account_stage(state, work, plant, unload, k, j, t, steady_from):
    """The statistics of the step: the worst error, and the steady window's."""
    stats, err, hw_cmd = state.stats, work.flags[ERROR], work.hw_cmd
    in_desat = stats[UNLOADING] == 1 or t - stats[UNLOAD_END] <= unload[5]
    stats[MAX_ERR] = max(stats[MAX_ERR], err)
    if k >= steady_from:
        if k == steady_from or j == 0:  # no previous command in this window
            _copy_into(hw_cmd, work.hw_prev)
        _steady_stats(
            stats,
            err,
            hw_cmd,
            work.hw_prev,
            state.x,
            plant.wheel_inertia,
            work.flags[AT_LIMIT] > 0,
            in_desat,
            work.flags[EARTH_LIT],
        )
    _copy_into(hw_cmd, work.hw_prev)


@njit(**_INLINED)
def command_step(state, work, k, j, plant, law, sky, sensors, filt, noise, steady_from):
    """The first half of step ``k`` (row ``j`` of the block's noise): sky, gyros, sensors
    and the filter's updates, thruster unloading, the control law and the wheel commands
    (into ``work.hw_cmd``, N·m), and the step's statistics. The wheels act between the two
    halves: ``run_block`` runs their models, HIL sends the commands on a bus."""
    dt, f, x = plant.dt, work.flags, state.x
    t = k * dt
    _sky_stage(work, state.stats, sky, k, t)
    if sensors.gyro:
        _gyro_stage(state, work, sensors, filt.mode, noise.gyro[j], k, plant.n, dt)
    if k % sensors.every == 0:
        _visibility_stage(state, work, sensors, filt, noise, k)
    f[MEASURED] = 1.0 if filt.mode != TRUTH and k % sensors.every == 0 else 0.0
    if f[MEASURED] > 0:  # no update through an outage: the filter only propagates
        _measure_stage(state, work, sensors, filt, noise.sensor)
    qv = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    f[ERROR] = math.degrees(2.0 * math.asin(min(1.0, qv)))  # true error (target: orbital frame)
    h_frac = _unload_step(
        state.stats,
        law.unload,
        law.hw_target,
        x,
        plant.G,
        plant.h_max,
        f[ERROR],
        t,
        k,
        dt,
        work.h_body,
        work.tau_thr,
    )
    _control_stage(state, work, law, filt, plant.n)
    _allocate_stage(state, work, plant, law, h_frac)
    _account_stage(state, work, plant, law.unload, k, j, t, steady_from)


@njit(cache=True, inline="always")
def _nees_of(state, work, plant, sensors, filt):
    """The filter's NEES now (:func:`_nees`), the rest of its error state filled in."""
    x, w_hat, mode, e, gs = state.x, state.w_hat, filt.mode, work.e_nees, state.gyro
    for i in range(3, state.P.shape[0]):
        if mode == GYRO and i >= 6:  # the sun sensor's misalignment
            e[i] = filt.bias_true[i - 6] - w_hat[i - 3]
        elif mode == GYRO:  # what β̂ stands for: the bias plus E ω
            e[i] = gs[i - 3] + gs[i] - w_hat[i - 3]
            for c in range(3):
                e[i] += sensors.gyro_E[i - 3, c] * work.w_mean[c]
        elif i < 6:
            e[i] = x[1 + i] - w_hat[i - 3]
        elif filt.bias_kind == TORQUE_STATE:  # b̂ absorbs every torque the filter lacks
            if i == 6:
                _unmodelled_torque_into(x, work, plant, filt, work.nees_work[0])
            e[i] = work.nees_work[0, i - 6] - w_hat[i - 3]
        else:
            e[i] = filt.bias_true[i - 6] - w_hat[i - 3]
    return _nees(x, state.q_hat, e, state.P, work.Wn[0], work.Wn[1, 0])


@njit(cache=True, inline="always")
def _unmodelled_torque_into(x, work, plant, filt, out):
    """What the filter's torque state b̂ should equal now, N·m (3,) into ``out``: the
    disturbance torque at the true attitude less the filter's model of it (its inertia,
    its disturbance vector), both at this step's solar pressure scale and with their own
    constant torques, without the process noise (white: no state can track it) or the
    thrusters (the filter knows them). With the constant torque alone as the truth, b̂
    was compared with 0 on a spacecraft whose b̂ carries the solar pressure torque through
    the centre-of-pressure offset (NEES ~1e4 for 9 states)."""
    srp, t, C = work.flags[SRP_SCALE], work.nees_work[1], work.nees_work[2:]
    _disturbance_into(x, plant.J, plant.dist, srp, work.s_orb, work.m_orb, C, out)
    _disturbance_into(x, filt.J, filt.dist_model, srp, work.s_orb, work.m_orb, C, t)
    for c in range(3):
        out[c] -= t[c]


@njit(cache=True)
def _disturbance_into(q, J, dist, srp_scale, sun_orb, moon_orb, C, out):
    """``plant.disturbance_torque`` (3,) N·m at q with ``dist[1]`` scaled by ``srp_scale``,
    into ``out``, allocating nothing (C: (3, 3) scratch; a test holds the two equal)."""
    _dcm_into(q, C)
    r0, r1, r2 = C[0, 2], C[1, 2], C[2, 2]  # nadir in body axes
    s0 = C[0, 0] * sun_orb[0] + C[0, 1] * sun_orb[1] + C[0, 2] * sun_orb[2]
    s1 = C[1, 0] * sun_orb[0] + C[1, 1] * sun_orb[1] + C[1, 2] * sun_orb[2]
    s2 = C[2, 0] * sun_orb[0] + C[2, 1] * sun_orb[1] + C[2, 2] * sun_orb[2]
    m0 = C[0, 0] * moon_orb[0] + C[0, 1] * moon_orb[1] + C[0, 2] * moon_orb[2]
    m1 = C[1, 0] * moon_orb[0] + C[1, 1] * moon_orb[1] + C[1, 2] * moon_orb[2]
    m2 = C[2, 0] * moon_orb[0] + C[2, 1] * moon_orb[1] + C[2, 2] * moon_orb[2]
    p = dist[1] * srp_scale
    for c in range(3):
        out[c] = dist[7 + c]
    _add_gradient(out, dist[0], J, r0, r1, r2)
    _add_gradient(out, dist[5], J, s0, s1, s2)
    _add_gradient(out, dist[6], J, m0, m1, m2)
    out[0] -= p * (dist[3] * s2 - dist[4] * s1)  # ρ × (−P ŝ)
    out[1] -= p * (dist[4] * s0 - dist[2] * s2)
    out[2] -= p * (dist[2] * s1 - dist[3] * s0)


@njit(cache=True, forceinline=True)
def _add_gradient(out, gain, J, a0, a1, a2):
    """out += gain · a × (J a): a gradient torque along the unit vector a (body axes)."""
    j0 = J[0, 0] * a0 + J[0, 1] * a1 + J[0, 2] * a2
    j1 = J[1, 0] * a0 + J[1, 1] * a1 + J[1, 2] * a2
    j2 = J[2, 0] * a0 + J[2, 1] * a1 + J[2, 2] * a2
    out[0] += gain * (a1 * j2 - a2 * j1)
    out[1] += gain * (a2 * j0 - a0 * j2)
    out[2] += gain * (a0 * j1 - a1 * j0)


@njit(cache=True, inline="always")
def _log_stage(state, work, plant, sensors, filt, log, log_k, t):
    """One logged row (see :func:`run_block`)."""
    x, w_hat, f, mode, nx = state.x, state.w_hat, work.flags, filt.mode, state.P.shape[0]
    log.t[log_k] = t
    for i in range(x.shape[0]):
        log.x[log_k, i] = x[i]
    for i in range(7):
        log.est[log_k, i] = work.est[i]
    for i in range(7, log.est.shape[1]):
        log.est[log_k, i] = 0.0
    if mode == DYNAMICS and nx > 6:
        at = 10 if filt.bias_kind == 2 else 7  # log columns: b, then β
        for i in range(nx - 6):
            log.est[log_k, at + i] = w_hat[3 + i]
    if mode == GYRO:
        for i in range(min(nx, 9) - 3):  # β̂, then φ̂ of the sun sensor
            log.est[log_k, 13 + i] = w_hat[i]
    for i in range(3):
        log.tau[log_k, i] = 0.0
        for c in range(work.hw_real.shape[0]):
            log.tau[log_k, i] -= plant.G[i, c] * work.hw_real[c]
    if mode != TRUTH:
        log.nees[log_k] = _nees_of(state, work, plant, sensors, filt) if f[MEASURED] > 0 else np.nan
        for i in range(min(nx, 6)):
            log.sigma[log_k, i] = math.sqrt(state.P[i, i])
    log.sky[log_k, 0] = f[SUNLIT]
    log.sky[log_k, 1] = f[SUN_STATUS]
    log.sky[log_k, 2] = f[EARTH_STATUS]
    log.sky[log_k, 3] = f[TRACKER_STATUS] if sensors.tracker else 1.0


@njit(cache=True, inline="always")
def _predict_stage(state, work, plant, sensors, filt):
    """The filter to the next step: its covariance to the next measurement (at one), and
    the DYNAMICS filter's state through its own plant model."""
    f, mode, P = work.flags, filt.mode, state.P
    dm = work.dm
    dm[1] = filt.dist_model[1] * f[SRP_SCALE]
    if f[MEASURED] > 0:  # covariance to the next measurement, F at this estimate
        T_sensor = sensors.every * plant.dt
        if mode == GYRO:  # F's blocks written out: a tenth of the dense products
            gyro_predict_covariance_into(P, work.est[4:7], filt.Qc, T_sensor, work.Wn)
        else:
            error_jacobian_into(
                state.q_hat,
                state.w_hat,
                work.h_body,
                filt.J,
                filt.J_inv,
                plant.n,
                filt.dist_model[0],
                work.Bmap,
                work.F,
                work.W3,
            )
            predict_covariance_into(P, work.F, filt.Qc, T_sensor, work.Wn)
    if mode == DYNAMICS:
        x, xm = state.x, work.xm
        for i in range(x.shape[0]):
            xm[i] = state.q_hat[i] if i < 4 else (state.w_hat[i - 4] if i < 7 else x[i])
        for i in range(3):  # the thruster command (and b̂'s torque) is known to the filter
            dm[7 + i] = filt.dist_model[7 + i] + work.tau_thr[i] + work.tau_b[i]
        # the filter knows the wheels' torques and momenta (their tachometers)
        rk4_step(
            xm,
            work.hw_real,
            plant.dt,
            filt.J,
            filt.J_inv,
            plant.G,
            plant.h_max,
            plant.n,
            dm,
            work.s_orb,
            work.m_orb,
            work.rk4,
        )
        for i in range(4):
            state.q_hat[i] = xm[i]
        for i in range(3):
            state.w_hat[i] = xm[4 + i]


@njit(cache=True)
def jitter_torque_into(plant, x, angle, ahead, out):
    """The wheels' imbalance torque on the body (3,) N·m, ``ahead`` s after the state x with
    rotor angles ``angle`` (N,) rad (each rotor turning at its speed now), into ``out``.

    Basilisk's simple jitter model (``reactionWheelStateEffector``, JitterSimple): a rotor
    at angle θ and speed Ω relative to the body puts the force F = U_s Ω² ŵ₂(θ) on the body
    at its centre r and the torque U_d Ω² ŵ₂(θ), ŵ₂(θ) = cos θ ŵ₂ + sin θ ŵ₃ (ŵ₃ = ĝ × ŵ₂):
    τ = r × F + U_d Ω² ŵ₂(θ). Ω = h_w / J_s − ĝᵀω (h_w is the absolute momentum, see
    ``plant``)."""
    G, r, axes = plant.G, plant.wheel_position, plant.rotor_axes
    out[0] = out[1] = out[2] = 0.0
    for i in range(G.shape[1]):
        omega = x[7 + i] / plant.wheel_inertia - (G[0, i] * x[4] + G[1, i] * x[5] + G[2, i] * x[6])
        th = angle[i] + omega * ahead
        c, s = math.cos(th), math.sin(th)
        u0 = c * axes[i, 0, 0] + s * axes[i, 1, 0]
        u1 = c * axes[i, 0, 1] + s * axes[i, 1, 1]
        u2 = c * axes[i, 0, 2] + s * axes[i, 1, 2]
        fs, td = plant.imbalance[i, 0] * omega * omega, plant.imbalance[i, 1] * omega * omega
        out[0] += r[i, 1] * fs * u2 - r[i, 2] * fs * u1 + td * u0
        out[1] += r[i, 2] * fs * u0 - r[i, 0] * fs * u2 + td * u1
        out[2] += r[i, 0] * fs * u1 - r[i, 1] * fs * u0 + td * u2


@njit(cache=True, inline="always")
def _jitter_stage(state, work, plant):
    """The imbalance torques at the RK4 stages' times (``work.forcing``), and each rotor's
    angle advanced over the step (at its speed at the step's start, as the forcing)."""
    x, dt, angle = state.x, plant.dt, state.wheel_angle
    for s in range(3):
        jitter_torque_into(plant, x, angle, 0.5 * dt * s, work.forcing[s])
    G = plant.G
    for i in range(G.shape[1]):
        omega = x[7 + i] / plant.wheel_inertia - (G[0, i] * x[4] + G[1, i] * x[5] + G[2, i] * x[6])
        angle[i] = (angle[i] + omega * dt) % (2.0 * math.pi)


@njit(cache=True, inline="always")
def _propagate_stage(state, work, plant, process_noise, h_reported):
    """The plant over the step (RK4) under the disturbances, the process noise, the
    thrusters and the realised wheel torques; with ``h_reported`` (N,) the wheels'
    momenta are then the ones they report (HIL; empty: the integrated ones)."""
    x, d = state.x, work.d
    for i in range(3):
        d[7 + i] = plant.dist[7 + i] + process_noise[i] + work.tau_thr[i]
    d[1] = plant.dist[1] * work.flags[SRP_SCALE]  # SRP: none in the shadow, ∝ 1/r² of the Sun
    J, J_inv, G, h_max, n, dt = plant.J, plant.J_inv, plant.G, plant.h_max, plant.n, plant.dt
    if plant.jitter:  # the wheels' imbalance, turning with the rotors within the step
        _jitter_stage(state, work, plant)
        rk4_step_forced(
            x, work.hw_real, dt, J, J_inv, G, h_max, n, d, work.s_orb, work.m_orb, work.rk4,
            work.forcing,
        )  # fmt: skip
    else:
        rk4_step(x, work.hw_real, dt, J, J_inv, G, h_max, n, d, work.s_orb, work.m_orb, work.rk4)
    for i in range(h_reported.shape[0]):
        x[7 + i] = min(max(h_reported[i], -plant.h_max[i]), plant.h_max[i])
    _count_zero_crossings(state.stats, x, plant.h_max, state.wheel_sign)


@njit(**_INLINED)
def finish_step(state, work, k, j, log_k, plant, sensors, filt, noise, log, h_reported):
    """The second half of step ``k``, after the wheels realised ``work.hw_real`` (N,) N·m:
    the log row (every ``log.every`` steps), the filter's prediction and the plant's
    propagation (``h_reported``: see :func:`_propagate_stage`). Returns the next log row."""
    if k % log.every == 0:
        _log_stage(state, work, plant, sensors, filt, log, log_k, k * plant.dt)
        log_k += 1
    _predict_stage(state, work, plant, sensors, filt)
    _propagate_stage(state, work, plant, noise.process[j], h_reported)
    return log_k


@njit(cache=True, inline="always")
def _actuate_stage(work, wheels, plant, x, t):
    """The wheel models realise the commands (into ``work.hw_real``)."""
    realise(
        wheels.kind,
        t,
        plant.dt,
        work.hw_cmd,
        x,
        wheels.healthy,
        wheels.faulty,
        wheels.fault_s,
        wheels.state,
        (wheels.A, wheels.B, wheels.C, wheels.ident, wheels.servo),
        wheels.nominal,
        work.hw_real,
    )
    if plant.torque_scale != 1.0:  # the tachometers see what the wheels really did
        for i in range(work.hw_real.shape[0]):
            work.hw_real[i] *= plant.torque_scale


@njit(**_LEAN)
def run_block(state, work, k0, steps, log_k, plant, law, sky, sensors, filt, noise, wheels, log):
    """Run ``steps`` steps from step index ``k0``; returns the next log row and whether a
    wheel touched its momentum limit (in this run so far).

    Each step is :func:`command_step`, the wheel models (``wheels.realise``) and
    :func:`finish_step` — the step HIL runs with its wheels on a bus in between.
    ``state`` (:class:`State`) is updated in place, as are ``work`` (:class:`Work`), the
    wheels' state and the log rows from ``log_k`` (:class:`Log`). The records say what
    each input is; besides them: ``law.unload`` = [enabled, start fraction, stop fraction,
    pulse torque N·m, steps between pulses, recovery s, pointing error (°) above which no
    window starts and no pulse fires, null-space bias gain (1/s; 0: none), its torque
    limit N·m]; ``filt.gate`` = [χ² innovation bound (0: none), consecutive rejections
    after which a sensor's next measurement is taken anyway]. In the DYNAMICS mode
    ``state.w_hat`` is [ω̂] with P 6×6, or [ω̂, b̂] with the disturbance state of kind
    ``filt.bias_kind`` (1: a body torque b (3); 2: an SRP lever arm β (3), acting as
    ν ŝ × β; 3: both, [b, β]; see ``ekf``); in the GYRO mode it is the gyro bias β̂ (3,)
    with P 6×6, or [β̂, φ̂] with P 9×9 and φ̂ the sun sensor's misalignment (body axes;
    ``filt.bias_true`` its truth). ``log.est`` rows are [q̂, ω̂, b, β, β̂_gyro, φ̂] (zeros
    for a state the filter lacks), ``log.sigma`` rows √diag P[:6] and ``log.sky`` rows the
    sunlit fraction and the sun sensor's, earth sensor's and star tracker's status (0 used,
    1 unavailable, 2 gated).
    """
    start_block(work)
    integrated = work.hw_real[:0]  # none reported: the plant integrates the wheels' momenta
    for j in range(steps):
        k = k0 + j
        command_step(state, work, k, j, plant, law, sky, sensors, filt, noise, log.steady_from)
        _actuate_stage(work, wheels, plant, state.x, k * plant.dt)
        log_k = finish_step(state, work, k, j, log_k, plant, sensors, filt, noise, log, integrated)
    return log_k, work.flags[SATURATED] > 0
