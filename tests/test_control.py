import itertools
import json
import math

import control
import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.attitude.control import PAPER_RHOS, attitude_plant, compare, linearize, ltr_study
from rwlab.attitude.design import DesignError, kalman, lqg, lqr, ltr, sigma
from rwlab.attitude.frames import GEO_RATE
from rwlab.attitude.scenario import SCENARIOS
from rwlab.cli import main

J = np.diag([1200.0, 1000.0, 1500.0])


def _double_integrators():
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    B = np.vstack([np.zeros((3, 3)), np.linalg.inv(J)])
    C = np.hstack([np.eye(3), np.zeros((3, 3))])
    return control.ss(A, B, C, 0)


def test_lqr_of_a_double_integrator_has_the_textbook_gain():
    sys = control.ss([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], 0)
    K = lqr(sys, np.eye(2), np.eye(1))
    assert np.allclose(K, [[1.0, math.sqrt(3.0)]])  # ARE solution for Q = I, R = 1


def test_lqg_compensator_stabilises_the_plant():
    sys = _double_integrators()
    K = lqr(sys, np.eye(6), np.eye(3))
    L = kalman(sys, np.eye(6), np.eye(3))
    comp = lqg(sys, K, L)
    closed = control.feedback(sys, comp, sign=-1)
    assert np.all(np.real(control.poles(closed)) < 0)


def test_input_ltr_gap_shrinks_monotonically_and_ends_small():
    """Minimum-phase square plant (three double integrators): as ρ → 0 the loop K(s)G(s)
    recovers K(sI − A)⁻¹B over the band."""
    sys = _double_integrators()
    Q = np.diag([1e6] * 3 + [1e8] * 3)
    rhos = [76.92, 7.692, 0.7692, 0.007692, 1e-4, 1e-6]
    res = ltr(sys, Q, np.eye(3) * 25, rhos, R0=np.eye(3) * 1e-7)
    gaps = [res.max_gap(r, (1e-3, 1e-1)) for r in rhos]
    assert all(b < a for a, b in itertools.pairwise(gaps))
    assert gaps[-1] < 1.0  # dB: within 12 % at every frequency of the band


def test_output_ltr_is_the_dual_and_converges_too():
    sys = _double_integrators()
    res = ltr(sys, np.eye(6) * 1e-6, np.eye(3) * 1e-6, [10.0, 1e-2, 1e-5], side="output")
    gaps = [res.max_gap(r, (1e-3, 1e-1)) for r in res.loops]
    assert gaps[-1] < gaps[0]


def test_design_refuses_bad_weights_pairs_and_rho():
    sys = _double_integrators()
    with pytest.raises(DesignError, match="semidefinite"):
        lqr(sys, -np.eye(6), np.eye(3))
    with pytest.raises(DesignError, match="positive definite"):
        lqr(sys, np.eye(6), np.zeros((3, 3)))
    with pytest.raises(DesignError, match="symmetric"):
        lqr(sys, np.triu(np.ones((6, 6))), np.eye(3))
    unstable = control.ss([[1.0, 0], [0, 2.0]], [[1.0], [0]], [[1.0, 0]], 0)
    with pytest.raises(DesignError, match="stabilisable"):
        lqr(unstable, np.eye(2), np.eye(1))
    with pytest.raises(DesignError, match="detectable"):
        kalman(unstable, np.eye(2), np.eye(1))
    for bad in ([0.0], [-1.0], [float("nan")], []):
        with pytest.raises(DesignError, match="ρ"):
            ltr(sys, np.eye(6), np.eye(3), bad)


def test_sigma_of_a_static_gain_is_its_singular_values():
    g = control.ss([], [], [], np.diag([3.0, 0.5]))
    assert np.allclose(sigma(g, [0.1, 10.0]), [[3.0, 0.5], [3.0, 0.5]])


def test_linearisation_at_the_reference_is_the_known_geo_model():
    A, B = linearize(np.array([0, 0, 0, 1.0]), np.zeros(3), np.zeros(3), J, gravity_gradient=False)
    assert np.allclose(A[:3, 3:], np.eye(3), atol=1e-9)
    assert np.allclose(B[3:], np.linalg.inv(J))
    A_gg, _ = linearize(np.array([0, 0, 0, 1.0]), np.zeros(3), np.zeros(3), J)
    # pitch gravity gradient: Jy θ̈ = −3n²(Jx − Jz) θ, and the roll–yaw gyroscopic coupling
    assert A_gg[3, 5] == pytest.approx(GEO_RATE * (1200 - 1000 + 1500) / 1200, rel=1e-4)
    assert A_gg[4, 1] == pytest.approx(-3 * GEO_RATE**2 * (1200 - 1500) / 1000, rel=1e-4)


