"""Fault injection into the twin and model-based fault diagnosis (issue 14, items 3–4)."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

import rwlab
from rwlab.cli import main
from rwlab.diagnose import HealthyReference, diagnose
from rwlab.diagnose.detect import Cusum, RunTest, cusum_threshold, run_length
from rwlab.diagnose.detectors import MODEL_BASED
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
def model_file(identified_prbs):
    """A model identified (paper A's study) from a fault-free 20-minute PRBS, seed 0."""
    return identified_prbs[1] / "model.json"


def _diagnose(path, model_file):
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    data = load_record(path, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf)
    return diagnose(data, wheel, HealthyReference.from_model_file(model_file))


def test_the_model_carries_a_healthy_reference_measured_on_the_whole_record(model_file):
    ref = HealthyReference.from_model_file(model_file)
    # the inertial current per rpm/s is I·(2π/60)/k_t of the twin (physics, not the fit)
    expected = RW90.inertia * 2 * math.pi / 60 / RW90.torque_constant
    assert ref.current_model[0] == pytest.approx(expected, rel=0.05)
    assert ref.repeat_samples >= 500  # moving samples of the 20-min record (issue: 36–214)
    assert set(ref.tests) == {"friction", "friction_change", "motor", "speed", "lag", "slew"}
    assert all(s.samples >= 4 * s.block for s in ref.tests.values())
    again = HealthyReference.from_dict(json.loads(json.dumps(ref.to_dict())))
    assert again == ref


@pytest.mark.slow  # a 20-minute record, its reference and its diagnosis: ~20 s
def test_a_reference_without_the_optional_change_test_is_still_stored(tmp_path, model_file):
    # a PRBS of ±1200 rpm never holds the ≥ 1500 rpm the friction-change test takes (the
    # held-out unit 842's default PRBS gave it 5 of 80 samples, and no reference was stored)
    from rwlab.diagnose import healthy_reference
    from rwlab.wheel import IdentifiedWheel

    run_experiment(ExperimentConfig(amplitude=1200, seed=3), tmp_path / "r.mcap")
    wheel = IdentifiedWheel.from_json(model_file)
    data = load_record(
        tmp_path / "r.mcap", wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf
    )
    ref = healthy_reference(data, wheel)
    assert "friction_change" not in ref.tests and "friction" in ref.tests
    result = diagnose(data, wheel, ref)  # armed from friction's σ: healthy data, no alarm
    assert "friction_change" in result.thresholds and result.alarms == []


def test_a_fault_present_at_power_up_is_a_fault(tmp_path, model_file):
    # ×2: beyond the friction spread between healthy units (±30 % → up to ×1.86), which
    # no comparison with another unit's reference can tell from wear present at power-up
    path = tmp_path / "worn.mcap"
    run_experiment(ExperimentConfig(duration=600, seed=11, faults=("friction=2@0",)), path)
    alarms = _diagnose(path, model_file).alarms
    assert alarms and alarms[0].kind == "friction", alarms
    # within the record (the issue: any time when present from t = 0); the slew test, at
    # the tune set's σ of a slew rather than the reference's 9 slews' (0.19, low by chance),
    # needs this PRBS's second slew through zero, at 307.5 s (it alarmed at 41 s on 0.19)
    assert alarms[0].t_s <= 400
    lo, hi = alarms[0].ci
    # the interval holds the model's uncertainty (the spread between units), not noise only
    assert lo <= 2 <= hi


def test_a_weak_motor_is_not_called_friction(tmp_path, model_file):
    path = tmp_path / "weak.mcap"
    run_experiment(
        ExperimentConfig(duration=900, seed=12, faults=("torque_constant=0.8@300",)), path
    )
    alarms = _diagnose(path, model_file).alarms
    assert alarms and all(a.t_s >= 300 for a in alarms)
    assert alarms[0].kind == "torque_constant" and alarms[0].magnitude == pytest.approx(
        0.8, rel=0.1
    )
    assert "friction" not in {a.kind for a in alarms}


def test_two_faults_at_once_are_both_named(tmp_path, model_file):
    path = tmp_path / "two.mcap"
    faults = ("friction=1.5@300", "speed_sensor_bias=15@300")
    run_experiment(ExperimentConfig(duration=900, seed=13, faults=faults), path)
    kinds = {a.kind for a in _diagnose(path, model_file).alarms}
    assert kinds == {"friction", "speed_sensor_bias"}


def test_diagnose_refuses_an_acceleration_mode_record(tmp_path, model_file):
    path = tmp_path / "acc.mcap"
    run_experiment(ExperimentConfig(duration=60, mode="acceleration", amplitude=100), path)
    args = ["diagnose", str(path), "--model", str(model_file), "--out", str(tmp_path / "d")]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2 and "acceleration-mode" in result.output


def test_diagnose_refuses_a_record_commanded_faster_than_the_model(tmp_path, model_file):
    """A healthy chirp commanded every 0.1 s, sampled at the model's 0.5 s, is not the
    command the wheel was given: diagnosed, it raised a current-limit alarm (a new user's
    trial, round 3). Refused as live diagnosis refuses it, saying what to do."""
    path = tmp_path / "fast.mcap"
    run_experiment(ExperimentConfig(signal="chirp", duration=60, Ts=0.1, seed=2), path)
    args = ["diagnose", str(path), "--model", str(model_file), "--out", str(tmp_path / "d")]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2 and "--Ts 0.5" in result.output, result.output
    assert not (tmp_path / "d").exists()


def test_dropout_count_takes_the_bus_rate_unless_the_reference_lost_more(model_file):
    """A 20-minute identification record's few lost frames are a poor loss rate: 3 lost
    (1.3 expected on the calibration's 640 h of the same bus) set the count at 4 frames a
    block, and a 0.3-s dropout (3 frames) went unseen with that model (units 1812, 2744).
    Such a reference takes the calibration's rate; one that lost far more than chance
    (a lossier bus) keeps its own, and a higher count."""
    import dataclasses

    from rwlab.diagnose import Diagnoser
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    ref = HealthyReference.from_model_file(model_file)

    def count(lost: int) -> int:
        own = dataclasses.replace(ref, lost_per_sample=(lost + 0.5) / ref.samples)
        return Diagnoser(wheel, own).thresholds["dropout"]

    assert count(0) == count(3) == 3
    assert count(40) > 3


def test_diagnose_refuses_a_model_without_reference(tmp_path, model_file):
    info = json.loads(model_file.read_text())
    del info["healthy_reference"]
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps(info))
    run_experiment(ExperimentConfig(duration=60), tmp_path / "r.mcap")
    args = [
        "diagnose",
        str(tmp_path / "r.mcap"),
        "--model",
        str(bare),
        "--out",
        str(tmp_path / "d"),
    ]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2 and "rwlab identify" in result.output


@pytest.mark.slow  # 9 s in the quick lane (-n 2, shared machine)
def test_diagnose_over_a_folder_writes_the_trend(tmp_path, model_file):
    folder = tmp_path / "wheel"
    folder.mkdir()
    for week, factor in enumerate((2.0, 2.6)):
        cfg = ExperimentConfig(duration=600, seed=20 + week, faults=(f"friction={factor}@0",))
        run_experiment(cfg, folder / f"week{week}.mcap")
    args = ["diagnose", str(folder), "--model", str(model_file), "--out", str(tmp_path / "d")]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output  # friction ×2 alarms: a script can tell
    trend = json.loads((tmp_path / "d" / "trend.json").read_text())
    sizes = [p["faults"]["friction"]["magnitude"] for p in trend["records"]]
    assert sizes[0] < sizes[1]  # the wear grows
    assert (tmp_path / "d" / "trend.html").exists()


@pytest.mark.slow
def test_a_fault_free_two_hour_record_raises_no_alarm(tmp_path, model_file):
    path = tmp_path / "healthy.mcap"
    run_experiment(ExperimentConfig(duration=7200, seed=1), path)
    result = CliRunner().invoke(
        main, ["diagnose", str(path), "--model", str(model_file), "--out", str(tmp_path / "d")]
    )
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "d" / "fdi.json").read_text())
    assert report["events"] == [] and report["verdict"].startswith("healthy")
    assert set(report["thresholds"]) >= {*MODEL_BASED, "speed_sensor_stuck"}
    assert "twin_calibration_rw90.json" in report["calibration"]  # the preset's default


