"""The realistic wheel twin (issue 22): each imperfection against physics or its ideal contrast."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rwlab.errors import ConfigError
from rwlab.testbed import ExperimentConfig, read_record, run_experiment
from rwlab.wheel import RW90, Mode, WheelParams, WheelPhysics
from rwlab.wheel.imperfections import TOLERANCES, stribeck_friction
from rwlab.wheel.physics import IDEAL, rad_s_to_rpm, rpm_to_rad_s


def _hold(wheel: WheelPhysics, seconds: float, dt: float = 1e-3) -> None:
    for _ in range(round(seconds / dt)):
        wheel.step(dt)


def _readings(params: WheelParams, rpm: float, n: int = 200, every: float = 0.1):
    wheel = WheelPhysics(params, seed=3)
    wheel.command(Mode.SPEED, rpm)
    _hold(wheel, 40.0 + abs(rpm) / 250)  # settled
    speed, current = [], []
    for _ in range(n):
        _hold(wheel, every)
        speed.append(wheel.measured_speed_rpm())
        current.append(wheel.measured_current())
    return np.array(speed), np.array(current)


def test_motor_current_reading_is_noisy_and_quantised_at_constant_speed():
    _, current = _readings(RW90, 3000.0)
    assert np.std(current) > 0.001  # the ADC and amplifier noise show
    lsb = RW90.current_lsb_a
    assert np.allclose(current / lsb, np.round(current / lsb))
    _, exact = _readings(IDEAL, 3000.0)
    assert np.std(exact) < 1e-4  # the ideal twin reports the true current, still settling


def test_hall_speed_is_coarser_at_10_rpm_than_at_3000_rpm():
    slow, _ = _readings(RW90, 10.0)
    fast, _ = _readings(RW90, 3000.0)
    assert np.std(slow) >= 3 * np.std(fast), (np.std(slow), np.std(fast))
    assert abs(np.mean(slow) - 10) < 1.0 and abs(np.mean(fast) - 3000) < 0.5
    assert np.std(fast) > 0  # capture jitter still shows


def test_hall_speed_reads_zero_below_the_minimum_speed():
    wheel = WheelPhysics(RW90)
    wheel.command(Mode.SPEED, 30.0)
    _hold(wheel, 30.0)
    wheel.command(Mode.IDLE, 0.0)  # coasts down through the slowest readable speed
    seen = []
    for _ in range(1200):  # 4.5 rpm/s: 7 s to stop
        _hold(wheel, 0.01)
        if 0 < rad_s_to_rpm(wheel.speed) < 0.5 * RW90.min_measurable_rpm:
            seen.append(wheel.measured_speed_rpm())
    assert len(seen) >= 5 and not any(seen)  # it turns, too slowly for a Hall edge in time


def test_a_slow_reversal_dwells_at_zero_speed_until_breakaway():
    """Stiction: reversing slowly (8 → −8 rpm), the wheel stops at zero, then breaks away."""

    def time_at_rest(params: WheelParams) -> tuple[float, float]:
        wheel = WheelPhysics(params)
        wheel.command(Mode.SPEED, 8.0)
        _hold(wheel, 30.0)
        wheel.command(Mode.SPEED, -8.0)
        stopped, dt = 0.0, 1e-3
        for _ in range(30_000):
            wheel.step(dt)
            stopped += dt if abs(wheel.speed) < rpm_to_rad_s(0.01) else 0.0
        return stopped, rad_s_to_rpm(wheel.speed)

    dwell, final = time_at_rest(RW90)
    assert dwell >= 0.5 and final < -4.0  # stuck (1.8 s measured), then broke away, reversed
    ideal_dwell, ideal_final = time_at_rest(IDEAL)
    assert ideal_dwell < 0.1 and ideal_final < -4.0


@given(
    speed=st.floats(-900, 900).filter(lambda w: abs(w) > 1e-6),
    coulomb=st.floats(0, 1e-3),
    extra=st.floats(0, 1e-3),
    ws=st.floats(0.01, 10),
    b=st.floats(0, 1e-5),
)
def test_stribeck_friction_opposes_motion_between_its_limits(speed, coulomb, extra, ws, b):
    f = stribeck_friction(speed, coulomb, coulomb + extra, ws, b)
    assert f * speed >= 0  # dissipative
    low, high = coulomb + b * abs(speed), coulomb + extra + b * abs(speed)
    assert low * (1 - 1e-12) <= abs(f) <= high * (1 + 1e-12)


def test_stribeck_friction_starts_at_breakaway_and_falls_to_coulomb():
    assert stribeck_friction(1e-9, 2e-4, 3e-4, 1.0, 0.0) == pytest.approx(3e-4)
    assert stribeck_friction(-50.0, 2e-4, 3e-4, 1.0, 1e-6) == pytest.approx(-2e-4 - 5e-5)


def test_back_emf_caps_the_speed_a_low_bus_voltage_can_reach():
    params = replace(RW90, bus_voltage=12.0)
    wheel = WheelPhysics(params)
    wheel.command(Mode.ACCELERATION, 314.0)
    _hold(wheel, 40.0)
    ceiling = params.driver_max_duty * params.bus_voltage / params.torque_constant  # i → 0
    assert wheel.speed < ceiling
    assert wheel.speed > 0.9 * ceiling * (1 - 0.0012 * (wheel.temperature - 20)) - 20
    unlimited = WheelPhysics(replace(params, back_emf=False))
    unlimited.command(Mode.ACCELERATION, 314.0)
    _hold(unlimited, 40.0)
    assert unlimited.speed > 1.2 * ceiling


def test_temperature_lowers_viscous_friction():
    wheel = WheelPhysics(replace(RW90, friction_drift=0.0))
    cold = wheel.bearing_friction(500.0)
    wheel.temperature = RW90.ambient_c + 20
    warm = wheel.bearing_friction(500.0)
    b = RW90.viscous_friction * 500
    assert cold - warm == pytest.approx(b * (1 - math.exp(-0.02 * 20)), rel=1e-9)


def test_unit_seeds_draw_parameters_within_their_tolerances():
    units = [RW90.for_unit(n) for n in range(20)]
    for name, tol in TOLERANCES.items():
        values = np.array([getattr(u, name) for u in units])
        nominal = getattr(RW90, name)
        half = tol.relative * abs(nominal) + tol.absolute
        assert np.all(np.abs(values - nominal) <= half * (1 + 1e-12)), name
        assert np.ptp(values) > 0.5 * half, name  # they do differ, over most of the range
    assert RW90.for_unit(3) == RW90.for_unit(3)
    assert len({u.hall_pattern_seed for u in units}) == 20
    assert all(u.speed_kp == RW90.speed_kp for u in units)  # one firmware for every unit
    with pytest.raises(ConfigError, match="unit"):
        RW90.for_unit(-1)


def test_toml_names_a_preset_and_a_unit(tmp_path):
    path = tmp_path / "w.toml"
    path.write_text('[wheel]\npreset = "ideal"\nunit = 2\n')
    params = WheelParams.from_toml(path)
    assert params == IDEAL.for_unit(2)
    path.write_text('[wheel]\npreset = "perfect"\n')
    with pytest.raises(ConfigError, match="preset"):
        WheelParams.from_toml(path)
    with pytest.raises(ConfigError, match="breakaway"):
        WheelParams(breakaway_friction=1e-5)
    with pytest.raises(ConfigError, match="true or false"):
        WheelParams(stiction=1)


def test_telemetry_carries_jitter_bus_voltage_and_the_unit(tmp_path):
    out = tmp_path / "r.mcap"
    cfg = ExperimentConfig(signal="step", duration=60, unit=1, telemetry_rate=20)
    run_experiment(cfg, out)
    rec = read_record(out)
    t = np.array([m["t"] for m in rec.messages["/telemetry"]])
    gaps = np.diff(t)
    assert np.std(gaps) > 1e-5 and np.all(np.abs(gaps - 0.05) < 0.05 + 2e-3)
    volts = [m["bus_voltage_v"] for m in rec.messages["/heartbeat"]]
    assert all(abs(v - RW90.bus_voltage) <= 1.0 for v in volts)
    assert rec.metadata["experiment"]["unit"] == 1
    assert rec.metadata["wheel"]["inertia"] == RW90.for_unit(1).inertia
    ideal = tmp_path / "i.mcap"
    run_experiment(ExperimentConfig(signal="step", duration=60, wheel="ideal"), ideal)
    t = np.array([m["t"] for m in read_record(ideal).messages["/telemetry"]])
    assert np.std(np.diff(t)) < 1e-9  # the ideal twin sends exactly on time


@given(volts=st.floats(10.0, 41.5), temp=st.floats(-40.0, 87.5))
def test_heartbeat_carries_the_bus_voltage_to_half_a_volt(volts, temp):
    from rwlab.wheel import protocol as proto

    beat = proto.Heartbeat(3, Mode.SPEED, proto.Fault.NONE, temp, 12, 7, volts)
    back = proto.decode(proto.encode(beat))
    assert abs(back.bus_voltage - volts) <= 0.25 + 1e-9
    assert abs(back.temperature - temp) <= 0.25 + 1e-9 and back.commands_seen == 7


def test_the_documented_wheel_toml_is_the_default_twin():
    from pathlib import Path

    path = Path(__file__).parent.parent / "docs" / "wheels" / "rw90.toml"
    assert WheelParams.from_toml(path) == RW90
