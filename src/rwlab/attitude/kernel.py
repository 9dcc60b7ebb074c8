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

Filter timing: the estimate is propagated with the plant model every step (the
controller needs it); the covariance only once per sensor period, at the
measurement (``ekf.predict_covariance_into``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rwlab.attitude.ekf import _update, error_jacobian_into, predict_covariance_into
from rwlab.attitude.frames import dcm, qmul
from rwlab.attitude.plant import rk4_step
from rwlab.attitude.wheels import realise

__all__ = ["STATS", "control_torque", "new_stats", "run_block"]

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
)
MAX_ERR, STEADY_MAX, STEADY_EXCL, DESAT_MAX = 0, 1, 2, 3
SAT_STEPS, STEADY_STEPS, TAU_PEAK, TAU_SQ, ERR_SQ = 4, 5, 6, 7, 8
H_PEAK, DESAT_COUNT, UNLOADING, UNLOAD_END, IMPULSE, DESAT_STEPS, EXCL_STEPS = (
    9,
    10,
    11,
    12,
    13,
    14,
    15,
)


def new_stats() -> np.ndarray:
    """A fresh statistics vector (see :data:`STATS`)."""
    s = np.zeros(len(STATS))
    s[UNLOAD_END] = -math.inf
    return s


@njit(cache=True)
def _sun(t, dec, phase, moving, n):
    theta = phase + (n * t if moving else 0.0)
    return np.array(
        [-math.sin(theta) * math.cos(dec), -math.sin(dec), -math.cos(theta) * math.cos(dec)]
    )


