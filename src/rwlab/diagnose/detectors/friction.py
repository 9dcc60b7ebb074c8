"""Worn bearings: friction × F raises the friction current at every speed."""

from __future__ import annotations

import numpy as np

from rwlab.diagnose.detectors.base import Detector
from rwlab.diagnose.detectors.sensor_bias import QUIET_SHARE
from rwlab.diagnose.features import Features


class Friction(Detector):
    """Friction × F: the current residual (F − 1)·(c₁ω + c₂ sign ω), read where
    the model is quiet (|α_model| under ``QUIET_SHARE`` of the acceleration
    limit: there the current is friction's alone, and the spread of inertia and
    k_t between units cannot pose as friction); at the acceleration limit the
    loop cannot add that current, so the acceleration falls short by
    (F − 1)·friction current / c₀."""

    fault = "friction"
    unit = "factor"
    healthy_size = 1.0

    def grid(self, features: Features) -> np.ndarray:
        return np.geomspace(0.25, 8.0, 801)

    def gains(self, features, weights, grid):
        g = features.friction_current_a
        p = (grid[None, :] - 1.0) * g[:, None]
        c0 = features.scales.current_model[0]
        at_limit = features.saturated
        limit = features.scales.accel_limit_rpm_s
        quiet = np.abs(features.model_accel_rpm_s) <= QUIET_SHARE * limit
        gain = self.channel_gain(features.current_residual_a, weights["current"] * quiet, p)
        return gain + self.channel_gain(
            features.accel_residual_rpm_s, weights["accel"] * at_limit, -p / c0
        )
