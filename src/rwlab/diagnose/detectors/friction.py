"""Worn bearings: friction × F raises the friction current at every speed."""

from __future__ import annotations

import numpy as np

from rwlab.diagnose.detectors.base import Detector
from rwlab.diagnose.features import STEADY_SHARE, Features, limit_reach, own_limit_residual


class Friction(Detector):
    """Friction × F: the current residual (F − 1)·(c₁ω + c₂ sign ω), read at
    constant speed (measured and model |α| under ``STEADY_SHARE`` of the acceleration
    limit: there the current is friction's alone, and the spread of inertia and
    k_t between units cannot pose as friction); the loop's integrator adds the
    friction's current until the driver's clamp binds, and then, or at the acceleration
    limit (where the capped request holds), the acceleration falls short
    (:meth:`Detector.shortfall`). Against the record's own past it reads the current
    alone, against the unit's friction law (``Features.own(law=True)``): the own past
    is a reference for the current only, and read on the acceleration with a healthy
    zone of the own past's width, a clamp's shortfall passed for friction × 8. At the
    acceleration limit, where a chirp's fast part holds the wheel and never at constant
    speed, it reads the reach against the unit's own (:meth:`limit_gains`,
    ``Features.limit_reference``): friction × F falls short by (F − 1) × the unit's
    friction."""

    fault = "friction"
    unit = "factor"
    healthy_size = 1.0
    worse = 1  # worn bearings: more friction
    own_law = True  # at constant speed the own reference is the unit's friction law
    reads_limit = True

    def grid(self, features: Features) -> np.ndarray:
        return np.geomspace(0.25, 8.0, 801)

    def gains(self, features, weights, grid):
        g = features.friction_current_a
        p = (grid[None, :] - 1.0) * g[:, None]
        quiet = features.steady(STEADY_SHARE)
        gain = self.channel_gain(features.current_residual_a, weights["current_steady"] * quiet, p)
        if features.against_own:  # the own past changes the current's reference alone
            return gain
        clamp = features.scales.current_limit_a
        p_accel = self.shortfall(features, clamp, friction_factor=grid[None, :])
        return gain + self.channel_gain(features.accel_residual_rpm_s, weights["accel"], p_accel)

    def limit_gains(self, features, weights, grid):
        if features.limit_reference is None:
            return None
        r, read = own_limit_residual(features)
        delta = np.where(read, features.limit_reference[:, 0], 0.0)
        _, x, _ = limit_reach(features)
        p = (1.0 - grid[None, :]) * ((1.0 - delta) * x)[:, None]  # × the unit's friction
        return self.channel_gain(r, weights.get("limit", weights["accel"]) * read, p)