@pytest.mark.parametrize(
    ("faults", "seed", "named", "at_alarm"),
    [
        # open issue (stop 63): friction ×2 is first read as a clamp at the current the
        # acceleration limit draws (0.58 A), re-labelled friction 25 s later; the RW90's
        # healthy clamp zone, measured down to 0.547 A while rounding made samples look
        # clamped, had hidden it. Named right by the record's end.
        (
            ("friction=2@200", "speed_sensor_stuck@400"),
            2,
            {"friction", "speed_sensor_stuck"},
            False,
        ),
        # a weak motor a first crossing had named a clamp (a new user's live run): named on
        # its onset's window once the crossing holds
        (("torque_constant=0.8@300",), 0, {"torque_constant"}, True),
    ],
)
def test_live_alarms_are_the_offline_alarms(tmp_path, model_file, faults, seed, named, at_alarm):
    path = tmp_path / "live.mcap"
    cfg = ExperimentConfig(duration=900, seed=seed, faults=faults, model=str(model_file))
    run_experiment(cfg, path)
    live = [e["message"] for e in read_record(path).topic("/event") if e["kind"] == "alarm"]
    offline = rwlab.diagnose(path, model_file).events  # the GLR pipeline on the record
    assert named <= {e.fault for e in offline}  # by the record's end
    if at_alarm:
        assert named <= {e.first for e in offline} and offline[0].first in named
    # the size at the alarm is the named fault's (the weak motor's was the clamp's fit)
    assert all(e.at_alarm.fault == e.first for e in offline)
    # the same alarms at the same times, named alike (the live line sizes the fault at the
    # alarm; the record's event follows it to the record's end), and each re-labelling
    alarms = [m for m in live if "re-labelled" not in m]
    assert [" ".join(m.split()[:4]) for m in alarms] == [
        f"{e.first} at {e.t_s:.1f} s" for e in offline
    ]
    relabelled = {" ".join(m.split()[:4]) for m in live if "re-labelled" in m}
    assert relabelled == {f"{e.fault} at {e.t_s:.1f} s" for e in offline if e.relabelled}


def test_friction_change_compares_a_unit_with_its_own_law():
    """Another unit (viscous ×1.25, Coulomb ×0.75, a 4 mA current offset) in holds at
    random speeds of both signs: against the reference's law its relative excess changes
    with speed; against its own law fitted on older samples it does not, until its
    friction steps ×1.5 at 1500 s (truth built here, not by the detector)."""
    from rwlab.diagnose.blocktests import FrictionChange
    from rwlab.diagnose.reference import BlockStats

    c = np.array([1.8e-3, 3.6e-6, 7e-3, 0.0])  # the reference's current model (A per unit)
    stats = BlockStats(0.0, 0.05, 20, 0.5, 0, "batch means")
    det = FrictionChange(stats, 0.15, cusum_threshold(1e6 / 40), 6, c)
    rng = np.random.default_rng(5)
    alarms, sizes, t = [], [], 0.0
    while t < 1800:
        speed = rng.choice([-1, 1]) * rng.uniform(1500, 6000)
        for _ in range(rng.integers(20, 60)):  # one hold, 0.5 s samples
            t += 0.5
            ref = c[1] * speed + c[2] * math.copysign(1, speed)
            unit = 1.25 * c[1] * speed + 0.75 * c[2] * math.copysign(1, speed)
            unit *= 1.5 if t >= 1500 else 1.0
            residual = unit - ref + 4e-3 + 5e-4 * rng.standard_normal()
            if det.add_sample(t, residual, speed, ref):
                alarms.append(t)
                sizes.append(1 + float(np.mean(det.since_change())))  # as the alarm sizes it
                det.restart()
    assert alarms and 1500 <= alarms[0] <= 1600, alarms
    assert sizes[0] == pytest.approx(1.5, abs=0.1)


def test_friction_change_compares_only_where_its_baseline_law_interpolates():
    """A PRBS's baseline holds +2000 to +4500 rpm and −5500 rpm: the law's split between
    Coulomb friction and sense offset rests on the prior about the reference's, so at
    −2000 rpm it extrapolates (unit 1372's healthy PRBS read 7 σ there with unit 1534's
    model). Samples there are not compared until the baseline reaches them; inside its
    span they are, on either sign."""
    from rwlab.diagnose.blocktests import GUARD_S, FrictionChange
    from rwlab.diagnose.reference import BlockStats

    c = np.array([1.8e-3, 3.6e-6, 7e-3, 0.0])
    det = FrictionChange(BlockStats(0.0, 0.05, 20, 0.5, 0, "batch means"), 0.15, 50.0, 2, c)

    def hold(t0: float, speed: float, n: int = 60) -> int:
        """Feed one healthy hold; how many of its samples the test compared."""
        before = len(det.raw)
        for i in range(n):
            ref = c[1] * speed + c[2] * math.copysign(1, speed)
            det.add_sample(t0 + 0.5 * i, 0.0, speed, ref)
        return len(det.raw) - before

    t = 0.0
    for speed in (2000.0, 4500.0, -5500.0, 3000.0):
        hold(t, speed)
        t += 30.0
    t += GUARD_S  # every hold above is in the baseline now
    assert hold(t, -2000.0) == 0  # below the negative span: not compared
    assert hold(t + 30, 3500.0) == 60  # inside the positive span
    assert hold(t + 60, -5400.0) == 60  # within the margin of the negative span


def test_friction_change_law_fits_its_own_baseline_when_units_differ_in_offset():
    """A healthy unit 9 mA off its reference in sense offset and 7 mA in Coulomb current
    (unit 1604's PRBS with unit 1832's model): its holds' residuals run from −6 to +19 mA
    between signs and speeds. That is the law's signal, not noise: taken as noise it let
    the prior outweigh the data, and the law missed the unit's own +1700 rpm hold by
    7 mA, so its later holds near there read a friction rise (+0.2 here, the noise left
    at 2 mA; that record's read 6 σ)."""
    from rwlab.diagnose.blocktests import GUARD_S, FrictionChange
    from rwlab.diagnose.reference import BlockStats

    c = np.array([1.8e-3, 3.6e-6, 7e-3, 0.0])
    det = FrictionChange(BlockStats(0.0, 0.05, 20, 0.5, 0, "batch means"), 0.15, 50.0, 2, c)
    rng = np.random.default_rng(3)

    def hold(t0: float, speed: float, n: int = 60) -> list[float]:
        """Feed one healthy hold; the values it was compared with (relative excess)."""
        before = len(det.raw)
        for i in range(n):
            sign = math.copysign(1, speed)
            ref = c[1] * speed + c[2] * sign
            excess = 1.3e-6 * speed + 7e-3 * sign + 9e-3 + 2e-3 * rng.standard_normal()
            det.add_sample(t0 + 0.5 * i, excess, speed, ref)
        return [v for _, v in list(det.raw)[before:]]

    t = 0.0
    for speed in (1700.0, -1700.0, -3700.0, -5900.0, 4100.0, 1700.0):
        hold(t, speed)
        t += 30.0
    values = hold(t + GUARD_S, 1950.0)
    assert len(values) == 60 and abs(np.mean(values)) < 0.1, np.mean(values)


def test_a_rate_a_detector_cannot_deliver_is_warned_about(tmp_path, model_file):
    # the twin's healthy units stay within their tolerance of the reference's: the absolute
    # friction test never alarmed on the calibration's healthy hours, so 100/h is refused
    # in words (the thresholds still set), not silently delivered as none
    from rwlab.diagnose import Diagnoser
    from rwlab.diagnose.calibration import Curve, ThresholdCalibration
    from rwlab.errors import RwlabWarning
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    reference = HealthyReference.from_model_file(model_file)
    k = Diagnoser(wheel, reference, calibration=False)._detectors["friction"].k
    never = Curve("cusum", (0.0, 5.0), (0, 0), k, 560)  # no alarm in 8 h at any threshold
    cal = ThresholdCalibration(wheel.Ts, 8.0, {"friction@1": never})
    with pytest.warns(RwlabWarning, match="friction: .*cannot deliver 100/h"):
        d = Diagnoser(wheel, reference, false_alarms_per_hour=100.0, calibration=cal)
    assert any(n.startswith("friction:") for n in d.notes)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the default rate is below what hours can resolve:
        # no warning, but each threshold whose rate is not measured says so
        for d in (Diagnoser(wheel, reference, calibration=cal), Diagnoser(wheel, reference)):
            assert d.notes and all(
                "not" in n and ("verified" in n or "measured" in n) for n in d.notes
            ), d.notes
    path = tmp_path / "healthy.mcap"
    run_experiment(ExperimentConfig(duration=60, seed=5), path)
    out = tmp_path / "d"
    args = ["diagnose", str(path), "--model", str(model_file), "--out", str(out), "--rules"]
    result = CliRunner().invoke(main, [*args, "--false-alarms", "100"])
    assert result.exit_code == 0, result.output
    assert "warning: " in result.output and "/h" in result.output
    notes = json.loads((out / "diagnosis.json").read_text())["threshold_notes"]
    assert any("cannot deliver 100/h" in n for n in notes)


