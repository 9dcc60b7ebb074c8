"""NSP on the wire, as the wheel families speak it: framing, CRC, and the two polled links.

NSP (the Nanosatellite Protocol of UTIAS SFL, used by the NewSpace NRWA-T6 and
the Sinclair Interplanetary / Rocket Lab RW4-12 wheels) sends each message in
SLIP framing (FEND 0xC0; FESC 0xDB; FESC TFEND 0xDB 0xDC for a data 0xC0;
FESC TFESC 0xDB 0xDD for a data 0xDB) as::

    [destination][source][message control][data …][CRC lo][CRC hi]

The message control byte is ``Poll`` (bit 7: a reply is wanted), ``B`` (bit 6),
``A`` (bit 5: ACK in a reply, NACK when clear) and the 5-bit command code. The
CRC is CCITT (x¹⁶ + x¹² + x⁵ + 1) initialised to 0xFFFF with the bytes fed least
significant bit first (the reflected form: polynomial 0x8408 as processed), no
final XOR, sent least significant byte first; the reveng catalogue calls this
CRC-16/MCRF4XX (check value 0x6F91 for ``b"123456789"``). rwlab's ``nsp``
profile used the MSB-first form (CRC-16/CCITT-FALSE): its frames fail here.

Sources (read, not copied):

- NewSpace Systems, *NRWA-T6 Interface Control Document*, N2-A2a-DD0021 rev
  10.02 (2023-12-18), §11 (SLIP, message fields, CRC, validation steps: at least
  5 bytes, at most 260 data bytes) and §12 (commands, ACK/NACK);
- github.com/ryan-rbw/nsrw_emu (an NRWA-T6 emulator, C) and
  github.com/ryan-rbw/nsrw_test (its Python host, ``nss_host``): the CRC fed LSB
  first with 0x8408, replies with the Poll bit clear and B echoed;
- github.com/Rivercraft911/rxnReflect (a Python driver for a real RW4-12 after
  Rocket Lab's E400281 software ICD): ``crcmod`` with ``rev=True``, init 0xFFFF.

SLIP (RFC 1055, :mod:`rwlab.wheel.serial`) and the 8-line CRC are written by
hand: no maintained package offers NSP, and the CRC is not worth a dependency
(the tests check it against ``crccheck`` and ``binascii``).

Both wheel families answer only when polled, so their host links poll: the
driver asks for telemetry at its telemetry rate and turns each reply into a
:class:`rwlab.wheel.protocol.Telemetry` and, once a second, a
:class:`rwlab.wheel.protocol.Heartbeat`. A command is known to have arrived when
the wheel ACKs it; a NACK or no reply counts as a lost command.
"""

from __future__ import annotations

import abc
import math
import time
from dataclasses import dataclass
from typing import Any

from rwlab.errors import SlipError
from rwlab.wheel import protocol as proto
from rwlab.wheel.link import Clock, HostLink, Incoming, NodeLink
from rwlab.wheel.physics import RW90, Mode, WheelParams
from rwlab.wheel.serial import MAX_BYTES_PER_READ, SlipReader, slip_decode, slip_encode

__all__ = [
    "ACK",
    "B_BIT",
    "MAX_DATA_BYTES",
    "POLL",
    "NspHostLinkBase",
    "NspNodeLinkBase",
    "NspPacket",
    "SlipError",
    "SlipReader",
    "Verdict",
    "crc16_nsp",
    "decode_packet",
    "encode_packet",
    "setpoint_allowed",
]

POLL, B_BIT, ACK = 0x80, 0x40, 0x20
MAX_DATA_BYTES = 260  # NRWA-T6 ICD §11.3: a longer message is dropped unanswered


def crc16_nsp(data: bytes, crc: int = 0xFFFF) -> int:
    """The NSP message CRC: CCITT, init 0xFFFF, bytes fed LSB first (0x8408), no final XOR.

    Parameters
    ----------
    data : bytes
        Destination address through the last data byte.
    crc : int
        Initial value (chain calls over pieces).

    Returns
    -------
    int
        The CRC, 0..65535; sent low byte first.
    """
    for byte in data:
        crc = (crc >> 8) ^ _NSP_TABLE[(crc ^ byte) & 0xFF]
    return crc


