"""Clocks: the wall clock for hardware, and a simulated clock for fast, exact experiments.

Both offer ``now()`` and ``sleep_until(t)`` in seconds. The simulated clock
jumps instead of sleeping and, before each jump completes, lets every attached
node run up to the new time (``node.poll(t)``), so a 20-minute experiment runs
in seconds while every command and telemetry message still travels as a real
frame on the bus.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["SimClock", "WallClock"]


class WallClock:
    """Monotonic wall time."""

    simulated = False

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        """Sleep until ``t``; the last 2 ms are spun for sub-millisecond precision.

        The spin yields the GIL on every turn so that other threads (a node, a
        recorder) keep running.
        """
        while True:
            left = t - time.monotonic()
            if left <= 0:
                return
            time.sleep(left - 0.0015 if left > 0.002 else 0)

    def sleep(self, dt: float) -> None:
        self.sleep_until(self.now() + dt)


class SimClock:
    """Simulated time that advances only when someone sleeps.

    Attached tickers (a node's ``poll``, a polling driver's link) are called as
    time advances; a ticker may return the next time it wants to be called
    (a float), and the clock then stops there on its way, so a driver that polls
    its wheel at 10 Hz is called at 10 Hz however long the sleep.

    Parameters
    ----------
    start : float
        Initial time, s.
    """

    simulated = True

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._tickers: list[Callable[[float], object]] = []
        self._wakeups: dict[Callable[[float], object], float] = {}
        self._running: list[Callable[[float], object]] = []

    def attach(self, ticker: Callable[[float], object]) -> None:
        """Call ``ticker(t)`` whenever time advances to ``t`` (a node's ``poll``)."""
        self._tickers.append(ticker)

    def detach(self, ticker: Callable[[float], object]) -> None:
        if ticker in self._tickers:
            self._tickers.remove(ticker)
        self._wakeups.pop(ticker, None)

    def now(self) -> float:
        return self._t

    def sleep_until(self, t: float) -> None:
        if t <= self._t:
            return
        while True:
            due = [w for w in self._wakeups.values() if self._t < w < t]
            step = min(due, default=t)
            self._t = float(step)
            self._tick()
            if step >= t:
                return

    def kick(self) -> None:
        """Let every other attached ticker run now, without advancing time.

        A request/response driver calls this after writing a request so the
        simulated wheel answers at the same simulated instant.
        """
        self._tick()

    def _tick(self) -> None:
        for tick in list(self._tickers):
            if tick in self._running:
                continue  # a ticker that kicks is not re-entered
            self._running.append(tick)
            try:
                wake = tick(self._t)
            finally:
                self._running.remove(tick)
            if isinstance(wake, (int, float)) and not isinstance(wake, bool):
                self._wakeups[tick] = float(wake)
            else:
                self._wakeups.pop(tick, None)

    def sleep(self, dt: float) -> None:
        self.sleep_until(self._t + dt)
