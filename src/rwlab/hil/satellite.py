"""The satellite on the host: plant, sky, sensors, MEKF and controller, period by period.

:class:`Satellite` is the attitude loop of :func:`rwlab.attitude.sim.simulate`
cut open at the wheels. Each control period the host asks it for the wheel
torques (:meth:`Satellite.wheel_torques`: sensors, filter update, control law,
thruster unloading, allocation), sends them to the wheels, and hands back the
wheel momenta the wheels then *report* (:meth:`Satellite.advance`): the plant
takes the wheels' torque over the period as the change of that reported
momentum, so latency, quantisation, friction, dropouts and faults act on the
satellite as they would in flight.

Written in Python on purpose (the compiled ``kernel.run_block`` runs a whole
block without returning, and a bus cannot live inside it); the numerics are
the same: ``plant.rk4_step`` for the body and the filter's prediction, the
MEKF of ``attitude.ekf``, the sky of ``sim.sky_table`` and the noise streams
of ``sim.simulate``, drawn in the same blocks, so that the same scenario and
seed flown here with ideal wheels repeats ``attitude simulate`` (a test holds
them equal) and every difference on the bench is the wheels'.

Why this module is long: it mirrors ``attitude.sim``'s compiled loop period by period (a
test holds them equal); kept as one class so the two can be read side by side.
"""

from __future__ import annotations

import math

import numpy as np

from rwlab.attitude import kernel
from rwlab.attitude.ekf import (
    aligned_update_into,
    attitude_update_into,
    error_jacobian_into,
    gated_update_into,
    gyro_jacobian_into,
    predict_covariance_into,
    propagate_attitude_into,
)
from rwlab.attitude.frames import GEO_RATE, dcm, skew
from rwlab.attitude.plant import rk4_step
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sensors import draw_gyro_errors, gyro_sample_into, tracker_visible
from rwlab.attitude.sim import (
    BLOCK_STEPS,
    SKY_STEP,
    LinearController,
    SimResult,
    _axis_errors,
    _filter_record,
    _initial,
    _rate_map,
    _result,
    _sensor_record,
    _Streams,
    _unload_vector,
    _w_bo,
    control_torque,
    default_filter_psd,
    sky_table,
    steady_start,
)
from rwlab.errors import ConfigError
from rwlab.wheel.physics import rad_s_to_rpm

__all__ = ["Satellite"]

_S = {name: i for i, name in enumerate(kernel.STATS)}


def _noisy(b: np.ndarray, sigma: float, e: np.ndarray) -> np.ndarray:
    """Unit vector b turned by the small angle σ·e (e: three standard normals)."""
    v = b + sigma * np.cross(e, b)
    return v / np.linalg.norm(v)


