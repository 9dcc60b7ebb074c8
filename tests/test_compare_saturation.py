"""`rwlab compare` on a wheel whose driver limits the current differently from the
identified one: which clamp each model flies, where it came from, and the columns of
an `rwlab export` file."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.data import IOData
from rwlab.ident import arx
from rwlab.ident.greybox import RPM, WheelGreyBox
from rwlab.ident.model_file import Channel, WheelModelFile
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.wheel.physics import IDEAL


def _cli(*args: str):
    return CliRunner().invoke(main, list(args))


def _json(*args: str) -> dict:
    result = _cli(*args, "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.output)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A model file of a 0.7-A wheel (the ideal twin's physics as the grey box), and a
    4-minute record of a wheel whose driver clamps the current at 0.30 A, with its
    `rwlab export` CSV."""
    root = tmp_path_factory.mktemp("compare")
    p = IDEAL
    grey = WheelGreyBox(
        0.5, p.inertia, p.torque_constant, 0.7, p.coulomb_friction, p.breakaway_friction,
        p.stribeck_speed_rpm * RPM, p.viscous_friction, p.max_accel_rpm_s * RPM, p.speed_kp,
        p.speed_ki, p.torque_constant, p.coulomb_friction, p.viscous_friction,
        p.max_speed_rpm * RPM, 20,
    )  # fmt: skip
    u = np.repeat(np.random.default_rng(0).uniform(-6000, 6000, 40), 20)
    y = grey.simulate(u)
    linear = arx(IOData(u, y, 0.5), 2, 2, 1)
    model = WheelModelFile(
        linear,
        Channel("command", "rpm", 0.0),
        Channel("speed_rpm", "rpm", 0.0),
        validation_fit_percent=90.0,
        current_limit_a=0.7,
        nonlinear_models={"greybox": grey.to_dict()},
    )
    path = root / "model.json"
    path.write_text(json.dumps(model.to_dict()))
    record = root / "limited.mcap"
    cfg = ExperimentConfig(duration=240.0, seed=3, min_hold=20.0, max_hold=40.0)
    run_experiment(cfg, record, params=replace(IDEAL, current_limit=0.30))
    csv = root / "limited.csv"
    result = _cli("export", str(record), "--format", "csv", "--out", str(csv))
    assert result.exit_code == 0, result.output
    return path, record, csv


def test_compare_takes_the_records_current_limit_and_says_so(setup):
    model, record, _ = setup
    scores = _json("compare", str(model), str(record))
    grey = scores["greybox"]
    assert grey["saturation"]["current_limit_a"]["value"] == pytest.approx(0.30)
    assert grey["saturation"]["current_limit_a"]["source"].startswith("record")
    assert grey["fit_percent"] > 95  # the same physics under the record's clamp
    assert set(scores["linear"]["saturation"]) == {"speed_limit_rpm", "accel_limit_rpm_s"}


def test_compare_on_a_plain_csv_falls_back_to_the_model_files_limit_unless_given(setup):
    model, record, csv = setup
    from_record = _json("compare", str(model), str(record))["greybox"]
    # rwlab export's own CSV: its command and speed_rpm columns by default
    plain = _json("compare", str(model), str(csv))["greybox"]
    assert plain["saturation"]["current_limit_a"]["value"] == pytest.approx(0.7)
    assert plain["saturation"]["current_limit_a"]["source"].startswith("model file")
    assert plain["fit_percent"] < from_record["fit_percent"] - 5  # the wrong clamp costs
    given = _json("compare", str(model), str(csv), "--current-limit", "0.30")["greybox"]
    assert given["saturation"]["current_limit_a"] == {"value": 0.30, "source": "option"}
    assert given["fit_percent"] == pytest.approx(from_record["fit_percent"], abs=1e-6)


def test_compare_chooses_columns_with_input_and_output(setup, tmp_path):
    model, _, csv = setup
    default = _json("compare", str(model), str(csv))
    chosen = _json("compare", str(model), str(csv), "--input", "command", "--output", "speed_rpm")
    assert chosen == default
    bad = _cli("compare", str(model), str(csv), "--input", "nope")
    assert bad.exit_code == 2 and bad.output.startswith("error:") and "nope" in bad.output
    # a file whose columns are not an export's: the choice is the user's, by flag
    odd = tmp_path / "odd.csv"
    lines = csv.read_text().splitlines()
    odd.write_text("\n".join([lines[0].replace("command", "cmd"), *lines[1:]]) + "\n")
    refused = _cli("compare", str(model), str(odd))
    assert refused.exit_code == 2
    assert "--input" in refused.output and "--output" in refused.output
    named = _json("compare", str(model), str(odd), "--input", "cmd", "--output", "speed_rpm")
    assert named["greybox"]["fit_percent"] == pytest.approx(default["greybox"]["fit_percent"])
    refused = _cli("compare", str(model), str(csv), "--current-limit", "-1")
    assert refused.exit_code == 2


def test_each_saturation_comes_from_the_option_then_the_record_then_the_model_file():
    from rwlab.wheel.compare import resolve_saturation

    info = {
        "saturation": {"speed_rpm": 7800.0, "accel_rpm_s": 314.0},
        "greybox": {"current_limit": 0.3412, "current_limit_estimated": True},
    }
    # nothing given: the model file's, the grey box's estimate for the current limit
    out = resolve_saturation(info, {})
    assert out["current_limit_a"]["value"] == 0.3412
    assert "estimate" in out["current_limit_a"]["source"]
    assert out["speed_limit_rpm"]["source"].startswith("model file")
    # a limit the identification record only configured is named so
    held = {**info, "greybox": {"current_limit": 0.7, "current_limit_estimated": False}}
    assert "configured" in resolve_saturation(held, {})["current_limit_a"]["source"]
    # the record's (or the caller's) value wins, with its source
    given = {"current_limit_a": 0.25, "sources": {"current_limit_a": "record"}}
    out = resolve_saturation(info, given)
    assert out["current_limit_a"] == {"value": 0.25, "source": "record"}
    assert resolve_saturation({}, {}) == {}  # known nowhere: left out
