"""A lowered current clamp: the driver stops at L A below the specified limit."""

from __future__ import annotations

import numpy as np

from rwlab.diagnose.detectors.base import Detector
from rwlab.diagnose.features import Features


class CurrentLimit(Detector):
    """Clamp at L: the current balance still holds (no current residual), but
    where the loop demands more acceleration than L drives,
    α_L = (±L − c₃ − friction current)/c₀, the wheel reaches only α_L: the
    acceleration residual α_L − α_demand; and the measured current (less the
    sense offset c₃) exceeds L by its noise alone, so every ampere over L costs
    the current channel's Gaussian log-likelihood (a weak motor at the
    acceleration limit draws the full current: no clamp can explain it). Sizes
    up to the specified clamp (``model.json``), which is the healthy one."""

    fault = "current_limit"
    unit = "A"
    healthy_size = np.inf  # the specified clamp: grid's last point

    def grid(self, features: Features) -> np.ndarray:
        spec = features.scales.current_limit_a
        return spec * np.linspace(0.1, 1.0, 361)

    def gains(self, features, weights, grid):
        c0, _, _, c3 = features.scales.current_model
        demand = features.demand_accel_rpm_s
        d = np.sign(demand)[:, None]
        reach = (d * grid[None, :] - c3 - features.friction_current_a[:, None]) / c0
        p = np.where(d * demand[:, None] > d * reach, reach - demand[:, None], 0.0)
        over = np.maximum(np.abs(features.current_a - c3)[:, None] - grid[None, :], 0.0)
        beyond = -0.5 * weights["current"][:, None] * over * over
        return self.channel_gain(features.accel_residual_rpm_s, weights["accel"], p) + beyond
