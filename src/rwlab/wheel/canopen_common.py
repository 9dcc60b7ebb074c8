"""What every CANopen profile of the twin shares: the bus network, SDO checks, the SDO pump.

The profiles (``canopen``, ``canopen/oresat``, ``canopen/cia402``) are built on
the ``canopen`` package: its object dictionaries, PDO maps, SDO server
(``LocalNode``) and SDO client (``SdoClient``). This module adds only what the
package leaves to its user:

- :class:`BusNetwork`: a ``canopen.Network`` fed by the caller, so a simulated
  clock rules time (no notifier thread), and frames carry the caller's stamps.
- :func:`checked_sdo_request`: the SDO server's input check. CiA 301 SDO frames
  have 8 data bytes; the package's server raises (and logs a traceback) on a
  shorter one. Such a request is answered with the abort "command specifier not
  valid or unknown" (0x05040001) and counted as bad, as CANopenNode's server
  refuses any SDO frame whose length is not 8. Block downloads, which the
  package's server does not support, get the same abort (and no error log).
- :func:`setpoint_abort`: the CiA 301 abort code of a setpoint the wheel must
  refuse (0x06090030 value range exceeded for a non-finite number, 0x06090031 /
  0x06090032 written too high / too low), raised by a write callback so the
  package's server answers the abort and the value is never applied.
- :class:`SdoPumpNetwork`: the driver's side. The package's ``SdoClient`` waits
  for its answer on a queue a notifier thread fills; here the network itself
  fills it while it waits (kicking a simulated clock so the twin answers at the
  same simulated instant), and keeps every other frame for the link to read.

CiA 301 abort codes as ``canopen.sdo.exceptions.SdoAbortedError.CODES`` lists them.
"""

from __future__ import annotations

import abc
import functools
import hashlib
import math
import struct
import time
from collections.abc import Callable, Container, Iterator, Mapping
from importlib import resources
from typing import Any, ClassVar

import can
import canopen
from canopen.nmt import NMT_STATES
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoAbortedError

from rwlab.interrupts import uninterrupted
from rwlab.wheel import protocol as proto
from rwlab.wheel.dbc_link import read_frames
from rwlab.wheel.link import Clock, HostLink, NodeLink, WheelProtocol
from rwlab.wheel.physics import RW90, Fault, WheelParams

__all__ = [
    "ABORT_RANGE_EXCEEDED",
    "ABORT_TOO_HIGH",
    "ABORT_TOO_LOW",
    "ABORT_UNKNOWN_COMMAND",
    "BusNetwork",
    "CanopenHostBase",
    "CanopenProfile",
    "SdoPumpNetwork",
    "checked_sdo_request",
    "cob_ids",
    "nmt_heartbeat_byte",
    "send_frame",
    "setpoint_abort",
]

ABORT_UNKNOWN_COMMAND = 0x05040001  # client/server command specifier not valid or unknown
ABORT_RANGE_EXCEEDED = 0x06090030  # value range of parameter exceeded (write access)
ABORT_TOO_HIGH = 0x06090031  # value of parameter written too high
ABORT_TOO_LOW = 0x06090032  # value of parameter written too low
ABORT_DEVICE_STATE = 0x08000022  # cannot be transferred or stored: present device state
SDO_FRAME_BYTES = 8
BLOCK_DOWNLOAD = 0xC0  # client command specifier 6, in bits 5..7
SEGMENTS = (0x00, 0x60)  # client command specifiers 0 and 3: a segment of an open transfer
SDO_RX, SDO_TX = 0x600, 0x580


def canopen_id(node_id: int) -> int:
    """The CANopen node id of wheel ``node_id`` in rwlab's profiles: ``node_id + 1``
    (CANopen ids start at 1; OreSat's cards have their own, ``canopen_oresat.canopen_id``).

    Parameters
    ----------
    node_id : int
        0..15.

    Returns
    -------
    int
    """
    return proto.check_node(node_id) + 1


