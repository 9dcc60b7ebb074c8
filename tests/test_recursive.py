"""Recursive ARX/ARMAX: exact against batch least squares, and tracking a change."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import ConfigError, DataError
from rwlab.ident.recursive import RecursiveARMAX, RecursiveARX, rarx

A_TRUE, B_TRUE = [1, -1.5, 0.7], [0, 1.0, 0.5]


def record(N: int, seed: int, noise: float = 0.1, C=(1.0,)) -> IOData:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(N)
    y = lfilter(B_TRUE, A_TRUE, u) + lfilter(C, A_TRUE, noise * rng.standard_normal(N))
    return IOData(u, y, 0.5)


def test_without_forgetting_rls_equals_regularised_batch_least_squares():
    data = record(400, seed=0)
    theta, _ = rarx(data, 2, 2, 1, initial_covariance=100.0)
    y, u = data.y[:, 0], data.u[:, 0]
    pad = lambda x, k: np.concatenate([np.zeros(k), x[: len(x) - k]])  # noqa: E731
    Phi = np.column_stack([-pad(y, 1), -pad(y, 2), pad(u, 1), pad(u, 2)])
    batch = np.linalg.solve(Phi.T @ Phi + np.eye(4) / 100.0, Phi.T @ y)
    assert np.allclose(theta[-1], batch, rtol=1e-8, atol=1e-10)


def test_converges_to_the_true_system():
    est = RecursiveARX(2, 2, 1)
    data = record(2000, seed=1)
    for yt, ut in zip(data.y[:, 0], data.u[:, 0], strict=True):
        est.update(yt, ut)
    assert np.allclose(est.A, A_TRUE, atol=0.02) and np.allclose(est.B, B_TRUE, atol=0.02)
    m = est.to_poly(0.5)
    assert m.structure == "ARX221" and m.Ts == 0.5


@pytest.mark.parametrize("options", [{"forgetting": 0.98}, {"method": "kalman", "drift": 1e-4}])
def test_follows_a_gain_change_that_no_forgetting_misses(options):
    rng = np.random.default_rng(2)
    N = 3000
    u = rng.standard_normal(N)
    y = np.concatenate(
        [lfilter(B_TRUE, A_TRUE, u)[: N // 2], lfilter([0, 2.0, 1.0], A_TRUE, u)[N // 2 :]]
    )
    y = y + 0.05 * rng.standard_normal(N)  # the switch leaves a transient; both see the same
    data = IOData(u, y, 1.0)
    tracking, _ = rarx(data, 2, 2, 1, **options)
    frozen, _ = rarx(data, 2, 2, 1)
    assert abs(tracking[-1, 2] - 2.0) < 0.05
    assert abs(frozen[-1, 2] - 2.0) > 0.2


def test_armax_recovers_the_noise_polynomial():
    data = record(6000, seed=3, noise=0.3, C=(1.0, 0.5))
    est = RecursiveARMAX(2, 2, 1, 1)
    yhat = [est.update(yt, ut) for yt, ut in zip(data.y[:, 0], data.u[:, 0], strict=True)]
    assert est.theta[-1] == pytest.approx(0.5, abs=0.05)
    assert np.allclose(est.A, A_TRUE, atol=0.03)
    assert np.var(data.y[3000:, 0] - np.array(yhat)[3000:]) == pytest.approx(0.09, rel=0.1)


def test_bad_settings_and_samples():
    with pytest.raises(ConfigError):
        RecursiveARX(2, 2, 1, forgetting=1.5)
    with pytest.raises(ConfigError):
        RecursiveARX(2, 2, 1, method="gradient")
    with pytest.raises(ConfigError):
        RecursiveARX(0, 0, 1)
    with pytest.raises(DataError):
        RecursiveARX(1, 1).update(float("nan"), 0.0)
    with pytest.raises(DataError):
        rarx(IOData(np.zeros((10, 2)), np.zeros(10), 1.0), 1, 1)
