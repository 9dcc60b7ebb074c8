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

from rwlab.attitude import kernel
from rwlab.attitude.ekf import MEKF
from rwlab.attitude.frames import GEO_RATE, angle_deg, dcm, from_axis_angle, qmul
from rwlab.attitude.kernel import control_torque
from rwlab.attitude.plant import propagate
from rwlab.attitude.scenario import Scenario
from rwlab.errors import ConfigError
from rwlab.wheel.physics import Mode, WheelParams, WheelPhysics, rad_s_to_rpm, rpm_to_rad_s

__all__ = [
    "LinearController",
    "PDController",
    "SimResult",
    "attitude_noise_psd",
    "default_filter_psd",
    "simulate",
    "steady_start",
    "sun_direction",
]

MOON_DIRECTION = np.array([0.6, -0.1, 0.79])  # orbital frame, slowly varying; fixed here


def sun_direction(scenario: Scenario, t: float) -> np.ndarray:
    """Unit vector to the Sun in the orbital frame at time t (s)."""
    d = math.radians(scenario.sun_declination_deg)
    theta = math.radians(scenario.sun_phase_deg)
    if scenario.sun == "moving":
        theta += GEO_RATE * t  # the orbital frame turns once a day relative to the Sun
    return np.array([-math.sin(theta) * math.cos(d), -math.sin(d), -math.cos(theta) * math.cos(d)])


def _noisy(b: np.ndarray, sigma: float, e: np.ndarray) -> np.ndarray:
    """b turned by a small angle: σ rad times the standard normals e per axis (a vector sensor)."""
    v = b + sigma * np.cross(e, b)
    return v / np.linalg.norm(v)


