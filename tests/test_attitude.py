import math
import warnings

import numpy as np
import pytest
from scipy.linalg import expm

from rwlab.attitude.ekf import error_jacobian, vector_jacobian
from rwlab.attitude.frames import GEO_RATE, angle_deg, dcm, from_axis_angle, qmul
from rwlab.attitude.plant import (
    MOON_TIDE,
    SUN_TIDE,
    DisturbanceModel,
    disturbance_torque,
    propagate,
)
from rwlab.attitude.scenario import SCENARIOS, load_scenario
from rwlab.attitude.sim import PDController, simulate
from rwlab.errors import ConfigError

J = np.array([[1200.0, 20.0, -15.0], [20.0, 1000.0, 10.0], [-15.0, 10.0, 1500.0]])
J_INV = np.linalg.inv(J)
G = np.eye(3)
H_MAX = np.full(3, 1e9)
OFF = DisturbanceModel(False, False, False, False).vector()
SUN = np.array([1.0, 0.0, 0.0])
MOON = np.array([0.0, 1.0, 0.0])


def _run(x, steps, dt=0.1, n=GEO_RATE, dist=OFF):
    return propagate(x, np.zeros(3), dt, steps, J, J_INV, G, H_MAX, n, dist, SUN, MOON)


def test_torque_free_motion_conserves_momentum_and_energy():
    q = from_axis_angle([1, 2, 3], 0.7)
    w = np.array([0.01, -0.02, 0.015])
    hw = np.array([2.0, -1.0, 0.5])
    x = _run(np.concatenate([q, w, hw]), 10_000, dt=0.1, n=0.0)  # n = 0: orbital = inertial
    H0 = dcm(q).T @ (J @ w + hw)
    H1 = dcm(x[:4]).T @ (J @ x[4:7] + x[7:])
    assert np.linalg.norm(H1 - H0) / np.linalg.norm(H0) < 1e-9
    T0, T1 = 0.5 * w @ J @ w, 0.5 * x[4:7] @ J @ x[4:7]
    assert abs(T1 - T0) / T0 < 1e-9


def test_an_inertially_fixed_body_turns_at_minus_n_about_the_orbit_normal():
    x = _run(np.array([0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0]), 10_000)  # ω = 0 inertial, 1000 s
    q = x[:4]
    axis = q[:3] / np.linalg.norm(q[:3])
    angle = 2 * math.atan2(np.linalg.norm(q[:3]), q[3])
    # body relative to orbital: +n about y_o, and y_o is the *negative* orbit normal
    assert angle == pytest.approx(GEO_RATE * 1000, rel=1e-9)
    assert np.allclose(axis, [0, -1, 0]) or np.allclose(axis, [0, 1, 0])
    assert (dcm(q) @ np.array([1.0, 0, 0]))[2] > 0  # the body x axis rotated toward nadir


def test_gravity_gradient_torque_is_3n2_r_cross_Jr():
    dist = DisturbanceModel(True, False, False, False).vector()
    for seed in range(5):
        q = from_axis_angle(np.random.default_rng(seed).standard_normal(3), 0.4 + seed * 0.2)
        r = dcm(q) @ np.array([0.0, 0.0, 1.0])
        expected = 3 * GEO_RATE**2 * np.cross(r, J @ r)
        assert np.allclose(disturbance_torque(q, J, dist, SUN, MOON), expected, rtol=1e-12)


def test_disturbance_magnitudes_are_in_the_expected_orders():
    q = from_axis_angle([1, 1, 0], math.radians(5))

    def only(**kw):
        return DisturbanceModel(
            **{
                "gravity_gradient": False,
                "oblateness": False,
                "solar_pressure": False,
                "third_body": False,
                **kw,
            }
        )

    srp = np.linalg.norm(disturbance_torque(q, J, only(solar_pressure=True).vector(), SUN, MOON))
    gg = np.linalg.norm(disturbance_torque(q, J, only(gravity_gradient=True).vector(), SUN, MOON))
    obl = np.linalg.norm(disturbance_torque(q, J, only(oblateness=True).vector(), SUN, MOON))
    tb = np.linalg.norm(
        disturbance_torque(q, J, only(third_body=True).vector(), np.array([0.6, 0.0, 0.8]), MOON)
    )
    assert 1e-5 <= srp <= 1e-4  # the dominant GEO torque for a large comsat
    assert 1e-8 <= gg <= 1e-4
    assert 0 < obl < 1e-3 * gg  # oblateness: present but small at GEO
    assert 0 < tb < 1e-3 * gg  # Sun and Moon tides: present but small
    assert MOON_TIDE > SUN_TIDE  # the Moon's tide is about twice the Sun's


