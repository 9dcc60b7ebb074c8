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
"""

from __future__ import annotations

import math

import numpy as np

from rwlab.attitude import kernel
from rwlab.attitude.ekf import error_jacobian_into, gated_update_into, predict_covariance_into
from rwlab.attitude.frames import GEO_RATE, dcm, skew
from rwlab.attitude.plant import rk4_step
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import (
    BIAS_KINDS,
    BLOCK_STEPS,
    SKY_STEP,
    LinearController,
    SimResult,
    _axis_errors,
    _bias_truth,
    _initial,
    _known_only,
    _rate_map,
    _result,
    _sensor_record,
    _Streams,
    _unload_vector,
    _w_bo,
    control_torque,
    default_filter_psd,
    disturbance_psd,
    disturbance_state,
    sensor_alignment,
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
    ) -> None:
        if estimator not in ("ekf", "truth"):
            raise ConfigError(f"estimator must be 'ekf' or 'truth', got {estimator!r}")
        if not (math.isfinite(duration) and duration >= scenario.dt):
            raise ConfigError(f"duration must be at least one step ({scenario.dt:g} s)")
        if getattr(scenario, "gyro", None) is not None or getattr(scenario, "star_tracker", None):
            raise ConfigError(
                f"{scenario.name}: hardware in the loop flies the sun/earth-sensor MEKF; "
                "remove the gyros and the star tracker from the scenario"
            )
        sc = self.scenario = scenario
        self._sensors = _sensor_record(sc, np.zeros((3, 3)))
        self.controller = controller
        self.use_ekf = estimator == "ekf"
        self.dt = sc.dt
        self.steps = round(duration / sc.dt)
        self.sensor_every = round(sc.sensor_period / sc.dt)
        self.log_every = -(-max(1, int(log_every)) // self.sensor_every) * self.sensor_every
        self.steady_from = round(steady_start(self.steps * sc.dt) / sc.dt)
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
        self.h_max = np.full(self.nw, sc.wheel_max_momentum)
        self.dist = sc.disturbances.vector()
        self.dist_model = self.dist if sc.disturbances_known_to_filter else _known_only(sc)
        self.bias_kind = BIAS_KINDS[disturbance_state(sc)]
        self.bias_true = _bias_truth(sc, self.dist, self.dist_model)
        psd = (
            default_filter_psd(sc)
            if filter_torque_psd is None
            else sc.process_noise_torque**2 + filter_torque_psd
        )
        nx = P.shape[0]
        self.Qc = np.zeros((nx, nx))
        self.Qc[3:6, 3:6] = psd * self.J_inv @ self.J_inv.T
        if nx > 6:
            self.Qc[6:, 6:] = np.diag(disturbance_psd(sc))
        self.biased = self.use_ekf and nx > 6
        self.Bmap = np.zeros((3, max(nx - 6, 3)))
        if self.bias_kind != 2:
            self.Bmap[:, :3] = np.eye(3)
        m = sc.noise_margin * filter_noise_scale
        self.sig_sun, self.sig_earth = (
            math.radians(sc.sun_noise_deg),
            math.radians(sc.earth_noise_deg),
        )
        self.r_sun, self.r_earth = self.sig_sun * m, self.sig_earth * m
        self.fov_cos = math.cos(math.radians(min(sc.sun_fov_deg, 180.0)))
        self.sun_align = sensor_alignment(
            sc.sun_sensor_bias_deg, sc.sun_sensor_misalignment_deg, (1, 2)
        )
        self.earth_align = sensor_alignment(
            sc.earth_sensor_bias_deg, sc.earth_sensor_misalignment_deg, (0, 1)
        )
        excl = np.array([sc.earth_sensor_sun_exclusion_deg, sc.earth_sensor_moon_exclusion_deg])
        self.blind_cos = np.where(excl > 0, np.cos(np.radians(excl)), 2.0)
        self.unload = _unload_vector(sc)
        self.noise_sd = sc.process_noise_torque / math.sqrt(sc.dt)
        period = controller.update_period
        self.block = BLOCK_STEPS if not period else max(1, min(BLOCK_STEPS, round(period / sc.dt)))
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
        self._log: dict[str, list] = {
            name: [] for name in ("t", "x", "est", "tau", "nees", "sky", "cmd", "sensors", "sigma")
        }
        self._hw_dot_last = np.zeros(self.nw)
        self._hw_prev = np.zeros(self.nw)
        self._step: dict = {}
        self.last_sensors: dict = {}

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
        sc, k = self.scenario, self.k
        n_steps = min(self.block, self.steps + 1 - k)
        s_q, s_w = (self.q_hat, self.w_hat[:3]) if self.use_ekf else (self.x[:4], self.x[4:7])
        K = np.asarray(
            self.controller.gain(k * sc.dt, s_q, _w_bo(s_q, s_w), self.G @ self.x[7:]), float
        )
        self.K_w, self.M = np.ascontiguousarray(K[:, 3:]), _rate_map(K)
        noise = self.streams.block(
            k, n_steps, (self.sensor_every, self.sensor_every), self.noise_sd, self._sensors
        )
        self.process, self.sensor = noise.process, noise.sensor
        self.block_k0, self.i_sensor = k, 0
        self.sky_t0 = math.floor(k * sc.dt / SKY_STEP) * SKY_STEP
        rows = math.ceil(((k + n_steps) * sc.dt - self.sky_t0) / SKY_STEP) + 2
        self.sky = sky_table(sc, self.sky_t0 + SKY_STEP * np.arange(rows))

    def _sky_at(self, t: float):
        u = (t - self.sky_t0) / SKY_STEP
        i = min(max(int(u), 0), self.sky.shape[0] - 2)
        f = u - i
        row = self.sky[i] + f * (self.sky[i + 1] - self.sky[i])
        sun, moon = row[:3] / np.linalg.norm(row[:3]), row[3:6] / np.linalg.norm(row[3:6])
        return sun, moon, row[6], row[7], row[8] > 0.5

    def _sense(self, k: int, s_orb, m_orb, sunlit, moon_visible) -> bool:
        """Sensor statuses at sensor ticks and the filter's updates; whether it measured."""
        st, x = self.stats, self.x
        if k % self.sensor_every == 0:
            C = dcm(x[:4])
            sun_b, moon_b = C @ s_orb, C @ m_orb
            sun_ok = sunlit >= 1.0 and -sun_b[0] >= self.fov_cos
            earth_ok = not (
                (sunlit > 0.0 and sun_b[2] >= self.blind_cos[0])
                or (moon_visible and moon_b[2] >= self.blind_cos[1])
            )
            self._status = (0.0 if sun_ok else 1.0, 0.0 if earth_ok else 1.0)
            self._sun_b, self._C = sun_b, C
        measured = self.use_ekf and k % self.sensor_every == 0
        if not measured:
            return False
        sc = self.scenario
        sun_status, earth_status = self._status
        gate = sc.innovation_gate
        e = self.sensor[self.i_sensor]
        self.i_sensor += 1
        sensors: dict = {"sun": None, "earth": None}
        if sun_status == 0.0:
            sun_b = self._sun_b
            cos_i = -sun_b[0] if sc.sun_noise_incidence else 1.0
            b = _noisy(self.sun_align @ sun_b, self.sig_sun / cos_i, e[:3])
            r = self.r_sun / max(-b[0], 1e-3) if sc.sun_noise_incidence else self.r_sun
            g = gate if self._sun_rejected < sc.innovation_gate_max_rejections else 0.0
            ok = gated_update_into(self.q_hat, self.w_hat, self.P, b, s_orb, r, g, self._Wn)
            self._sun_rejected = 0 if ok else self._sun_rejected + 1
            sensors["sun"] = b
            if not ok:
                st[_S["sun_sensor_gated"]] += 1
                sun_status = 2.0
        else:
            st[_S["sun_sensor_outages"]] += 1
        if earth_status == 0.0:
            b = _noisy(self.earth_align @ self._C[:, 2], self.sig_earth, e[3:])
            g = gate if self._earth_rejected < sc.innovation_gate_max_rejections else 0.0
            nadir = np.array([0.0, 0.0, 1.0])
            ok = gated_update_into(
                self.q_hat, self.w_hat, self.P, b, nadir, self.r_earth, g, self._Wn
            )
            self._earth_rejected = 0 if ok else self._earth_rejected + 1
            sensors["earth"] = b
            if not ok:
                st[_S["earth_sensor_gated"]] += 1
                earth_status = 2.0
        else:
            st[_S["earth_sensor_blinded"]] += 1
        if sun_status != 0.0 and earth_status != 0.0:
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
        s_orb, m_orb, sunlit, earth_lit, moon_visible = self._sky_at(t)
        if earth_lit < 1.0:
            st[_S["eclipse_steps"]] += 1
        if sunlit < earth_lit:
            st[_S["moon_shadow_steps"]] += 1
        measured = self._sense(k, s_orb, m_orb, sunlit, moon_visible)
        err = math.degrees(2.0 * math.asin(min(1.0, float(np.linalg.norm(x[:3])))))
        h_body = self.G @ x[7:]
        tau_thr = self._unloading(t, k, err, h_body)
        est = np.concatenate([self.q_hat, self.w_hat[:3]]) if self.use_ekf else x[:7].copy()
        q = est[:4]
        s = np.concatenate([2 * q[:3] * math.copysign(1.0, q[3]), _w_bo(q, est[4:7])])
        tau = np.asarray(control_torque(self.K_w, self.M, float(self.controller.rate_limit), s))
        tau_b = np.zeros(3)
        if self.biased:
            if self.bias_kind >= 2:
                sun_hat = dcm(self.q_hat) @ s_orb
                cols = slice(3, 6) if self.bias_kind == 3 else slice(0, 3)
                self.Bmap[:, cols] = skew(sunlit * sun_hat)
            tau_b = self.Bmap @ self.w_hat[3:]
            tau = tau - tau_b
        # the idled wheels' measured torque is known: the others make up for it
        idle_torque = self.G[:, ~self.active] @ self._hw_dot_last[~self.active]
        hw_cmd = self._pinv @ (tau_thr - tau - idle_torque)
        tau_max = sc.wheel_max_torque
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
            power = np.abs(hw_cmd * self.x[7:] / self.scenario.wheel_inertia)
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
        bias = np.zeros(6)
        if self.biased:
            at = 3 if self.bias_kind == 2 else 0
            bias[at : at + self.w_hat.size - 3] = self.w_hat[3:]
        log["est"].append(np.concatenate([est, bias]))
        log["cmd"].append(hw_cmd.copy())
        log["tau"].append(None)  # the realised torque is known after the period
        nees = self._nees() if (self.use_ekf and measured) else (math.nan if self.use_ekf else 0.0)
        log["nees"].append(nees)
        log["sky"].append([sunlit, *self._status])
        sigma = np.zeros(6)
        if self.use_ekf:
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
        e[3:6] = x[4:7] - self.w_hat[:3]
        e[6:] = self.bias_true - self.w_hat[3:]
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
        d, dm = self.dist.copy(), self.dist_model.copy()
        d[7:10] = self.dist[7:10] + self.process[j] + s["tau_thr"]
        d[1] = self.dist[1] * s["sunlit"]
        dm[1] = self.dist_model[1] * s["sunlit"]
        if self.use_ekf:
            if s["measured"]:
                error_jacobian_into(
                    self.q_hat, self.w_hat, s["h_body"], self.J, self.J_inv, GEO_RATE,
                    self.dist_model[0], self.Bmap, self._F, self._W3,
                )  # fmt: skip
                T = self.sensor_every * self.dt
                predict_covariance_into(self.P, self._F, self.Qc, T, self._Wn)
            xm = np.concatenate([self.q_hat, self.w_hat[:3], x[7:]])
            dm[7:10] = self.dist_model[7:10] + s["tau_thr"] + s["tau_b"]
            rk4_step(
                xm, hw_real, self.dt, self.J, self.J_inv, self.G, self.h_max, GEO_RATE, dm,
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
            rad_s_to_rpm(x[:, 7:] / self.scenario.wheel_inertia),
            np.array(log["nees"]),
            self.saturated,
            self.stats.copy(),
            self.steady_from * self.dt,
        )
        r.sky = np.array(log["sky"])
        r.torque_est, r.srp_lever_est = est[:, 7:10], est[:, 10:13]
        r.stats["steps"] = self.steps
        r.stats["dt_s"] = self.dt
        r.stats["sensor_period_s"] = self.scenario.sensor_period
        r.stats["filter_states"] = self.P.shape[0] if self.use_ekf else 0
        r.sigma = np.array(log["sigma"])
        r.est_error_axes = _axis_errors(r.q, r.q_est)
        return r
