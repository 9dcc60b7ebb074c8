import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab import datasets
from rwlab.data import IOData, merge
from rwlab.errors import DataError, EstimationError, RwlabWarning
from rwlab.ident import PolyModel, armax, arx, bj, oe, pem
from rwlab.ident.pem import Orders, _jacobian_block, _signals
from rwlab.ident.polynomials import is_stable

# Truths: (A, B, C, D, F), orders for the estimator, estimator
ARMAX = ([1, -1.5, 0.7], [0, 1.0, 0.5], [1, -0.5], [1], [1])
OE = ([1], [0, 1.0, 0.5], [1], [1], [1, -1.2, 0.5])
BJ = ([1], [0, 1.0, 0.5], [1, 0.4], [1, -0.9], [1, -0.8])


def _simulate(truth, N, seed, sigma=0.3):
    A, B, C, D, F = truth
    r = np.random.default_rng(seed)
    u = r.standard_normal(N)
    e = sigma * r.standard_normal(N)
    y = lfilter(B, np.convolve(A, F), u) + lfilter(C, np.convolve(A, D), e)
    return IOData(u, y, 0.5)


def _fit(kind, data):
    if kind == "armax":
        return armax(data, 2, 2, 1, 1)
    if kind == "oe":
        return oe(data, 2, 2, 1)
    return bj(data, 2, 1, 1, 1, 1)


TRUTH = {"armax": ARMAX, "oe": OE, "bj": BJ}


def _true_params(kind):
    A, B, C, D, F = TRUTH[kind]
    return np.concatenate([A[1:], B[1:], C[1:], D[1:], F[1:]])


def _dynamics(m):
    """The input-output parameters a, b, f (the noise parameters c, d excluded)."""
    return np.concatenate([m.A[1:], m.B[1:], m.F[1:]])


def _true_dynamics(kind):
    A, B, _, _, F = TRUTH[kind]
    return np.concatenate([A[1:], B[1:], F[1:]])


@pytest.mark.parametrize("kind", ["armax", "oe", "bj"])
def test_estimates_converge_to_the_truth_with_little_noise(kind):
    m = _fit(kind, _simulate(TRUTH[kind], 3000, seed=1, sigma=1e-3))
    assert np.allclose(_dynamics(m), _true_dynamics(kind), atol=2e-4)
    # noise-model precision does not improve with less noise: judge it by its own σ
    assert np.all(np.abs(m.parameters - _true_params(kind)) <= 4 * m.parameter_std)
    assert m.report["termination"].startswith("converged")


@pytest.mark.parametrize("kind", ["armax", "oe", "bj"])
def test_noise_free_data_give_exact_dynamics(kind):
    m = _fit(kind, _simulate(TRUTH[kind], 2000, seed=2, sigma=0.0))
    assert np.allclose(_dynamics(m), _true_dynamics(kind), atol=1e-7)
    assert m.noise_variance < 1e-20


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["armax", "oe", "bj"])
def test_reported_covariance_is_honest_over_100_seeds(kind):
    """Truth inside ±3 reported σ for ≥ 95 % of runs, for every parameter (N = 5000)."""
    truth = _true_params(kind)
    inside = []
    for seed in range(100):
        m = _fit(kind, _simulate(TRUTH[kind], 5000, seed=1000 + seed))
        inside.append(np.abs(m.parameters - truth) <= 3 * m.parameter_std)
    coverage = np.mean(inside, axis=0)
    assert np.all(coverage >= 0.95), coverage


# Free polynomials of each structure, in Orders field order (na, nb, nc, nd, nf).
STRUCTURES = {
    "arx": ("na", "nb"),
    "armax": ("na", "nb", "nc"),
    "oe": ("nb", "nf"),
    "bj": ("nb", "nc", "nd", "nf"),
    "poly": ("na", "nb", "nc", "nd", "nf"),
}


