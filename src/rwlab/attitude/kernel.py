"""The compiled closed loop: every wheel model, a gain-matrix controller, the MEKF and thrusters.

``run_block`` advances the whole loop — sensors, filter, control law, wheel
allocation and limits, thruster momentum unloading, RK4 plant, process noise,
pointing statistics and logging — for ``steps`` steps without returning to
Python. ``sim.simulate`` calls it once per block (a gain update, or an hour of
simulated time), handing it that block's pre-drawn noise: every noise source has
its own random stream, so every controller sees the same sensor noise and the
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
from typing import NamedTuple

import numpy as np
from numba import njit

from rwlab.attitude.ekf import (
    _skew_into,
    aligned_update_into,
    attitude_error,
    attitude_update_into,
    error_jacobian_into,
    gated_update_into,
    gyro_predict_covariance_into,
    predict_covariance_into,
    propagate_attitude_into,
)
from rwlab.attitude.plant import rk4_step
from rwlab.attitude.sensors import gyro_sample_into, tracker_visible
from rwlab.attitude.wheels import realise

__all__ = [
    "STATS",
    "Filter",
    "Law",
    "Log",
    "Noise",
    "Plant",
    "Sensors",
    "Sky",
    "State",
    "Wheels",
    "control_torque",
    "new_stats",
    "run_block",
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

# the filter's modes (``Filter.mode``)
TRUTH, DYNAMICS, GYRO = 0, 1, 2


class Plant(NamedTuple):
    """The rigid body and its wheels: ``dt`` (s), orbit rate ``n`` (rad/s), J and J⁻¹ (3, 3),
    the wheel axes G (3, N) and G⁺, momentum limits ``h_max`` (N,), N·m·s, torque limit
    ``tau_max``, N·m, the disturbance vector ``dist`` (``DisturbanceModel.vector``), the
    wheels' spin inertia, kg·m² (for their power), and the factor by which every wheel's
    realised torque differs from its command (motor constant, drive electronics)."""

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
    for NEES, disturbances it models ``dist_model``) or GYRO (the gyro-driven MEKF); its
    continuous process noise Qc (n, n); the σ it assumes for the sun and earth sensors
    (rad); the innovation ``gate`` (2,); the star tracker's covariance ``tracker_R`` (3, 3);
    the inertia J and J⁻¹ (3, 3) of the DYNAMICS filter's model (not necessarily the truth's)."""

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
    wheel's last sign of spin (N,) (0 before it first turns), for counting zero crossings."""

    x: np.ndarray
    q_hat: np.ndarray
    w_hat: np.ndarray
    P: np.ndarray
    gyro: np.ndarray
    stats: np.ndarray
    wheel_sign: np.ndarray


class Wheels(NamedTuple):
    """The wheel model as the kernel reads it (``wheels.WheelArrays``'s fields)."""

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


def new_stats() -> np.ndarray:
    """A fresh statistics vector (see :data:`STATS`)."""
    s = np.zeros(len(STATS))
    s[UNLOAD_END] = -math.inf
    return s


@njit(cache=True)
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


@njit(cache=True, inline="always")
def _dcm_into(q, C):
    """C = frames.dcm(q[:4]), element by element (tested equal)."""
    q1, q2, q3, q4 = q[0], q[1], q[2], q[3]
    s = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    C[0, 0], C[1, 1], C[2, 2] = s + 2 * q1 * q1, s + 2 * q2 * q2, s + 2 * q3 * q3
    C[0, 1], C[1, 0] = 2 * (q1 * q2 + q4 * q3), 2 * (q1 * q2 - q4 * q3)
    C[0, 2], C[2, 0] = 2 * (q1 * q3 - q4 * q2), 2 * (q1 * q3 + q4 * q2)
    C[1, 2], C[2, 1] = 2 * (q2 * q3 + q4 * q1), 2 * (q2 * q3 - q4 * q1)


@njit(cache=True)
def _nees(q, q_hat, e, P, L):
    """Normalised estimation error squared δxᵀ P⁻¹ δx, δx = [2 (q ⊗ q̂⁻¹)_v, e[3:]] (n,):
    the caller fills ``e[3:]`` with the truth minus the estimate of the rest of the state
    (ω − ω̂, b − b̂ or β − β̂); e[:3] is written here. By a Cholesky factor of P written
    into the (n, n) scratch L."""
    e[0], e[1], e[2] = attitude_error(q, q_hat)
    nx = P.shape[0]
    total = 0.0
    z = np.empty(nx)  # only at logged steps
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


