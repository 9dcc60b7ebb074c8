"""The satellite on the host: the attitude loop of ``attitude simulate``, cut open at the wheels.

:class:`Satellite` flies the compiled step of :func:`rwlab.attitude.sim.simulate`
itself, period by period: each control period the host asks it for the wheel
torques (:meth:`Satellite.wheel_torques`: ``kernel.command_step`` — sky, gyros,
sensors and the filter's updates, thruster unloading, the control law and the
allocation), sends them to the wheels, and hands back the wheel momenta the wheels
then *report* (:meth:`Satellite.advance`: ``kernel.finish_step`` — log, the
filter's prediction, the plant). The plant takes the wheels' torque over the period
as the change of that reported momentum, so latency, quantisation, friction,
dropouts and faults act on the satellite as they would in flight.

The set-up is ``sim.Loop``'s (records, initial state, noise streams drawn in the
same blocks), so the same scenario and seed flown here with ideal wheels repeats
``attitude simulate`` to round-off, and every difference on the bench is the
wheels'. The only code here is what a bus adds: wheels taken out of the allocation
(:meth:`Satellite.set_active`) and the momenta they report.
"""

from __future__ import annotations

import math

import numpy as np

from rwlab.attitude import kernel
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import LinearController, Loop, SimResult, filter_psd, steady_start
from rwlab.errors import ConfigError

__all__ = ["Satellite"]


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
        self.dt = sc.run.dt
        self.steps = round(duration / sc.run.dt)
        sensor_every = round(sc.sensors.period / sc.run.dt)
        self.log_every = -(-max(1, int(log_every)) // sensor_every) * sensor_every
        if steady_after is None:
            steady_after = steady_start(self.steps * sc.run.dt)
        elif not (math.isfinite(steady_after) and 0 <= steady_after < self.steps * sc.run.dt):
            raise ConfigError(
                f"steady_after must be a number of seconds in [0, duration), got {steady_after!r}"
            )
        self.loop = Loop(
            sc,
            controller,
            steps=self.steps,
            estimator=estimator,
            log_every=self.log_every,
            seed=seed,
            wheel_momentum0=wheel_momentum0,
            filter_psd=filter_psd(sc, filter_torque_psd),
            noise_scale=sc.filter.noise_margin * filter_noise_scale,
            steady_from=round(steady_after / sc.run.dt),
        )
        self.plant = self.loop.plant  # its allocation changes when wheels are taken out
        self.nw = self.plant.G.shape[1]
        self.k = 0
        self.active = np.ones(self.nw, dtype=bool)
        self._block_k0 = 0
        self._block_end = 0
        self._log_k = 0
        self._commanded = False
        self._hw_dot_last = np.zeros(self.nw)

    # -- what the loop holds -------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """The plant's state [q (4), ω (3) rad/s, wheel momenta (N) N·m·s] (a view)."""
        return self.loop.state.x

    @property
    def q_hat(self) -> np.ndarray:
        """The filter's attitude estimate (4,) (a view)."""
        return self.loop.state.q_hat

    @property
    def w_meas(self) -> np.ndarray:
        """The gyros' last measurement (3,), rad/s (a view)."""
        return self.loop.work.w_meas

    @property
    def sensors(self) -> kernel.Sensors:
        """The true sensors (the kernel's record)."""
        return self.loop.sensors

    @property
    def stats(self) -> np.ndarray:
        """The running statistics (``kernel.STATS``) (a view)."""
        return self.loop.state.stats

    @property
    def allocation(self) -> np.ndarray:
        """The allocation matrix (N, 3) from body torque to wheel torques, N·m per N·m."""
        return self.plant.G_pinv

    @property
    def measured(self) -> bool:
        """Whether the filter took a measurement this period."""
        return self.loop.work.flags[kernel.MEASURED] > 0

    @property
    def demand(self) -> np.ndarray:
        """The body torque the wheels were asked for this period (3,), N·m."""
        return -self.loop.work.tau

    @property
    def last_sensors(self) -> dict:
        """This period's sun and earth sensor vectors (body axes) that reached the filter
        (None for a sensor that did not measure)."""
        w, f = self.loop.work, self.loop.work.flags
        return {
            "sun": w.sun_meas.copy() if f[kernel.SUN_USED] > 0 else None,
            "earth": w.earth_meas.copy() if f[kernel.EARTH_USED] > 0 else None,
        }

    @property
    def last_tracker(self) -> np.ndarray | None:
        """The star tracker's quaternion that reached the filter this period, if any."""
        w = self.loop.work
        return w.q_meas.copy() if w.flags[kernel.TRACKER_USED] > 0 else None

    # -- allocation ------------------------------------------------------------------
    def set_active(self, active: np.ndarray) -> None:
        """Allocate torque to these wheels only (bool (N,)); the others are fed forward.

        The minimum-norm allocation over the remaining columns of G is the
        null-space reallocation: with a pyramid any three wheels still span the body.
        """
        active = np.asarray(active, dtype=bool).copy()
        G = self.plant.G[:, active]
        if np.linalg.matrix_rank(G) < 3:
            raise ConfigError(
                f"the wheels left ({int(active.sum())}) no longer span three axes; "
                "the satellite cannot be controlled"
            )
        pinv = np.zeros((self.nw, 3))
        pinv[active] = np.linalg.pinv(G)
        self.active, self.plant = active, self.plant._replace(G_pinv=pinv)

    @property
    def t(self) -> float:
        """Time of the current control period, s."""
        return self.k * self.dt

    @property
    def done(self) -> bool:
        return self.k > self.steps

    # -- one control period -------------------------------------------------------------
    def wheel_torques(self) -> np.ndarray:
        """The wheel torques (N,) to command for this control period, N·m along each axis.

        Wheels that are not :attr:`active` get 0 (they are idled by the caller); their
        last measured torque is fed forward to the others.
        """
        if self.done:
            raise ConfigError("the run is over; no more control periods")
        loop, k = self.loop, self.k
        if k >= self._block_end:
            self._law, self._sky, self._noise, n_steps = loop.block(k)
            self._block_k0, self._block_end = k, k + n_steps
            kernel.start_block(loop.work)
        idle = ~self.active  # the idled wheels' measured torque is known: the others make up
        loop.work.tau_known[:] = self.plant.G[:, idle] @ self._hw_dot_last[idle]
        kernel.command_step(
            loop.state,
            loop.work,
            k,
            k - self._block_k0,
            self.plant,
            self._law,
            self._sky,
            loop.sensors,
            loop.filt,
            self._noise,
            loop.steady_from,
        )
        self._commanded = True
        return loop.work.hw_cmd.copy()

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
        if not self._commanded:
            raise ConfigError("advance() before wheel_torques()")
        loop = self.loop
        loop.work.hw_real[:] = (h_new - self.x[7:]) / self.dt
        self._hw_dot_last = loop.work.hw_real.copy()
        self._log_k = kernel.finish_step(
            loop.state,
            loop.work,
            self.k,
            self.k - self._block_k0,
            self._log_k,
            self.plant,
            loop.sensors,
            loop.filt,
            self._noise,
            loop.log,
            h_new.copy(),
        )
        self._commanded = False
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
        if self._log_k == 0:
            raise ConfigError("nothing was flown")
        return self.loop.result(self._log_k)
