"""Shared fixtures: seeded simulated systems with known truth."""

from __future__ import annotations

import shutil
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


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
needs_chromium = pytest.mark.skipif(
    not (CHROMIUM and CHROMEDRIVER),
    reason="needs Debian's chromium and chromium-driver (.ci/run installs them)",
)


@pytest.fixture
def browser():
    """Factory for headless Chromium drivers; ``offline=True`` sends any network request to a
    dead proxy, so a page that needs the network fails visibly."""
    drivers = []

    def make(offline: bool = False):
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        args = [
            "--headless=new",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--window-size=1200,1000",
        ]
        if offline:
            args += ["--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>"]
        for arg in args:
            options.add_argument(arg)
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
        drivers.append(driver)
        return driver

    yield make
    for driver in drivers:
        driver.quit()
