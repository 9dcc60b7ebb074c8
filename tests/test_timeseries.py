"""Time-series models (no input): ar, AR by arx, ARMA by armax; simulate/predict/compare/resid."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares
from scipy.signal import lfilter

from rwlab.data import IOData, merge
from rwlab.errors import DataError
from rwlab.ident import PolyModel, ar, armax, arx, compare, fit_percent, resid

A2 = np.array([1, -1.5, 0.7])  # AR(2): poles 0.84∠±27°
C1 = np.array([1, 0.5])


def _series(A, C, N, seed, sigma=1.0):
    e = sigma * np.random.default_rng(seed).standard_normal(N + 500)
    return IOData(None, lfilter(C, A, e)[500:], 0.5)  # 500 samples of burn-in: stationary


def _fb_reference(y, na, approach):
    """Independent: every forward (and backward) equation written out sample by sample."""
    rows, target = [], []
    for t in range(na, len(y)):
        rows.append([-y[t - i] for i in range(1, na + 1)])
        target.append(y[t])
        if approach == "fb":
            s = len(y) - 1 - t  # backward: y(s) + a1 y(s+1) + ... = e_b(s), s = 0..N-1-na
            rows.append([-y[s + i] for i in range(1, na + 1)])
            target.append(y[s])
    return np.linalg.lstsq(np.array(rows), np.array(target), rcond=None)[0]


def test_time_series_records_have_no_input():
    d = IOData(None, np.arange(5.0), 1.0)
    assert d.nu == 0 and d.u.shape == (5, 0) and d.input_names == ()
    assert IOData(np.zeros((5, 0)), np.arange(5.0), 1.0).nu == 0
    assert d.detrend().nu == 0 and d[1:4].N == 3


@pytest.mark.parametrize("approach", ["fb", "ls"])
def test_noise_free_sinusoid_gives_its_exact_ar2(approach):
    """y = sin(ωt + φ) satisfies y(t) − 2cos ω y(t−1) + y(t−2) = 0 exactly, forwards and
    backwards."""
    w = 0.3
    y = np.sin(w * np.arange(80) + 0.2)
    m = ar(IOData(None, y, 0.1), 2, approach)
    assert np.allclose(m.A, [1, -2 * np.cos(w), 1], atol=1e-10)
    assert m.nu == 0 and m.structure == "AR2" and m.noise_variance < 1e-20


@pytest.mark.parametrize("approach", ["fb", "ls"])
def test_ar_equals_an_independent_least_squares(approach):
    y = _series(A2, [1], 300, seed=1).y[:, 0]
    m = ar(IOData(None, y, 1.0), 3, approach)
    assert np.allclose(m.parameters, _fb_reference(y, 3, approach), atol=1e-10)


def test_long_ar2_recovers_the_truth_and_both_approaches_agree():
    data = _series(A2, [1], 50_000, seed=2, sigma=0.5)
    fb, ls = ar(data, 2), ar(data, 2, "ls")
    for m in (fb, ls):
        assert np.all(np.abs(m.parameters - A2[1:]) <= 4 * m.parameter_std)
        assert m.noise_variance == pytest.approx(0.25, rel=0.02)
    assert np.all(np.abs(fb.parameters - ls.parameters) <= 0.1 * ls.parameter_std)
    assert fb.report["approach"] == "fb" and ls.report["approach"] == "ls"


def test_reported_ar_covariance_matches_the_spread_over_seeds():
    est, std = [], []
    for seed in range(150):
        m = ar(_series(A2, [1], 400, seed=100 + seed), 2)
        est.append(m.parameters)
        std.append(m.parameter_std)
    assert np.allclose(np.mean(std, axis=0), np.std(est, axis=0), rtol=0.2)


def test_arx_without_input_is_forward_least_squares_ar():
    data = _series(A2, [1], 500, seed=3)
    assert np.allclose(arx(data, 2).parameters, ar(data, 2, "ls").parameters, atol=1e-12)
    assert np.allclose(arx(data, 2).covariance, ar(data, 2, "ls").covariance, rtol=1e-10)
    with pytest.raises(DataError, match="no input"):
        arx(data, 2, 2, 1)


def test_merged_time_series_are_estimated_jointly():
    parts = [_series(A2, [1], 3000, seed=s) for s in (4, 5)]
    m = ar(merge(*parts), 2)
    y = [p.y[:, 0] for p in parts]
    rows = [np.column_stack([-v[1:-1], -v[:-2]]) for v in y]
    back = [np.column_stack([-v[1:-1], -v[2:]]) for v in y]
    ref = np.linalg.lstsq(
        np.vstack(rows + back), np.concatenate([v[2:] for v in y] + [v[:-2] for v in y]), rcond=None
    )[0]
    assert np.allclose(m.parameters, ref, atol=1e-10)


def test_arma21_by_armax_recovers_the_truth_and_the_prediction_error_optimum():
    data = _series(A2, C1, 20_000, seed=6)
    m = armax(data, 2, nc=1)
    truth = np.concatenate([A2[1:], C1[1:]])
    assert m.structure == "ARMA21" and m.nu == 0
    assert np.all(np.abs(m.parameters - truth) <= 4 * m.parameter_std)
    assert m.noise_variance == pytest.approx(1.0, rel=0.03)
    y = data.y[:, 0]
    ref = least_squares(lambda th: lfilter([1, *th[:2]], [1, th[2]], y), truth, method="lm").x
    assert np.allclose(m.parameters, ref, atol=1e-5)
    assert armax(data, 2, [], 1).parameters == pytest.approx(m.parameters)


def test_ar_refuses_bad_input():
    y = np.random.default_rng(7).standard_normal(100)
    with pytest.raises(DataError, match="time series"):
        ar(IOData(y, y, 1.0), 2)
    with pytest.raises(DataError, match="approach"):
        ar(IOData(None, y, 1.0), 2, "burg")
    with pytest.raises(DataError, match="too few samples"):
        ar(IOData(None, y[:6], 1.0), 3)
    with pytest.raises(DataError, match="nc"):
        armax(IOData(None, y, 1.0), 2)


def test_time_series_simulates_to_zero_and_predicts_from_its_past():
    data = _series(A2, [1], 400, seed=8)
    y = data.y[:, 0]
    m = PolyModel(A2, None, Ts=data.Ts)
    assert np.array_equal(m.simulate(data), np.zeros(400))
    one = m.predict(data, 1)
    assert np.allclose(one[2:], 1.5 * y[1:-1] - 0.7 * y[:-2], atol=1e-12)
    two = m.predict(data, 2)  # ŷ(t|t−2) = 1.5 ŷ(t−1|t−2) − 0.7 y(t−2)
    assert np.allclose(two[3:], 1.5 * (1.5 * y[1:-2] - 0.7 * y[:-3]) - 0.7 * y[1:-2], atol=1e-12)


def test_compare_predicts_a_time_series_one_step_ahead_by_default():
    data = _series(A2, [1], 400, seed=9)
    m = ar(data, 2)
    c = compare(m, data)
    assert c.horizon == 1
    assert c.fit_percent == pytest.approx(fit_percent(data.y[:, 0], m.predict(data, 1, "estimate")))
    assert compare(m, data, 5).fit_percent < c.fit_percent


def test_resid_of_a_time_series_tests_whiteness_only():
    data = _series(A2, C1, 3000, seed=10)
    good, under = armax(data, 2, nc=1), ar(data, 1)
    r = resid(good, data)
    assert r.white and r.independent and r.ccf.size == 0 and np.isnan(r.independence_p)
    assert not resid(under, data).white


@settings(max_examples=20, deadline=None)
@given(a1=st.floats(-0.9, 0.9), c1=st.floats(-0.9, 0.9), nc=st.integers(0, 1))
def test_time_series_models_survive_json(tmp_path_factory, a1, c1, nc):
    m = PolyModel([1, a1], None, C=[1, c1][: nc + 1], Ts=0.2, noise_variance=0.3)
    back = PolyModel.load(m.save(tmp_path_factory.mktemp("ts") / "m.json"))
    assert back.nu == 0 and back.structure == m.structure
    assert np.array_equal(back.A, m.A) and np.array_equal(back.C, m.C)
