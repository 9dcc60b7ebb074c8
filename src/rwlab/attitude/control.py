"""Paper B's controllers on the GEO plant, and its comparison study.

- **LQR**: u = −K s, s = [θ, ω_bo] (θ = 2 q_v), K from the Riccati equation of
  the plant linearised about the *current* operating point, re-solved every
  ``update_period`` seconds (the paper re-linearises every step; 1 s by
  default here, configurable down to dt), acting on the true state.
- **LQG**: the same gain acting on the MEKF's estimate.
- **LQG/LTR**: the same gain; the filter is tuned for loop transfer recovery at
  the plant input — fictitious process noise q²·B Bᵀ through B and measurement
  noise ρ·R₀ (paper B: ρ = 0.7692); see :func:`ltr_noise` for q².

Weights follow Bryson's rule from the pointing requirement: attitude 0.05°,
rate 1e-4 rad/s, torque = the wheels' maximum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control
import numpy as np

from rwlab.attitude.design import LTRResult, lqr, ltr
from rwlab.attitude.frames import GEO_RATE, dcm, skew
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import LinearController, SimResult, simulate

__all__ = ["LQRController", "compare", "default_weights", "linearize", "ltr_study", "metrics"]

POINTING_DEG = 0.1  # paper B's requirement
PAPER_RHOS = (76.92, 7.692, 0.7692, 0.007692)
CHOSEN_RHO = 0.7692


def _f(s, tau, h_body, J, J_inv, n, gg):
    """ṡ for s = [θ, ω_bo] (θ = 2 q_v) under body torque τ (wheel torque held)."""
    qv = s[:3] / 2
    q = np.concatenate([qv, [math.sqrt(max(0.0, 1 - qv @ qv))]])
    C = dcm(q)
    w_oi = C @ np.array([0.0, -n, 0.0])
    w = s[3:] + w_oi
    r = C[:, 2]
    tau_gg = gg * np.cross(r, J @ r)
    w_dot = J_inv @ (-np.cross(w, J @ w + h_body) + tau + tau_gg)
    theta_dot = (q[3] * np.eye(3) + skew(qv)) @ s[3:]
    return np.concatenate([theta_dot, w_dot + np.cross(s[3:], w_oi)])


def linearize(q, w_bo, h_body, J, n: float = GEO_RATE, gravity_gradient: bool = True):
    """A (6×6), B (6×3) of ṡ = f(s, τ) about s = [2 q_v, ω_bo] (central differences)."""
    J = np.asarray(J, float)
    J_inv = np.linalg.inv(J)
    gg = 3 * n * n if gravity_gradient else 0.0
    s0 = np.concatenate([2 * np.asarray(q[:3]) * math.copysign(1.0, q[3]), w_bo])
    tau0 = np.zeros(3)
    A = np.zeros((6, 6))
    for i in range(6):
        h = 1e-7 if i < 3 else 1e-9
        e = np.zeros(6)
        e[i] = h
        A[:, i] = (
            _f(s0 + e, tau0, h_body, J, J_inv, n, gg) - _f(s0 - e, tau0, h_body, J, J_inv, n, gg)
        ) / (2 * h)
    B = np.vstack([np.zeros((3, 3)), J_inv])
    return A, B


def default_weights(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """Bryson weights: 0.05° attitude, 1e-4 rad/s rate, the wheels' maximum torque."""
    Q = np.diag([1 / math.radians(POINTING_WEIGHT_DEG) ** 2] * 3 + [1 / 1e-4**2] * 3)
    R = np.eye(3) / scenario.wheel_max_torque**2
    return Q, R


class LQRController(LinearController):
    """LQR on the plant re-linearised about the operating point every ``update_period`` s."""

    def __init__(self, scenario: Scenario, Q=None, R=None, update_period: float = 1.0) -> None:
        Qd, Rd = default_weights(scenario)
        self.Q = Qd if Q is None else np.asarray(Q, float)
        self.R = Rd if R is None else np.asarray(R, float)
        self.J = scenario.inertia_matrix
        self.gg = scenario.disturbances.gravity_gradient
        self.update_period = update_period
        self.K = lqr(
            control.ss(
                *linearize(
                    np.array([0, 0, 0, 1.0]),
                    np.zeros(3),
                    np.zeros(3),
                    self.J,
                    gravity_gradient=self.gg,
                ),
                np.eye(6),
                0,
            ),
            self.Q,
            self.R,
        )
        self._last = -math.inf

    def gain(self, t, q, w_bo, h_body) -> np.ndarray:
        if t - self._last >= (self.update_period or math.inf) - 1e-9:
            A, B = linearize(q, w_bo, h_body, self.J, gravity_gradient=self.gg)
            self.K = lqr(control.ss(A, B, np.eye(6), 0), self.Q, self.R)
            self._last = t
        return self.K


def attitude_plant(scenario: Scenario) -> control.StateSpace:
    """The linearised plant at the reference with θ measured: G(s) = C (sI − A)⁻¹ B, 3×3."""
    A, B = linearize(
        np.array([0, 0, 0, 1.0]),
        np.zeros(3),
        np.zeros(3),
        scenario.inertia_matrix,
        gravity_gradient=scenario.disturbances.gravity_gradient,
    )
    return control.ss(A, B, np.hstack([np.eye(3), np.zeros((3, 3))]), 0)


