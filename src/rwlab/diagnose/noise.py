"""Residual evaluation's noise model: each channel's σ as the motion makes it.

A healthy residual is not white: the identified model misses the wheel most
where the commanded acceleration changes fast (a chirp's fast end, a PRBS
step). The model measured here says, per residual channel, the σ of the
healthy residual in bins of the demand's jerk |Δα_demand|/Ts (rpm/s²), a factor on
it in bins of the model's speed (a Hall-timed speed reading is coarse where a
revolution no longer fits in the firmware's window: measured on all three twins,
the speed residual's σ 1–2.6 rpm under 600 rpm against 0.1–0.3 rpm above, where the
jerk bins alone called a slow stretch a sensor bias), and an
inflation κ: the variance of means of ``BLOCK_S`` of consecutive standardised
residuals over 1/(their number), so a log-likelihood over correlated samples counts
them as N/κ independent ones. Both are measured on healthy records
(:meth:`NoiseModel.measure`): the twin's for the shipped calibration, the lab's
own for ``rwlab diagnose calibrate``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rwlab.diagnose.features import Features, channel_mask, own_limit_residual
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
# |model speed| bin edges, rpm: ×2 apart from the slowest reading a Hall wheel gives to
# its top speeds; where a wheel's reading turns coarse is measured, not assumed
SPEED_READ = ("speed", "accel")  # the channels read off the speed sensor
SPEED_EDGES = (5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0, 640.0, 1280.0, 2560.0, 5120.0)
# the entry of the reach at the acceleration limit against the unit's own
# (features.own_limit_residual): one σ, its own scatter, not the acceleration channel's
LIMIT = "limit_own"


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


def _concat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


def speed_bins(features: Features) -> np.ndarray:
    """Each sample's speed bin: where its model speed's magnitude falls in
    :data:`SPEED_EDGES`, shape (N,)."""
    model = features.speed_rpm - features.speed_residual_rpm
    return np.searchsorted(SPEED_EDGES, np.abs(model))


def _binned_scale(
    z: np.ndarray, where: np.ndarray, n_bins: int, exact_is_unknown: bool = False
) -> np.ndarray:
    """The MAD σ (×1.4826: σ for Gaussian samples, unmoved by a few outliers) of ``z`` in
    each of ``n_bins`` bins; a bin of fewer than ``MIN_SAMPLES`` (or, with
    ``exact_is_unknown``, of a MAD of 0) takes its nearest measured neighbour's."""
    s = np.array(
        [
            1.4826 * float(np.median(np.abs(z[where == i])))
            if np.count_nonzero(where == i) >= MIN_SAMPLES
            else np.nan
            for i in range(n_bins)
        ]
    )
    if exact_is_unknown:
        s[s == 0] = np.nan
    if not np.isfinite(s).any():
        return np.ones(n_bins)
    near = np.flatnonzero(np.isfinite(s))
    for i in np.flatnonzero(~np.isfinite(s)):
        s[i] = s[near[np.argmin(np.abs(near - i))]]
    return s


def _inflation(z: np.ndarray, Ts: float) -> float:
    """κ of standardised residuals z: the variance of their ``BLOCK_S`` means over white
    noise's (≥ 1)."""
    block = max(2, round(BLOCK_S / Ts))
    n = z.size // block
    if n == 0:
        return 1.0
    means = z[: n * block].reshape(n, block).mean(axis=1)
    return max(1.0, float(means.var() * block / max(z.var(), 1e-300)))