def test_paper_rho_sweep_recovers_monotonically_on_the_default_scenarios():
    for name in ("geo-smallsat", "geo-comsat"):
        res = ltr_study(SCENARIOS[name])
        gaps = [res.max_gap(r, (1e-3, 1e-1)) for r in PAPER_RHOS]
        assert all(b < a for a, b in itertools.pairwise(gaps)), (name, gaps)
        assert np.all(np.asarray(res.loops[0.007692]) > 0)
        assert attitude_plant(SCENARIOS[name]).nstates == 6


@pytest.mark.slow
@pytest.mark.parametrize("name", ["geo-smallsat", "geo-comsat"])
def test_paper_ordering_lqr_beats_lqg_and_ltr_all_within_requirement(name):
    comp = compare(SCENARIOS[name], duration=900)
    m = comp.metrics
    for ctl in ("lqg", "lqg_ltr"):
        assert m[ctl]["steady_max_error_deg"] <= 0.1 and m[ctl]["meets_requirement"]
        assert m["lqr"]["steady_rms_error_deg"] < m[ctl]["steady_rms_error_deg"]
        assert m[ctl]["settling_time_s"] is not None and not m[ctl]["wheel_saturated"]


@pytest.fixture(scope="module")
def identified_wheel(tmp_path_factory):
    """model.json through the real pipeline: twin experiment → rwlab identify."""
    from rwlab.ident.study import identification_study, physical_model
    from rwlab.report.identification import write_study
    from rwlab.testbed import ExperimentConfig, load_record, run_experiment

    root = tmp_path_factory.mktemp("wheel")
    run_experiment(ExperimentConfig(duration=1200, Ts=0.5, seed=7), root / "prbs.mcap")
    result = identification_study(load_record(root / "prbs.mcap"))
    write_study(result, physical_model(result), root / "study")
    return root / "study" / "model.json"


def test_the_identified_wheel_flies_and_its_lag_cost_is_reported(tmp_path, identified_wheel):
    model = identified_wheel
    out = tmp_path / "cmp"
    r = CliRunner().invoke(
        main,
        [
            "attitude",
            "compare",
            "--scenario",
            "geo-smallsat",
            "--duration",
            "600",
            "--wheel-model",
            str(model),
            "--out",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= {"lqr", "lqg", "lqg_ltr", "lqg_identified_wheel"}
    for ctl in ("lqr", "lqg", "lqg_ltr"):
        assert {
            "steady_max_error_deg",
            "steady_rms_error_deg",
            "settling_time_s",
            "wheel_saturated",
        } <= set(metrics[ctl])
    wheel = metrics["lqg_identified_wheel"]
    assert wheel["steady_max_error_deg"] < 0.1 and not wheel["wheel_saturated"]  # stable
    assert metrics["identified_wheel_lag_cost_deg"] > 0  # the lag costs something
    assert wheel["steady_rms_error_deg"] == pytest.approx(
        metrics["lqg"]["steady_rms_error_deg"] + metrics["identified_wheel_lag_cost_deg"]
    )
    assert "lag costs" in (out / "report.html").read_text()
    sig = json.loads((out / "sigma.json").read_text())
    assert set(sig["loops"]) == {"76.92", "7.692", "0.7692", "0.007692"}


def test_ltr_command_writes_sigma_json(tmp_path):
    r = CliRunner().invoke(
        main,
        [
            "attitude",
            "ltr",
            "--scenario",
            "geo-comsat",
            "--rho",
            "1",
            "--rho",
            "0.01",
            "--out",
            str(tmp_path),
        ],
    )
    assert r.exit_code == 0, r.output
    sig = json.loads((tmp_path / "sigma.json").read_text())
    assert len(sig["omega"]) == len(sig["target"]) == len(sig["loops"]["1"])
    assert len(sig["target"][0]) == 3 and all(v > 0 for v in sig["target"][0])


def test_bad_configurations_exit_with_clear_errors(tmp_path):
    bad = tmp_path / "s.toml"
    bad.write_text("[scenario]\nwheel_inertiaa = 1\n")
    for args in (
        ["attitude", "compare", "--scenario", str(bad), "--out", str(tmp_path / "a")],
        ["attitude", "compare", "--rho", "0", "--out", str(tmp_path / "b")],
        ["attitude", "ltr", "--rho", "-1", "--out", str(tmp_path / "c")],
        ["attitude", "ltr", "--scenario", "geo-moon", "--out", str(tmp_path / "d")],
    ):
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 2 and r.output.startswith("error:"), (args, r.output)
