"""Confidence bands: do ±kσ from the parameter covariance cover the truth as often as they say?"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.errors import ModelError
from rwlab.ident import arx, n4sid, ssest
from rwlab.ident.uncertainty import bode_band, impulse_band, step_band

A_TRUE, B_TRUE = [1, -1.5, 0.7], [0, 1.0, 0.5]


def arx_record(rng, N: int = 400) -> IOData:
    u = rng.choice([-1.0, 1.0], N)
    y = lfilter(B_TRUE, A_TRUE, u) + lfilter([1.0], A_TRUE, 0.3 * rng.standard_normal(N))
    return IOData(u, y, 1.0)


def test_two_sigma_step_band_covers_the_truth_about_95_percent_of_the_time():
    rng = np.random.default_rng(0)
    truth = lfilter(B_TRUE, A_TRUE, np.ones(40))
    hits = []
    for _ in range(60):
        band = step_band(arx(arx_record(rng), 2, 2, 1), 40)
        hits.append(np.abs(band.value[1:, 0, 0] - truth[1:]) <= 2 * band.sd[1:, 0, 0])
    assert 0.85 <= np.mean(hits) <= 0.99


def test_monte_carlo_agrees_with_first_order_propagation():
    m = arx(arx_record(np.random.default_rng(1), 2000), 2, 2, 1)
    lin = impulse_band(m, 30)
    mc = impulse_band(m, 30, method="montecarlo", n_samples=3000, seed=2)
    assert np.allclose(mc.sd[1:], lin.sd[1:], rtol=0.1)
    assert np.array_equal(mc.value, lin.value)
    assert np.allclose(lin.upper(2) - lin.lower(2), 4 * lin.sd)


def test_state_space_bode_band_matches_the_spread_over_realisations():
    """ssest's (rank-deficient, free-form) covariance gives the right |G| spread."""
    rng = np.random.default_rng(3)
    w = np.array([0.1, 0.5, 1.5])
    mags, sds = [], []
    for _ in range(25):
        m = ssest(arx_record(rng, 600), 2)
        mag, phase = bode_band(m, w)
        mags.append(mag.value[:, 0, 0])
        sds.append(mag.sd[:, 0, 0])
        assert np.all(phase.sd > 0)
    ratio = np.std(mags, axis=0, ddof=1) / np.mean(sds, axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_a_model_without_covariance_has_no_band():
    data = arx_record(np.random.default_rng(4))
    with pytest.raises(ModelError):
        step_band(n4sid(data, 2), 10)
    with pytest.raises(ModelError):
        step_band(arx(data, 2, 2, 1), 10, method="bootstrap")
