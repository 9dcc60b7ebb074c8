"""A known static gain imposed on ARX, ARMAX, OE and BJ (rwlab.ident.gain_constraint).

Independent truths: the Lagrange (KKT) solution of equality-constrained least
squares and its textbook covariance σ²(P − Pc(cᵀPc)⁻¹cᵀP), P = (ΦᵀΦ)⁻¹; the
spread of estimates over seeds; and the invariant that the imposed gain is met
exactly whatever the data.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import DataError
from rwlab.ident import armax, arx, bj, oe
from rwlab.ident.study import _choose, _parts, identification_study

A_TRUE, B_TRUE = [1.0, -1.2, 0.5], [0.0, 0.3, 0.2]  # static gain 0.5 / 0.3
K_TRUE = 0.5 / 0.3


def _arx_data(seed: int, n: int = 400, noise: float = 0.3) -> IOData:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    y = lfilter(B_TRUE, A_TRUE, u) + lfilter([1.0], A_TRUE, noise * rng.standard_normal(n))
    return IOData(u, y, 1.0)


def _oe_data(seed: int, n: int = 600, noise: float = 0.3) -> IOData:
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], n // 5), 5)
    y = lfilter(B_TRUE, A_TRUE, u) + noise * rng.standard_normal(n)
    return IOData(u, y, 1.0)


def _kkt(data: IOData, K: float):
    """Constrained least squares by the Lagrange system, with its textbook covariance."""
    y, u = data.y[:, 0], data.u[:, 0]
    Phi = np.column_stack([-y[1:-1], -y[:-2], u[1:-1], u[:-2]])
    t = y[2:]
    c = np.array([-K, -K, 1.0, 1.0])
    M = np.block([[2 * Phi.T @ Phi, c[:, None]], [c[None, :], np.zeros((1, 1))]])
    theta = np.linalg.solve(M, np.concatenate([2 * Phi.T @ t, [K]]))[:4]
    e = t - Phi @ theta
    lam = e @ e / (len(t) - 3)
    P = np.linalg.inv(Phi.T @ Phi)
    Pc = P @ c
    return theta, lam * (P - np.outer(Pc, Pc) / (c @ Pc))


def test_constrained_arx_equals_the_lagrange_solution_and_its_covariance():
    data = _arx_data(1)
    K = 1.5  # not the true gain: the constraint binds
    m = arx(data, 2, 2, 1, dc_gain=K)
    theta, cov = _kkt(data, K)
    np.testing.assert_allclose(m.parameters, theta, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(m.covariance, cov, rtol=1e-8, atol=1e-14)
    assert float(m.dc_gain()) == pytest.approx(K, rel=1e-12)
    assert m.report["dc_gain"] == K and m.report["n_free"] == 3
    free = arx(data, 2, 2, 1)
    assert m.report["loss"] > free.report["loss"]  # a binding constraint costs fit


def test_constrained_arx_covariance_matches_the_spread_over_seeds():
    estimates, stds = [], []
    for seed in range(300):
        m = arx(_arx_data(seed, n=300), 2, 2, 1, dc_gain=K_TRUE)
        estimates.append(m.parameters)
        stds.append(m.parameter_std)
    spread = np.std(estimates, axis=0, ddof=1)
    np.testing.assert_allclose(np.mean(stds, axis=0), spread, rtol=0.15)
    # the true gain imposed: unbiased, and tighter than the free estimate
    np.testing.assert_allclose(np.mean(estimates, axis=0), [-1.2, 0.5, 0.3, 0.2], atol=0.01)
    free = np.std([arx(_arx_data(s, n=300), 2, 2, 1).parameters for s in range(300)], axis=0)
    assert np.all(spread < free)


@pytest.mark.parametrize(
    ("estimate", "args"),
    [(oe, (2, 2, 1)), (armax, (2, 2, 1, 1)), (bj, (2, 1, 1, 2, 1))],
    ids=["oe", "armax", "bj"],
)
def test_prediction_error_models_meet_the_gain_exactly_and_lose_fit_only_when_it_binds(
    estimate, args
):
    data = _oe_data(3)
    free = estimate(data, *args)
    at_truth = estimate(data, *args, dc_gain=K_TRUE)
    off = estimate(data, *args, dc_gain=1.2 * K_TRUE)
    for m, K in ((at_truth, K_TRUE), (off, 1.2 * K_TRUE)):
        assert float(m.dc_gain()) == pytest.approx(K, rel=1e-9)
        assert m.report["loss"] >= free.report["loss"] * (1 - 1e-9)
        # the constrained combination has no variance: c·θ is known
        A, F = m.A, m.F
        c = np.concatenate([-K * np.ones(len(A) - 1), np.ones(2)])
        c = np.concatenate([c, np.zeros(m.nc + m.nd), -K * np.ones(len(F) - 1)])
        assert c @ m.covariance @ c == pytest.approx(0.0, abs=1e-12 * np.trace(m.covariance))
    assert at_truth.report["loss"] < free.report["loss"] * 1.01  # the truth costs ~nothing
    assert off.report["loss"] > free.report["loss"] * 1.05  # a wrong gain costs much


def test_constrained_oe_standard_deviations_match_the_spread_over_seeds():
    fits = [oe(_oe_data(seed, n=400), 2, 2, 1, dc_gain=K_TRUE) for seed in range(100)]
    spread = np.std([m.parameters for m in fits], axis=0, ddof=1)
    reported = np.mean([m.parameter_std for m in fits], axis=0)
    np.testing.assert_allclose(reported, spread, rtol=0.2)


@settings(max_examples=30, deadline=None)
@given(st.floats(-5.0, 5.0).filter(lambda k: abs(k) > 1e-3), st.integers(0, 2**16))
def test_any_imposed_gain_is_met_exactly_by_arx(K, seed):
    data = _arx_data(seed, n=120)
    m = arx(data, 2, 2, 1, dc_gain=K)
    assert np.sum(m.B) == pytest.approx(K * np.sum(m.A), rel=1e-9, abs=1e-12)


def test_bad_gain_requests_are_clear_errors():
    data = _arx_data(0, n=100)
    with pytest.raises(DataError, match="finite"):
        arx(data, 2, 2, 1, dc_gain=float("nan"))
    two = IOData(np.column_stack([data.u[:, 0], data.u[::-1, 0]]), data.y, 1.0)
    with pytest.raises(DataError, match="one input"):
        arx(two, 2, [2, 2], [1, 1], dc_gain=1.0)
    with pytest.raises(DataError, match="one input"):
        oe(two, 2, 2, 1, dc_gain=1.0)


def test_the_study_prefers_a_free_model_whose_gain_agrees_and_says_when_it_imposed_one():
    steady = {"gain": 1.0, "holds": 21}
    anchor = {"gain": 1.001, "gain_std": 0.002, "holds": 14}
    rows = [
        {"structure": "ARX221", "n_params": 4, "fit_percent": 70.6,
         "dc_gain": 0.92, "dc_gain_error_percent": -8.0},
        {"structure": "ARX221+K", "n_params": 4, "fit_percent": 70.5, "gain_constrained": True,
         "dc_gain": 1.001, "dc_gain_error_percent": 0.1},
        {"structure": "OE221", "n_params": 4, "fit_percent": 71.9,
         "dc_gain": 0.996, "dc_gain_error_percent": -0.4},
    ]  # fmt: skip
    pick, why = _choose(rows, 3.0, 0.02, steady, anchor)
    assert pick["structure"] == "ARX221+K"
    assert "static gain constrained to K = 1.0010 ± 0.0020 measured on 14 settled holds" in why
    assert "unconstrained twin ARX221 fits 70.60 %" in why and "costs 0.10 points" in why
    rows[0] = {**rows[0], "dc_gain": 0.99, "dc_gain_error_percent": -1.0}
    pick, why = _choose(rows, 3.0, 0.02, steady, anchor)
    assert pick["structure"] == "ARX221" and "constrained to" not in why


def test_the_study_imposes_the_gain_of_the_estimation_part_only():
    """Holds whose settled gain is 1.0 before the split and 1.1 after it: the imposed K is
    the estimation part's (the validation part must not inform the model)."""
    rng = np.random.default_rng(4)
    Ts, hold, n = 0.5, 80, 2400
    u = np.repeat(rng.uniform(-3000, 3000, n // hold), hold)
    gain = np.where(np.arange(n) < 0.7 * n, 1.0, 1.1)
    y = lfilter([0.2], [1.0, -0.8], gain * u) + rng.normal(0, 2.0, n)
    study = identification_study(IOData(u, y, Ts), nonlinear=False)
    k = study.gain_constraint
    assert k["gain"] == pytest.approx(1.0, abs=3 * k["gain_std"] + 1e-3)
    assert k["holds"] >= 15 and k["part"] == "estimation"
    whole = study.steady_state["gain"]
    assert whole > 1.01  # the whole record's gain is pulled up by the validation part
    for r in study.constrained:
        assert r["dc_gain"] == pytest.approx(k["gain"], rel=1e-9)


def test_the_study_says_when_its_validation_part_swings_wider_than_its_estimation_part():
    """Steps twice as large after the split through a rate limit: the same model fits the
    validation part worse, and the study measures why (independent of the model)."""
    rng = np.random.default_rng(2)
    n, hold = 2400, 40
    levels = rng.choice([-1.0, 1.0], n // hold) * np.where(np.arange(n // hold) < 42, 1.0, 2.0)
    u = np.repeat(levels, hold)
    y = np.zeros(n)
    for t in range(1, n):  # first-order lag with a slew limit of 0.3 per sample
        y[t] = y[t - 1] + np.clip(0.2 * (u[t - 1] - y[t - 1]), -0.3, 0.3)
    y += rng.normal(0, 0.002, n)
    est, val = IOData(u[:1680], y[:1680], 1.0), IOData(u[1680:], y[1680:], 1.0)
    parts = _parts(arx(est, 2, 2, 1), est, val)
    e, v = parts["estimation"], parts["validation"]
    assert v["input_step_rms"] / e["input_step_rms"] == pytest.approx(2.0, rel=0.05)
    assert v["fast_share"] > 2 * e["fast_share"]  # more time at the slew limit
    assert e["fit_percent"] - v["fit_percent"] >= 5
    assert "the validation part's input steps are 2.0" in parts["note"]
    alike = _parts(arx(est, 2, 2, 1), est, est)
    assert alike["note"] is None