def _orders_with(structure: str, d: int, nk: int, steady: bool) -> Orders:
    """Orders of ``structure`` with exactly d free parameters, spread round-robin (nb ≥ 1)."""
    names = STRUCTURES[structure]
    counts = dict.fromkeys(("na", "nb", "nc", "nd", "nf"), 0)
    for i in range(d):
        counts[names[i % len(names)]] += 1
    if counts["nb"] == 0:  # d smaller than the number of polynomials
        counts[names[(d - 1) % len(names)]] -= 1
        counts["nb"] = 1
    return Orders(**counts, nk=nk, steady=steady)


def _finite_difference_jacobian(orders, theta, y, u, h=1e-6):
    cols = []
    for i in range(orders.d):
        step = np.zeros_like(theta)
        step[i] = h
        plus = _signals(orders, theta + step, y, u)[0]
        minus = _signals(orders, theta - step, y, u)[0]
        cols.append((plus - minus) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("steady", [False, True])
@pytest.mark.parametrize("structure", sorted(STRUCTURES))
@pytest.mark.parametrize("d", range(1, 13))
def test_analytic_jacobian_matches_finite_differences(d, structure, steady):
    """Every column of ψ = ∂ε/∂θ, for every parameter count 1..12: a corrupted column (as an
    in-place ufunc on a strided view produced for d = 8) fails here."""
    orders = _orders_with(structure, d, nk=1 + d % 3, steady=steady)
    assert orders.d == d
    r = np.random.default_rng(d)
    y, u = r.standard_normal(150), r.standard_normal(150)
    theta = 0.3 / np.sqrt(d) * r.standard_normal(d)  # small: every polynomial stays stable
    e, w, v = _signals(orders, theta, y, u)
    psi = _jacobian_block(orders, theta, y, u, e, w, v).T  # returned as ψᵀ, (d, N)
    assert psi.shape == (150, d)
    assert np.allclose(psi, _finite_difference_jacobian(orders, theta, y, u), atol=1e-6)


# Eight free parameters each (the count a numpy ≥ 2.1 strided-ufunc bug once corrupted).
EIGHT = {
    "oe441": (([1], [0, 1.0, 0.6, 0.3, 0.1], [1], [1], [1, -1.2, 0.6, -0.1, 0.05]), (4, 4, 1)),
    "armax3321": (
        ([1, -1.6, 0.9, -0.2], [0, 1.0, 0.5, 0.2], [1, -0.4, 0.2], [1], [1]),
        (3, 3, 2, 1),
    ),
    "bj22221": (
        ([1], [0, 1.0, 0.5], [1, 0.4, 0.2], [1, -0.9, 0.2], [1, -1.2, 0.5]),
        (2, 2, 2, 2, 1),
    ),
}


@pytest.mark.parametrize("name", sorted(EIGHT))
def test_eight_parameter_models_recover_the_truth(name):
    truth, orders = EIGHT[name]
    estimator = {"oe": oe, "armax": armax, "bj": bj}[name.rstrip("0123456789")]
    data = _simulate(truth, 4000, seed=11, sigma=1e-3)
    m = estimator(data, *orders)
    A, B, C, D, F = truth
    expected = np.concatenate([A[1:], B[1:], C[1:], D[1:], F[1:]])
    assert m.n_params == 8
    assert np.allclose(_dynamics(m), np.concatenate([A[1:], B[1:], F[1:]]), atol=1e-3)
    assert np.all(np.abs(m.parameters - expected) <= 5 * m.parameter_std)
    assert m.report["termination"].startswith("converged")


def test_noise_and_denominator_polynomials_come_back_stable():
    data = _simulate(BJ, 1500, seed=4)
    start = PolyModel(None, [0, 1.0, 0.5], C=[1, 2.5], D=[1, -1.8], F=[1, -2.0], Ts=0.5)
    m = pem(data, start)
    assert is_stable(m.C) and is_stable(m.D) and is_stable(m.F)
    assert np.allclose(m.parameters, _true_params("bj"), atol=0.1)


def test_pem_from_an_arx_start_reaches_the_armax_optimum():
    data = _simulate(ARMAX, 3000, seed=5)
    start = arx(data, 2, 2, 1)
    refined = pem(data, PolyModel(start.A, start.B, C=[1, 0.0], Ts=data.Ts))
    direct = armax(data, 2, 2, 1, 1)
    assert np.allclose(refined.parameters, direct.parameters, atol=1e-5)


def test_gas_furnace_box_jenkins_model_matches_the_textbook():
    """Box & Jenkins (1976) Series J: Y = −(0.53 + 0.37B + 0.51B²)/(1 − 0.57B) X(t−3) + N,
    N = a/(1 − 1.53B + 0.63B²)."""
    m = bj(datasets.gas_furnace().detrend(), 3, 0, 2, 1, 3)
    assert np.allclose(m.B, [0, 0, 0, -0.53, -0.37, -0.51], atol=0.03)
    assert np.allclose(m.F, [1, -0.57], atol=0.03)
    assert np.allclose(m.D, [1, -1.53, 0.63], atol=0.03)


def test_merged_experiments_are_estimated_jointly():
    parts = [_simulate(OE, 800, seed=s, sigma=1e-3) for s in (6, 7)]
    m = oe(merge(*parts), 2, 2, 1)
    assert np.allclose(m.parameters, _true_params("oe"), atol=5e-3)


def test_bad_inputs_are_typed_errors(rng):
    with pytest.raises(EstimationError, match="persistently exciting"):
        armax(IOData(np.zeros(200), rng.standard_normal(200), 1.0), 2, 2, 1, 1)
    with pytest.raises(DataError, match="too few samples"):
        bj(IOData(rng.standard_normal(8), rng.standard_normal(8), 1.0), 2, 2, 2, 2, 1)
    with pytest.raises(DataError, match="one value per input"):
        oe(IOData(rng.standard_normal((50, 2)), rng.standard_normal(50), 1.0), [2, 2, 2], 2, 1)
    with pytest.raises(DataError, match="needs an input"):
        oe(IOData(None, rng.standard_normal(50), 1.0), 2, 2, 1)
    with pytest.raises(DataError, match="no input"):
        armax(IOData(None, rng.standard_normal(50), 1.0), 2, 2, 1)
    with pytest.raises(DataError):
        armax(IOData(rng.standard_normal(50), rng.standard_normal(50), 1.0), 2, 0, 1, 1)


def test_cascaded_tanks_output_error_model_simulates_better_than_arx():
    """OE minimises the simulation error, ARX the one-step error: on the tanks benchmark's
    validation record the OE model must simulate better, with a positive (physical) gain."""
    from rwlab.ident import compare

    est, val = datasets.cascaded_tanks()
    m_oe, m_arx = oe(est, 2, 2, 1), arx(est, 2, 2, 1)
    assert m_oe.is_stable() and m_oe.dc_gain() > 0
    assert compare(m_oe, val).fit_percent > compare(m_arx, val).fit_percent > 0


@pytest.mark.parametrize("kind", ["armax", "oe", "bj"])
def test_steady_initial_conditions_fit_offset_data_that_start_at_rest(kind):
    """Data in offset units (like normalised data) that start in equilibrium: the 'steady'
    convention is exact, zero initial conditions are not."""
    A, B, _C, _D, F = TRUTH[kind]
    r = np.random.default_rng(8)
    u0 = 0.5
    u = u0 + r.standard_normal(1500)
    u[:1] = u0
    gain = np.sum(B) / (np.sum(A) * np.sum(F))
    y_dev = lfilter(B, np.convolve(A, F), u - u0)  # deviations from the equilibrium
    data = IOData(u, gain * u0 + y_dev, 1.0)
    est = {
        "armax": lambda i: armax(data, 2, 2, 1, 1, initial=i),
        "oe": lambda i: oe(data, 2, 2, 1, initial=i),
        "bj": lambda i: bj(data, 2, 1, 1, 1, 1, initial=i),
    }[kind]
    steady = est("steady")
    assert np.allclose(_dynamics(steady), _true_dynamics(kind), atol=1e-6)
    assert steady.report["initial_conditions"] == "steady" and steady.report["loss"] < 1e-20
    if kind == "oe":  # without a noise model nothing can absorb the zero-IC transient
        zero = est("zero")
        assert np.max(np.abs(_dynamics(zero) - _true_dynamics(kind))) > 1e-4


def test_stopping_without_converging_warns():
    data = _simulate(OE, 1000, seed=12)
    with pytest.warns(RwlabWarning, match="stopped after 1 iterations"):
        m = oe(data, 2, 2, 1, max_iter=1)
    assert m.report["termination"] == "maximum iterations reached"


def test_noise_free_data_converge_without_warning():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RwlabWarning)
        m = armax(_simulate(ARMAX, 1000, seed=13, sigma=0.0), 2, 2, 1, 1)
    assert m.report["termination"] == "converged (exact fit)"


