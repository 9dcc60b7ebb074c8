"""A frozen speed reading: the same non-zero value sample after sample."""

from __future__ import annotations

import math

import numpy as np

from rwlab.diagnose.detectors.base import Detector, Fit
from rwlab.diagnose.features import Features


class FrozenReading(Detector):
    """Stuck sensor: a frozen reading repeats every sample, a healthy one seldom
    and in short runs (Hall quantisation at a held speed). The statistic is the
    length of the current run of repeated non-zero readings; its threshold comes
    from the runs of healthy records (the calibration's peaks, as for every
    detector). No model-based channel reads it, so ``gains`` is zero."""

    fault = "speed_sensor_stuck"
    unit = ""
    healthy_size = 0.0

    def grid(self, features: Features) -> np.ndarray:
        return np.zeros(1)

    def gains(self, features, weights, grid):
        return np.zeros((features.N, grid.size))

    @staticmethod
    def runs(features: Features) -> np.ndarray:
        """Length of the current run of repeated readings at each sample, shape (N,)."""
        out = np.zeros(features.N, dtype=int)
        for k in range(1, features.N):  # a run counts readings, lost frames pause it
            out[k] = out[k - 1] + 1 if features.repeated[k] else 0
        return out

    def first_alarm(self, features: Features, threshold: float) -> tuple[int, Fit] | None:
        """Index and fit of the first run longer than ``threshold`` samples, or None."""
        runs = self.runs(features)
        hits = np.flatnonzero(runs > threshold)
        if not hits.size:
            return None
        k = int(hits[0])
        return k, Fit(self.fault, math.nan, (math.nan, math.nan), float(runs[k]), "")
