"""A weak motor: k_t × F needs 1/F the current for the same torque."""

from __future__ import annotations

import numpy as np

from rwlab.diagnose.detectors.base import Detector
from rwlab.diagnose.features import Features


class TorqueConstant(Detector):
    """k_t × F: the current residual (1/F − 1)·(c₀α + c₁ω + c₂ sign ω) at the
    measured motion; at the acceleration limit the loop's current is the nominal
    one, so the acceleration falls short by (F − 1)·(α_demand + friction current / c₀)."""

    fault = "torque_constant"
    unit = "factor"
    healthy_size = 1.0

    def grid(self, features: Features) -> np.ndarray:
        return np.geomspace(0.1, 2.0, 801)

    def gains(self, features, weights, grid):
        c0 = features.scales.current_model[0]
        p_current = (1.0 / grid[None, :] - 1.0) * features.drive_current_a[:, None]
        reach = features.demand_accel_rpm_s + features.friction_current_a / c0
        p_accel = (grid[None, :] - 1.0) * reach[:, None]
        gain = self.channel_gain(features.current_residual_a, weights["current"], p_current)
        return gain + self.channel_gain(
            features.accel_residual_rpm_s, weights["accel"] * features.saturated, p_accel
        )
