"""``rwlab hil``'s live diagnosis: a wheel's control periods as the pipeline's samples."""

from __future__ import annotations

import numpy as np
import pytest

from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import ConfigError
from rwlab.hil.live import SAMPLE_S, PipelineWatch, hil_calibration_file, sampled
from rwlab.wheel.physics import WheelParams


def test_samples_are_block_means_of_the_commands_and_currents_and_end_speeds():
    commands = np.arange(1.0, 11.0)  # two samples of 5 periods
    readings = np.column_stack([10 * np.arange(11.0), np.arange(11.0), np.zeros(11)])
    readings[3, 2] = 0.4  # a stale reading over (0, 5]: the second sample's
    data = sampled(commands, readings, 5, t0_s=100.0)
    assert data.N == 2 and data.Ts == SAMPLE_S and data.tstart == 100.0
    assert tuple(data.input_units) == ("rpm/s",)
    np.testing.assert_array_equal(data.u[:, 0], [3.0, 8.0])  # in force over the sample
    np.testing.assert_array_equal(data.y[:, 0], [0.0, 50.0])  # the speed at its start
    # the current over the periods up to the sample (the first: its own reading)
    np.testing.assert_array_equal(data.y[:, 1], [0.0, 3.0])
    np.testing.assert_array_equal(data.y[:, 2], [0.0, 0.4])
    data = sampled(commands[:9], readings, 5)
    assert data.N == 1  # the second sample's commands are not complete


def test_a_stale_reading_marks_its_sample():
    readings = np.column_stack([np.zeros(11), np.zeros(11), np.zeros(11)])
    readings[8, 2] = 0.7
    data = sampled(np.zeros(10), readings, 5)
    assert data.y[1, 2] == 0.0
    data = sampled(np.zeros(15), np.vstack([readings, np.zeros((5, 3))]), 5)
    assert data.y[2, 2] == 0.7  # periods 6-10 lead to the sample at period 10


def test_the_watch_refuses_a_calibration_or_period_it_cannot_sample_at():
    path = hil_calibration_file("rw90")
    assert path is not None
    cal = DiagnosisCalibration.load(path)
    assert cal.Ts == SAMPLE_S and cal.quick_window_s is not None
    with pytest.raises(ConfigError, match="divides"):
        PipelineWatch(cal, WheelParams(), 0.3, 1e-3)
    assert hil_calibration_file("no-such-wheel") is None


@pytest.mark.parametrize("wheel", ["rw90", "nrwa-t6"])
def test_the_presets_in_the_loop_ship_a_calibration_with_its_provenance(wheel):
    """Shipped as package data, valid against its schema, measured at the watch's sample
    time with its short window, on healthy flights of the preset's pyramid."""
    import json
    import tomllib

    from jsonschema import Draft202012Validator

    from rwlab.schemas import schema

    path = hil_calibration_file(wheel)
    assert path is not None
    Draft202012Validator(schema("diagnosis_calibration")).validate(json.loads(path.read_text()))
    cal = DiagnosisCalibration.load(path)
    assert cal.Ts == SAMPLE_S and cal.quick_window_s == 5.0 and cal.records == 12
    assert "healthy rwlab hil flights" in cal.origin and "bench_fdi_hil.py" in cal.origin
    root = path.parents[3]
    data = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "hil/*.json" in data["package-data"]["rwlab"]


def test_only_the_presets_own_spec_takes_its_calibration():
    """A unit's spec edited from a preset's file keeps the preset's name, not its numbers:
    it flies under the tracking test, not the preset's calibration."""
    from dataclasses import replace

    from rwlab.wheelspec import WheelSpec

    preset = WheelSpec.load("rw90")
    assert hil_calibration_file(preset) == hil_calibration_file("rw90") is not None
    edited = replace(preset, coulomb_friction_nm=1.25 * preset.coulomb_friction_nm)
    assert edited.name == "rw90" and hil_calibration_file(edited) is None
    assert hil_calibration_file(WheelSpec.load("rw-0.01")) is None  # none shipped


@pytest.mark.slow  # three flights of minutes over the virtual bus
def test_a_lab_calibrates_the_pipeline_on_its_own_wheels_flights(tmp_path):
    """A unit's own spec (the RW90's file, renamed) has no shipped calibration and
    flies under the tracking test; calibrated on two of its own healthy flights
    (``rwlab diagnose calibrate --in-loop``), ``--diagnosis-calibration`` puts the pipeline
    on its wheels, and friction × 4 is named on the faulty wheel."""
    import json
    import re

    from click.testing import CliRunner

    from rwlab.cli import main

    spec = CliRunner().invoke(main, ["wheel", "models", "rw90"]).output
    spec = re.sub(r'(?m)^name = "rw90"', 'name = "lab-unit-7"', spec)
    (tmp_path / "unit.toml").write_text(spec)
    base = ["hil", "--scenario", "geo-smallsat-pyramid", "--wheel", str(tmp_path / "unit.toml")]
    base += ["--no-reference", "--duration", "400"]

    def fly(name: str, *extra: str) -> str:
        res = CliRunner().invoke(
            main, [*base, "--channel", f"hil-live-{name}", "--out", str(tmp_path / name), *extra]
        )
        assert res.exit_code == 0, res.output
        return res.output

    assert "(command-tracking test: no in-loop calibration" in fly("h1", "--seed", "1")
    fly("h2", "--seed", "2")
    cal = tmp_path / "cal.json"
    records = [str(tmp_path / h / "record.mcap") for h in ("h1", "h2")]
    res = CliRunner().invoke(
        main, ["diagnose", "calibrate", *records, "--in-loop", "--out", str(cal)]
    )
    assert res.exit_code == 0, res.output
    assert json.loads(cal.read_text())["records"] == 8  # two flights, four wheels each
    fault = ["--fault", "2:friction=4@250", "--diagnosis-calibration", str(cal)]
    out = fly("f", "--seed", "3", *fault)
    assert "(GLR pipeline, calibrated on" in out
    [alarm] = json.loads((tmp_path / "f" / "metrics.json").read_text())["wheel_faults"]
    assert alarm["node"] == 2 and alarm["named_kind"] == "friction"
    # within three decisions of the onset: the crossing, its confirmation, one spare
    assert alarm["detector"].startswith("GLR pipeline") and alarm["detected_s"] - 250 <= 15