def test_a_calibration_over_two_model_units_counts_each_with_its_own_reference(
    tmp_path, model_file
):
    """Two references (the second as from a unit whose friction test scatters 30 % more)
    over one healthy record: hours count records × models, each CUSUM is counted with each
    model's own k (they differ) over shares of its tolerance, and every curve's alarms are
    those of each model counted alone."""
    from dataclasses import replace

    from rwlab.diagnose import Diagnoser, measure_calibration
    from rwlab.diagnose.calibration import SHARES
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    ref_a = HealthyReference.from_model_file(model_file)
    f = ref_a.tests["friction"]
    ref_b = replace(ref_a, tests={**ref_a.tests, "friction": replace(f, sigma=1.3 * f.sigma)})
    path = tmp_path / "healthy.mcap"
    run_experiment(ExperimentConfig(duration=240, seed=6, unit=6), path)
    data = load_record(path, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf)
    both = measure_calibration([data], wheel, ref_a, more_models=((wheel, ref_b),))
    a = measure_calibration([data], wheel, ref_a)
    b = measure_calibration([data], wheel, ref_b)
    assert both.hours == pytest.approx(2 * data.N * data.Ts / 3600)
    k = [Diagnoser(wheel, r, calibration=False)._detectors["friction"].k for r in (ref_a, ref_b)]
    assert min(k) < max(k)  # each model counted at its own k, over shares of its tolerance
    assert both.curves["friction@1"].k == pytest.approx(np.median(k))
    assert {c.share for key, c in both.curves.items() if key.startswith("friction@")} == set(SHARES)
    for name, curve in both.curves.items():
        total = np.add(a.curves[name].alarms, b.curves[name].alarms)
        assert curve.alarms == tuple(total), name


