"""The HIL wheel health check: null-space excitation and the command-tracking test."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rwlab.attitude.scenario import load_scenario
from rwlab.hil.health import (
    PROBE_CALIBRATION,
    NullSpaceDither,
    TrackingTest,
    name_fault,
    null_vector,
)
from rwlab.wheel.physics import RW90, rad_s_to_rpm

PYRAMID = load_scenario("geo-smallsat-pyramid").wheel_matrix


def test_null_vector_of_a_pyramid_and_none_for_three_axes():
    n = null_vector(PYRAMID)
    assert n is not None
    np.testing.assert_allclose(PYRAMID @ n, 0, atol=1e-12)
    assert np.max(np.abs(n)) == pytest.approx(1.0)
    assert null_vector(np.eye(3)) is None
    assert null_vector(PYRAMID[:, [0, 2, 3]]) is None  # any three of a pyramid span the body


@given(
    t=st.floats(0, 1e5),
    idle=st.sampled_from([None, 0, 1, 2, 3]),
)
def test_the_dither_puts_no_torque_on_the_body(t, idle):
    """Physics invariant: the excitation, probes included, lies in the null space of the
    wheels it drives."""
    active = np.ones(4, bool)
    if idle is not None:
        active[idle] = False
    tau = NullSpaceDither(PYRAMID, 4.2e-4, probe_rpm_s=280.0).torques(t, active)
    np.testing.assert_allclose(PYRAMID @ tau, 0, atol=1e-15)
    if idle is not None:  # three wheels left: no null space, no excitation
        assert not np.any(tau)


def test_the_dither_is_zero_mean_with_the_stated_amplitude():
    inertia = 4.2e-4
    d = NullSpaceDither(PYRAMID, inertia, amplitude_rpm_s=10.0, period_s=4.0)
    t = np.arange(0, 4.0, 0.001)
    tau = np.array([d.torques(x, np.ones(4, bool)) for x in t])
    accel_rpm_s = rad_s_to_rpm(tau / inertia)
    assert np.max(np.abs(accel_rpm_s)) == pytest.approx(10.0, rel=1e-6)
    np.testing.assert_allclose(accel_rpm_s.mean(axis=0), 0, atol=1e-9)


def test_a_probe_pushes_and_returns_whole_control_periods_and_leaves_the_speeds():
    """Each probe is ten 0.1-s periods out and ten back, on k·dt times as the loop computes
    them (floats a hair off the boundaries): the speeds it moves come back exactly."""
    inertia, dt = 4.2e-4, 0.1
    d = NullSpaceDither(PYRAMID, inertia, amplitude_rpm_s=0.0, probe_rpm_s=280.0)
    active = np.ones(4, bool)
    d.torques(0.0, active)
    phases = np.array([d.probe_phase(k * dt) for k in range(3600)])
    speed = sum(rad_s_to_rpm(d.torques(k * dt, active) / inertia) * dt for k in range(3600))
    starts = np.flatnonzero((phases[1:] == 1) & (phases[:-1] == 0)) + 1
    np.testing.assert_allclose(starts * dt, [60, 120, 180, 240, 300], atol=1e-9)
    assert np.sum(phases == 1) == np.sum(phases == -1) == 50
    np.testing.assert_allclose(speed, 0, atol=1e-9)
    d.torques(0.0, np.array([True, True, False, True]))  # three wheels: no null space
    assert d.probe_phase(60.0) == 0


def _wheel(
    test,
    rng,
    steps,
    follow,
    drag_rpm_s=0.0,
    speed=1000.0,
    dt=0.1,
    t0=0.0,
    probe=None,
    clamp=1.0,
    frozen=None,
):
    """A synthetic wheel under the dither: the speed it reports (0.5 rpm noise and quantum)
    follows ``follow`` × the command, less a drag; returns the first alarm or None.

    With ``probe`` (a ``NullSpaceDither`` of one wheel) its probes are flown too: the drive
    asks 0.002 A per rpm/s and delivers at most ``clamp`` A; a clamped wheel's acceleration
    is what the clamp allows. A ``frozen`` reading (rpm) is reported whatever the speed."""
    for k in range(steps):
        t = t0 + k * dt
        cmd = 10.0 * math.cos(2 * math.pi * t / 4.0)
        phase = 0
        if probe is not None:
            phase = probe.probe_phase(t)
            cmd += phase * 280.0
        current = min(0.02 + 0.002 * abs(cmd), clamp)
        moved = follow * math.copysign(min(abs(cmd), (clamp - 0.02) / 0.002), cmd)
        speed += (moved - drag_rpm_s) * dt
        reading = round((speed + rng.normal(0, 0.5)) * 2) / 2 if frozen is None else frozen
        found = test.update(cmd, reading, current, phase)
        if found is not None:
            return k, found
        if probe is not None and test.wants_probe:
            probe.probe_soon(t + dt)
    return None


def _probed(seed):
    """A calibrating test, its noise and a probe schedule (two opposed wheels: a null space)."""
    probe = NullSpaceDither(np.array([[1.0, 1.0], [0, 0], [0, 0]]), 4.2e-4, probe_rpm_s=280.0)
    probe.torques(0.0, np.ones(2, bool))
    test = TrackingTest(
        0.1, RW90, calibration_s=300.0, false_alarms_per_hour=1e-3, probe_every_s=60.0
    )
    return np.random.default_rng(seed), test, probe


def test_a_probe_finds_a_clamp_the_dither_never_reaches_and_names_it():
    """A clamp at 0.4 A: the dither asks 0.04 A, so only the probe (0.58 A) reaches it. A
    healthy hour of probes raises nothing; the first probe after the clamp names it."""
    rng, test, probe = _probed(3)
    assert _wheel(test, rng, 3000 + 36_000, follow=1.0, probe=probe) is None
    assert len(test.healthy_probes) == PROBE_CALIBRATION
    k, alarm = _wheel(test, rng, 1200, follow=1.0, t0=3930.0, probe=probe, clamp=0.4)
    assert alarm.test == "capacity probe" and alarm.kind == "current_limit"
    assert alarm.statistic > alarm.threshold
    assert 3930.0 + k * 0.1 == pytest.approx(3962.0)  # the end of the next probe


def test_a_probe_names_a_weak_motor_by_the_current_it_still_draws():
    """k_t × 0.8 (the wheel follows 80 % of its command, its drive delivers the current it
    asks): the probe's shortfall with a full current is the motor, not a clamp."""
    rng, test, probe = _probed(4)
    assert _wheel(test, rng, 3000, follow=1.0, probe=probe) is None
    found = _wheel(test, rng, 1200, follow=0.8, t0=300.0, probe=probe)
    assert found is not None and found[1].test == "capacity probe"
    assert found[1].kind == "torque_constant"


