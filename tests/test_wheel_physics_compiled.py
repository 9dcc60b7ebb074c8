"""The compiled twin physics gives the interpreted twin's numbers, bit for bit.

``tests/data/physics_golden.json`` holds traces of the pure-Python physics (commit
d8832b8, before the step was compiled; x86-64, glibc's libm) for the three wheel
presets and the ideal twin, two seeds and a drawn unit each, through speed and
acceleration commands, a reversal through zero (stiction, Hall edges), coasting,
the injectable rotor and driver faults (friction, torque constant, current limit, a
forced overcurrent) and a fault clear. Every state and every measurement is
compared exactly: a hash of the full 1 kHz trace and the trace every 0.5 s (to show
where it went wrong). Regenerate (only on purpose, from the reference physics):
``PYTHONPATH=src python -m tests.test_wheel_physics_compiled --write``.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from rwlab.wheel import Fault, Mode, WheelParams, WheelPhysics

GOLDEN = Path(__file__).parent / "data" / "physics_golden.json"
DT = 1e-3
CASES = [
    (preset, seed, unit)
    for preset in ("rw90", "nrwa-t6", "rw-0.01", "ideal")
    for seed, unit in ((0, None), (11, 3))
]
COLUMNS = (
    "time angle speed current temperature bus_voltage integral faults mode limited "
    "measured_speed measured_current measured_bus"
).split()


def _params(preset: str, unit: int | None) -> WheelParams:
    params = WheelParams.preset(preset)
    return params if unit is None else params.for_unit(unit)


def _script(wheel: WheelPhysics) -> list[tuple[float, object]]:
    """(time s, action) pairs: commands and faults, scaled to the wheel's limits."""
    top = 0.6 * wheel.params.max_speed_rpm
    accel = 0.5 * wheel.params.max_accel_rpm_s

    def latch_overcurrent() -> None:
        wheel.forced_current = 2 * wheel.params.overcurrent_fault

    def weaken() -> None:
        wheel.friction_factor, wheel.torque_constant_factor = 2.5, 0.8

    def clamp() -> None:
        wheel.current_limit = 0.5 * wheel.params.current_limit

    return [
        (0.0, (Mode.SPEED, 0.02 * top)),  # slow: stiction and coarse Hall speed
        (2.0, (Mode.SPEED, top)),
        (5.0, (Mode.SPEED, -0.3 * top)),  # a reversal through zero
        (8.0, weaken),
        (9.0, (Mode.ACCELERATION, accel)),
        (11.0, clamp),
        (12.0, (Mode.IDLE, 0.0)),  # coasting on friction
        (14.0, (Mode.SPEED, 5.0)),
        (15.5, latch_overcurrent),
        (16.0, (Mode.SPEED, top)),  # refused: the fault is latched
        (17.0, (Mode.CLEAR_FAULT, 0.0)),
        (17.5, (Mode.SPEED, -0.5 * top)),
    ]


def trace(preset: str, seed: int, unit: int | None, duration: float = 20.0) -> np.ndarray:
    """The wheel's state and measurements after every 1 ms step, shape (steps, 13)."""
    wheel = WheelPhysics(_params(preset, unit), seed)
    script = _script(wheel)
    steps = round(duration / DT)
    out = np.empty((steps, len(COLUMNS)))
    k = 0
    for i in range(steps):
        while k < len(script) and script[k][0] <= i * DT + 1e-9:
            action = script[k][1]
            if callable(action):
                action()
            else:
                wheel.command(*action)  # type: ignore[misc]
            k += 1
        wheel.step(DT)
        measured = (
            (wheel.measured_speed_rpm(), wheel.measured_current(), wheel.measured_bus_voltage())
            if i % 100 == 99  # telemetry at 10 Hz: the rng draws as a node makes them
            else (np.nan, np.nan, np.nan)
        )
        out[i] = (
            wheel.time,
            wheel.angle,
            wheel.speed,
            wheel.current,
            wheel.temperature,
            wheel.bus_voltage,
            wheel._integral,
            int(wheel.faults),
            int(wheel.mode),
            float(wheel.speed_limited),
            *measured,
        )
    return out


def _key(preset: str, seed: int, unit: int | None) -> str:
    return f"{preset}/seed{seed}/unit{unit}"


def _summary(out: np.ndarray) -> dict:
    return {
        "sha256": hashlib.sha256(np.ascontiguousarray(out).tobytes()).hexdigest(),
        "every_500ms": out[499::500].tolist(),
    }


@pytest.mark.parametrize(("preset", "seed", "unit"), CASES)
def test_compiled_physics_reproduces_the_interpreted_twin_bit_for_bit(preset, seed, unit):
    golden = json.loads(GOLDEN.read_text())[_key(preset, seed, unit)]
    out = trace(preset, seed, unit)
    coarse = out[499::500]
    np.testing.assert_array_equal(coarse, np.array(golden["every_500ms"], dtype=float))
    assert _summary(out)["sha256"] == golden["sha256"]


def test_the_script_reaches_every_regime():
    """The golden cases are worth something only if the wheel goes where the script says."""
    out = trace("rw90", 0, None)
    col = {name: out[:, i] for i, name in enumerate(COLUMNS)}
    assert (col["speed"] > 0).any() and (col["speed"] < 0).any()  # both directions
    assert ((col["speed"] == 0) & (col["mode"] != Mode.IDLE)).any()  # stuck by stiction
    assert (col["faults"].astype(int) & Fault.OVERCURRENT).any()
    assert col["faults"][-1] == 0 and col["mode"][-1] == Mode.SPEED  # cleared, running
    assert (col["current"] != 0).any() and np.isfinite(col["measured_speed"][99::100]).all()


def write() -> None:
    golden = {_key(*case): _summary(trace(*case)) for case in CASES}
    GOLDEN.write_text(json.dumps(golden, indent=0) + "\n")


if __name__ == "__main__":
    if "--write" in sys.argv:
        write()