def _holds(diagnoser, factor: float, hours: float = 0.5, seed: int = 0, **kw) -> list:
    """Holds at ±3000 rpm (two minutes each) of a unit whose friction current is ``factor``
    × the datasheet's nominal (truth from the RW90's parameters, 1 mA of noise); the
    friction alarms (``detector``: another test's)."""
    rng = np.random.default_rng(seed)
    viscous = RW90.viscous_friction / RW90.torque_constant * 2 * math.pi / 60  # A per rpm
    coulomb = RW90.coulomb_friction / RW90.torque_constant  # A
    v_factor, speeds = kw.get("viscous", factor), kw.get("speeds", lambda t: 3000.0)
    alarms = []
    for k in range(int(hours * 3600 / 0.5)):
        speed = math.copysign(speeds(0.5 * k), 1 if (k // 240) % 2 == 0 else -1)
        current = math.copysign(v_factor * viscous * abs(speed) + factor * coulomb, speed)
        alarms += diagnoser.update(0.5 * k, speed, speed, current + rng.normal(0, 1e-3), 0.0)
    return [a for a in alarms if a.detector == kw.get("detector", "friction")]


def test_a_low_friction_reference_does_not_alarm_on_a_high_friction_healthy_unit(model_file):
    """A reference identified on a unit at the datasheet's lower friction bound, whose fit
    also put the viscous part low (unit 100's: 0.5 of nominal viscous, 0.7 Coulomb), and a
    healthy unit at the upper bound (1.3 × nominal): 1.25 of relative excess at 3000 rpm,
    beyond the constant tolerance (0.86) but within the datasheet's spread: no alarm.
    The same unit with friction × 1.5 alarms."""
    from rwlab.diagnose import Diagnoser
    from rwlab.diagnose.reference import BlockStats
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    viscous = RW90.viscous_friction / RW90.torque_constant * 2 * math.pi / 60
    coulomb = RW90.coulomb_friction / RW90.torque_constant
    c0 = HealthyReference.from_model_file(model_file).current_model[0]
    stats = {
        "friction": BlockStats(0.0, 0.08, 20, 0.3, 900, "batch means"),
        "motor": BlockStats(0.0, 0.035, 10, 0.3, 900, "batch means"),
        "speed": BlockStats(0.0, 0.1, 20, 0.2, 400, "batch means"),
        "lag": BlockStats(0.0, 0.005, 10, 0.2, 600, "batch means"),
    }
    low = HealthyReference(
        0.5, (c0, 0.5 * viscous, 0.7 * coulomb, 0.0), stats, 0.01, 1000, 1e-4, 2400
    )

    def fresh():
        return Diagnoser(wheel, low, calibration=False)

    assert _holds(fresh(), 1.3) == []
    assert _holds(fresh(), 1.3 * 1.5) != []
    # the change test: a healthy unit of high viscous friction, held at 2000 rpm first and
    # at 5500 rpm later; its own law from the first holds is shrunk towards the reference's
    # by the datasheet's spread (with 30 % of this low reference's currents the law stayed
    # near the reference's and the unit's own friction alarmed, at 580 s)
    later = {"viscous": 1.3, "speeds": lambda t: 2000.0 if t < 900 else 5500.0}
    assert _holds(fresh(), 1.0, 0.75, detector="friction_change", **later) == []


# -- faults during a chirp: the speed offset and the slew asymmetry ----------------------


def test_speed_offset_is_the_residual_at_zero_speed_whatever_the_model_mismatch():
    """A residual made of a gain error, a lag (acceleration) term, a Coulomb-like term and a
    constant bias, with noise: the window's offset is the bias (truth built here); holds and
    a window that never crosses zero speed do not qualify."""
    from rwlab.diagnose.motion import OFFSET_WINDOW, speed_offset

    rng = np.random.default_rng(3)
    t = 0.5 * np.arange(OFFSET_WINDOW)
    model = 800 * np.sin(2 * np.pi * t / 13.0)
    accel = np.gradient(model, 0.5)
    for bias in (-20.0, 0.0, 12.5):
        rs = bias + 0.01 * model + 0.02 * accel + 3 * np.sign(model)
        rs += rng.normal(0, 1.0, model.size)
        window = np.column_stack([rs, model, accel, np.ones_like(t)])
        assert speed_offset(window) == pytest.approx(bias, abs=1.0)
    held = np.column_stack([rs, model, accel, (np.arange(t.size) % 10 == 0).astype(float)])
    assert speed_offset(held) is None  # a stepped command: the held-speed test's
    one_sided = np.column_stack([rs, model + 2000, accel, np.ones_like(t)])
    assert speed_offset(one_sided) is None  # an intercept would be an extrapolation


def _slew(toward: float, away: float, rising: bool = True, step: float = 0.02):
    """A slew through zero: 8 samples each side at 0.5 s, the half towards zero at
    ``toward`` rpm/s and the half away at ``away``; the current steps by ``step`` A."""
    sign = 1 if rising else -1
    first = [(0.5 * k, sign * (-2000 + toward * 0.5 * k), -0.54 * sign) for k in range(8)]
    t0, w0 = first[-1][0] + 1.0, sign * 150.0
    second = [(t0 + 0.5 * k, w0 + sign * away * 0.5 * k, sign * (step - 0.54)) for k in range(8)]
    return first + second


def test_slew_asymmetry_reads_friction_the_feed_forward_does_not_know():
    from rwlab.diagnose.motion import slew_asymmetry

    c = (1.8e-3, 2.5e-6, 9e-3, 0.0)  # the Coulomb deceleration c2/c0 = 5 rpm/s
    for rising in (True, False):
        assert slew_asymmetry(_slew(314, 314, rising), c) == pytest.approx(0.0, abs=1e-9)
        # a friction 5 rpm/s beyond the feed-forward's: towards zero +5, away −5
        assert slew_asymmetry(_slew(319, 309, rising), c) == pytest.approx(2.0)
    assert slew_asymmetry(_slew(319, 309, step=0.0), c) is None  # a clamped current
    assert slew_asymmetry(_slew(319, 309)[:10], c) is None  # too short a half


def test_a_clamped_slew_reads_the_whole_friction_whatever_the_motor():
    """At a clamped current I·α = k_t·i ∓ friction on the two halves, so half the rates'
    difference is the friction deceleration; a slew whose current steps at zero speed
    (the feed-forward at the acceleration limit) is no clamped slew."""
    from rwlab.diagnose.motion import clamped_deceleration

    for rising in (True, False):
        decel, speed = clamped_deceleration(_slew(260, 240, rising, step=0.0))
        assert decel == pytest.approx(10.0)
        # the inner samples in the band: 7 of the half towards zero, 7 of the one away
        towards = [2000 - 260 * 0.5 * k for k in range(1, 8)]
        away = [150 + 240 * 0.5 * k for k in range(7)]
        assert speed == pytest.approx(np.mean(towards + away))
    assert clamped_deceleration(_slew(319, 309)) is None  # a feed-forward step of 20 mA
    assert clamped_deceleration(_slew(260, 240, step=0.0)[:10]) is None  # too short a half


def _own_friction_a(speed_rpm: float) -> float:
    """A unit's friction current (A) unlike the reference's: 3e-6 A/rpm and 8 mA."""
    return 3e-6 * abs(speed_rpm) + 8e-3


@pytest.mark.parametrize("factor", [1.0, 1.5])
def test_the_clamped_test_compares_a_slew_with_the_units_own_friction(factor):
    """Own slow samples of a unit whose friction and sense offset differ from the
    reference's, then clamped slews whose deceleration is ``factor`` × that friction:
    each value is factor − 1 exactly (noise-free), the test decides from the second slew
    on, alarms only on worn bearings, and samples after the first slew do not move it."""
    from rwlab.diagnose.blocktests import CLAMP_EXCESS, ClampedFriction

    c = np.array([1.8e-3, 2.5e-6, 9e-3, -1e-3])
    test = ClampedFriction(c, CLAMP_EXCESS)
    for w in np.r_[np.linspace(300, 5000, 200), -np.linspace(300, 5000, 200)]:
        current = np.sign(w) * _own_friction_a(w) + 2e-3  # its own offset: 2 mA
        test.add_own(current - c @ [0.0, w, np.sign(w), 1.0], w)
    decel = [factor * _own_friction_a(w) / c[0] for w in (1500.0, 900.0)]
    assert not test.add_slew(10.0, decel[0], 1500.0)  # one slew decides nothing
    test.add_own(1.0, 3000.0)  # after the first slew: not the unit's own friction
    assert test.add_slew(20.0, decel[1], 900.0) == (factor > 1 + CLAMP_EXCESS)
    assert [v for _, v, _ in test.values] == pytest.approx([factor - 1] * 2, abs=1e-6)
    assert not test.add_slew(30.0, 2 * decel[1], 400.0)  # a slow slew is not compared
    assert len(test.values) == 2


def test_slew_asymmetry_in_nominal_units_does_not_depend_on_the_reference_split():
    """Two references whose current models split friction differently (unit 300's
    identified c2/c0 was 3.2 rpm/s, unit 0's 5.1) read one slew alike in the datasheet's
    Coulomb decelerations: the physics (rpm/s) over a fixed unit."""
    from rwlab.diagnose.motion import slew_asymmetry
    from rwlab.diagnose.reference import nominal_coulomb_deceleration

    scale = nominal_coulomb_deceleration()
    # τ_c/I of the RW90's datasheet values, rpm/s (truth: the parameters, not the code)
    assert scale == pytest.approx(RW90.coulomb_friction / RW90.inertia * 60 / (2 * math.pi))
    low, high = (1.8e-3, 2.9e-6, 5.6e-3, 0.0), (1.8e-3, 2.5e-6, 9.2e-3, 0.0)
    seg = _slew(314 + scale, 314 - scale)  # one nominal Coulomb deceleration each way
    assert slew_asymmetry(seg, low, scale) == pytest.approx(2.0)
    assert slew_asymmetry(seg, high, scale) == pytest.approx(2.0)
    assert slew_asymmetry(seg, low) != pytest.approx(slew_asymmetry(seg, high))  # the old unit


def _slew_reference(sigma: float, samples: int = 10):
    from rwlab.diagnose.reference import BlockStats, nominal_coulomb_deceleration

    stats = {
        "friction": BlockStats(0.2, 0.08, 20, 0.3, 900, "batch means"),
        "slew": BlockStats(-0.8, sigma, 1, 0.004, samples, "AR(1)"),
    }
    return HealthyReference(
        0.5, (1.8e-3, 2.9e-6, 5.6e-3, 0.0), stats, 0.01, 1000, 1e-4, 2400,
        slew_scale_rpm_s=nominal_coulomb_deceleration(),
    )  # fmt: skip


def test_a_slew_reference_from_ten_slews_does_not_set_the_healthy_spread(model_file):
    """A reference whose 10 slews happened to scatter little (σ 0.13, unit 300's) against
    healthy units whose slews scatter with the tune set's σ: the detector's σ is the
    larger, and its tolerance holds the reference level's own standard error, so healthy
    slews (drawn here from the twin's measured spread, independent of the code) do not
    alarm; with the reference's σ they would."""
    from rwlab.diagnose import Diagnoser
    from rwlab.diagnose.detect import cusum_threshold
    from rwlab.diagnose.motion import SLEW_SIGMA
    from rwlab.wheel import IdentifiedWheel

    wheel = IdentifiedWheel.from_json(model_file)
    narrow = _slew_reference(0.13)
    det = Diagnoser(wheel, narrow, calibration=False)._detectors["slew"]
    assert det.stats.sigma == SLEW_SIGMA
    se = 1.959964 * SLEW_SIGMA / math.sqrt(10)
    assert det.k == pytest.approx(0.5 + math.hypot(0.3, se) / SLEW_SIGMA)
    rng = np.random.default_rng(42)
    slews = -0.8 + 0.15 + rng.normal(0.0, SLEW_SIGMA, 2000)  # a unit 0.15 off the reference
    h = cusum_threshold(200.0, 0.5)  # an ARL of 200 slews without a tolerance

    def alarms(stats_sigma, k):
        up, n = 0.0, 0
        for x in slews:
            up = max(0.0, up + (x + 0.8) / stats_sigma - k)
            if up > h:
                n, up = n + 1, 0.0
        return n

    assert alarms(det.stats.sigma, det.k) <= 2  # within the 2000 slews' sampling
    assert alarms(0.13, 0.5 + 0.3 / 0.13) > 10  # the reference's own σ: alarm after alarm


@pytest.fixture(scope="module")
def unit_model_file(tmp_path_factory):
    """As the bench and the package's thresholds: identified on unit 0's 20-minute PRBS."""
    out = tmp_path_factory.mktemp("ident_unit0")
    run_experiment(ExperimentConfig(duration=1200, seed=0, unit=0), out / "prbs.mcap")
    result = CliRunner().invoke(main, ["identify", str(out / "prbs.mcap"), "--out", str(out / "m")])
    assert result.exit_code == 0, result.output
    return out / "m" / "model.json"


@pytest.mark.slow
def test_a_biased_sensor_and_worn_bearings_are_named_during_a_chirp(tmp_path, unit_model_file):
    """The wheel never holds a speed: a 15 rpm bias and friction ×1.5 from 600 s of a
    15-minute chirp (other units than the model's) are found within 300 s and named."""
    found = {}
    for fault, seed in (("speed_sensor_bias=15@600", 31), ("friction=1.5@600", 32)):
        path = tmp_path / f"{seed}.mcap"
        cfg = ExperimentConfig(signal="chirp", duration=900, seed=seed, unit=seed, faults=(fault,))
        run_experiment(cfg, path)
        alarms = _diagnose(path, unit_model_file).alarms
        assert alarms and all(600 <= a.t_s <= 900 for a in alarms), alarms
        found[fault] = alarms[0]
    bias = found["speed_sensor_bias=15@600"]
    assert bias.kind == "speed_sensor_bias" and bias.ci[0] <= 15 <= bias.ci[1]
    worn = found["friction=1.5@600"]
    assert worn.kind == "friction" and worn.ci[0] <= 1.5 <= worn.ci[1]


@pytest.mark.slow
def test_a_healthy_chirp_of_another_unit_raises_no_alarm(tmp_path, unit_model_file):
    path = tmp_path / "chirp.mcap"
    run_experiment(ExperimentConfig(signal="chirp", duration=1200, seed=33, unit=33), path)
    result = _diagnose(path, unit_model_file)
    assert result.alarms == []
    # against any healthy unit, the estimates' intervals hold the healthy values (the
    # record-noise ones need not: unit 33 is not unit 0)
    healthy = {"friction": 1.0, "torque_constant": 1.0, "speed_sensor_bias": 0.0}
    assert "torque_constant" in result.estimates
    for kind, e in result.estimates.items():
        lo, hi = e["ci95_units"]
        assert lo <= healthy[kind] <= hi, (kind, e)
        assert lo <= e["ci95"][0] <= e["ci95"][1] <= hi


def test_a_sensor_frozen_at_rest_from_power_up_is_not_a_current_limit(tmp_path, model_file):
    """The reading stays 0 rpm while the wheel draws its full current at the model's
    acceleration limit: the lag test fires first, and names the frozen sensor."""
    path = tmp_path / "frozen.mcap"
    cfg = ExperimentConfig(duration=300, seed=41, unit=301, faults=("speed_sensor_stuck@0",))
    run_experiment(cfg, path)
    result = _diagnose(path, model_file)
    assert result.alarms and {a.kind for a in result.alarms} == {"speed_sensor_stuck"}
    assert result.estimates == {}  # every estimate rests on the frozen reading
    # the stuck test had no moving non-zero reading to decide on, but the fault was seen
    assert result.coverage["stuck"]["decided"] == 0
    assert "speed_sensor_stuck" not in result.unseen()


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.040, 0.045, 0.055])
def test_a_nominal_model_with_any_timing_raises_no_alarm_on_a_healthy_chirp(
    tmp_path_factory, model_file, delay_s
):
    """As a README user: the model identified on the nominal wheel (no ``--unit``), a
    healthy chirp of another unit. Models of healthy units differ in their servo delay
    by a few ms (0.047–0.050 s on units 0, 7, 400 and the nominal); at a fast chirp's
    reversals that timing decided whether the lag test alarmed (it did at 0.040 and
    0.045 s). No alarm for delays within ±5 ms of the identified one."""
    import dataclasses

    from rwlab.wheel import IdentifiedWheel

    path = tmp_path_factory.getbasetemp() / "chirp_unit501.mcap"
    if not path.exists():
        run_experiment(ExperimentConfig(signal="chirp", duration=1200, seed=501, unit=501), path)
    fitted = IdentifiedWheel.from_json(model_file)
    assert fitted.servo is not None and abs(fitted.servo.delay - 0.05) < 0.005
    wheel = IdentifiedWheel(
        fitted.model,
        input_offset=fitted.u0,
        output_offset=fitted.y0,
        speed_limit_rpm=fitted.speed_limit_rpm,
        accel_limit_rpm_s=fitted.accel_limit_rpm_s,
        servo=dataclasses.replace(fitted.servo, delay=delay_s),
    )
    data = load_record(path, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf)
    alarms = diagnose(data, wheel, HealthyReference.from_model_file(model_file)).alarms
    assert alarms == [], alarms