def _error(q, w, q_ref, w_ref):
    dq = qmul(q, np.array([-q_ref[0], -q_ref[1], -q_ref[2], q_ref[3]]))
    return np.concatenate([2 * dq[:3] * np.sign(dq[3]), w - w_ref])


def test_ekf_state_jacobian_matches_finite_differences():
    q = from_axis_angle([0.3, -1, 0.5], 0.3)
    w = dcm(q) @ np.array([0, -GEO_RATE, 0]) + np.array([2e-4, -1e-4, 3e-4])
    hw = np.array([10.0, -5.0, 3.0])
    dist = DisturbanceModel(True, False, False, False).vector()
    dt, eps = 0.2, 1e-7
    # every argument given, as the kernel's twin test gives them: one compiled signature
    F = error_jacobian(q, w, G @ hw, J, J_INV, GEO_RATE, 3 * GEO_RATE**2, None)
    ref = _run(np.concatenate([q, w, hw]), 20, dt / 20, dist=dist)
    Phi_num = np.zeros((6, 6))
    for i in range(6):
        e = np.zeros(6)
        e[i] = eps
        qp = qmul(np.concatenate([e[:3] / 2, [1.0]]), q)
        qp /= np.linalg.norm(qp)
        xp = _run(np.concatenate([qp, w + e[3:], hw]), 20, dt / 20, dist=dist)
        Phi_num[:, i] = _error(xp[:4], xp[4:7], ref[:4], ref[4:7]) / eps
    assert np.allclose(Phi_num, expm(F * dt), atol=1e-7)
    assert not np.allclose(Phi_num, np.eye(6), atol=1e-5)  # the check has something to see


def test_vector_measurement_jacobian_matches_finite_differences():
    q = from_axis_angle([1, 0.2, -0.4], 0.9)
    r = np.array([0.3, -0.5, 0.81])
    b, H = vector_jacobian(q, r, 6)  # dim given, as the filter gives it: one signature
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1e-7
        qp = qmul(np.concatenate([e / 2, [1.0]]), q)
        numeric = (dcm(qp / np.linalg.norm(qp)) @ r - b) / 1e-7
        assert np.allclose(numeric, H[:, i], atol=1e-6)
    assert np.allclose(H[:, 3:], 0)


def test_noise_free_ekf_converges_from_a_5_degree_error():
    sc = SCENARIOS["geo-comsat"].with_(
        **{
            "sensors.sun_noise_deg": 1e-5,
            "sensors.earth_noise_deg": 1e-5,
            "spacecraft.process_noise_torque": 0.0,
            "filter.initial_error_deg": 5.0,
            "filter.disturbances_known": True,
            "filter.innovation_gate": 0.0,
        }
    )
    r = simulate(sc, PDController(20.0, 400.0), duration=600, estimator="ekf")
    assert r.est_error_deg[-1] < 1e-3  # from 5° (the first log is already after one update)
    assert np.all(r.est_error_deg[-30:] < 1e-3)


