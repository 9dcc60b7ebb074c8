import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData, merge
from rwlab.errors import DataError, EstimationError
from rwlab.ident import arx


def test_noise_free_arx_data_give_exact_parameters(rng):
    A, B = [1, -1.758, 0.7852], [0, 0.0275, -0.0012]  # paper A's ARX221
    u = rng.standard_normal(500)
    m = arx(IOData(u, lfilter(B, A, u), 0.5), 2, 2, 1)
    assert np.max(np.abs(m.A - A)) <= 1e-9 and np.max(np.abs(m.B - B)) <= 1e-9
    assert m.nk == (1,) and m.Ts == 0.5 and m.structure == "ARX221"


def test_noise_free_miso_arx_is_exact(rng):
    A = [1, -0.5, 0.2]
    u = rng.standard_normal((400, 2))
    y = lfilter([0, 1.0, 0.3], A, u[:, 0]) + lfilter([0, 0, -0.7], A, u[:, 1])
    m = arx(IOData(u, y, 1.0), 2, [2, 1], [1, 2])
    assert np.allclose(m.A, A, atol=1e-9)
    assert np.allclose(m.B, [[0, 1.0, 0.3], [0, 0, -0.7]], atol=1e-9)
    assert m.nu == 2 and np.allclose(m.simulate(u), y, atol=1e-8)


def test_delays_beyond_one_and_direct_feedthrough(rng):
    u = rng.standard_normal(300)
    for nk, B in ((0, [0.4, 0.2]), (3, [0, 0, 0, 0.4, 0.2])):
        y = lfilter(B, [1, -0.6], u)
        m = arx(IOData(u, y, 1.0), 1, 2, nk)
        assert np.allclose(m.B, B, atol=1e-9) and m.nk == (nk,)


def test_reported_covariance_matches_the_spread_over_seeds():
    A, B = [1, -1.5, 0.7], [0, 1.0, 0.5]
    estimates, stds = [], []
    for seed in range(200):
        r = np.random.default_rng(seed)
        u = r.choice([-1.0, 1.0], 400)
        y = lfilter(B, A, u) + lfilter([1], A, 0.2 * r.standard_normal(400))
        m = arx(IOData(u, y, 1.0), 2, 2, 1)
        estimates.append(m.parameters)
        stds.append(m.parameter_std)
    spread = np.std(estimates, axis=0)
    assert np.allclose(np.mean(stds, axis=0), spread, rtol=0.15)
    assert np.allclose(np.mean(estimates, axis=0), [*A[1:], *B[1:]], atol=3 * spread.max() / 10)


def test_noise_variance_estimates_the_innovation_variance(arx_system):
    _, _, data = arx_system
    m = arx(data, 2, 2, 1)
    assert m.noise_variance == pytest.approx(0.01, rel=0.1)
    assert m.report["fit_percent"] > 90


def test_experiments_are_merged_without_crossing_boundaries(rng):
    A, B = [1, -0.9], [0, 1.0]
    parts = []
    for _ in range(2):
        u = rng.standard_normal(50)
        parts.append(IOData(u, lfilter(B, A, u), 1.0))
    m = arx(merge(*parts), 1, 1, 1)
    assert np.allclose(m.A, A, atol=1e-9) and np.allclose(m.B, B, atol=1e-9)
    # naive concatenation puts a regression row across the seam and is no longer exact
    joined = IOData(np.concatenate([p.u for p in parts]), np.concatenate([p.y for p in parts]), 1.0)
    assert arx(joined, 1, 1, 1).noise_variance > 1e-6


def test_constant_input_is_not_persistently_exciting():
    with pytest.raises(EstimationError, match="persistently exciting"):
        arx(IOData(np.ones(100), np.random.default_rng(0).standard_normal(100), 1.0), 2, 2, 1)


def test_too_few_samples_and_bad_orders_are_clear_errors(rng):
    small = IOData(rng.standard_normal(6), rng.standard_normal(6), 1.0)
    with pytest.raises(DataError, match="too few samples"):
        arx(small, 3, 3, 1)
    data = IOData(rng.standard_normal(50), rng.standard_normal(50), 1.0)
    for bad in ((-1, 2, 1), (2, -2, 1), (2, 2, -1), (2.5, 2, 1), (True, 2, 1)):
        with pytest.raises(DataError):
            arx(data, *bad)
    with pytest.raises(DataError, match="IOData"):
        arx(np.zeros((10, 2)), 1, 1, 1)


def test_estimation_does_not_modify_the_data(arx_system):
    _, _, data = arx_system
    before = data.y.copy()
    arx(data, 2, 2, 1)
    assert np.array_equal(data.y, before)


def _plain_lstsq_arx(y, u, na, nb, nk):
    """Independent reference: the ARX regression built row by row, solved by np.linalg.lstsq."""
    n0 = max([na] + [k + b - 1 for b, k in zip(nb, nk, strict=True)])
    rows = []
    for t in range(n0, len(y)):
        row = [-y[t - i] for i in range(1, na + 1)]
        for j, (b, k) in enumerate(zip(nb, nk, strict=True)):
            row += [u[t - k - i, j] for i in range(b)]
        rows.append(row)
    return np.linalg.lstsq(np.array(rows), y[n0:], rcond=None)[0]


@pytest.mark.parametrize(("nb", "nk"), [([2, 3], [1, 2]), ([2, 2], [1, 2]), ([1, 3], [0, 3])])
def test_two_input_arx_with_different_nb_nk_equals_plain_least_squares(rng, nb, nk):
    u = rng.standard_normal((600, 2))
    y = lfilter([0, 1.0, 0.5], [1, -0.8, 0.2], u[:, 0]) + lfilter([0, 0, 0.7], [1, -0.3], u[:, 1])
    y = y + 0.1 * rng.standard_normal(600)
    m = arx(IOData(u, y, 1.0), 2, nb, nk)
    reference = _plain_lstsq_arx(y, u, 2, nb, nk)
    assert m.nb == tuple(nb) and m.nk == tuple(nk)
    assert m.covariance.shape == (2 + sum(nb),) * 2 == (m.n_params,) * 2
    assert np.max(np.abs(m.parameters - reference)) <= 1e-8
    for j, (b, k) in enumerate(zip(nb, nk, strict=True)):  # padded rows: zeros outside k..k+b
        assert not m.B[j, :k].any() and not m.B[j, k + b :].any()
    assert m.parameter_names[2 : 2 + nb[0]] == [f"b[1]{nk[0] + i}" for i in range(nb[0])]
