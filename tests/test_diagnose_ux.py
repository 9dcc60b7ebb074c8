"""The diagnosis as a user meets it: refusals, what each test decided on, the console,
the report and the output folders (issue 23's newcomer findings)."""

from __future__ import annotations

import json
import re
import warnings

import jsonschema
import numpy as np
import pytest
from click.testing import CliRunner

from rwlab import schemas
from rwlab.cli import main
from rwlab.diagnose import HealthyReference, diagnose
from rwlab.errors import ConfigError, DataError, RwlabWarning
from rwlab.testbed import ExperimentConfig, load_record, run_experiment
from rwlab.wheel import IdentifiedWheel

OUTPUTS = ("speed", "current", "age", "lost")


@pytest.fixture(scope="module")
def identified(identified_prbs):
    """``rwlab identify`` on a fault-free 20-minute PRBS (seed 0): its output and model."""
    output, study, _ = identified_prbs
    return output, study / "model.json"


@pytest.fixture(scope="module")
def model_file(identified):
    return identified[1]


@pytest.fixture(scope="module")
def wheel(model_file):
    return IdentifiedWheel.from_json(model_file)


@pytest.fixture(scope="module")
def record_60s(tmp_path_factory):
    """A fault-free 60-s PRBS (seed 3), made once: the refusals below read it."""
    path = tmp_path_factory.mktemp("ux-60s") / "r.mcap"
    run_experiment(ExperimentConfig(duration=60, seed=3), path)
    return path


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _diagnosed(path, seed, model_file, wheel):
    """A fault-free 600-s PRBS of the nominal wheel, loaded and diagnosed (warnings off)."""
    run_experiment(ExperimentConfig(duration=600, seed=seed), path)
    data = load_record(path, wheel.Ts, outputs=OUTPUTS, max_gap=np.inf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RwlabWarning)
        return data, diagnose(data, wheel, HealthyReference.from_model_file(model_file))


# -- refusals that say what to do ---------------------------------------------------------


def test_the_speed_alone_is_refused_with_how_to_load_the_current(record_60s, model_file, wheel):
    speed_only = load_record(record_60s, wheel.Ts)  # load_record's default
    with pytest.raises(DataError, match=r"current.*outputs=\('speed', 'current', 'age', 'lost'\)"):
        diagnose(speed_only, wheel, HealthyReference.from_model_file(model_file))