@pytest.mark.slow
@pytest.mark.parametrize("state, dim", [("torque+srp", 12), ("none", 6)])
def test_ekf_is_consistent_over_long_noisy_runs(state, dim):
    """Normalised estimation error squared, pooled over 4 seeds × 3 h (one sample a minute),
    averages to the state dimension within 10 % (samples a minute apart are still
    correlated, so the χ² band of independent samples would be too narrow). With the
    disturbance state the truth is SRP alone (a constant lever arm, zero constant torque,
    the Sun moving with the season's ephemeris) and the filter's walks are made
    negligible, so that its model is the truth's (its default walks are deliberately
    wider than a constant truth, which makes it conservative: NEES ≈ 5 of 12); without
    it every torque is known."""
    unknown = state != "none"
    sc = SCENARIOS["geo-comsat"].with_(
        **{
            "filter.noise_margin": 1.0,
            "filter.initial_error_deg": 0.05,
            "spacecraft.disturbances": DisturbanceModel(True, False, unknown, False),
            "filter.disturbances_known": not unknown,
            "filter.disturbance_state": state,
            "filter.torque_drift_s": 1e12,
            "filter.srp_drift_s": 1e12,
            "sky.epoch": "2027-02-01T00:00:00Z",
        }
    )
    nees = [
        simulate(sc, PDController(20.0, 400.0), duration=3 * 3600, log_every=600, seed=seed).nees[
            10:
        ]
        for seed in range(4)
    ]
    assert np.mean(np.concatenate(nees)) == pytest.approx(dim, rel=0.1)


def _constant_torque_day(state: str):
    """Noise-free sensors, no process noise, and a constant body torque of 1.9e-3 N·m (ten
    times the comsat's SRP) that the filter does not model; gravity gradient only besides."""
    sc = SCENARIOS["geo-comsat"].with_(
        **{
            "sensors.sun_noise_deg": 1e-5,
            "sensors.earth_noise_deg": 1e-5,
            "spacecraft.process_noise_torque": 0.0,
            "filter.innovation_gate": 0.0,
            "spacecraft.disturbances": DisturbanceModel(
                True, False, False, False, constant_torque=TORQUE
            ),
            "filter.disturbance_state": state,
        }
    )
    from rwlab.attitude.control import LQRController

    return simulate(sc, LQRController(sc), duration=1800, estimator="ekf", log_every=50)


TORQUE = (1e-3, -1.5e-3, 5e-4)


def test_the_torque_state_learns_a_constant_unknown_torque_and_cancels_it():
    r = _constant_torque_day("torque")
    late = r.t >= 1200
    b = r.torque_est[late]
    assert np.all(np.linalg.norm(b - TORQUE, axis=1) < 0.01 * np.linalg.norm(TORQUE))
    assert np.max(r.est_error_deg[late]) < 1e-4
    # fed forward, the torque no longer offsets the body; what is left (< 1e-3°) is the
    # wheels' growing momentum coupling roll and yaw (h × ω), which the law does not cancel
    assert np.max(r.error_deg[late]) < 1e-3
    # without the state the same filter lags the torque and the loop has no integral action
    off = _constant_torque_day("none")
    assert np.max(off.error_deg[off.t >= 1200]) > 50 * np.max(r.error_deg[late])


