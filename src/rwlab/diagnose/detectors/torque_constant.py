"""A weak motor: k_t × F needs 1/F the current for the same torque."""

from __future__ import annotations

import numpy as np

from rwlab.diagnose.detectors.base import Detector
from rwlab.diagnose.features import Features


class TorqueConstant(Detector):
    """k_t × F: the current residual (1/F − 1)·(c₀α + c₁ω + c₂ sign ω) at the
    measured motion; below the acceleration limit the loop's integrator makes up the
    lost torque until the driver's clamp L binds, and at the limit the capped request
    drives F of it (:meth:`Detector.shortfall`): the acceleration falls short where
    the demand needs more than F·L, and at the limit."""

    fault = "torque_constant"
    unit = "factor"
    healthy_size = 1.0
    worse = -1  # a weaker motor

    def grid(self, features: Features) -> np.ndarray:
        return np.geomspace(0.1, 2.0, 801)

    def gains(self, features, weights, grid):
        p_current = (1.0 / grid[None, :] - 1.0) * features.drive_current_a[:, None]
        clamp = features.scales.current_limit_a
        p_accel = self.shortfall(features, clamp, torque_factor=grid[None, :])
        gain = self.channel_gain(features.current_residual_a, weights["current"], p_current)
        return gain + self.channel_gain(features.accel_residual_rpm_s, weights["accel"], p_accel)
