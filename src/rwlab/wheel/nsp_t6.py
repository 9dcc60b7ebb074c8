"""NSP profile ``nrwa-t6``: the NewSpace Systems NRWA-T6 wheel's protocol, twin and driver.

Learnt from NewSpace Systems, *NRWA-T6 Interface Control Document*,
N2-A2a-DD0021 rev 10.02 (2023-12-18) §10.2.7, §11, §12 (the PDF ships with
github.com/ryan-rbw/nsrw_test), and cross-checked with the open emulator
github.com/ryan-rbw/nsrw_emu and its host github.com/ryan-rbw/nsrw_test
(``nss_host``). Written here; nothing copied. Framing and CRC:
:mod:`rwlab.wheel.nsp_wire`.

- RS-485, 8-N-1 at 460.8 kbit/s (:attr:`NrwaT6Protocol.baudrate`).
- Addresses: wheel ``node_id`` (0..7, the three ADDR pins) answers on ``node_id``
  (main port) and ``node_id + 0x80`` (redundant port); the host is 0x11.
- PING: ACK with ``[device type][serial][fw major][fw minor][fw patch]``.
- PEEK ``[addr]`` → the 32-bit word; POKE ``[addr][word]``; addresses
  0x00–0x30 (the initialised parameters), anything else NACKed.
- APPLICATION-TELEMETRY 0x07 ``[block]``: STANDARD (25 bytes: status, latched
  faults, control mode, setpoint, PWM duty, current target Q14.2 mA, current
  Q20.12 mA, speed Q24.8 rpm), TEMPERATURES (raw NTC codes), VOLTAGES and
  CURRENTS (UQ16.16), DIAGNOSTICS-GENERAL (uptime UQ30.2 s, revolutions),
  -EDAC, -SCIA, -SCIB (counters).
- APPLICATION-COMMAND 0x08 ``[control mode][setpoint int32]``: IDLE 0b0000,
  CURRENT 0b0001 (Q14.18 mA), SPEED 0b0010 (Q14.18 rpm), TORQUE 0b0100
  (Q10.22 mN·m), PWM 0b1000; any other value means IDLE (Table 12-25). The
  reply carries the control-mode register.
- CLEAR-FAULT 0x09 ``[mask uint32]`` clears the latched fault bits in the mask.
- CONFIGURE-PROTECTION 0x0A ``[bits uint32]``: 1 disables a protection; the
  status register's bits 17-21 show them.
- Little-endian throughout; Q formats in AMD notation (the sign bit counted in
  the integer bits).

Where the ICD is open or the twin differs, the choice is in
``docs/wheels/nsp.md`` (with the item-by-item comparison): the twin NACKs
CURRENT and PWM (it has no current loop or open PWM), INIT and CRC (not
implemented by the NRWA-T6 either), TRIP-LCL (it cannot cut its own power) and
a CONFIGURE-PROTECTION that would disable the overspeed fault, the overspeed
limit or the current limit (its physics always applies them); a setpoint beyond
the twin's limits is NACKed and never applied (an NRWA-T6 would limit it).
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

__all__ = ["NrwaT6HostLink", "NrwaT6NodeLink", "NrwaT6Protocol", "q_decode", "q_encode"]

PING, INIT, PEEK, POKE, CRC = 0x00, 0x01, 0x02, 0x03, 0x06
APP_TELEMETRY, APP_COMMAND, CLEAR_FAULT, CONFIGURE_PROTECTION = 0x07, 0x08, 0x09, 0x0A
IDLE, CURRENT, SPEED, TORQUE, PWM = 0x0, 0x1, 0x2, 0x4, 0x8
STANDARD, TEMPERATURES, VOLTAGES, CURRENTS = 0x00, 0x01, 0x02, 0x03
DIAG_GENERAL, DIAG_EDAC, DIAG_SCIA, DIAG_SCIB = 0x04, 0x05, 0x06, 0x07
STANDARD_BLOCK = struct.Struct("<IIBihhii")  # 25 bytes, Table 12-13
REDUNDANT_PORT = 0x80
DEVICE_TYPE = 0x06  # the ICD leaves the number open; nsrw_emu's choice
FIRMWARE = (1, 0, 0)

# Status register (Table 12-14)
ST_RAM_BOOT, ST_OVERSPEED_LIMITED, ST_DIRECTION, ST_DRIVE_ON = 1 << 0, 1 << 4, 1 << 8, 1 << 9
ST_POWER_GOOD = 0x7F << 22  # the seven PGOOD flags, 1 = ok
ST_PROTECTION_SHIFT = 17  # bits 17-21: CONFIGURE-PROTECTION's bits 0-4, 1 = disabled
# CONFIGURE-PROTECTION (Table 12-29): bits 0-2 disable the overspeed fault, the overspeed
# limit and the current limit, which the twin's physics always applies; bits 3-4 the EDAC
# scrub and the braking load, which the twin does not model
PROTECTIONS_KEPT, PROTECTION_BITS = 0x07, 0x1F
# Fault register (Table 12-15); bits 30 and 31 are reserved in the ICD: the twin's
# over-current trip (the NRWA-T6 limits its current, §9.5, and has no such fault) and
# command watchdog
FT_DRIVE_FAULT, FT_OVERSPEED, FT_OVERSPEED_LIMITED = 1 << 0, 1 << 5, 1 << 6
FT_SLIP_ERROR, FT_CRC_ERROR = 1 << 11, 1 << 12
FT_OVERCURRENT, FT_WATCHDOG = 1 << 30, 1 << 31
_FAULT_BITS = {
    Fault.OVERTEMP: FT_DRIVE_FAULT,  # "an overtemperature shutdown event"
    Fault.OVERSPEED: FT_OVERSPEED,
    Fault.OVERCURRENT: FT_OVERCURRENT,
    Fault.WATCHDOG: FT_WATCHDOG,
}
# NTC conversion parameters (Table 12-16): (Rs, Rp, R25, beta), T25 = 298.15 K
_NTC_BOARD = (10e3, 100e3, 10e3, 3450.0)
_NTC_MOTOR = (5.1e3, 100e3, 5e3, 3490.0)
_NOMINAL_RAILS = (1.5, 3.3, 5.0, 12.0)  # V, the rails the twin does not model
_TO_T6 = {Mode.IDLE: IDLE, Mode.SPEED: SPEED, Mode.ACCELERATION: TORQUE}
MIN_PEEK, MAX_PEEK = 0x00, 0x30


def q_encode(value: float, frac_bits: int, bits: int = 32, signed: bool = True) -> int:
    """A number as a Q fixed-point word (AMD notation: Q14.18 is 32 bits, sign included).

    Parameters
    ----------
    value : float
        In the field's unit.
    frac_bits : int
        Fraction bits (18 for Q14.18).
    bits : int
        Word length, 16 or 32.
    signed : bool
        Two's complement (Q) or unsigned (UQ).

    Returns
    -------
    int
        The word, 0 .. 2**bits - 1, rounded to nearest.

    Raises
    ------
    ProtocolError
        Not finite, or beyond the format's range.
    """
    if not math.isfinite(value):
        raise proto.ProtocolError(f"NRWA-T6 fixed-point field cannot carry {value!r}")
    raw = round(value * (1 << frac_bits))
    low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if not low <= raw <= high:
        scale = 1 << frac_bits
        raise proto.ProtocolError(
            f"{value:g} is beyond the NRWA-T6 field's range {low / scale:g}..{high / scale:g}"
        )
    return raw & ((1 << bits) - 1)


def q_decode(raw: int, frac_bits: int, bits: int = 32, signed: bool = True) -> float:
    """The number a Q fixed-point word holds (inverse of :func:`q_encode`).

    Parameters
    ----------
    raw : int
        The word as an unsigned integer.
    frac_bits, bits, signed
        As :func:`q_encode`.

    Returns
    -------
    float
    """
    if signed and raw & (1 << (bits - 1)):
        raw -= 1 << bits
    return raw / (1 << frac_bits)


def _clamped_q(value: float, frac_bits: int, bits: int = 32, signed: bool = True) -> int:
    """A measurement in a Q field, saturated at the field's range (as an ADC saturates)."""
    top = ((1 << (bits - 1)) - 1 if signed else (1 << bits) - 1) / (1 << frac_bits)
    low = -top if signed else 0.0
    return q_encode(min(max(value, low), top), frac_bits, bits, signed)