def test_quaternion_stays_unit_and_pointing_holds_with_noise():
    r = simulate(SCENARIOS["geo-smallsat"], PDController(0.2, 4.0), duration=1800)
    assert np.allclose(np.linalg.norm(r.q, axis=1), 1.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(r.q_est, axis=1), 1.0, atol=1e-12)
    assert np.max(r.error_deg[len(r.error_deg) // 2 :]) < 0.1


@pytest.mark.parametrize("model", ["physics"])
def test_the_rw_physics_can_be_the_actuator(model):
    sc = SCENARIOS["geo-smallsat"].with_(**{"wheels.model": model})
    r = simulate(sc, PDController(0.2, 4.0), duration=600, estimator="truth")
    assert r.error_deg[-1] < 0.1 * r.error_deg[0]


def test_pyramid_wheels_share_the_load():
    sc = SCENARIOS["geo-comsat"].with_(**{"wheels.axes": "pyramid"})
    r = simulate(sc, PDController(20.0, 400.0), duration=600, estimator="truth")
    assert r.wheel_speed_rpm.shape[1] == 4 and r.error_deg[-1] < 0.01


def test_scenario_files_are_validated(tmp_path):
    good = tmp_path / "s.toml"
    good.write_text(
        '[scenario]\nbase = "geo-comsat"\n[run]\ndt = 0.2\n[sensors]\nperiod = 1.0\n'
        "[spacecraft.disturbances]\nsrp_area = 10.0\n"
    )
    sc = load_scenario(str(good))
    assert sc.run.dt == 0.2 and sc.spacecraft.disturbances.srp_area == 10.0
    assert sc.spacecraft.inertia == (1200.0, 1000.0, 1500.0)
    bad = tmp_path / "b.toml"
    bad.write_text("[scenario]\ninertiaa = [1, 2, 3]\n")
    with pytest.raises(ConfigError, match="inertiaa"):
        load_scenario(str(bad))
    with pytest.raises(ConfigError, match="unknown scenario"):
        load_scenario("geo-nosuch")
    with pytest.raises(ConfigError, match="positive definite"):
        SCENARIOS["geo-comsat"].with_(**{"spacecraft.inertia": (1.0, -2.0, 3.0)})
    with pytest.raises(ConfigError, match="triangle"):
        SCENARIOS["geo-comsat"].with_(**{"spacecraft.inertia": (1.0, 1.0, 5.0)})
    assert angle_deg(np.array([0, 0, 0, 1.0])) == 0.0


def test_scalar_derivative_equals_the_readable_reference():
    from rwlab.attitude.plant import _derivative_into, derivative

    rng = np.random.default_rng(1)
    sc = SCENARIOS["geo-comsat"].with_(**{"wheels.axes": "pyramid"})
    J = sc.inertia_matrix + np.array([[0, 5, 3], [5, 0, -2], [3, -2, 0.0]])
    J_inv, G, h_max = np.linalg.inv(J), sc.wheel_matrix, np.full(4, 50.0)
    for _ in range(100):
        q = rng.standard_normal(4)
        x = np.concatenate([q / np.linalg.norm(q), rng.standard_normal(3) * 1e-2, [50, -3, 7, 1]])
        hw_dot = rng.standard_normal(4) * 0.1
        d = sc.spacecraft.disturbances.vector()
        d[7:] = rng.standard_normal(3) * 1e-4
        s, m = rng.standard_normal(3), rng.standard_normal(3)
        args = (J, J_inv, G, h_max, GEO_RATE, d, s / np.linalg.norm(s), m / np.linalg.norm(m))
        ref = derivative(x, hw_dot, *args)
        out = np.empty_like(x)
        _derivative_into(x, hw_dot, *args, out)
        assert np.allclose(out, ref, rtol=1e-12, atol=1e-18)


def test_noise_streams_do_not_depend_on_block_size_or_estimator():
    from types import SimpleNamespace

    from rwlab.attitude.sim import _Streams

    a, b = _Streams(4), _Streams(4)
    on = SimpleNamespace(gyro=True, tracker=True)
    whole = a.block(0, 100, (5, 10), 2.0, on)
    first, second = b.block(0, 37, (5, 10), 2.0, on), b.block(37, 63, (5, 10), 2.0, on)
    for i in range(4):  # process, sun/earth, gyro, tracker
        assert np.array_equal(whole[i], np.vstack([first[i], second[i]]))
    assert [len(x) for x in whole] == [100, 20, 100, 10]
    # a run re-designed every 7 s (other blocks) sees the same disturbances as one designed once
    sc = SCENARIOS["geo-comsat"]
    once = simulate(sc, PDController(20.0, 400.0), duration=60, estimator="truth")
    ctl = PDController(20.0, 400.0)
    ctl.update_period = 7.0
    blocks = simulate(sc, ctl, duration=60, estimator="truth")
    assert np.array_equal(once.q, blocks.q)


def test_saturation_aware_law_is_linear_inside_and_rate_limited_outside():
    from rwlab.attitude.kernel import control_torque

    K = np.hstack([np.diag([2.0, 3.0, 4.0]), np.diag([20.0, 30.0, 40.0])])
    M = np.linalg.solve(K[:, 3:], K[:, :3])
    s = np.array([1e-4, -2e-4, 3e-4, 1e-5, 0.0, -1e-5])
    assert np.allclose(control_torque(K[:, 3:].copy(), M, np.inf, s), -K @ s)
    big = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])  # 57°: far outside the linear range
    tau = control_torque(K[:, 3:].copy(), M, 1e-3, big)
    assert np.allclose(tau, [-20.0 * 1e-3, 0, 0])  # K_ω ω_max, not K_θ θ


