"""Closed-loop simulation: plant, wheels, sensors, estimator and a controller, step by step.

Each step of ``run.dt`` seconds: sensors measure (every ``sensors.period``), the
estimator updates, the controller returns a body torque, the torque is
allocated to the wheels (minimum-norm, clipped to their limits), the wheels
realise it (ideal, the RW physics of ``rwlab.wheel``, or the identified model
from ``model.json``), and the plant and the filter move one step.

Controllers are linear laws τ = −K s (:class:`LinearController`) acting on the
estimate (or on the truth with ``estimator='truth'``). :class:`Loop` sets a run up
(records, state, noise streams, block by block); the step itself is compiled
(``kernel.command_step`` + ``kernel.finish_step``, the wheel models of ``wheels`` in
between): ``simulate`` runs it a block at a time (``kernel.run_block``), ``hil.Satellite``
a period at a time with its wheels on a bus.

Why this module is long: the loop's set-up (noise streams, the filter's design noise,
initial state and estimate, the kernel's records), its controllers and its result type
sit beside the loop that uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rwlab._display import ShortRepr
from rwlab.attitude import kernel
from rwlab.attitude.frames import GEO_RATE, angle_deg, dcm, from_axis_angle, qmul
from rwlab.attitude.kernel import control_torque
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.wheels import jitter_arrays, transverse_axes, wheel_setup
from rwlab.errors import ConfigError
from rwlab.wheel.physics import rad_s_to_rpm

__all__ = [
    "LinearController",
    "Loop",
    "PDController",
    "SimResult",
    "attitude_noise_psd",
    "default_filter_psd",
    "disturbance_psd",
    "disturbance_state",
    "filter_psd",
    "relative_rate",
    "simulate",
    "steady_start",
    "sun_direction",
]

MOON_DIRECTION = np.array([0.6, -0.1, 0.79])  # orbital frame, slowly varying; fixed here


def sun_direction(scenario: Scenario, t: float) -> np.ndarray:
    """Unit vector to the Sun in the orbital frame at time t (s).

    Parameters
    ----------
    scenario : Scenario
        Its ``sun`` model.
    t : float
        Time since the start, s.

    Returns
    -------
    numpy.ndarray, shape (3,)
    """
    d = math.radians(scenario.sky.sun_declination_deg)
    theta = math.radians(scenario.sky.sun_phase_deg)
    if scenario.sky.sun == "moving":
        theta += GEO_RATE * t  # the orbital frame turns once a day relative to the Sun
    return np.array([-math.sin(theta) * math.cos(d), -math.sin(d), -math.cos(theta) * math.cos(d)])


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
    """Quaternion PD law τ = −Kp·2q_v·sign(q4) − Kd·ω_bo (like Basilisk's MRP feedback).

    Parameters
    ----------
    kp : float
        Proportional gain, N·m/rad.
    kd : float
        Derivative gain, N·m·s/rad.
    rate_limit : float
        Largest commanded rate in a large slew, rad/s.
    """

    def __init__(self, kp: float, kd: float, rate_limit: float = math.inf) -> None:
        self.K = np.hstack([kp * np.eye(3), kd * np.eye(3)])
        self.rate_limit = rate_limit

    def gain(self, t, q, w_bo, h_body) -> np.ndarray:
        return self.K


@dataclass(repr=False)
class SimResult(ShortRepr):
    """Time histories of one run (rows are logged steps) and statistics over every step.

    Attributes
    ----------
    t : (K,) s
    q : (K, 4) true attitude (orbital → body)
    w_bo : (K, 3) rad/s
    q_est, w_est : the estimate
    torque : (K, 3) body control torque, N·m
    wheel_speed_rpm : (K, N)
    error_deg : (K,) true pointing error
    est_error_deg : (K,) estimation error
    nees : (K,) normalised estimation error²
        At measurement steps; 0 without a filter.
    wheel_saturated : bool
        A wheel touched its momentum limit.
    stats : dict over every step (not only the logged ones), see ``kernel.STATS``.
    steady_from_s : start of the steady-state window, s.
    sky : (K, 3) sunlit fraction and the sun and earth sensors' status (0 used,
    1 unavailable: eclipse, field of view or blinding, 2 gated) at the logged steps.
    torque_est, srp_lever_est : (K, 3) the filter's disturbance states, N·m: a body
    torque and the SRP lever arm P·A·C_r·ρ (zeros for a state it lacks, see
    ``Scenario.filter.disturbance_state``).
    gyro_bias_est : (K, 3) the gyro-driven filter's bias estimate β̂, rad/s (zeros without).
    sun_sensor_alignment_est : (K, 3) its estimate of the sun sensor's misalignment (body
    axes), rad (zeros without).
    sigma : (K, 6) the filter's 1σ: attitude (rad, body axes), then rate (rad/s) or gyro
    bias (rad/s) (zeros without a filter): the ±3σ envelopes of the estimation error.
    est_error_axes : (K, 3) the estimation error per body axis, rad, 2 (q ⊗ q̂⁻¹)_v.
    tracker_status : (K,) the star tracker's status (0 used, 1 unavailable or absent).
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
    torque_est: np.ndarray | None = None
    srp_lever_est: np.ndarray | None = None
    gyro_bias_est: np.ndarray | None = None
    sun_sensor_alignment_est: np.ndarray | None = None
    sigma: np.ndarray | None = None
    est_error_axes: np.ndarray | None = None
    tracker_status: np.ndarray | None = None


