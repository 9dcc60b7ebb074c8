"""Real-time quality in every record (issue 28, item 5)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rwlab.errors import ConfigError
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.testbed.record import read_record
from rwlab.testbed.runner import Timing


def test_timing_statistics_are_those_of_the_send_times():
    rng = np.random.default_rng(0)
    Ts = 1e-3
    due = Ts * np.arange(1000)
    late = rng.exponential(2e-4, 1000)
    late[[10, 500]] = [5e-3, 2e-3]  # two commands badly late
    timing = Timing(Ts, 1e-3)
    for d, s in zip(due, due + late, strict=True):
        timing.add(float(d), float(s))
    t = timing.summary()
    assert t["late"] == int(np.sum(late > 1e-3)) and t["commands"] == 1000
    assert t["lateness_s"]["max"] == pytest.approx(5e-3)
    assert t["lateness_s"]["p50"] == pytest.approx(np.median(late))
    assert t["period_s"]["p50"] == pytest.approx(np.median(np.diff(due + late)))


def _events(path, kind):
    return [e for e in read_record(path).topic("/event") if e["kind"] == kind]


def test_a_simulated_run_is_on_time_and_says_completed(tmp_path):
    path = tmp_path / "sim.mcap"
    s = run_experiment(ExperimentConfig(duration=20, Ts=0.5), path)
    assert s.status == "completed" and s.timing["late"] == 0
    assert s.timing["lateness_s"]["max"] == pytest.approx(0, abs=1e-9)
    (timing,) = _events(path, "timing")
    assert json.loads(timing["message"]) == s.timing
    assert _events(path, "stop")[0]["message"] == "completed"


def test_a_real_time_run_outside_its_tolerance_says_timing_faults(tmp_path):
    path = tmp_path / "rt.mcap"
    cfg = ExperimentConfig(duration=0.5, Ts=0.05, realtime=True, late_tolerance=1e-9)
    s = run_experiment(cfg, path)  # on the wall clock every send is some ns after its time
    assert s.status == "completed with timing faults" and s.timing["late"] == s.commands
    assert _events(path, "stop")[0]["message"] == "completed with timing faults"


@pytest.mark.parametrize("tol", [0, -1, float("nan"), float("inf"), True, "1"])
def test_bad_tolerances_are_refused(tol):
    with pytest.raises(ConfigError, match="late_tolerance"):
        ExperimentConfig(late_tolerance=tol)