def test_a_large_slew_never_asks_the_wheels_for_more_than_they_have():
    from rwlab.attitude.control import LQRController, metrics, torque_capacity

    sc = SCENARIOS["geo-comsat"].with_(
        **{"run.initial_error_deg": 30.0, "run.initial_rate": (0.0, 0.0, 0.0)}
    )
    r = simulate(sc, LQRController(sc), duration=2400, estimator="truth")
    m = metrics(r)
    assert m["torque_peak_Nm"] <= 0.6 * torque_capacity(sc)  # the slew's reserve is kept
    assert m["steady_max_error_deg"] < 0.01  # and it arrives


def test_torque_saturation_is_reported_when_the_wheels_cannot_hold():
    from rwlab.attitude.control import LQRController, metrics
    from rwlab.attitude.plant import DisturbanceModel

    sc = SCENARIOS["geo-comsat"]
    strong = sc.with_(
        **{"spacecraft.disturbances": DisturbanceModel(constant_torque=(0.0, 0.5, 0.0))}
    )
    m_ok = metrics(simulate(sc, LQRController(sc), duration=300, estimator="truth"))
    m_bad = metrics(simulate(strong, LQRController(strong), duration=300, estimator="truth"))
    assert m_ok["torque_saturated_fraction"] == 0.0
    assert m_bad["torque_saturated_fraction"] > 0.9 and not m_bad["meets_requirement"]


def test_thrusters_unload_the_wheels_and_pointing_holds_outside_the_windows():
    from rwlab.attitude.control import LQRController, metrics

    sc = SCENARIOS["geo-smallsat"]
    h0 = np.array([0.55, -0.3, 0.2]) * sc.wheels.max_momentum
    r = simulate(sc, LQRController(sc), duration=3600, estimator="truth", wheel_momentum0=h0)
    m = metrics(r)
    assert m["desaturation_count"] == 1
    h_end = np.abs(r.wheel_speed_rpm[-1]) * np.pi / 30 * sc.wheels.inertia
    assert r.stats["unloading"] == 0 and m["wheel_momentum_peak_fraction"] < 0.7
    assert np.all(h_end <= 2 * sc.momentum.unload_stop_fraction * sc.wheels.max_momentum)
    assert m["thruster_impulse_Nms"] == pytest.approx(
        np.abs(h0).sum() - np.abs(h_end).sum(), rel=0.2
    )
    assert m["max_error_deg_excluding_desaturation"] <= 0.1
    off = simulate(
        sc.with_(**{"momentum.unloading": False}),
        LQRController(sc),
        duration=3600,
        estimator="truth",
        wheel_momentum0=h0,
    )
    assert metrics(off)["desaturation_count"] == 0


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ('[scenario]\nbase = "geo-smalsat"', "base"),
        ('[spacecraft]\ninertia = "abc"', "spacecraft.inertia"),
        ("[spacecraft]\ninertia = 5", "spacecraft.inertia"),
        ('[run]\nseed = "x"', "run.seed"),
        ("[run]\ninitial_axis = [0, 0, 0]", "run.initial_axis"),
        ("[wheels]\nmax_torque = 1e9", "wheels.max_torque"),
        ("[momentum]\nunloading = 1", "momentum.unloading"),
        ("[control]\nlqr_torque_fraction = 2.0", "control.lqr_torque_fraction"),
        ("[wheels]\nmax_torqe = 0.1", "wheels.max_torqe"),
        ("[wheel]\nmax_torque = 0.1", "wheel"),
        ("[sensors.gyro]\narw = 1", "sensors.gyro.arw"),
        ("[spacecraft.disturbances]\nsrp_offset = [1, 2]", "srp_offset"),
    ],
)
def test_bad_scenario_values_are_config_errors(tmp_path, line, match):
    path = tmp_path / "s.toml"
    head = "" if line.startswith("[scenario]") else '[scenario]\nbase = "geo-comsat"\n'
    path.write_text(f"{head}{line}\n")
    with pytest.raises(ConfigError, match=match):
        load_scenario(str(path))


