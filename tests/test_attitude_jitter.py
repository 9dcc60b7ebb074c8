"""Wheel jitter (issue 44): each wheel's static and dynamic imbalance, Basilisk's simple model.

Known truth: Basilisk's JitterSimple equations (``reactionWheelStateEffector``), written
here independently in closed form: a rotor at angle θ = θ₀ + Ω t puts U_s Ω² ŵ₂(θ) on the
body at its centre r and the torque U_d Ω² ŵ₂(θ), ŵ₂(θ) = cos θ ŵ₂ + sin θ ŵ₃. (Basilisk,
``bsk``, is no dependency: bench/basilisk_jitter.py flies the first case in Basilisk itself,
agreeing to 7e-8 of the swing; see docs/tutorials/attitude.md.)"""

import math

import numpy as np
import pytest
from scipy.signal import welch

from rwlab.attitude.frames import GEO_RATE
from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.scenario import SCENARIOS
from rwlab.attitude.sim import PDController, simulate
from rwlab.attitude.wheels import transverse_axes
from rwlab.errors import ConfigError

U_S, U_D = 4.8e-6, 1.54e-6  # kg·m, kg·m² (a Honeywell HR16's, as Basilisk's simIncludeRW)
R_WHEEL = (0.5, 0.2, -0.3)  # m


