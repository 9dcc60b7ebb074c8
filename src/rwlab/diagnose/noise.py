"""Residual evaluation's noise model: each channel's σ as the motion makes it.

A healthy residual is not white: the identified model misses the wheel most
where the commanded acceleration changes fast (a chirp's fast end, a PRBS
step). The model measured here says, per residual channel, the σ of the
healthy residual in bins of the demand's jerk |Δα_demand|/Ts (rpm/s²), and an
inflation κ: the variance of means of ``BLOCK_S`` of consecutive standardised
residuals over 1/(their number), so a log-likelihood over correlated samples counts
them as N/κ independent ones. Both are measured on healthy records
(:meth:`NoiseModel.measure`): the twin's for the shipped calibration, the lab's
own for ``rwlab diagnose calibrate``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rwlab.diagnose.features import Features, channel_mask
from rwlab.errors import DataError

__all__ = ["CHANNELS", "NoiseModel"]

# channel name → the Features attribute it reads
CHANNELS = {
    "current": "current_residual_a",
    "accel": "accel_residual_rpm_s",
    "speed": "speed_residual_rpm",
    # the current at constant speed (friction's alone): its own σ, free of the inertia's
    # misfit between units that the moving samples carry
    "current_steady": "current_residual_a",
}
# the block for κ, s: the decisions' shortest window (bank.WINDOWS_S[0]). κ is the
# variance of a window's mean over what white noise gives it, so a log-LR over a window
# counts its samples as N/κ independent ones at the length decisions are taken on: with
# 20-sample blocks (10 s) κ missed the model's slow misfit (a speed residual's minutes-long
# wander after a slew) and 60-s windows reached log-LRs of 320 on healthy records
BLOCK_S = 60.0
# jerk bin edges, rpm/s²: spaced by ×5 between a held speed and a chirp's fast end
JERK_EDGES = (1.0, 5.0, 25.0, 125.0, 625.0)
MIN_SAMPLES = 30  # a bin with fewer healthy samples takes its neighbour's σ


def jerk(features: Features) -> np.ndarray:
    """|Δ demand acceleration| / Ts per sample, rpm/s², shape (N,)."""
    d = np.abs(np.diff(features.demand_accel_rpm_s, prepend=features.demand_accel_rpm_s[0]))
    return d / features.scales.Ts


def bins(features: Features) -> np.ndarray:
    """Each sample's noise bin: its jerk's; or the last one (``len(JERK_EDGES) + 1``) where
    the loop holds its acceleration limit (a slew: the model's slope misses the wheel's by
    the spread of inertia between units, not by the jerk's timing error)."""
    j = jerk(features)
    held = features.saturated & (j < JERK_EDGES[0])
    return np.where(held, len(JERK_EDGES) + 1, np.searchsorted(JERK_EDGES, j))


@dataclass(frozen=True)
class NoiseModel:
    """σ per channel per jerk bin, and each channel's inflation.

    Attributes
    ----------
    sigma : dict of str to tuple of float
        Per channel (:data:`CHANNELS`), σ in each of ``len(JERK_EDGES) + 2`` bins
        (:func:`bins`), in the channel's unit (A, rpm/s, rpm).
    inflation : dict of str to float
        κ per channel (≥ 1).
    """

    sigma: dict[str, tuple[float, ...]]
    inflation: dict[str, float]

    def weights(self, features: Features) -> dict[str, np.ndarray]:
        """1/(σ²κ) per sample and channel (0 where a sample is unusable), shape (N,) each;
        and ``current_level``: the current's 1/σ² alone, for a level the reading must hold."""
        where = bins(features)  # the same bins the σ were measured in
        out = {}
        for name in CHANNELS:
            key = self.key(name, features.against_own)
            sigma = np.asarray(self.sigma[key])[where]
            out[name] = np.where(
                channel_mask(features, name), 1.0 / (sigma**2 * self.inflation[key]), 0.0
            )
        # the current's level against a clamp: 1/σ² without κ, each sample its own evidence
        # (a reading over the clamp is the reading, not the model's slow misfit)
        key = self.key("current", features.against_own)
        out["current_level"] = out["current"] * self.inflation[key]
        return out

    def key(self, name: str, against_own: bool) -> str:
        """The noise model's entry for channel ``name``: ``current_own`` for the current
        against the record's own past where measured (:meth:`Features.own`)."""
        own = f"{name}_own"
        return own if against_own and own in self.sigma else name

    @classmethod
    def measure(cls, records: list[Features]) -> NoiseModel:
        """Measure the model on healthy records' features.

        Each record's residuals are taken about their own median, so a unit's
        offset from the reference (its friction, its k_t) is no noise.

        Parameters
        ----------
        records : list of Features

        Returns
        -------
        NoiseModel

        Raises
        ------
        DataError
            Fewer than ``MIN_SAMPLES`` usable samples in all.
        """
        sigma: dict[str, tuple[float, ...]] = {}
        inflation: dict[str, float] = {}
        own = [f.own() for f in records]
        for key, attr, name, group in (
            *((n, a, n, records) for n, a in CHANNELS.items()),
            *((f"{n}_own", CHANNELS[n], n, own) for n in ("current", "current_steady")),
        ):
            values, where = [], []
            group = [f for f in group if channel_mask(f, name).any()]
            for f in group:
                ok = channel_mask(f, name)
                r = getattr(f, attr)[ok]
                values.append(r - np.median(r))
                where.append(bins(f)[ok])
            v = np.concatenate(values) if values else np.zeros(0)
            b = np.concatenate(where) if where else np.zeros(0, dtype=int)
            if v.size < MIN_SAMPLES and key.endswith("_own"):
                continue  # records too short for their own reference: the population's only
            if v.size < MIN_SAMPLES:
                raise DataError(f"the noise model needs ≥ {MIN_SAMPLES} usable healthy samples")
            per_bin = []
            for i in range(len(JERK_EDGES) + 2):
                x = v[b == i]
                # MAD·1.4826: σ for Gaussian samples, unmoved by a few outliers
                per_bin.append(
                    1.4826 * float(np.median(np.abs(x))) if x.size >= MIN_SAMPLES else np.nan
                )
            s = np.array(per_bin)
            for i in range(len(s)):  # a thin bin takes the nearest measured one's σ
                if not np.isfinite(s[i]):
                    near = np.flatnonzero(np.isfinite(s))
                    s[i] = s[near[np.argmin(np.abs(near - i))]]
            s[:-1] = np.maximum.accumulate(np.maximum(s[:-1], 1e-12))  # never less at more jerk
            sigma[key] = tuple(float(x) for x in s)
            z = np.concatenate(
                [
                    (
                        (getattr(f, attr) - np.median(getattr(f, attr)[channel_mask(f, name)]))
                        / s[bins(f)]
                    )[channel_mask(f, name)]
                    for f in group
                ]
            )
            block = max(2, round(BLOCK_S / group[0].scales.Ts))
            n = z.size // block
            means = z[: n * block].reshape(n, block).mean(axis=1)
            inflation[key] = max(1.0, float(means.var() * block / max(z.var(), 1e-300)))
        return cls(sigma, inflation)

    def to_dict(self) -> dict:
        return {
            "jerk_edges_rpm_s2": list(JERK_EDGES),
            "sigma": {k: list(v) for k, v in self.sigma.items()},
            "inflation": dict(self.inflation),
        }

    @classmethod
    def from_dict(cls, d: dict) -> NoiseModel:
        return cls(
            {k: tuple(float(x) for x in v) for k, v in d["sigma"].items()},
            {k: float(v) for k, v in d["inflation"].items()},
        )