class ShippedEds:
    """An object dictionary rwlab ships beside its profile (``rwlab/wheel/*.eds``).

    Parameters
    ----------
    name : str
        The file name, e.g. ``"cia402_wheel.eds"``.
    """

    def __init__(self, name: str) -> None:
        self.name = name

    def path(self) -> str:
        """Path of the profile's object dictionary.

        Returns
        -------
        str
        """
        return str(resources.files(__package__).joinpath(self.name))

    @functools.cached_property
    def sha256(self) -> str:
        """The file's SHA-256, hex: what a protocol's identity names."""
        text = resources.files(__package__).joinpath(self.name).read_text()
        return hashlib.sha256(text.encode()).hexdigest()

    def dictionary(self, cid: int) -> ObjectDictionary:
        """A fresh object dictionary for CANopen node ``cid``.

        Parameters
        ----------
        cid : int
            The CANopen node id.

        Returns
        -------
        canopen.ObjectDictionary
        """
        return canopen.import_od(self.path(), node_id=cid)


_NMT_CODES = {name: code for code, name in NMT_STATES.items()}  # the canopen package's table


def nmt_heartbeat_byte(node: canopen.LocalNode) -> int:
    """The state byte a heartbeat carries for ``node``'s NMT state (CiA 301: 0x04 stopped,
    0x05 operational, 0x7F pre-operational), as an NMT master's commands left it.

    Parameters
    ----------
    node : canopen.LocalNode
        The twin's node.

    Returns
    -------
    int
    """
    return _NMT_CODES.get(node.nmt.state, _NMT_CODES["OPERATIONAL"])


def send_frame(bus: can.BusABC, cob_id: int, data: bytes, t: float) -> None:
    """Send one standard-id frame stamped ``t`` (s, the caller's clock).

    Parameters
    ----------
    bus : can.BusABC
    cob_id : int
        The 11-bit COB-ID.
    data : bytes
        0..8 bytes.
    t : float
        Time stamp, s.
    """
    msg = can.Message(arbitration_id=cob_id, data=bytes(data), is_extended_id=False)
    msg.timestamp = t
    with uninterrupted():  # a stop inside python-can's queue can leave its lock taken
        bus.send(msg)


class BusNetwork(canopen.Network):
    """A ``canopen`` network fed by the caller (no notifier thread: a simulated clock rules).

    Frames the ``canopen`` package sends itself (SDO answers, EMCY) carry the time
    the link last saw, so simulated records stay on simulated time.

    Parameters
    ----------
    bus : can.BusABC
        The bus the network sends on (the caller reads it).
    """

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(bus)
        self.stamp = 0.0  # s, the time stamp of frames the package sends (SDO answers, EMCY)
        self._bus = bus

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        msg = can.Message(
            arbitration_id=can_id, data=bytes(data), is_extended_id=False, is_remote_frame=remote
        )
        msg.timestamp = self.stamp
        with uninterrupted(), self.send_lock:
            self._bus.send(msg)


