"""Non-parametric estimates (spa, etfe, impulseest) against systems whose truth is known."""

from __future__ import annotations

import control
import numpy as np
import pytest

from rwlab.data import IOData
from rwlab.errors import DataError
from rwlab.ident import etfe, impulseest, spa

# a known second-order system, Ts = 1 s so rad/s = rad/sample: poles 0.6 ± 0.37j
SYS = control.tf([0, 0.3, 0.2], [1, -1.2, 0.5], 1.0)


def siso_record(N: int, seed: int, noise_sd: float = 0.1) -> IOData:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(N)
    y = control.forced_response(SYS, U=u).outputs + noise_sd * rng.standard_normal(N)
    return IOData(u, y, 1.0)


def test_spa_matches_the_true_magnitude_within_2_db():
    g = spa(siso_record(5000, seed=0))
    assert g.omega.size == 128 and g.omega[-1] == pytest.approx(np.pi)  # MATLAB's grid
    band = (g.omega >= 0.05) & (g.omega <= 1.5)
    true = control.frequency_response(SYS, g.omega[band]).complex.ravel()
    err_db = g.magnitude_db()[band, 0, 0] - 20 * np.log10(np.abs(true))
    assert np.max(np.abs(err_db)) < 2.0


def test_spa_standard_deviation_is_of_the_right_size():
    # its own ±3σ covers most of the truth away from the window's bias at the peak
    g = spa(siso_record(20000, seed=4), window_size=60)
    true = control.frequency_response(SYS, g.omega).complex.ravel()
    inside = np.abs(g.response[:, 0, 0] - true) <= 3 * g.response_sd[:, 0, 0]
    assert inside.mean() > 0.9
    assert np.all(g.response_sd > 0)


def test_spa_of_white_noise_is_its_flat_spectrum():
    rng = np.random.default_rng(5)
    Ts, sigma = 0.5, 2.0
    g = spa(IOData(None, sigma * rng.standard_normal(20000), Ts))
    assert g.response.shape == (128, 1, 0)
    assert np.allclose(np.real(g.spectrum[:, 0, 0]), sigma**2 * Ts, rtol=0.15)  # Φ = σ² Ts


def test_spa_two_inputs_two_outputs():
    rng = np.random.default_rng(6)
    N = 20000
    u = rng.standard_normal((N, 2))
    g_true = {(0, 0): [0.5, 0.3], (0, 1): [0.0, -0.4], (1, 0): [1.0], (1, 1): [0.2, 0.2, 0.2]}
    y = np.zeros((N, 2))
    for (i, j), h in g_true.items():
        y[:, i] += np.convolve(u[:, j], h)[:N]
    g = spa(IOData(u, y, 1.0))
    for (i, j), h in g_true.items():
        truth = np.exp(-1j * np.outer(g.omega, np.arange(len(h)))) @ np.array(h)
        assert np.max(np.abs(g.response[:, i, j] - truth)) < 0.1, (i, j)


def test_etfe_is_exact_for_a_periodic_input_without_noise():
    period, periods = 64, 20
    rng = np.random.default_rng(7)
    u = np.tile(rng.standard_normal(period), periods)
    # start in the periodic steady state: simulate one extra period and drop it
    y = control.forced_response(SYS, U=np.concatenate([u[:period], u])).outputs[period:]
    omega = 2 * np.pi * np.arange(1, period // 2) / period
    g = etfe(IOData(u, y, 1.0), omega)
    true = control.frequency_response(SYS, omega).complex.ravel()
    assert np.allclose(g.response[:, 0, 0], true, rtol=1e-8, atol=1e-10)


def test_impulseest_recovers_a_known_fir_within_its_3_sigma_bands():
    k = np.arange(30)
    g_true = np.concatenate([0.8**k * np.cos(0.5 * k), np.zeros(20)])
    rng = np.random.default_rng(8)
    N = 2000
    u = rng.standard_normal(N)
    y = np.convolve(u, g_true)[:N] + 0.1 * rng.standard_normal(N)
    m = impulseest(IOData(u, y, 1.0), 50)
    inside = np.abs(m.coefficients[:, 0, 0] - g_true) <= 3 * m.sd[:, 0, 0]
    assert inside.mean() >= 0.95
    assert m.noise_variance[0] == pytest.approx(0.01, rel=0.15)
    # the frequency response's standard deviation is the exact linear map of the coefficients'
    fr = m.frequency_response([0.0])
    assert fr.response[0, 0, 0] == pytest.approx(m.coefficients[:, 0, 0].sum())
    cov = m.covariance[0]
    assert fr.response_sd[0, 0, 0] == pytest.approx(np.sqrt(cov.sum()))


def test_impulseest_least_squares_is_exact_without_noise_and_with_delay():
    rng = np.random.default_rng(9)
    u = rng.standard_normal((500, 2))
    y = np.zeros(500)
    y[3:] = 0.5 * u[:-3, 0] + 0.25 * u[:-3, 1]
    y[4:] -= 0.4 * u[:-4, 1]
    m = impulseest(IOData(u, y, 0.2), 10, nk=2, kernel="none")
    assert m.lags[0] == 2
    expected = np.zeros((10, 1, 2))
    expected[1, 0] = [0.5, 0.25]
    expected[2, 0, 1] = -0.4
    assert np.allclose(m.coefficients, expected, atol=1e-10)


def test_bad_input_is_a_clear_error():
    d = siso_record(200, seed=1)
    with pytest.raises(DataError):
        spa(d, window_size=500)
    with pytest.raises(DataError):
        impulseest(IOData(None, d.y, 1.0))
    with pytest.raises(DataError):
        impulseest(d, 300)
    with pytest.raises(DataError):
        impulseest(d, 10, kernel="DC")
    with pytest.raises(DataError):
        etfe(IOData(np.ones((200, 2)), d.y, 1.0))


def test_spa_reports_the_window_bias_that_its_band_leaves_out():
    # a resonance sharper than the window: the bias indicator is largest at the peak
    from scipy.signal import lfilter

    from rwlab.data import IOData
    from rwlab.ident import spa

    r = np.random.default_rng(2)
    u = r.standard_normal(4000)
    den = [1, -2 * 0.98 * np.cos(0.6), 0.98**2]
    y = lfilter([0, 0.1], den, u) + 0.05 * r.standard_normal(4000)
    fr = spa(IOData(u, y, 1.0), 30)
    bias = fr.report["bias"]
    assert bias["window_size"] == 30 and bias["resolution_rad_s"] == pytest.approx(2 * np.pi / 30)
    est = np.asarray(bias["estimate"])[:, 0, 0]
    peak = np.argmin(np.abs(fr.omega - 0.6))
    assert est[peak] > 5 * np.median(est)
    # and there the ±σ band misses the truth: the bias is the larger error
    z = np.exp(1j * fr.omega[peak])
    true = 0.1 / z / (1 + den[1] / z + den[2] / z**2)
    assert abs(fr.response[peak, 0, 0] - true) > 2 * fr.response_sd[peak, 0, 0]
