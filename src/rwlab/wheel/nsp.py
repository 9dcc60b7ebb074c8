"""NSP, rwlab's own profile (``nsp``): NSP framing with rwlab's CRC, mode writes and registers.

This is the outline rwlab completed with its own choices before the wheel
families' profiles existed; a real wheel speaks ``nsp/nrwa-t6``
(:mod:`rwlab.wheel.nsp_t6`) or ``nsp/rw4-12`` (:mod:`rwlab.wheel.nsp_rw4`),
whose CRC is the reflected one of :mod:`rwlab.wheel.nsp_wire`. It is kept so
that records and scripts made with it still run; framing and packets are
shared with the families (:mod:`rwlab.wheel.nsp_wire`).

A packet travels in SLIP framing (FEND 0xC0, FESC 0xDB, TFEND 0xDC, TFESC 0xDD)
as ``[dst][src][MCF][payload…][CRC lo][CRC hi]``; the CRC is CRC-16/CCITT
(polynomial 0x1021, initial value 0xFFFF, MSB first: not the families' CRC) over
dst..payload. MCF bit 7 asks for a reply ("poll"), bit 5 marks a reply ACK (set)
or NACK (clear), bits 4..0 name the command (PING 0x00, INIT 0x01, PEEK 0x02, POKE 0x03, DIAGNOSTIC
0x04, CRC 0x06, READ-FILE 0x07, WRITE-FILE 0x08, CLEAR-FAULT 0x09).

What the public outline leaves open is fixed here, for the twin and its driver
alike (a real wheel's memory map would replace it):

- addresses: the host is 0x11; wheel ``node_id`` is ``0x20 + node_id``;
- POKE ``[0x00][mode][float32 LE]`` sets the mode: IDLE 0x00, SPEED 0x03
  (rad/s), MOMENTUM 0x11 (N·m·s), TORQUE 0x12 (N·m);
- PEEK ``[address]`` reads: 0x10, the telemetry block ``<BffBBfIHB``: mode,
  speed (rad/s), current (A), latched faults, flags (bit 0 speed limited, bit 1
  a command refused), temperature (°C), uptime (s), commands seen, counter;
  0x11, the speed alone (float32, rad/s);
- PING answers ACK with the text ``rwlab NSP twin``.

The driver polls the telemetry block at its telemetry rate and turns rad/s and
N·m into the rpm and rpm/s of :mod:`rwlab.wheel.protocol` with the wheel's
inertia. SLIP and this CRC are a few lines each (see :mod:`rwlab.wheel.serial`).
"""

from __future__ import annotations

import struct
from dataclasses import replace
from typing import Any

from rwlab.wheel import nsp_wire
from rwlab.wheel import protocol as proto
from rwlab.wheel.link import Clock, NodeLink, WheelProtocol
from rwlab.wheel.nsp_wire import NspHostLinkBase, NspPacket, SlipReader
from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams, rad_s_to_rpm, rpm_to_rad_s
from rwlab.wheel.serial import crc16_ccitt

__all__ = [
    "HOST_ADDRESS",
    "NspHostLink",
    "NspNodeLink",
    "NspPacket",
    "NspProtocol",
    "SlipReader",
    "decode_packet",
    "encode_packet",
    "wheel_address",
]

HOST_ADDRESS = 0x11
PING, INIT, PEEK, POKE, DIAGNOSTIC, CRC, READ_FILE, WRITE_FILE, CLEAR_FAULT = (
    0x00, 0x01, 0x02, 0x03, 0x04, 0x06, 0x07, 0x08, 0x09,
)  # fmt: skip
POLL, ACK = 0x80, 0x20
NSP_IDLE, NSP_SPEED, NSP_MOMENTUM, NSP_TORQUE = 0x00, 0x03, 0x11, 0x12
TELEMETRY_BLOCK, SPEED_REGISTER = 0x10, 0x11
BLOCK = struct.Struct("<BffBBfIHB")
PING_TEXT = b"rwlab NSP twin"
_TO_NSP = {Mode.IDLE: NSP_IDLE, Mode.SPEED: NSP_SPEED, Mode.ACCELERATION: NSP_TORQUE}
_FROM_NSP = {v: k for k, v in _TO_NSP.items()}


def wheel_address(node_id: int) -> int:
    """The NSP address of wheel ``node_id`` (0..15): ``0x20 + node_id``.

    Parameters
    ----------
    node_id : int
        The wheel, 0..15.

    Returns
    -------
    int
    """
    return 0x20 + proto.check_node(node_id)