POINTING_WEIGHT_DEG = 0.05  # Bryson's attitude scale in default_weights


def ltr_noise(scenario: Scenario) -> tuple[float, float]:
    """(q², r_c) of the input-LTR filter design, shared by the ρ sweep and the simulation.

    r_c is the attitude measurement noise as a continuous PSD (rad²·s: variance
    × sensor period); q² the fictitious torque PSD through B (N²·m²·s), chosen so
    that at ρ = 1 the filter's bandwidth is a third of the LQR loop's — recovery
    then grows as ρ shrinks (filter bandwidth ∝ ρ^(-1/4)).
    """
    sigma = math.radians((scenario.sun_noise_deg + scenario.earth_noise_deg) / 2)
    r_c = (sigma * scenario.noise_margin) ** 2 * scenario.sensor_period
    theta0 = math.radians(POINTING_WEIGHT_DEG)
    q2 = scenario.wheel_max_torque**2 * r_c / (9 * theta0) ** 2
    return q2, r_c


def ltr_study(scenario: Scenario, rhos=PAPER_RHOS, omega=None) -> LTRResult:
    """Paper B Fig. 8: loop singular values at the plant input for each ρ next to LQR's."""
    Q, R = default_weights(scenario)
    q2, r_c = ltr_noise(scenario)
    return ltr(
        attitude_plant(scenario),
        Q,
        R,
        rhos,
        R0=np.eye(3) * r_c,
        q2=q2,
        side="input",
        omega=np.logspace(-5, 1, 240) if omega is None else omega,
    )


def metrics(r: SimResult, band_deg: float = POINTING_DEG) -> dict:
    """Pointing metrics of one run (the steady window is the second half)."""
    steady = r.error_deg[len(r.error_deg) // 2 :]
    outside = np.flatnonzero(r.error_deg > band_deg)
    settled = outside.size == 0 or outside[-1] < len(r.t) - 1
    theta = np.degrees(2 * r.q[:, :3])
    sign0 = np.sign(theta[0])
    overshoot = float(max(0.0, np.max(-sign0 * theta))) if np.any(sign0) else 0.0
    dt = float(np.median(np.diff(r.t))) if len(r.t) > 1 else 0.0
    return {
        "steady_max_error_deg": float(np.max(steady)),
        "steady_rms_error_deg": float(np.sqrt(np.mean(steady**2))),
        "settling_time_s": (float(r.t[outside[-1] + 1]) if outside.size else 0.0)
        if settled
        else None,
        "overshoot_deg": overshoot,
        "control_effort_Nms": float(np.sum(np.abs(r.torque)) * dt),
        "peak_wheel_speed_rpm": float(np.max(np.abs(r.wheel_speed_rpm))),
        "wheel_saturated": bool(r.wheel_saturated),
        "steady_rms_estimation_error_deg": float(
            np.sqrt(np.mean(r.est_error_deg[len(r.est_error_deg) // 2 :] ** 2))
        ),
        "meets_requirement": bool(np.max(steady) <= band_deg),
    }


@dataclass
class Comparison:
    """Runs and metrics of the three controllers (and the identified-wheel run)."""

    scenario: Scenario
    runs: dict
    metrics: dict
    rho: float


def compare(
    scenario: Scenario,
    *,
    duration: float | None = None,
    seed: int | None = None,
    rho: float = CHOSEN_RHO,
    wheel_model_file: str | None = None,
    update_period: float = 1.0,
) -> Comparison:
    """LQR (true state), LQG (MEKF) and LQG/LTR (LTR-tuned MEKF) on the same scenario and seeds.

    With ``wheel_model_file`` the LQG loop is also run with the identified wheel
    model as the actuator (``lqg_identified_wheel``) to show the wheel's lag cost.
    """
    seed = scenario.seed if seed is None else seed
    runs = {
        "lqr": simulate(
            scenario,
            LQRController(scenario, update_period=update_period),
            duration=duration,
            estimator="truth",
            seed=seed,
        ),
        "lqg": simulate(
            scenario,
            LQRController(scenario, update_period=update_period),
            duration=duration,
            estimator="ekf",
            seed=seed,
        ),
    }
    q2, _ = ltr_noise(scenario)
    ltr_filter = dict(filter_torque_psd=q2, filter_noise_scale=math.sqrt(rho))
    runs["lqg_ltr"] = simulate(
        scenario,
        LQRController(scenario, update_period=update_period),
        duration=duration,
        estimator="ekf",
        seed=seed,
        **ltr_filter,
    )
    if wheel_model_file:
        wheel = scenario.with_(wheel_model="identified", wheel_model_file=str(wheel_model_file))
        runs["lqg_identified_wheel"] = simulate(
            wheel,
            LQRController(wheel, update_period=update_period),
            duration=duration,
            estimator="ekf",
            seed=seed,
        )
    return Comparison(scenario, runs, {k: metrics(v) for k, v in runs.items()}, rho)