def test_rwlab_ident_pem_is_a_plain_function_and_the_module_still_imports():
    import inspect
    import sys

    from rwlab import ident

    module = sys.modules["rwlab.ident.pem"]
    assert inspect.isfunction(ident.pem) and ident.pem is module.pem
    assert module.armax is armax  # from rwlab.ident.pem import armax still works
    data = _simulate(ARMAX, 800, seed=14)
    start = PolyModel([1, -1.4, 0.6], [0, 0.9, 0.4], C=[1, 0.0], Ts=data.Ts)
    refined = ident.pem(data, start)
    assert refined.structure == start.structure and refined.n_params == start.n_params
    assert refined.report["loss"] <= armax(data, 2, 2, 1, 1).report["loss"] * (1 + 1e-6)


def test_armax_escapes_the_local_minimum_of_the_cascaded_tanks():
    """ARMAX3321 on the detrended tanks has two minima; the Hannan–Rissanen start lies in the
    worse one. The result must be at least as good as scipy's MINPACK LM (an independent
    implementation of the same prediction error) started in the better basin, from the
    output-error dynamics."""
    from scipy.optimize import least_squares

    d = datasets.cascaded_tanks()[0].detrend()
    y, u = d.y[:, 0], d.u[:, 0]

    def eps(th):
        C = [1, *th[6:]]
        return lfilter([1, *th[:3]], C, y) - lfilter([0, *th[3:6]], C, u)

    o = oe(d, 3, 3, 1)
    ref = least_squares(eps, np.concatenate([o.F[1:], o.B[1:], [0.0, 0.0]]), method="lm").x
    m = armax(d, 3, 3, 2, 1)
    assert m.report["loss"] <= np.mean(eps(ref) ** 2) * (1 + 1e-6)