def _scenario(dt: float, **more):
    quiet = DisturbanceModel(
        gravity_gradient=False, oblateness=False, solar_pressure=False, third_body=False
    )
    return SCENARIOS["geo-smallsat"].with_(
        **{
            "run.dt": dt,
            "run.initial_error_deg": 0.0,
            "sensors.period": dt * round(0.01 / dt),
            "spacecraft.disturbances": quiet,
            "spacecraft.process_noise_torque": 0.0,
            "wheels.static_imbalance_kg_m": (U_S, 0.0, 0.0),
            "wheels.dynamic_imbalance_kg_m2": (U_D, 0.0, 0.0),
            "wheels.positions_m": (R_WHEEL, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
            "wheels.jitter": True,
            **more,
        }
    )


def _basilisk_impulse(omega, t, w2, w3, r):
    """∫₀ᵗ τ dt of JitterSimple for one rotor at constant Ω from θ = 0 (N·m·s, (K, 3))."""
    c = (np.sin(omega * t))[:, None] * w2 - (np.cos(omega * t) - 1.0)[:, None] * w3
    u_int = omega * c  # ∫ Ω² ŵ₂(θ) dt = Ω [sin θ ŵ₂ − (cos θ − 1) ŵ₃]
    return U_D * u_int + np.cross(r, U_S * u_int)


def test_the_body_takes_basilisks_jitter_impulse_within_one_percent():
    """One wheel at 300 rad/s: the spacecraft's total angular momentum J ω + G h_w changes
    by the impulse of Basilisk's jitter torque (nothing else acts on it; the motor's
    torque is internal), to 1 % of its swing, through a whole turn of the rotor."""
    dt, omega = 2.5e-4, 300.0
    sc = _scenario(dt, **{"sensors.period": dt})  # a log row every step
    h0 = np.array([sc.wheels.inertia * omega, 0.0, 0.0])
    run = simulate(
        sc, PDController(1e-6, 1e-5), estimator="truth", duration=0.03, wheel_momentum0=h0,
        seed=0, log_every=1, steady_after=0.0,
    )  # fmt: skip
    # the state's rows: q, then ω; the wheels' momenta from their logged speeds
    # ω = ω_bo + A(q) (0, −n, 0) ≈ ω_bo + (0, −n, 0) (q stays at identity to 1e-6)
    w = run.w_bo + np.array([0.0, -GEO_RATE, 0.0])
    h_w = run.wheel_speed_rpm * math.pi / 30 * sc.wheels.inertia
    H = w @ sc.inertia_matrix.T + h_w @ sc.wheel_matrix.T
    axes = transverse_axes(sc.wheel_matrix)[0]
    expected = _basilisk_impulse(omega, run.t, axes[0], axes[1], np.array(R_WHEEL))
    swing = np.ptp(expected, axis=0).max()
    assert swing > 1e-4  # the case is not trivial: 0.17 N·m swinging at 48 Hz
    assert run.t.size == 121
    assert np.max(np.abs((H - H[0]) - expected)) < 0.01 * swing


def test_the_jitter_torque_is_basilisks_at_any_angle():
    """The kernel's torque at θ and Ω against the closed form, for a pyramid's wheels."""
    from rwlab.attitude import kernel
    from rwlab.attitude.sim import Loop, filter_psd

    sc = _scenario(2.5e-4, **{"wheels.axes": "pyramid", "wheels.static_imbalance_kg_m": U_S,
                              "wheels.dynamic_imbalance_kg_m2": U_D,
                              "wheels.positions_m": ((0.4, 0.1, 0.2),) * 4})  # fmt: skip
    ctl = PDController(1.0, 10.0)
    loop = Loop(sc, ctl, steps=1, estimator="truth", log_every=40, seed=0,
                wheel_momentum0=None, filter_psd=filter_psd(sc, None), noise_scale=1.0,
                steady_from=0)  # fmt: skip
    x = np.zeros(11)
    x[3], x[4:7] = 1.0, (1e-3, -2e-3, 5e-4)
    x[7:] = (0.1, -0.05, 0.2, 0.01)
    angle = np.array([0.3, 2.0, -1.0, 4.0])
    out = np.empty(3)
    kernel.jitter_torque_into(loop.plant, x, angle, 0.01, out)
    expected = np.zeros(3)
    G, axes = sc.wheel_matrix, transverse_axes(sc.wheel_matrix)
    for i in range(4):
        omega = x[7 + i] / sc.wheels.inertia - G[:, i] @ x[4:7]
        th = angle[i] + omega * 0.01
        u = math.cos(th) * axes[i, 0] + math.sin(th) * axes[i, 1]
        expected += np.cross((0.4, 0.1, 0.2), U_S * omega**2 * u) + U_D * omega**2 * u
    np.testing.assert_allclose(out, expected, rtol=1e-12)
    assert np.allclose(np.einsum("ij,ikj->ik", G.T, axes), 0)  # ŵ₂, ŵ₃ ⟂ ĝ


def test_the_pointing_error_spectrum_peaks_at_the_spin_frequency():
    """With imbalance on, the attitude error's PSD (the RPE's spectrum) has its largest
    peak above the control bandwidth at the wheel's spin rate; with ``wheels.jitter`` off
    the same run has nothing there."""
    dt, f_spin = 5e-4, 7.0
    omega = 2 * math.pi * f_spin
    sc = _scenario(dt)
    h0 = np.array([sc.wheels.inertia * omega, 0.0, 0.0])
    psd = {}
    for jitter in (True, False):
        run = simulate(
            sc.with_(**{"wheels.jitter": jitter}), PDController(0.05, 0.5), estimator="truth",
            duration=20.0, wheel_momentum0=h0, seed=0, log_every=1, steady_after=0.0,
        )  # fmt: skip
        theta = 2 * run.q[:, :3]  # small-angle error per body axis, rad
        fs = 1 / (run.t[1] - run.t[0])
        f, p = welch(theta - theta.mean(axis=0), fs=fs, nperseg=1024, axis=0)
        psd[jitter] = p.sum(axis=1)
        spin_hz = run.wheel_speed_rpm[:, 0] / 60  # the loop moves it a little
    band = f > 1.0  # above the loop's bandwidth
    peak = f[band][np.argmax(psd[True][band])]
    assert np.ptp(spin_hz) < 0.5  # the loop keeps the wheel near its start
    # the peak lies within the band the rotor swept (± one bin, 0.1 Hz)
    assert spin_hz.min() - f[1] <= peak <= spin_hz.max() + f[1]
    at = np.argmin(np.abs(f - peak))
    assert psd[True][at] > 1e4 * psd[False][at]


def test_a_step_that_cannot_resolve_the_rotor_is_refused():
    with pytest.raises(ConfigError, match=r"run\.dt ≤"):
        SCENARIOS["geo-smallsat"].with_(**{"wheels.jitter": True})  # the spec's imbalance
    off = SCENARIOS["geo-smallsat"]  # the shipped scenarios fly perfect rotors
    assert not off.wheels.jitter and off.wheels.static_imbalance_kg_m > 0
    with pytest.raises(ConfigError, match="≥ 0"):
        _scenario(2.5e-4, **{"wheels.static_imbalance_kg_m": -1.0})
    with pytest.raises(ConfigError, match="one per wheel"):
        _scenario(2.5e-4, **{"wheels.static_imbalance_kg_m": (1e-6, 2e-6)})
