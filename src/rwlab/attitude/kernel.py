"""The compiled closed loop: ideal wheels, a linear-gain controller and (optionally) the MEKF.

``run_block`` advances the whole loop — sensors, filter, control law, wheel
allocation and limits, RK4 plant, process noise, logging — for ``steps``
steps without returning to Python, so a simulated GEO day at dt = 0.1 s costs
seconds. Python (``sim.simulate``) calls it once per gain update.

The control law is τ = −K s with s = [2 q_v sign(q4), ω_bo] of the estimate
(or of the truth when the filter is off): PD and LQR gains alike.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rwlab.attitude.ekf import _update, error_jacobian, predict_covariance
from rwlab.attitude.frames import dcm, qmul
from rwlab.attitude.plant import propagate

__all__ = ["run_block", "seed"]


@njit(cache=True)
def seed(value):
    """Seed numba's random generator (separate from numpy's)."""
    np.random.seed(value)


@njit(cache=True)
def _sun(t, dec, phase, moving, n):
    theta = phase + (n * t if moving else 0.0)
    return np.array(
        [-math.sin(theta) * math.cos(dec), -math.sin(dec), -math.cos(theta) * math.cos(dec)]
    )


@njit(cache=True)
def _noisy(b, sigma):
    v = b + sigma * np.cross(np.random.standard_normal(3), b)
    return v / np.sqrt(v @ v)


@njit(cache=True)
def _state(q, w, n):
    s = np.empty(6)
    sgn = 1.0 if q[3] >= 0 else -1.0
    s[:3] = 2.0 * q[:3] * sgn
    s[3:] = w - dcm(q) @ np.array([0.0, -n, 0.0])
    return s


@njit(cache=True)
def run_block(
    x,
    q_hat,
    w_hat,
    P,
    k0,
    steps,
    K,
    use_ekf,
    dt,
    sensor_every,
    log_every,
    J,
    J_inv,
    G,
    G_pinv,
    h_max,
    tau_max,
    n,
    dist,
    dist_model,
    noise_sd,
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
    log_t,
    log_x,
    log_est,
    log_tau,
    log_nees,
    log_k,
):
    """Run ``steps`` steps from step index ``k0``; returns the new x, q̂, ŵ, P, log
    position and whether a wheel touched its momentum limit."""
    nadir = np.array([0.0, 0.0, 1.0])
    saturated = False
    nw = h_max.shape[0]
    for j in range(steps):
        k = k0 + j
        t = k * dt
        s_orb = _sun(t, sun_dec, sun_phase, sun_moving, n)
        if use_ekf and k % sensor_every == 0:
            C = dcm(x[:4])
            sun_b = C @ s_orb
            if -sun_b[0] >= sun_fov_cos:
                q_hat, w_hat, P = _update(q_hat, w_hat, P, _noisy(sun_b, sig_sun), s_orb, r_sun)
            q_hat, w_hat, P = _update(q_hat, w_hat, P, _noisy(C[:, 2], sig_earth), nadir, r_earth)
        if use_ekf:
            s = _state(q_hat, w_hat, n)
        else:
            s = _state(x[:4], x[4:7], n)
        tau = -(K @ s)
        hw_dot = -(G_pinv @ tau)
        for i in range(nw):
            hw_dot[i] = min(max(hw_dot[i], -tau_max), tau_max)
            if abs(x[7 + i]) >= 0.999 * h_max[i]:
                saturated = True
        if k % log_every == 0:
            log_t[log_k] = t
            log_x[log_k] = x
            log_est[log_k, :4] = q_hat if use_ekf else x[:4]
            log_est[log_k, 4:] = w_hat if use_ekf else x[4:7]
            log_tau[log_k] = -(G @ hw_dot)
            if use_ekf:
                dq = qmul(x[:4], np.array([-q_hat[0], -q_hat[1], -q_hat[2], q_hat[3]]))
                if dq[3] < 0:
                    dq = -dq
                e = np.empty(6)
                e[:3] = 2 * dq[:3]
                e[3:] = x[4:7] - w_hat
                log_nees[log_k] = e @ np.linalg.solve(P, e)
            log_k += 1
        h_body = G @ x[7:]
        d = dist.copy()
        d[7:10] += noise_sd * np.random.standard_normal(3)
        x_next = propagate(x, hw_dot, dt, 1, J, J_inv, G, h_max, n, d, s_orb, moon)
        if use_ekf:
            xm = np.empty_like(x)
            xm[:4] = q_hat
            xm[4:7] = w_hat
            xm[7:] = x[7:]
            F = error_jacobian(q_hat, w_hat, h_body, J, J_inv, n, 3 * n * n)
            xm = propagate(xm, hw_dot, dt, 1, J, J_inv, G, h_max, n, dist_model, s_orb, moon)
            q_hat = xm[:4].copy()
            w_hat = xm[4:7].copy()
            P = predict_covariance(P, F, Qc, dt)
        x = x_next
    return x, q_hat, w_hat, P, log_k, saturated