@given(
    bias=st.sampled_from([-25.0, -10.0, 10.0, 15.0, 20.0]),
    noise=st.lists(
        st.integers(-299, 299).filter(lambda x: abs(x) >= 50).map(lambda x: x / 10),
        min_size=8,
        max_size=40,
        unique=True,
    ),
)
def test_rest_reading_names_the_value_a_bias_reads_at_zero_speed(bias, noise):
    """Healthy: the no-edge reading is 0 between chance readings, never an alarm; with a
    bias every no-edge reading is the bias, and the readings between are the bias plus a
    speed the Hall edges measured (≥ the twin's 5 rpm): the fourth names it."""
    from rwlab.diagnose.motion import RestReading

    healthy = RestReading(4)
    readings = [v for x in noise for v in (x, x, x, 0.0)]  # ≤ 3 of a value, then a 0
    assert not any(healthy.add(v) for v in readings)
    biased = RestReading(4)
    fired = []
    for x in [x for x in noise if bias + x != 0][:7]:  # chance readings between, once each
        fired.append(biased.add(bias + x))
        fired.append(biased.add(bias))
    assert fired.index(True) == 7 and biased.value == bias


def test_rest_reading_is_silent_on_a_repeating_motions_near_equal_readings():
    """A chirp's fast end rocks a healthy wheel through zero at one amplitude: each pass
    reads nearly the same low speed, now and then exactly (unit 1305's chirp: −11.8 rpm
    five times, no 0 between). Near-equal readings are a motion, not a bias's one value;
    without the rule the fourth −11.8 alarms."""
    from rwlab.diagnose.motion import RestReading

    passes = [-10.8, -12.1, -11.9, -11.8, -11.8, -11.8, -12.2, -11.9, -11.8, -11.7, -12.2]
    test = RestReading(4)
    assert not any(test.add(v) for v in passes)
    exact = RestReading(4)  # the same passes with the near readings left out
    assert any(exact.add(v) for v in passes if v == -11.8)


def _chirp_alarms(tmp_path, model_file, unit: int, faults: tuple[str, ...]) -> list:
    """The alarms on a 15-minute chirp of another unit (seed = unit) with ``faults``."""
    path = tmp_path / "chirp.mcap"
    cfg = ExperimentConfig(signal="chirp", duration=900, seed=unit, unit=unit, faults=faults)
    run_experiment(cfg, path)
    return _diagnose(path, model_file).alarms


@pytest.mark.slow
def test_a_clamp_and_a_biased_sensor_are_both_named_during_a_chirp(tmp_path, model_file):
    """A 0.45 A clamp and a −15 rpm bias from 480 s of a 15-minute chirp of another unit:
    the clamped wheel passes through zero when the model does not, and the bias is still
    read there, to its value: within 200 s (165 s; with the model's crossings alone 254 s,
    and 385 s on the bench's unit 370)."""
    faults = ("current_limit=0.45@480", "speed_sensor_bias=-15@480")
    alarms = _chirp_alarms(tmp_path, model_file, 504, faults)
    assert alarms and all(480 <= a.t_s <= 680 for a in alarms), alarms
    assert {a.kind for a in alarms} == {"current_limit", "speed_sensor_bias"}, alarms
    bias = next(a for a in alarms if a.kind == "speed_sensor_bias")
    assert bias.ci is not None and bias.ci[0] <= -15 <= bias.ci[1], bias


@pytest.mark.slow
def test_worn_bearings_behind_a_clamp_are_both_named_during_a_chirp(tmp_path, model_file):
    """Friction × 1.5 and a 0.45 A clamp from 480 s of a 15-minute chirp of another unit:
    the clamped slews carry the whole friction, against the unit's own before (the slew
    test reads only a feed-forward's excess, which a clamp removes): both named within
    300 s, the friction's interval holding 1.5."""
    faults = ("friction=1.5@480", "current_limit=0.45@480")
    alarms = _chirp_alarms(tmp_path, model_file, 505, faults)
    assert alarms and all(480 <= a.t_s <= 780 for a in alarms), alarms
    found = {a.kind: a for a in alarms}
    assert set(found) == {"current_limit", "friction"}, alarms
    friction = found["friction"]
    assert friction.detector == "clamped" and friction.ci[0] <= 1.5 <= friction.ci[1], friction


@pytest.mark.slow
def test_a_weak_motor_and_a_biased_sensor_are_both_named_during_a_chirp(tmp_path, model_file):
    """k_t × 0.8 and a 20 rpm bias from 600 s of a 15-minute chirp of another unit (the
    wheel cannot follow the model's acceleration): both named within 300 s, with the
    nominal model, the bias to its reading's quantum."""
    faults = ("torque_constant=0.8@600", "speed_sensor_bias=20@600")
    alarms = _chirp_alarms(tmp_path, model_file, 502, faults)
    assert alarms and all(600 <= a.t_s <= 900 for a in alarms), alarms
    found = {a.kind: a for a in alarms}
    assert set(found) == {"torque_constant", "speed_sensor_bias"}, alarms
    kt, bias = found["torque_constant"], found["speed_sensor_bias"]
    assert kt.ci[0] <= 0.8 <= kt.ci[1] and bias.ci[0] <= 20 <= bias.ci[1]


@pytest.mark.slow  # 8 s in the quick lane (-n 2, shared machine)
def test_a_current_sense_offset_leaves_the_friction_test_unchanged(tmp_path, model_file):
    """Units differ by ±5 mA of current-sense offset, as much as the friction current
    at 500 rpm. The same record with 5 mA added to every current reading gives the
    friction test the same block values (the offset cancels between speed signs)."""
    from rwlab.diagnose.diagnoser import Diagnoser
    from rwlab.diagnose.diagnosis import record_columns
    from rwlab.wheel import IdentifiedWheel

    path = tmp_path / "prbs.mcap"
    run_experiment(ExperimentConfig(duration=600, seed=503, unit=503), path)
    wheel = IdentifiedWheel.from_json(model_file)
    ref = HealthyReference.from_model_file(model_file)
    data = load_record(path, wheel.Ts, outputs=("speed", "current", "age", "lost"), max_gap=np.inf)
    traces = []
    for shift_a in (0.0, 0.005):
        diag = Diagnoser(wheel, ref, calibration=False, trace=True)
        columns = list(record_columns(data, wheel))
        columns[3] = columns[3] + shift_a  # a copy: the record's array is not touched
        for row in zip(*columns, strict=True):
            diag.update(*(float(x) for x in row))
        traces.append(np.array(diag.traces()["friction"]))
    assert traces[0].size >= 5
    np.testing.assert_allclose(traces[1], traces[0], atol=1e-6)


def test_the_clamped_size_interval_holds_the_spread_between_units():
    """Two clamped slews reading +0.40 and +0.41 over the unit's own friction: the size
    is 1.405; its interval is not their scatter (0.007) but at least the healthy level's
    spread between units (σ 0.12): half-width ≥ 1.96 × 0.12."""
    from rwlab.diagnose.isolate import CLAMP_LEVEL_SD, Z95, isolate

    (found,) = isolate("clamped", {"clamped": (np.array([0.40, 0.41]), 0.0)})
    assert found.kind == "friction" and found.magnitude == pytest.approx(1.405)
    lo, hi = found.ci
    assert hi - found.magnitude == pytest.approx(found.magnitude - lo)
    assert hi - found.magnitude >= Z95 * CLAMP_LEVEL_SD


def _step_charge_values(factor: float, path_rpm: tuple[float, ...]) -> list[float]:
    """StepCharge's values for a model that moves at 300 rpm/s through ``path_rpm`` (each
    level held 60 s) and a wheel of k_t × ``factor`` behind it: at the limit the
    controller's current (the reference's I/k_t × 300 rpm/s) for 1/factor as long (the
    last, partial sample's share of it), then the unit's own friction (3e-6 A/rpm, 8 mA,
    and a 2 mA offset: not the reference's) at the wheel's speed."""
    from rwlab.diagnose.motion import StepCharge

    c = np.array([1.8e-3, 2.5e-6, 9e-3, -1e-3])
    Ts, rate = 0.5, 300.0
    test = StepCharge(c, Ts, quiet_rpm_s=10.0)
    model = wheel = path_rpm[0]
    values, t = [], 0.0
    for target in path_rpm:
        for _ in range(round(60 / Ts)):
            t += Ts
            step_model = float(np.clip(target - model, -rate * Ts, rate * Ts))
            step_wheel = float(np.clip(target - wheel, -factor * rate * Ts, factor * rate * Ts))
            model, wheel = model + step_model, wheel + step_wheel
            inertial = c[0] * step_wheel / Ts / factor  # what moved the wheel so
            current = inertial + np.sign(wheel) * (3e-6 * abs(wheel) + 8e-3) + 2e-3
            value = test.add(t, model, step_model / Ts, current)
            if value is not None:
                values.append(value)
    return values