class CanopenNodeBase(NodeLink):
    """The twin's end of every CANopen profile: its ``canopen.LocalNode`` on a
    :class:`BusNetwork`, operational, and what it does with the frames it receives.

    Subclasses answer SDO writes and reads (:meth:`_on_sdo_write`, :meth:`_on_sdo_read`)
    and call :meth:`_route_frames` from ``receive``.

    Parameters
    ----------
    bus : can.BusABC
    node_id : int
        The wheel's node id, 0..15.
    clock : WallClock or SimClock
    cid : int
        The wheel's CANopen node id.
    dictionary : canopen.ObjectDictionary
        The wheel's object dictionary.
    """

    def __init__(
        self, bus: can.BusABC, node_id: int, clock: Clock, cid: int, dictionary: ObjectDictionary
    ) -> None:
        super().__init__()
        self.bus, self.node_id, self.clock = bus, proto.check_node(node_id), clock
        self.network = BusNetwork(bus)
        self.cid = cid
        self.local = canopen.LocalNode(cid, dictionary)
        self.network.add_node(self.local)
        self.local.tpdo.read(from_od=True)
        self.local.add_write_callback(self._on_sdo_write)
        self.local.add_read_callback(self._on_sdo_read)
        self.local.nmt.state = "OPERATIONAL"
        self._params = RW90
        self._commands: list[tuple[float, proto.Command]] = []
        self._arrival = 0.0  # s, when the frame being handled came
        self._sequence = 0
        self._faults = Fault.NONE
        self._twin: str | None = None

    def configure(self, params: WheelParams) -> None:
        self._params = params

    @abc.abstractmethod
    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Apply a write the package's SDO server received (raise its abort to refuse it)."""

    @abc.abstractmethod
    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> float | int | None:
        """The value of an object the node keeps itself (None: the dictionary's)."""

    def _route_frames(
        self, now: float, own: Container[int], wanted: Container[int], sizes: Mapping[int, int]
    ) -> None:
        """Hand each received frame to ``network``: the node's own COB-ids (``own``, and its
        heartbeat) heard from elsewhere name another twin on the bus; a COB-id not in
        ``wanted`` is foreign; a bad SDO request is answered with an abort, and a frame
        whose length is not its ``sizes`` entry (RPDOs), or too short for its objects, is
        counted bad."""
        for msg in read_frames(self.bus):
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                self.foreign_frames += 1
                continue
            cob = msg.arbitration_id
            if cob in own or cob == 0x700 + self.cid:
                reports = getattr(self.bus, "reports_sources", False)
                self._twin = str(msg.channel) if reports else "another sender"
                continue
            if cob not in wanted:
                self.foreign_frames += 1
                continue
            self._arrival = msg.timestamp if self.clock.simulated else now
            self.network.stamp = self._arrival
            if cob == 0x600 + self.cid and not checked_sdo_request(self.network, cob, msg.data):
                self.bad_frames += 1
                continue
            if cob in sizes and len(msg.data) != sizes[cob]:
                self.bad_frames += 1
                continue
            try:
                self.network.notify(cob, bytearray(msg.data), self._arrival)
            except (struct.error, ValueError, IndexError, KeyError, TypeError):
                self.bad_frames += 1  # a frame too short for its objects

    def heard_twin(self) -> str | None:
        """Where another twin answering as this node was heard from, or None.

        Returns
        -------
        str or None
            The bus channel it came from, or ``"another sender"``.
        """
        return self._twin


def checked_sdo_request(network: BusNetwork, cob_id: int, data: bytes | bytearray) -> bool:
    """True when ``data`` is an SDO request for the package's server; otherwise answer its abort.

    A request that is not 8 bytes, a block download, and a segment with no segmented
    transfer open (which the package's server refuses too, but logs as an
    error) are answered 0x05040001 here.

    Parameters
    ----------
    network : BusNetwork
        The twin's network (sends the abort).
    cob_id : int
        The request's COB-ID, 0x600 + node id.
    data : bytes
        The request.

    Returns
    -------
    bool
    """
    if len(data) == SDO_FRAME_BYTES and data[0] & 0xE0 != BLOCK_DOWNLOAD:
        if data[0] & 0xE0 not in SEGMENTS or _transfer_open(network, cob_id - SDO_RX):
            return True
    head = bytes(data[1:4]).ljust(3, b"\0")  # index and subindex, as far as they came
    abort = bytes([0x80]) + head + struct.pack("<I", ABORT_UNKNOWN_COMMAND)
    network.send_message(cob_id - SDO_RX + SDO_TX, abort)
    return False


def _transfer_open(network: BusNetwork, node_id: int) -> bool:
    # the canopen package's SdoServer keeps an open segmented transfer's bytes in
    # ``_buffer`` (None otherwise) and offers no public way to ask
    node = network.nodes.get(node_id)
    return getattr(getattr(node, "sdo", None), "_buffer", None) is not None


def setpoint_abort(value: float, limit: float) -> None:
    """Raise the CiA 301 abort for a setpoint beyond ``±limit`` or not a number.

    Parameters
    ----------
    value : float
        The setpoint, in the unit of ``limit``.
    limit : float
        The largest magnitude the wheel obeys.

    Raises
    ------
    canopen.SdoAbortedError
        0x06090030 (not finite), 0x06090031 (above), 0x06090032 (below).
    """
    if not math.isfinite(value):
        raise SdoAbortedError(ABORT_RANGE_EXCEEDED)
    if value > limit:
        raise SdoAbortedError(ABORT_TOO_HIGH)
    if value < -limit:
        raise SdoAbortedError(ABORT_TOO_LOW)


