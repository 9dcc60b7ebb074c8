"""State-space models: SSModel, n4sid, ssest against systems whose truth is known."""

from __future__ import annotations

import control
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from rwlab.data import IOData, load, merge
from rwlab.errors import DataError, FileFormatError, ModelError
from rwlab.ident import SSModel, n4sid, ssest

# a 2-input 2-output 4th-order innovations-form system: poles 0.7 ± 0.4j, 0.85, 0.3
A = np.array([[0.7, 0.4, 0, 0], [-0.4, 0.7, 0, 0], [0, 0, 0.85, 0], [0, 0, 0, 0.3]])
B = np.array([[1.0, 0.0], [0.5, 0.3], [0.0, 1.0], [0.8, -0.6]])
C = np.array([[1.0, 0.0, 1.0, 0.5], [0.0, 1.0, -0.5, 1.0]])
K = np.array([[0.3, 0.1], [0.0, 0.2], [0.2, -0.1], [0.1, 0.3]])
TRUE_POLES = np.array([0.7 + 0.4j, 0.7 - 0.4j, 0.85, 0.3])


def innovations_data(N: int, seed: int, noise_sd: float = 0.1, Ts: float = 0.1) -> IOData:
    """Simulate x⁺ = A x + B u + K e, y = C x + e by a plain loop (independent of rwlab)."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((N, 2))
    e = noise_sd * rng.standard_normal((N, 2))
    x = np.zeros(4)
    y = np.empty((N, 2))
    for t in range(N):
        y[t] = C @ x + e[t]
        x = A @ x + B @ u[t] + K @ e[t]
    return IOData(u, y, Ts)


def pole_error(p: np.ndarray, q: np.ndarray) -> float:
    """Largest distance between poles after the best one-to-one matching."""
    dist = np.abs(p[:, None] - q[None, :])
    rows, cols = linear_sum_assignment(dist)
    return float(dist[rows, cols].max())


@pytest.fixture(scope="module")
def mimo():
    return innovations_data(3000, seed=1)


@pytest.fixture(scope="module")
def mimo_models(mimo):
    return n4sid(mimo, 4), ssest(mimo, 4)


def test_n4sid_and_ssest_recover_the_four_poles(mimo_models):
    m4, ms = mimo_models
    assert pole_error(m4.poles(), TRUE_POLES) < 0.02
    assert pole_error(ms.poles(), TRUE_POLES) < 0.02


def test_ssest_prediction_loss_is_no_larger_than_n4sids(mimo, mimo_models):
    m4, ms = mimo_models
    assert ms.report["loss"] <= m4.report["loss"]
    e4 = m4.residuals(mimo, initial="estimate")
    es = ms.residuals(mimo, initial="estimate")
    assert np.mean(es**2) <= np.mean(e4**2)
    # the innovations have variance 0.01 per output: neither model can beat the noise by much
    assert np.allclose(np.diag(ms.noise_variance), 0.01, rtol=0.1)


@pytest.mark.parametrize("weighting", ["CVA", "MOESP", "N4SID"])
def test_every_weighting_finds_the_poles(mimo, weighting):
    m = n4sid(mimo, 4, weighting=weighting)
    assert pole_error(m.poles(), TRUE_POLES) < 0.02
    assert m.report["weighting"] == weighting


def test_order_chosen_from_the_singular_values(mimo):
    m = n4sid(mimo, "best")
    assert m.nx == 4
    sv = np.array(m.report["singular_values"])
    assert np.all(np.diff(sv) <= 1e-12)  # descending


def test_canonical_form_reaches_the_same_optimum(mimo, mimo_models):
    _, ms = mimo_models
    mc = ssest(mimo, 4, form="canonical")
    assert mc.C[0, 0] == 1.0 and mc.C[1, 2] == 1.0  # unit rows at the observability indices
    assert pole_error(mc.poles(), ms.poles()) < 1e-3
    assert mc.report["loss"] == pytest.approx(ms.report["loss"], rel=1e-3)


def test_noise_free_siso_system_is_recovered_exactly():
    # y = 0.5 q⁻¹ / (1 − 1.5 q⁻¹ + 0.7 q⁻²) u: poles 0.75 ± 0.37j
    rng = np.random.default_rng(3)
    u = rng.standard_normal(2000)
    sys = control.ss(control.tf([0.5, 0.0], [1, -1.5, 0.7], 1.0))
    y = control.forced_response(sys, U=u).outputs
    m = n4sid(IOData(u, y, 1.0), 2, disturbance="none")
    w = np.linspace(0.01, 3.1, 50)
    truth = control.frequency_response(sys, w).complex.ravel()
    assert np.allclose(m.frequency_response(w)[:, 0, 0], truth, rtol=1e-6, atol=1e-8)
    assert pole_error(m.poles(), np.roots([1, -1.5, 0.7])) < 1e-6


def test_merged_experiments(mimo):
    other = innovations_data(1500, seed=7)
    m = n4sid(merge(mimo[:1500], other), 4)
    assert pole_error(m.poles(), TRUE_POLES) < 0.03


def test_json_round_trip(tmp_path, mimo_models):
    _, ms = mimo_models
    path = ms.save(tmp_path / "ss.json")
    back = SSModel.load(path)
    for name in ("A", "B", "C", "D", "K", "noise_variance", "covariance", "x0"):
        assert np.array_equal(getattr(back, name), getattr(ms, name)), name
    assert back.Ts == ms.Ts and back.report == ms.report
    with pytest.raises(FileExistsError):
        ms.save(path)
    with pytest.raises(FileFormatError):
        SSModel.from_dict({"format": "something else"})


def test_python_control_round_trip(mimo_models):
    _, ms = mimo_models
    sys = ms.to_ss()
    assert isinstance(sys, control.StateSpace) and sys.dt == ms.Ts
    back = SSModel.from_ss(sys, K=ms.K)
    assert np.array_equal(back.A, ms.A) and np.array_equal(back.K, ms.K)
    w = np.array([0.1, 1.0, 10.0])
    assert np.allclose(ms.frequency_response(w), np.moveaxis(sys(np.exp(1j * w * ms.Ts)), -1, 0))
    with pytest.raises(ModelError):
        SSModel.from_ss(control.ss(-1.0, 1.0, 1.0, 0.0))  # continuous time


def test_siso_conversion_to_polymodel_keeps_both_transfer_functions():
    m = SSModel([[0.9, 0.2], [0.0, 0.5]], [[1.0], [0.5]], [[1.0, -1.0]], K=[[0.3], [0.1]], Ts=0.5)
    p = m.to_poly()
    w = np.linspace(0.05, 6.0, 20)
    assert np.allclose(p.frequency_response(w), m.frequency_response(w)[:, 0, 0])
    z = np.exp(1j * w * m.Ts)
    H_ss = m.noise_ss()(z).ravel()
    H_poly = p.noise_tf()(z).ravel()
    assert np.allclose(H_ss, H_poly)
    with pytest.raises(ModelError):
        SSModel(A, B, C, Ts=1.0).to_poly()  # two outputs


def test_with_parameters_and_bad_input():
    m = SSModel(A, B, C, K=K, Ts=0.1)
    assert np.array_equal(m.with_parameters(m.parameters).A, m.A)
    with pytest.raises(ModelError):
        m.with_parameters(np.zeros(3))
    with pytest.raises(ModelError):
        SSModel(A, B, C[:, :3], Ts=0.1)
    with pytest.raises(DataError):
        n4sid(innovations_data(300, 0), 4, weighting="PCA")
    with pytest.raises(DataError):
        n4sid(innovations_data(30, 0), 4)  # too short for the horizons
    with pytest.raises(DataError):
        m.predict(IOData(np.zeros((10, 1)), np.zeros((10, 2)), 0.1))


def test_several_outputs_survive_split_detrend_and_files(tmp_path, mimo):
    est, val = mimo.split(0.5)
    assert (est.ny, val.ny, est.N + val.N) == (2, 2, mimo.N)
    d = mimo.detrend("linear")
    assert np.allclose(d.y.mean(axis=0), 0, atol=1e-12)
    for suffix in ("csv", "parquet", "mat"):
        back = load(d.write(tmp_path / f"r.{suffix}"))
        assert back.output_names == d.output_names and np.allclose(back.y, d.y)
        assert np.allclose(back.trend.output_slope, d.trend.output_slope)


def test_cli_verbs(tmp_path, mimo):
    import json

    from click.testing import CliRunner

    from rwlab.cli import main

    path = mimo.write(tmp_path / "mimo.csv")
    run = CliRunner().invoke
    res = run(
        main, ["ident", "ssest", str(path), "4", "--json", "--save", str(tmp_path / "m.json")]
    )
    assert res.exit_code == 0, res.output
    model = SSModel.from_dict(json.loads(res.output)["model"])
    assert pole_error(model.poles(), TRUE_POLES) < 0.03
    assert SSModel.load(tmp_path / "m.json").to_dict() == model.to_dict()
    res = run(
        main, ["ident", "spa", "dryer", "--detrend", "constant", "--save", str(tmp_path / "g.json")]
    )
    assert res.exit_code == 0 and "omega" in res.output
    assert len(json.loads((tmp_path / "g.json").read_text())["omega"]) == 128
    res = run(main, ["ident", "impulse", "dryer", "--detrend", "constant", "--n", "20", "--json"])
    assert res.exit_code == 0 and len(json.loads(res.output)["coefficients"]) == 20
    res = run(main, ["ident", "n4sid", str(path), "0"])
    assert res.exit_code == 2
