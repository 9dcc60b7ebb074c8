"""Closed-loop simulation: plant, wheels, sensors, estimator and a controller, step by step.

Each step of ``dt`` seconds: sensors measure (every ``sensor_period``), the
estimator updates, the controller returns a body torque, the torque is
allocated to the wheels (minimum-norm, clipped to their limits), the wheels
realise it (ideal, the RW physics of ``rwlab.wheel``, or the identified model
from ``model.json``), and the plant and the filter move one step.

Controllers are objects with ``torque(t, q, w_bo, h_body) -> (3,) N·m`` acting
on the estimate (or on the truth with ``estimator='truth'``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rwlab.attitude.ekf import MEKF
from rwlab.attitude.frames import GEO_RATE, angle_deg, dcm, from_axis_angle, qmul
from rwlab.attitude.plant import propagate
from rwlab.attitude.scenario import Scenario
from rwlab.wheel.physics import Mode, WheelParams, WheelPhysics, rad_s_to_rpm, rpm_to_rad_s

__all__ = ["LinearController", "PDController", "SimResult", "simulate", "sun_direction"]

MOON_DIRECTION = np.array([0.6, -0.1, 0.79])  # orbital frame, slowly varying; fixed here


def sun_direction(scenario: Scenario, t: float) -> np.ndarray:
    """Unit vector to the Sun in the orbital frame at time t (s)."""
    d = math.radians(scenario.sun_declination_deg)
    theta = math.radians(scenario.sun_phase_deg)
    if scenario.sun == "moving":
        theta += GEO_RATE * t  # the orbital frame turns once a day relative to the Sun
    return np.array([-math.sin(theta) * math.cos(d), -math.sin(d), -math.cos(theta) * math.cos(d)])


def _noisy(b: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """b turned by a small random angle of σ rad per axis (a unit-vector sensor)."""
    v = b + sigma * np.cross(rng.standard_normal(3), b)
    return v / np.linalg.norm(v)


class LinearController:
    """τ = −K(t) s with s = [2 q_v sign(q4), ω_bo]; subclasses say how K is chosen.

    ``update_period`` (s): how often ``gain`` is asked again (None: once).
    """

    update_period: float | None = None

    def gain(self, t: float, q: np.ndarray, w_bo: np.ndarray, h_body: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def torque(self, t, q, w_bo, h_body) -> np.ndarray:
        s = np.concatenate([2 * q[:3] * math.copysign(1.0, q[3]), w_bo])
        return -self.gain(t, q, w_bo, h_body) @ s


class PDController(LinearController):
    """Quaternion PD law τ = −Kp·2q_v·sign(q4) − Kd·ω_bo (like Basilisk's MRP feedback)."""

    def __init__(self, kp: float, kd: float) -> None:
        self.K = np.hstack([kp * np.eye(3), kd * np.eye(3)])

    def gain(self, t, q, w_bo, h_body) -> np.ndarray:
        return self.K


class _Wheels:
    """Turn wheel-torque commands into realised wheel torques (N·m) for one step."""

    def __init__(self, sc: Scenario, hw0: np.ndarray) -> None:
        self.sc = sc
        self.kind = sc.wheel_model
        n = sc.n_wheels
        if self.kind == "physics":
            params = WheelParams(
                inertia=sc.wheel_inertia,
                max_speed_rpm=sc.wheel_max_speed_rpm,
                overspeed_fault_rpm=sc.wheel_max_speed_rpm * 1.1,
                max_accel_rpm_s=rad_s_to_rpm(sc.wheel_max_torque / sc.wheel_inertia),
                # the 0.7 A current limit then allows 5 % more than the rated torque
                torque_constant=sc.wheel_max_torque / 0.7 * 1.05,
            )
            self.units = [WheelPhysics(params, seed=i) for i in range(n)]
            for unit, h in zip(self.units, hw0, strict=True):
                unit.speed = h / sc.wheel_inertia
        elif self.kind == "identified":
            from rwlab.wheel.identified import IdentifiedWheel

            self.units = [IdentifiedWheel.from_json(sc.wheel_model_file) for _ in range(n)]
            self.command_rpm = np.array([rad_s_to_rpm(h / sc.wheel_inertia) for h in hw0])
            for unit, c in zip(self.units, self.command_rpm, strict=True):
                unit.reset(c)
            self.Ts = self.units[0].Ts
            self.clock = 0.0
            self.rate = np.zeros(n)

    def realise(self, command: np.ndarray, hw: np.ndarray, dt: float) -> np.ndarray:
        cmd = np.clip(command, -self.sc.wheel_max_torque, self.sc.wheel_max_torque)
        if self.kind == "ideal":
            return cmd
        I_w = self.sc.wheel_inertia
        if self.kind == "physics":
            out = np.empty_like(cmd)
            for i, unit in enumerate(self.units):
                before = unit.speed
                unit.command(Mode.ACCELERATION, rad_s_to_rpm(cmd[i] / I_w))
                unit.step(dt)
                out[i] = I_w * (unit.speed - before) / dt
            return out
        # identified model: acceleration mode built on its speed loop, updated every Ts
        self.command_rpm += rad_s_to_rpm(cmd / I_w) * dt
        self.clock += dt
        if self.clock >= self.Ts - 1e-9:
            self.clock -= self.Ts
            for i, unit in enumerate(self.units):
                before = unit.speed_rpm
                unit.step(self.command_rpm[i])
                self.rate[i] = I_w * rpm_to_rad_s(unit.speed_rpm - before) / self.Ts
        return self.rate.copy()


@dataclass
class SimResult:
    """Time histories of one run (rows are logged steps).

    Attributes
    ----------
    t : (K,) s; q : (K, 4) true attitude (orbital → body); w_bo : (K, 3) rad/s;
    q_est, w_est : the estimate; torque : (K, 3) body control torque, N·m;
    wheel_speed_rpm : (K, N); error_deg : (K,) true pointing error;
    est_error_deg : (K,) estimation error; nees : (K,) normalised estimation error².
    """

    t: np.ndarray
    q: np.ndarray
    w_bo: np.ndarray
    q_est: np.ndarray
    w_est: np.ndarray
    torque: np.ndarray
    wheel_speed_rpm: np.ndarray
    error_deg: np.ndarray
    est_error_deg: np.ndarray
    nees: np.ndarray
    wheel_saturated: bool


def _w_bo(q, w, n=GEO_RATE):
    return w - dcm(q) @ np.array([0.0, -n, 0.0])


def simulate(
    scenario: Scenario,
    controller,
    *,
    duration: float | None = None,
    estimator: str = "ekf",
    log_every: int = 10,
    seed: int | None = None,
    wheel_momentum0: np.ndarray | None = None,
    filter_torque_psd: float = 0.0,
    filter_noise_scale: float = 1.0,
) -> SimResult:
    """Run the closed loop. ``estimator``: 'ekf' (LQG-style) or 'truth' (ideal LQR).

    ``filter_torque_psd`` adds fictitious process noise (N²·m²·s) to the filter and
    ``filter_noise_scale`` scales the σ it assumes for the sensors: the LTR tuning.
    Ideal wheels with a :class:`LinearController` run in the compiled kernel;
    other wheel models or controllers run step by step in Python (same physics).
    """
    if estimator not in ("ekf", "truth"):
        raise ValueError(f"estimator must be 'ekf' or 'truth', got {estimator!r}")
    kw = dict(
        steps=round((scenario.duration if duration is None else duration) / scenario.dt),
        rng=np.random.default_rng(scenario.seed if seed is None else seed),
        estimator=estimator,
        log_every=log_every,
        wheel_momentum0=wheel_momentum0,
        filter_psd=scenario.process_noise_torque**2 + filter_torque_psd,
        noise_scale=scenario.noise_margin * filter_noise_scale,
    )
    if scenario.wheel_model == "ideal" and isinstance(controller, LinearController):
        return _simulate_compiled(scenario, controller, **kw)
    return _simulate_python(scenario, controller, **kw)


def _initial(sc: Scenario, rng, wheel_momentum0):
    q0 = from_axis_angle(sc.initial_axis, math.radians(sc.initial_error_deg))
    w0 = dcm(q0) @ np.array([0.0, -GEO_RATE, 0.0]) + np.asarray(sc.initial_rate, float)
    hw0 = np.zeros(sc.n_wheels) if wheel_momentum0 is None else np.asarray(wheel_momentum0, float)
    dq = from_axis_angle(rng.standard_normal(3), math.radians(sc.estimator_error_deg))
    s0 = math.radians(max(sc.estimator_error_deg, 0.1))
    P0 = np.diag([s0**2] * 3 + [(1e-4) ** 2] * 3)
    return q0, w0, hw0, qmul(dq, q0), w0 + 1e-5 * rng.standard_normal(3), P0


def _result(t, q, w_bo, q_est, w_est, torque, wheel, nees, saturated) -> SimResult:
    q = np.where(q[:, 3:4] >= 0, q, -q)
    q_est = np.where(q_est[:, 3:4] >= 0, q_est, -q_est)
    est_err = angle_deg(
        np.array(
            [qmul(a, np.array([-b[0], -b[1], -b[2], b[3]])) for a, b in zip(q, q_est, strict=True)]
        )
    )
    return SimResult(
        t, q, w_bo, q_est, w_est, torque, wheel, angle_deg(q), est_err, nees, bool(saturated)
    )


def _simulate_compiled(
    sc,
    controller,
    *,
    steps,
    estimator,
    log_every,
    rng,
    wheel_momentum0,
    filter_psd,
    noise_scale,
):
    from rwlab.attitude import kernel

    kernel.seed(int(rng.integers(2**31)))
    J = sc.inertia_matrix
    J_inv = np.linalg.inv(J)
    G = sc.wheel_matrix
    q0, w0, hw0, q_hat, w_hat, P = _initial(sc, rng, wheel_momentum0)
    x = np.concatenate([q0, w0, hw0])
    use_ekf = estimator == "ekf"
    if not use_ekf:
        q_hat, w_hat = q0.copy(), w0.copy()
    n_log = steps // log_every + 2
    log_t, log_x = np.zeros(n_log), np.zeros((n_log, x.size))
    log_est, log_tau, log_nees = np.zeros((n_log, 7)), np.zeros((n_log, 3)), np.zeros(n_log)
    dist = sc.disturbances.vector()
    Qc = np.zeros((6, 6))
    Qc[3:, 3:] = filter_psd * J_inv @ J_inv.T
    m = noise_scale
    fov_cos = math.cos(math.radians(min(sc.sun_fov_deg, 180.0)))
    period = controller.update_period
    block = steps + 1 if not period else max(1, round(period / sc.dt))
    k, log_k, saturated = 0, 0, False
    while k <= steps:
        n_steps = min(block, steps + 1 - k)
        s_q, s_w = (q_hat, w_hat) if use_ekf else (x[:4], x[4:7])
        K = np.ascontiguousarray(
            controller.gain(k * sc.dt, s_q, _w_bo(s_q, s_w), G @ x[7:]), dtype=float
        )
        x, q_hat, w_hat, P, log_k, sat = kernel.run_block(
            x,
            q_hat,
            w_hat,
            P,
            k,
            n_steps,
            K,
            use_ekf,
            sc.dt,
            round(sc.sensor_period / sc.dt),
            log_every,
            J,
            J_inv,
            G,
            np.linalg.pinv(G),
            np.full(sc.n_wheels, sc.wheel_max_momentum),
            sc.wheel_max_torque,
            GEO_RATE,
            dist,
            dist,
            sc.process_noise_torque / math.sqrt(sc.dt),
            Qc,
            math.radians(sc.sun_declination_deg),
            math.radians(sc.sun_phase_deg),
            sc.sun == "moving",
            fov_cos,
            math.radians(sc.sun_noise_deg),
            math.radians(sc.earth_noise_deg),
            math.radians(sc.sun_noise_deg) * m,
            math.radians(sc.earth_noise_deg) * m,
            MOON_DIRECTION,
            log_t,
            log_x,
            log_est,
            log_tau,
            log_nees,
            log_k,
        )
        saturated |= sat
        k += n_steps
    log_x, log_est = log_x[:log_k], log_est[:log_k]
    w_bo = np.array([_w_bo(r[:4], r[4:7]) for r in log_x])
    w_est = np.array([_w_bo(r[:4], r[4:7]) for r in log_est])
    wheel = rad_s_to_rpm(log_x[:, 7:] / sc.wheel_inertia)
    return _result(
        log_t[:log_k],
        log_x[:, :4],
        w_bo,
        log_est[:, :4],
        w_est,
        log_tau[:log_k],
        wheel,
        log_nees[:log_k] if use_ekf else np.zeros(log_k),
        saturated,
    )


def _simulate_python(
    scenario,
    controller,
    *,
    steps,
    estimator,
    log_every,
    rng,
    wheel_momentum0,
    filter_psd,
    noise_scale,
) -> SimResult:
    sc = scenario
    sensor_every = round(sc.sensor_period / sc.dt)
    J = sc.inertia_matrix
    J_inv = np.linalg.inv(J)
    G = sc.wheel_matrix
    G_pinv = np.linalg.pinv(G)
    h_max = np.full(sc.n_wheels, sc.wheel_max_momentum)
    dist_true = sc.disturbances.vector()
    dist_model = dist_true  # the filter knows the deterministic environment; noise is unknown
    q0, w0, hw0, q_hat0, w_hat0, P0 = _initial(sc, rng, wheel_momentum0)
    x = np.concatenate([q0, w0, hw0])
    wheels = _Wheels(sc, hw0)
    sig_sun = math.radians(sc.sun_noise_deg)
    sig_earth = math.radians(sc.earth_noise_deg)
    nadir = np.array([0.0, 0.0, 1.0])
    use_ekf = estimator == "ekf"
    if use_ekf:
        ekf = MEKF(J, q_hat0, w_hat0, P0, filter_psd)
    n_log = steps // log_every + 1
    log = {
        k: np.zeros((n_log, m))
        for k, m in (
            ("q", 4),
            ("w_bo", 3),
            ("q_est", 4),
            ("w_est", 3),
            ("torque", 3),
            ("wheel", sc.n_wheels),
            ("nees", 1),
        )
    }
    t_log = np.zeros(n_log)
    saturated = False
    noise_sd = sc.process_noise_torque / math.sqrt(sc.dt)
    k_log = 0
    for k in range(steps + 1):
        t = k * sc.dt
        s_orb = sun_direction(sc, t)
        if use_ekf and k % sensor_every == 0:
            C = dcm(x[:4])
            sun_b = C @ s_orb
            if math.degrees(math.acos(max(-1.0, min(1.0, -sun_b[0])))) <= sc.sun_fov_deg:
                ekf.update(_noisy(sun_b, sig_sun, rng), s_orb, sig_sun * noise_scale)
            ekf.update(_noisy(C @ nadir, sig_earth, rng), nadir, sig_earth * noise_scale)
        q_hat, w_hat = (ekf.q, ekf.w) if use_ekf else (x[:4], x[4:7])
        h_body = G @ x[7:]
        tau_cmd = controller.torque(t, q_hat, _w_bo(q_hat, w_hat), h_body)
        hw_dot = wheels.realise(-G_pinv @ tau_cmd, x[7:], sc.dt)
        saturated |= bool(np.any(np.abs(x[7:]) >= h_max * 0.999))
        if k % log_every == 0:
            t_log[k_log] = t
            log["q"][k_log] = x[:4] if x[3] >= 0 else -x[:4]
            log["w_bo"][k_log] = _w_bo(x[:4], x[4:7])
            log["q_est"][k_log] = q_hat if q_hat[3] >= 0 else -q_hat
            log["w_est"][k_log] = _w_bo(q_hat, w_hat)
            log["torque"][k_log] = -G @ hw_dot
            log["wheel"][k_log] = rad_s_to_rpm(x[7:] / sc.wheel_inertia)
            if use_ekf:
                e = ekf.error(x[:4], x[4:7])
                log["nees"][k_log] = e @ np.linalg.solve(ekf.P, e)
            k_log += 1
        if k == steps:
            break
        dist = dist_true.copy()
        dist[7:10] += noise_sd * rng.standard_normal(3)
        x_next = propagate(
            x, hw_dot, sc.dt, 1, J, J_inv, G, h_max, GEO_RATE, dist, s_orb, MOON_DIRECTION
        )
        if use_ekf:
            model = propagate(
                np.concatenate([ekf.q, ekf.w, x[7:]]),
                hw_dot,
                sc.dt,
                1,
                J,
                J_inv,
                G,
                h_max,
                GEO_RATE,
                dist_model,
                s_orb,
                MOON_DIRECTION,
            )
            ekf.predict(model, h_body, sc.dt)
        x = x_next
    return _result(
        t_log[:k_log],
        log["q"][:k_log],
        log["w_bo"][:k_log],
        log["q_est"][:k_log],
        log["w_est"][:k_log],
        log["torque"][:k_log],
        log["wheel"][:k_log],
        log["nees"][:k_log, 0],
        saturated,
    )