# Several inputs (per-input nb, nf, nk: MATLAB's order vectors) and no input (time series).
MULTI = {
    "armax_2u": Orders(2, (2, 1), 1, 0, (0, 0), (1, 3)),
    "oe_2u": Orders(0, (2, 1), 0, 0, (2, 1), (1, 0)),
    "bj_2u": Orders(0, (1, 2), 1, 2, (1, 2), (2, 1)),
    "poly_3u": Orders(1, (1, 1, 2), 1, 1, (1, 0, 2), (1, 2, 0)),
    "arma": Orders(2, (), 1, 0, (), ()),
    "ar_noise_d": Orders(1, (), 1, 2, (), ()),
}


@pytest.mark.parametrize("steady", [False, True])
@pytest.mark.parametrize("name", sorted(MULTI))
def test_analytic_jacobian_matches_finite_differences_for_several_and_no_inputs(name, steady):
    orders = MULTI[name]
    orders = Orders(orders.na, orders.nb, orders.nc, orders.nd, orders.nf, orders.nk, steady)
    r = np.random.default_rng(len(name))
    y, u = r.standard_normal(150), r.standard_normal((150, orders.nu))
    theta = 0.3 / np.sqrt(orders.d) * r.standard_normal(orders.d)
    e, w, v = _signals(orders, theta, y, u)
    psi = _jacobian_block(orders, theta, y, u, e, w, v).T
    assert psi.shape == (150, orders.d)
    assert np.allclose(psi, _finite_difference_jacobian(orders, theta, y, u), atol=1e-6)