def _nsp_shifts(crc: int) -> int:
    """The NSP CRC register's 8 shifts of one byte (0x8408, LSB first)."""
    for _ in range(8):
        crc = (crc >> 1) ^ 0x8408 if crc & 1 else crc >> 1
    return crc


# the 8 shifts of each byte value, so a byte costs one look-up (the register's higher
# bits only shift down: the shifts are linear)
_NSP_TABLE = tuple(_nsp_shifts(i) for i in range(256))


@dataclass(frozen=True)
class NspPacket:
    """One NSP message (its CRC checked on decoding, added on encoding).

    Attributes
    ----------
    dst, src : int
        Destination and source addresses, 0..255.
    mcf : int
        Message control: bit 7 Poll, bit 6 B, bit 5 A (ACK), bits 4..0 the command.
    payload : bytes
        The data field, at most 260 bytes.
    """

    dst: int
    src: int
    mcf: int
    payload: bytes = b""

    @property
    def command(self) -> int:
        """The command code, bits 4..0 of the message control byte."""
        return self.mcf & 0x1F

    @property
    def acked(self) -> bool:
        """The A bit: in a reply, ACK (set) or NACK (clear)."""
        return bool(self.mcf & ACK)


def encode_packet(packet: NspPacket, crc: Any = crc16_nsp) -> bytes:
    """The packet with its CRC (low byte first), in SLIP framing, ready for the wire.

    Parameters
    ----------
    packet : NspPacket
    crc : callable
        ``crc(bytes) -> int``; the families' :func:`crc16_nsp` unless told.

    Returns
    -------
    bytes
        ``FEND … FEND``.

    Raises
    ------
    ProtocolError
        A field is not a byte, or the data field is longer than 260 bytes.
    """
    for name in ("dst", "src", "mcf"):
        if not 0 <= getattr(packet, name) <= 0xFF:
            raise proto.ProtocolError(f"NSP {name} must be a byte, got {getattr(packet, name)}")
    if len(packet.payload) > MAX_DATA_BYTES:
        raise proto.ProtocolError(
            f"NSP data field of {len(packet.payload)} bytes; at most {MAX_DATA_BYTES}"
        )
    body = bytes([packet.dst, packet.src, packet.mcf]) + bytes(packet.payload)
    return slip_encode(body + crc(body).to_bytes(2, "little"))


def decode_packet(body: bytes, crc: Any = crc16_nsp) -> NspPacket:
    """A packet from one SLIP frame's body (the bytes between two FENDs).

    Parameters
    ----------
    body : bytes
        Escaped bytes between two FENDs.
    crc : callable
        ``crc(bytes) -> int``; the families' :func:`crc16_nsp` unless told.

    Returns
    -------
    NspPacket

    Raises
    ------
    ProtocolError
        A bad escape, fewer than 5 bytes, more than 260 data bytes, or a failed CRC.
    """
    try:
        raw = slip_decode(body)
    except ValueError:
        raise SlipError("NSP frame: FESC not followed by TFEND or TFESC") from None
    if len(raw) < 5:
        raise proto.ProtocolError(f"NSP frame of {len(raw)} bytes; at least 5 expected")
    if len(raw) - 5 > MAX_DATA_BYTES:
        raise proto.ProtocolError(f"NSP frame with {len(raw) - 5} data bytes; at most 260")
    if crc(raw[:-2]) != int.from_bytes(raw[-2:], "little"):
        raise proto.ProtocolError("NSP frame fails its CRC")
    return NspPacket(raw[0], raw[1], raw[2], bytes(raw[3:-2]))


def read_port(port: Any) -> bytes:
    """What a pyserial-like port has waiting, at most 64 KiB, without blocking."""
    waiting = port.in_waiting
    return bytes(port.read(min(waiting, MAX_BYTES_PER_READ))) if waiting else b""


