"""Paper B's controllers on the GEO plant, designed at the rates the loop runs, and its study.

- **LQR**: discrete gain (MATLAB ``lqrd``) for the plant linearised at the
  reference and sampled with a hold at the control period ``dt``, acting on the
  true state. Weights (Bryson) come from the scenario: attitude
  ``control.lqr_attitude_deg`` (the pointing requirement), rate ``control.lqr_rate_deg_s`` and a
  torque of ``control.lqr_torque_fraction`` × the wheels' torque capacity, so the wheels
  never saturate inside the pointing budget (paper B, eq. 26). Large errors are
  flown as a rate-limited slew (``kernel.control_torque``) that leaves
  ``control.slew_torque_fraction`` of the torque in reserve. Paper B re-linearises
  every step; ``update_period`` keeps that available (off by default: measured
  benefit below 0.2 % of K, see the README).
- **LQG**: the same gain on the MEKF's estimate. In paper B's setting the filter
  does not know SRP, the tides or J2: they are process noise, sized by
  ``sim.default_filter_psd``.
- **LQG/LTR**: the same gain; the filter tuned for input loop transfer recovery:
  fictitious torque noise q² through B, sensor noise ρ·R₀ (paper B: ρ = 0.7692).
  q² is sized for the LQR loop's real crossover ω_c on its slowest axis (the
  smallest singular value of B, i.e. the largest inertia): at ρ = 1 the filter
  bandwidth is ``filter.ltr_bandwidth_factor`` × ω_c on every axis. This is our reading
  of the paper's "LTR applied to the slowest dynamics found by an SVD".

The σ analysis (``ltr_study``, ``crossover``) is discrete at the control period,
with the 2 Hz sensors represented by an equivalent measurement at ``dt`` of the
same noise PSD (valid while the loop's bandwidth ≪ the sensors' Nyquist rate).

Why this module is long: paper B's three controllers and the study that compares them
share the scenario's design weights, the linearised plant and its discretisation; apart,
each file would reach into the other's helpers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import control
import numpy as np

from rwlab._display import ShortRepr
from rwlab.attitude.design import (
    DesignError,
    LTRResult,
    kalman_current,
    lqg_current,
    lqrd,
    ltr,
    sigma,
)
from rwlab.attitude.frames import GEO_RATE, dcm, skew
from rwlab.attitude.metrics import metrics  # re-exported: it lived here
from rwlab.attitude.scenario import Scenario
from rwlab.attitude.sim import (
    LinearController,
    PDController,
    SimResult,
    attitude_noise_psd,
    default_filter_psd,
    disturbance_psd,
    disturbance_state,
    simulate,
)

__all__ = [
    "CONTROLLERS",
    "LQRController",
    "compare",
    "crossover",
    "default_weights",
    "fly",
    "linearize",
    "ltr_noise",
    "ltr_study",
    "metrics",
    "pd_gains",
    "torque_capacity",
]

PAPER_RHOS = (76.92, 7.692, 0.7692, 0.007692)
CHOSEN_RHO = 0.7692
GAP_BAND = (1e-3, 1e-1)  # rad/s: where paper B's Fig. 8 compares the loops


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
    """A (6×6), B (6×3) of ṡ = f(s, τ) about s = [2 q_v, ω_bo] (central differences).

    Parameters
    ----------
    q : numpy.ndarray, shape (4,)
        Attitude quaternion (orbital → body, scalar last).
    w_bo : numpy.ndarray, shape (3,)
        Body rate relative to the orbital frame, rad/s.
    h_body : numpy.ndarray, shape (3,)
        Wheel momentum in body axes, N·m·s.
    J : numpy.ndarray, shape (3, 3)
        Inertia, kg·m².
    n : float
        Orbital rate, rad/s.
    gravity_gradient : bool
        Include the gravity-gradient torque.

    Returns
    -------
    A : numpy.ndarray, shape (6, 6)
    B : numpy.ndarray, shape (6, 3)
        Per N·m of body torque.
    """
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


def torque_capacity(scenario: Scenario) -> float:
    """Largest body torque (N·m) in any direction that no wheel's limit clips (G⁺ allocation).

    Parameters
    ----------
    scenario : Scenario
        Its wheels (axes and torque limit).

    Returns
    -------
    float
        The torque, N·m.
    """
    rows = np.linalg.norm(np.linalg.pinv(scenario.wheel_matrix), axis=1)
    return scenario.wheels.max_torque / float(rows.max())


def default_weights(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """Continuous Bryson weights Q (6×6), R (3×3) from the scenario's design fields.

    Parameters
    ----------
    scenario : Scenario
        Its ``lqr_*`` fields set the Bryson scales.

    Returns
    -------
    Q : numpy.ndarray, shape (6, 6)
        State weight on [2 q_v, ω_bo].
    R : numpy.ndarray, shape (3, 3)
        Torque weight, 1/(N·m)².
    """
    theta0 = math.radians(scenario.control.lqr_attitude_deg)
    rate0 = math.radians(scenario.control.lqr_rate_deg_s)
    tau0 = scenario.control.lqr_torque_fraction * torque_capacity(scenario)
    Q = np.diag([1 / theta0**2] * 3 + [1 / rate0**2] * 3)
    return Q, np.eye(3) / tau0**2


def attitude_plant(scenario: Scenario, q=None, w_bo=None, h_body=None) -> control.StateSpace:
    """The continuous linearised plant with θ measured, G(s) = C (sI − A)⁻¹ B (3×3),
    at the reference by default."""
    A, B = linearize(
        np.array([0, 0, 0, 1.0]) if q is None else q,
        np.zeros(3) if w_bo is None else w_bo,
        np.zeros(3) if h_body is None else h_body,
        scenario.inertia_matrix,
        gravity_gradient=scenario.spacecraft.disturbances.gravity_gradient,
    )
    return control.ss(A, B, np.hstack([np.eye(3), np.zeros((3, 3))]), 0)


def slew_rate_limit(scenario: Scenario, K: np.ndarray) -> float:
    """Rate limit of the saturation-aware law, rad/s: what K_ω can hold with the torque
    reserve, and what the momentum reserve allows on the largest inertia."""
    by_torque = scenario.control.slew_torque_fraction * torque_capacity(scenario)
    by_torque /= float(np.linalg.norm(K[:, 3:], 2))
    h_cap = scenario.wheels.max_momentum * torque_capacity(scenario) / scenario.wheels.max_torque
    by_momentum = (
        scenario.control.slew_momentum_fraction
        * h_cap
        / np.linalg.eigvalsh(scenario.inertia_matrix).max()
    )
    return float(min(by_torque, by_momentum))


class LQRController(LinearController):
    """Discrete LQR (``lqrd`` at the control period) in its saturation-aware form.

    Parameters
    ----------
    scenario : Scenario
    Q, R : array_like, optional
        Continuous weights (default :func:`default_weights`).
    update_period : float, optional
        Re-linearise about the current estimate and re-solve every this many
        seconds (paper B: every step); None designs once at the reference.
    """

    def __init__(self, scenario: Scenario, Q=None, R=None, update_period: float | None = None):
        Qd, Rd = default_weights(scenario)
        self.Q = Qd if Q is None else np.asarray(Q, float)
        self.R = Rd if R is None else np.asarray(R, float)
        self.scenario = scenario
        self.update_period = update_period
        self.K, self.plant = lqrd(attitude_plant(scenario), self.Q, self.R, scenario.run.dt)
        self.rate_limit = slew_rate_limit(scenario, self.K)

    def gain(self, t, q, w_bo, h_body) -> np.ndarray:
        if self.update_period:
            plant = attitude_plant(self.scenario, q, w_bo, h_body)
            self.K, _ = lqrd(plant, self.Q, self.R, self.scenario.run.dt)
        return self.K


def _omega_grid(dt: float) -> np.ndarray:
    return np.logspace(-5, math.log10(math.pi / dt) - 1e-6, 400)


def crossover(loop_sigma: np.ndarray, omega: np.ndarray) -> float:
    """Highest frequency (rad/s) where the largest singular value falls through 1.

    Parameters
    ----------
    loop_sigma : numpy.ndarray, shape (nw, k)
        Singular values of the loop, largest first.
    omega : numpy.ndarray, shape (nw,)
        Frequencies, rad/s.

    Returns
    -------
    float
        The crossover frequency, rad/s.
    """
    s = loop_sigma[:, 0]
    above = np.flatnonzero(s >= 1)
    if above.size == 0:
        return 0.0
    i = above[-1]
    if i + 1 >= s.size:
        return float(omega[-1])
    t = math.log(s[i]) / (math.log(s[i]) - math.log(s[i + 1]))  # log-log interpolation
    return float(math.exp(math.log(omega[i]) + t * (math.log(omega[i + 1]) - math.log(omega[i]))))


def ltr_noise(scenario: Scenario, ctl: LQRController | None = None) -> tuple[float, float]:
    """(q², r_c) of the LTR filter: fictitious torque PSD (N²·m²·s) and attitude noise PSD (rad²·s).

    q² = (κ ω_c)⁴ J_slow² r_c puts a double integrator's Kalman bandwidth
    (q²/(J² r_c))^¼ at κ = ``filter.ltr_bandwidth_factor`` times the LQR crossover ω_c
    on the slowest axis, J_slow = 1/σ_min(B) from the SVD of B.

    Parameters
    ----------
    scenario : Scenario
        The design scenario.
    ctl : LQRController, optional
        The regulator whose crossover sets the bandwidth (designed here if None).

    Returns
    -------
    q2 : float
        Fictitious torque PSD, N²·m²·s.
    r_c : float
        Attitude measurement noise PSD, rad²·s.
    """
    ctl = LQRController(scenario) if ctl is None else ctl
    w = _omega_grid(scenario.run.dt)
    sysd = ctl.plant
    target = sigma(control.ss(sysd.A, sysd.B, ctl.K, 0 * ctl.K @ sysd.B, sysd.dt), w)
    w_c = crossover(target, w)
    B = np.asarray(attitude_plant(scenario).B)
    J_slow = 1 / np.linalg.svd(B, compute_uv=False).min()
    r_c = attitude_noise_psd(scenario)
    return (scenario.filter.ltr_bandwidth_factor * w_c) ** 4 * J_slow**2 * r_c, r_c


def ltr_study(scenario: Scenario, rhos=PAPER_RHOS, omega=None) -> LTRResult:
    """Paper B Fig. 8 on the discrete loop: σ of K(z)G(z) at the plant input for each ρ.

    Parameters
    ----------
    scenario : Scenario
        The design scenario.
    rhos : sequence of float
        The recovery parameters ρ.
    omega : array_like, optional
        Frequencies, rad/s.

    Returns
    -------
    LTRResult
        Target and recovered loops' singular values.
    """
    ctl = LQRController(scenario)
    q2, r_c = ltr_noise(scenario, ctl)
    dt = scenario.run.dt
    return ltr(
        ctl.plant,
        None,
        None,
        rhos,
        K=ctl.K,
        R0=np.eye(3) * r_c / dt,  # the same PSD as a measurement every dt
        q2=q2 / dt,
        side="input",
        omega=_omega_grid(dt) if omega is None else omega,
    )


def _with_disturbance_state(scenario: Scenario, sysd, Qn, K):
    """The filter's model, process noise and gain as the compensator sees them.

    Without a disturbance state: the plant, ``Qn`` and K. With one: the plant
    augmented with an input torque d (x⁺ = A x + B (u + d), d⁺ = d + walk) and the
    gain [K, I] that cancels d̂. The loop analysis is time-invariant, so the Sun is
    frozen: the SRP lever arm then acts as part of the same input torque, and the
    walk's PSD is the sum of the states' (exact across the Sun line, an upper bound
    along it, where a frozen lever arm has no effect).
    """
    if disturbance_state(scenario) == "none":
        return sysd, Qn, K
    A, B, C = (np.asarray(m) for m in (sysd.A, sysd.B, sysd.C))
    n, dt = A.shape[0], scenario.run.dt
    walk = disturbance_psd(scenario).reshape(-1, 3).sum(axis=0)  # per axis, N²·m²/s
    # d is a torque like u (N·m); a walk of PSD q has increments of variance q·dt
    Aa = np.block([[A, B], [np.zeros((3, n)), np.eye(3)]])
    Ba, Ca = np.vstack([B, np.zeros((3, 3))]), np.hstack([C, np.zeros((3, 3))])
    model = control.ss(Aa, Ba, Ca, 0, dt)
    Qa = np.zeros((n + 3, n + 3))
    Qa[:n, :n] = Qn
    Qa[n:, n:] = np.diag(walk) * dt
    return model, Qa, np.hstack([K, np.eye(3)])


def loop_margins(scenario: Scenario, rho: float = CHOSEN_RHO) -> dict:
    """Loop broken at the plant input, for each controller: crossover and robustness.

    LQR: K(zI − A)⁻¹B; LQG: the compensator with the filter's own noise model;
    LQG/LTR: the compensator with the LTR filter at ρ. With a disturbance state
    (``filter.disturbance_state``) both compensators estimate an input torque and
    cancel it (:func:`_with_disturbance_state`). Returns, per controller,
    ``crossover_rad_s`` (largest σ of L falls through 1) and
    ``return_difference_min`` = min over ω of σ_min(I + L): a multivariable
    stability margin (α: every loop tolerates a gain in [1/(1+α), 1/(1−α)] and a
    phase of ±2 asin(α/2) at once).
    """
    ctl = LQRController(scenario)
    sysd = ctl.plant  # G(z): θ measured
    dt, w = scenario.run.dt, _omega_grid(scenario.run.dt)
    B = np.asarray(sysd.B)
    r_c = attitude_noise_psd(scenario)
    q2, _ = ltr_noise(scenario, ctl)
    loops = {"lqr": control.ss(sysd.A, B, ctl.K, 0 * ctl.K @ B, dt)}
    for name, psd, r in (
        ("lqg", default_filter_psd(scenario), r_c),
        ("lqg_ltr", q2, rho * r_c),
    ):
        model, Qn, K = _with_disturbance_state(scenario, sysd, psd / dt * B @ B.T, ctl.K)
        M = kalman_current(model, Qn, np.eye(3) * r / dt)
        loops[name] = control.series(sysd, lqg_current(model, K, M))
    out = {}
    for name, loop in loops.items():
        resp = np.moveaxis(np.asarray(loop.frequency_response(w).frdata), 2, 0)
        ret = np.linalg.svd(np.eye(3) + resp, compute_uv=False)[:, -1]
        out[name] = {
            "crossover_rad_s": crossover(sigma(loop, w), w),
            "return_difference_min": float(ret.min()),
        }
    return out


@dataclass(repr=False)
class Comparison(ShortRepr):
    """Runs and metrics of the three controllers (and the identified-wheel run)."""

    scenario: Scenario
    runs: dict
    metrics: dict
    rho: float
    config: dict

    def to_pandas(self):
        """The metrics as a table: one row per controller flown, one column per metric.

        Returns
        -------
        pandas.DataFrame
            Index ``controller``; the columns of ``metrics`` (SI units, degrees where named).
        """
        from rwlab._display import pandas

        pd = pandas()
        frame = pd.DataFrame.from_dict(self.metrics, orient="index")
        frame.index.name = "controller"
        return frame


def compare(
    scenario: Scenario,
    *,
    duration: float | None = None,
    seed: int | None = None,
    rho: float = CHOSEN_RHO,
    wheel_model_file: str | None = None,
    update_period: float | None = None,
    progress=None,
) -> Comparison:
    """LQR (true state), LQG (MEKF) and LQG/LTR (LTR-tuned MEKF), same scenario and noise.

    Every run draws its process noise, sensor noise and initial estimate from
    its own stream of the same seed, so the controllers see identical
    disturbances. With ``wheels.model_file`` the LQG loop is also run with the
    identified wheel model as the actuator (``lqg_identified_wheel``).
    ``progress(name)`` is called before each run.

    Parameters
    ----------
    scenario : Scenario
        The spacecraft, sky and sensors.
    duration : float, optional
        Length of each run, s (the scenario's by default).
    seed : int, optional
        Noise seed (the scenario's by default).
    rho : float
        LTR's recovery parameter ρ for the LQG/LTR run.
    wheel_model_file : str, optional
        A ``model.json`` to fly as the actuator of an extra LQG run.
    update_period : float, optional
        Re-linearisation period of the LQR gains, s (None: fixed gains).
    progress : callable, optional
        ``progress(name)`` before each run.

    Returns
    -------
    Comparison
        The runs, their metrics, ρ and the configuration.
    """
    seed = scenario.run.seed if seed is None else seed
    q2, _ = ltr_noise(scenario)
    plans: dict[str, tuple[Scenario, dict[str, Any]]] = {
        "lqr": (scenario, dict(estimator="truth")),
        "lqg": (scenario, dict(estimator="ekf")),
        "lqg_ltr": (
            scenario,
            dict(estimator="ekf", filter_torque_psd=q2, filter_noise_scale=math.sqrt(rho)),
        ),
    }
    if wheel_model_file:
        wheel = scenario.with_(
            **{"wheels.model": "identified", "wheels.model_file": str(wheel_model_file)}
        )
        plans["lqg_identified_wheel"] = (wheel, dict(estimator="ekf"))
    runs = {}
    for name, (sc, kw) in plans.items():
        if progress is not None:
            progress(name)
        ctl = LQRController(sc, update_period=update_period)
        runs[name] = simulate(sc, ctl, duration=duration, seed=seed, **kw)
    margins = loop_margins(scenario, rho)
    table = {}
    for name, run in runs.items():
        table[name] = metrics(run, scenario.control.pointing_requirement_deg)
        table[name].update(margins.get(name, margins["lqg"]))
    config = {
        "disturbances_known_to_filter": scenario.filter.disturbances_known,
        "filter_disturbance_state": disturbance_state(scenario),
        "seed": seed,
        "dt_s": scenario.run.dt,
        "sensor_period_s": scenario.sensors.period,
        "relinearize_period_s": update_period,
        "rho": rho,
        "ltr_fictitious_torque_psd": q2,
        "filter_torque_psd": default_filter_psd(scenario),
        "requirement_deg": scenario.control.pointing_requirement_deg,
    }
    return Comparison(scenario, runs, table, rho, config)


CONTROLLERS = ("pd", "lqr", "lqg", "lqg_ltr")


def pd_gains(scenario: Scenario) -> tuple[float, float]:
    """(kp N·m/rad, kd N·m·s/rad) of a PD law with the LQR design's proportional gain (Bryson:
    ``control.lqr_torque_fraction`` of the torque at ``control.lqr_attitude_deg``), ζ = 0.707 on
    the largest inertia.

    Parameters
    ----------
    scenario : Scenario
        The design scenario.

    Returns
    -------
    kp : float
        Proportional gain, N·m/rad.
    kd : float
        Derivative gain, N·m·s/rad.
    """
    kp = scenario.control.lqr_torque_fraction * torque_capacity(scenario)
    kp /= math.radians(scenario.control.lqr_attitude_deg)
    j_max = float(np.linalg.eigvalsh(scenario.inertia_matrix).max())
    return kp, 2 * 0.707 * math.sqrt(kp * j_max)


def fly(
    scenario: Scenario,
    controller: str,
    *,
    estimator: str | None = None,
    duration: float | None = None,
    seed: int | None = None,
    rho: float = CHOSEN_RHO,
    update_period: float | None = None,
    log_every: int = 10,
    progress=None,
    design: Scenario | None = None,
    steady_after: float | None = None,
) -> tuple[SimResult, dict]:
    """One controller on one scenario: the run and its :func:`metrics` (``rwlab attitude
    simulate``). ``estimator`` defaults to 'truth' for LQR and PD, 'ekf' otherwise.
    ``design``: the scenario the gains (and LTR's filter noise) are designed on, by
    default the flown one; a Monte Carlo run flies a dispersed truth with the nominal
    design (the filter still uses the flown scenario's inertia and sensor noise).
    ``steady_after``: seconds where the steady-state window starts (``sim.simulate``).

    Parameters
    ----------
    scenario : Scenario
        The scenario flown (the truth).
    controller : {'pd', 'lqr', 'lqg', 'lqg_ltr'}
        The control law.
    estimator : {'truth', 'ekf'}, optional
        What the law sees.
    duration : float, optional
        Run length, s.
    seed : int, optional
        Noise seed.
    rho : float
        LTR's ρ (``lqg_ltr`` only).
    update_period : float, optional
        Re-linearisation period of the LQR gains, s.
    log_every : int
        Steps between logged rows.
    progress : callable, optional
        Passed to :func:`rwlab.attitude.sim.simulate`.
    design : Scenario, optional
        The scenario the gains are designed on.
    steady_after : float, optional
        Where the steady-state window starts, s (default: half the run, at most an hour).

    Returns
    -------
    run : SimResult
        The time histories.
    metrics : dict
        :func:`metrics` of the run.
    """
    if controller not in CONTROLLERS:
        raise DesignError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    estimator = estimator or ("truth" if controller in ("pd", "lqr") else "ekf")
    design = scenario if design is None else design
    kw: dict[str, Any] = {}
    ctl: PDController | LQRController
    if controller == "pd":
        ctl = PDController(*pd_gains(design))
        ctl.rate_limit = slew_rate_limit(design, ctl.K)
    else:
        ctl = lqr = LQRController(design, update_period=update_period)
        if controller == "lqg_ltr":
            if not (math.isfinite(rho) and rho > 0):
                raise DesignError(f"ρ must be a positive number, got {rho}")
            psd = ltr_noise(design, lqr)[0]
            kw = dict(filter_torque_psd=psd, filter_noise_scale=math.sqrt(rho))
    run = simulate(
        scenario,
        ctl,
        duration=duration,
        estimator=estimator,
        seed=seed,
        log_every=log_every,
        progress=progress,
        steady_after=steady_after,
        **kw,
    )
    return run, metrics(run, scenario.control.pointing_requirement_deg)