B1, F1 = np.array([0, 1.0, 0.5]), np.array([1, -1.2, 0.5])  # nb 2, nf 2, nk 1
B2, F2 = np.array([0, 0, -0.7, 0.3]), np.array([1, -0.6])  # nb 2, nf 1, nk 2


def _two_inputs(N, seed, noise):
    """y = B1/F1 u1 + B2/F2 u2 + noise(e), with independent white inputs."""
    r = np.random.default_rng(seed)
    u = r.standard_normal((N, 2))
    y = lfilter(B1, F1, u[:, 0]) + lfilter(B2, F2, u[:, 1]) + noise(r.standard_normal(N))
    return IOData(u, y, 0.1)


def test_noise_free_two_input_oe_recovers_each_inputs_b_and_f():
    m = oe(_two_inputs(2000, 20, lambda e: 0 * e), [2, 2], [2, 1], [1, 2])
    assert m.nb == (2, 2) and m.nk == (1, 2) and m.nf == (2, 1) and m.n_params == 7
    assert np.allclose(m.B, [[0, 1.0, 0.5, 0], [0, 0, -0.7, 0.3]], atol=1e-8)
    assert np.allclose(m.F[0], F1, atol=1e-8) and np.allclose(m.F[1, :2], F2, atol=1e-8)
    assert m.structure == "OE[2, 2][2, 1][1, 2]"


def test_two_input_oe_with_noise_is_within_its_reported_uncertainty():
    m = oe(_two_inputs(4000, 21, lambda e: 0.2 * e), [2, 2], [2, 1], [1, 2])
    truth = np.concatenate([B1[1:], B2[2:], F1[1:], F2[1:]])
    assert m.parameter_names == ["b[1]1", "b[1]2", "b[2]2", "b[2]3", "f[1]1", "f[1]2", "f[2]1"]
    assert np.all(np.abs(m.parameters - truth) <= 4 * m.parameter_std)


def test_two_input_box_jenkins_recovers_dynamics_and_noise_model():
    C, D = [1, 0.4], [1, -0.9]
    m = bj(_two_inputs(5000, 22, lambda e: lfilter(C, D, 0.05 * e)), [2, 2], 1, 1, [2, 1], [1, 2])
    truth = np.concatenate([B1[1:], B2[2:], C[1:], D[1:], F1[1:], F2[1:]])
    assert np.all(np.abs(m.parameters - truth) <= 4 * m.parameter_std)
    assert m.report["termination"].startswith("converged")


ARMAX_A, ARMAX_C = np.array([1, -1.5, 0.7]), np.array([1, -0.5])
ARMAX_B = np.array([[0, 1.0, 0.5, 0], [0, 0, -0.7, 0.2]])  # nb = [2, 2], nk = [1, 2]


def _two_input_armax(N, seed, sigma):
    r = np.random.default_rng(seed)
    u = r.standard_normal((N, 2))
    y = sum(lfilter(ARMAX_B[j], ARMAX_A, u[:, j]) for j in range(2))
    y = y + lfilter(ARMAX_C, ARMAX_A, sigma * r.standard_normal(N))
    return IOData(u, y, 0.1)


