"""Fault injection into the twin and model-based fault diagnosis (issue 14, items 3–4)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

from rwlab.cli import main
from rwlab.diagnose import diagnose
from rwlab.diagnose.detect import Cusum, RunTest, cusum_threshold, run_length
from rwlab.errors import ConfigError
from rwlab.testbed import ExperimentConfig, load_record, read_record, run_experiment
from rwlab.wheel import RW90, Mode, WheelPhysics
from rwlab.wheel.faults import FAULTS, ScheduledFault, parse_fault

# -- fault syntax --------------------------------------------------------------------------


def test_parse_fault_reads_name_value_and_time():
    assert parse_fault("friction=3@900") == ScheduledFault("friction", 3.0, 900.0)
    assert parse_fault("speed_sensor_stuck@600") == ScheduledFault("speed_sensor_stuck", None, 600)
    assert parse_fault("speed_sensor_bias=-50@10.5").value == -50


@pytest.mark.parametrize(
    "text",
    [
        "friction@900",
        "friction=3",
        "friction=0@9",
        "speed_sensor_stuck=1@9",
        "wear=2@1",
        "friction=x@9",
        "friction=3@-1",
        "current_limit=nan@5",
        "",
    ],
)
def test_bad_faults_are_config_errors(text):
    with pytest.raises(ConfigError):
        parse_fault(text)


@given(
    st.sampled_from(sorted(FAULTS)),
    st.floats(0.01, 1e4, allow_nan=False),
    st.floats(0, 1e6, allow_nan=False),
)
def test_fault_text_round_trips(name, value, t_s):
    fault = ScheduledFault(name, None if FAULTS[name] is None else value, t_s)
    again = parse_fault(str(fault))
    assert again.name == name and again.t_s == pytest.approx(t_s, rel=1e-5)


# -- physics of the faults -------------------------------------------------------------------


def _hold(wheel: WheelPhysics, rpm: float, seconds: float) -> None:
    wheel.command(Mode.SPEED, rpm)
    for _ in range(round(seconds / 1e-3)):
        wheel.step(1e-3)


def test_worn_bearing_costs_the_friction_torque_in_current():
    healthy, worn = WheelPhysics(RW90), WheelPhysics(RW90)
    worn.friction_factor = 3.0
    for w in (healthy, worn):
        _hold(w, 3000, 60)
    omega = 3000 * 2 * math.pi / 60
    extra = 2 * (RW90.viscous_friction * omega + RW90.coulomb_friction) / RW90.torque_constant
    assert worn.current - healthy.current == pytest.approx(extra, rel=0.02)
    assert worn.speed == pytest.approx(healthy.speed, rel=1e-3)  # the speed loop hides it


def test_weak_motor_and_low_current_limit_slow_the_acceleration():
    nominal = RW90.max_accel  # rad/s², reached with the healthy motor
    weak, limited = WheelPhysics(RW90), WheelPhysics(RW90)
    weak.torque_constant_factor = 0.5
    limited.current_limit = 0.2
    for w in (weak, limited):
        _hold(w, 6000, 5)
    assert weak.speed / 5 < 0.6 * nominal
    tau = RW90.torque_constant * 0.2 - RW90.coulomb_friction
    assert limited.speed / 5 == pytest.approx(tau / RW90.inertia, rel=0.05)


# -- detectors against textbook values ------------------------------------------------------


def test_cusum_threshold_matches_the_textbook_arl():
    # one-sided CUSUM, k = 0.5: h = 4 → ARL₀ ≈ 336, h = 5 → 930 (Montgomery, Table 9.3);
    # the two-sided threshold is the one-sided one for twice the ARL₀
    assert cusum_threshold(336 / 2, 0.5) == pytest.approx(4.0, abs=0.02)
    assert cusum_threshold(930 / 2, 0.5) == pytest.approx(5.0, abs=0.03)


def test_cusum_false_alarm_run_length_is_the_one_asked_for():
    rng = np.random.default_rng(7)
    h = cusum_threshold(200.0, 0.5)
    runs = []
    for _ in range(400):
        c, n = Cusum(h, 0.5, clip=math.inf), 0
        while not c.update(rng.standard_normal()):
            n += 1
        runs.append(n + 1)
    assert np.mean(runs) == pytest.approx(200, rel=0.15)


def test_run_test_length_meets_the_exact_arl():
    n = run_length(1e4, 0.3)
    arl = lambda m: (1 - 0.3**m) / (0.7 * 0.3**m)  # noqa: E731
    assert arl(n) >= 1e4 > arl(n - 1)
    test = RunTest(3)
    assert [test.update(e) for e in (True, True, False, True, True, True)][-1]


# -- the twin misbehaves, the diagnosis notices ------------------------------------------


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A model identified (paper A's study) from a fault-free 20-minute PRBS, seed 0."""
    out = tmp_path_factory.mktemp("ident")
    run_experiment(ExperimentConfig(duration=1200, seed=0), out / "prbs.mcap")
    study = out / "study"
    result = CliRunner().invoke(main, ["identify", str(out / "prbs.mcap"), "--out", str(study)])
    assert result.exit_code == 0, result.output
    return study / "model.json"