def relative_rate(q, w, n=GEO_RATE):
    """ω_bo = ω − A(q) (0, −n, 0) for one row or each row of (K, 4) and (K, 3) arrays.

    Parameters
    ----------
    q : array, shape (4,) or (K, 4)
        Attitude quaternions, orbital → body.
    w : array, shape (3,) or (K, 3)
        Body rates, rad/s (inertial).
    n : float
        Orbit rate, rad/s.

    Returns
    -------
    numpy.ndarray, shape (3,) or (K, 3)
        The rates relative to the orbital frame, rad/s.
    """
    q1, q2, q3, q4 = (np.asarray(q, float)[..., i] for i in range(4))
    c = q4 * q4 - (q1 * q1 + q2 * q2 + q3 * q3)
    col = np.stack([2 * (q1 * q2 + q4 * q3), c + 2 * q2 * q2, 2 * (q2 * q3 - q4 * q1)], axis=-1)
    return w + n * col


def steady_start(duration: float) -> float:
    """Start of the steady-state window, s: half the run, at most its first hour.

    Parameters
    ----------
    duration : float
        Run length, s.

    Returns
    -------
    float
        The window's start, s.
    """
    return min(duration / 2, 3600.0)


def unknown_torque_bound(sc: Scenario) -> float:
    """A bound on the disturbance torque the filter does not model, N·m.

    SRP force times the centre-of-pressure offset, plus the Sun and Moon tides
    on the inertia spread and any constant torque; J2 is within the gravity
    gradient's 7e-5 margin.
    """
    d = sc.spacecraft.disturbances.vector()
    J = sc.inertia_matrix
    spread = float(np.ptp(np.linalg.eigvalsh(J)))
    tides = (d[5] + d[6]) * spread / 2
    return float(d[1] * np.linalg.norm(d[2:5]) + tides + np.linalg.norm(d[7:10]))


def default_filter_psd(sc: Scenario) -> float:
    """The torque PSD the filter assumes on its rate, N²·m²·s.

    With a disturbance state (``filter.disturbance_state``) the unknown torque
    is that state's job (:func:`bias_torque_psd`) and the rate carries only the
    white ``spacecraft.process_noise_torque``. Without it (paper B: SRP as process noise)
    and with the disturbances unknown to the filter, its process noise is sized so
    that the estimate's lag on the worst-case unmodelled torque τ_u stays within
    ``filter.disturbance_budget_deg`` (τ_u: ``filter.torque_bound``, or
    :func:`unknown_torque_bound` when that is 0): a Kalman filter on J θ̈ = τ measuring θ
    with PSD r lags a constant τ by τ/√(q/r), whatever J, so q = r (τ_u/θ_b)².

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    float
        The PSD, N²·m²·s.
    """
    q = sc.spacecraft.process_noise_torque**2
    if not sc.filter.disturbances_known and disturbance_state(sc) == "none":
        r = attitude_noise_psd(sc)
        bound = sc.filter.torque_bound or unknown_torque_bound(sc)
        q += r * (bound / math.radians(sc.filter.disturbance_budget_deg)) ** 2
    return q


def disturbance_state(sc: Scenario) -> str:
    """The filter's disturbance state as flown: ``filter.disturbance_state``, or "none"
    when there is nothing left to estimate (every disturbance known to the filter, or a
    torque bound of 0).

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    {'none', 'torque', 'srp', 'torque+srp'}
    """
    if filter_torque_scale(sc) == 0.0:
        return "none"
    return sc.filter.disturbance_state


def filter_torque_scale(sc: Scenario) -> float:
    """τ_u, N·m: the unmodelled torque the filter is designed for (``filter.torque_bound``,
    else :func:`unknown_torque_bound`; 0 with the disturbances known to the filter)."""
    if sc.filter.disturbances_known:
        return 0.0
    return sc.filter.torque_bound or unknown_torque_bound(sc)