class LinearController:
    """τ = −K(t) s with s = [2 q_v sign(q4), ω_bo], in its saturation-aware form.

    Subclasses say how K is chosen (``gain``). ``update_period`` (s): how often
    ``gain`` is asked again (None: once). ``rate_limit`` (rad/s): the slew rate
    beyond which the law stops asking for more rate (see ``kernel.control_torque``;
    inf: the plain linear law).
    """

    update_period: float | None = None
    rate_limit: float = math.inf

    def gain(self, t: float, q: np.ndarray, w_bo: np.ndarray, h_body: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def torque(self, t, q, w_bo, h_body) -> np.ndarray:
        s = np.concatenate([2 * q[:3] * math.copysign(1.0, q[3]), w_bo])
        K = self.gain(t, q, w_bo, h_body)
        return control_torque(np.ascontiguousarray(K[:, 3:]), _rate_map(K), self.rate_limit, s)


def _rate_map(K: np.ndarray) -> np.ndarray:
    """K_ω⁻¹ K_θ (3×3) of a gain K = [K_θ K_ω]."""
    return np.ascontiguousarray(np.linalg.solve(K[:, 3:], K[:, :3]))


class PDController(LinearController):
    """Quaternion PD law τ = −Kp·2q_v·sign(q4) − Kd·ω_bo (like Basilisk's MRP feedback)."""

    def __init__(self, kp: float, kd: float, rate_limit: float = math.inf) -> None:
        self.K = np.hstack([kp * np.eye(3), kd * np.eye(3)])
        self.rate_limit = rate_limit

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
    """Time histories of one run (rows are logged steps) and statistics over every step.

    Attributes
    ----------
    t : (K,) s; q : (K, 4) true attitude (orbital → body); w_bo : (K, 3) rad/s;
    q_est, w_est : the estimate; torque : (K, 3) body control torque, N·m;
    wheel_speed_rpm : (K, N); error_deg : (K,) true pointing error;
    est_error_deg : (K,) estimation error; nees : (K,) normalised estimation error²
    (at measurement steps; 0 without a filter).
    wheel_saturated : a wheel touched its momentum limit.
    stats : dict over every step (not only the logged ones), see ``kernel.STATS``.
    steady_from_s : start of the steady-state window, s.
    sky : (K, 3) sunlit fraction and the sun and earth sensors' status (0 used,
    1 unavailable: eclipse, field of view or blinding, 2 gated) at the logged steps.
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
    stats: dict
    steady_from_s: float
    sky: np.ndarray | None = None


def _w_bo(q, w, n=GEO_RATE):
    return w - dcm(q) @ np.array([0.0, -n, 0.0])


def steady_start(duration: float) -> float:
    """Start of the steady-state window, s: half the run, at most its first hour."""
    return min(duration / 2, 3600.0)


def unknown_torque_bound(sc: Scenario) -> float:
    """A bound on the disturbance torque the filter does not model, N·m.

    SRP force times the centre-of-pressure offset, plus the Sun and Moon tides
    on the inertia spread and any constant torque; J2 is within the gravity
    gradient's 7e-5 margin.
    """
    d = sc.disturbances.vector()
    J = sc.inertia_matrix
    spread = float(np.ptp(np.linalg.eigvalsh(J)))
    tides = (d[5] + d[6]) * spread / 2
    return float(d[1] * np.linalg.norm(d[2:5]) + tides + np.linalg.norm(d[7:10]))


def default_filter_psd(sc: Scenario) -> float:
    """The torque PSD the filter assumes, N²·m²·s (paper B: SRP as process noise).

    With the disturbances unknown to the filter, its process noise is sized so
    that the estimate's lag on the worst-case unmodelled torque τ_u stays within
    ``filter_disturbance_budget_deg`` (τ_u: ``filter_torque_bound``, or
    :func:`unknown_torque_bound` when that is 0): a Kalman filter on J θ̈ = τ measuring θ
    with PSD r lags a constant τ by τ/√(q/r), whatever J, so q = r (τ_u/θ_b)².
    """
    q = sc.process_noise_torque**2
    if not sc.disturbances_known_to_filter:
        r = attitude_noise_psd(sc)
        bound = sc.filter_torque_bound or unknown_torque_bound(sc)
        q += r * (bound / math.radians(sc.filter_disturbance_budget_deg)) ** 2
    return q


def attitude_noise_psd(sc: Scenario) -> float:
    """Attitude measurement noise as a continuous PSD, rad²·s: the sensors' mean σ (with the
    filter's margin) squared, times the sensor period."""
    sigma = math.radians((sc.sun_noise_deg + sc.earth_noise_deg) / 2) * sc.noise_margin
    return sigma**2 * sc.sensor_period


class _Streams:
    """One independent random stream per noise source, all from one seed."""

    def __init__(self, seed: int) -> None:
        init, process, sensor = np.random.SeedSequence(seed).spawn(3)
        self.init = np.random.default_rng(init)
        self.process = np.random.default_rng(process)
        self.sensor = np.random.default_rng(sensor)

    def block(self, k: int, n_steps: int, sensor_every: int, noise_sd: float):
        """Process torques (n_steps, 3) and sensor normals (sensor steps, 6) of steps k…"""
        first = -(-k // sensor_every) * sensor_every
        n_sensor = len(range(first, k + n_steps, sensor_every))
        return (
            self.process.standard_normal((n_steps, 3)) * noise_sd,
            self.sensor.standard_normal((n_sensor, 6)),
        )


def simulate(
    scenario: Scenario,
    controller,
    *,
    duration: float | None = None,
    estimator: str = "ekf",
    log_every: int = 10,
    seed: int | None = None,
    wheel_momentum0: np.ndarray | None = None,
    filter_torque_psd: float | None = None,
    filter_noise_scale: float = 1.0,
    progress=None,
) -> SimResult:
    """Run the closed loop. ``estimator``: 'ekf' (LQG-style) or 'truth' (ideal LQR).

    Parameters
    ----------
    scenario : Scenario
    controller : LinearController
        Or any object with ``torque(t, q, w_bo, h_body)`` (Python path).
    duration : float, optional
        Seconds (the scenario's by default).
    estimator : {'ekf', 'truth'}
    log_every : int
        Steps between logged rows (rounded up to whole sensor periods).
    seed : int, optional
        Seeds the independent noise streams (the scenario's by default).
    wheel_momentum0 : (N,) array, optional
        Initial wheel momenta, N·m·s.
    filter_torque_psd : float, optional
        Process noise the filter assumes, N²·m²·s (default :func:`default_filter_psd`);
        LTR passes its fictitious noise here.
    filter_noise_scale : float
        Scales the sensor σ the filter assumes (√ρ for LTR).
    progress : callable, optional
        Called with the number of steps done after each block.

    Ideal wheels with a :class:`LinearController` run in the compiled kernel;
    other wheel models or controllers run step by step in Python (same physics,
    noise and law; no momentum unloading).
    """
    if estimator not in ("ekf", "truth"):
        raise ConfigError(f"estimator must be 'ekf' or 'truth', got {estimator!r}")
    duration = scenario.duration if duration is None else duration
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration!r}")
    steps = round(duration / scenario.dt)
    if steps < 1:
        raise ConfigError(f"duration {duration:g} s is shorter than one step ({scenario.dt:g} s)")
    sensor_every = round(scenario.sensor_period / scenario.dt)
    kw = dict(
        steps=steps,
        streams=_Streams(scenario.seed if seed is None else seed),
        estimator=estimator,
        log_every=-(-max(1, int(log_every)) // sensor_every) * sensor_every,
        wheel_momentum0=wheel_momentum0,
        filter_psd=default_filter_psd(scenario)
        if filter_torque_psd is None
        else scenario.process_noise_torque**2 + filter_torque_psd,
        noise_scale=scenario.noise_margin * filter_noise_scale,
        steady_from=round(steady_start(steps * scenario.dt) / scenario.dt),
        progress=progress,
    )
    if scenario.wheel_model == "ideal" and isinstance(controller, LinearController):
        result = _simulate_compiled(scenario, controller, **kw)
    elif scenario.epoch is not None:
        raise ConfigError("an epoch (the real sky) needs ideal wheels and a linear controller")
    else:
        result = _simulate_python(scenario, controller, **kw)
    result.stats["steps"] = steps
    result.stats["dt_s"] = scenario.dt
    result.stats["sensor_period_s"] = scenario.sensor_period
    return result


def _initial(sc: Scenario, rng, wheel_momentum0):
    q0 = from_axis_angle(sc.initial_axis, math.radians(sc.initial_error_deg))
    w0 = dcm(q0) @ np.array([0.0, -GEO_RATE, 0.0]) + np.asarray(sc.initial_rate, float)
    hw0 = np.zeros(sc.n_wheels) if wheel_momentum0 is None else np.asarray(wheel_momentum0, float)
    dq = from_axis_angle(rng.standard_normal(3), math.radians(sc.estimator_error_deg))
    s0 = math.radians(max(sc.estimator_error_deg, 0.1))
    P0 = np.diag([s0**2] * 3 + [(1e-4) ** 2] * 3)
    return q0, w0, hw0, qmul(dq, q0), w0 + 1e-5 * rng.standard_normal(3), P0


def _result(t, q, w_bo, q_est, w_est, torque, wheel, nees, saturated, stats, steady_s):
    q = np.where(q[:, 3:4] >= 0, q, -q)
    q_est = np.where(q_est[:, 3:4] >= 0, q_est, -q_est)
    est_err = angle_deg(
        np.array(
            [qmul(a, np.array([-b[0], -b[1], -b[2], b[3]])) for a, b in zip(q, q_est, strict=True)]
        )
    )
    return SimResult(
        t,
        q,
        w_bo,
        q_est,
        w_est,
        torque,
        wheel,
        angle_deg(q),
        est_err,
        nees,
        bool(saturated),
        dict(zip(kernel.STATS, (float(v) for v in stats), strict=True)),
        steady_s,
    )


def _unload_vector(sc: Scenario) -> np.ndarray:
    """The kernel's unloading parameters (see ``kernel.run_block``)."""
    return np.array(
        [
            float(sc.momentum_unloading),
            sc.unload_start_fraction,
            sc.unload_stop_fraction,
            sc.thruster_torque * sc.thruster_min_pulse_s / sc.dt,  # one pulse's impulse in a step
            max(1, round(sc.unload_pulse_period_s / sc.dt)),
            sc.unload_recovery_s,
            sc.pointing_requirement_deg,
        ]
    )


SKY_STEP = 1.0  # s between rows of the sky table the kernel interpolates


def sky_table(sc: Scenario, t: np.ndarray) -> np.ndarray:
    """The sky (``ephemeris.sky_table``) at times t (s): from the ephemerides with an epoch,
    else paper B's vectors (:func:`sun_direction`, a fixed Moon) with the same shadow model."""
    from rwlab.attitude import ephemeris

    if sc.epoch is not None:
        epoch = ephemeris.parse_epoch(sc.epoch)
        sun, moon = ephemeris.sun_moon_orbital(epoch, sc.station_longitude_deg, t)
    else:
        sun = np.array([sun_direction(sc, ti) for ti in t]) * ephemeris.AU
        moon = np.broadcast_to(MOON_DIRECTION / np.linalg.norm(MOON_DIRECTION) * 3.844e8, sun.shape)
    return ephemeris.sky_table(sun, moon)


def sensor_alignment(bias_deg, misalignment_deg, transverse: tuple[int, int]) -> np.ndarray:
    """The rotation (3, 3) from a true body vector to the one a sensor reports: its output
    bias (about its two ``transverse`` body axes) after its mounting misalignment (small
    angles, x y z)."""
    rot = np.radians(np.asarray(misalignment_deg, float))
    rot[list(transverse)] += np.radians(np.asarray(bias_deg, float))
    angle = float(np.linalg.norm(rot))
    return dcm(from_axis_angle(rot, angle)).T if angle > 0 else np.eye(3)


def _simulate_compiled(
    sc,
    controller,
    *,
    steps,
    estimator,
    log_every,
    streams,
    wheel_momentum0,
    filter_psd,
    noise_scale,
    steady_from,
    progress,
):
    J = sc.inertia_matrix
    J_inv = np.linalg.inv(J)
    G = sc.wheel_matrix
    q0, w0, hw0, q_hat, w_hat, P = _initial(sc, streams.init, wheel_momentum0)
    x = np.concatenate([q0, w0, hw0])
    use_ekf = estimator == "ekf"
    if not use_ekf:
        q_hat, w_hat = q0.copy(), w0.copy()
    n_log = steps // log_every + 2
    log_t, log_x, log_sky = np.zeros(n_log), np.zeros((n_log, x.size)), np.zeros((n_log, 3))
    log_est, log_tau, log_nees = np.zeros((n_log, 7)), np.zeros((n_log, 3)), np.zeros(n_log)
    dist = sc.disturbances.vector()
    dist_model = dist if sc.disturbances_known_to_filter else _known_only(sc)
    Qc = np.zeros((6, 6))
    Qc[3:, 3:] = filter_psd * J_inv @ J_inv.T
    m = noise_scale
    fov_cos = math.cos(math.radians(min(sc.sun_fov_deg, 180.0)))
    sensor_every = round(sc.sensor_period / sc.dt)
    period = controller.update_period
    block = BLOCK_STEPS if not period else max(1, min(BLOCK_STEPS, round(period / sc.dt)))
    noise_sd = sc.process_noise_torque / math.sqrt(sc.dt)
    stats = kernel.new_stats()
    unload = _unload_vector(sc)
    G_pinv = np.linalg.pinv(G)
    h_max = np.full(sc.n_wheels, sc.wheel_max_momentum)
    sun_align = sensor_alignment(sc.sun_sensor_bias_deg, sc.sun_sensor_misalignment_deg, (1, 2))
    earth_align = sensor_alignment(
        sc.earth_sensor_bias_deg, sc.earth_sensor_misalignment_deg, (0, 1)
    )
    exclusion = np.array([sc.earth_sensor_sun_exclusion_deg, sc.earth_sensor_moon_exclusion_deg])
    blind_cos = np.where(exclusion > 0, np.cos(np.radians(exclusion)), 2.0)  # 2: never blinded
    k, log_k, saturated = 0, 0, False
    while k <= steps:
        n_steps = min(block, steps + 1 - k)
        s_q, s_w = (q_hat, w_hat) if use_ekf else (x[:4], x[4:7])
        K = np.ascontiguousarray(
            controller.gain(k * sc.dt, s_q, _w_bo(s_q, s_w), G @ x[7:]), dtype=float
        )
        process, sensor = streams.block(k, n_steps, sensor_every, noise_sd)
        sky_t0 = math.floor(k * sc.dt / SKY_STEP) * SKY_STEP
        rows = math.ceil(((k + n_steps) * sc.dt - sky_t0) / SKY_STEP) + 2
        sky = sky_table(sc, sky_t0 + SKY_STEP * np.arange(rows))
        x, q_hat, w_hat, P, log_k, sat = kernel.run_block(
            x,
            q_hat,
            w_hat,
            P,
            k,
            n_steps,
            np.ascontiguousarray(K[:, 3:]),
            _rate_map(K),
            float(controller.rate_limit),
            use_ekf,
            sc.dt,
            sensor_every,
            log_every,
            steady_from,
            J,
            J_inv,
            G,
            G_pinv,
            h_max,
            sc.wheel_max_torque,
            GEO_RATE,
            dist,
            dist_model,
            process,
            sensor,
            Qc,
            sky,
            sky_t0,
            SKY_STEP,
            fov_cos,
            sc.sun_noise_incidence,
            math.radians(sc.sun_noise_deg),
            math.radians(sc.earth_noise_deg),
            math.radians(sc.sun_noise_deg) * m,
            math.radians(sc.earth_noise_deg) * m,
            sun_align,
            earth_align,
            blind_cos,
            np.array([sc.innovation_gate, sc.innovation_gate_max_rejections]),
            unload,
            stats,
            log_t,
            log_x,
            log_est,
            log_tau,
            log_nees,
            log_sky,
            log_k,
        )
        saturated |= sat
        k += n_steps
        if progress is not None:
            progress(min(k, steps))
    log_x, log_est = log_x[:log_k], log_est[:log_k]
    w_bo = np.array([_w_bo(r[:4], r[4:7]) for r in log_x])
    w_est = np.array([_w_bo(r[:4], r[4:7]) for r in log_est])
    wheel = rad_s_to_rpm(log_x[:, 7:] / sc.wheel_inertia)
    result = _result(
        log_t[:log_k],
        log_x[:, :4],
        w_bo,
        log_est[:, :4],
        w_est,
        log_tau[:log_k],
        wheel,
        log_nees[:log_k] if use_ekf else np.zeros(log_k),
        saturated,
        stats,
        steady_from * sc.dt,
    )
    result.sky = log_sky[:log_k]
    return result


BLOCK_STEPS = 36_000  # steps per kernel call without re-linearisation (an hour at 0.1 s)


def _known_only(sc: Scenario) -> np.ndarray:
    """The disturbance vector the filter models in paper B's setting: gravity gradient only."""
    d = sc.disturbances.vector()
    known = np.zeros_like(d)
    gg = 3 * GEO_RATE**2 * float(sc.disturbances.gravity_gradient)
    known[0] = gg
    return known


def _simulate_python(
    scenario,
    controller,
    *,
    steps,
    estimator,
    log_every,
    streams,
    wheel_momentum0,
    filter_psd,
    noise_scale,
    steady_from,
    progress,
) -> SimResult:
    sc = scenario
    sensor_every = round(sc.sensor_period / sc.dt)
    J = sc.inertia_matrix
    J_inv = np.linalg.inv(J)
    G = sc.wheel_matrix
    G_pinv = np.linalg.pinv(G)
    h_max = np.full(sc.n_wheels, sc.wheel_max_momentum)
    dist_true = sc.disturbances.vector()
    dist_model = dist_true if sc.disturbances_known_to_filter else _known_only(sc)
    q0, w0, hw0, q_hat0, w_hat0, P0 = _initial(sc, streams.init, wheel_momentum0)
    x = np.concatenate([q0, w0, hw0])
    wheels = _Wheels(sc, hw0)
    sig_sun = math.radians(sc.sun_noise_deg)
    sig_earth = math.radians(sc.earth_noise_deg)
    nadir = np.array([0.0, 0.0, 1.0])
    use_ekf = estimator == "ekf"
    if use_ekf:
        ekf = MEKF(J, q_hat0, w_hat0, P0, filter_psd, gg_gain=dist_model[0])
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
    process, sensor = streams.block(0, steps + 1, sensor_every, noise_sd)
    err = np.zeros(steps + 1)
    cmd = np.zeros((steps + 1, sc.n_wheels))
    h_frac = 0.0
    k_log = 0
    for k in range(steps + 1):
        t = k * sc.dt
        s_orb = sun_direction(sc, t)
        if use_ekf and k % sensor_every == 0:
            e = sensor[k // sensor_every]
            C = dcm(x[:4])
            sun_b = C @ s_orb
            if math.degrees(math.acos(max(-1.0, min(1.0, -sun_b[0])))) <= sc.sun_fov_deg:
                ekf.update(_noisy(sun_b, sig_sun, e[:3]), s_orb, sig_sun * noise_scale)
            ekf.update(_noisy(C @ nadir, sig_earth, e[3:]), nadir, sig_earth * noise_scale)
        q_hat, w_hat = (ekf.q, ekf.w) if use_ekf else (x[:4], x[4:7])
        h_body = G @ x[7:]
        tau_cmd = controller.torque(t, q_hat, _w_bo(q_hat, w_hat), h_body)
        cmd[k] = -G_pinv @ tau_cmd
        hw_dot = wheels.realise(cmd[k], x[7:], sc.dt)
        saturated |= bool(np.any(np.abs(x[7:]) >= h_max * 0.999))
        h_frac = max(h_frac, float(np.max(np.abs(x[7:]) / h_max)))
        err[k] = math.degrees(2 * math.asin(min(1.0, float(np.linalg.norm(x[:3])))))
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
        dist[7:10] += process[k]
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
        if progress is not None and k % BLOCK_STEPS == 0:
            progress(k)
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
        _stats_from_steps(err, cmd, sc.wheel_max_torque, steady_from, h_frac),
        steady_from * sc.dt,
    )


def _stats_from_steps(err, cmd, tau_max, steady_from, h_frac) -> np.ndarray:
    """The kernel's statistics from every step's error (°) and wheel commands (no unloading)."""
    s = kernel.new_stats()
    steady, cmd_steady = err[steady_from:], cmd[steady_from:]
    clipped = np.clip(cmd, -tau_max, tau_max)
    s[kernel.MAX_ERR] = err.max()
    s[kernel.STEADY_MAX] = s[kernel.STEADY_EXCL] = steady.max(initial=0.0)
    s[kernel.SAT_STEPS] = np.count_nonzero(np.any(np.abs(cmd_steady) >= tau_max, axis=1))
    s[kernel.STEADY_STEPS] = s[kernel.EXCL_STEPS] = steady.size
    s[kernel.TAU_PEAK] = np.abs(clipped).max()
    s[kernel.TAU_SQ] = np.sum(np.mean(clipped[steady_from:] ** 2, axis=1))
    s[kernel.ERR_SQ] = np.sum(steady**2)
    s[kernel.H_PEAK] = h_frac
    return s