def ntc_code(temperature_c: float, ntc: tuple[float, float, float, float]) -> int:
    """The 12-bit raw value of a thermistor at ``temperature_c`` (ICD eq. 1 and 2 inverted).

    Parameters
    ----------
    temperature_c : float
        °C.
    ntc : tuple
        (Rs, Rp, R25 in Ω, beta in K).

    Returns
    -------
    int
        0..4095.
    """
    rs, rp, r25, beta = ntc
    r_th = r25 * math.exp(beta * (1 / (temperature_c + 273.15) - 1 / 298.15))
    return min(4095, max(0, round(4096 * r_th * rp / (rp * rs + r_th * (rp + rs)))))


def ntc_temperature(code: int, ntc: tuple[float, float, float, float]) -> float:
    """The temperature a thermistor's raw value means, °C (ICD eq. 1 and 2).

    Parameters
    ----------
    code : int
        The raw 12-bit value.
    ntc : tuple
        (Rs, Rp, R25 in Ω, beta in K).

    Returns
    -------
    float
        °C; NaN for a code outside the divider's range.
    """
    rs, rp, r25, beta = ntc
    denominator = 4096 * rp - code * rp - code * rs
    if code <= 0 or denominator <= 0:
        return math.nan
    r_th = code * rp * rs / denominator
    return 1 / (math.log(r_th / r25) / beta + 1 / 298.15) - 273.15