@dataclass(frozen=True)
class NoiseModel:
    """σ per channel per jerk bin and speed bin, and each channel's inflation.

    Attributes
    ----------
    sigma : dict of str to tuple of float
        Per channel (:data:`CHANNELS`), σ in each of ``len(JERK_EDGES) + 2`` bins
        (:func:`bins`), in the channel's unit (A, rpm/s, rpm); :data:`LIMIT`: one σ of
        the reach at the acceleration limit against the unit's own, rpm/s.
    inflation : dict of str to float
        κ per channel (≥ 1).
    speed_factor : dict of str to tuple of float
        Per channel, the factor on σ in each of ``len(SPEED_EDGES) + 1`` speed bins
        (:func:`speed_bins`); a channel without one: 1 (files made before it).
    """

    sigma: dict[str, tuple[float, ...]]
    inflation: dict[str, float]
    speed_factor: dict[str, tuple[float, ...]] = field(default_factory=dict)

    def weights(self, features: Features) -> dict[str, np.ndarray]:
        """1/(σ²κ) per sample and channel (0 where a sample is unusable), shape (N,) each;
        ``speed_held`` and ``accel_held``: the same with the speed sensor's factor at held
        speeds (:attr:`speed_factor`); ``current_level``: the current's 1/σ² alone, for a
        level the reading must hold."""
        where = bins(features)  # the same bins the σ were measured in
        speed = speed_bins(features)
        out = {}
        for name in CHANNELS:
            key = self.key(name, features.against_own)
            if key not in self.sigma:  # a channel no calibration record reads
                out[name] = np.zeros(features.N)
                continue
            sigma = np.asarray(self.sigma[key])[where]
            mask, kappa = channel_mask(features, name), self.inflation[key]
            out[name] = np.where(mask, 1.0 / (sigma**2 * kappa), 0.0)
            if key in self.speed_factor:
                g = np.asarray(self.speed_factor[key])[speed]
                # at a held speed, the speed sensor's own scale (the bias test's weights)
                out[f"{name}_held"] = out[name] / np.where(where == 0, g, 1.0) ** 2
                # the motion's tests: the reading's scatter at the sample's speed is a floor
                # in every bin (a slew through a speed the Hall sensor reads coarsely, its
                # zero crossing, is no finer than a hold there)
                read = self.sigma[key][0] * g
                out[name] = np.where(mask, 1.0 / (np.maximum(sigma, read) ** 2 * kappa), 0.0)
        if LIMIT in self.sigma:  # the reach at the limit against the unit's own
            read = features.usable & ~features.repeated
            out["limit"] = np.where(
                read, 1.0 / (self.sigma[LIMIT][0] ** 2 * self.inflation[LIMIT]), 0.0
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
        factor: dict[str, tuple[float, ...]] = {}
        # against the own past: the current on every turning sample, and at constant
        # speed against the unit's friction law (what each own detector reads)
        own = {"current": [f.own() for f in records]}
        own["current_steady"] = [f.own(law=True) for f in records]
        for key, attr, name, group in (
            *((n, a, n, records) for n, a in CHANNELS.items()),
            *((f"{n}_own", CHANNELS[n], n, own[n]) for n in own),
        ):
            group = [f for f in group if channel_mask(f, name).any()]
            if not group:  # no record reads it (the speed of acceleration-mode records)
                continue
            pairs = [(f, channel_mask(f, name)) for f in group]
            v = _concat([getattr(f, attr)[ok] - np.median(getattr(f, attr)[ok]) for f, ok in pairs])
            if v.size < MIN_SAMPLES and key.endswith("_own"):
                continue  # records too short for their own reference: the population's only
            if v.size < MIN_SAMPLES:
                raise DataError(f"the noise model needs ≥ {MIN_SAMPLES} usable healthy samples")
            jerk_bin = _concat([bins(f)[ok] for f, ok in pairs])
            s = _binned_scale(v, jerk_bin, len(JERK_EDGES) + 2)
            s[:-1] = np.maximum.accumulate(np.maximum(s[:-1], 1e-12))  # never less at more jerk
            sigma[key] = tuple(float(x) for x in s)
            scale = s[jerk_bin]
            # a reading of exactly 0 is the sensor's floor (below the speed it measures), no
            # measurement of the speed: the held readings' scatter is measured without them
            held = (jerk_bin == 0) & (_concat([f.speed_rpm[ok] for f, ok in pairs]) != 0)
            if name in SPEED_READ and np.count_nonzero(held) >= MIN_SAMPLES:
                speed_bin = _concat([speed_bins(f)[ok] for f, ok in pairs])
                # a bin without enough readings (or with a MAD of 0) takes its nearest
                # measured one's; never finer than the held samples' σ
                g = _binned_scale(
                    v[held] / s[0], speed_bin[held], len(SPEED_EDGES) + 1, exact_is_unknown=True
                )
                factor[key] = tuple(float(x) for x in np.maximum(g, 1.0))
            inflation[key] = _inflation(v / scale, group[0].scales.Ts)
        v = _concat(
            [
                r[read] - np.median(r[read])
                for r, read in map(own_limit_residual, own["current_steady"])
                if read.any()
            ]
        )
        if v.size >= MIN_SAMPLES:  # else the reach is weighed as the acceleration channel
            sigma[LIMIT] = (1.4826 * float(np.median(np.abs(v))),)
            inflation[LIMIT] = _inflation(v / sigma[LIMIT][0], own["current_steady"][0].scales.Ts)
        return cls(sigma, inflation, factor)

    def to_dict(self) -> dict:
        return {
            "jerk_edges_rpm_s2": list(JERK_EDGES),
            "sigma": {k: list(v) for k, v in self.sigma.items()},
            "inflation": dict(self.inflation),
            "speed_edges_rpm": list(SPEED_EDGES),
            "speed_factor": {k: list(v) for k, v in self.speed_factor.items()},
        }

    @classmethod
    def from_dict(cls, d: dict) -> NoiseModel:
        return cls(
            {k: tuple(float(x) for x in v) for k, v in d["sigma"].items()},
            {k: float(v) for k, v in d["inflation"].items()},
            {k: tuple(float(x) for x in v) for k, v in d.get("speed_factor", {}).items()},
        )
