"""A wheel's telemetry in flight: dropouts named, on every wheel set.

The tracking test and the capacity probe (:mod:`rwlab.hil.health`) watch a
wheel's torque; neither sees its telemetry stop for a moment (the loop holds
the last reading, and the wheel still follows). This test counts the frames
each wheel's link lost (its telemetry counter's gaps) in blocks of
``BLOCK_S``, as the bench diagnosis does on a record
(:class:`~rwlab.diagnose.detectors.LostFrames`): healthy losses are Poisson,
and a block that loses at least
:func:`~rwlab.diagnose.detectors.lost_frames.alarm_count` frames is a dropout
(said at once: a block's count only grows). The healthy rate is the wheel's
own, measured in flight — from its first ``calibration_s`` on, over all of
the flight before each block — and taken at the upper end of its 95 %
interval (Garwood): minutes of flight with no loss do not say the link never
loses one, and a point estimate from them let a healthy link's chance losses
raise alarms. The alarm count falls as the flight lengthens (a link that lost
nothing in 300 s: 5 frames in a block; after an hour: 3).

It needs no redundant wheel and no excitation, so it also watches a set the
health check cannot (three orthogonal wheels). A dropout while the rate is
being measured raises the healthy rate (the test is then blunter for that
wheel); a dropout that loses fewer frames than the alarm count is not told
from the link's own losses: at 10 Hz telemetry one of 0.3-0.4 s loses 3-4
frames (named only after ~10 min of flight for 4, ~1 h for 3), and one over
0.4 s leaves the wheel silent for the run's 0.5-s timeout, which stops the run.
"""

from __future__ import annotations

from rwlab.diagnose.detectors.lost_frames import BLOCK_S, alarm_count
from rwlab.diagnose.wheel_calibration import garwood
from rwlab.hil.health import TrackingAlarm

__all__ = ["BLOCK_S", "DropoutTest"]


class DropoutTest:
    """One wheel's telemetry-dropout test (module docstring).

    Parameters
    ----------
    calibration_s : float
        Seconds of flight before the first block is tested.
    per_hour : float
        False alarms per hour asked.
    """

    def __init__(self, calibration_s: float, per_hour: float) -> None:
        self.calibration_s, self.per_hour = float(calibration_s), float(per_hour)
        self._start: tuple[float, int] | None = None  # (t, lost) when the flight began
        self._block: tuple[float, int] | None = None  # (t, lost) at the open block's start
        self.lost_per_s: float | None = None  # the healthy rate's upper 95 % bound, 1/s
        self.limit: int | None = None  # the open block's alarm count
        self.blocks_tested = 0
        self.alarmed = False  # latched by the first alarm: one per wheel

    def update(self, t: float, lost_frames: int) -> TrackingAlarm | None:
        """Feed the link's lost-frame counter at flight time ``t`` (s); an alarm, or None.

        Parameters
        ----------
        t : float
            Flight time, s.
        lost_frames : int
            The link's telemetry frames lost since it opened (never decreasing).

        Returns
        -------
        TrackingAlarm or None
            ``telemetry_dropout`` once the open block has lost the alarm count
            (statistic: its frames lost; threshold: the count); after it, None.
        """
        if self.alarmed:
            return None
        if self._start is None:
            self._start = (t, lost_frames)
        if self._block is None:
            if t - self._start[0] < self.calibration_s:
                return None
            self._open(t, lost_frames)
        assert self._block is not None and self.limit is not None
        t_block, lost_block = self._block
        count = lost_frames - lost_block
        if count >= self.limit:
            self.blocks_tested += 1
            self.alarmed = True
            return TrackingAlarm("telemetry_dropout", "telemetry dropout test", count, self.limit)
        if t - t_block >= BLOCK_S - 1e-6:  # the control periods' sum carries round-off
            self.blocks_tested += 1
            self._open(t, lost_frames)
        return None

    def _open(self, t: float, lost_frames: int) -> None:
        """A new block at ``t``: its alarm count from the flight so far."""
        t0, lost0 = self._start  # type: ignore[misc]
        self.lost_per_s = garwood(lost_frames - lost0, t - t0)[1]
        self.limit = alarm_count(self.lost_per_s * BLOCK_S, self.per_hour)
        self._block = (t, lost_frames)
