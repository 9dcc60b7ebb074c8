"""Telemetry dropouts: more frames lost in a block than the bus loses when healthy."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import poisson

from rwlab.diagnose.detectors.base import Detector, Fit
from rwlab.diagnose.features import Features

BLOCK_S = 10.0  # lost frames are counted per block this long: a dropout lasts well under it


def alarm_count(mean: float, per_hour: float, block_s: float = BLOCK_S) -> int:
    """The fewest frames lost in one block that raise a dropout alarm.

    Parameters
    ----------
    mean : float
        Frames a healthy link loses per block on average (Poisson), ≥ 0.
    per_hour : float
        False alarms per hour asked (> 0).
    block_s : float
        The block's length, s.

    Returns
    -------
    int
        The smallest count c with P(count ≥ c) ≤ the rate asked per block.
    """
    return int(poisson.isf(per_hour * block_s / 3600, mean)) + 1


class LostFrames(Detector):
    """Dropouts: healthy losses are Poisson at the measured rate λ per sample; the
    alarm count per block is the smallest whose tail probability, per block, is
    the rate asked. The size is the frames lost in the alarm's block."""

    fault = "telemetry_dropout"
    unit = "frames"
    healthy_size = 0.0

    def grid(self, features: Features) -> np.ndarray:
        return np.zeros(1)

    def gains(self, features, weights, grid):
        return np.zeros((features.N, grid.size))

    def first_alarm(
        self, features: Features, lam: float, per_hour: float
    ) -> tuple[int, Fit] | None:
        """Index and fit of the first block whose losses reach the alarm count, or None."""
        block = max(1, round(BLOCK_S / features.scales.Ts))
        mean = lam * block
        limit = alarm_count(mean, per_hour)
        counts = np.add.reduceat(features.lost_frames, np.arange(0, features.N, block))
        hits = np.flatnonzero(counts >= limit)
        if not hits.size:
            return None
        c = float(counts[hits[0]])
        llr = c * math.log(max(c, 1e-9) / mean) - (c - mean)
        k = min(features.N - 1, (int(hits[0]) + 1) * block - 1)
        return k, Fit(self.fault, c, (c, c), llr, self.unit)