def _diagnose(path, model_file):
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    data = load_record(path, wheel.Ts, outputs=("speed", "current", "age"), max_gap=np.inf)
    return diagnose(data, wheel)


def test_faults_are_recorded_as_events(tmp_path):
    cfg = ExperimentConfig(duration=60, seed=3, faults=("friction=2@20", "telemetry_dropout=3@30"))
    summary = run_experiment(cfg, tmp_path / "r.mcap")
    events = [e for e in read_record(tmp_path / "r.mcap").topic("/event") if e["kind"] != "start"]
    injected = [(e["t"], e["message"]) for e in events if e["kind"] == "fault_injected"]
    assert injected == [
        (pytest.approx(20), "friction=2@20"),
        (pytest.approx(30), "telemetry_dropout=3@30"),
    ]
    assert 25 <= summary.lost_frames <= 35  # 3 s of 10 Hz telemetry


def test_faults_need_the_simulated_wheel():
    with pytest.raises(ConfigError):
        ExperimentConfig(interface="socketcan", channel="can0", faults=("friction=2@1",))
    with pytest.raises(ConfigError):
        ExperimentConfig(duration=10, faults=("friction=2@11",))


@pytest.mark.slow
def test_friction_and_stuck_sensor_are_detected_in_time_and_named(tmp_path, model_file):
    cases = {
        "friction=3@900": (900, 60, "friction"),
        "speed_sensor_stuck@600": (600, 30, "speed_sensor_stuck"),
    }
    for fault, (start, within, kind) in cases.items():
        path = tmp_path / f"{kind}.mcap"
        run_experiment(ExperimentConfig(duration=1200, seed=5, faults=(fault,)), path)
        alarms = _diagnose(path, model_file).alarms
        assert alarms, fault
        assert all(a.t_s >= start for a in alarms), (fault, alarms)  # none precedes the fault
        assert alarms[0].t_s - start <= within and alarms[0].kind == kind, (fault, alarms)


@pytest.mark.slow
def test_a_fault_free_two_hour_record_raises_no_alarm(tmp_path, model_file):
    path = tmp_path / "healthy.mcap"
    run_experiment(ExperimentConfig(duration=7200, seed=1), path)
    result = CliRunner().invoke(
        main, ["diagnose", str(path), "--model", str(model_file), "--out", str(tmp_path / "d")]
    )
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert report["alarms"] == []
    assert set(report["thresholds"]) >= {"current", "stuck", "dropout"}
    assert (tmp_path / "d" / "report.html").read_text().count("<figure") == 2


def test_live_alarms_are_the_offline_alarms(tmp_path, model_file):
    path = tmp_path / "live.mcap"
    cfg = ExperimentConfig(duration=600, seed=2, faults=("friction=4@400",), model=str(model_file))
    run_experiment(cfg, path)
    live = [e["message"] for e in read_record(path).topic("/event") if e["kind"] == "alarm"]
    offline = _diagnose(path, model_file).alarms
    assert offline and offline[0].t_s >= 400 and offline[0].kind == "friction"
    assert [m.split(" (")[0] for m in live] == [f"{a.kind} at {a.t_s:.1f} s" for a in offline]
