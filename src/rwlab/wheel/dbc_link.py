"""The ``rwlab`` protocol: the RW90 twin's own DBC (``rw.dbc``) on any python-can bus."""

from __future__ import annotations

from typing import Any

import can

from rwlab.interrupts import uninterrupted
from rwlab.wheel import protocol as proto
from rwlab.wheel.link import Clock, HostLink, Incoming, NodeLink, WheelProtocol

__all__ = ["MAX_FRAMES_PER_READ", "RwlabHostLink", "RwlabNodeLink", "RwlabProtocol"]

MAX_FRAMES_PER_READ = 4096  # a flood cannot hold a reader: the rest waits for the next read


def _source(bus: can.BusABC, msg: can.Message) -> str | None:
    return str(msg.channel) if getattr(bus, "reports_sources", False) else None


def read_frames(bus: can.BusABC) -> list[can.Message]:
    """Up to :data:`MAX_FRAMES_PER_READ` frames waiting on ``bus``; transport errors end the read.

    Parameters
    ----------
    bus : can.BusABC

    Returns
    -------
    list of can.Message
    """
    frames = []
    with uninterrupted():  # a stop inside python-can's queue can leave its lock taken
        for _ in range(MAX_FRAMES_PER_READ):
            try:
                msg = bus.recv(timeout=0)
            except (can.CanError, ValueError):
                continue  # an undecodable datagram on python-can's own udp bus: dropped
            if msg is None:
                break
            frames.append(msg)
    return frames


class RwlabHostLink(HostLink):
    """The driver's end of ``rw.dbc`` on a python-can bus.

    Parameters
    ----------
    bus : can.BusABC
        The python-can bus.
    node_id : int
        The wheel's node id (:func:`rwlab.wheel.protocol.check_node`).
    simulated : bool
        Frames carry simulated time (the twin's clock), not the wall clock.
    """

    def __init__(self, bus: can.BusABC, node_id: int, simulated: bool) -> None:
        super().__init__()
        self.bus, self.node_id, self.simulated = bus, proto.check_node(node_id), simulated

    def send(self, cmd: proto.Command, now: float) -> None:
        msg = proto.encode(cmd)
        msg.timestamp = now
        with uninterrupted():
            self.bus.send(msg)
        if self.raw_listener:
            self.raw_listener(now, msg.arbitration_id, bytes(msg.data), "tx")

    def receive(self, now: float) -> list[Incoming]:
        out = []
        for msg in read_frames(self.bus):
            t = msg.timestamp if self.simulated else now
            if self.raw_listener:
                self.raw_listener(t, msg.arbitration_id, bytes(msg.data), "rx")
            try:
                frame = proto.decode(msg)
            except proto.ProtocolError:
                self.bad_frames += 1
                continue
            if frame is None:
                self.foreign_frames += 1  # another protocol's frame
                continue
            if frame.node_id != self.node_id or isinstance(frame, proto.Command):
                continue  # other wheels, and other hosts' commands
            out.append(Incoming(t, frame, _source(self.bus, msg)))
        return out


class RwlabNodeLink(NodeLink):
    """The twin's end of ``rw.dbc`` on a python-can bus.

    Parameters
    ----------
    bus, node_id, simulated
        As for :class:`RwlabHostLink`.
    """

    def __init__(self, bus: can.BusABC, node_id: int, simulated: bool) -> None:
        super().__init__()
        self.bus, self.node_id, self.simulated = bus, proto.check_node(node_id), simulated
        self._twin: str | None = None

    def receive(self, now: float) -> list[tuple[float, proto.Command]]:
        out = []
        for msg in read_frames(self.bus):
            try:
                frame = proto.decode(msg)
            except proto.ProtocolError:
                self.bad_frames += 1
                continue
            if frame is None:
                self.foreign_frames += 1
                continue
            if frame.node_id != self.node_id:
                continue
            if not isinstance(frame, proto.Command):
                # our own frames are not echoed on these buses: another wheel has our id
                self._twin = _source(self.bus, msg) or "another sender"
                continue
            out.append((msg.timestamp if self.simulated else now, frame))
        return out

    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        msg = proto.encode(frame)
        if corrupt is not None:
            data = bytearray(msg.data)
            data[corrupt % 7] ^= 0xA5
            msg = can.Message(arbitration_id=msg.arbitration_id, data=data, is_extended_id=False)
        msg.timestamp = t
        with uninterrupted():
            self.bus.send(msg)

    def heard_twin(self) -> str | None:
        return self._twin


class RwlabProtocol(WheelProtocol):
    """rwlab's reference protocol: ``rw.dbc`` (cantools) on any python-can bus."""

    name = "rwlab"
    description = "rwlab's DBC (rw.dbc, cantools) on any python-can bus; the RW90 twin's own"
    transports = ("can",)

    def host_link(self, transport: Any, node_id: int, *, clock: Clock) -> RwlabHostLink:
        return RwlabHostLink(transport, node_id, clock.simulated)

    def node_link(self, transport: Any, node_id: int, *, clock: Clock) -> RwlabNodeLink:
        return RwlabNodeLink(transport, node_id, clock.simulated)

    def identity(self) -> str:
        return f"rwlab dbc sha256 {proto.dbc_sha256()}"

    def signal_ranges(self) -> dict[str, tuple[float, float, str]]:
        """The DBC's signal ranges (as cantools reads them), by the quantity each carries.

        Returns
        -------
        dict
            Quantity → (lowest, highest, ``rw.dbc Message.Signal``).
        """
        db = proto.database()
        where = {
            "speed_rpm": ("RW_Telemetry", "Speed"),
            "current_a": ("RW_Telemetry", "Current"),
            "bus_voltage_v": ("RW_Heartbeat", "BusVoltage"),
            "temperature_c": ("RW_Heartbeat", "Temperature"),
            "setpoint": ("RW_Command", "Setpoint"),
        }
        out = {}
        for quantity, (message, name) in where.items():
            signal = db.get_message_by_name(message).get_signal_by_name(name)
            low, high = signal.minimum, signal.maximum
            if low is None or high is None:  # rw.dbc gives every range; a bare one: unchecked
                continue
            out[quantity] = (float(low), float(high), f"rw.dbc {message}.{name}")
        return out