def wheel_address(node_id: int) -> int:
    """The NRWA-T6 main-port address of wheel ``node_id`` (its ADDR pins), 0..7.

    Parameters
    ----------
    node_id : int

    Returns
    -------
    int
    """
    if not isinstance(node_id, int) or not 0 <= node_id <= 7:
        raise proto.ProtocolError(
            f"an NRWA-T6 address is set by three pins: use node id 0..7, not {node_id!r}"
        )
    return node_id


class NrwaT6NodeLink(NspNodeLinkBase):
    """The twin's end: an NRWA-T6 answering on ``node_id`` and ``node_id + 0x80``.

    Parameters
    ----------
    port, node_id, clock
        As for :class:`rwlab.wheel.nsp_wire.NspNodeLinkBase` (the twin's clock).
    """

    def __init__(self, port: Any, node_id: int, clock: Clock) -> None:
        super().__init__(port, node_id, clock)
        self.address = wheel_address(node_id)
        self.control_register = IDLE
        self.setpoint_word = 0
        self.status = ST_RAM_BOOT | ST_POWER_GOOD
        self.faults = 0
        self.speed_rpm = self.current_a = self.temperature = 0.0
        self.bus_voltage = 0.0
        self.uptime = 0
        self.revolutions = 0.0
        self._last_telemetry_t: float | None = None
        self.memory = {address: 0 for address in range(MIN_PEEK, MAX_PEEK + 1)}

    def configure(self, params: Any) -> None:
        """Limits and identity words from the wheel's parameters."""
        super().configure(params)
        self.memory.update(
            {
                0x00: 1,  # serial number
                0x01: DEVICE_TYPE,
                0x02: FIRMWARE[0],
                0x03: FIRMWARE[1],
                0x04: FIRMWARE[2],
                0x05: q_encode(36.0, 16, signed=False),  # +30 V drive overvoltage limit, V
                0x06: _clamped_q(params.overspeed_fault_rpm, 8, signed=False),
                0x07: _clamped_q(params.max_speed_rpm, 18, signed=False),
                0x08: q_encode(100e3, 14, signed=False),  # motor power limit, mW
                0x09: _clamped_q(params.current_limit * 1000, 14, signed=False),
                0x20: q_encode(31.0, 16),  # braking overvoltage load setpoint, V (§9.5.2.1)
            }
        )

    def addresses(self) -> tuple[int, ...]:
        return (self.address, self.address | REDUNDANT_PORT)

    def note_bad_frame(self, slip_error: bool) -> None:
        self.faults |= FT_SLIP_ERROR if slip_error else FT_CRC_ERROR  # port A, latched

    def handle(self, packet: NspPacket) -> Verdict:
        data, code = packet.payload, packet.command
        if code == PING and not data:
            return Verdict(True, bytes([DEVICE_TYPE, self.memory[0x00] & 0xFF, *FIRMWARE]))
        if code == PEEK and len(data) == 1 and data[0] in self.memory:
            return Verdict(True, self.memory[data[0]].to_bytes(4, "little"))
        if code == POKE and len(data) == 5 and data[0] in self.memory:
            self.memory[data[0]] = int.from_bytes(data[1:], "little")
            return Verdict(True)
        if code == APP_TELEMETRY and len(data) == 1:
            block = self._block(data[0])
            return NACK if block is None else Verdict(True, block)
        if code == APP_COMMAND and len(data) == 5:
            return self._app_command(data[0], int.from_bytes(data[1:], "little", signed=True))
        if code == CLEAR_FAULT and len(data) == 4:
            return self._clear(int.from_bytes(data, "little"))
        if code == CONFIGURE_PROTECTION and len(data) == 4:
            return self._configure_protection(int.from_bytes(data, "little"))
        return NACK  # INIT, CRC, TRIP-LCL, reserved, malformed

    def _app_command(self, register: int, word: int) -> Verdict:
        mode_id = register & 0x0F
        if mode_id in (CURRENT, PWM):  # no current loop or open PWM in the twin
            return Verdict(False, bytes([self.control_register]))
        if mode_id == SPEED:
            command = self.command(Mode.SPEED, q_decode(word & 0xFFFFFFFF, 18))
        elif mode_id == TORQUE:
            torque = q_decode(word & 0xFFFFFFFF, 22) / 1000  # mN·m → N·m
            command = self.command(Mode.ACCELERATION, rad_s_to_rpm(torque / self.params.inertia))
        else:  # 0b0000 or any value Table 12-25 does not define: IDLE
            command, register = self.command(Mode.IDLE, 0.0), register & 0xF0
        if not setpoint_allowed(self.params, command.mode, command.setpoint):
            return Verdict(False, bytes([self.control_register]), command)
        self.control_register, self.setpoint_word = register, word
        return Verdict(True, bytes([register]), command)

    def _clear(self, mask: int) -> Verdict:
        wheel_bits = FT_DRIVE_FAULT | FT_OVERSPEED | FT_OVERCURRENT | FT_WATCHDOG
        latched = self.faults & wheel_bits & mask
        self.faults &= ~mask
        # the twin clears all its latched faults at once; only when one is asked for
        return Verdict(True, b"", self.command(Mode.CLEAR_FAULT, 0.0) if latched else None)

    def _configure_protection(self, bits: int) -> Verdict:
        if bits & PROTECTIONS_KEPT:  # the twin cannot fly without them: not executed
            return NACK
        kept = self.status & ~(PROTECTION_BITS << ST_PROTECTION_SHIFT)
        self.status = kept | (bits & PROTECTION_BITS) << ST_PROTECTION_SHIFT
        return Verdict(True)

    def _rail_current(self) -> float:
        """The +30 V rail's current, A: the motor's electrical power over the rail voltage."""
        p = self.params
        emf = p.torque_constant * rpm_to_rad_s(self.speed_rpm)
        power = (p.winding_resistance * self.current_a + emf) * self.current_a
        return max(power, 0.0) / self.bus_voltage if self.bus_voltage > 0 else 0.0

    def _block(self, block: int) -> bytes | None:
        if block == STANDARD:
            return STANDARD_BLOCK.pack(
                self.status,
                self.faults,
                self.control_register,
                self.setpoint_word,
                0,  # PWM duty: the twin's driver has no PWM stage
                _signed(_clamped_q(self.current_a * 1000, 2, 16), 16),
                _signed(_clamped_q(self.current_a * 1000, 12)),
                _signed(_clamped_q(self.speed_rpm, 8)),
            )
        if block == TEMPERATURES:
            board = ntc_code(self.temperature, _NTC_BOARD)
            return struct.pack("<4H", board, board, board, ntc_code(self.temperature, _NTC_MOTOR))
        if block == VOLTAGES:
            rails = (*_NOMINAL_RAILS, self.bus_voltage, 2.5)
            return b"".join(_clamped_q(v, 16, signed=False).to_bytes(4, "little") for v in rails)
        if block == CURRENTS:
            rail = _signed(_clamped_q(self._rail_current(), 16))
            return struct.pack("<5Ii", 0, 0, 0, 0, 0, rail)
        if block == DIAG_GENERAL:
            uptime = _clamped_q(self.uptime, 2, signed=False)
            return struct.pack("<5I", uptime, int(self.revolutions) & 0xFFFFFFFF, 0, 0, 0)
        if block == DIAG_EDAC:
            return bytes(20)
        if block in (DIAG_SCIA, DIAG_SCIB):
            if block == DIAG_SCIB:
                return bytes(16)
            counts = (self.bytes_received, self.bytes_sent, self.messages_received, self.bad_frames)
            return struct.pack("<4I", *(c & 0xFFFFFFFF for c in counts))
        return None

    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        """Update the registers (an NRWA-T6 answers polls; it does not stream)."""
        if isinstance(frame, proto.Telemetry):
            if self._last_telemetry_t is not None:
                self.revolutions += abs(frame.speed_rpm) / 60 * (t - self._last_telemetry_t)
            self._last_telemetry_t = t
            self.speed_rpm, self.current_a = frame.speed_rpm, frame.current
            status = self.status & (PROTECTION_BITS << ST_PROTECTION_SHIFT)
            status |= ST_RAM_BOOT | ST_POWER_GOOD
            status |= ST_OVERSPEED_LIMITED if frame.speed_limited else 0
            status |= ST_DIRECTION if frame.speed_rpm < 0 else 0
            status |= ST_DRIVE_ON if frame.mode != Mode.IDLE else 0
            self.status = status
            self.faults |= FT_OVERSPEED_LIMITED if frame.speed_limited else 0
            if frame.fault_active:  # a latched fault idles the wheel: the register says so
                self.control_register &= 0xF0
                self.setpoint_word = 0
        else:
            for fault, bit in _FAULT_BITS.items():
                self.faults |= bit if frame.faults & fault else 0
            self.temperature, self.uptime = frame.temperature, frame.uptime
            self.bus_voltage = frame.bus_voltage
        self.corrupt_next_reply(corrupt)


