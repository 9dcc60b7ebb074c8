"""Shared fixtures: seeded simulated systems with known truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab.data import IOData

DATA_DIR = Path(__file__).parent / "data"


def simulate_poly(A, B, C, D, F, u, e):
    """y = B/(A F) u + C/(A D) e, from rest."""
    return lfilter(B, np.convolve(A, F), u) + lfilter(C, np.convolve(A, D), e)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def arx_system(rng):
    """ARX(2,2,1) truth from MATLAB's arx documentation example, noise σ = 0.1."""
    A, B = np.array([1, -1.5, 0.7]), np.array([0, 1.0, 0.5])
    u = rng.choice([-1.0, 1.0], 2000)
    e = 0.1 * rng.standard_normal(2000)
    y = simulate_poly(A, B, [1], [1], [1], u, e)
    return A, B, IOData(u, y, 0.1)