def cob_ids(canopen_id: int, tpdos: tuple[int, ...], rpdos: tuple[int, ...]) -> str:
    """The COB-IDs a CANopen node ``canopen_id`` answers on, for ``serve`` to print.

    Parameters
    ----------
    canopen_id : int
        1..127.
    tpdos, rpdos : tuple of int
        The COB-IDs of its TPDOs and RPDOs.

    Returns
    -------
    str
    """
    return (
        f"CANopen node {canopen_id} (0x{canopen_id:02X}): SDO 0x{SDO_RX + canopen_id:03X} "
        f"-> 0x{SDO_TX + canopen_id:03X}, "
        + (f"RPDO {'/'.join(f'0x{c:03X}' for c in rpdos)}, " if rpdos else "")
        + f"TPDO {'/'.join(f'0x{c:03X}' for c in tpdos)}, EMCY 0x{0x80 + canopen_id:03X}, "
        f"heartbeat 0x{0x700 + canopen_id:03X}"
    )


class SdoPumpNetwork(BusNetwork):
    """The driver's network: an SDO request waits for its answer by reading the bus itself.

    Parameters
    ----------
    bus : can.BusABC
    clock : WallClock or SimClock
        A simulated clock is kicked so the twin answers at the same instant.
    server_id : int
        The CANopen node id of the SDO server (the wheel).
    timeout : float
        Wall seconds to wait for an answer.
    """

    def __init__(self, bus: can.BusABC, clock: Clock, server_id: int, timeout: float = 0.3):
        super().__init__(bus)
        self.clock, self.timeout = clock, timeout
        self._request_id, self._response_id = SDO_RX + server_id, SDO_TX + server_id
        self.kept: list[can.Message] = []  # frames read while waiting, for the link
        self.on_frame: Callable[[float, int, bytes, str], None] | None = None  # a recorder

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.stamp = self.clock.now()
        super().send_message(can_id, data, remote)
        if self.on_frame is not None:
            self.on_frame(self.stamp, can_id, bytes(data), "tx")
        if can_id == self._request_id:
            self._pump()

    def _pump(self) -> None:
        """Read the bus until the SDO answer comes (the package's client then finds it)."""
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            if self.clock.simulated:
                self.clock.kick()  # type: ignore[union-attr]
            for msg in read_frames(self._bus):
                if msg.arbitration_id == self._response_id and not msg.is_remote_frame:
                    if self.on_frame is not None:
                        t = msg.timestamp if self.clock.simulated else self.clock.now()
                        self.on_frame(t, msg.arbitration_id, bytes(msg.data), "rx")
                    self.notify(msg.arbitration_id, bytearray(msg.data), msg.timestamp)
                    return
                self.kept.append(msg)
            time.sleep(2e-5)

    def take(self) -> list[can.Message]:
        """Frames kept while waiting, then those waiting on the bus now, oldest first.

        Returns
        -------
        list of can.Message
        """
        out, self.kept = self.kept, []
        return out + read_frames(self._bus)


class TpdoSchedule:
    """When each TPDO of a twin is due, from its event timer (0x1800 + n - 1, sub 5, ms).

    CiA 301: a TPDO of transmission type 254/255 is sent when its event timer
    elapses; a timer of 0 disables it, and the TPDO is then sent on every
    change, which for telemetry is every sample. The timer is read from the
    node's object dictionary each time, so a host that writes it (as OreSat's
    C3 may) changes the rate at once.

    Parameters
    ----------
    node : canopen.LocalNode
    """

    def __init__(self, node: canopen.LocalNode) -> None:
        self.node = node
        self._booked: dict[int, tuple[float, float, float]] = {}  # last sent, period, next

    def timer_s(self, number: int) -> float:
        """The event timer of TPDO ``number`` (1-based), s (0: sent on every sample)."""
        raw = self.node.get_data(0x1800 + number - 1, 5)
        return int.from_bytes(raw, "little") / 1000

    def due(self, number: int, t: float) -> bool:
        """True (and the next time booked) when TPDO ``number`` should be sent at ``t`` (s)."""
        period = self.timer_s(number)
        if period <= 0:
            return True
        last, booked_period, due = self._booked.get(number, (t - period, period, t))
        if period != booked_period:  # the timer was written: count from the last send
            due = last + period
        if t < due - min(1e-3, 0.1 * period):  # a sample early by rounding still counts
            self._booked[number] = (last, period, due)
            return False
        self._booked[number] = (t, period, due + period if due + period > t else t + period)
        return True