@njit(cache=True, inline="always")
def _srp_map_into(q, s_orb, sunlit, C, s_body, out):
    """out = ν [ŝ×], ŝ = A(q) s_orb the Sun in body axes: SRP's torque per unit lever arm
    (C (3, 3) and s_body (3,) are scratch)."""
    _dcm_into(q, C)
    _matvec(C, s_orb, s_body)
    _skew_into(sunlit * s_body[0], sunlit * s_body[1], sunlit * s_body[2], out)


@njit(cache=True)
def _noisy_into(b, sigma, e0, e1, e2, out):
    """out = unit vector b turned by a small angle: σ times the standard normals e (e × b)."""
    v0 = b[0] + sigma * (e1 * b[2] - e2 * b[1])
    v1 = b[1] + sigma * (e2 * b[0] - e0 * b[2])
    v2 = b[2] + sigma * (e0 * b[1] - e1 * b[0])
    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    out[0], out[1], out[2] = v0 / norm, v1 / norm, v2 / norm


@njit(cache=True, inline="always")
def _matvec(M, v, out):
    """out = M @ v by loops: numba's ``@`` calls BLAS, which costs microseconds on 3×3."""
    for i in range(M.shape[0]):
        acc = 0.0
        for j in range(M.shape[1]):
            acc += M[i, j] * v[j]
        out[i] = acc


@njit(cache=True, inline="always")
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


@njit(cache=True)
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
    for i in range(nw):
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
                    if abs(dev) > unload[2] * h_max.min():
                        tau_thr[i] = -math.copysign(unload[3], dev)
                        stats[IMPULSE] += unload[3] * dt
                        fired = True
                if not fired:  # what is left lies in the wheels' null space
                    stats[UNLOADING] = 0
                    stats[UNLOAD_END] = t
    return h_frac


@njit(cache=True, inline="always")
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


@njit(cache=True)
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
    out[:] = x[:4]
    b0 = frame[0, 0] * v0 + frame[1, 0] * v1 + frame[2, 0] * v2  # body = frameᵀ v
    b1 = frame[0, 1] * v0 + frame[1, 1] * v1 + frame[2, 1] * v2
    b2 = frame[0, 2] * v0 + frame[1, 2] * v1 + frame[2, 2] * v2
    propagate_attitude_into(out, b0, b1, b2, 1.0)