def encode_packet(packet: NspPacket) -> bytes:
    """The packet with rwlab's MSB-first CRC, in SLIP framing, ready for the wire.

    Parameters
    ----------
    packet : NspPacket

    Returns
    -------
    bytes
        ``FEND … FEND``.
    """
    return nsp_wire.encode_packet(packet, crc16_ccitt)


def decode_packet(body: bytes) -> NspPacket:
    """A packet from one SLIP frame's body (between FENDs), rwlab's MSB-first CRC checked.

    Parameters
    ----------
    body : bytes
        Escaped bytes between two FENDs.

    Returns
    -------
    NspPacket

    Raises
    ------
    ProtocolError
        Bad escape, too short, or the CRC fails.
    """
    return nsp_wire.decode_packet(body, crc16_ccitt)


_read = nsp_wire.read_port


class NspNodeLink(NodeLink):
    """The twin's end: answers PING, PEEK, POKE and CLEAR-FAULT as wheel ``0x20 + node_id``.

    Parameters
    ----------
    port : serial port
        The byte link to the driver (pyserial-like: ``read``/``write``).
    node_id : int
        The wheel's node id.
    clock : Clock
        Where time comes from (simulated or wall clock).
    """

    def __init__(self, port: Any, node_id: int, clock: Clock) -> None:
        super().__init__()
        self.port, self.node_id, self.clock = port, proto.check_node(node_id), clock
        self.address = wheel_address(node_id)
        self._reader = SlipReader()
        self._sequence = 0
        self._block = BLOCK.pack(NSP_IDLE, 0.0, 0.0, 0, 0, 20.0, 0, 0, 0)
        self._inertia = RW90.inertia
        self._corrupt_next: int | None = None

    def configure(self, params: WheelParams) -> None:
        """The wheel's inertia turns TORQUE (N·m) into the twin's rpm/s."""
        self._inertia = params.inertia

    def receive(self, now: float) -> list[tuple[float, proto.Command]]:
        out = []
        for body in self._reader.feed(_read(self.port)):
            try:
                packet = decode_packet(body)
            except proto.ProtocolError:
                self.bad_frames += 1
                continue
            if packet.dst != self.address or packet.mcf & ACK or packet.src == self.address:
                self.foreign_frames += 1  # another device's, or a reply
                continue
            cmd = self._handle(packet)
            if cmd is not None:
                out.append((now, cmd))
        return out

    def _handle(self, packet: NspPacket) -> proto.Command | None:
        cmd, ok, reply, command = packet.command, False, b"", None
        if cmd == PING:
            ok, reply = True, PING_TEXT
        elif cmd == PEEK and packet.payload[:1] == bytes([TELEMETRY_BLOCK]):
            ok, reply = True, bytes([TELEMETRY_BLOCK]) + self._block
        elif cmd == PEEK and packet.payload[:1] == bytes([SPEED_REGISTER]):
            ok, reply = True, bytes([SPEED_REGISTER]) + self._block[1:5]
        elif cmd == POKE:
            command = self._mode_write(packet.payload)
            ok = command is not None
        elif cmd == CLEAR_FAULT:
            command = self._command(Mode.CLEAR_FAULT, 0.0)
            ok = True
        if packet.mcf & POLL:
            mcf = (ACK if ok else 0) | cmd
            self._reply(NspPacket(packet.src, self.address, mcf, reply))
        return command

    def _mode_write(self, payload: bytes) -> proto.Command | None:
        if len(payload) != 6 or payload[0] != 0x00 or payload[1] not in _FROM_NSP:
            return None
        (value,) = struct.unpack("<f", payload[2:6])
        mode = _FROM_NSP[payload[1]]
        if mode == Mode.SPEED:
            return self._command(mode, rad_s_to_rpm(value))
        if mode == Mode.ACCELERATION:  # TORQUE, N·m → the twin's rpm/s
            return self._command(mode, rad_s_to_rpm(value / self._inertia))
        return self._command(mode, 0.0)

    def _command(self, mode: Mode, setpoint: float) -> proto.Command:
        self._sequence = self._sequence % 255 + 1
        return proto.Command(self.node_id, mode, float(setpoint), self._sequence)

    def _reply(self, packet: NspPacket) -> None:
        if self.clock.now() < self.silent_until:  # a telemetry dropout: the line is silent
            return
        data = bytearray(encode_packet(packet))
        if self._corrupt_next is not None:
            data[1 + self._corrupt_next % (len(data) - 2)] ^= 0x01
            self._corrupt_next = None
        self.port.write(bytes(data))

    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        """Update the wheel's registers (NSP wheels answer polls; they do not stream)."""
        mode, speed, current, faults, flags, temp, uptime, seen, counter = BLOCK.unpack(self._block)
        if isinstance(frame, proto.Telemetry):
            mode = _TO_NSP.get(frame.mode, NSP_IDLE)
            speed, current = rpm_to_rad_s(frame.speed_rpm), frame.current
            flags = (flags & ~1) | int(frame.speed_limited)
            counter = frame.counter & 0xFF
        else:
            faults, temp, uptime = int(frame.faults) & 0xFF, frame.temperature, frame.uptime
            seen = frame.commands_seen & 0xFFFF
            flags = (flags & ~2) | (2 if frame.command_rejected else 0)
        self._block = BLOCK.pack(mode, speed, current, faults, flags, temp, uptime, seen, counter)
        self._corrupt_next = corrupt if corrupt is not None else self._corrupt_next


