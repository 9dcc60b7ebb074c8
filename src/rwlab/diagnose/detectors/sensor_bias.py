"""A biased speed reading: the telemetry reports ω + b."""

from __future__ import annotations

import numpy as np

from rwlab.diagnose.detectors.base import Detector
from rwlab.diagnose.features import STEADY_SHARE, Features


class SensorBias(Detector):
    """Bias b: the speed residual b (the loop closes on the true speed); the
    loop's catch-up read from the reported speed is off by kp·b, so the
    acceleration residual is +kp·b. Both are read only at constant speed
    (measured and model |α| under ``STEADY_SHARE`` of the acceleration limit): in a speed change
    a weak motor, worn bearings or a clamp make the wheel lag, which a constant
    offset would otherwise absorb. Each held sample weighs as the speed it was read at
    allows (:attr:`NoiseModel.speed_factor`): a Hall-timed reading is coarse at low
    speed, where a slow healthy stretch otherwise reads as a bias."""

    fault = "speed_sensor_bias"
    unit = "rpm"
    healthy_size = 0.0

    def grid(self, features: Features) -> np.ndarray:
        return np.linspace(-150.0, 150.0, 1201)

    def gains(self, features, weights, grid):
        n = features.N
        # a reading of exactly 0 is the sensor's floor at rest, not a reading of the speed
        quiet = features.steady(STEADY_SHARE) & (features.speed_rpm != 0)
        # the held samples' σ by the speed the reading was taken at, where measured
        weights = {k: weights.get(f"{k}_held", weights[k]) * quiet for k in ("speed", "accel")}
        p_speed = np.broadcast_to(grid[None, :], (n, grid.size))
        gain = self.channel_gain(features.speed_residual_rpm, weights["speed"], p_speed)
        kp = features.scales.loop_gain_per_s
        if kp > 0:
            gain = gain + self.channel_gain(
                features.accel_residual_rpm_s, weights["accel"], kp * p_speed
            )
        return gain
