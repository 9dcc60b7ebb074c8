"""The twin is built from a wheel model's spec and honours its limits, for every preset."""

from __future__ import annotations

import numpy as np
import pytest

from rwlab.wheel import Mode, WheelParams, WheelPhysics
from rwlab.wheel.physics import simulate_speed_command
from rwlab.wheelspec import TWIN_NAMES, WheelSpec

PRESETS = ("rw90", "nrwa-t6", "rw-0.01")


@pytest.mark.parametrize("name", PRESETS)
def test_twin_fields_are_the_specs(name):
    spec = WheelSpec.load(name)
    params = WheelParams.preset(name)
    for spec_name, twin_name in TWIN_NAMES.items():
        assert getattr(params, twin_name) == getattr(spec, spec_name), spec_name
    assert params.model == name


@pytest.mark.parametrize("name", PRESETS)
def test_unit_draw_uses_the_models_tolerances(name):
    spec = WheelSpec.load(name)
    nominal = WheelParams.from_spec(spec)
    units = [nominal.for_unit(u) for u in range(40)]
    for spec_name, tol in spec.tolerances.items():
        twin = TWIN_NAMES[spec_name]
        spread = np.array([getattr(u, twin) for u in units]) - getattr(nominal, twin)
        bound = tol.relative * abs(getattr(nominal, twin)) + tol.absolute
        assert np.all(np.abs(spread) <= bound * (1 + 1e-12)), spec_name
        assert np.max(np.abs(spread)) > 0.5 * bound, spec_name  # the spread is used
    assert nominal.for_unit(7) == WheelParams.from_spec(spec, unit=7)


@pytest.mark.parametrize("name", PRESETS)
def test_twin_honours_speed_and_acceleration_limits(name):
    spec = WheelSpec.load(name)
    params = WheelParams.from_spec(spec)
    # a step far beyond the limit: the wheel rises at its acceleration limit and stops at
    # its speed limit
    beyond = 2 * spec.max_speed_rpm
    speed = simulate_speed_command(np.full(400, beyond), 0.5, params)
    assert np.max(speed) <= spec.max_speed_rpm * 1.01
    assert np.max(speed) >= spec.max_speed_rpm * 0.97
    slope = np.max(np.diff(speed)) / 0.5
    assert slope <= spec.max_accel_rpm_s * 1.05
    assert slope >= spec.max_accel_rpm_s * 0.5  # accelerates near its limit early on


@pytest.mark.parametrize("name", PRESETS)
def test_twin_current_stays_within_the_current_limit(name):
    spec = WheelSpec.load(name)
    wheel = WheelPhysics(WheelParams.from_spec(spec), seed=1)
    wheel.command(Mode.ACCELERATION, 10 * spec.max_accel_rpm_s)
    peak = 0.0
    for _ in range(2000):
        wheel.step(2e-3)
        peak = max(peak, abs(wheel.current))
    assert peak <= spec.current_limit_a * (1 + 1e-9)


@pytest.mark.parametrize("name", PRESETS)
def test_the_setpoint_weight_is_the_specs_inner_controller(name, tmp_path):
    """β belongs to the spec's inner controller (each preset a plain PI, β = 1, with its
    source) and flows into the twin; a spec file with its own β flies it, and one written
    before β reads 1 and says so."""
    spec = WheelSpec.load(name)
    assert spec.speed_setpoint_weight == 1.0
    assert "assumed, because" in spec.source("speed_setpoint_weight")
    assert WheelParams.from_spec(spec).speed_setpoint_weight == 1.0
    half = WheelParams.from_spec(spec.with_(speed_setpoint_weight=0.15))
    assert half.speed_setpoint_weight == 0.15
    # a step with β = 0.15 has less proportional kick: the wheel starts slower
    starts = []
    for params in (WheelParams.from_spec(spec), half):
        wheel = WheelPhysics(params, seed=0)
        wheel.command(Mode.SPEED, 0.2 * spec.max_speed_rpm)
        for _ in range(20):
            wheel.step(0.01)
        starts.append(wheel.momentum)
    assert starts[1] < starts[0]
    old = spec.to_dict()
    del old["controller"]["speed_setpoint_weight"]
    back = WheelSpec.from_dict(old)
    assert back.speed_setpoint_weight == 1.0
    assert "states none" in back.source("speed_setpoint_weight")
    # a spec (a model.json) written before β keeps its hash: its file's form has no β
    assert "speed_setpoint_weight" not in back.to_dict()["controller"]
    import hashlib
    import json

    text = json.dumps(old, sort_keys=True, separators=(",", ":"))
    assert back.hash == hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
    assert WheelSpec.from_dict(back.to_dict()) == back
