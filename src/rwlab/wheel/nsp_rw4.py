"""NSP profile ``rw4-12``: the Rocket Lab / Sinclair Interplanetary RW4-12 wheel, twin and driver.

Rocket Lab's software ICD (E400281) is not public. This profile follows what an
open driver written and run against a real RW4-12 after that ICD does:
github.com/Rivercraft911/rxnReflect (``rw_wheel/driver.py``, June 2025; read,
not copied). Framing and CRC: :mod:`rwlab.wheel.nsp_wire` (the reflected
CCITT CRC the driver computes with ``crcmod``'s ``rev=True``).

- Host 0x11, wheel ``0x20 + node_id`` (the driver's configured wheel is 0x20);
  115200 baud, the driver's line speed.
- PING: ACK with an ASCII identity text.
- INIT ``[uint32 start address]``: ACK (the twin is always in its application).
- WRITE-FILE 0x08 ``[0x00][mode][float32]``: file 0x00 is the command; modes
  IDLE 0x00, SPEED 0x03 (rad/s), MOMENTUM 0x11 (N·m·s), TORQUE 0x12 (N·m).
- READ-FILE 0x07 ``[file]`` → ``[file][float32]``, SI units, on the EDAC file
  map: 0x03 bus voltage (V), 0x08 +3.3 V rail (V), 0x10–0x13 temperatures (°C),
  0x15 speed (rad/s), 0x16 momentum (N·m·s), 0x1F motor current (A), 0x28
  rotor inertia (kg·m²).
- Little-endian float32 (the driver's ``struct`` format ``<Bf``).

Open in the public sources, chosen here and listed in ``docs/wheels/nsp.md``:
fault reporting and clearing (the twin accepts CLEAR-FAULT 0x09, and keeps
its mode, faults and flags in file 0x40, an rwlab extension a real RW4-12 would
NACK: the driver then reports no faults), the NACK cases (an unknown file or
mode, a wrong length, a non-finite or out-of-range setpoint: never applied).
"""

from __future__ import annotations

import math
import struct
from typing import Any

from rwlab.wheel import protocol as proto
from rwlab.wheel.link import Clock, WheelProtocol
from rwlab.wheel.nsp_wire import (
    NACK,
    NspHostLinkBase,
    NspNodeLinkBase,
    NspPacket,
    Verdict,
    setpoint_allowed,
)
from rwlab.wheel.physics import Fault, Mode, rad_s_to_rpm, rpm_to_rad_s

__all__ = ["Rw412HostLink", "Rw412NodeLink", "Rw412Protocol", "wheel_address"]

PING, INIT, READ_FILE, WRITE_FILE, CLEAR_FAULT = 0x00, 0x01, 0x07, 0x08, 0x09
IDLE, SPEED, MOMENTUM, TORQUE = 0x00, 0x03, 0x11, 0x12
COMMAND_FILE = 0x00
VBUS, VCC, TEMP0, TEMP3, SPEED_FILE, MOMENTUM_FILE = 0x03, 0x08, 0x10, 0x13, 0x15, 0x16
CURRENT_FILE, INERTIA_FILE = 0x1F, 0x28
STATUS_FILE = 0x40  # rwlab's extension: bits 0..3 faults, 4 speed limited, 5 refused, 8..15 mode
FLOAT = struct.Struct("<f")
PING_TEXT = b"rwlab RW4-12 twin"
_FROM_RW4 = {IDLE: Mode.IDLE, SPEED: Mode.SPEED, MOMENTUM: Mode.SPEED, TORQUE: Mode.ACCELERATION}
_TO_RW4 = {Mode.IDLE: IDLE, Mode.SPEED: SPEED, Mode.ACCELERATION: TORQUE}
FLOAT32_MAX = 3.4028234663852886e38