@njit(cache=True)
def run_block(state, k0, steps, log_k, plant, law, sky, sensors, filt, noise, wheels, log):
    """Run ``steps`` steps from step index ``k0``; returns the next log row and whether a
    wheel touched its momentum limit.

    ``state`` (:class:`State`) is updated in place, as are the wheels' state and the log
    rows from ``log_k`` (:class:`Log`). The records say what each input is; besides them:
    ``law.unload`` = [enabled, start fraction, stop fraction, pulse torque N·m, steps
    between pulses, recovery s, pointing error (°) above which no window starts and no
    pulse fires, null-space bias gain (1/s; 0: none), its torque limit N·m];
    ``filt.gate`` = [χ² innovation bound (0: none), consecutive rejections
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
    x, q_hat, w_hat, P, gs, stats, wheel_sign = state
    J, J_inv, G, h_max, n, dt = plant.J, plant.J_inv, plant.G, plant.h_max, plant.n, plant.dt
    unload = law.unload
    nadir = np.array([0.0, 0.0, 1.0])
    saturated = False
    nw = h_max.shape[0]
    m = x.shape[0]
    mode = filt.mode
    every = sensors.every
    T_sensor = every * dt
    i_sensor = i_tracker = 0
    tau_thr = np.zeros(3)
    s = np.empty(6)
    tau = np.empty(3)
    work = np.empty(3)
    hw_cmd, hw_prev, hw_real = np.empty(nw), np.zeros(nw), np.empty(nw)
    h_body = np.empty(3)
    rk4_work = np.empty((5, m))
    d = plant.dist.copy()
    dm = filt.dist_model.copy()
    xm = np.empty(m)
    est = np.empty(7)  # what the controller sees: [q̂, ω̂] or the true [q, ω]
    nx = P.shape[0]  # 6, or 9 or 12 with the disturbance state b̂ = w_hat[3:]
    biased = mode == DYNAMICS and nx > 6
    aligned = mode == GYRO and nx >= 9  # [δθ, δβ, φ_sun (, φ_earth)]
    earth_aligned = mode == GYRO and nx == 12
    F, W3, Wn = np.empty((nx, nx)), np.empty((4, 3, 3)), np.empty((6, nx, nx))
    C, Bmap = np.empty((3, 3)), np.zeros((3, max(nx - 6, 3)))  # Bmap: torque per unit b̂
    if filt.bias_kind != 2:  # the constant torque's columns come first
        for i in range(3):
            Bmap[i, i] = 1.0
    srp_map = Bmap[:, 3:] if filt.bias_kind == 3 else Bmap[:, :3]
    C_hat, sun_hat, tau_b = np.empty((3, 3)), np.empty(3), np.zeros(3)
    s_orb, m_orb, sun_b, moon_b = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    b_true, b_meas, nadir_b = np.empty(3), np.empty(3), np.empty(3)
    w_mean, w_meas, q_meas, e_nees = np.zeros(3), np.zeros(3), np.empty(4), np.zeros(nx)
    sun_status = earth_status = tracker_status = 0.0
    sun_rejected = earth_rejected = 0  # consecutive gated measurements of each sensor
    for j in range(steps):
        k = k0 + j
        t = k * dt
        u = (t - sky.t0) / sky.step
        sunlit, earth_lit, moon_visible, srp_scale = _sky_at(sky.table, u, s_orb, m_orb)
        if k > 0:  # sample k stands for the step that ends there: steps + 1 samples, steps·dt
            if earth_lit < 1.0:
                stats[ECL_STEPS] += 1
            if sunlit < earth_lit:
                stats[MOON_STEPS] += 1
        if sensors.gyro:  # the angle turned over the last step, as a rate
            for c in range(3):
                w_mean[c] = 0.5 * (gs[6 + c] + x[4 + c])
                gs[6 + c] = x[4 + c]
            gyro_sample_into(w_mean, sensors.gyro_E, sensors.gyro_par, gs, noise.gyro[j], w_meas)
            if mode == GYRO and k > 0:  # q̂ over the last step with ω̂ = ω_m − β̂
                for c in range(3):
                    work[c] = w_meas[c] - w_hat[c]
                _dcm_into(q_hat, C_hat)
                propagate_attitude_into(
                    q_hat,
                    work[0] + n * C_hat[0, 1],
                    work[1] + n * C_hat[1, 1],
                    work[2] + n * C_hat[2, 1],
                    dt,
                )
        tick = k % every == 0
        if tick:
            _dcm_into(x, C)
            _matvec(C, s_orb, sun_b)
            _matvec(C, m_orb, moon_b)
            for c in range(3):
                nadir_b[c] = C[c, 2]
            # the sun sensor needs the whole disc inside its field; the earth sensor
            # (boresight +z) is blinded by a visible Sun or Moon inside its exclusion cone
            sun_ok = sunlit >= 1.0 and -sun_b[0] >= sensors.sun_fov_cos
            earth_ok = not (
                (sunlit > 0.0 and sun_b[2] >= sensors.blind_cos[0])
                or (moon_visible and moon_b[2] >= sensors.blind_cos[1])
            )
            sun_status = 0.0 if sun_ok else 1.0
            earth_status = 0.0 if earth_ok else 1.0
            if sensors.tracker and k % sensors.tracker_every == 0:
                seen = tracker_visible(
                    sensors.tracker_frame,
                    sun_b,
                    moon_b,
                    nadir_b,
                    sunlit,
                    moon_visible,
                    sensors.tracker_cos,
                )
                tracker_status = 0.0 if seen else 1.0
                if not seen:
                    stats[TRACKER_BLIND] += 1
                elif mode != TRUTH:
                    _tracker_measurement(
                        x,
                        sensors.tracker_frame,
                        sensors.tracker_sigma,
                        noise.tracker[i_tracker],
                        q_meas,
                    )
                    attitude_update_into(q_hat, w_hat, P, q_meas, filt.tracker_R, Wn)
                i_tracker += 1
        measured = mode != TRUTH and tick
        if measured:  # no update through an outage: the filter only propagates
            e = noise.sensor[i_sensor]
            i_sensor += 1
            if sun_status == 0.0:
                cos_i = -sun_b[0] if sensors.sun_incidence else 1.0  # noise ∝ 1/cos(incidence)
                _matvec(sensors.sun_align, sun_b, b_true)
                _noisy_into(b_true, sensors.sig_sun / cos_i, e[0], e[1], e[2], b_meas)
                r = filt.r_sun / max(-b_meas[0], 1e-3) if sensors.sun_incidence else filt.r_sun
                g = filt.gate[0] if sun_rejected < filt.gate[1] else 0.0
                if aligned:  # the sun sensor's misalignment is in the state
                    ok = aligned_update_into(q_hat, w_hat, P, b_meas, s_orb, r, g, 6, Wn)
                else:
                    ok = gated_update_into(q_hat, w_hat, P, b_meas, s_orb, r, g, Wn)
                sun_rejected = 0 if ok else sun_rejected + 1
                if not ok:
                    stats[SUN_GATED] += 1
                    sun_status = 2.0
            else:
                stats[SUN_OUT] += 1
            if earth_status == 0.0:
                _matvec(sensors.earth_align, nadir_b, b_true)
                _noisy_into(b_true, sensors.sig_earth, e[3], e[4], e[5], b_meas)
                g = filt.gate[0] if earth_rejected < filt.gate[1] else 0.0
                r = filt.r_earth
                if earth_aligned:
                    ok = aligned_update_into(q_hat, w_hat, P, b_meas, nadir, r, g, 9, Wn)
                else:
                    ok = gated_update_into(q_hat, w_hat, P, b_meas, nadir, r, g, Wn)
                earth_rejected = 0 if ok else earth_rejected + 1
                if not ok:
                    stats[EARTH_GATED] += 1
                    earth_status = 2.0
            else:
                stats[EARTH_BLIND] += 1
            no_tracker = not sensors.tracker or tracker_status != 0.0
            if sun_status != 0.0 and earth_status != 0.0 and no_tracker:
                stats[NO_UPDATE] += 1
        qv = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
        err = math.degrees(2.0 * math.asin(min(1.0, qv)))  # the true error (target: orbital frame)
        h_frac = _unload_step(
            stats, unload, law.hw_target, x, G, h_max, err, t, k, dt, h_body, tau_thr
        )

        for i in range(4):
            est[i] = x[i] if mode == TRUTH else q_hat[i]
        for i in range(3):
            if mode == TRUTH:
                est[4 + i] = x[4 + i]
            elif mode == GYRO:
                est[4 + i] = w_meas[i] - w_hat[i]
            else:
                est[4 + i] = w_hat[i]
        _state_into(est, n, s)
        _control_into(law.K_w, law.M, law.w_max, s, work, tau)
        if biased:  # disturbance accommodation: cancel the estimated torque
            if filt.bias_kind >= 2:
                _srp_map_into(q_hat, s_orb, srp_scale, C_hat, sun_hat, srp_map)
            _matvec(Bmap, w_hat[3:], tau_b)
            for i in range(3):
                tau[i] -= tau_b[i]
        for i in range(3):  # feedback, plus the known thruster torque fed forward to the wheels
            work[i] = tau_thr[i] - tau[i]
        _matvec(plant.G_pinv, work, hw_cmd)
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
        if h_frac >= 0.999:
            saturated = True
        realise(
            wheels.kind,
            t,
            dt,
            hw_cmd,
            x,
            wheels.healthy,
            wheels.faulty,
            wheels.fault_s,
            wheels.state,
            (wheels.A, wheels.B, wheels.C, wheels.ident, wheels.servo),
            wheels.nominal,
            hw_real,
        )
        if plant.torque_scale != 1.0:  # the tachometers see what the wheels really did
            for i in range(nw):
                hw_real[i] *= plant.torque_scale

        in_desat = stats[UNLOADING] == 1 or t - stats[UNLOAD_END] <= unload[5]
        stats[MAX_ERR] = max(stats[MAX_ERR], err)
        if k >= log.steady_from:
            if k == log.steady_from or j == 0:  # no previous command in this window
                hw_prev[:] = hw_cmd
            _steady_stats(
                stats, err, hw_cmd, hw_prev, x, plant.wheel_inertia, at_limit, in_desat, earth_lit
            )
        hw_prev[:] = hw_cmd

        if k % log.every == 0:
            log.t[log_k] = t
            for i in range(m):
                log.x[log_k, i] = x[i]
            for i in range(7):
                log.est[log_k, i] = est[i]
            for i in range(7, log.est.shape[1]):
                log.est[log_k, i] = 0.0
            if biased:
                at = 10 if filt.bias_kind == 2 else 7  # log columns: b, then β
                for i in range(nx - 6):
                    log.est[log_k, at + i] = w_hat[3 + i]
            if mode == GYRO:
                for i in range(min(nx, 9) - 3):  # β̂, then φ̂ of the sun sensor
                    log.est[log_k, 13 + i] = w_hat[i]
            for i in range(3):
                log.tau[log_k, i] = 0.0
                for c in range(nw):
                    log.tau[log_k, i] -= G[i, c] * hw_real[c]
            if mode != TRUTH:
                if measured:
                    for i in range(3, nx):
                        if mode == GYRO and i >= 6:  # the sun sensor's misalignment
                            e_nees[i] = filt.bias_true[i - 6] - w_hat[i - 3]
                        elif mode == GYRO:  # what β̂ stands for: the bias plus E ω
                            e_nees[i] = gs[i - 3] + gs[i] - w_hat[i - 3]
                            for c in range(3):
                                e_nees[i] += sensors.gyro_E[i - 3, c] * w_mean[c]
                        elif i < 6:
                            e_nees[i] = x[1 + i] - w_hat[i - 3]
                        else:
                            e_nees[i] = filt.bias_true[i - 6] - w_hat[i - 3]
                    log.nees[log_k] = _nees(x, q_hat, e_nees, P, Wn[0])
                else:
                    log.nees[log_k] = np.nan
                for i in range(min(nx, 6)):
                    log.sigma[log_k, i] = math.sqrt(P[i, i])
            log.sky[log_k, 0] = sunlit
            log.sky[log_k, 1] = sun_status
            log.sky[log_k, 2] = earth_status
            log.sky[log_k, 3] = tracker_status if sensors.tracker else 1.0
            log_k += 1

        for i in range(3):
            d[7 + i] = plant.dist[7 + i] + noise.process[j, i] + tau_thr[i]
        d[1] = plant.dist[1] * srp_scale  # SRP: none in the shadow, ∝ 1/r² of the Sun
        dm[1] = filt.dist_model[1] * srp_scale
        if measured:  # covariance to the next measurement, F at this estimate
            if mode == GYRO:  # F's blocks written out: a tenth of the dense products
                gyro_predict_covariance_into(P, est[4:7], filt.Qc, T_sensor, Wn)
            else:
                error_jacobian_into(
                    q_hat, w_hat, h_body, filt.J, filt.J_inv, n, filt.dist_model[0], Bmap, F, W3
                )
                predict_covariance_into(P, F, filt.Qc, T_sensor, Wn)
        if mode == DYNAMICS:
            xm[:4] = q_hat
            xm[4:7] = w_hat[:3]
            xm[7:] = x[7:]
            for i in range(3):  # the thruster command (and b̂'s torque) is known to the filter
                dm[7 + i] = filt.dist_model[7 + i] + tau_thr[i] + tau_b[i]
            # the filter knows the wheels' torques and momenta (their tachometers)
            rk4_step(xm, hw_real, dt, filt.J, filt.J_inv, G, h_max, n, dm, s_orb, m_orb, rk4_work)
            for i in range(4):
                q_hat[i] = xm[i]
            for i in range(3):
                w_hat[i] = xm[4 + i]
        rk4_step(x, hw_real, dt, J, J_inv, G, h_max, n, d, s_orb, m_orb, rk4_work)
        _count_zero_crossings(stats, x, h_max, wheel_sign)
    return log_k, saturated