def test_a_healthy_wheel_raises_no_alarm_and_a_dead_one_is_named_in_seconds():
    rng = np.random.default_rng(5)
    test = TrackingTest(0.1, RW90, calibration_s=300.0, false_alarms_per_hour=1e-3)
    assert _wheel(test, rng, 3000 + 36_000, follow=1.0) is None  # calibration + 1 h healthy
    assert test.healthy_spread_rpm_s() == pytest.approx(0.5 * math.sqrt(2), rel=0.2)
    # the motor dies: the wheel coasts against its friction and ignores its command
    k, alarm = _wheel(test, rng, 600, follow=0.0, drag_rpm_s=6.8, t0=3900.0)
    assert k * 0.1 <= 10.0 and alarm.statistic > alarm.threshold
    assert alarm.test == "tracking CUSUM" and alarm.kind == "torque_constant"


def test_extra_friction_is_told_from_a_dead_motor():
    rng = np.random.default_rng(8)
    test = TrackingTest(0.1, RW90, calibration_s=300.0, false_alarms_per_hour=1e-3)
    assert _wheel(test, rng, 3000, follow=1.0) is None
    found = _wheel(test, rng, 600, follow=1.0, drag_rpm_s=6.8, t0=300.0)
    assert found is not None and found[1].kind == "friction"


def test_name_fault_reads_a_clamped_current():
    a_c = 10 * np.cos(np.linspace(0, 6, 40))
    kind = name_fault(a_c, np.zeros(40), np.full(40, 0.001), np.full(40, 0.05), 1000.0)
    assert kind == "current_limit"


