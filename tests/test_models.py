import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import DataError, FileFormatError, ModelError
from rwlab.ident import PolyModel, c2d

PAPER_A = [1, -1.758, 0.7852]
PAPER_B = [0, 0.0275, -0.0012]


def test_paper_arx221_tustin_at_1s_reproduces_equation_14():
    g = PolyModel(PAPER_A, PAPER_B, Ts=1.0).d2c("tustin")
    num, den = g.num[0][0], g.den[0][0]
    # paper A, eq. 14: (−0.0081 s² + 0.00135 s + 0.02969) / (s² + 0.2425 s + 0.03071),
    # compared to the digits the paper prints
    printed = [
        (num[0], -0.0081, 4),
        (num[1], 0.00135, 5),
        (num[2], 0.02969, 5),
        (den[0], 1.0, 4),
        (den[1], 0.2425, 4),
        (den[2], 0.03071, 5),
    ]
    for value, paper, decimals in printed:
        assert abs(value - paper) <= 0.5 * 10.0**-decimals + 1e-12, (value, paper)


def test_paper_model_at_the_real_half_second_differs_from_equation_14():
    g = PolyModel(PAPER_A, PAPER_B, Ts=0.5).d2c("tustin")
    assert g.den[0][0][1] == pytest.approx(2 * 0.2425, rel=1e-3)  # poles scale with 1/Ts


def test_zoh_d2c_then_c2d_returns_the_original_model():
    m = PolyModel(PAPER_A, PAPER_B, Ts=0.5)
    back = c2d(m.d2c("zoh"), 0.5, "zoh")
    assert np.allclose(back.A, m.A, atol=1e-10) and np.allclose(back.B, m.B, atol=1e-10)
    assert back.nk == (1,)


def test_zoh_d2c_of_a_sampled_first_order_lag_is_that_lag():
    K, tau, Ts = 2.0, 3.0, 0.5
    a = np.exp(-Ts / tau)
    g = PolyModel([1, -a], [0, K * (1 - a)], Ts=Ts).d2c("zoh")
    assert np.allclose(g.num[0][0] / g.den[0][0][0], [K / tau])
    assert np.allclose(g.den[0][0] / g.den[0][0][0], [1, 1 / tau])


@settings(max_examples=25, deadline=None)
@given(
    r=st.floats(0.05, 0.95),
    th=st.floats(0.05, 2.5),
    b1=st.floats(0.05, 2),
    b2=st.floats(-2, 2),
    Ts=st.floats(0.01, 5),
)
def test_zoh_round_trip_holds_for_stable_second_order_models(r, th, b1, b2, Ts):
    A = [1, -2 * r * np.cos(th), r * r]
    m = PolyModel(A, [0, b1, b2], Ts=Ts)
    back = c2d(m.d2c("zoh"), Ts, "zoh")
    assert np.allclose(back.A, m.A, atol=1e-8)
    assert np.allclose(back.B, m.B, atol=1e-8 * max(1, abs(b1) + abs(b2)))


def test_d2c_with_extra_delay_needs_a_pade_order():
    m = PolyModel([1, -0.9], [0, 0, 0, 0.1], Ts=0.1)
    assert m.input_delay_s == pytest.approx(0.2)
    with pytest.raises(ModelError, match="pade_order"):
        m.d2c("zoh")
    g = m.d2c("zoh", pade_order=3)
    assert control.dcgain(g) == pytest.approx(m.dc_gain(), rel=1e-9)
    assert control.dcgain(m.d2c("tustin")) == pytest.approx(m.dc_gain(), rel=1e-9)


def test_zoh_is_refused_for_a_pole_on_the_negative_real_axis():
    with pytest.raises(ModelError, match="tustin"):
        PolyModel([1, 0.5], [0, 1], Ts=1.0).d2c("zoh")


def test_simulate_matches_a_direct_filter_and_leaves_input_alone(rng):
    m = PolyModel([1, -1.5, 0.7], [0, 1, 0.5], F=[1, -0.2], Ts=0.1)
    u = rng.standard_normal(300)
    u0 = u.copy()
    y = m.simulate(u)
    assert np.allclose(y, lfilter([0, 1, 0.5], np.convolve([1, -1.5, 0.7], [1, -0.2]), u))
    assert np.array_equal(u, u0)


def test_k_step_prediction_of_an_ar1_process_is_a_to_the_k():
    a = 0.8
    m = PolyModel([1, -a], [0, 0], Ts=1.0)
    y = np.random.default_rng(0).standard_normal(200)
    data = IOData(np.zeros(200), y, 1.0)
    for k in (1, 2, 5):
        expected = np.concatenate([np.zeros(k), a**k * y[:-k]])
        assert np.allclose(m.predict(data, k), expected)