def test_without_lost_frames_the_dropout_test_says_it_decided_nothing(
    record_60s, model_file, wheel
):
    data = load_record(record_60s, wheel.Ts, outputs=("speed", "current"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RwlabWarning)
        d = diagnose(data, wheel, HealthyReference.from_model_file(model_file))
    assert d.coverage["dropout"]["decided"] == 0 and "lost" in d.coverage["dropout"]["why"]
    assert any(n.startswith("dropout: not tested") for n in d.notes)
    assert any(n.startswith("stuck:") and "telemetry_age_s" in n for n in d.notes)
    assert "dropout" in d.untested() and "telemetry_dropout" in d.unseen()


def test_another_sample_time_says_how_to_resample(record_60s, model_file, wheel):
    other = load_record(record_60s, wheel.Ts / 5, outputs=OUTPUTS, max_gap=np.inf)
    with pytest.raises(DataError, match=rf"load_record\(path, {wheel.Ts:g}, outputs="):
        diagnose(other, wheel, HealthyReference.from_model_file(model_file))


def test_from_file_takes_a_path_or_says_what_it_takes(model_file, wheel):
    assert IdentifiedWheel.from_file(model_file).Ts == wheel.Ts
    assert IdentifiedWheel.from_file(str(model_file)).Ts == wheel.Ts
    with pytest.raises(ConfigError, match="from_info"):
        IdentifiedWheel.from_file(json.loads(model_file.read_text()))


def test_a_fault_without_its_value_shows_the_syntax(tmp_path):
    result = _cli("experiment", "--fault", "friction@100", "--out", tmp_path / "r.mcap")
    assert result.exit_code == 2
    assert "friction=FACTOR@SECONDS" in result.output


def test_identify_says_it_stored_a_healthy_reference(identified):
    output, model_file = identified
    samples = json.loads(model_file.read_text())["healthy_reference"]["samples"]
    assert f"healthy reference for fault diagnosis stored in model.json ({samples}" in output
    report = (model_file.parent / "report.html").read_text()
    assert "holds the healthy reference for fault diagnosis" in report


# -- "no alarm" against "nothing tested" --------------------------------------------------


def test_a_twenty_second_record_says_what_it_could_not_test(tmp_path, model_file):
    run_experiment(ExperimentConfig(duration=20, seed=4), tmp_path / "short.mcap")
    result = _cli(
        "diagnose", tmp_path / "short.mcap", "--model", model_file, "--out", tmp_path / "d",
        "--rules",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    # truth: the speed and hold tests take a command held ≥ 30 s, which 20 s cannot hold;
    # the change test samples 300 s old; the friction test 20 samples at constant speed
    # after both signs were held 10 samples each
    assert report["coverage"]["speed"]["decided"] == 0
    assert report["coverage"]["hold"]["decided"] == 0
    assert "friction" in report["unseen_faults"]
    assert "speed" in report["untested"]
    assert "warning:" in result.output and "says nothing" in result.output
    assert "not tested (no test could decide): friction" in result.output
    assert "nothing to decide on:" in result.output


def _printed_estimate(output: str, kind: str) -> tuple[float, float, float]:
    """``kind``'s size and 95 % interval on the console's estimates line."""
    line = next(x for x in output.splitlines() if x.startswith("estimates against"))
    m = re.search(rf"{kind} (\S+) \[(\S+), (\S+)\]", line)
    assert m, line
    return float(m[1]), float(m[2]), float(m[3])


@pytest.mark.parametrize(("factor", "status"), [(1.0, 0), (2.0, 1)])
def test_the_exit_status_says_whether_a_fault_was_found_and_the_sizes_are_printed(
    tmp_path, model_file, factor, status
):
    """A script tells a fault from health by the exit status (1 and 0), as ``diff``; the
    console gives the sizes alarm or not, and the interval holds the injected factor."""
    faults = () if factor == 1.0 else (f"friction={factor}@0",)
    run_experiment(ExperimentConfig(duration=600, seed=21, faults=faults), tmp_path / "r.mcap")
    args = ("--model", model_file, "--out", tmp_path / "d", "--rules")
    result = _cli("diagnose", tmp_path / "r.mcap", *args)
    assert result.exit_code == status, result.output
    assert ("alarm at" in result.output) == bool(status)
    assert (tmp_path / "d" / "diagnosis.json").exists()  # written either way
    size, low, high = _printed_estimate(result.output, "friction")
    assert low <= factor <= high and low < size < high


@pytest.mark.slow  # 9 s in the quick lane (-n 2, shared machine)
def test_the_estimates_are_the_records_latest_minutes_not_a_quiet_tests(tmp_path, model_file):
    """A 30 rpm bias from 600 s of a 20-minute PRBS (another unit): the held-speed test
    last decided minutes before the end, and its latest 10 minutes of values reached back
    before the onset, sizing the bias 21.3 [21.26, 21.42] (a new user's record). The
    estimate takes the record's latest 10 minutes: all after the onset."""
    cfg = ExperimentConfig(duration=1200, seed=2, unit=6, faults=("speed_sensor_bias=30@600",))
    run_experiment(cfg, tmp_path / "r.mcap")
    args = ("--model", model_file, "--out", tmp_path / "d", "--rules")
    result = _cli("diagnose", tmp_path / "r.mcap", *args)
    assert result.exit_code == 1, result.output
    size, low, high = _printed_estimate(result.output, "speed_sensor_bias")
    assert low <= 30.0 <= high and size == pytest.approx(30.0, abs=1.5)


def test_each_test_says_what_it_decided_on(tmp_path, model_file, wheel):
    data, d = _diagnosed(tmp_path / "r.mcap", 5, model_file, wheel)
    # the dropout test decides on each whole 10-s block of the record
    assert d.coverage["dropout"] == {
        "decided": data.N // round(10 / wheel.Ts),
        "unit": "10-s blocks",
    }
    # a block CUSUM decides on at most one block per `block` qualifying samples
    ref = d.reference.tests
    for name in ("friction", "motor", "speed", "lag"):
        assert 0 < d.coverage[name]["decided"] <= data.N // ref[name].block, name
    assert 0 < d.coverage["stuck"]["decided"] <= data.N
    assert set(d.tested()) | set(d.untested()) == set(d.coverage)
    # a short repr, not the histories
    assert len(repr(d)) < 200 and "tests decided" in repr(d)
    # nothing alarmed: the residual statistics are the whole record's, not "before alarm"
    if not d.alarms:
        assert set(d.residual_statistics()["speed"]) == {"unit", "whole_record"}
    payload = d.to_dict()
    assert payload["coverage"] == json.loads(json.dumps(d.coverage))


def test_the_report_plots_every_test_that_decided(tmp_path, model_file, wheel):
    from rwlab.report import diagnosis as report

    _, d = _diagnosed(tmp_path / "r.mcap", 6, model_file, wheel)

    class Capture:
        def __init__(self):
            self.figures = []

        def figure(self, fig, fig_id, caption):
            self.figures.append((fig_id, len(fig.axes)))

        def html(self, text):
            pass

    page = Capture()
    report._statistics_figure(page, d, [])
    cusums = [n for n in d.tested() if f"stat_{n}" in d.history]
    assert len(cusums) > 4  # more than the four the old figure showed (slew, hold, ...)
    assert page.figures == [("fig-statistics", len(cusums))]


def test_a_truncated_record_is_diagnosed_with_a_warning(tmp_path, model_file):
    path = tmp_path / "r.mcap"
    run_experiment(ExperimentConfig(duration=120, seed=7), path)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    refused = _cli("diagnose", cut, "--model", model_file, "--out", tmp_path / "d")
    assert refused.exit_code == 2 and "ends in the middle of a record" in refused.output
    args = ("--model", model_file, "--out", tmp_path / "d", "--salvage", "--rules")
    result = _cli("diagnose", cut, *args)
    assert result.exit_code == 0, result.output
    assert "salvaged" in result.output
    page = (tmp_path / "d" / "report.html").read_text()
    assert 'id="coverage-table"' in page and 'id="estimates-table"' in page
    # the pipeline's page says so under its verdict
    result = _cli("diagnose", cut, "--model", model_file, "--out", tmp_path / "g", "--salvage")
    assert result.exit_code == 0, result.output
    page = (tmp_path / "g" / "report.html").read_text()
    assert page.index("the record was salvaged") < page.index('id="alarms"')


def test_a_record_cut_to_one_sample_is_diagnosed_without_numpy_warnings(tmp_path, model_file):
    """A new user's record of one command (a 5-kB cut was one, before records were
    chunked with CRCs: a cut copy is now refused as damaged). The report's sample time
    came from the samples' spacing, and numpy warned of an empty mean; it is the model's."""
    cut = tmp_path / "cut.mcap"
    run_experiment(ExperimentConfig(duration=0.5, seed=7), cut)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = _cli("diagnose", cut, "--model", model_file, "--out", tmp_path / "d", "--rules")
    assert result.exit_code == 0, result.output
    assert "Mean of empty slice" not in result.output
    page = (tmp_path / "d" / "report.html").read_text()
    assert "at Ts = 0.5 s" in page


# -- output folders and the live console --------------------------------------------------


def test_a_folder_with_a_bad_record_leaves_nothing_and_names_it(tmp_path, model_file):
    folder = tmp_path / "wheel"
    folder.mkdir()
    run_experiment(ExperimentConfig(duration=60, seed=8), folder / "a_good.mcap")
    bad = ExperimentConfig(duration=60, mode="acceleration", amplitude=100)
    run_experiment(bad, folder / "b_accel.mcap")
    result = _cli("diagnose", folder, "--model", model_file, "--out", tmp_path / "out")
    assert result.exit_code == 2
    assert "b_accel.mcap" in result.output and "acceleration-mode" in result.output
    assert not (tmp_path / "out").exists()  # not even a_good's diagnosis
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]


def test_live_alarms_and_injected_faults_are_printed(tmp_path, model_file):
    args = ["experiment", "--duration", 300, "--seed", 9, "--fault", "speed_sensor_stuck@100"]
    result = _cli(*args, "--model", model_file, "--out", tmp_path / "r.mcap")
    assert result.exit_code == 0, result.output
    assert "alarm: speed_sensor_stuck at" in result.output  # as it came
    assert "live diagnosis: speed_sensor_stuck at" in result.output
    assert "injected: speed_sensor_stuck@100" in result.output
    # the alarms printed are the record's
    from rwlab.testbed import read_record

    events = [e["message"] for e in read_record(tmp_path / "r.mcap").topic("/event")]
    printed = [
        line.removeprefix("alarm: ")
        for line in result.output.splitlines()
        if line.startswith("alarm: ")
    ]
    assert printed and all(p in events for p in printed)


@pytest.mark.slow  # three 15-minute records and a folder diagnosis: ~1 min
def test_the_trend_shows_each_records_size_alarm_or_not(tmp_path, model_file):
    """Records of one wheel, the same test signal, friction ×1, ×1.15, ×1.3 from power-up:
    each record's friction estimate, alarm or not, and their ratios are the factors."""
    folder = tmp_path / "wheel"
    folder.mkdir()
    factors = (1.0, 1.15, 1.3)
    for week, factor in enumerate(factors):
        faults = () if factor == 1.0 else (f"friction={factor}@0",)
        cfg = ExperimentConfig(duration=900, seed=30, unit=5, faults=faults)
        run_experiment(cfg, folder / f"{'cba'[week]}_week{week}.mcap")  # names against time
    result = _cli("diagnose", folder, "--model", model_file, "--out", tmp_path / "d", "--rules")
    rows = [line for line in result.output.splitlines() if "_week" in line[:8]]
    alarmed = any("no alarm" not in row for row in rows)
    assert result.exit_code == int(alarmed), result.output  # 1 when any record alarmed
    assert "estimates: " in result.output
    shown = [row.split()[0] for row in rows]
    assert shown == ["c_week0.mcap", "b_week1.mcap", "a_week2.mcap"]  # start-time order
    trend = json.loads((tmp_path / "d" / "trend.json").read_text())
    validator = jsonschema.Draft202012Validator
    jsonschema.validate(trend, schemas.schema("trend"), cls=validator)
    for name in ("c_week0", "b_week1"):
        report = json.loads((tmp_path / "d" / name / "diagnosis.json").read_text())
        jsonschema.validate(report, schemas.schema("diagnosis"), cls=validator)
    records = trend["records"]
    assert [p["record"] for p in records] == ["c_week0.mcap", "b_week1.mcap", "a_week2.mcap"]
    assert records[0]["faults"] == {}  # the healthy record: no alarm, yet a size
    friction = [p["estimates"]["friction"] for p in records]
    assert all(f["ci95"][0] <= f["magnitude"] <= f["ci95"][1] for f in friction)
    # the same unit and signal: the reference unit's difference cancels in the ratios
    base = friction[0]["magnitude"]
    for f, factor in zip(friction[1:], factors[1:], strict=True):
        assert f["magnitude"] / base == pytest.approx(factor, rel=0.05)
    # a weak motor it is not: the torque constant stays at the healthy record's
    kt = [p["estimates"]["torque_constant"]["magnitude"] for p in records]
    assert max(kt) - min(kt) < 0.03


def test_the_twin_calibration_of_the_models_preset_is_written_and_read(tmp_path, model_file):
    out = tmp_path / "twin.json"
    result = _cli("diagnose", "twin-calibration", "--model", model_file, "--out", out)
    assert result.exit_code == 0, result.output
    assert "rw90" in result.output and "bench_fdi.py" in result.output
    from rwlab.diagnose.wheel_calibration import DiagnosisCalibration

    assert DiagnosisCalibration.load(out).hours >= 2.0


# -- the GLR pipeline by default ------------------------------------------------------------


def test_a_preset_models_record_takes_the_presets_twin_calibration(tmp_path, model_file):
    """Without --calibration the pipeline runs on the twin calibration of the model's wheel
    preset; the verdict comes first and a healthy record raises no alarm (exit 0)."""
    run_experiment(ExperimentConfig(duration=300, seed=41), tmp_path / "r.mcap")
    result = _cli("diagnose", tmp_path / "r.mcap", "--model", model_file, "--out", tmp_path / "d")
    assert result.exit_code == 0, result.output
    assert result.output.startswith("healthy: no alarm in 300")
    fdi = json.loads((tmp_path / "d" / "fdi.json").read_text())
    assert fdi["calibration"].endswith("twin_calibration_rw90.json")
    assert fdi["events"] == []
    assert fdi["unseen"] == []  # five minutes of PRBS: every fault could have been seen
    page = (tmp_path / "d" / "report.html").read_text()
    assert 'id="fig-residuals"' in page  # the README's figure of the diagnosis


def test_a_model_of_another_wheel_is_told_to_calibrate_on_its_own_records(tmp_path, model_file):
    """A unit's own spec (an RW90 whose clamp is 0.6 A): the twins' thresholds are not its
    own; the error says how to calibrate, or to run the rule detectors."""
    from dataclasses import replace

    from rwlab.wheelspec import WheelSpec

    info = json.loads(model_file.read_text())
    spec = replace(WheelSpec.load("rw90"), current_limit_a=0.6)
    info["wheel"] = {**spec.limits(), "spec": spec.to_dict()}
    unit = tmp_path / "unit.json"
    unit.write_text(json.dumps(info))
    run_experiment(ExperimentConfig(duration=30, seed=42), tmp_path / "r.mcap")
    result = _cli("diagnose", tmp_path / "r.mcap", "--model", unit, "--out", tmp_path / "d")
    assert result.exit_code == 2
    assert "rwlab diagnose calibrate" in result.output and "--rules" in result.output
    assert not (tmp_path / "d").exists()
    both = _cli(
        "diagnose", tmp_path / "r.mcap", "--model", model_file, "--out", tmp_path / "d",
        "--rules", "--calibration", model_file,
    )  # fmt: skip
    assert both.exit_code == 2 and "--rules takes no --calibration" in both.output


def test_live_diagnosis_of_another_wheel_takes_its_own_calibration(tmp_path, model_file):
    """rwlab experiment --model of a lab's own wheel (its spec file: an RW90 whose clamp is
    0.6 A): refused before any work without a calibration, run with
    --diagnosis-calibration (here the preset's file, written out)."""
    from dataclasses import replace

    from rwlab.wheelspec import WheelSpec

    info = json.loads(model_file.read_text())
    spec = replace(WheelSpec.load("rw90"), name="lab-unit", current_limit_a=0.6)
    info["wheel"] = {**spec.limits(), "spec": spec.to_dict()}
    unit = tmp_path / "unit.json"
    unit.write_text(json.dumps(info))
    (tmp_path / "unit.toml").write_text(spec.to_toml())
    run = ("experiment", "--wheel", tmp_path / "unit.toml", "--duration", 60, "--seed", 3,
           "--model", unit)  # fmt: skip
    refused = _cli(*run, "--out", tmp_path / "a.mcap")
    assert refused.exit_code == 2 and "rwlab diagnose calibrate" in refused.output
    assert not (tmp_path / "a.mcap").exists()
    cal = tmp_path / "cal.json"
    written = _cli("diagnose", "twin-calibration", "--model", model_file, "--out", cal)
    assert written.exit_code == 0, written.output
    result = _cli(*run, "--diagnosis-calibration", cal, "--out", tmp_path / "b.mcap")
    assert result.exit_code == 0, result.output
    assert "live diagnosis: no alarm" in result.output


def test_a_twenty_second_record_says_what_the_pipeline_could_not_see(tmp_path, model_file):
    """No alarm on 20 s of PRBS is no evidence of a healthy bearing: the verdict says which
    faults the record cannot tell from healthy and how large the others must have been to
    show (friction: beyond the largest size its grid holds, ×8)."""
    run_experiment(ExperimentConfig(duration=20, seed=4), tmp_path / "short.mcap")
    result = _cli(
        "diagnose", tmp_path / "short.mcap", "--model", model_file, "--out", tmp_path / "d"
    )
    assert result.exit_code == 0, result.output
    assert "healthy: no alarm in 20" in result.output and "not seen" in result.output
    report = json.loads((tmp_path / "d" / "fdi.json").read_text())
    assert report["unseen"] and report["detectable"]["friction"]["above"] > 8.0
    assert f"friction above ×{report['detectable']['friction']['above']:.3g}" in result.output


def test_a_record_of_another_wheel_is_refused_not_diagnosed(tmp_path, model_file):
    """An NRWA-T6 record against the RW90's model read as a weak motor (a new user's trial):
    the record's wheel and the model's differ, and both the diagnosis and the live
    diagnosis say so before any work."""
    run_experiment(ExperimentConfig(wheel="nrwa-t6", duration=30, seed=3), tmp_path / "t6.mcap")
    result = _cli("diagnose", tmp_path / "t6.mcap", "--model", model_file, "--out", tmp_path / "d")
    assert result.exit_code == 2 and "'nrwa-t6'" in result.output and "'rw90'" in result.output
    assert not (tmp_path / "d").exists()
    live = _cli("experiment", "--wheel", "nrwa-t6", "--duration", 30, "--model", model_file,
                "--out", tmp_path / "live.mcap")  # fmt: skip
    assert live.exit_code == 2 and "'rw90'" in live.output
    assert not (tmp_path / "live.mcap").exists()
    alone = _cli("experiment", "--duration", 30, "--diagnosis-calibration", model_file,
                 "--out", tmp_path / "x.mcap")  # fmt: skip
    assert alone.exit_code == 2 and "needs model" in alone.output


def test_calibration_takes_healthy_records_only_and_keeps_an_existing_file(tmp_path, model_file):
    """A record with an injected fault would teach the thresholds the fault as health
    (friction ×3 then read healthy: a new user's trial); an existing calibration is not
    overwritten without --force."""
    faulty = tmp_path / "f.mcap"
    run_experiment(ExperimentConfig(duration=30, seed=3, faults=("friction=3@10",)), faulty)
    out = tmp_path / "c.json"
    result = _cli("diagnose", "calibrate", faulty, "--model", model_file, "--out", out)
    assert result.exit_code == 2 and "friction=3@10" in result.output and not out.exists()
    out.write_text("{}")
    again = _cli("diagnose", "calibrate", faulty, "--model", model_file, "--out", out)
    assert again.exit_code == 2 and "--force" in again.output and out.read_text() == "{}"
