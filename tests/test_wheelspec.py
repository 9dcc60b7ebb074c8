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


@pytest.mark.parametrize("name", PRESETS)
def test_a_spec_pickles_whole_and_stays_read_only(name):
    import pickle

    spec = WheelSpec.load(name)
    again = pickle.loads(pickle.dumps(spec))
    assert again == spec and again.hash == spec.hash
    assert dict(again.sources) == dict(spec.sources) and again.origin == spec.origin
    with pytest.raises(TypeError):
        again.sources["inertia_kg_m2"] = "changed"  # type: ignore[index]


def test_the_presets_differ_where_a_wheel_model_does():
    specs = [WheelSpec.load(n) for n in PRESETS]
    for field in ("inertia_kg_m2", "max_speed_rpm", "max_torque_nm", "speed_kp", "current_limit_a"):
        assert len({getattr(s, field) for s in specs}) == 3, field


def test_published_numbers():
    t6 = WheelSpec.load("nrwa-t6")
    assert (t6.max_torque_nm, t6.max_speed_rpm, t6.controller_mode) == (0.31, 5000.0, "torque")
    # NRWA-T6 ICD N2-A2a-DD0021 rev 10.02: 6 A (§8.1) × 53.4 mN·m/A (§9.1) at the motor, 30 V
    # drive rail (§8.1); 5000 rpm holds Fig 8-1's back-EMF knee, 7.1 N·m·s
    assert (t6.current_limit_a, t6.torque_constant_nm_a, t6.bus_voltage_v) == (6.0, 0.0534, 30.0)
    assert t6.motor_torque_nm == pytest.approx(0.3204)
    assert t6.momentum_capacity_nms == pytest.approx(7.1, rel=5e-3)
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
        (
            'max_torque_nm = { value = 0.0138, source = "',
            'max_torque_nm = 0.0138  # "',
            "max_torque",
        ),
        ("max_torque_nm = { value = 0.0138", 'max_torque_nm = { value = "x"', "max_torque_nm"),
        ("max_torque_nm = { value = 0.0138", "max_torque_nm = { value = 0.5", "current limit"),
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


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        (
            "inertia_kg_m2 = {",
            "inertai_kg_m2 = {",
            "unknown key 'inertai_kg_m2' in \\[rotor\\]; did you mean 'inertia_kg_m2'",
        ),
        (
            "max_speed_rpm = { value = 7800.0, source",
            "max_speed_rpm = { valeu = 7800.0, source",
            "unknown key 'valeu' in limits.max_speed_rpm; did you mean 'value'",
        ),
        (
            'format = "rwlab.WheelSpec/1"',
            'format = "rwlab.WheelSpec/1"\ntitel = "x"',
            "unknown key 'titel' at the top level; did you mean 'title'",
        ),
        (
            "[thermal]",
            '[thermal]\nbus_voltage_v = { value = 24.0, source = "x" }',
            "bus_voltage_v belongs in \\[supply\\]",
        ),
        (
            "inertia_kg_m2 = { relative",
            "inertia_kg_m2 = { relatve",
            "unknown key 'relatve' in tolerances.inertia_kg_m2; did you mean 'relative'",
        ),
    ],
)
def test_an_unknown_key_is_named_with_the_key_it_likely_meant(old, new, words, tmp_path):
    path = _edit("rw90", old, new, tmp_path)
    with pytest.raises(ConfigError, match=words):
        WheelSpec.load(path)


@pytest.mark.parametrize(
    ("name", "old", "new", "words"),
    [  # the T6 driven from its 28 V input, not its +30 V rail: 27.96 V of back-EMF > 27.40 V
        (
            "nrwa-t6",
            "bus_voltage_v = { value = 30.0",
            "bus_voltage_v = { value = 28.0",
            r"max_speed_rpm \(5000\) is out of the motor's reach.*27\.96 V.*27\.40 V",
        ),
        (
            "rw90",
            "bus_voltage_v = { value = 24.0",
            "bus_voltage_v = { value = 12.0",
            r"max_speed_rpm \(7800\) is out of the motor's reach",
        ),
        # an acceleration limit just under the T6's torque: 210 rpm/s × 0.0136 kg·m² < 0.31 N·m
        (
            "nrwa-t6",
            "max_accel_rpm_s = { value = 220.0",
            "max_accel_rpm_s = { value = 210.0",
            r"max_torque_nm \(0\.31 N·m\) cannot reach the spacecraft.*0\.2991 N·m",
        ),
        (
            "rw90",
            "max_torque_nm = { value = 0.0138",
            "max_torque_nm = { value = 0.015",
            r"max_accel_rpm_s 314 × inertia_kg_m2 0\.00042 gives 0\.01381 N·m",
        ),
    ],
)
def test_a_wheel_that_cannot_reach_its_speed_or_deliver_its_torque_is_refused(
    name, old, new, words, tmp_path
):
    path = _edit(name, old, new, tmp_path)
    with pytest.raises(ConfigError, match=words):
        WheelSpec.load(path)


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_reaches_its_speed_and_delivers_its_torque(name):
    spec = WheelSpec.load(name)
    assert spec.accel_torque_nm >= spec.max_torque_nm
    drive = spec.driver_max_duty * spec.bus_voltage_v
    assert spec.torque_constant_nm_a * spec.max_speed_rad_s < drive


@pytest.mark.parametrize("name", PRESETS)
def test_to_toml_is_a_whole_file_that_reads_back_to_the_same_spec(name, tmp_path):
    spec = WheelSpec.load(name)
    path = tmp_path / "mine.toml"
    path.write_text(spec.to_toml(), encoding="utf-8")
    again = WheelSpec.load(path)
    assert again == spec and again.hash == spec.hash
    edited = spec.to_toml().replace(f'name = "{name}"', 'name = "my-wheel"')
    path.write_text(edited, encoding="utf-8")
    assert WheelSpec.load(path).name == "my-wheel"


def test_a_spec_carried_by_a_record_is_not_refused_for_its_physics():
    # a record or model.json keeps the wheel as it was configured, even one the physics
    # check now refuses as a file (the T6 preset before it was made one motor: the ICD's
    # k_t on the 28 V input instead of the +30 V drive rail)
    old = WheelSpec.load("nrwa-t6").with_(bus_voltage_v=28.0, current_limit_a=5.81)
    assert WheelSpec.from_dict(old.to_dict()) == old
