"""A lowered current clamp: the driver stops at L A below the specified limit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rwlab.diagnose.detectors.base import Detector, profile_fit
from rwlab.diagnose.features import Features


class CurrentLimit(Detector):
    """Clamp at L: the current balance still holds (no current residual), but
    where the loop demands more acceleration than L drives,
    α_L = (±L − c₃ − friction current)/c₀, the wheel reaches only α_L: the
    acceleration residual α_L − α_demand; and the measured current (less the
    sense offset c₃) exceeds L by its noise alone, so every ampere over L costs
    the current channel's Gaussian log-likelihood (a weak motor at the
    acceleration limit draws the full current: no clamp can explain it); where it
    binds, the current sits at L (a flat top), so a current below L there costs as
    much (a healthy wheel whose loop demand the model overstates, on a chirp's fast
    end, draws less than L: the clamp must not explain its shortfall). The level is
    the reading's, judged sample by sample at the reading's own scatter
    (``current_level``, :meth:`Detector.level_cost`): a weak motor at the acceleration
    limit falls as short as a clamp would, and only its current, over the clamp on
    every such sample, tells them apart. Sizes up to the specified clamp
    (``model.json``), which is the healthy one; the size and its interval are read off
    the flat top (:meth:`refine`)."""

    fault = "current_limit"
    unit = "A"
    healthy_size = np.inf  # the specified clamp: grid's last point
    worse = -1  # a lower clamp

    def grid(self, features: Features) -> np.ndarray:
        spec = features.scales.current_limit_a
        return spec * np.linspace(0.1, 1.0, 361)

    def refine(self, features, weights, fit, a, k):
        # the clamp read off the flat top: where the fitted clamp binds in the window, the
        # level the current sits at (Huber's location, its profile interval). The reach a
        # clamp allows scales with the unit's own inertia/k_t, a few % off the reference's
        # c₀, and would pull the size by as much; the reading at the flat top does not
        binding = _held(self.shortfall(features, fit.size) != 0.0)[a:k, 0]
        w = weights["current_level"][a:k][binding]
        if np.count_nonzero(w) < 3:
            return fit
        c3 = features.scales.current_model[3]
        level = np.abs(features.current_a[a:k][binding] - c3)
        # on a grid of its own over the readings (the location lies among them): the
        # detector's grid is coarser than this interval
        sizes = np.linspace(level.min(), level.max(), 201)
        ll = self.level_cost(level[:, None] - sizes[None, :], w).sum(axis=0)
        top = profile_fit(self.fault, self.unit, sizes, ll, np.ones(sizes.size, bool))
        # a quantised reading places the level only within half its step either side
        steps = np.diff(np.unique(np.abs(features.current_a[a:k])))
        half = float(steps.min()) / 2 if steps.size else 0.0
        ci95 = (min(top.ci95[0], top.size - half), max(top.ci95[1], top.size + half))
        return replace(fit, size=top.size, ci95=ci95)

    def gains(self, features, weights, grid):
        c3 = features.scales.current_model[3]
        p = self.shortfall(features, grid[None, :])
        level = np.abs(features.current_a - c3)[:, None] - grid[None, :]
        # where it binds the clamp holds the current at L (a flat top); elsewhere it allows
        # any current up to L: a shortfall of acceleration with the current below L is not
        # the clamp's, and a current over L never is
        miss = np.where(_held(p != 0.0), level, np.maximum(level, 0.0))
        beyond = self.level_cost(miss, weights["current_level"])
        return self.channel_gain(features.accel_residual_rpm_s, weights["accel"], p) + beyond


def _held(binding: np.ndarray) -> np.ndarray:
    """The samples (N, G) a clamp holds the current at its level for the whole interval:
    binding, and binding at the next sample too. At a binding run's last sample the slew
    ends within the interval and the reading has already left the flat top (on clamped
    twins: 0.10 A read against a 0.175 A clamp, ~7 of log-likelihood per slew)."""
    held = binding.copy()
    held[:-1] &= binding[1:]
    return held