def test_noise_free_two_input_armax_is_exact():
    m = armax(_two_input_armax(1500, 23, 0.0), 2, [2, 2], 1, [1, 2])
    assert np.allclose(m.A, ARMAX_A, atol=1e-8) and np.allclose(m.B, ARMAX_B, atol=1e-8)


def test_two_input_armax_with_noise_is_within_its_reported_uncertainty():
    m = armax(_two_input_armax(4000, 24, 0.3), 2, [2, 2], 1, [1, 2])
    truth = np.array([-1.5, 0.7, 1.0, 0.5, -0.7, 0.2, -0.5])
    assert np.all(np.abs(m.parameters - truth) <= 4 * m.parameter_std)
    data = _two_input_armax(4000, 24, 0.3)
    start = arx(data, 2, [2, 2], [1, 2])  # biased by the coloured noise: a different start
    refined = pem(data, PolyModel(start.A, start.B, C=[1, 0.0], Ts=0.1, nb=start.nb))
    assert np.allclose(refined.parameters, m.parameters, atol=1e-5)


def test_a_two_input_model_with_one_f_per_input_behaves_as_its_sum(tmp_path):
    m = PolyModel(
        None, np.vstack([np.r_[B1, 0], B2]), F=[[1, -1.2, 0.5], [1, -0.6, 0]], nf=[2, 1], Ts=0.1
    )
    u = np.random.default_rng(25).standard_normal((300, 2))
    parts = [lfilter(B1, F1, u[:, 0]), lfilter(B2, F2, u[:, 1])]
    assert np.allclose(m.simulate(u), parts[0] + parts[1], atol=1e-12)
    g = m.dc_gain()
    assert np.allclose(g, [B1.sum() / F1.sum(), B2.sum() / F2.sum()])
    back = PolyModel.load(m.save(tmp_path / "m.json"))
    assert back.nf == (2, 1) and np.array_equal(back.F, m.F) and back.n_params == m.n_params
    # a start-up transient of each F is a free response: 'estimate' removes it exactly
    x1 = lfilter(B1, F1, u[:, 0], zi=[0.8, -0.3])[0]
    x2 = lfilter(B2, F2, u[:, 1], zi=[0.5, 0.1, 0.0])[0]
    data = IOData(u, x1 + x2, 0.1)
    assert np.allclose(m.predict(data, 1, initial="estimate"), x1 + x2, atol=1e-9)
    assert np.allclose(m.simulate(data, initial="estimate"), x1 + x2, atol=1e-9)
    with pytest.raises(Exception, match="nf"):
        PolyModel(
            None,
            np.vstack([np.r_[B1, 0], B2]),
            F=[[1, -1.2, 0.5], [1, -0.6, 0.1]],
            nf=[2, 1],
            Ts=0.1,
        )


def test_oe_multi_start_escapes_the_local_minimum_a_single_start_stops_in():
    # bench/check_pem_optimum.py --oe-runs 300: seed 31 is the record (of 300) where a
    # single start stops 0.26 % above the optimum; the truth-started search is the reference
    import importlib

    from scipy.signal import lfilter

    P = importlib.import_module("rwlab.ident.pem")  # the module (rwlab.ident.pem is the function)

    B = np.array([0, 1.0, 0.5, -0.3, 0.2])
    F = np.convolve([1, -1.5, 0.9], [1, 0.4, 0.6])
    r = np.random.default_rng(31)
    u = r.standard_normal(2000)
    y = lfilter(B, F, u) + 5 * r.standard_normal(2000)
    data = IOData(u, y, 1.0)
    orders = P.Orders(0, (4,), 0, 0, (4,), (1,), False)
    truth = np.concatenate([B[1:], F[1:]])
    best = P._minimize(orders, truth, [(y, u[:, None])], 100, 1e-10)[2] / 2000
    assert oe(data, 4, 4, 1, starts=0).report["loss"] > 1.001 * best
    assert oe(data, 4, 4, 1).report["loss"] <= 1.0001 * best