def _through_zero(test, rng, cmd_rpm_s=-3.0, dwell_s=10.0, speed=40.0, dt=0.1):
    """A healthy wheel with breakaway friction (``test.params``) driven through zero by a
    steady command: the Stribeck excess its drive does not compensate slows it near zero,
    it sticks at zero for ``dwell_s`` (reading 0), breaks away and goes on; the reading
    is 0 inside the Hall dead zone. Returns the first alarm or None."""
    p = test.params
    excess = rad_s_to_rpm((p.breakaway_friction - p.coulomb_friction) / p.inertia)  # rpm/s
    stuck = 0.0
    for _ in range(round(120 / dt)):
        if speed == 0.0 and stuck < dwell_s:
            stuck += dt
        else:
            direction = math.copysign(1.0, speed if speed else cmd_rpm_s)
            drag = excess * math.exp(-((speed / p.stribeck_speed_rpm) ** 2))
            new = speed + (cmd_rpm_s - direction * drag) * dt
            speed = 0.0 if new * speed < 0 and stuck == 0.0 else new
        if abs(speed) < p.min_measurable_rpm:
            reading = 0.0
        else:
            reading = round((speed + rng.normal(0, 0.5)) * 2) / 2
        found = test.update(cmd_rpm_s, reading, 0.02)
        if found is not None:
            return found
    assert speed < -50  # it did cross and leave the band
    return None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_healthy_wheel_dwelling_in_stiction_at_zero_raises_no_alarm(seed):
    """After a pyramid loses a wheel the others cross zero and stick there for seconds:
    breakaway, not a tracking fault. The same wheel with the stiction band switched off
    (the old test) raises a false alarm, so this can fail."""
    params = replace(RW90, stiction=True, breakaway_friction=3e-4, stribeck_speed_rpm=10.0)
    outcomes = []
    for band in (True, False):
        rng = np.random.default_rng(seed)
        test = TrackingTest(0.1, params, calibration_s=300.0, false_alarms_per_hour=1e-3)
        if not band:
            test.band_rpm = 0.0
        assert _wheel(test, rng, 3000, follow=1.0) is None  # calibrated at 1000 rpm
        outcomes.append(_through_zero(test, rng))
    assert outcomes[0] is None
    assert test.band_rpm == 0.0 and outcomes[1] is not None  # the old test's false alarm


@pytest.mark.parametrize(
    ("follow", "clamp", "kind"), [(1.0, 0.4, "current_limit"), (0.8, 1.0, "torque_constant")]
)
def test_a_wheel_faulty_from_power_up_is_named_by_its_first_probe(follow, clamp, kind):
    """Its first probes cannot be its healthy ones: a push it misses by more than a healthy
    drive's lag ever does is an alarm at once, named against the current its drive's
    feed-forward asks for (the synthetic drive asks what the RW90's does, within 10 %)."""
    rng, test, probe = _probed(6)
    k, alarm = _wheel(test, rng, 3000, follow=follow, probe=probe, clamp=clamp)
    assert alarm.test.startswith("capacity probe") and alarm.kind == kind
    assert k * 0.1 == pytest.approx(62.0) and not test.healthy_probes  # the first probe


@pytest.mark.parametrize(("follow", "drag_rpm_s"), [(0.8, 1.5), (1.0, 6.0), (1.0, 1.5)])
def test_a_drag_on_the_held_speed_raises_its_alarm_at_once(follow, drag_rpm_s):
    """A weak motor drags on the held speed (its drive's friction feed-forward falls short)
    as extra friction does: the tracking test raises its alarm at once, names the drag,
    and asks for no probe (one pushing with a wheel that cannot follow costs pointing);
    which of the two it is, ``rwlab hil`` names by the idled wheel's coast-down
    (tests/test_hil.py)."""
    rng, test, probe = _probed(9)
    assert _wheel(test, rng, 3000, follow=1.0, probe=probe) is None
    k, alarm = _wheel(test, rng, 600, follow=follow, drag_rpm_s=drag_rpm_s, t0=310.0, probe=probe)
    assert (alarm.test, alarm.kind) == ("tracking CUSUM", "friction")
    assert not test.wants_probe and 310.0 + k * 0.1 < 340.0  # within half a minute


def test_a_reading_that_does_not_move_under_a_probe_is_a_frozen_sensor():
    """A frozen reading follows neither the dither (whose swings cancel in the tracking
    test) nor the probe: the probe finds it, and a reading that did not change by one
    quantum while the wheel was pushed at 90 % of its torque is the sensor, not the motor
    (a dead motor's wheel still coasts)."""
    rng, test, probe = _probed(11)
    assert _wheel(test, rng, 3000, follow=1.0, probe=probe) is None
    k, alarm = _wheel(test, rng, 1200, follow=1.0, t0=330.0, probe=probe, frozen=1000.5)
    assert alarm.test == "capacity probe" and alarm.kind == "speed_sensor_stuck"
    assert 330.0 + k * 0.1 == pytest.approx(362.0)