@pytest.mark.parametrize("factor", [1.0, 0.8, 0.6])
def test_a_speed_changes_charge_is_the_inertial_charge_over_the_motor_factor(factor):
    """From settled level to settled level the current beyond friction carries
    I·Δω/k_t whatever the path: a motor of k_t × F draws 1/F of the reference's, taking
    1/F as long at the controller's current; the unit's own friction and offset cancel
    between the two settled ends, exactly where the wheel follows the model and keeps
    one sign (through zero the unit's Coulomb current, 1 mA from the reference's, leaves
    0.05 %: the shift between the ends is linear in speed, the difference is not). A weak
    wheel lags the model, so its friction (at its own speed, not the model's: the Coulomb
    sign turns later) takes up to 1 % of the charge, always making it read low."""
    values = np.array(_step_charge_values(factor, (1000.0, 4000.0, 1500.0, -2500.0)))
    assert len(values) == 3
    if factor == 1:
        assert values[:2] == pytest.approx(1.0, rel=1e-9)
        assert values[2] == pytest.approx(1.0, rel=1e-3)
    else:
        assert np.all(values < 1 / factor) and values == pytest.approx(1 / factor, rel=0.01)


def test_a_small_or_reversing_speed_change_gives_no_charge():
    """Below 1000 rpm, or where the model's path between two settled levels is longer
    than the net change (an overshoot), the friction law's error is no longer small."""
    from rwlab.diagnose.motion import StepCharge

    assert _step_charge_values(1.0, (1000.0, 1800.0)) == []
    test = StepCharge(np.array([1.8e-3, 2.5e-6, 9e-3, -1e-3]), 0.5, quiet_rpm_s=10.0)
    speeds = np.r_[[0.0] * 40, np.linspace(0, 4000, 30), np.linspace(4000, 2000, 15), [2000.0] * 60]
    accels = np.r_[0.0, np.diff(speeds) / 0.5]
    samples = enumerate(zip(speeds, accels, strict=True))
    assert all(test.add(0.5 * k, w, a, 0.01) is None for k, (w, a) in samples)


def test_a_weak_motor_behind_a_frozen_reading_is_compared_with_the_units_own_level():
    """Changes that settled before the freeze set the unit's level; one under way at it
    (a weak motor that came with the freeze is in part of it) counts for nothing; each
    one begun after it alarms beyond that level × (1 + CHARGE_EXCESS), or without a
    level beyond the reference's headroom and CHARGE_MARGIN."""
    from rwlab.diagnose.blocktests import CHARGE_EXCESS, CHARGE_MARGIN, FrozenMotor

    test = FrozenMotor(headroom=0.07)
    assert test.h == pytest.approx(0.07 + CHARGE_MARGIN)
    for start, end, value in ((10, 40, 1.30), (60, 90, 0.94), (95, 130, 1.50)):
        assert not test.add(value, start, end, frozen_s=None)  # no stuck alarm yet
    # the reading froze at 100 s (the alarm came later): the third change straddles it
    assert not test.add(2.0, start_s=99.0, end_s=140.0, frozen_s=100.0)
    level = np.median([1.30, 0.94])
    assert not test.add(level * (1 + CHARGE_EXCESS) * 0.999, 150.0, 180.0, frozen_s=100.0)
    assert test.h == CHARGE_EXCESS
    assert test.add(level * 1.25, 300.0, 330.0, frozen_s=100.0)
    assert test.values == pytest.approx([(1 + CHARGE_EXCESS) * 0.999, 1.25])
    assert test.decided == 2
    values, own = test.recent()
    assert own == 2 and values == pytest.approx(test.values)
    alone = FrozenMotor(headroom=0.07)  # frozen from power-up: the reference's level
    assert not alone.add(1.10, 20.0, 50.0, frozen_s=0.0)
    assert alone.add(1.12, 60.0, 90.0, frozen_s=0.0) and alone.recent()[1] == 0


@pytest.mark.parametrize("factor", [1.0, 0.8])
def test_a_weak_motor_is_named_behind_a_frozen_reading(tmp_path, model_file, factor):
    """Steps of another unit, the reading frozen at a 0-rpm hold at 300 s (with k_t × F):
    the stuck sensor is named when the next step begins, and a weak motor (only then) from
    that step's charge, its interval holding 0.8; the diagnosis no longer lists the motor
    among the faults it could not see after the freeze."""
    faults = ("speed_sensor_stuck@300",) + ((f"torque_constant={factor}@300",) * (factor != 1))
    path = tmp_path / "steps.mcap"
    run_experiment(
        ExperimentConfig(signal="step", duration=600, seed=506, unit=506, faults=faults), path
    )
    result = _diagnose(path, model_file)
    found = {a.kind: a for a in result.alarms}
    assert all(a.t_s >= 300 for a in result.alarms), result.alarms
    if factor == 1:
        assert set(found) == {"speed_sensor_stuck"}, result.alarms
    else:
        assert set(found) == {"speed_sensor_stuck", "torque_constant"}, result.alarms
        kt = found["torque_constant"]
        assert kt.detector == "charge" and kt.ci[0] <= factor <= kt.ci[1], kt
    assert result.coverage["charge"]["decided"] >= 1
    assert "torque_constant" not in result.blind()


def _held_speed_evidence(held_error_rpm: float, command_rpm: float) -> dict:
    """What isolation reads after a held-speed alarm: the same reading, block after block."""
    return {
        "speed": np.full(6, held_error_rpm),
        "held_command_rpm": command_rpm,
        "recent_speed": np.full(8, command_rpm + held_error_rpm),
        "sigma": {"speed": 0.5},
        "ref_mean": {"speed": 0.0},
    }


@pytest.mark.parametrize("bias", [-18.0, 8.0, 15.0])
def test_a_constant_reading_of_a_wheel_resting_at_zero_is_a_bias_not_a_stuck_sensor(bias):
    """A resting wheel's Hall reading is exactly 0 (no edge comes): a small non-zero value
    repeated there is an offset on the report (a reviewer's step record with a 15-rpm bias
    from power-up was named stuck). Held at a speed, one value over and over is stuck."""
    from rwlab.diagnose.isolate import isolate

    (found,) = isolate("speed", _held_speed_evidence(bias, 0.0))
    assert found.kind == "speed_sensor_bias" and found.magnitude == bias
    assert found.ci[0] < bias < found.ci[1]
    assert isolate("speed", _held_speed_evidence(bias, 1500.0))[0].kind == "speed_sensor_stuck"
    # far beyond what a bias of the report could be: a reading frozen at an old speed
    assert isolate("speed", _held_speed_evidence(900.0, 0.0))[0].kind == "speed_sensor_stuck"


# -- issue 23's review: friction on steps, load steps vs bias, the clamp's interval ----------


def _step_record(tmp_path, name, faults):
    """A 600-s step record of the nominal twin (levels 0, +A, 0, −A, 0, 120 s each): the
    faults at 420 s fall inside the −A hold, after its first settled samples."""
    path = tmp_path / f"{name}.mcap"
    run_experiment(ExperimentConfig(signal="step", duration=600, seed=31, faults=faults), path)
    return path


def test_friction_at_a_held_speed_is_seen_against_the_records_own_current(tmp_path, model_file):
    """Friction × 1.5 is inside the spread between units (×1.86), so only the unit's own
    current at the same held speed shows it; the wheel's loop rejects the load step
    within seconds, so the held-speed error it leaves is no bias."""
    alarms = _diagnose(_step_record(tmp_path, "worn", ("friction=1.5@420",)), model_file).alarms
    assert alarms and all(a.t_s >= 420 for a in alarms), alarms
    assert {a.kind for a in alarms} == {"friction"}, alarms
    hold = next(a for a in alarms if a.detector == "hold")
    assert hold.ci[0] <= 1.5 <= hold.ci[1]
    assert hold.t_s <= 480 + 30  # named at the next acceleration (the motor test's)


def test_a_weak_motor_at_a_held_speed_is_not_called_friction(tmp_path, model_file):
    """A weak motor raises the held current by 1/F as well: the hold test names nothing
    before the motor test has seen an acceleration, which tells the two apart."""
    path = _step_record(tmp_path, "weak", ("torque_constant=0.8@420",))
    kinds = {a.kind for a in _diagnose(path, model_file).alarms}
    assert kinds == {"torque_constant"}


