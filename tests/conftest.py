"""Shared fixtures: seeded simulated systems with known truth, and the records and
identifications several test files read, made once per test session."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock, Timeout
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


def _once_per_session(tmp_path_factory, name: str, make: Callable[[Path], None]) -> Path:
    """A folder ``make(folder)`` fills once per test session, whatever the number of
    pytest-xdist workers: the first worker to ask makes it under a lock, the others wait
    for it and read it (pytest-xdist's documented recipe). Tests read it, never write it."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of this session
    folder = root / f"session-{name}"
    with FileLock(str(folder) + ".lock"):
        if not (folder / ".done").exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            make(folder)
            (folder / ".done").touch()
    return folder


@pytest.fixture(scope="session")
def identified_prbs(tmp_path_factory) -> tuple[str, Path, Path]:
    """``rwlab identify`` on a fault-free 20-minute PRBS of the simulated RW90 (seed 0),
    made once per session: (the command's console output, the study folder with
    report.html, study.json and model.json, the record). Read-only."""

    def make(folder: Path) -> None:
        from click.testing import CliRunner

        from rwlab.cli import main
        from rwlab.testbed import ExperimentConfig, run_experiment

        run_experiment(ExperimentConfig(duration=1200, seed=0), folder / "prbs.mcap")
        args = ["identify", str(folder / "prbs.mcap"), "--out", str(folder / "study")]
        args.append("--nonlinear-models")  # the grey box and the NLARX too: the reports show them
        result = CliRunner().invoke(main, args)
        assert result.exit_code == 0, result.output
        (folder / "output.txt").write_text(result.output)

    folder = _once_per_session(tmp_path_factory, "identified-prbs", make)
    return (folder / "output.txt").read_text(), folder / "study", folder / "prbs.mcap"


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory) -> Path:
    """``rwlab demo --quick`` run once per session: its output folder, with the console's
    text beside it (``../console.txt``). Read-only."""

    def make(folder: Path) -> None:
        from click.testing import CliRunner

        from rwlab.cli import main

        result = CliRunner().invoke(main, ["demo", "--quick", "--out", str(folder / "out")])
        assert result.exit_code == 0, result.output
        (folder / "console.txt").write_text(result.stdout)

    return _once_per_session(tmp_path_factory, "quick-demo", make) / "out"


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per core this process may use. One more filled the real-time
    waits (the whole suite 269 s against 328 s on two cores), but starved the tests that
    run on the wall clock: three full runs in a row each failed one of them (a served
    wheel's watchdog, a demo's stop, a twin's streamed speed), and CI failed on a fourth
    (a monitor replay)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return cores or 1


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels(tmp_path_factory) -> None:
    """Under pytest-xdist, the slowest numba kernels to compile, into numba's cache
    (``cache=True``), each by one worker at its start: the attitude loop
    (``kernel.run_block``, with the wheel twin's step) by the first, HIL's two halves
    of a step by the next, side by side. Every other worker goes on with its tests, and
    the first of theirs that needs one of those kernels waits for its cache instead of
    compiling it too (:func:`_wait_for`): the loop is ~30 s of a core cold, and three
    workers compiling it at once on two cores cost a fresh clone's quick lane ~30 s
    (measured). A no-op in one process (``-p no:xdist``, ``-o addopts=""``)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    from rwlab.attitude import kernel

    shared = tmp_path_factory.getbasetemp().parent
    jobs = [
        ("loop", _compile_the_loop, (kernel.run_block,)),
        ("hil-step", _compile_hils_step, (kernel.command_step, kernel.finish_step)),
    ]
    # pytest-xdist's worksteal hands gw0 the first half of the tests (test_api, the attitude
    # loop's) and gw1 the second (test_edges on, HIL's): each compiles what its own first
    # tests need, instead of waiting for the other (measured: ~6 s of a worker idle)
    if int(os.environ["PYTEST_XDIST_WORKER"].removeprefix("gw")) % 2:
        jobs.reverse()
    for name, compile_them, kernels in jobs:
        lock = FileLock(str(shared / f"compiled-{name}.lock"))
        try:
            lock.acquire(timeout=0)
        except Timeout:  # another worker compiles them
            for dispatcher in kernels:
                _wait_for(lock.lock_file, dispatcher)
            continue
        try:
            compile_them()
        finally:
            lock.release()


def _compile_the_loop() -> None:
    import rwlab
    from rwlab.wheel import WheelPhysics  # the twin's step (rwlab.wheel.kernel)

    for controller in ("lqr", "lqg"):
        rwlab.simulate("geo-smallsat", controller, duration=2.0)
    WheelPhysics().run(1e-3, 10)


def _compile_hils_step() -> None:
    from rwlab.attitude.control import LQRController
    from rwlab.attitude.scenario import SCENARIOS
    from rwlab.hil.satellite import Satellite

    scenario = SCENARIOS["geo-smallsat"]
    satellite = Satellite(scenario, LQRController(scenario), duration=1.0, seed=0)
    torques = satellite.wheel_torques()
    satellite.advance(satellite.x[7:] + torques * scenario.run.dt)


def _wait_for(lock_file: str, kernel) -> None:
    """Have ``kernel`` (a numba dispatcher) wait for the lock ``lock_file`` before it
    first compiles: numba then finds what the worker holding the lock cached, and loads
    it. A new lock each time: a process forked from this one (a demo's flights) may be
    the one that waits, and a lock does not cross a fork."""
    compile_here = kernel.compile

    def compile_once_cached(signature):
        with FileLock(lock_file):  # free once the other worker has compiled and cached them
            pass
        del kernel.compile  # numba's own again
        return compile_here(signature)

    kernel.compile = compile_once_cached