def test_prediction_of_an_output_error_model_is_its_simulation(rng):
    m = PolyModel(None, [0, 1, 0.5], F=[1, -0.8], Ts=1.0)
    u = rng.standard_normal(100)
    data = IOData(u, rng.standard_normal(100), 1.0)
    for k in (1, 3, np.inf):
        assert np.allclose(m.predict(data, k), m.simulate(u))


def test_frequency_response_dc_gain_and_poles_agree_with_python_control():
    m = PolyModel(PAPER_A, PAPER_B, C=[1, 0.3], Ts=0.5)
    w = np.array([0.01, 0.3, 2.0])
    tf = m.to_tf()
    assert tf.dt == 0.5
    assert np.allclose(m.frequency_response(w), tf(np.exp(1j * w * 0.5)).ravel())
    assert m.dc_gain() == pytest.approx(control.dcgain(tf))
    assert m.step_response(2000)[-1] == pytest.approx(m.dc_gain(), rel=1e-6)
    assert np.allclose(np.sort_complex(m.poles()), np.sort_complex(control.poles(m.to_ss())))
    assert m.is_stable()
    assert not PolyModel([1, -1.1], [0, 1], Ts=1).is_stable()


coef = st.floats(-5, 5, allow_nan=False)


@settings(max_examples=40, deadline=None)
@given(
    a=st.lists(coef, max_size=4),
    b=st.lists(coef, min_size=1, max_size=4),
    c=st.lists(coef, max_size=2),
    f=st.lists(coef, max_size=2),
    nk=st.integers(0, 3),
    Ts=st.floats(1e-3, 100),
)
def test_json_round_trip_is_lossless(tmp_path_factory, a, b, c, f, nk, Ts):
    if b[0] == 0:
        b[0] = 1.0
    m = PolyModel(
        [1, *a],
        [0] * nk + b,
        C=[1, *c],
        F=[1, *f],
        Ts=Ts,
        noise_variance=0.5,
        report={"method": "test"},
    )
    path = m.save(tmp_path_factory.mktemp("m") / "model.json")
    back = PolyModel.load(path)
    for name in "ABCDF":
        assert np.array_equal(getattr(back, name), getattr(m, name))
    assert back.Ts == m.Ts and back.nk == m.nk and back.structure == m.structure


def test_model_files_are_checked(tmp_path):
    p = tmp_path / "m.json"
    p.write_text('{"format": "something else"}')
    with pytest.raises(FileFormatError):
        PolyModel.load(p)
    p.write_text("{not json")
    with pytest.raises(FileFormatError):
        PolyModel.load(p)
    m = PolyModel([1, -0.5], [0, 1], Ts=1.0)
    m.save(tmp_path / "x.json")
    with pytest.raises(FileExistsError):
        m.save(tmp_path / "x.json")


def test_malformed_models_are_refused():
    with pytest.raises(ModelError, match="monic"):
        PolyModel([2, 1], [0, 1], Ts=1)
    with pytest.raises(ModelError, match="nk"):
        PolyModel([1], [1, 1], Ts=1, nk=1)
    with pytest.raises(DataError):
        PolyModel([1], [0, 1], Ts=None)
    with pytest.raises(ModelError):
        PolyModel([1], [0, 1], Ts=1, covariance=np.eye(3))


def test_printout_names_the_structure_and_uncertainty():
    m = PolyModel(PAPER_A, PAPER_B, Ts=0.5, covariance=np.diag([1e-4, 1e-4, 4e-6, 4e-6]))
    text = str(m)
    assert "ARX221" in text and "(+/- 0.01)" in text and "- 1.758" in text


def test_padded_multi_input_model_keeps_its_orders_through_json(tmp_path):
    B = [[0, 1.0, 0.5, 0], [0, 0, 0.3, 0.2]]  # nb = [2, 2], nk = [1, 2]: row 1 padded
    m = PolyModel([1, -0.5], B, Ts=1.0, nb=[2, 2], covariance=np.eye(5))
    back = PolyModel.load(m.save(tmp_path / "m.json"))
    assert back.nb == (2, 2) and back.nk == (1, 2) and back.n_params == 5
    with pytest.raises(ModelError, match="end with zeros"):
        PolyModel([1], [[0, 1.0, 0.5], [0, 1.0, 0.0]], Ts=1.0, nb=[1, 1])
