"""compare, resid and predict on every model class; resid's verdicts against known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.ident import PolyModel, SSModel, compare, impulseest, n4sid, resid, ssest
from tests.test_statespace import innovations_data


@pytest.fixture(scope="module")
def two_output():
    return innovations_data(1500, seed=4)


@pytest.fixture(scope="module")
def one_output():
    d = innovations_data(1500, seed=5)
    return IOData(d.u, d.y[:, 0], d.Ts)


@pytest.mark.parametrize("estimator", [n4sid, ssest])
@pytest.mark.parametrize("outputs", ["one_output", "two_output"])
def test_compare_and_resid_run_on_state_space_models(estimator, outputs, request):
    data = request.getfixturevalue(outputs)
    model = estimator(data, 4)
    c = compare(model, data)
    fits = np.atleast_1d(c.fit_percent)
    assert fits.shape == (data.ny,) and np.all(fits > 50)
    assert c.yhat.shape == c.y.shape
    one_step = np.atleast_1d(compare(model, data, horizon=1).fit_percent)
    assert np.all(one_step >= fits - 1e-9)  # the Kalman predictor uses the measured outputs
    r = resid(model, data)
    assert r.acf_all.shape == (26, data.ny) and r.ccf_all.shape == (51, data.ny, 2)
    assert r.white and r.independent  # the right order on its own data


def test_state_space_k_step_prediction_equals_the_polynomial_form():
    # an ARMAX y = 0.5q⁻¹/(1 − 0.8q⁻¹) u + (1 + 0.6q⁻¹)/(1 − 0.8q⁻¹) e in innovations form:
    # x⁺ = 0.8x + 0.5u + (0.6 + 0.8)e, y = x + e (K = c₁ − a₁)
    ss = SSModel([[0.8]], [[0.5]], [[1.0]], K=[[1.4]], Ts=1.0)
    poly = PolyModel([1, -0.8], [0, 0.5], [1, 0.6], Ts=1.0)
    r = np.random.default_rng(0)
    u = r.standard_normal(300)
    y = lfilter([0, 0.5], [1, -0.8], u) + lfilter([1, 0.6], [1, -0.8], 0.3 * r.standard_normal(300))
    data = IOData(u, y, 1.0)
    for k in (1, 2, 5, np.inf):
        np.testing.assert_allclose(ss.predict(data, k)[:, 0], poly.predict(data, k), atol=1e-10)


def test_fir_model_predicts_by_simulating_and_compare_runs_on_it():
    r = np.random.default_rng(1)
    u = r.standard_normal(800)
    h = 0.5 * 0.7 ** np.arange(20)
    y = lfilter(np.concatenate([[0], h]), [1.0], u) + 0.01 * r.standard_normal(800)
    data = IOData(u, y, 1.0)
    fir = impulseest(data, 30, nk=1)
    np.testing.assert_allclose(fir.predict(data, 3), fir.predict(data, np.inf))
    assert compare(fir, data, initial="zero").fit_percent > 98
    assert resid(fir, data).independent


def _two_input_record(seed: int, N: int = 400) -> tuple[IOData, PolyModel, PolyModel]:
    r = np.random.default_rng(seed)
    u = r.standard_normal((N, 2))
    B = np.array([[0, 1.0], [0, 0.4]])
    F = np.array([[1, -0.5], [1, -0.7]])
    y = sum(lfilter(B[j], F[j], u[:, j]) for j in range(2)) + 0.5 * r.standard_normal(N)
    true = PolyModel([1.0], B, F=F, Ts=1.0, nk=[1, 1])
    wrong = PolyModel([1.0], B * np.array([[1.0], [0.5]]), F=F, Ts=1.0, nk=[1, 1])
    return IOData(u, y, 1.0), true, wrong


def test_resid_tests_every_input_and_rejects_a_halved_second_gain():
    rejected = first_input_only = true_rejected = 0
    for seed in range(100):
        data, true, wrong = _two_input_record(seed)
        r = resid(wrong, data)
        rejected += not r.independent
        first_input_only += r.input_p[0] < 0.01  # what a first-input test would have seen
        true_rejected += not resid(true, data).independent
    assert rejected >= 90
    assert first_input_only <= 5  # input 1's model is right: the error lives on input 2
    assert true_rejected <= 5


def _closed_loop(seed: int, N: int = 500) -> IOData:
    """y = 0.5q⁻¹/(1 − 0.9q⁻¹) u + 1/(1 − 0.9q⁻¹) e (ARX) under u(t) = r(t) − 0.8 y(t)."""
    g = np.random.default_rng(seed)
    ref = g.standard_normal(N)
    e = 0.5 * g.standard_normal(N)
    y, u = np.zeros(N), np.zeros(N)
    for t in range(N):
        y[t] = (0.9 * y[t - 1] + 0.5 * u[t - 1] if t else 0.0) + e[t]
        u[t] = ref[t] - 0.8 * y[t]
    return IOData(u, y, 1.0)


def test_resid_accepts_the_true_model_on_closed_loop_data_and_reports_the_feedback():
    true = PolyModel([1, -0.9], [0, 0.5], Ts=1.0)
    rejected = feedback = 0
    for seed in range(100):
        r = resid(true, _closed_loop(seed))
        rejected += not r.independent
        feedback += r.feedback
    assert rejected <= 5
    assert feedback >= 90  # the residual leads the input: reported, apart from the verdict


def _integrator(seed: int) -> IOData:
    r = np.random.default_rng(seed)
    u = r.standard_normal(400)
    return IOData(u, lfilter([0, 0.1], [1, -1.0], u) + 0.05 * r.standard_normal(400), 1.0)


def test_n4sid_warns_on_an_unstable_estimate_and_can_enforce_stability():
    from rwlab.errors import RwlabWarning

    data = _integrator(1)  # a true pole at z = 1: noise puts the estimate just outside
    with pytest.warns(RwlabWarning, match="unstable"):
        free = n4sid(data, 2)
    assert not free.is_stable() and not free.report["stability"]["stable"]
    stable = n4sid(data, 2, enforce_stability=True)
    assert stable.is_stable() and stable.report["stability"]["enforced"]
    # B re-fitted with the reflected A: the simulation is as good as the unstable model's
    fit = compare(stable, data).fit_percent
    assert fit > 90 and fit > compare(free, data).fit_percent - 2


def test_ssarx_weighting_is_consistent_on_closed_loop_data_where_cva_is_not():
    data = _closed_loop(0, 2000)  # true pole 0.9, gain b = 0.5
    cva = n4sid(data, 1)
    ssarx = n4sid(data, 1, weighting="SSARX")
    assert abs(ssarx.poles()[0] - 0.9) < 0.03
    assert abs(cva.poles()[0] - 0.9) > 3 * abs(ssarx.poles()[0] - 0.9)
    assert abs(float(ssarx.C[0, 0] * ssarx.B[0, 0]) - 0.5) < 0.05
