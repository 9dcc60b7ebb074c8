"""Telemetry dropouts: more frames lost in a block than the bus loses when healthy."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import poisson

from rwlab.diagnose.detectors.base import Detector, Fit
from rwlab.diagnose.features import Features

BLOCK_S = 10.0  # lost frames are counted per block this long: a dropout lasts well under it


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
        p_block = per_hour * BLOCK_S / 3600
        limit = int(poisson.isf(p_block, mean)) + 1  # P(count ≥ limit) ≤ p_block
        counts = np.add.reduceat(features.lost_frames, np.arange(0, features.N, block))
        hits = np.flatnonzero(counts >= limit)
        if not hits.size:
            return None
        c = float(counts[hits[0]])
        llr = c * math.log(max(c, 1e-9) / mean) - (c - mean)
        k = min(features.N - 1, (int(hits[0]) + 1) * block - 1)
        return k, Fit(self.fault, c, (c, c), llr, self.unit)
