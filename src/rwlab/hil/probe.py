"""A capacity probe as one wheel saw it: the push, the way back, and the fault they name.

:class:`rwlab.hil.health.NullSpaceDither` flies the probe and
:class:`rwlab.hil.health.TrackingTest` judges it; this module holds what a probe
measured (:class:`Half`, :class:`Probe`) and its signature (:meth:`Probe.named`).

Hand-written: no library models a reaction wheel drive's response to a torque probe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Half", "Probe"]


@dataclass
class Half:
    """One half of a probe (the push, or the way back) as the wheel saw it.

    Parameters
    ----------
    start_rpm : float
        The speed reported before the half, rpm.
    commanded_rpm : float
        The speed change commanded over it so far, rpm.
    end_rpm : float
        The speed reported at its latest period's end, rpm.
    current_sum_a, requested_sum_a : float
        Sums of the |current| reported and of the |current| the drive's feed-forward
        asked for, one term per period, A.
    periods : int
        Control periods so far.
    readings : set of float
        The distinct speeds reported over it, rpm.
    """

    start_rpm: float
    commanded_rpm: float = 0.0
    end_rpm: float = math.nan
    current_sum_a: float = 0.0
    requested_sum_a: float = 0.0
    periods: int = 0
    readings: set[float] = field(default_factory=set)

    def add(
        self, commanded_rpm: float, speed_rpm: float, current_a: float, requested_a: float
    ) -> None:
        """Add one control period.

        Parameters
        ----------
        commanded_rpm : float
            The speed change commanded over the period, rpm.
        speed_rpm : float
            The speed reported at its end, rpm.
        current_a, requested_a : float
            The current reported, and the one the drive's feed-forward asked for, A.
        """
        self.commanded_rpm += commanded_rpm
        self.end_rpm = speed_rpm
        self.readings.add(speed_rpm)
        self.current_sum_a += abs(current_a)
        self.requested_sum_a += abs(requested_a)
        self.periods += 1

    @property
    def shortfall_rpm(self) -> float:
        """The speed change the wheel missed, rpm (positive: it fell short)."""
        moved = self.end_rpm - self.start_rpm
        return math.copysign(1.0, self.commanded_rpm) * (self.commanded_rpm - moved)

    @property
    def current_a(self) -> float:
        """The mean |current| over the half, A."""
        return self.current_sum_a / self.periods

    @property
    def requested_a(self) -> float:
        """The mean |current| the drive's feed-forward asked for over the half, A."""
        return self.requested_sum_a / self.periods


@dataclass
class Probe:
    """A probe's push and way back. Its signature splits the two shortfalls: a motor that
    lost torque misses both alike (``symmetric_rpm``); a drag against the rotation costs
    the half that moves away from zero and helps the other (``drag_rpm``).

    Parameters
    ----------
    out : Half
        The push.
    back : Half, optional
        The way back (None until it starts).
    """

    out: Half
    back: Half | None = None

    @property
    def complete(self) -> bool:
        return self.back is not None and self.back.periods == self.out.periods

    @property
    def symmetric_rpm(self) -> float:
        assert self.back is not None
        return (self.out.shortfall_rpm + self.back.shortfall_rpm) / 2

    @property
    def drag_rpm(self) -> float:
        assert self.back is not None
        away = math.copysign(1.0, self.out.commanded_rpm) == math.copysign(1.0, self.out.end_rpm)
        return (1 if away else -1) * (self.out.shortfall_rpm - self.back.shortfall_rpm) / 2

    def named(self, healthy: list[Probe]) -> str:
        """The fault that explains this probe.

        Parameters
        ----------
        healthy : list of Probe
            The wheel's healthy probes; none: a drive without lag that draws what its
            feed-forward asks for stands for them.

        Returns
        -------
        str
            ``speed_sensor_stuck`` when the reading did not change at all, else
            ``current_limit`` when the missing current (drawn per current asked)
            explains at least half of the push's missed speed change, else ``friction``
            or ``torque_constant``, whichever excess is larger: the drag's or the
            symmetric shortfall's.
        """
        # the current drawn per current asked: a probe off the schedule meets the dither
        # in another phase, so it asks for a few percent more or less
        drawn = float(np.mean([p.out.current_a / p.out.requested_a for p in healthy] or [1.0]))
        excess = self.out.shortfall_rpm - np.mean([p.out.shortfall_rpm for p in healthy] or [0])
        share = self.out.current_a / self.out.requested_a / drawn
        missing_rpm = max(0.0, 1.0 - share) * abs(self.out.commanded_rpm)
        if self.back is not None and self.out.readings | self.back.readings == {self.out.start_rpm}:
            return "speed_sensor_stuck"  # pushed at 90 % of its torque, not one quantum
        if missing_rpm > excess / 2:
            return "current_limit"
        drag = self.drag_rpm - np.mean([p.drag_rpm for p in healthy] or [0])
        symmetric = self.symmetric_rpm - np.mean([p.symmetric_rpm for p in healthy] or [0])
        return "friction" if drag > symmetric else "torque_constant"
