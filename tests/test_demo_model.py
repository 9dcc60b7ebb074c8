"""The demo's model.json carries its wheel model (issue 41): a scenario refuses it as it
refuses ``rwlab identify``'s."""

from __future__ import annotations

import json

from click.testing import CliRunner

from rwlab.cli import main
from rwlab.demo import demo_model
from rwlab.ident.study import identification_study
from rwlab.testbed import load_record
from rwlab.wheelspec import WheelSpec


def test_the_demo_model_carries_its_wheel_and_an_rw90_model_is_refused_on_geo_comsat(tmp_path):
    record = tmp_path / "prbs.mcap"
    args = ["experiment", "--duration", "400", "--seed", "3", "--out", str(record)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    model = demo_model(identification_study(load_record(record)))
    spec = WheelSpec.load("rw90")
    assert model["wheel"]["name"] == "rw90" and model["wheel"]["hash"] == spec.hash
    assert model["saturation"]["speed_rpm"] == spec.max_speed_rpm
    path = tmp_path / "model.json"
    path.write_text(json.dumps(model), encoding="utf-8")
    sim = ["attitude", "simulate", "--scenario", "geo-comsat", "--wheel-model", str(path)]
    r = CliRunner().invoke(main, [*sim, "--duration", "10", "--out", str(tmp_path / "sim")])
    assert r.exit_code == 2 and "needs 0.1 N·m" in r.output, r.output
