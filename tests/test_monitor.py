"""The live monitor in a real browser: headless Chromium (Debian's chromium + chromium-driver)."""

import functools
import threading
import time
from pathlib import Path

import pytest

from rwlab.testbed import ExperimentConfig, run_experiment, runner
from rwlab.testbed.monitor import serve_in_thread
from rwlab.testbed.record import partial_path
from rwlab.wheel.node import WheelNode
from tests.conftest import needs_chromium

ARTIFACTS = Path(__file__).resolve().parent.parent / "test-artifacts"

pytestmark = [pytest.mark.slow, needs_chromium]

POINTS = """
const doc = Bokeh.documents[0];
if (!doc) return -1;
const src = doc.get_model_by_name('telemetry');
if (!src) return -1;
const t = src.data instanceof Map ? src.data.get('t') : src.data.t;
return t.length;
"""


def _wait_for(driver, script, predicate, timeout=20.0):
    end = time.monotonic() + timeout
    value = None
    while time.monotonic() < end:
        value = driver.execute_script(script)
        if predicate(value):
            return value
        time.sleep(0.1)
    raise AssertionError(f"page never satisfied the condition; last value {value!r}")


def test_monitor_page_shows_a_live_trace_that_updates(tmp_path, browser, monkeypatch):
    record = tmp_path / "live.mcap"
    cfg = ExperimentConfig(
        signal="step", duration=12, Ts=0.1, realtime=True, telemetry_rate=50, amplitude=3000
    )
    # The browser, the page's server and the experiment share this process: on a loaded
    # 2-core CI machine the experiment's thread has been starved past the twin's 1-s command
    # watchdog, and the wheel, rightly, idled (WATCHDOG) and stopped its telemetry. The page,
    # not the watchdog, is what this test is about.
    monkeypatch.setattr(runner, "WheelNode", functools.partial(WheelNode, watchdog=10.0))
    seen = threading.Event()  # the page has shown what it must: the experiment may stop
    failed: list[BaseException] = []

    def stop_once_seen(k, n):
        if seen.is_set():
            raise KeyboardInterrupt  # as Ctrl-C: the wheel idled, the record closed

    def experiment():
        try:
            run_experiment(cfg, record, progress=stop_once_seen)
        except KeyboardInterrupt:
            pass
        except BaseException as error:  # told by the assertion below, not lost in a thread
            failed.append(error)

    run = threading.Thread(target=experiment, daemon=True)
    run.start()
    while not (record.exists() or partial_path(record).exists()):  # written as .partial
        time.sleep(0.05)
    server = serve_in_thread(record)
    driver = browser()
    try:
        driver.get(server.url)
        first = _wait_for(driver, POINTS, lambda n: n is not None and n > 10)
        time.sleep(1.5)
        second = driver.execute_script(POINTS)
        assert not failed, f"the experiment stopped: {failed[0]!r}"
        assert second > first + 30  # 50 Hz telemetry keeps arriving on the page
        status = driver.execute_script("return Bokeh.documents[0].get_model_by_name('status').text")
        assert "mode" in status and "rpm" in status
        ARTIFACTS.mkdir(exist_ok=True)
        driver.save_screenshot(str(ARTIFACTS / "monitor.png"))
    finally:
        seen.set()
        server.stop()
        run.join(timeout=20)


def test_monitor_replays_a_finished_record(tmp_path, browser):
    record = tmp_path / "done.mcap"
    run_experiment(ExperimentConfig(signal="prbs", duration=60, Ts=0.5, telemetry_rate=20), record)
    # 10 s of replay: a loaded CI machine has taken over 3 s from the page's session to its
    # first drawn points, so a much faster replay could arrive whole before the first look
    server = serve_in_thread(record, replay=True, speed=6.0)
    driver = browser()
    try:
        driver.get(server.url)
        first = _wait_for(driver, POINTS, lambda n: n is not None and n > 0)
        second = _wait_for(driver, POINTS, lambda n: n is not None and n > first)
        assert second > first
        total = _wait_for(driver, POINTS, lambda n: n is not None and n >= 1200, timeout=40)
        assert total >= 1200  # the whole record, 60 s at 20 Hz, arrives
    finally:
        server.stop()