def disturbance_psd(sc: Scenario) -> np.ndarray:
    """PSDs of the filter's disturbance random walks, N²·m²/s, one per state (n − 6,).

    Each walk spreads by τ_u (:func:`filter_torque_scale`) over its drift time: the
    constant torque over ``filter.torque_drift_s`` (a year: it is constant, the walk only keeps the
    filter from locking onto a wrong value), the SRP lever arm over
    ``filter.srp_drift_s`` (a day: the arrays turn once a day and the centre of
    pressure moves with them and with the seasons).

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    numpy.ndarray, shape (n − 6,)
        The PSDs, N²·m²/s.
    """
    tau = filter_torque_scale(sc)
    kind = disturbance_state(sc)
    psd = [tau**2 / sc.filter.torque_drift_s] * 3 if "torque" in kind else []
    return np.array(psd + ([tau**2 / sc.filter.srp_drift_s] * 3 if "srp" in kind else []))


# the kernel's codes for the disturbance state, and its size
BIAS_KINDS = {"none": 0, "torque": 1, "srp": 2, "torque+srp": 3}
BIAS_SIZES = {"none": 0, "torque": 3, "srp": 3, "torque+srp": 6}


def _bias_truth(sc: Scenario, dist, dist_model) -> np.ndarray:
    """What the disturbance state should converge to, N·m, for NEES: the constant torque
    and the SRP lever arm P·A·C_r·ρ that the filter does not model."""
    torque = np.asarray(dist[7:10] - dist_model[7:10])
    lever = (dist[1] - dist_model[1]) * np.asarray(dist[2:5])
    kind = disturbance_state(sc)
    return np.concatenate([torque if "torque" in kind else [], lever if "srp" in kind else []])


def attitude_noise_psd(sc: Scenario) -> float:
    """Attitude measurement noise as a continuous PSD, rad²·s: the sensors' mean σ (with the
    filter's margin) squared, times the sensor period.

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    float
        The PSD, rad²·s.
    """
    sigma = (
        math.radians((sc.sensors.sun_noise_deg + sc.sensors.earth_noise_deg) / 2)
        * sc.filter.noise_margin
    )
    return sigma**2 * sc.sensors.period


