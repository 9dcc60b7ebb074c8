"""A frozen speed reading: the same non-zero value sample after sample."""

from __future__ import annotations

import math

import numpy as np

from rwlab.diagnose.detectors.base import Detector, Fit
from rwlab.diagnose.features import STEADY_SHARE, Features


class FrozenReading(Detector):
    """Stuck sensor: a frozen reading repeats every sample, a healthy one seldom
    and in short runs (Hall quantisation at a held speed). The statistic is the
    length of the current run of repeated non-zero readings while the wheel is meant to
    move: a repeat at constant speed (the model's and the reading's, ``STEADY_SHARE``)
    pauses the run, for a healthy reading repeats there as long as the speed is held.
    Its threshold comes from the runs of healthy records (the calibration's peaks, as for
    every detector). No model-based channel reads it, so ``gains`` is zero."""

    fault = "speed_sensor_stuck"
    unit = ""
    healthy_size = 0.0

    def grid(self, features: Features) -> np.ndarray:
        return np.zeros(1)

    def gains(self, features, weights, grid):
        return np.zeros((features.N, grid.size))

    @staticmethod
    def runs(features: Features) -> np.ndarray:
        """Length of the current run of repeated readings while moving at each sample,
        shape (N,)."""
        moving = ~features.steady(STEADY_SHARE)
        out = np.zeros(features.N, dtype=int)
        for k in range(1, features.N):  # a run counts readings, lost frames pause it
            out[k] = out[k - 1] + int(moving[k]) if features.repeated[k] else 0
        return out

    def first_alarm(self, features: Features, threshold: float) -> tuple[int, Fit] | None:
        """Index and fit of the first run longer than ``threshold`` samples, or None."""
        runs = self.runs(features)
        hits = np.flatnonzero(runs > threshold)
        if not hits.size:
            return None
        k = int(hits[0])
        return k, Fit(self.fault, math.nan, (math.nan, math.nan), float(runs[k]), "")
