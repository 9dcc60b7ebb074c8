"""The rule detectors judge a wheel by its own model's datasheet (issue 41 item 3, diagnose):
nominal friction and inertial currents, the tolerances between units, the current noise
and the speed limits all come from the ``model.json``'s wheel spec, not the RW90's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rwlab.diagnose import Diagnoser
from rwlab.diagnose.reference import (
    DEFAULT_TOLERANCE,
    BlockStats,
    HealthyReference,
    nominal_friction_currents,
    nominal_inertial_current,
    unit_bounds,
    unit_tolerance,
)
from rwlab.ident.models import PolyModel
from rwlab.wheel import IdentifiedWheel
from rwlab.wheelspec import WheelSpec, preset_names

STATS = {
    "friction": BlockStats(0.0, 0.08, 20, 0.3, 900, "batch means"),
    "motor": BlockStats(0.0, 0.035, 10, 0.3, 900, "batch means"),
    "speed": BlockStats(0.0, 0.1, 20, 0.2, 400, "batch means"),
    "lag": BlockStats(0.0, 0.005, 10, 0.2, 600, "batch means"),
}


def _wheel(spec: WheelSpec | None) -> IdentifiedWheel:
    """A first-order speed loop at Ts = 0.5 s with the spec's limits (the RW90's: None)."""
    s = spec or WheelSpec.load("rw90")
    model = PolyModel(A=[1.0, -0.8], B=[0.0, 0.2], Ts=0.5)
    return IdentifiedWheel(
        model,
        speed_limit_rpm=s.max_speed_rpm,
        accel_limit_rpm_s=s.max_accel_rpm_s,
        wheel_spec=spec,
    )


def _reference(spec: WheelSpec, friction: float) -> HealthyReference:
    """A reference unit at ``friction`` × the spec's nominal friction, nominal I/k_t, the
    spec's tolerances between units."""
    viscous, coulomb = nominal_friction_currents(spec)
    c = (nominal_inertial_current(spec), friction * viscous, friction * coulomb, 0.0)
    return HealthyReference(0.5, c, STATS, 0.01, 1000, 1e-4, 2400, unit_tolerance(spec))


def _friction_alarms(diagnoser: Diagnoser, spec: WheelSpec, factor: float) -> list:
    """Holds at ± half the spec's speed limit (two minutes each, half an hour) of a unit
    whose friction current is ``factor`` × the spec's nominal, 1 % of noise."""
    rng = np.random.default_rng(0)
    viscous, coulomb = nominal_friction_currents(spec)
    rpm = 0.5 * spec.max_speed_rpm
    alarms = []
    for k in range(3600):
        speed = math.copysign(rpm, 1 if (k // 240) % 2 == 0 else -1)
        current = math.copysign(factor * (viscous * rpm + coulomb), speed)
        current *= 1 + rng.normal(0, 0.01)
        alarms += diagnoser.update(0.5 * k, speed, speed, current, 0.0)
    return [a for a in alarms if a.detector == "friction"]


def test_the_rw90_spec_gives_the_constants_the_detectors_were_tuned_with():
    """Known truth: the RW90's tolerances (friction ±30 %, I ±2 %, k_t ±5 %, 5 mA of sense
    offset) give the defaults: 0.86 and 0.15 between units, 1.3 and 1.074 × nominal."""
    rw90 = WheelSpec.load("rw90")
    assert unit_tolerance(rw90) == DEFAULT_TOLERANCE
    b = unit_bounds(rw90)
    assert b.friction_upper == pytest.approx(1.3)
    assert b.motor_upper == pytest.approx(1.02 / 0.95)
    assert b.current_offset_a == pytest.approx(0.005)
    d = Diagnoser(_wheel(None), _reference(rw90, 1.0), calibration=False)
    assert d.spec.name == "rw90"  # a model without a spec: the RW90's, as before specs
    assert d.held_max_rpm == pytest.approx(6500.0)
    assert d.motor_min_a == pytest.approx(0.1)


@pytest.mark.parametrize("name", preset_names())
def test_a_healthy_unit_at_the_datasheet_bound_passes_and_a_worn_one_alarms(name):
    """Each preset with its own model: a reference unit at the spec's lower friction bound,
    a healthy unit at its upper bound raises no friction alarm; the same unit with
    friction × 1.5 does. Judged with the RW90's datasheet instead, the CubeSat wheel's
    worn unit went unseen (its nominal friction current is half the RW90's, so the RW90's
    bound allowed 5.7× the reference's), and a T6 unit of higher I/k_t than its
    reference had no motor tolerance left (the RW90's I/k_t is 0.08 of the T6's)."""
    spec = WheelSpec.load(name)
    f = unit_bounds(spec).friction_upper - 1.0
    wheel = _wheel(spec)

    def fresh():
        return Diagnoser(wheel, _reference(spec, 1.0 - f), calibration=False)

    assert _friction_alarms(fresh(), spec, 1.0 + f) == []
    assert _friction_alarms(fresh(), spec, 1.5 * (1.0 + f)) != []
    # the motor test's tolerance: the spec's upper bound of I/k_t over a nominal reference
    d = fresh()
    motor = d._detectors["motor"]
    tol = (motor.k - 0.5) * STATS["motor"].sigma
    bound = min(unit_tolerance(spec)["motor"], unit_bounds(spec).motor_upper - 1)
    assert tol == pytest.approx(bound)
    assert tol > 0.02


def test_the_tests_scale_with_the_wheels_current_noise_and_speed_limit():
    """The motor test's floor is 25 σ of the wheel's own current noise; the held-speed
    test's top is 5/6 of the lower of its speed limit and no-load back-EMF speed."""
    for name in preset_names():
        spec = WheelSpec.load(name)
        d = Diagnoser(_wheel(spec), _reference(spec, 1.0), calibration=False)
        assert d.motor_min_a == pytest.approx(25 * spec.current_noise_a)
        emf = spec.bus_voltage_v * spec.driver_max_duty / spec.torque_constant_nm_a * 30 / math.pi
        assert d.held_max_rpm == pytest.approx(5 / 6 * min(spec.max_speed_rpm, emf))
        assert d.held_max_rpm < spec.max_speed_rpm


def test_the_reference_is_measured_with_the_prior_it_is_tested_with():
    """The friction-change test's values on the identification record (its σ in the
    reference) come from the same datasheet prior as the test on a later record: with the
    RW90's prior there and the T6's here, a healthy T6 unit (unit 11's 20-minute PRBS
    against unit 0's model) alarmed at 909 s."""
    spec = WheelSpec.load("nrwa-t6")
    measuring = Diagnoser(_wheel(spec), None)
    testing = Diagnoser(_wheel(spec), _reference(spec, 1.0), calibration=False)
    assert measuring._change_probe.spec is spec
    assert testing._detectors["friction_change"].spec is spec