class Satellite:
    """The attitude loop with the wheels outside it.

    Parameters
    ----------
    scenario : Scenario
    controller : LinearController
    estimator : {'ekf', 'truth'}
        The MEKF's estimate (LQG) or the true state (LQR) feeds the law.
    duration : float
        Seconds; the loop runs ``round(duration / dt) + 1`` control periods, as
        ``simulate`` does.
    seed : int
        Seeds the noise streams (the same streams as ``simulate``'s).
    wheel_momentum0 : (N,) array, optional
        Initial wheel momenta, N·m·s (their speeds must then be the wheels' own).
    filter_torque_psd, filter_noise_scale : see :func:`rwlab.attitude.sim.simulate`.
    steady_after : float, optional
        Seconds after which the steady-state statistics start (as ``simulate``'s;
        default half the run, at most its first hour).
    log_every : int
        Control periods between logged rows (rounded up to whole sensor periods).
    """

    def __init__(
        self,
        scenario: Scenario,
        controller: LinearController,
        *,
        estimator: str = "ekf",
        duration: float,
        seed: int = 0,
        wheel_momentum0: np.ndarray | None = None,
        filter_torque_psd: float | None = None,
        filter_noise_scale: float = 1.0,
        log_every: int = 10,
        steady_after: float | None = None,
    ) -> None:
        if estimator not in ("ekf", "truth"):
            raise ConfigError(f"estimator must be 'ekf' or 'truth', got {estimator!r}")
        if not (math.isfinite(duration) and duration >= scenario.run.dt):
            raise ConfigError(f"duration must be at least one step ({scenario.run.dt:g} s)")
        if scenario.momentum.bias:
            raise ConfigError(
                "the HIL loop sets the wheels' bias itself (HilConfig.wheel_bias_rpm, "
                "rwlab hil --wheel-bias-rpm): set momentum.bias = 0 in the scenario"
            )
        sc = self.scenario = scenario
        self.controller = controller
        self.use_ekf = estimator == "ekf"
        self.dt = sc.run.dt
        self.steps = round(duration / sc.run.dt)
        self.sensor_every = round(sc.sensors.period / sc.run.dt)
        self.log_every = -(-max(1, int(log_every)) // self.sensor_every) * self.sensor_every
        if steady_after is None:
            steady_after = steady_start(self.steps * sc.run.dt)
        elif not (math.isfinite(steady_after) and 0 <= steady_after < self.steps * sc.run.dt):
            raise ConfigError(
                f"steady_after must be a number of seconds in [0, duration), got {steady_after!r}"
            )
        self.steady_from = round(steady_after / sc.run.dt)
        self.streams = _Streams(seed)
        x_q, w0, hw0, q_hat, w_hat, P = _initial(sc, self.streams.init, wheel_momentum0)
        self.x = np.concatenate([x_q, w0, hw0])
        if not self.use_ekf:
            q_hat, w_hat, P = x_q.copy(), w0.copy(), P[:6, :6].copy()
        self.q_hat, self.w_hat, self.P = q_hat, w_hat, P
        self.J = sc.inertia_matrix
        self.J_inv = np.linalg.inv(self.J)
        self.G = sc.wheel_matrix
        self.nw = self.G.shape[1]
        self.h_max = np.full(self.nw, sc.wheels.max_momentum)
        self.dist = sc.spacecraft.disturbances.vector()
        # the gyros' state [β walk, β Gauss–Markov, ω at the last sample] and the unit's
        # fixed errors, drawn as simulate draws them
        self.gs, gyro_E = np.zeros(9), np.zeros((3, 3))
        if sc.sensors.gyro is not None:
            gyro_E, self.gs[:3] = draw_gyro_errors(sc.sensors.gyro, self.streams.gyro)
            self.gs[6:] = w0
        self.sensors = _sensor_record(sc, gyro_E)
        psd = (
            default_filter_psd(sc)
            if filter_torque_psd is None
            else sc.spacecraft.process_noise_torque**2 + filter_torque_psd
        )
        nx = P.shape[0]
        m = sc.filter.noise_margin * filter_noise_scale
        # the estimator as the compiled loop has it (its own inertia, noise, gates)
        self.filt = _filter_record(sc, estimator, nx, psd, m)
        self.mode = self.filt.mode
        self.biased = self.mode == kernel.DYNAMICS and nx > 6
        self.aligned = self.mode == kernel.GYRO and nx >= 9  # the sun sensor's turn
        self.earth_aligned = self.mode == kernel.GYRO and nx == 12
        self.Bmap = np.zeros((3, max(nx - 6, 3)))
        if self.filt.bias_kind != 2:
            self.Bmap[:, :3] = np.eye(3)
        self.w_mean, self.w_meas = np.zeros(3), np.zeros(3)
        self.unload = _unload_vector(sc)
        self.noise_sd = sc.spacecraft.process_noise_torque / math.sqrt(sc.run.dt)
        period = controller.update_period
        self.block = (
            BLOCK_STEPS if not period else max(1, min(BLOCK_STEPS, round(period / sc.run.dt)))
        )
        self.stats = kernel.new_stats()
        self.saturated = False
        self.k = 0
        self.active = np.ones(self.nw, dtype=bool)
        self._pinv = np.linalg.pinv(self.G)
        self._work = np.empty((5, self.x.size))
        self._F = np.empty((nx, nx))
        self._W3 = np.empty((4, 3, 3))
        self._Wn = np.empty((6, nx, nx))
        self._sun_rejected = self._earth_rejected = 0
        self._status = (0.0, 0.0)
        self._tracker_status = 0.0
        self._log: dict[str, list] = {
            name: [] for name in ("t", "x", "est", "tau", "nees", "sky", "cmd", "sensors", "sigma")
        }
        self._hw_dot_last = np.zeros(self.nw)
        self._hw_prev = np.zeros(self.nw)
        self._step: dict = {}
        self.last_sensors: dict = {}
        self.last_tracker: np.ndarray | None = None  # the tracker's q at this tick, if any

    # -- allocation ------------------------------------------------------------------
    def set_active(self, active: np.ndarray) -> None:
        """Allocate torque to these wheels only (bool (N,)); the others are fed forward.

        The minimum-norm allocation over the remaining columns of G is the
        null-space reallocation: with a pyramid any three wheels still span the body.
        """
        active = np.asarray(active, dtype=bool).copy()
        G = self.G[:, active]
        if np.linalg.matrix_rank(G) < 3:
            raise ConfigError(
                f"the wheels left ({int(active.sum())}) no longer span three axes; "
                "the satellite cannot be controlled"
            )
        pinv = np.zeros((self.nw, 3))
        pinv[active] = np.linalg.pinv(G)
        self.active, self._pinv = active, pinv

    @property
    def t(self) -> float:
        """Time of the current control period, s."""
        return self.k * self.dt

    @property
    def done(self) -> bool:
        return self.k > self.steps

    # -- one control period -------------------------------------------------------------
    def _new_block(self) -> None:
        sc, k, sn = self.scenario, self.k, self.sensors
        n_steps = min(self.block, self.steps + 1 - k)
        # the gain's operating point: what the controller knows (with gyros, q̂ and the
        # nominal rate, ω_bo = 0), as simulate takes it
        if self.mode == kernel.TRUTH:
            s_q, s_w = self.x[:4], self.x[4:7]
        elif self.mode == kernel.GYRO:
            s_q = self.q_hat
            s_w = dcm(s_q) @ np.array([0.0, -GEO_RATE, 0.0])
        else:
            s_q, s_w = self.q_hat, self.w_hat[:3]
        K = np.asarray(
            self.controller.gain(k * sc.run.dt, s_q, _w_bo(s_q, s_w), self.G @ self.x[7:]), float
        )
        self.K_w, self.M = np.ascontiguousarray(K[:, 3:]), _rate_map(K)
        self.noise = self.streams.block(k, n_steps, (sn.every, sn.tracker_every), self.noise_sd, sn)
        self.block_k0, self.i_sensor, self.i_tracker = k, 0, 0
        # the compiled loop starts each block with these fresh (kernel.run_block)
        self._status, self._tracker_status = (0.0, 0.0), 0.0
        self._sun_rejected = self._earth_rejected = 0
        self.sky_t0 = math.floor(k * sc.run.dt / SKY_STEP) * SKY_STEP
        rows = math.ceil(((k + n_steps) * sc.run.dt - self.sky_t0) / SKY_STEP) + 2
        self.sky = sky_table(sc, self.sky_t0 + SKY_STEP * np.arange(rows))

    def _sky_at(self, t: float):
        u = (t - self.sky_t0) / SKY_STEP
        i = min(max(int(u), 0), self.sky.shape[0] - 2)
        f = u - i
        row = self.sky[i] + f * (self.sky[i + 1] - self.sky[i])
        sun, moon = row[:3] / np.linalg.norm(row[:3]), row[3:6] / np.linalg.norm(row[3:6])
        return sun, moon, row[6], row[7], row[8] > 0.5, row[9]

    def _sample_gyros(self, k: int) -> None:
        """The gyros' sample over the last step; the gyro filter propagates q̂ with it."""
        x, gs = self.x, self.gs
        self.w_mean[:] = 0.5 * (gs[6:9] + x[4:7])
        gs[6:9] = x[4:7]
        sn = self.sensors
        j = k - self.block_k0
        gyro_sample_into(self.w_mean, sn.gyro_E, sn.gyro_par, gs, self.noise.gyro[j], self.w_meas)
        if self.mode == kernel.GYRO and k > 0:  # q̂ over the last step with ω̂ = ω_m − β̂
            w = self.w_meas - self.w_hat[:3]
            C = dcm(self.q_hat)
            propagate_attitude_into(
                self.q_hat, w[0] + GEO_RATE * C[0, 1], w[1] + GEO_RATE * C[1, 1],
                w[2] + GEO_RATE * C[2, 1], self.dt,
            )  # fmt: skip

    def _track(self, k: int, sunlit, moon_visible, moon_b) -> None:
        """The star tracker at its ticks: visibility, and the filter's attitude update."""
        sn, x = self.sensors, self.x
        seen = tracker_visible(
            sn.tracker_frame, self._sun_b, moon_b, self._C[:, 2].copy(), sunlit,
            moon_visible, sn.tracker_cos,
        )  # fmt: skip
        self._tracker_status = 0.0 if seen else 1.0
        if not seen:
            self.stats[_S["star_tracker_blinded"]] += 1
        elif self.mode != kernel.TRUTH:
            q_meas = np.empty(4)
            e = self.noise.tracker[self.i_tracker]
            kernel._tracker_measurement(x, sn.tracker_frame, sn.tracker_sigma, e, q_meas)
            self.last_tracker = q_meas.copy()
            attitude_update_into(
                self.q_hat, self.w_hat, self.P, q_meas, self.filt.tracker_R, self._Wn
            )
        self.i_tracker += 1

    def _update(self, b, ref, r, g, at: int | None) -> bool:
        """One vector sensor's gated update (with its misalignment states at ``at``)."""
        if at is None:
            return gated_update_into(self.q_hat, self.w_hat, self.P, b, ref, r, g, self._Wn)
        return aligned_update_into(self.q_hat, self.w_hat, self.P, b, ref, r, g, at, self._Wn)

    def _sense(self, k: int, s_orb, m_orb, sunlit, moon_visible) -> bool:
        """Sensor statuses at sensor ticks and the filter's updates; whether it measured."""
        st, x, sn, filt = self.stats, self.x, self.sensors, self.filt
        tick = k % sn.every == 0
        if tick:
            C = dcm(x[:4])
            sun_b, moon_b = C @ s_orb, C @ m_orb
            sun_ok = sunlit >= 1.0 and -sun_b[0] >= sn.sun_fov_cos
            earth_ok = not (
                (sunlit > 0.0 and sun_b[2] >= sn.blind_cos[0])
                or (moon_visible and moon_b[2] >= sn.blind_cos[1])
            )
            self._status = (0.0 if sun_ok else 1.0, 0.0 if earth_ok else 1.0)
            self._sun_b, self._C = sun_b, C
            self.last_tracker = None
            if sn.tracker and k % sn.tracker_every == 0:
                self._track(k, sunlit, moon_visible, moon_b)
        measured = self.mode != kernel.TRUTH and tick
        if not measured:
            return False
        sun_status, earth_status = self._status
        gate, max_rejected = filt.gate
        e = self.noise.sensor[self.i_sensor]
        self.i_sensor += 1
        sensors: dict = {"sun": None, "earth": None}
        if sun_status == 0.0:
            sun_b = self._sun_b
            cos_i = -sun_b[0] if sn.sun_incidence else 1.0  # noise ∝ 1/cos(incidence)
            b = _noisy(sn.sun_align @ sun_b, sn.sig_sun / cos_i, e[:3])
            r = filt.r_sun / max(-b[0], 1e-3) if sn.sun_incidence else filt.r_sun
            g = gate if self._sun_rejected < max_rejected else 0.0
            ok = self._update(b, s_orb, r, g, 6 if self.aligned else None)
            self._sun_rejected = 0 if ok else self._sun_rejected + 1
            sensors["sun"] = b
            if not ok:
                st[_S["sun_sensor_gated"]] += 1
                sun_status = 2.0
        else:
            st[_S["sun_sensor_outages"]] += 1
        if earth_status == 0.0:
            b = _noisy(sn.earth_align @ self._C[:, 2], sn.sig_earth, e[3:])
            g = gate if self._earth_rejected < max_rejected else 0.0
            nadir = np.array([0.0, 0.0, 1.0])
            ok = self._update(b, nadir, filt.r_earth, g, 9 if self.earth_aligned else None)
            self._earth_rejected = 0 if ok else self._earth_rejected + 1
            sensors["earth"] = b
            if not ok:
                st[_S["earth_sensor_gated"]] += 1
                earth_status = 2.0
        else:
            st[_S["earth_sensor_blinded"]] += 1
        no_tracker = not sn.tracker or self._tracker_status != 0.0
        if sun_status != 0.0 and earth_status != 0.0 and no_tracker:
            st[_S["no_update_ticks"]] += 1
        self._status = (sun_status, earth_status)
        self.last_sensors = sensors
        return True

    def _unloading(self, t: float, k: int, err: float, h_body: np.ndarray) -> np.ndarray:
        """The kernel's thruster momentum unloading (same thresholds and counters)."""
        st, u, x = self.stats, self.unload, self.x
        tau_thr = np.zeros(3)
        h_frac = float(np.max(np.abs(x[7:]) / self.h_max))
        if u[0] > 0:
            pointing = err <= u[6]
            if st[_S["unloading"]] == 0 and h_frac > u[1] and pointing:
                st[_S["unloading"]] = 1
                st[_S["desaturation_count"]] += 1
            if st[_S["unloading"]] == 1:
                if h_frac <= u[2]:
                    st[_S["unloading"]] = 0
                    st[_S["unload_end_s"]] = t
                elif k % int(u[4]) == 0 and pointing:
                    fire = np.abs(h_body) > u[2] * self.h_max.min()
                    tau_thr[fire] = -np.copysign(u[3], h_body[fire])
                    st[_S["thruster_impulse_Nms"]] += u[3] * self.dt * fire.sum()
                    if not fire.any():
                        st[_S["unloading"]] = 0
                        st[_S["unload_end_s"]] = t
        st[_S["momentum_peak_fraction"]] = max(st[_S["momentum_peak_fraction"]], h_frac)
        if h_frac >= 0.999:
            self.saturated = True
        return tau_thr

    def wheel_torques(self) -> np.ndarray:
        """The wheel torques (N,) to command for this control period, N·m along each axis.

        Wheels that are not :attr:`active` get 0 (they are idled by the caller); their
        last measured torque is fed forward to the others.
        """
        if self.done:
            raise ConfigError("the run is over; no more control periods")
        k, t, sc, st, x = self.k, self.t, self.scenario, self.stats, self.x
        if k == 0 or k - self.block_k0 >= self.block:
            self._new_block()
        s_orb, m_orb, sunlit, earth_lit, moon_visible, srp_scale = self._sky_at(t)
        if k > 0:  # as the simulation kernel: sample k stands for the step that ends there
            if earth_lit < 1.0:
                st[_S["eclipse_steps"]] += 1
            if sunlit < earth_lit:
                st[_S["moon_shadow_steps"]] += 1
        if self.sensors.gyro:
            self._sample_gyros(k)
        measured = self._sense(k, s_orb, m_orb, sunlit, moon_visible)
        err = math.degrees(2.0 * math.asin(min(1.0, float(np.linalg.norm(x[:3])))))
        h_body = self.G @ x[7:]
        tau_thr = self._unloading(t, k, err, h_body)
        if self.mode == kernel.TRUTH:
            est = x[:7].copy()
        elif self.mode == kernel.GYRO:  # the rate the gyros measure, less the bias estimate
            est = np.concatenate([self.q_hat, self.w_meas - self.w_hat[:3]])
        else:
            est = np.concatenate([self.q_hat, self.w_hat[:3]])
        q = est[:4]
        s = np.concatenate([2 * q[:3] * math.copysign(1.0, q[3]), _w_bo(q, est[4:7])])
        tau = np.asarray(control_torque(self.K_w, self.M, float(self.controller.rate_limit), s))
        tau_b = np.zeros(3)
        if self.biased:
            if self.filt.bias_kind >= 2:
                sun_hat = dcm(self.q_hat) @ s_orb
                cols = slice(3, 6) if self.filt.bias_kind == 3 else slice(0, 3)
                self.Bmap[:, cols] = skew(srp_scale * sun_hat)
            tau_b = self.Bmap @ self.w_hat[3:]
            tau = tau - tau_b
        # the idled wheels' measured torque is known: the others make up for it
        idle_torque = self.G[:, ~self.active] @ self._hw_dot_last[~self.active]
        hw_cmd = self._pinv @ (tau_thr - tau - idle_torque)
        tau_max = sc.wheels.max_torque
        at_limit = bool(np.any(np.abs(hw_cmd) >= tau_max))
        hw_cmd = np.clip(hw_cmd, -tau_max, tau_max)
        st[_S["torque_peak_Nm"]] = max(st[_S["torque_peak_Nm"]], float(np.max(np.abs(hw_cmd))))
        in_desat = st[_S["unloading"]] == 1 or t - st[_S["unload_end_s"]] <= self.unload[5]
        st[_S["max_error_deg"]] = max(st[_S["max_error_deg"]], err)
        if k >= self.steady_from:
            if k == self.steady_from or k == self.block_k0:  # no previous command here
                self._hw_prev = hw_cmd
            self._steady_stats(err, hw_cmd, at_limit, in_desat, earth_lit)
        self._hw_prev = hw_cmd
        self._step = dict(
            measured=measured,
            h_body=h_body,
            tau_thr=tau_thr,
            tau_b=tau_b,
            sun=s_orb,
            moon=m_orb,
            sunlit=sunlit,
            srp_scale=srp_scale,
            est=est,
            err=err,
            demand=-tau,
        )
        if k % self.log_every == 0:
            self._log_row(t, est, hw_cmd, measured, sunlit)
        return hw_cmd

    def _steady_stats(self, err, hw_cmd, at_limit, in_desat, earth_lit) -> None:
        st = self.stats
        st[_S["steady_max_error_deg"]] = max(st[_S["steady_max_error_deg"]], err)
        st[_S["steady_steps"]] += 1
        st[_S["steady_error_sq_sum"]] += err * err
        st[_S["steady_torque_sq_sum"]] += float(np.sum(hw_cmd**2)) / self.nw
        if "steady_torque_jitter_sq_sum" in _S:  # white jitter of σ gives E[d²] = 2σ²
            d = hw_cmd - self._hw_prev
            st[_S["steady_torque_jitter_sq_sum"]] += float(np.sum(d * d)) / (2 * self.nw)
            power = np.abs(hw_cmd * self.x[7:] / self.scenario.wheels.inertia)
            st[_S["steady_wheel_power_sum"]] += float(np.sum(power))
        if at_limit:
            st[_S["steady_torque_saturated_steps"]] += 1
        if in_desat:
            st[_S["max_error_in_desat_deg"]] = max(st[_S["max_error_in_desat_deg"]], err)
            st[_S["desat_window_steps"]] += 1
        else:
            st[_S["steady_max_error_excl_desat_deg"]] = max(
                st[_S["steady_max_error_excl_desat_deg"]], err
            )
            st[_S["steady_excl_desat_steps"]] += 1
        if earth_lit < 1.0:
            st[_S["steady_eclipse_steps"]] += 1
            st[_S["steady_eclipse_max_error_deg"]] = max(
                st[_S["steady_eclipse_max_error_deg"]], err
            )
            st[_S["steady_eclipse_error_sq_sum"]] += err * err
        else:
            st[_S["steady_outside_eclipse_max_error_deg"]] = max(
                st[_S["steady_outside_eclipse_max_error_deg"]], err
            )
            st[_S["steady_outside_eclipse_error_sq_sum"]] += err * err

    def _log_row(self, t, est, hw_cmd, measured, sunlit) -> None:
        log = self._log
        log["t"].append(t)
        log["x"].append(self.x.copy())
        extra = np.zeros(12)  # [b, β, β̂_gyro, φ̂] as the compiled loop logs them
        nx = self.P.shape[0]
        if self.biased:
            at = 3 if self.filt.bias_kind == 2 else 0
            extra[at : at + nx - 6] = self.w_hat[3:]
        if self.mode == kernel.GYRO:
            extra[6 : 6 + min(nx, 9) - 3] = self.w_hat[: min(nx, 9) - 3]
        log["est"].append(np.concatenate([est, extra]))
        log["cmd"].append(hw_cmd.copy())
        log["tau"].append(None)  # the realised torque is known after the period
        ekf = self.mode != kernel.TRUTH
        nees = self._nees() if (ekf and measured) else (math.nan if ekf else 0.0)
        log["nees"].append(nees)
        tracker = self._tracker_status if self.sensors.tracker else 1.0
        log["sky"].append([sunlit, *self._status, tracker])
        sigma = np.zeros(6)
        if ekf:
            sigma = np.sqrt(np.diag(self.P)[:6])
        log["sigma"].append(sigma)

    def _nees(self) -> float:
        x, qh = self.x, self.q_hat
        a, b = x[:4], qh
        sign = 2.0 if float(a @ b) >= 0 else -2.0
        e = np.empty(self.P.shape[0])
        e[0] = sign * (b[3] * a[0] - a[3] * b[0] + a[1] * b[2] - a[2] * b[1])
        e[1] = sign * (b[3] * a[1] - a[3] * b[1] + a[2] * b[0] - a[0] * b[2])
        e[2] = sign * (b[3] * a[2] - a[3] * b[2] + a[0] * b[1] - a[1] * b[0])
        w, truth = self.w_hat, self.filt.bias_true
        if self.mode == kernel.GYRO:  # what β̂ stands for: the bias plus E ω
            gs = self.gs
            e[3:6] = gs[:3] + gs[3:6] + self.sensors.gyro_E @ self.w_mean - w[:3]
        else:
            e[3:6] = x[4:7] - w[:3]
        e[6:] = truth - w[3:]
        return float(e @ np.linalg.solve(self.P, e))

    def advance(self, wheel_momentum: np.ndarray) -> None:
        """Close the period with the wheel momenta (N,) the wheels report at its end, N·m·s.

        The wheels' torque over the period is the change of that momentum (held
        constant, as a zero-order hold); the filter is told it (the wheels'
        tachometers), the plant feels it, and the plant's wheel momenta are the
        reported ones.
        """
        h_new = np.asarray(wheel_momentum, dtype=float)
        if h_new.shape != (self.nw,) or not np.all(np.isfinite(h_new)):
            raise ConfigError(f"need {self.nw} finite wheel momenta, got {wheel_momentum!r}")
        if not self._step:
            raise ConfigError("advance() before wheel_torques()")
        x, s = self.x, self._step
        hw_real = (h_new - x[7:]) / self.dt
        if self._log["tau"] and self._log["tau"][-1] is None:
            self._log["tau"][-1] = -(self.G @ hw_real)
        j = self.k - self.block_k0
        filt = self.filt
        d, dm = self.dist.copy(), filt.dist_model.copy()
        d[7:10] = self.dist[7:10] + self.noise.process[j] + s["tau_thr"]
        d[1] = self.dist[1] * s["srp_scale"]  # SRP: none in the shadow, ∝ 1/r² of the Sun
        dm[1] = filt.dist_model[1] * s["srp_scale"]
        if s["measured"]:  # covariance to the next measurement, F at this estimate
            if self.mode == kernel.GYRO:
                gyro_jacobian_into(s["est"][4:7], self._F)
            else:
                error_jacobian_into(
                    self.q_hat, self.w_hat, s["h_body"], filt.J, filt.J_inv, GEO_RATE,
                    filt.dist_model[0], self.Bmap, self._F, self._W3,
                )  # fmt: skip
            T = self.sensors.every * self.dt
            predict_covariance_into(self.P, self._F, filt.Qc, T, self._Wn)
        if self.mode == kernel.DYNAMICS:  # the filter's model knows the wheels' torques
            xm = np.concatenate([self.q_hat, self.w_hat[:3], x[7:]])
            dm[7:10] = filt.dist_model[7:10] + s["tau_thr"] + s["tau_b"]
            rk4_step(
                xm, hw_real, self.dt, filt.J, filt.J_inv, self.G, self.h_max, GEO_RATE, dm,
                s["sun"], s["moon"], self._work,
            )  # fmt: skip
            self.q_hat = xm[:4].copy()
            self.w_hat = np.concatenate([xm[4:7], self.w_hat[3:]])
        rk4_step(
            x, hw_real, self.dt, self.J, self.J_inv, self.G, self.h_max, GEO_RATE, d,
            s["sun"], s["moon"], self._work,
        )  # fmt: skip
        x[7:] = np.clip(h_new, -self.h_max, self.h_max)
        self._hw_dot_last = hw_real
        self._step = {}
        self.k += 1

    # -- what it looked like -------------------------------------------------------------
    @property
    def error_deg(self) -> float:
        """The true pointing error now, °."""
        return math.degrees(2.0 * math.asin(min(1.0, float(np.linalg.norm(self.x[:3])))))

    @property
    def estimation_error_deg(self) -> float:
        """Angle between the true and the estimated attitude now, °."""
        a, b = self.x[:4], self.q_hat
        return math.degrees(2.0 * math.acos(min(1.0, abs(float(a @ b)))))

    def result(self) -> SimResult:
        """The run as ``simulate`` returns it (logged rows, statistics over every period)."""
        log = self._log
        n = len(log["t"])
        if n == 0:
            raise ConfigError("nothing was flown")
        taus = [tau if tau is not None else np.zeros(3) for tau in log["tau"]]
        x = np.array(log["x"])
        est = np.array(log["est"])
        w_bo = _w_bo(x[:, :4], x[:, 4:7])
        w_est = _w_bo(est[:, :4], est[:, 4:7])
        r = _result(
            np.array(log["t"]),
            x[:, :4],
            w_bo,
            est[:, :4],
            w_est,
            np.array(taus),
            rad_s_to_rpm(x[:, 7:] / self.scenario.wheels.inertia),
            np.array(log["nees"]),
            self.saturated,
            self.stats.copy(),
            self.steady_from * self.dt,
        )
        sky = np.array(log["sky"])
        r.sky, r.tracker_status = sky[:, :3], sky[:, 3]
        r.torque_est, r.srp_lever_est = est[:, 7:10], est[:, 10:13]
        r.gyro_bias_est, r.sun_sensor_alignment_est = est[:, 13:16], est[:, 16:19]
        r.stats["steps"] = self.steps
        r.stats["dt_s"] = self.dt
        r.stats["sensor_period_s"] = self.scenario.sensors.period
        r.stats["filter_states"] = self.P.shape[0] if self.use_ekf else 0
        r.sigma = np.array(log["sigma"])
        r.est_error_axes = _axis_errors(r.q, r.q_est)
        return r