class NspHostLink(NspHostLinkBase):
    """The driver's end: POKEs modes, PEEKs the telemetry block at ``poll_rate``.

    The polling, the ACK counting and the request/reply wire are the NSP family's
    (:class:`rwlab.wheel.nsp_wire.NspHostLinkBase`), with rwlab's MSB-first CRC.

    Parameters
    ----------
    port, node_id, clock, poll_rate
        As for :class:`rwlab.wheel.nsp_wire.NspHostLinkBase`; the wheel answers as NSP
        address ``0x20 + node_id``.
    inertia : float
        Rotor inertia, kg·m²: turns an acceleration command (rpm/s) into the torque
        (N·m) NSP commands; 0: the RW90's (:meth:`configure` sets the wheel's).
    """

    wheel_address = staticmethod(wheel_address)

    crc = staticmethod(crc16_ccitt)

    def __init__(
        self, port: Any, node_id: int, clock: Clock, poll_rate: float = 10.0, inertia: float = 0.0
    ) -> None:
        super().__init__(port, node_id, clock, poll_rate)
        if inertia:
            self.params = replace(self.params, inertia=inertia)
        self._block: tuple[Any, ...] = ()

    def encode_command(self, cmd: proto.Command) -> tuple[int, bytes]:
        if cmd.mode == Mode.CLEAR_FAULT:
            return CLEAR_FAULT, b""
        value = 0.0
        if cmd.mode == Mode.SPEED:
            value = rpm_to_rad_s(cmd.setpoint)
        elif cmd.mode == Mode.ACCELERATION:
            value = self.params.inertia * rpm_to_rad_s(cmd.setpoint)  # N·m
        return POKE, bytes([0x00, _TO_NSP[cmd.mode]]) + struct.pack("<f", value)

    def read_telemetry(self) -> proto.Telemetry | None:
        reply = self.transact(PEEK, bytes([TELEMETRY_BLOCK]))
        if reply is None or not reply.acked or len(reply.payload) != 1 + BLOCK.size:
            return None
        self._block = BLOCK.unpack(reply.payload[1:])
        mode, speed, current, faults, flags = self._block[:5]
        return self.telemetry(
            rad_s_to_rpm(speed),
            current,
            _FROM_NSP.get(mode, Mode.IDLE),
            bool(faults),
            bool(flags & 1),
        )

    def read_heartbeat(self, telemetry: proto.Telemetry) -> proto.Heartbeat | None:
        """The heartbeat from the telemetry block just read (no request of its own).

        Parameters
        ----------
        telemetry : Telemetry
            The telemetry of that block.

        Returns
        -------
        Heartbeat
        """
        _, _, _, faults, flags, temp, uptime, seen, _ = self._block
        rejected = bool(flags & 2) or self._rejected
        return proto.Heartbeat(
            self.node_id, telemetry.mode, Fault(faults & 0xF), temp, uptime, seen, rejected
        )


class NspProtocol(WheelProtocol):
    """NSP over a serial port (pyserial): SLIP framing, CRC-16/CCITT, polled telemetry."""

    name = "nsp"
    description = "NSP, rwlab's own outline: SLIP + MSB-first CRC (no real wheel answers it)"
    transports = ("stream",)
    poll_rate = 10.0

    def host_link(self, transport: Any, node_id: int, *, clock: Clock) -> NspHostLink:
        return NspHostLink(transport, node_id, clock, self.poll_rate)

    def node_link(self, transport: Any, node_id: int, *, clock: Clock) -> NspNodeLink:
        return NspNodeLink(transport, node_id, clock)