class CanopenHostBase(HostLink):
    """What rwlab's driver of every SDO-commanded CANopen profile does: the remote node on
    an :class:`SdoPumpNetwork`, the raw record, and the wheel's TPDOs read from the bus.

    Parameters
    ----------
    bus, node_id, clock, cid, dictionary
        As for :class:`CanopenNodeBase`.
    """

    def __init__(
        self, bus: can.BusABC, node_id: int, clock: Clock, cid: int, dictionary: ObjectDictionary
    ) -> None:
        super().__init__()
        self.bus, self.node_id, self.clock = bus, proto.check_node(node_id), clock
        self.cid = cid
        self.network = SdoPumpNetwork(bus, clock, cid)
        self.network.on_frame = self._record
        self.remote = canopen.RemoteNode(cid, dictionary)
        self.network.add_node(self.remote)
        self.remote.tpdo.read(from_od=True)
        self.inertia = RW90.inertia

    def _record(self, t: float, cob: int, data: bytes, direction: str) -> None:
        if self.raw_listener:
            self.raw_listener(t, cob, data, direction)

    def _tpdos(self, now: float) -> Iterator[tuple[float, int, Any, str | None]]:
        """Each TPDO 1..4 of the wheel received since the last call, decoded into its map.

        Every frame read is recorded; a heartbeat that is not 1 byte or a TPDO of the
        wrong length counts as bad, any other frame (SDO, other nodes) as foreign.

        Parameters
        ----------
        now : float
            Clock time, s (the frames' time on a wall clock).

        Yields
        ------
        t : float
            The frame's time, s.
        number : int
            The TPDO's number, 1..4.
        pdo_map : canopen.pdo.PdoMap
            The TPDO, its variables holding the values received.
        source : str or None
            The bus channel it came from, where the bus reports one.
        """
        cid = self.cid
        numbers = {0x180 + cid: 1, 0x280 + cid: 2, 0x380 + cid: 3, 0x480 + cid: 4}
        for msg in self.network.take():
            t = msg.timestamp if self.clock.simulated else now
            cob, data = msg.arbitration_id, bytes(msg.data)
            self._record(t, cob, data, "rx")
            source = str(msg.channel) if getattr(self.bus, "reports_sources", False) else None
            number = numbers.get(cob)
            if number is None:
                if cob == 0x700 + cid and len(data) != 1:
                    self.bad_frames += 1
                elif cob not in (0x700 + cid, 0x80 + cid):
                    self.foreign_frames += 1  # SDO, other nodes, other protocols
                continue
            pdo_map = self.remote.tpdo[number]
            if len(data) != len(pdo_map.data):
                self.bad_frames += 1
                continue
            pdo_map.on_message(cob, bytearray(data), t)
            yield t, number, pdo_map, source


class CanopenProfile(WheelProtocol):
    """A CANopen profile of the twin, on any python-can bus, named in records by its
    shipped object dictionary's hash.

    Subclasses set ``name``, ``description``, ``eds`` and the classes of their two links,
    ``host_class`` and ``node_class`` (each built from the bus, node id and clock).
    """

    eds: ClassVar[ShippedEds]
    host_class: Callable[[can.BusABC, int, Clock], HostLink]
    node_class: Callable[[can.BusABC, int, Clock], NodeLink]

    def host_link(self, transport: Any, node_id: int, *, clock: Clock) -> HostLink:
        return self.host_class(transport, node_id, clock)

    def node_link(self, transport: Any, node_id: int, *, clock: Clock) -> NodeLink:
        return self.node_class(transport, node_id, clock)

    def identity(self) -> str:
        return f"{self.name} eds sha256 {self.eds.sha256}"
