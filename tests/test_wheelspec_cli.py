"""`rwlab wheel models` and `rwlab experiment --wheel NAME` on each shipped wheel model."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.testbed.load import load_record
from rwlab.testbed.record import read_record
from rwlab.wheelspec import WheelSpec

PRESETS = ("rw90", "nrwa-t6", "rw-0.01")


def test_wheel_models_json_lists_every_preset_with_its_limits():
    r = CliRunner().invoke(main, ["wheel", "models", "--json"])
    assert r.exit_code == 0, r.output
    rows = {row["name"]: row for row in json.loads(r.output)}
    for name in PRESETS:
        spec = WheelSpec.load(name)
        row = rows[name]
        assert row["inertia_kg_m2"] == spec.inertia_kg_m2
        assert row["max_speed_rpm"] == spec.max_speed_rpm
        assert row["max_torque_nm"] == spec.max_torque_nm
        assert row["current_limit_a"] == spec.current_limit_a
    table = CliRunner().invoke(main, ["wheel", "models"])
    assert table.exit_code == 0 and all(name in table.output for name in PRESETS)


@pytest.mark.parametrize("name", PRESETS)
def test_experiment_on_each_wheel_model_records_its_spec(name, tmp_path):
    out = tmp_path / f"{name}.mcap"
    r = CliRunner().invoke(
        main, ["experiment", "--wheel", name, "--duration", "60", "--seed", "2", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    meta = read_record(out).metadata
    spec = WheelSpec.load(name)
    assert WheelSpec.from_dict(meta["wheel_spec"]).hash == spec.hash
    assert meta["driver_settings"]["max_speed_rpm"] == spec.max_speed_rpm
    assert meta["wheel"]["model"] == name
    command = load_record(out).u[:, 0]
    # the default amplitude is the wheel model's nominal speed, not another wheel's
    assert meta["experiment"]["amplitude"] == spec.nominal_speed_rpm
    assert np.max(np.abs(command)) <= spec.nominal_speed_rpm


def test_a_spec_file_flies_as_the_simulated_wheel(tmp_path):
    from importlib import resources

    text = (resources.files("rwlab.wheelspec") / "presets" / "rw-0.01.toml").read_text("utf-8")
    text = text.replace('name = "rw-0.01"', 'name = "my-wheel"')
    text = text.replace("max_speed_rpm = { value = 6500.0", "max_speed_rpm = { value = 6000.0")
    path = tmp_path / "my-wheel.toml"
    path.write_text(text, encoding="utf-8")
    out = tmp_path / "mine.mcap"
    r = CliRunner().invoke(
        main, ["experiment", "--wheel", str(path), "--duration", "20", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    meta = read_record(out).metadata
    assert meta["wheel_spec"]["name"] == "my-wheel"
    assert meta["driver_settings"]["max_speed_rpm"] == 6000.0


@pytest.mark.parametrize("name", PRESETS)
def test_wheel_models_name_prints_a_whole_spec_that_loads_back(name, tmp_path):
    r = CliRunner().invoke(main, ["wheel", "models", name])
    assert r.exit_code == 0, r.output
    path = tmp_path / "mine.toml"
    path.write_text(r.output.replace(f'name = "{name}"', 'name = "mine"'), encoding="utf-8")
    mine = WheelSpec.load(path)
    assert mine.name == "mine"
    spec = WheelSpec.load(name)
    assert mine.to_dict() | {"name": name} == spec.to_dict()


def test_help_texts_name_the_wheel_model_not_only_the_rw90():
    for cmd in (["experiment", "--help"], ["wheel", "--help"]):
        r = CliRunner().invoke(main, cmd)
        assert r.exit_code == 0 and "simulated RW90" not in r.output, r.output