def test_a_flat_scenario_file_is_read_with_a_warning_and_converts_to_the_same(tmp_path):
    from rwlab.attitude.scenario import convert_scenario_file
    from rwlab.errors import FormatWarning

    flat = tmp_path / "flat.toml"
    flat.write_text(
        '[scenario]\nbase = "geo-smallsat"\nwheel_max_torque = 0.01\nsensor_period = 1.0\n'
        "estimator_error_deg = 0.5\ndisturbances_known_to_filter = true\n"
        "[disturbances]\nconstant_torque = [1e-4, 0, 0]\n[gyro]\n"
    )
    with pytest.warns(FormatWarning, match=r"\[wheels\] max_torque.*\[sensors\.gyro\]"):
        old = load_scenario(str(flat))
    # the same values, by their new names: the conversion is a renaming, nothing else
    assert old.wheels.max_torque == 0.01 and old.sensors.period == 1.0
    assert old.filter.initial_error_deg == 0.5 and old.filter.disturbances_known
    assert old.spacecraft.disturbances.constant_torque == (1e-4, 0, 0)
    assert old.sensors.gyro is not None and old.run.initial_error_deg == 2.0
    new = tmp_path / "flat.sections.toml"
    new.write_text(convert_scenario_file(flat))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # the converted file reads without a format warning,
        converted = load_scenario(str(new))  # only the one on a wheel's own torque number
    assert [str(w.message).count("wheel model's numbers") for w in caught] == [1]
    assert converted == old  # the name too: the converted file keeps the flat one's
    mixed = tmp_path / "mixed.toml"
    mixed.write_text("[scenario]\ndt = 0.2\n[wheels]\nmax_torque = 0.1\n")
    with pytest.raises(ConfigError, match="mixes"):
        load_scenario(str(mixed))


def test_with_changes_fields_by_dotted_name_and_refuses_unknown_ones():
    sc = SCENARIOS["geo-comsat"]
    changed = sc.with_(**{"wheels.max_torque": 0.1, "spacecraft.disturbances.srp_area": 3.0})
    assert changed.wheels.max_torque == 0.1 and changed.spacecraft.disturbances.srp_area == 3.0
    assert sc.wheels.max_torque == 0.31  # unchanged: the nrwa-t6 spec's
    for bad in ("wheel_max_torque", "wheels.max_torqe", "name.x", "run"):
        with pytest.raises(ConfigError):
            sc.with_(**{bad: 1.0})


@pytest.mark.parametrize("n", [6, 9, 12])
def test_the_kernels_scalar_filter_twins_equal_their_references(n):
    from rwlab.attitude.ekf import (
        error_jacobian_into,
        predict_covariance,
        predict_covariance_into,
    )

    rng = np.random.default_rng(3)
    q = from_axis_angle(rng.standard_normal(3), 0.3)
    w, h = 1e-3 * rng.standard_normal(3), 5 * rng.standard_normal(3)
    F = np.full((n, n), np.nan)
    gg = 3 * GEO_RATE**2
    B = rng.standard_normal((3, n - 6))  # (3, 0) without the disturbance state
    error_jacobian_into(q, w, h, J, J_INV, GEO_RATE, gg, B, F, np.empty((4, 3, 3)))
    ref = error_jacobian(q, w, h, J, J_INV, GEO_RATE, gg, B if n > 6 else None)
    assert ref.shape == (n, n) and np.allclose(F, ref, rtol=1e-12, atol=1e-18)
    if n > 6:  # δω̇ ∋ J⁻¹ B δb, δḃ = 0
        assert np.allclose(ref[3:6, 6:], J_INV @ B, rtol=1e-14) and not np.any(ref[6:])
    L = rng.standard_normal((n, n))
    P, Qc = L @ L.T, np.diag(([0, 0, 0, 1e-9, 2e-9, 3e-9] + [1e-12, 2e-12, 3e-12] * 2)[:n])
    expected = predict_covariance(P, F, Qc, 0.5)
    predict_covariance_into(P, F, Qc, 0.5, np.empty((6, n, n)))
    assert np.allclose(P, expected, rtol=1e-12, atol=1e-15) and np.array_equal(P, P.T)


