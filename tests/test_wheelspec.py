"""WheelSpec: the presets load and round-trip; a bad spec is a ConfigError naming the key."""

from __future__ import annotations

import math
import tomllib
from importlib import resources

import pytest

from rwlab.errors import ConfigError
from rwlab.wheelspec import SECTIONS, WheelSpec, preset_names

PRESETS = ("rw90", "nrwa-t6", "rw-0.01")


def _text(name: str) -> str:
    return (resources.files("rwlab.wheelspec") / "presets" / f"{name}.toml").read_text("utf-8")


def test_the_three_presets_ship():
    assert set(PRESETS) <= set(preset_names())


@pytest.mark.parametrize("name", PRESETS)
def test_preset_loads_with_a_source_for_every_number(name):
    spec = WheelSpec.load(name)
    assert spec.name == name
    numbers = [n for items in SECTIONS.values() for n, _ in items]
    assert sorted(spec.sources) == sorted(numbers)
    assert all(len(spec.sources[n]) > 10 for n in numbers)
    assert spec.max_torque_nm <= spec.motor_torque_nm
    assert math.isclose(
        spec.momentum_capacity_nms, spec.inertia_kg_m2 * spec.max_speed_rpm * math.pi / 30
    )


@pytest.mark.parametrize("name", PRESETS)
def test_round_trip_and_hash(name, tmp_path):
    spec = WheelSpec.load(name)
    again = WheelSpec.from_dict(spec.to_dict())
    assert again == spec and again.hash == spec.hash
    # the same numbers in another file (comments dropped, keys reordered) hash the same
    path = tmp_path / "copy.toml"
    path.write_text("# a copy\n" + _text(name), encoding="utf-8")
    assert WheelSpec.load(path).hash == spec.hash
    assert spec.with_(max_torque_nm=spec.max_torque_nm / 2).hash != spec.hash


def test_the_presets_differ_where_a_wheel_model_does():
    specs = [WheelSpec.load(n) for n in PRESETS]
    for field in ("inertia_kg_m2", "max_speed_rpm", "max_torque_nm", "speed_kp", "current_limit_a"):
        assert len({getattr(s, field) for s in specs}) == 3, field


def test_published_numbers():
    t6 = WheelSpec.load("nrwa-t6")
    assert (t6.max_torque_nm, t6.max_speed_rpm, t6.controller_mode) == (0.31, 5000.0, "torque")
    assert t6.motor_torque_nm == pytest.approx(0.31, rel=2e-3)
    cube = WheelSpec.load("rw-0.01")
    assert cube.momentum_capacity_nms == pytest.approx(0.018, rel=1e-3)
    assert cube.max_torque_nm == 0.001


def _edit(name: str, old: str, new: str, tmp_path):
    text = _text(name)
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ('{ value = 0.015, source = "paper A, Table 1 (nominal torque)" }', "0.015", "max_torque"),
        ("max_torque_nm = { value = 0.015", 'max_torque_nm = { value = "x"', "max_torque_nm"),
        ("max_torque_nm = { value = 0.015", "max_torque_nm = { value = 0.5", "current limit"),
        ("[thermal]", '[thermal]\nfan_speed = { value = 1.0, source = "x y z" }', "fan_speed"),
        ("inertia_kg_m2 = { value = 4.2e-4", "inertia_kg_m2 = { value = -4.2e-4", "inertia_kg_m2"),
        ('controller_mode = { value = "speed"', 'controller_mode = { value = "pwm"', "pwm"),
        ('format = "rwlab.WheelSpec/1"', 'format = "rwlab.WheelSpec/9"', "WheelSpec/9"),
    ],
)
def test_bad_spec_is_a_config_error_naming_the_key(old, new, words, tmp_path):
    path = _edit("rw90", old, new, tmp_path)
    with pytest.raises(ConfigError, match=words) as err:
        WheelSpec.load(path)
    assert str(path) in str(err.value)


def test_unknown_name_lists_the_presets():
    with pytest.raises(ConfigError, match="rw90"):
        WheelSpec.load("rw91")


def test_not_toml(tmp_path):
    path = tmp_path / "x.toml"
    path.write_text("this is = = not toml", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid TOML"):
        WheelSpec.load(path)


def test_schema_is_the_loader_shape():
    from rwlab.schemas import schema

    props = schema("wheelspec")["properties"]
    for section, items in SECTIONS.items():
        assert set(props[section]["properties"]) == {n for n, _ in items}
    for name in PRESETS:  # and the files are valid against it as plain TOML
        import jsonschema

        jsonschema.validate(tomllib.loads(_text(name)), schema("wheelspec"))
