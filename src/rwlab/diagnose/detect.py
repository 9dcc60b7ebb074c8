"""Sequential change detectors and their thresholds from a stated false-alarm rate.

Two tests, both on samples that are independent when the wheel is healthy:

- :class:`Cusum` — Page's two-sided CUSUM for a shift of the mean of unit-variance
  innovations. Its threshold ``h`` comes from Siegmund's approximation of the
  one-sided average run length to a false alarm for N(0, 1) samples
  (Basseville & Nikiforov, *Detection of Abrupt Changes*, 1993, §5.2.2):

      ARL₀(h, k) ≈ (exp(2k·b) − 2k·b − 1) / (2k²),   b = h + 1.166,

  and the two sides alarm independently, 1/ARL₀ = 1/ARL₀⁺ + 1/ARL₀⁻, so each
  side is set to twice the wanted ARL₀. Innovations are clipped at ±``clip``
  before they enter the sums: for Gaussian samples that can only lengthen the
  run to a false alarm (the threshold stays on the safe side), and it bounds
  how far one transient misfit of the model can push the statistic.
- :class:`RunTest` — an alarm after ``n`` events in a row (a frozen reading),
  where one event has probability ``p`` when healthy. The exact ARL₀ of the
  first run of ``n`` in Bernoulli(p) trials is (1 − pⁿ) / ((1 − p)·pⁿ), and ``n``
  is the smallest that reaches the wanted ARL₀.

SciPy's ``brentq`` solves Siegmund's formula for ``h``; the CUSUM recursions are
written out because they run one sample at a time (live) and no maintained
library offers a streaming CUSUM with this threshold rule.
"""

from __future__ import annotations

import math

from scipy.optimize import brentq

from rwlab.errors import ConfigError

__all__ = ["Cusum", "RunTest", "arl_to_samples", "cusum_threshold", "run_length"]


def arl_to_samples(false_alarms_per_hour: float, Ts: float) -> float:
    """The wanted ARL₀ in samples for a false-alarm rate (per hour) at sample time Ts (s).

    Parameters
    ----------
    false_alarms_per_hour : float
        Accepted false-alarm rate, per hour (> 0).
    Ts : float
        Sample time, s.

    Returns
    -------
    float
        The in-control average run length, samples.
    """
    if not (math.isfinite(false_alarms_per_hour) and false_alarms_per_hour > 0):
        raise ConfigError(f"the false-alarm rate must be > 0 per hour, got {false_alarms_per_hour}")
    return 3600.0 / (Ts * false_alarms_per_hour)


def _siegmund_arl(h: float, k: float) -> float:
    x = 2 * k * (h + 1.166)
    return (math.expm1(x) - x) / (2 * k * k)


def cusum_threshold(arl0: float, k: float = 0.5) -> float:
    """Threshold h of a two-sided CUSUM with reference ``k`` (σ units) for ARL₀ ``arl0`` samples.

    Parameters
    ----------
    arl0 : float
        Wanted in-control average run length, samples.
    k : float
        Reference value, in σ of the whitened residual.

    Returns
    -------
    float
        The threshold h, σ units.
    """
    if not (k > 0 and arl0 > 1):
        raise ConfigError(f"need k > 0 and ARL₀ > 1 sample, got k={k}, ARL₀={arl0}")
    h_max = 700 / (2 * k) - 1.166  # exp(700) is near the largest double
    return brentq(lambda h: math.log(_siegmund_arl(h, k) / (2 * arl0)), 1e-9, h_max)


def run_length(arl0: float, p: float) -> int:
    """Smallest n whose first run of n events (probability ``p`` each) has ARL₀ ≥ ``arl0``.

    Parameters
    ----------
    arl0 : float
        Wanted in-control average run length, samples.
    p : float
        Probability of one event, in (0, 1).

    Returns
    -------
    int
        The run length n.
    """
    if not 0 <= p < 1:
        raise ConfigError(f"the event probability must be in [0, 1), got {p}")
    n = 1
    while p > 0 and (1 - p**n) / ((1 - p) * p**n) < arl0:
        n += 1
    return n


class Cusum:
    """Two-sided CUSUM on unit-variance innovations.

    Parameters
    ----------
    h : float
        Threshold, σ units.
    k : float
        Reference value (half the mean shift to detect), σ units.
    clip : float
        Innovations are clipped to ±clip before entering the sums.
    """

    def __init__(self, h: float, k: float = 0.5, clip: float = 3.0) -> None:
        self.h, self.k, self.clip = h, k, clip
        self.up = self.down = 0.0

    @property
    def statistic(self) -> float:
        """The larger of the two sums, σ units."""
        return max(self.up, self.down)

    def update(self, z: float) -> bool:
        """Add one innovation (σ units); True when the statistic exceeds ``h``."""
        z = min(max(z, -self.clip), self.clip)
        self.up = max(0.0, self.up + z - self.k)
        self.down = max(0.0, self.down - z - self.k)
        return self.statistic > self.h


class RunTest:
    """Alarm after ``n`` events in a row.

    Parameters
    ----------
    n : int
        Events in a row that raise the alarm.
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self.run = 0

    @property
    def statistic(self) -> float:
        return float(self.run)

    def update(self, event: bool) -> bool:
        self.run = self.run + 1 if event else 0
        return self.run >= self.n

    def restart(self) -> None:
        """Forget the current run (after an alarm, when counting false alarms)."""
        self.run = 0