def setpoint_allowed(params: WheelParams, mode: Mode, setpoint: float) -> bool:
    """The rule :class:`rwlab.wheel.WheelNode` applies: finite and within the wheel's limits.

    Parameters
    ----------
    params : WheelParams
    mode : Mode
    setpoint : float
        rpm (SPEED) or rpm/s (ACCELERATION).

    Returns
    -------
    bool
    """
    limit = {Mode.SPEED: params.max_speed_rpm, Mode.ACCELERATION: params.max_accel_rpm_s}
    bound = limit.get(mode)
    return math.isfinite(setpoint) and (bound is None or abs(setpoint) <= bound)


@dataclass(frozen=True)
class Verdict:
    """What a twin does with one request: ACK or NACK, the reply's data, the command to apply.

    Attributes
    ----------
    ack : bool
    reply : bytes
        The reply's data field.
    command : Command or None
        Handed to the wheel; a NACKed one only to be counted as rejected (it fails
        the wheel's own limit check), never applied.
    """

    ack: bool
    reply: bytes = b""
    command: proto.Command | None = None


NACK = Verdict(False)


class NspNodeLinkBase(NodeLink):
    """The twin's end of an NSP family: validates, answers when polled, counts the rest.

    A frame that fails SLIP, length or CRC is dropped unanswered and counted in
    :attr:`bad_frames` (the ICD's rule); a valid one for another address, or a
    reply, in :attr:`foreign_frames`; a request that cannot be carried out is
    NACKed and counted in :attr:`nacked`. Subclasses answer the commands.

    Parameters
    ----------
    port : serial port
        A pyserial-like port (``in_waiting``, ``read``, ``write``).
    node_id : int
        The wheel.
    clock : WallClock or SimClock
        The twin's clock.
    """

    def __init__(self, port: Any, node_id: int, clock: Clock) -> None:
        super().__init__()
        self.port, self.node_id, self.clock = port, proto.check_node(node_id), clock
        self.params = RW90
        self.nacked = 0
        self.bytes_received = self.bytes_sent = self.messages_received = 0
        self._reader = SlipReader()
        self._sequence = 0
        self._corrupt_next: int | None = None

    @abc.abstractmethod
    def addresses(self) -> tuple[int, ...]:
        """The NSP destination addresses this wheel answers on.

        Returns
        -------
        tuple of int
        """

    @abc.abstractmethod
    def handle(self, packet: NspPacket) -> Verdict:
        """Carry out one request addressed to this wheel.

        Parameters
        ----------
        packet : NspPacket
            The request.

        Returns
        -------
        Verdict
            The reply to send and the command it carried, if any.
        """

    def configure(self, params: WheelParams) -> None:
        """The wheel's inertia (SI units) and limits (what is NACKed)."""
        self.params = params

    def note_bad_frame(self, slip_error: bool) -> None:
        """Called for each frame dropped for SLIP, length or CRC.

        Parameters
        ----------
        slip_error : bool
            The SLIP framing was wrong (a bad escape); else the length or the CRC.
        """

    def receive(self, now: float) -> list[tuple[float, proto.Command]]:
        data = read_port(self.port)
        self.bytes_received += len(data)
        out = []
        for body in self._reader.feed(data):
            try:
                packet = decode_packet(body)
            except proto.ProtocolError as error:
                self.bad_frames += 1
                self.note_bad_frame(isinstance(error, SlipError))
                continue
            if packet.dst not in self.addresses() or packet.dst == packet.src:
                self.foreign_frames += 1  # another device's request, or a reply
                continue
            self.messages_received += 1
            verdict = self.handle(packet)
            if not verdict.ack:
                self.nacked += 1
            if packet.mcf & POLL:  # the reply echoes B and the command; Poll clear
                mcf = (packet.mcf & B_BIT) | (ACK if verdict.ack else 0) | packet.command
                self._reply(NspPacket(packet.src, packet.dst, mcf, verdict.reply))
            if verdict.command is not None:
                out.append((now, verdict.command))
        return out

    def command(self, mode: Mode, setpoint: float) -> proto.Command:
        """A protocol-free command for the wheel, numbered in arrival order."""
        self._sequence = self._sequence % 255 + 1
        return proto.Command(self.node_id, mode, float(setpoint), self._sequence)

    def _reply(self, packet: NspPacket) -> None:
        if self.clock.now() < self.silent_until:  # a telemetry dropout: the line is silent
            return
        data = bytearray(encode_packet(packet))
        if self._corrupt_next is not None:
            data[1 + self._corrupt_next % (len(data) - 2)] ^= 0x01
            self._corrupt_next = None
        self.bytes_sent += len(data)
        self.port.write(bytes(data))

    def corrupt_next_reply(self, corrupt: int | None) -> None:
        """Fault injection: damage the next reply at this byte index (None: leave it)."""
        if corrupt is not None:
            self._corrupt_next = corrupt


