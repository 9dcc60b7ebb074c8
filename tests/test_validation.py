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
    assert np.allclose(sim.yhat, m.simulate(data))
    assert np.allclose(one.yhat, m.predict(data, 1))
    assert one.fit_percent > sim.fit_percent  # prediction uses measured outputs


def test_estimation_report_has_matlabs_fields(arx_system):
    _, _, data = arx_system
    rep = arx(data, 2, 2, 1).report
    for key in ("fit_percent", "mse", "fpe", "aic", "naic", "bic", "loss", "n_params"):
        assert key in rep
    N, d, V = rep["n_samples"], rep["n_params"], rep["loss"]
    assert rep["naic"] == pytest.approx(np.log(V) + 2 * d / N)
    assert rep["fpe"] == pytest.approx(V * (1 + d / N) / (1 - d / N))
