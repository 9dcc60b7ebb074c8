"""The host driver: ``WheelClient`` commands one wheel over any python-can bus.

Like python-can itself, one client works with every transport: a virtual bus
in tests, SocketCAN on a bench, the SLIP serial bus over RS-232; and with every
wheel protocol of :mod:`rwlab.wheel.link` (``rwlab``, ``canopen``, ``nsp``, or
a registered one). The client refuses commands outside the wheel's limits
before sending, raises ``WheelTimeout`` when the wheel is silent, ``WheelFault``
when it reports a fault and ``WheelConflict`` when two sources answer under its
node id, and — used as a context manager — always leaves the wheel idle.

Whatever else arrives is never fatal: damaged frames are dropped and counted
(:attr:`WheelClient.bad_frames`), frames of other protocols too
(:attr:`WheelClient.foreign_frames`), and telemetry beyond what the wheel can
physically do (speed past its overspeed trip, current past twice its
overcurrent trip, non-finite values) is not taken as the wheel's state: it is
counted (:attr:`WheelClient.implausible_frames`) and handed to :meth:`drain`
as an :class:`Implausible` event.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from rwlab.errors import WheelCommandError, WheelConflict, WheelFault, WheelTimeout
from rwlab.wheel import protocol as proto
from rwlab.wheel.clock import SimClock, WallClock
from rwlab.wheel.link import RawListener, get_protocol
from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams

__all__ = ["Implausible", "WheelClient"]

IMPLAUSIBLE_SPEED_MARGIN = 1.1  # × the overspeed trip: beyond it no real wheel is spinning
IMPLAUSIBLE_CURRENT_MARGIN = 2.0  # × the overcurrent trip


@dataclass(frozen=True)
class Implausible:
    """Telemetry the wheel cannot have sent truthfully, kept as an event, not as its state.

    Attributes
    ----------
    node_id : int
    reason : str
        What is beyond the physical limit, with the numbers.
    telemetry : Telemetry
        The frame as received.
    """

    node_id: int
    reason: str
    telemetry: proto.Telemetry


class WheelClient:
    """Driver for one wheel.

    Parameters
    ----------
    bus : can.BusABC
        The bus the wheel is on.
    node_id : int
        The wheel's node id, 0..15.
    params : WheelParams
        Limits to enforce before sending (default RW90).
    clock : WallClock or SimClock
        Must be the node's clock when the wheel is simulated.
    timeout : float
        Seconds to wait for an answer before ``WheelTimeout``.
    history : int
        How many received telemetry frames to keep in :attr:`received`.
    protocol : str
        The wheel protocol by name: ``rwlab`` (default), ``canopen``, ``nsp`` or a
        registered one (:func:`rwlab.wheel.link.get_protocol`).
    """

    def __init__(
        self,
        bus: Any,
        node_id: int = 0,
        params: WheelParams = RW90,
        *,
        clock: WallClock | SimClock | None = None,
        timeout: float = 0.5,
        history: int = 100_000,
        protocol: str = "rwlab",
    ) -> None:
        self.bus = bus
        self.node_id = proto.check_node(node_id)
        self.params = params
        self.clock = clock or WallClock()
        self.timeout = timeout
        self.latest: proto.Telemetry | None = None
        self.latest_time: float | None = None
        self.heartbeat: proto.Heartbeat | None = None
        self.received: deque[tuple[float, proto.Telemetry]] = deque(maxlen=history)
        self.lost_frames = 0
        self.implausible_frames = 0
        self.sources: set[str] = set()
        self._sequence = 0
        self._sent_at: dict[int, float] = {}
        self._inbox: list[tuple[float, proto.Telemetry | proto.Heartbeat | Implausible]] = []
        self.protocol = get_protocol(protocol)
        self.link = self.protocol.host_link(bus, self.node_id, clock=self.clock)
        self.link.configure(params)

    @property
    def frame_listener(self) -> RawListener | None:
        """Called with (t, id, bytes, 'rx' or 'tx') for every raw frame (to record the bus)."""
        return self.link.raw_listener

    @frame_listener.setter
    def frame_listener(self, listener: RawListener | None) -> None:
        self.link.raw_listener = listener

    @property
    def bad_frames(self) -> int:
        """Damaged frames and datagrams received (dropped)."""
        bus = self.bus
        extra = int(getattr(bus, "bad_datagrams", 0)) + int(getattr(bus, "bad_frames", 0))
        return self.link.bad_frames + extra

    @property
    def lost_commands(self) -> int:
        """Commands the protocol knows the wheel did not receive (no ACK, for nsp)."""
        return self.link.lost_commands

    @property
    def foreign_frames(self) -> int:
        """Valid frames of other protocols received (ignored)."""
        return self.link.foreign_frames

    # -- commands --------------------------------------------------------------------
    def set_speed(self, rpm: float) -> int:
        """Speed mode: track ``rpm``. Returns the command's sequence number."""
        self._check_limit("speed", rpm, self.params.max_speed_rpm, "rpm")
        return self._send(Mode.SPEED, rpm)

    def set_acceleration(self, rpm_per_s: float) -> int:
        """Acceleration (torque) mode: change speed at ``rpm_per_s``."""
        self._check_limit("acceleration", rpm_per_s, self.params.max_accel_rpm_s, "rpm/s")
        return self._send(Mode.ACCELERATION, rpm_per_s)

    def idle(self) -> int:
        """Motor off; the wheel coasts down."""
        return self._send(Mode.IDLE, 0.0, allow_faulted=True)

    def clear_fault(self) -> int:
        """Clear latched faults (the wheel stays idle)."""
        seq = self._send(Mode.CLEAR_FAULT, 0.0, allow_faulted=True)
        self.heartbeat = None
        return seq

    def _check_limit(self, what: str, value: float, limit: float, unit: str) -> None:
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise WheelCommandError(f"{what} command must be a finite number, got {value!r}")
        if abs(value) > limit:
            raise WheelCommandError(
                f"{what} command {value:g} {unit} is beyond the wheel's limit of ±{limit:g} {unit}"
            )

    def _send(self, mode: Mode, setpoint: float, allow_faulted: bool = False) -> int:
        if allow_faulted:  # idle and clear go out whatever the bus says meanwhile
            try:
                self.poll()
            except WheelConflict:
                pass
        else:
            self.poll()
            self.raise_if_faulted()
        self._sequence = self._sequence % 255 + 1
        now = self.clock.now()
        self.link.send(proto.Command(self.node_id, mode, float(setpoint), self._sequence), now)
        self._sent_at[self._sequence] = now
        return self._sequence

    # -- receiving --------------------------------------------------------------------
    def poll(self) -> list[tuple[float, proto.Telemetry]]:
        """Read every frame waiting on the bus; returns the new telemetry with times (s)."""
        new = []
        for incoming in self.link.receive(self.clock.now()):
            t, frame = incoming.t, incoming.frame
            self._check_source(incoming.source)
            if isinstance(frame, proto.Telemetry) and (why := self._implausible(frame)):
                self.implausible_frames += 1
                self._inbox.append((t, Implausible(self.node_id, why, frame)))
                continue
            if isinstance(frame, proto.Telemetry):
                if self.latest is not None:
                    self.lost_frames += (frame.counter - self.latest.counter - 1) % 256
                self.latest, self.latest_time = frame, t
                self.received.append((t, frame))
                new.append((t, frame))
            elif isinstance(frame, proto.Heartbeat):
                self.heartbeat = frame
            self._inbox.append((t, frame))
        return new

    def _check_source(self, source: str | None) -> None:
        if source is None or source in self.sources:
            return
        self.sources.add(source)
        if len(self.sources) > 1:
            raise WheelConflict(
                f"wheel {self.node_id} answers from {len(self.sources)} sources "
                f"({', '.join(sorted(self.sources))}): two wheels share node id {self.node_id} "
                "on this channel; give each its own node id or channel"
            )

    def _implausible(self, t: proto.Telemetry) -> str | None:
        p = self.params
        speed_max = IMPLAUSIBLE_SPEED_MARGIN * p.overspeed_fault_rpm
        current_max = IMPLAUSIBLE_CURRENT_MARGIN * p.overcurrent_fault
        if not (math.isfinite(t.speed_rpm) and abs(t.speed_rpm) <= speed_max):
            return f"speed {t.speed_rpm:g} rpm beyond the wheel's physical ±{speed_max:g} rpm"
        if not (math.isfinite(t.current) and abs(t.current) <= current_max):
            return f"current {t.current:g} A beyond the wheel's physical ±{current_max:g} A"
        return None

    def drain(self) -> list[tuple[float, proto.Telemetry | proto.Heartbeat | Implausible]]:
        """Every telemetry, heartbeat and implausible frame received since the last drain.

        Unlike :meth:`poll`, this includes frames read inside commands and waits,
        so a recorder that drains loses nothing.
        """
        self.poll()
        out, self._inbox = self._inbox, []
        return out

    @property
    def faults(self) -> Fault:
        """Latched faults the wheel last reported."""
        hb = Fault.NONE if self.heartbeat is None else self.heartbeat.faults
        if hb == Fault.NONE and self.latest is not None and self.latest.fault_active:
            return Fault(0xF)  # the telemetry bit says "some fault"; the heartbeat says which
        return hb

    def raise_if_faulted(self) -> None:
        """Raise ``WheelFault`` if the wheel reports a latched fault."""
        faults = self.faults
        if faults:
            names = "|".join(f.name for f in Fault if f and f in faults and f.name)
            raise WheelFault(
                f"wheel {self.node_id} reports fault {names}; call clear_fault() once the cause "
                "is understood",
                int(faults),
            )

    def wait_ack(self, sequence: int, timeout: float | None = None) -> proto.Telemetry:
        """Wait until telemetry echoes ``sequence``; returns that frame.

        Raises ``WheelTimeout`` if it does not come in ``timeout`` s, ``WheelFault``
        if the wheel reports a fault meanwhile (unless the command was IDLE or CLEAR).
        """
        deadline = self.clock.now() + (self.timeout if timeout is None else timeout)
        self.link.poll_now(self.clock.now())  # a polled wheel: ask now, not at the next poll
        while True:
            for _, frame in self.poll():
                if frame.sequence_echo == sequence:
                    return frame
            if self.clock.now() >= deadline:
                raise WheelTimeout(
                    f"wheel {self.node_id} did not acknowledge command {sequence} within "
                    f"{deadline - self._sent_at.get(sequence, deadline):.3g} s"
                )
            self.clock.sleep_until(min(deadline, self.clock.now() + 5e-4))

    def latency_of(self, sequence: int, telemetry_time: float) -> float:
        """Seconds from sending ``sequence`` to the telemetry that echoed it."""
        return telemetry_time - self._sent_at[sequence]

    def telemetry(self, max_age: float | None = None) -> proto.Telemetry:
        """The newest telemetry; ``WheelTimeout`` if none arrived within ``max_age`` s."""
        self.poll()
        age = self.timeout if max_age is None else max_age
        if (
            self.latest is None
            or self.latest_time is None
            or self.clock.now() - self.latest_time > age
        ):
            raise WheelTimeout(f"no telemetry from wheel {self.node_id} in the last {age:g} s")
        return self.latest

    def stream(self, duration: float) -> Iterator[tuple[float, proto.Telemetry]]:
        """Yield (time, telemetry) as frames arrive for ``duration`` s.

        Raises ``WheelTimeout`` when the wheel is silent for longer than ``timeout``,
        ``WheelFault`` when it reports a fault.
        """
        end = self.clock.now() + duration
        last = self.clock.now()
        while self.clock.now() < end:
            frames = self.poll()
            yield from frames
            self.raise_if_faulted()
            if frames:
                last = self.clock.now()
            elif self.clock.now() - last > self.timeout:
                raise WheelTimeout(f"wheel {self.node_id} went silent for {self.timeout:g} s")
            self.clock.sleep_until(min(end, self.clock.now() + 1e-3))

    # -- safety -------------------------------------------------------------------------
    def close(self) -> None:
        """Idle the wheel and wait (up to ``timeout``) for it to confirm.

        Best effort: a broken bus or a silent wheel must not hide the error that
        made the caller stop, so nothing is raised here.
        """
        try:
            self.wait_ack(self.idle())
        except Exception:
            pass
        finally:
            self.link.close()

    def __enter__(self) -> WheelClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