@njit(cache=True)
def _noisy(b, sigma, e):
    """Unit vector b turned by a small angle: σ times the standard normals e (3,)."""
    v = b + sigma * np.cross(e, b)
    return v / np.sqrt(v @ v)


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
def run_block(
    x,
    q_hat,
    w_hat,
    P,
    k0,
    steps,
    K_w,
    M,
    w_max,
    use_ekf,
    dt,
    sensor_every,
    log_every,
    steady_from,
    J,
    J_inv,
    G,
    G_pinv,
    h_max,
    tau_max,
    n,
    dist,
    dist_model,
    process_noise,
    sensor_noise,
    Qc,
    sun_dec,
    sun_phase,
    sun_moving,
    sun_fov_cos,
    sig_sun,
    sig_earth,
    r_sun,
    r_earth,
    moon,
    unload,
    wheel_kind,
    wheel_healthy,
    wheel_faulty,
    wheel_fault_s,
    wheel_state,
    wheel_A,
    wheel_B,
    wheel_C,
    wheel_ident,
    wheel_servo,
    stats,
    log_t,
    log_x,
    log_est,
    log_tau,
    log_nees,
    log_k,
):
    """Run ``steps`` steps from step index ``k0``.

    ``process_noise`` (steps, 3) is the white torque of each step, N·m;
    ``sensor_noise`` (≥ sensor steps in the block, 6) the standard normals of
    the sun and earth sensors. ``unload`` = [enabled, start fraction, stop
    fraction, pulse torque N·m, pulse steps between pulses, recovery s, pointing
    error (°) above which no window starts and no pulse fires]; ``wheel_*`` the
    wheel model (:class:`rwlab.attitude.wheels.WheelArrays`; its state is updated
    in place); ``stats`` (see :data:`STATS`) is updated in place. Returns the new
    x, q̂, ŵ, P, log position and whether a wheel touched its momentum limit.
    """
    nadir = np.array([0.0, 0.0, 1.0])
    saturated = False
    nw = h_max.shape[0]
    m = x.shape[0]
    T_sensor = sensor_every * dt
    i_sensor = 0
    tau_thr = np.zeros(3)
    s = np.empty(6)
    tau = np.empty(3)
    work = np.empty(3)
    hw_cmd = np.empty(nw)
    hw_real = np.empty(nw)
    h_body = np.empty(3)
    rk4_work = np.empty((5, m))
    d = dist.copy()
    dm = dist_model.copy()
    x = x.copy()
    xm = np.empty(m)
    est = np.empty(7)  # what the controller sees: [q̂, ω̂] or the true [q, ω]
    F, W3, W6 = np.empty((6, 6)), np.empty((4, 3, 3)), np.empty((6, 6, 6))
    P = P.copy()
    s_orb = _sun(0.0, sun_dec, sun_phase, sun_moving, n)
    for j in range(steps):
        k = k0 + j
        t = k * dt
        if sun_moving:
            s_orb = _sun(t, sun_dec, sun_phase, sun_moving, n)
        measured = use_ekf and k % sensor_every == 0
        if measured:
            C = dcm(x[:4])
            sun_b = C @ s_orb
            e = sensor_noise[i_sensor]
            i_sensor += 1
            if -sun_b[0] >= sun_fov_cos:
                q_hat, w_hat, P = _update(
                    q_hat, w_hat, P, _noisy(sun_b, sig_sun, e[:3]), s_orb, r_sun
                )
            q_hat, w_hat, P = _update(
                q_hat, w_hat, P, _noisy(C[:, 2].copy(), sig_earth, e[3:]), nadir, r_earth
            )
        qv = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
        err = math.degrees(2.0 * math.asin(min(1.0, qv)))  # the true error (target: orbital frame)
        # momentum unloading: thruster pulses against the wheels' body momentum
        for i in range(3):
            h_body[i] = G[i, 0] * x[7]
            for c in range(1, nw):
                h_body[i] += G[i, c] * x[7 + c]
            tau_thr[i] = 0.0
        h_frac = 0.0
        for i in range(nw):
            h_frac = max(h_frac, abs(x[7 + i]) / h_max[i])
        if unload[0] > 0:
            pointing = err <= unload[6]
            if stats[UNLOADING] == 0 and h_frac > unload[1] and pointing:
                stats[UNLOADING] = 1
                stats[DESAT_COUNT] += 1
            if stats[UNLOADING] == 1:
                if h_frac <= unload[2]:
                    stats[UNLOADING] = 0
                    stats[UNLOAD_END] = t
                elif k % int(unload[4]) == 0 and pointing:  # no pulses during a slew
                    fired = False
                    for i in range(3):
                        if abs(h_body[i]) > unload[2] * h_max.min():
                            tau_thr[i] = -math.copysign(unload[3], h_body[i])
                            stats[IMPULSE] += unload[3] * dt
                            fired = True
                    if not fired:  # what is left lies in the wheels' null space
                        stats[UNLOADING] = 0
                        stats[UNLOAD_END] = t

        for i in range(7):
            est[i] = (q_hat[i] if i < 4 else w_hat[i - 4]) if use_ekf else x[i]
        _state_into(est, n, s)
        _control_into(K_w, M, w_max, s, work, tau)
        for i in range(3):  # feedback, plus the known thruster torque fed forward to the wheels
            work[i] = tau_thr[i] - tau[i]
        _matvec(G_pinv, work, hw_cmd)
        at_limit = False
        for i in range(nw):
            if abs(hw_cmd[i]) >= tau_max:
                at_limit = True
            hw_cmd[i] = min(max(hw_cmd[i], -tau_max), tau_max)
            stats[TAU_PEAK] = max(stats[TAU_PEAK], abs(hw_cmd[i]))
        stats[H_PEAK] = max(stats[H_PEAK], h_frac)
        if h_frac >= 0.999:
            saturated = True
        realise(
            wheel_kind,
            t,
            dt,
            hw_cmd,
            x,
            wheel_healthy,
            wheel_faulty,
            wheel_fault_s,
            wheel_state,
            wheel_A,
            wheel_B,
            wheel_C,
            wheel_ident,
            wheel_servo,
            hw_real,
        )

        in_desat = stats[UNLOADING] == 1 or t - stats[UNLOAD_END] <= unload[5]
        stats[MAX_ERR] = max(stats[MAX_ERR], err)
        if k >= steady_from:
            stats[STEADY_MAX] = max(stats[STEADY_MAX], err)
            stats[STEADY_STEPS] += 1
            stats[ERR_SQ] += err * err
            for i in range(nw):
                stats[TAU_SQ] += hw_cmd[i] * hw_cmd[i] / nw
            if at_limit:
                stats[SAT_STEPS] += 1
            if in_desat:
                stats[DESAT_MAX] = max(stats[DESAT_MAX], err)
                stats[DESAT_STEPS] += 1
            else:
                stats[STEADY_EXCL] = max(stats[STEADY_EXCL], err)
                stats[EXCL_STEPS] += 1

        if k % log_every == 0:
            log_t[log_k] = t
            for i in range(m):
                log_x[log_k, i] = x[i]
            for i in range(7):
                log_est[log_k, i] = est[i]
            for i in range(3):
                log_tau[log_k, i] = 0.0
                for c in range(nw):
                    log_tau[log_k, i] -= G[i, c] * hw_real[c]
            if use_ekf:
                dq = qmul(x[:4], np.array([-q_hat[0], -q_hat[1], -q_hat[2], q_hat[3]]))
                if dq[3] < 0:
                    dq = -dq
                ee = np.empty(6)
                ee[:3] = 2 * dq[:3]
                ee[3:] = x[4:7] - w_hat
                log_nees[log_k] = ee @ np.linalg.solve(P, ee) if measured else np.nan
            log_k += 1

        for i in range(3):
            d[7 + i] = dist[7 + i] + process_noise[j, i] + tau_thr[i]
        if use_ekf:
            if measured:  # covariance to the next measurement, F at this estimate
                error_jacobian_into(q_hat, w_hat, h_body, J, J_inv, n, dist_model[0], F, W3)
                predict_covariance_into(P, F, Qc, T_sensor, W6)
            xm[:4] = q_hat
            xm[4:7] = w_hat
            xm[7:] = x[7:]
            for i in range(3):  # the thruster command is known to the filter
                dm[7 + i] = dist_model[7 + i] + tau_thr[i]
            # the filter knows the wheels' torques and momenta (their tachometers)
            rk4_step(xm, hw_real, dt, J, J_inv, G, h_max, n, dm, s_orb, moon, rk4_work)
            q_hat = xm[:4].copy()
            w_hat = xm[4:7].copy()
        rk4_step(x, hw_real, dt, J, J_inv, G, h_max, n, d, s_orb, moon, rk4_work)
    return x, q_hat, w_hat, P, log_k, saturated
