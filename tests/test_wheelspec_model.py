"""model.json carries the wheel model's spec: its saturations are the spec's, on every preset."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from rwlab.cli import main
from rwlab.errors import FileFormatError
from rwlab.ident.model_file import WheelModelFile
from rwlab.wheelspec import WheelSpec

PRESETS = ("rw90", "nrwa-t6", "rw-0.01")


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """Each preset: a 400-s PRBS on its twin, identified with the defaults."""
    out = {}
    for name in PRESETS:
        folder = tmp_path_factory.mktemp(name)
        record = folder / "prbs.mcap"
        args = ["experiment", "--wheel", name, "--duration", "400", "--seed", "5"]
        r = CliRunner().invoke(main, [*args, "--out", str(record)])
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(main, ["identify", str(record), "--out", str(folder / "id")])
        assert r.exit_code == 0, r.output
        out[name] = folder / "id" / "model.json"
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", PRESETS)
def test_identify_gives_the_specs_saturations(identified, name):
    spec = WheelSpec.load(name)
    d = json.loads(identified[name].read_text())
    assert d["format"] == "rwlab.WheelModel/2"
    assert d["saturation"]["speed_rpm"] == spec.max_speed_rpm
    assert d["saturation"]["accel_rpm_s"] == spec.max_accel_rpm_s
    assert d["wheel"]["name"] == name and d["wheel"]["hash"] == spec.hash
    assert d["wheel"]["max_torque_nm"] == spec.max_torque_nm
    model = WheelModelFile.load(identified[name])
    assert model.wheel_spec == spec
    if "greybox" in d:  # the physical model starts from this wheel's inertia, not the RW90's
        assert d["greybox"]["inertia"] == spec.inertia_kg_m2


@pytest.mark.slow
def test_a_version_1_model_reads_without_a_spec_and_an_edited_spec_is_refused(identified, tmp_path):
    d = json.loads(identified["nrwa-t6"].read_text())
    old = {k: v for k, v in d.items() if k != "wheel"} | {"format": "rwlab.WheelModel/1"}
    (tmp_path / "v1.json").write_text(json.dumps(old))
    model = WheelModelFile.load(tmp_path / "v1.json")
    assert model.wheel_spec is None and model.speed_limit_rpm == 5000.0
    d["wheel"]["spec"]["limits"]["max_torque_nm"]["value"] = 0.2
    (tmp_path / "edited.json").write_text(json.dumps(d))
    with pytest.raises(FileFormatError, match="hash"):
        WheelModelFile.load(tmp_path / "edited.json")
