import math

import numpy as np
import pytest
from scipy import stats
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
    F = error_jacobian(q, w, G @ hw, J, J_INV, GEO_RATE, 3 * GEO_RATE**2)
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
    b, H = vector_jacobian(q, r)
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1e-7
        qp = qmul(np.concatenate([e / 2, [1.0]]), q)
        numeric = (dcm(qp / np.linalg.norm(qp)) @ r - b) / 1e-7
        assert np.allclose(numeric, H[:, i], atol=1e-6)
    assert np.allclose(H[:, 3:], 0)


def test_noise_free_ekf_converges_from_a_5_degree_error():
    sc = SCENARIOS["geo-comsat"].with_(
        sun_noise_deg=1e-5, earth_noise_deg=1e-5, process_noise_torque=0.0, estimator_error_deg=5.0
    )
    r = simulate(sc, PDController(20.0, 400.0), duration=600, estimator="ekf")
    assert r.est_error_deg[-1] < 1e-3  # from 5° (the first log is already after one update)
    assert np.all(r.est_error_deg[-30:] < 1e-3)


def test_ekf_is_consistent_over_a_long_noisy_run():
    """Normalised estimation error squared averaged over 4 h stays in its 95 % band."""
    sc = SCENARIOS["geo-comsat"].with_(noise_margin=1.0, estimator_error_deg=0.05)
    r = simulate(
        sc, PDController(20.0, 400.0), duration=4 * 3600, estimator="ekf", log_every=600
    )  # one sample a minute: nearly independent
    nees = r.nees[10:]
    lo, hi = stats.chi2.ppf([0.025, 0.975], 6 * nees.size) / nees.size
    assert lo <= nees.mean() <= hi


def test_quaternion_stays_unit_and_pointing_holds_with_noise():
    r = simulate(SCENARIOS["geo-smallsat"], PDController(0.2, 4.0), duration=1800)
    assert np.allclose(np.linalg.norm(r.q, axis=1), 1.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(r.q_est, axis=1), 1.0, atol=1e-12)
    assert np.max(r.error_deg[len(r.error_deg) // 2 :]) < 0.1


@pytest.mark.parametrize("model", ["physics"])
def test_the_rw_physics_can_be_the_actuator(model):
    sc = SCENARIOS["geo-smallsat"].with_(wheel_model=model)
    r = simulate(sc, PDController(0.2, 4.0), duration=600, estimator="truth")
    assert r.error_deg[-1] < 0.1 * r.error_deg[0]


def test_pyramid_wheels_share_the_load():
    sc = SCENARIOS["geo-comsat"].with_(wheel_axes="pyramid")
    r = simulate(sc, PDController(20.0, 400.0), duration=600, estimator="truth")
    assert r.wheel_speed_rpm.shape[1] == 4 and r.error_deg[-1] < 0.01


def test_scenario_files_are_validated(tmp_path):
    good = tmp_path / "s.toml"
    good.write_text(
        '[scenario]\nbase = "geo-comsat"\ndt = 0.2\nsensor_period = 1.0\n'
        "[disturbances]\nsrp_area = 10.0\n"
    )
    sc = load_scenario(str(good))
    assert sc.dt == 0.2 and sc.disturbances.srp_area == 10.0
    assert sc.inertia == (1200.0, 1000.0, 1500.0)
    bad = tmp_path / "b.toml"
    bad.write_text("[scenario]\ninertiaa = [1, 2, 3]\n")
    with pytest.raises(ConfigError, match="inertiaa"):
        load_scenario(str(bad))
    with pytest.raises(ConfigError, match="unknown scenario"):
        load_scenario("geo-nosuch")
    with pytest.raises(ConfigError, match="positive definite"):
        SCENARIOS["geo-comsat"].with_(inertia=(1.0, -2.0, 3.0))
    with pytest.raises(ConfigError, match="triangle"):
        SCENARIOS["geo-comsat"].with_(inertia=(1.0, 1.0, 5.0))
    assert angle_deg(np.array([0, 0, 0, 1.0])) == 0.0