@pytest.mark.slow
def test_worn_bearings_and_a_bias_at_one_hold_are_both_named(tmp_path, model_file):
    path = _step_record(tmp_path, "two", ("friction=1.5@420", "speed_sensor_bias=15@420"))
    alarms = _diagnose(path, model_file).alarms
    assert {a.kind for a in alarms} == {"friction", "speed_sensor_bias"}, alarms
    bias = next(a for a in alarms if a.kind == "speed_sensor_bias")
    assert bias.ci[0] <= 15 <= bias.ci[1]


@pytest.mark.parametrize("offset_a", [-0.0045, 0.0, 0.004])
def test_the_current_limit_interval_is_on_the_clamp_not_the_currents(offset_a):
    """The currents at a clamp scatter with the sensor's noise and carry its unit's offset
    (±5 mA): the interval is on the clamp (it holds it for offsets within the 95 % range
    of that spread, ±4.75 mA), not the
    2.5–97.5 % spread of the readings (which a 5-mA offset moves off the clamp)."""
    from rwlab.diagnose.isolate import isolate

    rng = np.random.default_rng(7)
    clamp = 0.45
    currents = np.round((clamp + offset_a + 0.0015 * rng.standard_normal(200)) / 0.002) * 0.002
    ev = {"recent_speed": np.arange(8.0), "lag_currents": currents, "lag_excess": np.array([])}
    (found,) = isolate("lag", ev)
    assert found.kind == "current_limit"
    assert found.ci[0] <= clamp <= found.ci[1]
    assert found.ci[1] - found.ci[0] < 0.03  # still a useful size


def test_a_weak_motor_is_named_at_the_limit_only_when_its_interval_excludes_one():
    """At a clamp's onset a few current-balance samples can read in excess (the unit
    held-out review's current limit on a PRBS was named torque_constant 0.88 [0.78,
    1.00]): an excess whose k_t interval holds 1 is no evidence of a weak motor, so the
    clamp is named; a clear excess (k_t × 0.8: 0.25) still names the weak motor."""
    from rwlab.diagnose.isolate import LAG_SPLIT, isolate

    currents = np.full(12, 0.45)
    base = {"recent_speed": np.arange(8.0), "lag_currents": currents}
    base |= {"ref_mean": {"motor": 0.0}, "sigma": {"motor": 0.12}}
    ambiguous = np.full(3, LAG_SPLIT + 0.03)  # k_t would read ~0.88, interval reaching 1
    (found,) = isolate("lag", {**base, "lag_excess": ambiguous})
    assert found.kind == "current_limit" and found.magnitude == pytest.approx(0.45)
    (found,) = isolate("lag", {**base, "lag_excess": np.full(3, 0.25)})
    assert found.kind == "torque_constant" and found.ci[1] < 1
    assert found.ci[0] <= 0.8 <= found.ci[1]


@pytest.mark.slow  # 8 s in the quick lane (-n 2, shared machine)
def test_friction_after_a_rest_is_seen_against_the_mirror_speed(tmp_path, model_file):
    """Worn bearings from a 0-rpm rest on: the next hold (−A) has no earlier hold at that
    speed, but friction is even in speed and the current before the first motion is the
    unit's sense offset, so the +A hold tells (a reviewer's step record was missed)."""
    path = tmp_path / "mirror.mcap"
    cfg = ExperimentConfig(
        signal="step", duration=600, seed=37, unit=37, faults=("friction=1.5@300",)
    )
    run_experiment(cfg, path)
    alarms = _diagnose(path, model_file).alarms
    assert alarms and all(a.t_s >= 300 for a in alarms), alarms
    assert {a.kind for a in alarms} == {"friction"}, alarms
    assert alarms[0].t_s <= 600 and alarms[0].ci[0] <= 1.5 <= alarms[0].ci[1]


# -- issue 23: friction at a hold's start is no bias -----------------------------------------


def _unit10_record(tmp_path, fault):
    """Unit 10's PRBS: its hold at −1941 rpm settles at 299 s, 1.5 s before the fault."""
    path = tmp_path / "u10.mcap"
    run_experiment(ExperimentConfig(duration=400, seed=10, unit=10, faults=(fault,)), path)
    return path


def test_a_load_step_as_a_hold_settles_is_not_a_speed_sensor_bias(tmp_path, model_file):
    """Worn bearings 1.5 s after the wheel settled at a hold leave no earlier current at
    that hold; the speed error the loop then rejects rises and decays (a transient), where
    a bias is a step: it was named a 4.5 rpm bias at 308.5 s."""
    alarms = _diagnose(_unit10_record(tmp_path, "friction=1.5@300"), model_file).alarms
    assert "speed_sensor_bias" not in {a.kind for a in alarms}, alarms


def test_a_bias_at_a_hold_is_still_named_at_once(tmp_path, model_file):
    """The same hold with a 10-rpm bias: a step that stays, named without the wait."""
    alarms = _diagnose(_unit10_record(tmp_path, "speed_sensor_bias=10@300"), model_file).alarms
    bias = [a for a in alarms if a.kind == "speed_sensor_bias"]
    assert bias and bias[0].t_s <= 300 + 15, alarms
    assert bias[0].ci[0] <= 10 <= bias[0].ci[1]


@pytest.mark.parametrize("level", [0.0, 4.0, -15.0])
def test_steady_tells_a_step_from_a_transient(level):
    from rwlab.diagnose.blocktests import steady

    rng = np.random.default_rng(3)
    noise = 0.3 * rng.standard_normal(20)
    assert steady(level + noise, 0.7)
    decay = 6.0 * np.exp(-np.arange(20) / 6.0) + noise  # a PI loop rejecting a load step
    assert not steady(decay, 0.7)
    assert not steady(level + noise[:3], 0.7)  # too few to tell
    if level:  # a clear step is one from 4 values on, a rising error is not
        assert steady(level + 0.1 * noise[:4], 0.7)
    assert not steady(np.array([2.6, 4.0, 5.0, 5.9]), 0.7)  # unit 10's load step


def _worn_slew(factor: float, limit: float = 314.0, top: float = 2500.0):
    """A rising slew from −top to +top rpm at the acceleration limit of a wheel whose
    friction (viscous and Coulomb, RW90's datasheet) is ``factor`` × what its controller
    feeds forward: the excess slows the wheel away from zero and speeds it towards zero.
    Integrated here in small steps, sampled every 0.5 s."""
    to_rpm = 60 / (2 * math.pi)
    rows, t, w, dt = [], 0.0, -top, 1e-3
    while w < top:
        if round(t / dt) % 500 == 0:
            rows.append((t, w, 0.5 if w > 0 else 0.48))  # the feed-forward's step at 0 rpm
        friction = RW90.viscous_friction * abs(w) / to_rpm + RW90.coulomb_friction
        w += dt * (limit + math.copysign(1, w) * -(factor - 1) * friction / RW90.inertia * to_rpm)
        t += dt
    return rows


@pytest.mark.parametrize("factor", [1.5, 2.0, 3.0])
def test_the_slew_size_holds_the_viscous_friction_at_the_slews_speeds(factor):
    """Worn bearings scale the viscous friction too, which at 2000 rpm is as large as the
    Coulomb part: sized on Coulomb alone a ×1.5 read 1.7–2.0 on the twin (×1.5 on unit 32
    read 3.78 [2.34, 5.22])."""
    from rwlab.diagnose.isolate import isolate
    from rwlab.diagnose.motion import slew_asymmetry, slew_friction_gain
    from rwlab.diagnose.reference import nominal_coulomb_deceleration

    seg = _worn_slew(factor)
    c = (1.8e-3, 2.5e-6, 9e-3, 0.0)
    value = slew_asymmetry(seg, c, nominal_coulomb_deceleration())
    gain = slew_friction_gain(seg)
    assert gain > 1.5  # the slew's mean speed is over 1000 rpm
    ev = {
        "slew": np.array([value]),
        "slew_gain": np.array([gain]),
        "slew_before": np.zeros(4),  # the unit's own healthy level: no asymmetry
        "sigma": {"slew": 0.3},
        "ref_mean": {"slew": -1.0},  # another unit's, unused where the record has its own
        "tolerance": {"slew": 0.3},
        "recent_speed": np.arange(8.0),
    }
    (found,) = isolate("slew", ev)
    assert found.kind == "friction"
    assert found.magnitude == pytest.approx(factor, rel=0.03)
    assert found.ci[0] < factor < found.ci[1]


# -- issue 23: one size per fault ------------------------------------------------------------


def _sized(x: float, sd: float):
    from rwlab.diagnose.isolate import Z95, Finding

    return Finding("friction", x, (x - Z95 * sd, x + Z95 * sd), "factor")


def test_consistent_sizes_combine_to_their_inverse_variance_mean():
    from rwlab.diagnose.isolate import Z95, combine

    out = combine([_sized(2.0, 0.2), _sized(2.3, 0.4)])
    w = np.array([1 / 0.2**2, 1 / 0.4**2])  # textbook weights
    assert out["magnitude"] == pytest.approx((w @ [2.0, 2.3]) / w.sum())
    half = out["ci95"][1] - out["magnitude"]
    assert half == pytest.approx(Z95 / math.sqrt(w.sum()))
    assert out["used"] == [0, 1] and out["left_out"] == []