@pytest.mark.parametrize("n", [6, 9])
def test_the_kernels_scalar_update_equals_the_reference_and_gates(n):
    from rwlab.attitude.ekf import _update, gated_update_into

    rng = np.random.default_rng(4)
    q = from_axis_angle(rng.standard_normal(3), 0.2)
    w = 1e-3 * rng.standard_normal(n - 3)  # [ω̂] or [ω̂, b̂]
    L = 1e-2 * rng.standard_normal((n, n))
    P = L @ L.T + 1e-6 * np.eye(n)
    ref = np.array([0.6, -0.48, 0.64])
    meas = dcm(from_axis_angle(rng.standard_normal(3), 0.01) * 1.0) @ dcm(q) @ ref
    q_ref, w_ref, P_ref = _update(q, w, P, meas, ref, 3e-4)
    q2, w2, P2 = q.copy(), w.copy(), P.copy()
    assert gated_update_into(q2, w2, P2, meas, ref, 3e-4, 0.0, np.empty((4, n, n)))
    assert np.allclose(q2, q_ref, rtol=0, atol=1e-14) and np.allclose(w2, w_ref, atol=1e-16)
    assert np.allclose(P2, P_ref, rtol=1e-10, atol=1e-18) and np.array_equal(P2, P2.T)
    # a wild measurement (the Sun seen 90° off) is refused by a χ² gate and changes nothing
    q3, w3, P3 = q.copy(), w.copy(), P.copy()
    wild = np.cross(dcm(q) @ ref, [0.0, 0.0, 1.0])
    wild /= np.linalg.norm(wild)
    assert not gated_update_into(q3, w3, P3, wild, ref, 3e-4, 25.0, np.empty((4, n, n)))
    assert np.array_equal(q3, q) and np.array_equal(w3, w) and np.array_equal(P3, P)


def _exact_joseph(P, H, sigma):
    """(I − KH) P (I − KH)ᵀ + K R Kᵀ in exact rational arithmetic (K = P Hᵀ S⁻¹)."""
    from fractions import Fraction

    def mat(a):
        return [[Fraction(float(v)) for v in row] for row in np.atleast_2d(a)]

    def mul(a, b):
        cols = list(zip(*b, strict=True))
        return [[sum(x * y for x, y in zip(r, c, strict=True)) for c in cols] for r in a]

    def tr(a):
        return [list(c) for c in zip(*a, strict=True)]

    Pf, Hf, r = mat(P), mat(H), Fraction(float(sigma)) ** 2
    S = mul(mul(Hf, Pf), tr(Hf))
    for i in range(3):
        S[i][i] += r
    (a, b, c), (d, e, f), (g, h, k) = S
    cof = [[e * k - f * h, c * h - b * k, b * f - c * e],
           [f * g - d * k, a * k - c * g, c * d - a * f],
           [d * h - e * g, b * g - a * h, a * e - b * d]]  # fmt: skip
    det = a * cof[0][0] + b * cof[1][0] + c * cof[2][0]
    K = mul(mul(Pf, tr(Hf)), [[v / det for v in row] for row in cof])
    KH = mul(K, Hf)
    I_KH = [[(i == j) - KH[i][j] for j in range(6)] for i in range(6)]
    out = mul(mul(I_KH, Pf), tr(I_KH))
    KK = mul(K, tr(K))
    return np.array([[float(out[i][j] + r * KK[i][j]) for j in range(6)] for i in range(6)])


