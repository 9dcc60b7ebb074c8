"""The balance test (friction in the current balance of every steady sample, issue 23).

Truth is built here from the current balance i = (I·α + b·ω + τ_c sign ω)/k_t + offset of a
unit other than the reference's, never from the detector."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rwlab.diagnose.blocktests import BALANCE_BLOCK, FrictionBalance
from rwlab.diagnose.detect import arl_to_samples, cusum_threshold

C = np.array([1.7e-3, 3.4e-6, 8.3e-3, 0.0])  # the reference's current model (A per unit)
TS = 0.5


def _run(
    friction: float = 1.0,
    kt: float = 1.0,
    onset: float = 1200.0,
    hours: float = 0.5,
    seed: int = 0,
    h: float | None = None,
) -> tuple[list, list]:
    """A unit (friction 1.3 ×, inertia/k_t 1.05 × the reference's, 3 mA offset) on a PRBS-like
    signal: holds of 20–60 s at ±500–5000 rpm joined by slews at 300 rpm/s; friction ×
    ``friction`` and k_t × ``kt`` from ``onset``. The alarms' times and findings."""
    rng = np.random.default_rng(seed)
    det = FrictionBalance(h or cusum_threshold(arl_to_samples(1e-3, TS) / BALANCE_BLOCK))
    alarms, findings, t, speed = [], [], 0.0, 1000.0
    while t < hours * 3600:
        target = rng.choice([-1, 1]) * rng.uniform(500, 5000)
        path = list(np.arange(speed, target, math.copysign(150.0, target - speed))[1:])
        path += [target] * int(rng.integers(40, 120))
        for w in path:
            accel, speed, t = (w - speed) / TS, w, t + TS
            sign = math.copysign(1.0, w)
            f_ref = C[1] * w + C[2] * sign
            fault = t >= onset
            unit = (1.05 * C[0] * accel + 1.3 * f_ref * (friction if fault else 1.0)) / (
                kt if fault else 1.0
            )
            current = unit + 3e-3 + rng.normal(0, 3e-3)
            if abs(w) < 300 or (len(path) > 1 and w != target and w == path[0]):
                continue  # below the stiction band; the slew's first sample is no steady one
            residual = current - (C[0] * accel + f_ref)
            if det.add_sample(t, residual, C[1] * w, C[2] * sign, C[0] * accel):
                alarms.append(t)
                findings.append(det.finding())
                det.restart()
    return alarms, findings


def test_friction_x1_5_is_found_and_sized_within_300_s():
    alarms, findings = _run(friction=1.5)
    assert alarms and 1200 < alarms[0] <= 1500, alarms
    found = next(f for f in findings if f is not None)
    assert found.kind == "friction"
    assert found.ci[0] <= 1.5 <= found.ci[1], found


def test_a_healthy_unit_other_than_the_reference_raises_no_alarm():
    for seed in range(3):
        alarms, _ = _run(hours=1.0, seed=seed)
        assert alarms == [], (seed, alarms)


def test_a_weak_motor_is_not_named_friction_by_it():
    """k_t × 0.8 raises the friction and the inertial current alike: the test may see a
    change but names no friction."""
    alarms, findings = _run(kt=0.8)
    assert alarms, "a 25 % current rise is a change"
    assert all(f is None or f.kind != "friction" for f in findings), findings


@pytest.mark.parametrize("factor", [1.3, 2.0])
def test_the_size_holds_the_true_factor(factor):
    _, findings = _run(friction=factor, seed=4)
    found = next(f for f in findings if f is not None)
    assert found.ci[0] <= factor <= found.ci[1], found