def wheel_address(node_id: int) -> int:
    """The NSP address of RW4-12 ``node_id`` (0..15): ``0x20 + node_id``.

    Parameters
    ----------
    node_id : int

    Returns
    -------
    int
    """
    return 0x20 + proto.check_node(node_id)


class Rw412NodeLink(NspNodeLinkBase):
    """The twin's end: an RW4-12 answering PING, INIT, READ-FILE, WRITE-FILE, CLEAR-FAULT.

    Parameters
    ----------
    port, node_id, clock
        As for :class:`rwlab.wheel.nsp_wire.NspNodeLinkBase` (the twin's clock).
    """

    def __init__(self, port: Any, node_id: int, clock: Clock) -> None:
        super().__init__(port, node_id, clock)
        self.address = wheel_address(node_id)
        self.mode_byte = IDLE
        self.speed_rad_s = self.current_a = 0.0
        self.temperature, self.bus_voltage = 20.0, 0.0
        self.faults = Fault.NONE
        self.speed_limited = self.refused = False

    def addresses(self) -> tuple[int, ...]:
        return (self.address,)

    def handle(self, packet: NspPacket) -> Verdict:
        data, code = packet.payload, packet.command
        if code == PING and not data:
            return Verdict(True, PING_TEXT)
        if code == INIT and len(data) in (0, 4):
            return Verdict(True)
        if code == READ_FILE and len(data) == 1:
            value = self._file(data[0])
            return NACK if value is None else Verdict(True, data[:1] + FLOAT.pack(value))
        if code == WRITE_FILE and len(data) == 6 and data[0] == COMMAND_FILE:
            return self._write_command(data[1], FLOAT.unpack(data[2:])[0])
        if code == CLEAR_FAULT and not data:
            self.refused = False
            return Verdict(True, b"", self.command(Mode.CLEAR_FAULT, 0.0))
        return NACK  # PEEK, POKE and the rest: not in the public map; malformed requests

    def _write_command(self, mode_byte: int, value: float) -> Verdict:
        if mode_byte not in _FROM_RW4:
            return NACK
        inertia = self.params.inertia
        rad_s = {SPEED: value, MOMENTUM: value / inertia, TORQUE: value / inertia}.get(mode_byte, 0)
        command = self.command(_FROM_RW4[mode_byte], rad_s_to_rpm(rad_s))
        if not setpoint_allowed(self.params, command.mode, command.setpoint):
            self.refused = True
            return Verdict(False, b"", command)
        self.mode_byte = mode_byte
        return Verdict(True, b"", command)

    def _file(self, file: int) -> float | None:
        files = {
            VBUS: self.bus_voltage,
            VCC: 3.3,  # a rail the twin does not model: its nominal value
            SPEED_FILE: self.speed_rad_s,
            MOMENTUM_FILE: self.params.inertia * self.speed_rad_s,
            CURRENT_FILE: self.current_a,
            INERTIA_FILE: self.params.inertia,
            STATUS_FILE: float(
                int(self.faults) | self.speed_limited << 4 | self.refused << 5 | self.mode_byte << 8
            ),
        }
        if TEMP0 <= file <= TEMP3:
            return self.temperature  # one temperature in the twin: all four sensors read it
        return files.get(file)

    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        """Update the files (an RW4-12 answers polls; it does not stream)."""
        if isinstance(frame, proto.Telemetry):
            self.speed_rad_s = rpm_to_rad_s(frame.speed_rpm)
            self.current_a, self.speed_limited = frame.current, frame.speed_limited
            if frame.fault_active:
                self.mode_byte = IDLE  # a latched fault idles the wheel
        else:
            self.faults, self.temperature = frame.faults, frame.temperature
            self.bus_voltage = frame.bus_voltage
        self.corrupt_next_reply(corrupt)