def test_a_size_that_disagrees_with_the_others_is_left_out():
    """c_u20_f18's x1.8 was sized 3.35, 2.42 and 1.61 by three tests."""
    from rwlab.diagnose.isolate import Finding, combine

    found = [_sized(1.55, 0.05), Finding("friction", None, None, "factor"), _sized(1.5, 0.06)]
    out = combine([*found, _sized(3.4, 0.3)])
    assert out["used"] == [0, 2] and out["left_out"] == [3]
    assert out["ci95"][0] < 1.53 < out["ci95"][1]
    assert combine([Finding("stuck", 900.0, None, "rpm")])["magnitude"] == 900.0


def test_the_combined_interval_covers_the_truth_95_percent_of_the_time():
    from rwlab.diagnose.isolate import combine

    rng = np.random.default_rng(11)
    sds = np.array([0.1, 0.25, 0.4])
    hits = 0
    for _ in range(2000):
        out = combine([_sized(1.5 + s * rng.standard_normal(), s) for s in sds])
        hits += out["ci95"][0] <= 1.5 <= out["ci95"][1]
    # the consistency cut leaves out a true size now and then: coverage a little below 95 %
    assert 0.90 <= hits / 2000 <= 0.97


# -- two faults, or one that looks like two (helper diag-pairs) ----------------------------


def _rotor_evidence(rng, motor_excess: float, friction_excess: float, n: int = 60) -> dict:
    """Evidence of the friction and motor tests around the true relative excesses (the
    torque balance: a weak motor k_t × F raises both by 1/F − 1, friction × G the
    constant-speed one by G/F − 1), with the tests' noise σ."""
    sigma = {"motor": 0.1, "friction": 0.3}
    return {
        "motor": motor_excess + sigma["motor"] * rng.standard_normal(n),
        "friction": friction_excess + sigma["friction"] * rng.standard_normal(n),
        "sigma": sigma,
        "tolerance": {"motor": 0.2, "friction": 0.3},
        "ref_mean": {"motor": 0.0},
    }


def test_a_motor_alarm_below_its_naming_tolerance_names_the_weak_motor_not_friction():
    """k_t × 0.9 (excess 0.11, inside the 0.2 tolerance, where a CUSUM with enough blocks
    still alarms): the motor test's own alarm is the current under acceleration, so the
    weak motor is named and sized, never an unsized friction."""
    from rwlab.diagnose.isolate import isolate

    ev = _rotor_evidence(np.random.default_rng(1), 1 / 0.9 - 1, 0.0)
    del ev["friction"]  # a chirp: no constant-speed sample
    (found,) = isolate("motor", ev)
    assert found.kind == "torque_constant"
    assert found.ci[0] <= 0.9 <= found.ci[1]


@pytest.mark.parametrize(("k_t", "friction"), [(0.8, 1.0), (0.8, 1.5)])
def test_a_weak_motor_named_before_explains_its_share_of_the_friction_excess(k_t, friction):
    """After a weak motor was named (k_t with its interval), a friction alarm whose excess
    1/F − 1 the weak motor explains names no friction; friction × 1.5 on top (excess
    G/F − 1) is still named, sized against the weak motor, its interval on the truth."""
    from rwlab.diagnose.isolate import isolate

    rng = np.random.default_rng(2)
    ev = _rotor_evidence(rng, 0.0, friction / k_t - 1)
    del ev["motor"]  # the motor test has no block since the change (a PRBS at its holds)
    ev["torque_constant"] = (k_t, (k_t - 0.04, k_t + 0.04))
    kinds = {f.kind: f for f in isolate("friction", ev)}
    if friction == 1.0:
        assert set(kinds) == {"torque_constant"}
    else:
        assert set(kinds) == {"friction"}
        lo, hi = kinds["friction"].ci
        assert lo <= friction <= hi


def test_a_frozen_reading_says_which_faults_it_left_unseen(tmp_path, model_file):
    """k_t × 0.8 and a speed reading stuck at once on steps: every model-based test reads
    the frozen speed from then on, so the diagnosis names the stuck sensor and says the
    rotor faults and a bias went unseen after it, not a silent miss."""
    path = _step_record(tmp_path, "stuck", ("torque_constant=0.8@420", "speed_sensor_stuck@420"))
    result = _diagnose(path, model_file)
    stuck = [a for a in result.alarms if a.kind == "speed_sensor_stuck"]
    assert stuck and stuck[0].t_s >= 420, result.alarms
    blind = result.blind()
    assert "torque_constant" in blind or "torque_constant" in result.faults()
    assert set(blind) <= {"friction", "torque_constant", "current_limit", "speed_sensor_bias"}
    assert all(t == stuck[0].t_s for t in blind.values())
    assert result.to_dict()["blind_after_s"] == blind


@pytest.mark.parametrize(
    ("k_t", "clamp_a", "worn"),
    [(0.9, None, 0.0), (0.8, None, 0.0), (1.0, 0.45, 0.0), (1.0, 0.45, 0.3)],
)
def test_the_units_own_current_at_the_limit_tells_a_clamp_from_a_weak_motor(k_t, clamp_a, worn):
    """At its acceleration limit the controller sets the current open loop: a weak motor
    leaves it at the unit's own level before the change (and only slows the wheel, the
    current balance's excess 1/F − 1), a lowered clamp lowers it. k_t × 0.9's excess (0.11)
    is within a clamp's onset noise, so only the current level names it; a clamp with worn
    bearings on top (a current excess ``worn``, the friction the model does not know) is
    still the clamp, not a weak motor."""
    from rwlab.diagnose.isolate import isolate

    rng = np.random.default_rng(3)
    own = 0.56  # A, this unit's current at the limit before the change
    after = own if clamp_a is None else clamp_a
    excess = (1 / k_t - 1 if clamp_a is None else worn) + 0.1 * rng.standard_normal(6)
    ev = {
        "recent_speed": np.arange(8.0),
        "lag_currents": after + 0.003 * rng.standard_normal(40),
        "lag_currents_before": own + 0.02 * rng.standard_normal(200),
        "lag_excess": excess,
        "ref_mean": {"motor": 0.0},
        "sigma": {"motor": 0.1},
    }
    (found,) = isolate("lag", ev)
    if clamp_a is None:
        assert found.kind == "torque_constant"
        assert found.ci[0] <= k_t <= found.ci[1]
    else:
        assert found.kind == "current_limit"
        assert found.ci[0] <= clamp_a <= found.ci[1]


def test_slew_change_compares_a_slew_with_the_records_own_earlier_slews():
    """Slews every 10 s at the healthy −0.9 ± 0.2, then friction ×1.5 adds +1 (a default
    chirp's short slews, nominal Coulomb decelerations): the change alarms within five
    slews; the same record going on healthy, or lower (a chirp's later slews read −1.1),
    never does; the baseline holds only slews a guard older."""
    from rwlab.diagnose.blocktests import SLEW_GUARD_S, SlewChange

    times = np.arange(480.0, 700.0, 10.0)
    wobble = 0.2 * np.where(np.arange(times.size) % 2, 1.0, -1.0)

    def run(after: float) -> tuple[SlewChange, list[float]]:
        det = SlewChange(0.3, 1 / 20, cusum_threshold(1e5))
        values = np.where(times < 600, -0.9, after) + wobble
        alarms = []
        for t, v in zip(times, values, strict=True):
            if det.add_slew(t, v):
                alarms.append(t)
                det.restart()
        return det, alarms

    _, alarms = run(after=+0.1)
    assert alarms and 600 <= alarms[0] <= 640
    for healthy in (-0.9, -1.1):
        assert run(after=healthy)[1] == []
    det, _ = run(after=-0.9)
    # at the last slew the baseline is the latest ten slews a guard older
    base = (-0.9 + wobble)[times <= times[-1] - SLEW_GUARD_S][-10:]
    assert det.mean == pytest.approx(base.mean())


@pytest.mark.slow
def test_friction_on_a_chirp_the_reference_level_missed_is_found_against_its_own_slews(
    tmp_path, unit_model_file
):
    """Unit 2813's friction ×1.5 from 600 s of a chirp: its slews after the onset read
    about +1 over its own before, but stayed within the reference test's tolerance
    between units (no alarm before the change test); found within 300 s, named, sized."""
    path = tmp_path / "chirp.mcap"
    cfg = ExperimentConfig(
        signal="chirp", duration=900, seed=94813, unit=2813, faults=("friction=1.5@600",)
    )
    run_experiment(cfg, path)
    alarms = _diagnose(path, unit_model_file).alarms
    assert alarms and alarms[0].detector == "slew_change", alarms
    assert alarms[0].kind == "friction" and 600 <= alarms[0].t_s <= 900
    assert alarms[0].ci[0] <= 1.5 <= alarms[0].ci[1]
