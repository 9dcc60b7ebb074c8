"""Telemetry dropouts named in flight (issue 42): the dropout test on its own, and in a
flight of three orthogonal wheels that the health check cannot watch."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st
from scipy.stats import poisson

from rwlab.cli import main
from rwlab.diagnose.detectors.lost_frames import alarm_count
from rwlab.hil.run import parse_node_fault
from rwlab.hil.telemetry import DropoutTest

from .test_hil import _channel


@given(st.floats(0.0, 20.0), st.floats(1e-4, 10.0), st.floats(1.0, 60.0))
def test_the_alarm_count_is_the_fewest_losses_as_rare_as_the_rate_asked(mean, per_hour, block):
    c = alarm_count(mean, per_hour, block)
    p = per_hour * block / 3600
    assert poisson.sf(c - 1, mean) <= p * (1 + 1e-9)  # P(count ≥ c)
    assert c == 1 or poisson.sf(c - 2, mean) > p  # one fewer is not that rare


def _fly(test: DropoutTest, t_from: float, t_to: float, lost: int, dt: float = 0.1):
    """Feed ``test`` a counter holding ``lost`` every ``dt`` over [t_from, t_to); alarms."""
    out = []
    for k in range(round((t_to - t_from) / dt)):
        t = t_from + k * dt
        if (alarm := test.update(t, lost)) is not None:
            out.append((t, alarm))
    return out


def test_a_link_that_lost_nothing_alarms_on_five_frames_then_on_three_after_an_hour():
    """Known truth: no loss in 300 s gives a healthy rate of at most χ²₀.₉₇₅(2)/2/300 s =
    0.0123/s (Garwood), 0.123 per 10-s block; at 1e-3 false alarms per hour (2.8e-6 per
    block) P(≥ 4) = 9.5e-6 is too likely and P(≥ 5) = 2.3e-7 is not: 5 frames. After an
    hour with no loss, 0.0102 per block: P(≥ 3) = 1.8e-7, P(≥ 2) = 5.2e-5: 3 frames."""
    test = DropoutTest(calibration_s=300.0, per_hour=1e-3)
    assert _fly(test, 0.0, 300.1, 0) == [] and test.limit == 5
    assert _fly(test, 300.1, 3600.1, 0) == [] and test.limit == 3
    assert test.blocks_tested == 330  # (3600.1 - 300.1) s in blocks of 10 s


@pytest.mark.parametrize("count, named", [(5, False), (6, True)])
def test_a_block_that_loses_the_alarm_count_is_named_at_once(count, named):
    test = DropoutTest(calibration_s=300.0, per_hour=1e-3)
    _fly(test, 0.0, 0.1, 0)
    _fly(test, 0.1, 300.1, 2)  # two frames lost while the rate was measured
    assert test.limit == 6  # 2 in 300 s: at most 7.22/300 s = 0.0241/s, 0.241 per block
    alarms = _fly(test, 300.1, 305.0, 2 + count)
    assert [a.kind for _, a in alarms] == (["telemetry_dropout"] if named else [])
    if named:
        t, alarm = alarms[0]
        assert t == pytest.approx(300.1) and alarm.statistic == 6 and alarm.threshold == 6


def test_a_lossy_link_raises_no_more_false_alarms_than_asked():
    """Healthy losses, Poisson at 0.05 frames/s (a link that loses 1 in 1000 at 50 Hz),
    40 one-hour flights at 10 alarms per hour asked: the rate measured in flight is taken
    at its upper bound, so fewer come (measured: 2.7/h over 70 h; a point estimate of the
    rate from 300 s asks for more than the link gives)."""
    rng = np.random.default_rng(3)
    alarms, hours = 0, 0.0
    for _ in range(40):
        test, lost = DropoutTest(calibration_s=300.0, per_hour=10.0), 0
        for k in range(3600):
            lost += int(rng.poisson(0.05))
            if test.update(float(k), lost) is not None:
                break
        alarms += test.alarmed
        hours += (k - 300) / 3600
    assert 0 < alarms <= 10 * hours


def test_a_dropout_of_three_orthogonal_wheels_is_named_and_the_wheel_flies_on(tmp_path):
    """The CubeSat's three orthogonal wheels have no null space for the health check; the
    dropout test watches their telemetry all the same (0.3 s at 50 Hz: 15 frames)."""
    out = tmp_path / "out"
    args = ["hil", "--scenario", "geo-cubesat", "--no-reference", "--channel", _channel()]
    args += ["--duration", "60", "--calibration", "30", "--telemetry-rate", "50"]
    args += ["--seed", "12", "--out", str(out), "--fault", "1:telemetry_dropout=0.3@40"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    m = json.loads((out / "metrics.json").read_text())
    (fault,) = m["wheel_faults"]
    assert (fault["node"], fault["named_kind"]) == (1, "telemetry_dropout")
    assert fault["detector"].startswith("telemetry dropout test: 15 frames lost in 10 s")
    assert 40.0 <= fault["detected_s"] <= 40.6 and fault["action"].startswith("kept")
    assert m["bench"]["lost_telemetry_frames"]["1"] >= 15
    assert "telemetry check:" in res.output and "dropout on wheel 1" in res.output
    assert m["config"]["nodes"] == [1, 2, 3]  # wheel 1 stayed in the allocation
    assert m["telemetry_check"]["blocks_tested"]["2"] >= 2


def test_frames_lost_under_the_alarm_count_are_said_on_the_console(tmp_path):
    """At 10 Hz a 0.3-s dropout loses 3 frames, under the 10 a flight 30 s old asks for:
    not named, but the console says they were lost."""
    args = ["hil", "--scenario", "geo-cubesat", "--no-reference", "--channel", _channel()]
    args += ["--duration", "60", "--calibration", "30", "--seed", "12"]
    args += ["--out", str(tmp_path / "out"), "--fault", "2:telemetry_dropout=0.3@40"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    assert "no dropout; frames lost under the alarm count: wheel 2: 3" in res.output


def test_an_alarm_answers_the_injected_fault_it_names_else_the_latest_before_it():
    from rwlab.hil.run import _injected

    faults = [parse_node_fault(f) for f in ("1:telemetry_dropout=0.3@400", "1:friction=4@500")]
    faults.append(parse_node_fault("2:friction=4@100"))
    assert _injected(faults, 1, "friction", 504.0).name == "friction"
    assert _injected(faults, 1, "torque_constant", 504.0).t_s == 500.0  # misnamed: the latest
    assert _injected(faults, 1, "telemetry_dropout", 400.4).t_s == 400.0
    assert _injected(faults, 1, "friction", 300.0).t_s == 400.0  # before any: the first
    assert _injected(faults, 3, "friction", 300.0) is None