class Rw412HostLink(NspHostLinkBase):
    """The driver's end: WRITE-FILE for modes, READ-FILE of speed and current polled.

    Parameters
    ----------
    port, node_id, clock, poll_rate
        As for :class:`rwlab.wheel.nsp_wire.NspHostLinkBase`.
    """

    wheel_address = staticmethod(wheel_address)

    def __init__(self, port: Any, node_id: int, clock: Clock, poll_rate: float = 10.0) -> None:
        super().__init__(port, node_id, clock, poll_rate)
        self._status = 0
        self._status_file = True  # rwlab's extension file 0x40, until the wheel NACKs it
        self._opened = clock.now()

    def encode_command(self, cmd: proto.Command) -> tuple[int, bytes]:
        if cmd.mode == Mode.CLEAR_FAULT:
            return CLEAR_FAULT, b""
        value = 0.0
        if cmd.mode == Mode.SPEED:
            value = rpm_to_rad_s(cmd.setpoint)
        elif cmd.mode == Mode.ACCELERATION:
            value = self.params.inertia * rpm_to_rad_s(cmd.setpoint)  # N·m
        if not (math.isfinite(value) and abs(value) <= FLOAT32_MAX):
            raise proto.ProtocolError(f"an RW4-12 setpoint must be a finite float32, got {value}")
        return WRITE_FILE, bytes([COMMAND_FILE, _TO_RW4[cmd.mode]]) + FLOAT.pack(value)

    def read_file(self, file: int) -> float | None:
        """One READ-FILE: the file's float32, or None on a NACK, a missing or a wrong reply.

        Parameters
        ----------
        file : int
            The EDAC file number.

        Returns
        -------
        float or None
        """
        reply = self.transact(READ_FILE, bytes([file]))
        if reply is None or not reply.acked or len(reply.payload) != 5 or reply.payload[0] != file:
            return None
        return float(FLOAT.unpack(reply.payload[1:])[0])

    def read_telemetry(self) -> proto.Telemetry | None:
        speed, current = self.read_file(SPEED_FILE), self.read_file(CURRENT_FILE)
        if speed is None or current is None:
            return None
        status = self.read_file(STATUS_FILE) if self._status_file else None
        self._status_file = status is not None  # a real RW4-12 NACKs it: ask once
        self._status = int(status) if status is not None and math.isfinite(status) else 0
        mode = _FROM_RW4.get(self._status >> 8 & 0xFF, Mode.IDLE)
        return self.telemetry(
            rad_s_to_rpm(speed), current, mode, bool(self._status & 0xF), bool(self._status & 16)
        )

    def read_heartbeat(self, telemetry: proto.Telemetry) -> proto.Heartbeat | None:
        temperature, bus_voltage = self.read_file(TEMP0), self.read_file(VBUS)
        if temperature is None or bus_voltage is None:
            return None
        return proto.Heartbeat(
            self.node_id,
            telemetry.mode,
            Fault(self._status & 0xF),
            temperature,
            int(self.clock.now() - self._opened),  # no uptime file in the public map
            self.acked_commands & 0xFFFF,
            bus_voltage=bus_voltage,
            command_rejected=self._rejected or bool(self._status & 32),
        )


class Rw412Protocol(WheelProtocol):
    """NSP as the Rocket Lab / Sinclair RW4-12 speaks it (READ-FILE / WRITE-FILE, float32 SI)."""

    name = "nsp/rw4-12"
    description = "NSP, Rocket Lab RW4-12 profile: READ-FILE/WRITE-FILE, float32 SI, 115200 baud"
    transports = ("stream",)
    baudrate = 115_200
    poll_rate = 10.0

    def host_link(self, transport: Any, node_id: int, *, clock: Clock) -> Rw412HostLink:
        return Rw412HostLink(transport, node_id, clock, self.poll_rate)

    def node_link(self, transport: Any, node_id: int, *, clock: Clock) -> Rw412NodeLink:
        return Rw412NodeLink(transport, node_id, clock)

    def addresses(self, node_id: int) -> str:
        return f"NSP address 0x{wheel_address(node_id):02X}"
