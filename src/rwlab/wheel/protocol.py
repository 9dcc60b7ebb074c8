"""The wheel's CAN protocol: one DBC file (``rw.dbc``) for the simulated node and the driver.

Frame ids carry the node id in their low 4 bits (``0x100 + node`` commands,
``0x180 + node`` telemetry, ``0x700 + node`` heartbeat), so up to 16 wheels
share a bus. Byte 7 of every frame is a CRC-8 (SAE J1850: polynomial 0x1D,
initial value and final XOR 0xFF, the AUTOSAR E2E choice) over the frame id and
bytes 0..6, so a corrupted payload, an all-zero frame or a frame sent under
another id is detected and dropped, never acted on.
Encoding and decoding are cantools'; the CRC (ten lines, no package needed)
and the node-id masking are written here.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import cast

import can
import cantools

from rwlab.errors import ProtocolError  # ProtocolError re-exported here, where it was
from rwlab.wheel.physics import Fault, Mode

__all__ = [
    "COMMAND_ID",
    "HEARTBEAT_ID",
    "TELEMETRY_ID",
    "Command",
    "Heartbeat",
    "ProtocolError",
    "Telemetry",
    "dbc_sha256",
    "decode",
    "encode",
]

COMMAND_ID, TELEMETRY_ID, HEARTBEAT_ID = 0x100, 0x180, 0x700
BITRATE = 1_000_000
MAX_NODE_ID = 15
REJECTED_BIT = 0x10  # heartbeat Faults: a setpoint beyond the wheel's limits was refused


@cache
def database() -> cantools.database.Database:
    """The parsed ``rw.dbc``."""
    text = resources.files(__package__).joinpath("rw.dbc").read_text()
    return cast(cantools.database.Database, cantools.database.load_string(text, "dbc"))


def dbc_sha256() -> str:
    """SHA-256 of ``rw.dbc``, recorded in testbed files so a record names its protocol.

    Returns
    -------
    str
        Hexadecimal digest.
    """
    return hashlib.sha256(resources.files(__package__).joinpath("rw.dbc").read_bytes()).hexdigest()


@dataclass(frozen=True)
class Command:
    """A host command.

    Parameters
    ----------
    node_id : int
        The wheel addressed.
    mode : Mode
        IDLE, SPEED or ACCELERATION.
    setpoint : float
        rpm (SPEED) or rpm/s (ACCELERATION).
    sequence : int
        The command's sequence number (the wheel echoes it).
    """

    node_id: int
    mode: Mode
    setpoint: float
    sequence: int


@dataclass(frozen=True)
class Telemetry:
    """A wheel's telemetry frame.

    Parameters
    ----------
    node_id : int
        The wheel that sent it.
    speed_rpm : float
        Measured speed, rpm.
    current : float
        Motor current, A.
    mode : Mode
        The mode the wheel is in.
    fault_active : bool
        A fault is latched (see the heartbeat).
    speed_limited : bool
        The speed limit is holding the wheel.
    sequence_echo : int
        The sequence number of the last command applied.
    counter : int
        The frame counter (a gap is a lost frame).
    """

    node_id: int
    speed_rpm: float
    current: float
    mode: Mode
    fault_active: bool
    speed_limited: bool
    sequence_echo: int
    counter: int


@dataclass(frozen=True)
class Heartbeat:
    """A wheel's status frame.

    Parameters
    ----------
    node_id, mode
        As for :class:`Telemetry`.
    faults : Fault
        The latched faults.
    temperature : float
        Motor temperature, °C.
    uptime : int
        Seconds since power-on.
    commands_seen : int
        Commands received.
    bus_voltage : float
        Supply voltage, V (the field's floor, 10 V, when the sender has none).
    command_rejected : bool
        The wheel refused a setpoint beyond its limits since the last CLEAR_FAULT (the
        motor kept its previous command).
    """

    node_id: int
    mode: Mode
    faults: Fault
    temperature: float
    uptime: int
    commands_seen: int
    bus_voltage: float = 10.0  # V; the field's floor (10 V) when the sender has none
    command_rejected: bool = False


def check_node(node_id: int) -> int:
    """A CAN node id, checked (every protocol's node and client call this).

    Parameters
    ----------
    node_id : int
        0 … ``MAX_NODE_ID``.

    Returns
    -------
    int
        ``node_id`` itself.

    Raises
    ------
    ProtocolError
        Not an integer in range.
    """
    if not isinstance(node_id, int) or not 0 <= node_id <= MAX_NODE_ID:
        raise ProtocolError(f"node id must be an integer 0..{MAX_NODE_ID}, got {node_id!r}")
    return node_id


def crc8_sae_j1850(data: bytes, crc: int = 0xFF) -> int:
    """CRC-8/SAE-J1850 of ``data`` (poly 0x1D, init 0xFF, final XOR 0xFF).

    Parameters
    ----------
    data : bytes
        The bytes to protect.
    crc : int
        Initial register value (0xFF for the standard CRC).

    Returns
    -------
    int
        The CRC, 0..255.
    """
    for byte in data:
        crc = _CRC8_TABLE[(crc ^ byte) & 0xFF]
    return crc ^ 0xFF


def _crc8_shifts(crc: int) -> int:
    """The CRC-8/SAE-J1850 register after its 8 shifts of one byte (poly 0x1D, MSB first)."""
    for _ in range(8):
        crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


# the register after each byte value, so a byte costs one look-up, not 8 shifts (the
# frame check runs on every frame the twins and the clients exchange)
_CRC8_TABLE = tuple(_crc8_shifts(i) for i in range(256))


def frame_crc(arbitration_id: int, data: bytes | bytearray) -> int:
    """The wheel protocol's byte-7 check: CRC-8/SAE-J1850 over the 11-bit id and bytes 0..6.

    Parameters
    ----------
    arbitration_id : int
        The frame's 11-bit id (its two bytes, little-endian, open the CRC).
    data : bytes
        At least 7 bytes; bytes 0..6 are covered.

    Returns
    -------
    int
        The check byte, 0..255.
    """
    return crc8_sae_j1850(arbitration_id.to_bytes(2, "little") + bytes(data[:7]))


MESSAGES = {COMMAND_ID: "RW_Command", TELEMETRY_ID: "RW_Telemetry", HEARTBEAT_ID: "RW_Heartbeat"}


def encode(message: Command | Telemetry | Heartbeat) -> can.Message:
    """CAN frame for a command, telemetry (speed and current clipped to their fields) or a
    heartbeat; raises ProtocolError for values the frame cannot carry.

    Parameters
    ----------
    message : Command, Telemetry or Heartbeat
        What to send.

    Returns
    -------
    can.Message
    """
    m = message
    if isinstance(m, Command):
        if not math.isfinite(m.setpoint) or abs(m.setpoint) > 1e6:
            raise ProtocolError(f"setpoint must be finite and within ±1e6, got {m.setpoint}")
        base = COMMAND_ID
        signals = {
            "Setpoint": float(m.setpoint),
            "Mode": int(m.mode),
            "Sequence": m.sequence & 0xFF,
        }
    elif isinstance(m, Telemetry):
        base = TELEMETRY_ID
        signals = {
            "Speed": max(-83886.08, min(83886.07, round(m.speed_rpm, 2))),
            "Current": max(-2.048, min(2.047, round(m.current, 3))),
            "Mode": int(m.mode) & 0x3,
            "FaultActive": int(m.fault_active),
            "SpeedLimited": int(m.speed_limited),
            "SequenceEcho": m.sequence_echo & 0xFF,
            "Counter": m.counter & 0xFF,
        }
    else:
        base = HEARTBEAT_ID
        signals = {
            "Mode": int(m.mode) & 0x3,
            "BusVoltage": max(10.0, min(41.5, round(m.bus_voltage * 2) / 2)),
            "Faults": (int(m.faults) & 0xF) | (REJECTED_BIT if m.command_rejected else 0),
            "Temperature": max(-40.0, min(87.5, round(m.temperature * 2) / 2)),
            "Uptime": min(int(m.uptime), 0xFFFF),
            "CommandsSeen": int(m.commands_seen) & 0xFFFF,
        }
    frame_id = base + check_node(m.node_id)
    data = bytearray(
        database().get_message_by_name(MESSAGES[base]).encode({**signals, "Checksum": 0})
    )
    data[7] = frame_crc(frame_id, bytes(data))
    return can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)


def decode(msg: can.Message) -> Command | Telemetry | Heartbeat | None:
    """Decode a frame; None for frames of other protocols; ProtocolError for damaged ones.

    Parameters
    ----------
    msg : can.Message
        A received frame.

    Returns
    -------
    Command, Telemetry, Heartbeat or None
    """
    if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
        return None
    base, node = msg.arbitration_id & ~0xF, msg.arbitration_id & 0xF
    if base not in MESSAGES:
        return None
    data = bytes(msg.data)
    if len(data) != 8:
        raise ProtocolError(f"frame 0x{msg.arbitration_id:03X} has {len(data)} bytes, expected 8")
    if frame_crc(msg.arbitration_id, data) != data[7]:
        raise ProtocolError(f"frame 0x{msg.arbitration_id:03X} fails its checksum")
    decoded = database().get_message_by_name(MESSAGES[base]).decode(data, decode_choices=False)
    s = cast(Mapping[str, float], decoded)  # numbers only: choices are not decoded
    try:
        if base == COMMAND_ID:
            if not math.isfinite(s["Setpoint"]):
                raise ProtocolError("command setpoint is not a finite number")
            return Command(node, Mode(int(s["Mode"])), float(s["Setpoint"]), int(s["Sequence"]))
        if base == TELEMETRY_ID:
            return Telemetry(
                node,
                float(s["Speed"]),
                float(s["Current"]),
                Mode(int(s["Mode"])),
                bool(s["FaultActive"]),
                bool(s["SpeedLimited"]),
                int(s["SequenceEcho"]),
                int(s["Counter"]),
            )
        return Heartbeat(
            node,
            Mode(int(s["Mode"])),
            Fault(int(s["Faults"]) & 0xF),
            float(s["Temperature"]),
            int(s["Uptime"]),
            int(s["CommandsSeen"]),
            float(s["BusVoltage"]),
            bool(int(s["Faults"]) & REJECTED_BIT),
        )
    except ValueError as exc:  # an out-of-range enum value
        raise ProtocolError(f"frame 0x{msg.arbitration_id:03X}: {exc}") from None