class _Streams:
    """One independent random stream per noise source, all from one seed."""

    def __init__(self, seed: int) -> None:
        # spawn keys are positional: the first three streams are those of earlier versions
        init, process, sensor, gyro, tracker = np.random.SeedSequence(seed).spawn(5)
        self.init = np.random.default_rng(init)
        self.process = np.random.default_rng(process)
        self.sensor = np.random.default_rng(sensor)
        self.gyro = np.random.default_rng(gyro)
        self.tracker = np.random.default_rng(tracker)

    def block(self, k: int, n_steps: int, every: tuple[int, int], noise_sd: float, sensors):
        """The noise of steps k… (:class:`kernel.Noise`): process torques, sensor normals
        (sun/earth and tracker ticks: ``every`` steps), gyro normals when gyros fly."""
        ticks = [len(range(-(-k // e) * e, k + n_steps, e)) for e in every]
        return kernel.Noise(
            process=self.process.standard_normal((n_steps, 3)) * noise_sd,
            sensor=self.sensor.standard_normal((ticks[0], 6)),
            gyro=self.gyro.standard_normal((n_steps if sensors.gyro else 0, 9)),
            tracker=self.tracker.standard_normal((ticks[1] if sensors.tracker else 0, 3)),
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
    steady_after: float | None = None,
    progress=None,
) -> SimResult:
    """Run the closed loop. ``estimator``: 'ekf' (LQG-style) or 'truth' (ideal LQR).

    Parameters
    ----------
    scenario : Scenario
    controller : LinearController
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
    steady_after : float, optional
        Seconds after which the steady-state statistics start (default
        :func:`steady_start`: half the run, at most its first hour).
    progress : callable, optional
        Called with the number of steps done after each block.

    Returns
    -------
    SimResult
        The logged time histories and the statistics over every step.

    Notes
    -----
    Every wheel model runs in the compiled kernel (``kernel.run_block``), in blocks
    of at most an hour of steps (shorter when the controller re-linearises).
    """
    if estimator not in ("ekf", "truth"):
        raise ConfigError(f"estimator must be 'ekf' or 'truth', got {estimator!r}")
    if not isinstance(controller, LinearController):
        raise ConfigError(f"controller must be a LinearController, got {type(controller).__name__}")
    duration = scenario.run.duration if duration is None else duration
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration!r}")
    steps = round(duration / scenario.run.dt)
    if steps < 1:
        raise ConfigError(
            f"duration {duration:g} s is shorter than one step ({scenario.run.dt:g} s)"
        )
    sensor_every = round(scenario.sensors.period / scenario.run.dt)
    if steady_after is None:
        steady_after = steady_start(steps * scenario.run.dt)
    elif not (_is_real(steady_after) and 0 <= steady_after < steps * scenario.run.dt):
        raise ConfigError(
            f"steady_after must be a number of seconds in [0, duration), got {steady_after!r}"
        )
    loop = Loop(
        scenario,
        controller,
        steps=steps,
        estimator=estimator,
        log_every=-(-max(1, int(log_every)) // sensor_every) * sensor_every,
        seed=scenario.run.seed if seed is None else seed,
        wheel_momentum0=wheel_momentum0,
        filter_psd=filter_psd(scenario, filter_torque_psd),
        noise_scale=scenario.filter.noise_margin * filter_noise_scale,
        steady_from=round(steady_after / scenario.run.dt),
    )
    return _fly_blocks(loop, progress)


def filter_psd(sc: Scenario, filter_torque_psd: float | None) -> float:
    """The torque PSD the filter assumes, N²·m²·s: :func:`default_filter_psd`, or the
    process noise plus ``filter_torque_psd`` (LTR's fictitious noise) when given.

    Parameters
    ----------
    sc : Scenario
    filter_torque_psd : float or None
        N²·m²·s.

    Returns
    -------
    float
    """
    if filter_torque_psd is None:
        return default_filter_psd(sc)
    return sc.spacecraft.process_noise_torque**2 + filter_torque_psd


SUN_ALIGNMENT_PRIOR_DEG = 0.03  # 1σ of the sun sensor's misalignment the filter starts from
SUN_ALIGNMENT_DRIFT_DEG_DAY = 0.005  # its random walk a day (thermal distortion)


def _aligned(sc: Scenario) -> int:
    """How many sensors' misalignments the gyro filter carries: 0, 1 (the sun sensor's) or
    2 (and the earth sensor's)."""
    if sc.sensors.gyro is None or not sc.filter.sun_sensor_alignment:
        return 0
    return 2 if sc.filter.earth_sensor_alignment else 1


def _is_real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _initial(sc: Scenario, rng, wheel_momentum0):
    """True and estimated initial states. The estimate after q̂ is [ω̂], or [ω̂, b̂] with b̂
    at its prior mean 0 with σ the designer's torque bound (:func:`filter_torque_scale`)."""
    q0 = from_axis_angle(sc.run.initial_axis, math.radians(sc.run.initial_error_deg))
    w0 = dcm(q0) @ np.array([0.0, -GEO_RATE, 0.0]) + np.asarray(sc.run.initial_rate, float)
    hw0 = bias_momenta(sc) if wheel_momentum0 is None else np.asarray(wheel_momentum0, float)
    dq = from_axis_angle(rng.standard_normal(3), math.radians(sc.filter.initial_error_deg))
    s0 = math.radians(max(sc.filter.initial_error_deg, 0.1))
    P0 = np.diag([s0**2] * 3 + [(1e-4) ** 2] * 3)
    w_hat = w0 + 1e-5 * rng.standard_normal(3)
    if (
        sc.sensors.gyro is not None
    ):  # the gyro-driven filter: [δθ, δβ (, φ)], β̂ = 0 at the turn-on σ
        sb = math.radians(max(sc.sensors.gyro.initial_bias_deg_h, 1e-3)) / 3600.0
        sphi = [math.radians(SUN_ALIGNMENT_PRIOR_DEG) ** 2] * 3 * _aligned(sc)
        P0 = np.diag([s0**2] * 3 + [sb**2] * 3 + sphi)
        return q0, w0, hw0, qmul(dq, q0), np.zeros(3 + len(sphi)), P0
    nb = BIAS_SIZES[disturbance_state(sc)]
    if nb:
        sb = filter_torque_scale(sc)
        P0 = np.diag(np.concatenate([np.diag(P0), [sb**2] * nb]))
        w_hat = np.concatenate([w_hat, np.zeros(nb)])
    return q0, w0, hw0, qmul(dq, q0), w_hat, P0


def _result(t, q, w_bo, q_est, w_est, torque, wheel, nees, saturated, stats, steady_s):
    q = np.where(q[:, 3:4] >= 0, q, -q)
    q_est = np.where(q_est[:, 3:4] >= 0, q_est, -q_est)
    # q ⊗ q̂⁻¹ row by row (frames.qmul, vectorised): its angle is the estimation error
    av, a4, bv, b4 = q[:, :3], q[:, 3:], q_est[:, :3], q_est[:, 3:]
    dq = np.hstack(
        [b4 * av - a4 * bv + np.cross(av, bv), a4 * b4 + np.sum(av * bv, axis=1)[:, None]]
    )
    est_err = angle_deg(dq)
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
            float(sc.momentum.unloading),
            sc.momentum.unload_start_fraction,
            sc.momentum.unload_stop_fraction,
            sc.momentum.thruster_torque
            * sc.momentum.thruster_min_pulse_s
            / sc.run.dt,  # one pulse's impulse in a step
            max(1, round(sc.momentum.unload_pulse_period_s / sc.run.dt)),
            sc.momentum.unload_recovery_s,
            sc.control.pointing_requirement_deg,
            NULL_BIAS_GAIN if sc.n_wheels > 3 and sc.momentum.bias else 0.0,
            NULL_BIAS_TORQUE_FRACTION * sc.wheels.max_torque,
        ]
    )


NULL_BIAS_GAIN = 1.0 / 600.0  # 1/s: the null-space loop's 10-min time constant
NULL_BIAS_TORQUE_FRACTION = 0.02  # of the rated torque: what the null loop may use


def null_vector(G: np.ndarray) -> np.ndarray:
    """The wheels' unit null vector n (N,), G n = 0, its first entry > 0; zeros when the
    wheels have no null space (three wheels).

    Parameters
    ----------
    G : numpy.ndarray, shape (3, N)
        Wheel spin axes in body axes.

    Returns
    -------
    numpy.ndarray, shape (N,)
    """
    if G.shape[1] <= 3:
        return np.zeros(G.shape[1])
    n = np.linalg.svd(G)[2][-1]
    return n * np.sign(n[np.flatnonzero(np.abs(n) > 1e-12)[0]])


def bias_momenta(sc: Scenario) -> np.ndarray:
    """The wheel momenta (N,) N·m·s the momentum bias holds the wheels at: with a null
    space (the 4-wheel pyramid) ``momentum_bias`` along the unit null vector — no body
    momentum, so no body torque and nothing for the thrusters to unload; with three
    orthogonal wheels the pitch wheel (body y) at ``momentum_bias``: the orbit rate's axis,
    so that momentum stays put inertially (no roll/yaw interchange) and the unloading
    keeps it there. Roll and yaw wheels of a 3-wheel set cannot be biased: a body-fixed
    roll/yaw momentum turns once an orbit in inertial space and would cost thrust."""
    if not sc.momentum.bias:
        return np.zeros(sc.n_wheels)
    G = sc.wheel_matrix
    if G.shape[1] > 3:
        return sc.momentum.bias * null_vector(G)
    return np.linalg.pinv(G) @ np.array([0.0, sc.momentum.bias, 0.0])


SKY_STEP = 1.0  # s between rows of the sky table the kernel interpolates


def sky_table(sc: Scenario, t: np.ndarray) -> np.ndarray:
    """The sky (``ephemeris.sky_table``) at times t (s): from the ephemerides with an epoch,
    else paper B's vectors (:func:`sun_direction`, a fixed Moon) with the same shadow model."""
    from rwlab.attitude import ephemeris

    if sc.sky.epoch is not None:
        epoch = ephemeris.parse_epoch(sc.sky.epoch)
        sun, moon = ephemeris.sun_moon_orbital(epoch, sc.sky.station_longitude_deg, t)
    else:
        moon = MOON_DIRECTION / np.linalg.norm(MOON_DIRECTION) * 3.844e8
        if sc.sky.sun != "moving":  # paper B's fixed sky: every row the same, computed once
            sun = sun_direction(sc, 0.0) * ephemeris.AU
            row = ephemeris.sky_table(sun[None, :], moon[None, :])
            return np.repeat(row, len(t), axis=0)
        sun = np.array([sun_direction(sc, ti) for ti in t]) * ephemeris.AU
        moon = np.broadcast_to(moon, sun.shape)
    return ephemeris.sky_table(sun, moon)


def sensor_alignment(bias_deg, misalignment_deg, transverse: tuple[int, int]) -> np.ndarray:
    """The rotation (3, 3) from a true body vector to the one a sensor reports: its output
    bias (about its two ``transverse`` body axes) after its mounting misalignment (small
    angles, x y z)."""
    rot = np.radians(np.asarray(misalignment_deg, float))
    rot[list(transverse)] += np.radians(np.asarray(bias_deg, float))
    angle = float(np.linalg.norm(rot))
    if angle > 0:
        # C-ordered like every array the kernel takes: a transposed (F-ordered) one is
        # another numba type, and ``run_block`` would be compiled again for it
        return np.ascontiguousarray(dcm(from_axis_angle(rot, angle)).T)
    return np.eye(3)


def _plant_record(sc: Scenario) -> kernel.Plant:
    G = sc.wheel_matrix
    imbalance, positions = jitter_arrays(sc)
    return kernel.Plant(
        dt=sc.run.dt,
        n=GEO_RATE,
        J=sc.inertia_matrix,
        J_inv=np.linalg.inv(sc.inertia_matrix),
        G=G,
        G_pinv=np.linalg.pinv(G),
        h_max=np.full(sc.n_wheels, sc.wheels.max_momentum),
        tau_max=sc.wheels.max_torque,
        dist=sc.spacecraft.disturbances.vector(),
        wheel_inertia=sc.wheels.inertia,
        torque_scale=sc.wheels.torque_scale,
        jitter=bool(imbalance.any()),
        imbalance=imbalance,
        wheel_position=positions,
        rotor_axes=transverse_axes(G),
    )


def _sensor_record(sc: Scenario, gyro_E: np.ndarray) -> kernel.Sensors:
    """The true sensors; ``gyro_E`` (3, 3): the gyro unit's scale factors and misalignment."""
    from rwlab.attitude.sensors import star_tracker_frame

    exclusion = np.array(
        [sc.sensors.earth_sensor_sun_exclusion_deg, sc.sensors.earth_sensor_moon_exclusion_deg]
    )
    every = round(sc.sensors.period / sc.run.dt)
    gyro, st = sc.sensors.gyro, sc.sensors.star_tracker
    return kernel.Sensors(
        every=every,
        sun_fov_cos=math.cos(math.radians(min(sc.sensors.sun_fov_deg, 180.0))),
        sun_incidence=sc.sensors.sun_noise_incidence,
        sig_sun=math.radians(sc.sensors.sun_noise_deg),
        sig_earth=math.radians(sc.sensors.earth_noise_deg),
        sun_align=sensor_alignment(
            sc.sensors.sun_sensor_bias_deg, sc.sensors.sun_sensor_misalignment_deg, (1, 2)
        ),
        earth_align=sensor_alignment(
            sc.sensors.earth_sensor_bias_deg, sc.sensors.earth_sensor_misalignment_deg, (0, 1)
        ),
        blind_cos=np.where(exclusion > 0, np.cos(np.radians(exclusion)), 2.0),  # 2: never
        gyro=gyro is not None,
        gyro_par=gyro.vector(sc.run.dt) if gyro is not None else np.zeros(4),
        gyro_E=gyro_E,
        tracker=st is not None,
        tracker_every=round(st.period_s / sc.run.dt) if st is not None else every,
        tracker_frame=star_tracker_frame(st.boresight) if st is not None else np.eye(3),
        tracker_sigma=st.sigma_rad() if st is not None else np.zeros(3),
        tracker_cos=st.exclusion_cos() if st is not None else np.full(3, 2.0),
    )


def _filter_record(sc: Scenario, estimator: str, nx: int, filter_psd: float, scale: float):
    """The estimator (:class:`kernel.Filter`) for an ``nx``-state filter."""
    from rwlab.attitude.ekf import gyro_process_noise

    dist = sc.spacecraft.disturbances.vector()
    dist_model = dist if sc.filter.disturbances_known else _known_only(sc)
    mode = kernel.TRUTH if estimator == "truth" else kernel.DYNAMICS
    bias_true = _bias_truth(sc, dist, dist_model)
    if sc.sensors.gyro is not None and estimator != "truth":
        mode = kernel.GYRO
        Qc = gyro_process_noise(sc.sensors.gyro.sigma_v**2, sc.sensors.gyro.filter_bias_psd(), nx)
        if nx > 6:
            Qc[6:, 6:] = np.eye(nx - 6) * math.radians(SUN_ALIGNMENT_DRIFT_DEG_DAY) ** 2 / 86400
        # the truth of φ: each sensor's rotation (bias on its transverse axes, misalignment)
        sun = np.radians(np.asarray(sc.sensors.sun_sensor_misalignment_deg, float))
        sun[1:] += np.radians(np.asarray(sc.sensors.sun_sensor_bias_deg, float))
        earth = np.radians(np.asarray(sc.sensors.earth_sensor_misalignment_deg, float))
        earth[:2] += np.radians(np.asarray(sc.sensors.earth_sensor_bias_deg, float))
        bias_true = np.concatenate([sun, earth])[: nx - 6]
    else:
        J_inv = np.linalg.inv(sc.filter_inertia_matrix)
        Qc = np.zeros((nx, nx))
        Qc[3:6, 3:6] = filter_psd * J_inv @ J_inv.T
        if nx > 6:
            Qc[6:, 6:] = np.diag(disturbance_psd(sc))
    st = sc.sensors.star_tracker
    return kernel.Filter(
        mode=mode,
        bias_kind=BIAS_KINDS[disturbance_state(sc)] if mode == kernel.DYNAMICS else 0,
        bias_true=bias_true,
        dist_model=dist_model,
        Qc=Qc,
        r_sun=math.radians(sc.sensors.sun_noise_deg) * scale,
        r_earth=math.radians(sc.sensors.earth_noise_deg) * scale,
        gate=np.array(
            [sc.filter.innovation_gate, sc.filter.innovation_gate_max_rejections], dtype=float
        ),
        tracker_R=st.body_covariance() * scale**2 if st is not None else np.eye(3),
        J=sc.filter_inertia_matrix,
        J_inv=np.linalg.inv(sc.filter_inertia_matrix),
    )


def _log_record(steps: int, log_every: int, steady_from: int, m: int) -> kernel.Log:
    n_log = steps // log_every + 2
    return kernel.Log(
        every=log_every,
        steady_from=steady_from,
        t=np.zeros(n_log),
        x=np.zeros((n_log, m)),
        est=np.zeros((n_log, 19)),
        tau=np.zeros((n_log, 3)),
        nees=np.zeros(n_log),
        sky=np.zeros((n_log, 4)),
        sigma=np.zeros((n_log, 6)),
    )


def _law_record(sc: Scenario, controller, K: np.ndarray) -> kernel.Law:
    return kernel.Law(
        K_w=np.ascontiguousarray(K[:, 3:]),
        M=_rate_map(K),
        w_max=float(controller.rate_limit),
        unload=_unload_vector(sc),
        hw_target=bias_momenta(sc),
        null=null_vector(sc.wheel_matrix),
    )


class Loop:
    """One run's attitude loop, set up: its records, state and noise streams, block by block.

    ``simulate`` runs each block compiled (``kernel.run_block``); ``hil.Satellite`` runs
    the same step (``kernel.command_step`` and ``kernel.finish_step``) period by period
    with its wheels on a bus in between. Both take every input from here.

    Parameters
    ----------
    scenario : Scenario
    controller : LinearController
    steps : int
        Steps of ``run.dt`` to fly (``steps + 1`` samples).
    estimator : {'ekf', 'truth'}
    log_every : int
        Steps between logged rows (a whole number of sensor periods).
    seed : int
        Seeds the independent noise streams.
    wheel_momentum0 : (N,) array or None
        Initial wheel momenta, N·m·s (None: the momentum bias).
    filter_psd : float
        The torque PSD the filter assumes, N²·m²·s.
    noise_scale : float
        Scales the sensor σ the filter assumes.
    steady_from : int
        First step of the steady-state statistics.
    """

    def __init__(
        self,
        scenario: Scenario,
        controller: LinearController,
        *,
        steps: int,
        estimator: str,
        log_every: int,
        seed: int,
        wheel_momentum0: np.ndarray | None,
        filter_psd: float,
        noise_scale: float,
        steady_from: int,
    ) -> None:
        sc = self.scenario = scenario
        self.controller, self.steps, self.steady_from = controller, steps, steady_from
        self.streams = _Streams(seed)
        q0, w0, hw0, q_hat, w_hat, P = _initial(sc, self.streams.init, wheel_momentum0)
        x = np.concatenate([q0, w0, hw0])
        if estimator != "ekf":
            q_hat, w_hat, P = q0.copy(), w0.copy(), P[:6, :6].copy()
        gyro_state, gyro_E = np.zeros(9), np.zeros((3, 3))
        if sc.sensors.gyro is not None:  # the unit's fixed errors and turn-on bias
            from rwlab.attitude.sensors import draw_gyro_errors

            gyro_E, gyro_state[:3] = draw_gyro_errors(sc.sensors.gyro, self.streams.gyro)
            gyro_state[6:] = w0
        self.plant = _plant_record(sc)
        self.sensors = _sensor_record(sc, gyro_E)
        self.filt = _filter_record(sc, estimator, P.shape[0], filter_psd, noise_scale)
        self.log = _log_record(steps, log_every, steady_from, x.size)
        self.state = kernel.State(
            x=x,
            q_hat=q_hat,
            w_hat=w_hat,
            P=P,
            gyro=gyro_state,
            stats=kernel.new_stats(),
            wheel_sign=np.sign(hw0),
            wheel_angle=np.zeros(hw0.size),
        )
        self.work = kernel.new_work(self.plant, self.filt, P.shape[0])
        self.wheels = wheel_setup(sc, hw0)
        period = controller.update_period
        self.block_steps = (
            BLOCK_STEPS if not period else max(1, min(BLOCK_STEPS, round(period / sc.run.dt)))
        )
        self.noise_sd = sc.spacecraft.process_noise_torque / math.sqrt(sc.run.dt)

    def block(self, k: int) -> tuple[kernel.Law, kernel.Sky, kernel.Noise, int]:
        """The block that starts at step ``k``: the law (the gain at what the controller
        knows now), the sky table, the block's noise and its number of steps."""
        sc, x, filt, sn = self.scenario, self.state.x, self.filt, self.sensors
        n_steps = min(self.block_steps, self.steps + 1 - k)
        # the gain's operating point: what the controller knows (with gyros, q̂ and the
        # nominal rate, ω_bo = 0)
        s_q = x[:4] if filt.mode == kernel.TRUTH else self.state.q_hat
        s_w = {
            kernel.TRUTH: x[4:7],
            kernel.DYNAMICS: self.state.w_hat[:3],
            kernel.GYRO: dcm(s_q) @ np.array([0.0, -GEO_RATE, 0.0]),
        }[filt.mode]
        K = np.ascontiguousarray(
            self.controller.gain(k * sc.run.dt, s_q, relative_rate(s_q, s_w), self.plant.G @ x[7:]),
            dtype=float,
        )
        noise = self.streams.block(k, n_steps, (sn.every, sn.tracker_every), self.noise_sd, sn)
        sky_t0 = math.floor(k * sc.run.dt / SKY_STEP) * SKY_STEP
        rows = math.ceil(((k + n_steps) * sc.run.dt - sky_t0) / SKY_STEP) + 2
        sky = kernel.Sky(sky_table(sc, sky_t0 + SKY_STEP * np.arange(rows)), sky_t0, SKY_STEP)
        return _law_record(sc, self.controller, K), sky, noise, n_steps

    def result(self, log_k: int) -> SimResult:
        """The run's first ``log_k`` logged rows and its statistics as a :class:`SimResult`."""
        sc, mode = self.scenario, self.filt.mode
        saturated = self.work.flags[kernel.SATURATED] > 0
        result = _assemble(sc, self.log, log_k, saturated, self.state.stats, self.steady_from, mode)
        result.stats["steps"] = self.steps
        result.stats["dt_s"] = sc.run.dt
        result.stats["sensor_period_s"] = sc.sensors.period
        result.stats["filter_states"] = self.state.P.shape[0] if mode != kernel.TRUTH else 0
        return result


def _fly_blocks(loop: Loop, progress) -> SimResult:
    """Every block of ``loop`` compiled (``kernel.run_block``)."""
    k = log_k = 0
    while k <= loop.steps:
        law, sky, noise, n_steps = loop.block(k)
        log_k, _ = kernel.run_block(
            loop.state,
            loop.work,
            k,
            n_steps,
            log_k,
            loop.plant,
            law,
            sky,
            loop.sensors,
            loop.filt,
            noise,
            loop.wheels,
            loop.log,
        )
        k += n_steps
        if progress is not None:
            progress(min(k, loop.steps))
    return loop.result(log_k)


def _assemble(sc, log, log_k, saturated, stats, steady_from, mode) -> SimResult:
    log_x, log_est = log.x[:log_k], log.est[:log_k]
    w_bo = relative_rate(log_x[:, :4], log_x[:, 4:7])
    w_est = relative_rate(log_est[:, :4], log_est[:, 4:7])
    wheel = rad_s_to_rpm(log_x[:, 7:] / sc.wheels.inertia)
    result = _result(
        log.t[:log_k],
        log_x[:, :4],
        w_bo,
        log_est[:, :4],
        w_est,
        log.tau[:log_k],
        wheel,
        log.nees[:log_k] if mode != kernel.TRUTH else np.zeros(log_k),
        saturated,
        stats,
        steady_from * sc.run.dt,
    )
    result.sky = log.sky[:log_k, :3]
    result.tracker_status = log.sky[:log_k, 3]
    result.torque_est, result.srp_lever_est = log_est[:, 7:10], log_est[:, 10:13]
    result.gyro_bias_est = log_est[:, 13:16]
    result.sun_sensor_alignment_est = log_est[:, 16:19]
    result.sigma = log.sigma[:log_k]
    result.est_error_axes = _axis_errors(result.q, result.q_est)
    return result


def _axis_errors(q: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """2 (q ⊗ q̂⁻¹)_v row by row (the filter's δθ, body axes), rad (K, 3)."""
    av, a4, bv, b4 = q[:, :3], q[:, 3:], q_est[:, :3], q_est[:, 3:]
    v = b4 * av - a4 * bv + np.cross(av, bv)
    sign = np.where(a4[:, 0] * b4[:, 0] + np.sum(av * bv, axis=1) >= 0, 2.0, -2.0)
    return v * sign[:, None]


BLOCK_STEPS = 36_000  # steps per kernel call without re-linearisation (an hour at 0.1 s)


def _known_only(sc: Scenario) -> np.ndarray:
    """The disturbance vector the filter models in paper B's setting: gravity gradient only."""
    d = sc.spacecraft.disturbances.vector()
    known = np.zeros_like(d)
    gg = 3 * GEO_RATE**2 * float(sc.spacecraft.disturbances.gravity_gradient)
    known[0] = gg
    return known
