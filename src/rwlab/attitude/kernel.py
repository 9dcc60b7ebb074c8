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
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rwlab.attitude.ekf import (
    _skew_into,
    error_jacobian_into,
    gated_update_into,
    predict_covariance_into,
)
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
ECL_STEPS, MOON_STEPS, ECL_STEADY, ECL_MAX, ECL_SQ, OUT_MAX, OUT_SQ = 16, 17, 18, 19, 20, 21, 22
SUN_OUT, EARTH_BLIND, SUN_GATED, EARTH_GATED, NO_UPDATE = 23, 24, 25, 26, 27


def new_stats() -> np.ndarray:
    """A fresh statistics vector (see :data:`STATS`)."""
    s = np.zeros(len(STATS))
    s[UNLOAD_END] = -math.inf
    return s


@njit(cache=True)
def _sky_at(sky, u, sun, moon):
    """Sun and Moon unit vectors (into ``sun``, ``moon``) and (sunlit, earth_lit,
    moon_visible) at row position ``u`` of the sky table (linear interpolation,
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
def _nees(x, q_hat, w_hat, P, b_true, L):
    """Normalised estimation error squared δxᵀ P⁻¹ δx, δx = [2 (q ⊗ q̂⁻¹)_v, ω − ω̂] (n = 6)
    or [.., b − b̂] (n = 9, b = ``b_true``), by a Cholesky factor of P written into the
    (n, n) scratch L."""
    a1, a2, a3, a4 = x[0], x[1], x[2], x[3]
    b1, b2, b3, b4 = q_hat[0], q_hat[1], q_hat[2], q_hat[3]
    sign = 2.0 if a4 * b4 + a1 * b1 + a2 * b2 + a3 * b3 >= 0 else -2.0
    nx = P.shape[0]
    e = np.empty(nx)  # only at logged steps
    e[0] = sign * (b4 * a1 - a4 * b1 + a2 * b3 - a3 * b2)
    e[1] = sign * (b4 * a2 - a4 * b2 + a3 * b1 - a1 * b3)
    e[2] = sign * (b4 * a3 - a4 * b3 + a1 * b2 - a2 * b1)
    for i in range(3, nx):
        e[i] = x[1 + i] - w_hat[i - 3] if i < 6 else b_true[i - 6] - w_hat[i - 3]
    total = 0.0
    z = np.empty(nx)
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
    bias_kind,
    bias_true,
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
    sky,
    sky_t0,
    sky_step,
    sun_fov_cos,
    sun_incidence,
    sig_sun,
    sig_earth,
    r_sun,
    r_earth,
    sun_align,
    earth_align,
    blind_cos,
    gate,
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
    log_sky,
    log_k,
):
    """Run ``steps`` steps from step index ``k0``.

    ``process_noise`` (steps, 3) is the white torque of each step, N·m;
    ``sensor_noise`` (≥ sensor steps in the block, 6) the standard normals of
    the sun and earth sensors. ``sky`` (rows, 9) is the sky table of
    ``ephemeris.sky_table``, row i at ``sky_t0 + i·sky_step`` s; ``sun_align``,
    ``earth_align`` (3, 3) turn the true body vector into the one each sensor
    reports (bias and misalignment); ``blind_cos`` (2,) the cosines of the earth
    sensor's Sun and Moon exclusion angles; ``gate`` = [χ² innovation bound (0:
    none), consecutive rejections after which a sensor's next measurement is taken
    anyway: a filter that has drifted must not lock its sensors out]. ``log_sky``
    rows: sunlit fraction, sun and earth sensor status (0 used, 1 unavailable, 2
    gated). ``unload`` = [enabled, start fraction, stop fraction, pulse torque
    N·m, pulse steps between pulses, recovery s, pointing error (°) above which
    no window starts and no pulse fires]; ``wheel_*`` the wheel model
    (:class:`rwlab.attitude.wheels.WheelArrays`; its state is updated in place);
    ``stats`` (see :data:`STATS`) is updated in place. ``w_hat`` is [ω̂] (3,) with P
    6×6, or [ω̂, b̂] with P n×n and the disturbance state of kind ``bias_kind`` (1: a
    body torque b (3), acting as b; 2: an SRP lever arm β (3), acting as ν ŝ × β
    with ŝ the Sun in the estimated body axes and ν the sunlit fraction; 3: both,
    [b, β]; see ``ekf``); ``bias_true`` (n − 6,) is its true value for NEES;
    ``log_est`` rows are [q̂, ω̂, b, β] (zeros for a state the filter lacks). Returns
    the new x, q̂, ŵ, P, log position and whether a wheel touched its momentum limit.
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
    nx = P.shape[0]  # 6, or 9 or 12 with the disturbance state b̂ = w_hat[3:]
    biased = use_ekf and nx > 6
    F, W3, Wn = np.empty((nx, nx)), np.empty((4, 3, 3)), np.empty((6, nx, nx))
    C, Bmap = np.empty((3, 3)), np.zeros((3, max(nx - 6, 3)))  # Bmap: torque per unit b̂
    if bias_kind != 2:  # the constant torque's columns come first
        for i in range(3):
            Bmap[i, i] = 1.0
    srp_map = Bmap[:, 3:] if bias_kind == 3 else Bmap[:, :3]
    C_hat, sun_hat, tau_b = np.empty((3, 3)), np.empty(3), np.zeros(3)
    q_hat, w_hat, P = q_hat.copy(), w_hat.copy(), P.copy()
    s_orb, m_orb, sun_b, moon_b = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    b_true, b_meas, nadir_b = np.empty(3), np.empty(3), np.empty(3)
    sun_status = earth_status = 0.0
    sun_rejected = earth_rejected = 0  # consecutive gated measurements of each sensor
    for j in range(steps):
        k = k0 + j
        t = k * dt
        sunlit, earth_lit, moon_visible = _sky_at(sky, (t - sky_t0) / sky_step, s_orb, m_orb)
        if earth_lit < 1.0:
            stats[ECL_STEPS] += 1
        if sunlit < earth_lit:
            stats[MOON_STEPS] += 1
        if k % sensor_every == 0:
            _dcm_into(x, C)
            _matvec(C, s_orb, sun_b)
            _matvec(C, m_orb, moon_b)
            # the sun sensor needs the whole disc inside its field; the earth sensor
            # (boresight +z) is blinded by a visible Sun or Moon inside its exclusion cone
            sun_ok = sunlit >= 1.0 and -sun_b[0] >= sun_fov_cos
            earth_ok = not (
                (sunlit > 0.0 and sun_b[2] >= blind_cos[0])
                or (moon_visible and moon_b[2] >= blind_cos[1])
            )
            sun_status = 0.0 if sun_ok else 1.0
            earth_status = 0.0 if earth_ok else 1.0
        measured = use_ekf and k % sensor_every == 0
        if measured:  # no update through an outage: the filter only propagates
            e = sensor_noise[i_sensor]
            i_sensor += 1
            if sun_status == 0.0:
                cos_i = -sun_b[0] if sun_incidence else 1.0  # noise ∝ 1/cos(incidence)
                _matvec(sun_align, sun_b, b_true)
                _noisy_into(b_true, sig_sun / cos_i, e[0], e[1], e[2], b_meas)
                r = r_sun / max(-b_meas[0], 1e-3) if sun_incidence else r_sun
                g = gate[0] if sun_rejected < gate[1] else 0.0
                ok = gated_update_into(q_hat, w_hat, P, b_meas, s_orb, r, g, Wn)
                sun_rejected = 0 if ok else sun_rejected + 1
                if not ok:
                    stats[SUN_GATED] += 1
                    sun_status = 2.0
            else:
                stats[SUN_OUT] += 1
            if earth_status == 0.0:
                for c in range(3):
                    nadir_b[c] = C[c, 2]
                _matvec(earth_align, nadir_b, b_true)
                _noisy_into(b_true, sig_earth, e[3], e[4], e[5], b_meas)
                g = gate[0] if earth_rejected < gate[1] else 0.0
                ok = gated_update_into(q_hat, w_hat, P, b_meas, nadir, r_earth, g, Wn)
                earth_rejected = 0 if ok else earth_rejected + 1
                if not ok:
                    stats[EARTH_GATED] += 1
                    earth_status = 2.0
            else:
                stats[EARTH_BLIND] += 1
            if sun_status != 0.0 and earth_status != 0.0:
                stats[NO_UPDATE] += 1
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
        if biased:  # disturbance accommodation: cancel the estimated torque
            if bias_kind >= 2:
                _srp_map_into(q_hat, s_orb, sunlit, C_hat, sun_hat, srp_map)
            _matvec(Bmap, w_hat[3:], tau_b)
            for i in range(3):
                tau[i] -= tau_b[i]
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
            if earth_lit < 1.0:
                stats[ECL_STEADY] += 1
                stats[ECL_MAX] = max(stats[ECL_MAX], err)
                stats[ECL_SQ] += err * err
            else:
                stats[OUT_MAX] = max(stats[OUT_MAX], err)
                stats[OUT_SQ] += err * err

        if k % log_every == 0:
            log_t[log_k] = t
            for i in range(m):
                log_x[log_k, i] = x[i]
            for i in range(7):
                log_est[log_k, i] = est[i]
            for i in range(6):
                log_est[log_k, 7 + i] = 0.0
            if biased:
                at = 10 if bias_kind == 2 else 7  # log columns: b, then β
                for i in range(nx - 6):
                    log_est[log_k, at + i] = w_hat[3 + i]
            for i in range(3):
                log_tau[log_k, i] = 0.0
                for c in range(nw):
                    log_tau[log_k, i] -= G[i, c] * hw_real[c]
            if use_ekf:
                nees = _nees(x, q_hat, w_hat, P, bias_true, Wn[0]) if measured else np.nan
                log_nees[log_k] = nees
            log_sky[log_k, 0] = sunlit
            log_sky[log_k, 1] = sun_status
            log_sky[log_k, 2] = earth_status
            log_k += 1

        for i in range(3):
            d[7 + i] = dist[7 + i] + process_noise[j, i] + tau_thr[i]
        d[1] = dist[1] * sunlit  # SRP in the shadow
        dm[1] = dist_model[1] * sunlit
        if use_ekf:
            if measured:  # covariance to the next measurement, F at this estimate
                error_jacobian_into(q_hat, w_hat, h_body, J, J_inv, n, dist_model[0], Bmap, F, W3)
                predict_covariance_into(P, F, Qc, T_sensor, Wn)
            xm[:4] = q_hat
            xm[4:7] = w_hat[:3]
            xm[7:] = x[7:]
            for i in range(3):  # the thruster command (and b̂'s torque) is known to the filter
                dm[7 + i] = dist_model[7 + i] + tau_thr[i] + tau_b[i]
            # the filter knows the wheels' torques and momenta (their tachometers)
            rk4_step(xm, hw_real, dt, J, J_inv, G, h_max, n, dm, s_orb, m_orb, rk4_work)
            for i in range(4):
                q_hat[i] = xm[i]
            for i in range(3):
                w_hat[i] = xm[4 + i]
        rk4_step(x, hw_real, dt, J, J_inv, G, h_max, n, d, s_orb, m_orb, rk4_work)
    return x, q_hat, w_hat, P, log_k, saturated