def _signed(word: int, bits: int = 32) -> int:
    return word - (1 << bits) if word & (1 << (bits - 1)) else word


class NrwaT6HostLink(NspHostLinkBase):
    """The driver's end: APPLICATION-COMMAND for modes, APPLICATION-TELEMETRY polled.

    Parameters
    ----------
    port, node_id, clock, poll_rate
        As for :class:`rwlab.wheel.nsp_wire.NspHostLinkBase`.
    """

    wheel_address = staticmethod(wheel_address)

    def __init__(self, port: Any, node_id: int, clock: Clock, poll_rate: float = 10.0) -> None:
        super().__init__(port, node_id, clock, poll_rate)
        self._faults = 0

    def encode_command(self, cmd: proto.Command) -> tuple[int, bytes]:
        if cmd.mode == Mode.CLEAR_FAULT:
            return CLEAR_FAULT, (0xFFFFFFFF).to_bytes(4, "little")
        if cmd.mode == Mode.SPEED:
            word = q_encode(cmd.setpoint, 18)  # rpm
        elif cmd.mode == Mode.ACCELERATION:  # rpm/s → net torque, mN·m
            word = q_encode(self.params.inertia * rpm_to_rad_s(cmd.setpoint) * 1000, 22)
        else:
            word = 0
        return APP_COMMAND, bytes([_TO_T6[cmd.mode]]) + word.to_bytes(4, "little")

    def read_telemetry(self) -> proto.Telemetry | None:
        reply = self.transact(APP_TELEMETRY, bytes([STANDARD]))
        if reply is None or not reply.acked or len(reply.payload) != STANDARD_BLOCK.size:
            return None
        status, faults, register, _, _, _, current, speed = STANDARD_BLOCK.unpack(reply.payload)
        self._faults = faults
        mode = {SPEED: Mode.SPEED, TORQUE: Mode.ACCELERATION}.get(register & 0x0F, Mode.IDLE)
        return self.telemetry(
            speed / 256,
            current / 4096 / 1000,
            mode,
            bool(self._wheel_faults()),
            bool(status & ST_OVERSPEED_LIMITED),
        )

    def _wheel_faults(self) -> Fault:
        return Fault(sum(f for f, bit in _FAULT_BITS.items() if self._faults & bit))

    def read_heartbeat(self, telemetry: proto.Telemetry) -> proto.Heartbeat | None:
        temps = self.transact(APP_TELEMETRY, bytes([TEMPERATURES]))
        volts = self.transact(APP_TELEMETRY, bytes([VOLTAGES]))
        diag = self.transact(APP_TELEMETRY, bytes([DIAG_GENERAL]))
        replies = (temps, volts, diag)
        if any(r is None or not r.acked for r in replies):
            return None
        assert temps is not None and volts is not None and diag is not None
        if (len(temps.payload), len(volts.payload), len(diag.payload)) != (8, 24, 20):
            return None
        motor_code = struct.unpack("<4H", temps.payload)[3]
        bus_voltage = q_decode(int.from_bytes(volts.payload[16:20], "little"), 16, signed=False)
        uptime = q_decode(int.from_bytes(diag.payload[:4], "little"), 2, signed=False)
        return proto.Heartbeat(
            self.node_id,
            telemetry.mode,
            self._wheel_faults(),
            ntc_temperature(motor_code, _NTC_MOTOR),
            int(uptime),
            self.acked_commands & 0xFFFF,
            bus_voltage=bus_voltage,
            command_rejected=self._rejected,
        )


class NrwaT6Protocol(WheelProtocol):
    """NSP as the NewSpace NRWA-T6 speaks it (ICD N2-A2a-DD0021 rev 10.02)."""

    name = "nsp/nrwa-t6"
    description = "NSP, NewSpace NRWA-T6 profile: RS-485 460.8 kbit/s, APP-TELEMETRY/COMMAND"
    transports = ("stream",)
    baudrate = 460_800
    poll_rate = 10.0
    wheel = "nrwa-t6"

    def host_link(self, transport: Any, node_id: int, *, clock: Clock) -> NrwaT6HostLink:
        return NrwaT6HostLink(transport, node_id, clock, self.poll_rate)

    def node_link(self, transport: Any, node_id: int, *, clock: Clock) -> NrwaT6NodeLink:
        return NrwaT6NodeLink(transport, node_id, clock)

    def addresses(self, node_id: int) -> str:
        address = wheel_address(node_id)
        return f"NSP address 0x{address:02X} (redundant port 0x{address | REDUNDANT_PORT:02X})"
