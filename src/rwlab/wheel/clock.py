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

    Parameters
    ----------
    start : float
        Initial time, s.
    """

    simulated = True

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._tickers: list[Callable[[float], None]] = []

    def attach(self, ticker: Callable[[float], None]) -> None:
        """Call ``ticker(t)`` whenever time advances to ``t`` (a node's ``poll``)."""
        self._tickers.append(ticker)

    def detach(self, ticker: Callable[[float], None]) -> None:
        if ticker in self._tickers:
            self._tickers.remove(ticker)

    def now(self) -> float:
        return self._t

    def sleep_until(self, t: float) -> None:
        if t <= self._t:
            return
        self._t = float(t)
        for tick in list(self._tickers):
            tick(self._t)

    def sleep(self, dt: float) -> None:
        self.sleep_until(self._t + dt)
