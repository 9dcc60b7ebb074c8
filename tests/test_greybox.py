"""The physical grey-box wheel and the nonlinear ARX, judged on twin wheels they were not fit on."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rwlab.data import IOData
from rwlab.errors import DataError, ModelError
from rwlab.ident import arx, fit_percent
from rwlab.ident.greybox import RPM, WheelGreyBox, greybox_fit
from rwlab.ident.nlarx import NLARXModel, nlarx
from rwlab.ident.study import DATASHEET
from rwlab.signals import prbs, rate_limit
from rwlab.wheel import RW90, IdentifiedWheel
from rwlab.wheel.physics import IDEAL, Mode, WheelPhysics

TS = 0.5


def _record(params, seed: int, minutes: float = 8.0) -> tuple[IOData, np.ndarray]:
    """A rate-limited PRBS into the twin (no bus): speed (rpm) and current (A) measured
    before each command, as a testbed record has them."""
    u = prbs(minutes * 60, TS, 6000.0, 5.0, seed=seed)
    u = rate_limit(u, 314.0, TS, initial=0.0)
    wheel = WheelPhysics(params, seed)
    y, current = np.empty(u.size), np.empty(u.size)
    for k, c in enumerate(u):
        y[k], current[k] = wheel.measured_speed_rpm(), wheel.measured_current()
        wheel.command(Mode.SPEED, c)
        for _ in range(100):
            wheel.step(TS / 100)
    return IOData(u, y, TS, input_names="command", output_names="speed_rpm"), current


@pytest.fixture(scope="module")
def unit_a():
    """A drawn unit of the ideal twin (exact dynamics, no stiction): kt ±5 %, friction ±30 %."""
    return IDEAL.for_unit(4)


@pytest.fixture(scope="module")
def grey(unit_a):
    data, current = _record(unit_a, 1)
    est = data.split(0.7)[0]
    return greybox_fit(est, kp=0.4, ki=0.08, current=current[: est.N], **DATASHEET), data


def test_greybox_recovers_the_units_physics_and_its_loop(grey, unit_a):
    model, _ = grey
    # speed and current make kt/J, τc/kt and b/kt observable: J stays at the datasheet value
    assert model.inertia == DATASHEET["inertia"]
    ratio = model.torque_constant / model.inertia
    true_ratio = unit_a.torque_constant / unit_a.inertia
    assert ratio == pytest.approx(true_ratio, rel=0.01)
    # friction where the wheel runs (3000 rpm): Coulomb and viscous apart trade off
    # (sign ω and ω are nearly collinear over a PRBS that seldom crosses zero)
    j = unit_a.inertia / model.inertia  # the model's torques are in units of its J
    w = 3000 * RPM
    friction = (model.coulomb + model.viscous * w) * j
    truth = unit_a.coulomb_friction + unit_a.viscous_friction * w
    assert friction == pytest.approx(truth, rel=0.15)
    assert model.kp == pytest.approx(unit_a.speed_kp, rel=0.05)
    assert model.ki == pytest.approx(unit_a.speed_ki, rel=0.05)
    assert model.accel_limit / RPM == pytest.approx(unit_a.max_accel_rpm_s, rel=0.01)
    estimated = {"torque_constant", "coulomb", "breakaway", "viscous", "accel_limit", "kp", "ki"}
    assert set(model.std) | set(model.unidentified) == estimated
    assert not set(model.std) & set(model.unidentified)
    # the ideal twin has no stiction (breakaway = Coulomb): nothing in the record shows it
    assert model.unidentified == ("breakaway",) and model.breakaway == model.coulomb
    assert all(v > 0 and math.isfinite(v) for v in model.std.values())


def test_greybox_takes_another_wheels_current_limit_where_a_linear_model_cannot(grey):
    model, data = grey
    est = data.split(0.7)[0]
    # another unit whose driver limits the current to 0.35 A: it cannot reach 314 rpm/s
    derated = replace(RW90, current_limit=0.35).for_unit(9)
    other, _ = _record(derated, 2)
    y = other.y[:, 0]
    grey_fit = fit_percent(y, model.with_limits(current_limit=0.35).simulate(other.u[:, 0], 0.0))
    linear = arx(est.detrend(reference=est), 2, 2, 1)
    wheel = IdentifiedWheel(
        linear, input_offset=float(est.u.mean()), output_offset=float(est.y.mean())
    )
    lin = np.concatenate([[0.0], wheel.simulate(other.u[:, 0])[:-1]])
    linear_fit = fit_percent(y, lin)
    assert grey_fit > 95
    assert grey_fit > linear_fit + 10


def test_greybox_round_trips_and_refuses_bad_parameters(grey):
    model, _ = grey
    back = WheelGreyBox.from_dict(model.to_dict())
    np.testing.assert_array_equal(back.vector, model.vector)
    with pytest.raises(ModelError):
        replace(model, torque_constant=-1.0)
    with pytest.raises(DataError):
        model.simulate([np.nan, 1.0])


def test_nlarx_fits_a_static_nonlinearity_a_linear_arx_cannot():
    # y(t) = 0.5 y(t−1) + sat(u(t−1) − y(t−1), ±1): a rate limit on a first-order servo
    r = np.random.default_rng(0)
    u = np.repeat(r.uniform(-5, 5, 200), 10)
    y = np.zeros(u.size)
    for t in range(1, u.size):
        y[t] = y[t - 1] + np.clip(u[t - 1] - y[t - 1], -1.0, 1.0)
    data = IOData(u, y + 0.01 * r.standard_normal(u.size), 1.0)
    est, val = data.split(0.7)
    model = nlarx(est)
    assert model.report["knot_count"] > 0
    sim = model.predict(val, np.inf)
    lin = arx(est, 2, 2, 1)
    assert fit_percent(val.y[:, 0], sim) > 95
    assert fit_percent(val.y[:, 0], sim) > fit_percent(val.y[:, 0], lin.simulate(val.u)) + 5
    assert NLARXModel.from_dict(model.to_dict()) == model