def test_the_scalar_update_holds_on_ill_conditioned_innovations():
    """With 1e-5° sensors the second vector's S has a condition number near 1e11: against
    exact arithmetic the Cholesky-based update keeps P's attitude block to 1e-6 (the
    LU-based reference ``_update`` is off by ~90 % there, cofactors were as bad)."""
    from rwlab.attitude.ekf import gated_update_into, vector_jacobian

    q, w = from_axis_angle([1, 0.5, -0.3], 0.05), np.zeros(3)
    P = np.diag([math.radians(5) ** 2] * 3 + [1e-8] * 3)
    turn = dcm(from_axis_angle([0.2, 1, 0], 0.08))
    for ref in ([0.0, 0, 1], [0.6, -0.48, 0.64], [0.0, 0, 1]):
        ref = np.array(ref)
        exact = _exact_joseph(P, vector_jacobian(q, ref, 6)[1], 2e-7)
        q2, w2, P2 = q.copy(), w.copy(), P.copy()
        gated_update_into(q2, w2, P2, turn @ ref, ref, 2e-7, 0.0, np.empty((4, 6, 6)))
        block = np.max(np.abs(exact[:3, :3]))
        assert np.max(np.abs(P2 - exact)[:3, :3]) < 1e-6 * block
        assert np.all(np.linalg.eigvalsh(P2) > 0)
        q, w, P = q2, w2, P2


def test_report_envelope_keeps_every_peak_of_a_long_trace():
    from rwlab.report.attitude import envelope

    t = np.arange(100_000) * 0.1
    y = np.random.default_rng(5).standard_normal(t.size)
    y[12_345], y[77_777] = 50.0, -40.0
    t2, y2 = envelope(t, y, bins=500)
    assert t2.size <= 1000 + 2 * 200 and np.all(np.diff(t2) > 0)
    assert y2.max() == 50.0 and y2.min() == -40.0
    assert np.array_equal(envelope(t[:900], y[:900], bins=500)[1], y[:900])


def test_kernel_nees_is_the_textbook_quadratic_form():
    from rwlab.attitude.kernel import _nees

    rng = np.random.default_rng(6)
    q = from_axis_angle(rng.standard_normal(3), 0.4)
    q_hat = -from_axis_angle(rng.standard_normal(3), 0.01)  # the sign of q̂ must not matter
    q_hat = qmul(q_hat, q)
    x = np.concatenate([q, 1e-3 * rng.standard_normal(3), np.zeros(3)])
    w_hat = x[4:7] + 1e-5 * rng.standard_normal(3)
    b, b_hat = 1e-4 * rng.standard_normal(3), 1e-4 * rng.standard_normal(3)
    L = 1e-3 * rng.standard_normal((9, 9))
    P = L @ L.T + 1e-8 * np.eye(9)
    dq = qmul(q, np.array([-q_hat[0], -q_hat[1], -q_hat[2], q_hat[3]]))
    dq = dq if dq[3] >= 0 else -dq
    e = np.concatenate([2 * dq[:3], x[4:7] - w_hat, b - b_hat])
    expected = e[:6] @ np.linalg.solve(P[:6, :6], e[:6])
    rest = np.concatenate([np.zeros(3), x[4:7] - w_hat])  # the caller fills e[3:]
    got = _nees(x, q_hat, rest, P[:6, :6].copy(), np.empty((6, 6)), np.empty(6))
    assert got == pytest.approx(expected, rel=1e-9)
    # with the disturbance state the error gains b − b̂
    rest = np.concatenate([np.zeros(3), x[4:7] - w_hat, b - b_hat])
    got = _nees(x, q_hat, rest, P, np.empty((9, 9)), np.empty(9))
    assert got == pytest.approx(e @ np.linalg.solve(P, e), rel=1e-9)


def test_kernel_dcm_twin_equals_frames_dcm():
    from rwlab.attitude.kernel import _dcm_into

    q = from_axis_angle([0.3, -1.0, 0.2], 2.1)
    C = np.empty((3, 3))
    _dcm_into(np.concatenate([q, np.zeros(6)]), C)
    assert np.allclose(C, dcm(q), rtol=0, atol=1e-15)