class NspHostLinkBase(HostLink):
    """The driver's end of an NSP family: polled requests, ACK-counted commands.

    Subclasses encode a command (:meth:`encode_command`) and read the wheel's
    state (:meth:`read_telemetry`, :meth:`read_heartbeat`) with :meth:`transact`.

    Parameters
    ----------
    port : serial port
        A pyserial-like port (``in_waiting``, ``read``, ``write``).
    node_id : int
        The wheel.
    clock : WallClock or SimClock
        The driver's clock (on a SimClock the link polls as the clock advances).
    poll_rate : float
        Telemetry polls per second, Hz.
    """

    host_address = 0x11  # "by convention … the primary computer" (NRWA-T6 ICD §11.2.2)
    crc: Any = staticmethod(crc16_nsp)  # the frames' CRC; rwlab's own NSP has its own

    def __init__(self, port: Any, node_id: int, clock: Clock, poll_rate: float = 10.0) -> None:
        super().__init__()
        self.port, self.node_id, self.clock = port, proto.check_node(node_id), clock
        self.address = self.wheel_address(node_id)
        self.params = RW90
        self.period = 1.0 / poll_rate
        self.reply_timeout = 0.5  # s of wall time: a pty or a 115200-baud line answers in ms
        self.nacks = 0
        self.acked_commands = 0  # what the heartbeat reports as "commands seen"
        self._reader = SlipReader()
        self._queue: list[Incoming] = []
        self._next_poll = clock.now()
        self._polls = 0
        self._last_sequence = 0
        self._rejected = False  # a NACKed setpoint since the last CLEAR-FAULT
        self._heartbeat_due = clock.now()
        self._last_state: tuple[Any, ...] | None = None
        self._busy = False
        if clock.simulated:
            clock.attach(self._tick)  # type: ignore[union-attr]

    @staticmethod
    @abc.abstractmethod
    def wheel_address(node_id: int) -> int:
        """The family's NSP address of wheel ``node_id`` (the link's ``address``).

        Parameters
        ----------
        node_id : int
            The wheel.

        Returns
        -------
        int
        """

    @abc.abstractmethod
    def encode_command(self, cmd: proto.Command) -> tuple[int, bytes]:
        """The request that carries a command.

        Parameters
        ----------
        cmd : Command
            The command.

        Returns
        -------
        (int, bytes)
            The NSP command code and the data field.

        Raises
        ------
        ProtocolError
            The wheel's protocol cannot encode it.
        """

    @abc.abstractmethod
    def read_telemetry(self) -> proto.Telemetry | None:
        """Poll the wheel's state.

        Returns
        -------
        Telemetry or None
            None when a reply is missing or malformed.
        """

    @abc.abstractmethod
    def read_heartbeat(self, telemetry: proto.Telemetry) -> proto.Heartbeat | None:
        """Poll the wheel's slow state (temperature, supply, faults).

        Parameters
        ----------
        telemetry : Telemetry
            The telemetry just read (its mode and node).

        Returns
        -------
        Heartbeat or None
            None when a reply is missing.
        """

    # -- the wire ---------------------------------------------------------------------
    def transact(self, command: int, payload: bytes = b"") -> NspPacket | None:
        """Send a polled request; the wheel's reply (ACK or NACK), or None without one.

        Parameters
        ----------
        command : int
            The command code, 0..31.
        payload : bytes
            The data field.

        Returns
        -------
        NspPacket or None
        """
        self._busy = True
        try:
            return self._transact(command, payload)
        finally:
            self._busy = False

    def _transact(self, command: int, payload: bytes) -> NspPacket | None:
        self._reader.feed(read_port(self.port))  # stale bytes are not this reply
        request = NspPacket(self.address, self.host_address, POLL | command, payload)
        wire = encode_packet(request, self.crc)
        self.port.write(wire)
        now = self.clock.now()
        if self.raw_listener:
            self.raw_listener(now, request.mcf, wire, "tx")
        deadline = time.monotonic() + self.reply_timeout
        while time.monotonic() < deadline:
            if self.clock.simulated:
                self.clock.kick()  # type: ignore[union-attr]
            for body in self._reader.feed(read_port(self.port)):
                try:
                    packet = decode_packet(body, self.crc)
                except proto.ProtocolError:
                    self.bad_frames += 1
                    continue
                if packet.src != self.address or packet.dst != self.host_address:
                    self.foreign_frames += 1
                    continue
                if self.raw_listener:
                    self.raw_listener(now, packet.mcf, slip_encode(body), "rx")
                if packet.command == command:
                    return packet
            time.sleep(5e-5)
        return None

    def send(self, cmd: proto.Command, now: float) -> None:
        command, payload = self.encode_command(cmd)
        reply = self.transact(command, payload)
        if reply is None or not reply.acked:
            self.lost_commands += 1
            if reply is not None:
                self.nacks += 1
                self._rejected = cmd.mode in (Mode.SPEED, Mode.ACCELERATION) or self._rejected
            return
        self.acked_commands += 1
        self._last_sequence = cmd.sequence
        if cmd.mode == Mode.CLEAR_FAULT:
            self._rejected = False

    # -- telemetry ----------------------------------------------------------------------
    def configure(self, params: WheelParams) -> None:
        """The wheel's inertia turns rpm/s into the N·m the family speaks."""
        self.params = params

    def set_telemetry_rate(self, rate: float) -> None:
        """Poll the wheel ``rate`` times per second, Hz."""
        self.period = 1.0 / rate
        self._next_poll = self.clock.now()

    def poll_now(self, now: float) -> None:
        """Poll the wheel now, keeping the schedule: a driver waiting for the telemetry that
        echoes an ACKed command gets it in one round trip, not at the next poll (up to a
        poll period, 100 ms at 10 Hz, later)."""
        if self._busy:
            return
        if now >= self._next_poll - 1e-12:
            self._tick(now)  # a scheduled poll is due anyway
        else:
            self._poll(now)

    def _tick(self, now: float) -> float:
        if not self._busy and now >= self._next_poll - 1e-12:
            self._poll(now)
            self._next_poll += self.period
            if self._next_poll <= now:
                self._next_poll = now + self.period
        return self._next_poll

    def _poll(self, now: float) -> None:
        self._polls += 1
        telemetry = self.read_telemetry()
        if telemetry is None:
            return  # the counter skips: the driver counts a lost frame
        self._queue.append(Incoming(now, telemetry))
        state = (telemetry.fault_active, self._rejected)
        if now >= self._heartbeat_due or state != self._last_state:
            heartbeat = self.read_heartbeat(telemetry)
            if heartbeat is not None:
                self._queue.append(Incoming(now, heartbeat))
                self._last_state = state
                self._heartbeat_due = now + 1.0

    def telemetry(
        self, speed_rpm: float, current: float, mode: Mode, fault: bool, limited: bool
    ) -> proto.Telemetry:
        """A :class:`Telemetry` of this wheel, numbered by poll, echoing the last ACKed command."""
        return proto.Telemetry(
            self.node_id,
            speed_rpm,
            current,
            mode,
            fault,
            limited,
            self._last_sequence,
            self._polls & 0xFF,
        )

    def receive(self, now: float) -> list[Incoming]:
        if not self.clock.simulated:
            self._tick(now)
        out, self._queue = self._queue, []
        return out

    def close(self) -> None:
        if self.clock.simulated:
            self.clock.detach(self._tick)  # type: ignore[union-attr]
