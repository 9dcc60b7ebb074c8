import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import DataError
from rwlab.ident import arx, compare, fit_percent, fpe, mse, resid


def test_fit_percent_is_matlabs_nrmse():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full(4, y.mean())) == pytest.approx(0.0)
    yhat = y + np.array([0.1, -0.1, 0.2, 0.0])
    expected = 100 * (1 - np.sqrt(0.06) / np.sqrt(5.0))
    assert fit_percent(y, yhat) == pytest.approx(expected)
    with pytest.raises(DataError):
        fit_percent(np.ones(3), np.ones(3))


def test_mse_and_fpe_formulas():
    assert mse([1, 2, 3], [1, 2, 5]) == pytest.approx(4 / 3)
    assert fpe(2.0, 4, 100) == pytest.approx(2.0 * 1.04 / 0.96)


def test_resid_calls_the_true_model_white_and_an_underfit_model_coloured(arx_system):
    _A, _B, data = arx_system
    est, val = data.split(0.5)
    good = resid(arx(est, 2, 2, 1), val)
    assert good.white and good.independent
    assert good.acf[0] == pytest.approx(1.0)
    assert good.acf_bound == pytest.approx(2.5758 / np.sqrt(val.N), rel=1e-4)
    bad = resid(arx(est, 1, 1, 1), val)
    assert not bad.white


def test_resid_detects_unmodelled_input_dynamics(rng):
    u = rng.standard_normal(3000)
    y = lfilter([0, 1.0], [1, -0.5], u) + lfilter([0, 0, 0, 0, 0.8], [1], u)
    y = y + 0.05 * rng.standard_normal(3000)
    data = IOData(u, y, 1.0)
    r = resid(arx(data, 1, 1, 1), data)
    assert not r.independent
    assert np.max(np.abs(r.ccf)) > r.ccf_bound


def test_compare_simulates_by_default_and_predicts_on_request(arx_system):
    _, _, data = arx_system
    m = arx(data, 2, 2, 1)
    sim = compare(m, data)
    one = compare(m, data, horizon=1)
    assert np.allclose(sim.yhat, m.simulate(data, initial="estimate"))
    assert np.allclose(one.yhat, m.predict(data, 1, initial="estimate"))
    assert one.fit_percent > sim.fit_percent  # prediction uses measured outputs


def test_estimation_report_has_matlabs_fields(arx_system):
    _, _, data = arx_system
    rep = arx(data, 2, 2, 1).report
    for key in ("fit_percent", "mse", "fpe", "aic", "naic", "bic", "loss", "n_params"):
        assert key in rep
    N, d, V = rep["n_samples"], rep["n_params"], rep["loss"]
    assert rep["naic"] == pytest.approx(np.log(V) + 2 * d / N)
    assert rep["fpe"] == pytest.approx(V * (1 + d / N) / (1 - d / N))


def _reference_estimated_simulation(model, data):
    """Independent reference for MATLAB's 'e': a state-space realisation of B/(A F) by scipy,
    its zero-state response, and the initial state x0 fitted by least squares."""
    from scipy import signal as sps

    den = np.convolve(model.A, model.F)
    n = max(len(den), len(model.B))
    num_z = np.pad(model.B, (0, n - len(model.B)))
    den_z = np.pad(den, (0, n - len(den)))
    ss = sps.StateSpace(*sps.tf2ss(num_z, den_z), dt=data.Ts)
    u = data.u[:, 0]
    forced = sps.dlsim(ss, u)[1][:, 0]
    basis = np.column_stack(
        [sps.dlsim(ss, np.zeros_like(u), x0=np.eye(n - 1)[i])[1][:, 0] for i in range(n - 1)]
    )
    x0 = np.linalg.lstsq(basis, data.y[:, 0] - forced, rcond=None)[0]
    return forced + basis @ x0


def test_compare_estimates_the_initial_state_by_default_like_matlab():
    """MATLAB's dryer example: ARX(2,2,3) on samples 1:300, validated on 800:900 (detrended).
    compare's default ('e') must equal the least-squares initial state of a scipy realisation,
    and beat zero initial conditions."""
    from rwlab import datasets

    z = datasets.dryer()
    est, val = z[0:300].detrend(), z[799:900].detrend()
    m = arx(est, 2, [2], [3])
    default = compare(m, val)
    assert np.allclose(default.yhat, _reference_estimated_simulation(m, val), atol=1e-8)
    assert default.fit_percent == compare(m, val, initial="estimate").fit_percent
    assert default.fit_percent > compare(m, val, initial="zero").fit_percent + 10


def test_estimated_initial_state_removes_any_start_up_transient_exactly(rng):
    """Noise-free ARMAX data that start in an unknown state: with 'estimate' the one-step
    prediction and the simulation are exact; with zero initial conditions they are not."""
    from rwlab.ident import PolyModel

    A, B, C = [1, -1.5, 0.7], [0, 1.0, 0.5], [1, -0.5]
    u = rng.standard_normal(400)
    x_past = rng.standard_normal(2) * 5  # y(−1), y(−2): a state the data do not show
    zi = lfilter_zi_from_past(A, B, x_past)
    y = lfilter(B, A, u, zi=zi)[0]
    data = IOData(u, y, 1.0)
    m = PolyModel(A, B, C=C, Ts=1.0)
    for horizon in (1, 3, np.inf):
        assert np.allclose(m.predict(data, horizon, initial="estimate"), y, atol=1e-9)
        assert not np.allclose(m.predict(data, horizon, initial="zero"), y, atol=1e-3)


def lfilter_zi_from_past(A, B, y_past):
    """Transposed-direct-form state of B/A for past outputs y(−1), y(−2) and zero past inputs."""
    from scipy.signal import lfiltic

    return lfiltic(B, A, y_past)


def test_simulate_with_estimate_needs_the_measured_output(arx_system):
    _, _, data = arx_system
    m = arx(data, 2, 2, 1)
    with pytest.raises(DataError, match="measured output"):
        m.simulate(data.u, initial="estimate")
    with pytest.raises(DataError, match="initial must be"):
        compare(m, data, initial="backcast")


def _coloured_input_run(seed, N=1000, pole=0.9):
    r = np.random.default_rng(seed)
    u = lfilter([1], [1, -pole], r.standard_normal(N))
    y = lfilter([0, 1.0, 0.5], [1, -1.5, 0.7], u) + lfilter(
        [1], [1, -1.5, 0.7], r.standard_normal(N)
    )
    return IOData(u, y, 1.0)


def test_independence_test_holds_its_level_with_a_coloured_input():
    """The true model's residuals are independent of the input by construction: at 99 %
    confidence the test may reject them in about 1 % of runs (≤ 3 % of 200 allowed), even
    with a strongly coloured (AR(1), pole 0.9) input. A model with a 10 % gain error must be
    rejected nearly always."""
    from rwlab.ident import PolyModel

    true = PolyModel([1, -1.5, 0.7], [0, 1.0, 0.5], Ts=1.0)
    wrong = PolyModel([1, -1.5, 0.7], [0, 0.9, 0.45], Ts=1.0)
    runs = [_coloured_input_run(seed) for seed in range(200)]
    rejected = np.mean([not resid(true, d).independent for d in runs])
    assert rejected <= 0.03
    assert np.mean([not resid(wrong, d).independent for d in runs[:50]]) >= 0.9
