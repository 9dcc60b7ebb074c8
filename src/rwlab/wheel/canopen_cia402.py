"""The ``canopen/cia402`` profile: the wheel as a CiA 402 drive (profile velocity, profile torque).

Labs often spin a flywheel with a generic CANopen motor drive; those speak
CiA 402 (drives and motion control) on CiA 301. This profile makes the twin
such a drive, with its own object dictionary ``cia402_wheel.eds``, and gives
rwlab's driver the same language. Learnt from CiA 402 as the ``canopen``
package's ``canopen.profiles.p402`` implements it (``BaseNode402``: the
controlword commands, the statusword masks of each state, the transition
table, the operation-mode codes and the 0x6502 support bits); the code is ours.

Objects (CiA 402 indices; units as the drive defines them)
-----------------------------------------------------------
=======  ==============================  =====  ===========================================
index    name                            type   unit / meaning
=======  ==============================  =====  ===========================================
0x6040   Controlword                     U16    bits 0 switch on, 1 enable voltage, 2 quick
                                                stop (low active), 3 enable operation,
                                                7 fault reset (rising edge)
0x6041   Statusword                      U16    state bits (masks below), 4 voltage
                                                enabled, 9 remote, 10 target reached,
                                                11 internal limit active, 12 speed = 0
0x6060   Modes of operation              I8     0 none, 3 profile velocity, 4 profile torque
0x6061   Modes of operation display      I8     the mode in force
0x60FF   Target velocity                 I32    0.001 rpm (see 0x60A9)
0x606C   Velocity actual value           I32    0.001 rpm
0x6071   Target torque                   I16    ‰ of the motor rated torque 0x6076
0x6077   Torque actual value             I16    ‰ of 0x6076 (k_t × current)
0x6078   Current actual value            I16    ‰ of the motor rated current 0x6075
0x6075   Motor rated current             U32    mA (the wheel's current limit)
0x6076   Motor rated torque              U32    mN·m (the wheel's nominal torque)
0x6079   DC link circuit voltage         U32    mV
0x607F   Max profile velocity            U32    0.001 rpm (the wheel's speed limit)
0x6072   Max torque                      U16    ‰ of 0x6076
0x603F   Error code                      U16    CiA 301/402 error code of the active fault
0x6502   Supported drive modes           U32    0x0C: profile velocity (bit 2) and torque (3)
0x60A9   SI unit velocity                U32    0xFDB44700: 10^-3 rev/min
0x2001   Telemetry counter               U8     +1 each TPDO2 (rwlab's, for frame loss)
0x2002   Drive temperature               I16    0.1 °C
0x2003   Commands received               U16
0x2004   Uptime                          U16    s
0x2005   Fault bits                      U8     1 overspeed, 2 overcurrent, 4 watchdog,
                                                8 overtemperature, 0x10 a setpoint refused
=======  ==============================  =====  ===========================================

Velocity units: CiA 402 leaves them to the drive (a factor group or 0x60A9).
The twin uses 0.001 rpm and says so in 0x60A9 = 0xFDB44700 (prefix 10^-3,
rev, min), the encoding the Synapticon SOMANET and Nanotec drive manuals give
for "0.001 RPM"; 1 rpm (0x00B44700) would quantise a PRBS's small steps.

PDOs: RPDO1 (0x200 + id) controlword, mode, target velocity; RPDO2 (0x300 +
id) controlword, target torque; TPDO1 (0x180 + id) statusword, mode display,
velocity actual; TPDO2 (0x280 + id) torque, current, error code, counter;
TPDO3 (0x380 + id) temperature, commands, uptime, fault bits; TPDO4 (0x480 +
id) DC link voltage. TPDO1/2 follow their event timers (0x1800/0x1801 sub 5,
10 ms by default), TPDO3/4 at 1 s with the NMT heartbeat (0x700 + id).

State machine: switch on disabled → (shutdown 0x06) ready to switch on →
(switch on 0x07) switched on → (enable operation 0x0F) operation enabled; a
latched wheel fault → fault (EMCY sent); fault reset (bit 7 rising) → switch on
disabled. Operation enabled in profile velocity runs the wheel's speed loop on
0x60FF; in profile torque its torque command on 0x6071; leaving operation
enabled idles the wheel, except quick stop, which brakes to 0 rpm on the
wheel's own acceleration limit (quick stop option code 0x605A = 2) and stays
in quick stop active until disable voltage or enable operation.

Refusals: an SDO write of 0x60FF or 0x6071 beyond the wheel's limits is
aborted 0x06090031/0x06090032, an unsupported mode 0x06090030 (CiA 301), and
nothing is applied; a PDO has no answer, so a PDO setpoint beyond the limits is
passed to the twin, which refuses and counts it (statusword bit 11, 0x2005
bit 4). The twin's command watchdog (``serve --watchdog``) stands for CiA
301's heartbeat consumer: a drive left without commands faults (0x8130); a
client that sets a target once and waits (``BaseNode402``) wants
``--watchdog 0``.

Node ids: wheel ``n`` (0..15) is CANopen node ``n + 1``.

Why this module is long: a quarter of it is this description (the drive's
objects and the choices CiA 402 leaves to a drive), and the rest is the two
ends of one profile, the twin's drive and rwlab's driver of it, which change
together (the state machine itself is :mod:`rwlab.wheel.cia402_state`).
"""

from __future__ import annotations

import struct
from typing import Any

import can
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoAbortedError
from canopen.sdo.exceptions import SdoError

from rwlab.wheel import protocol as proto
from rwlab.wheel.canopen_common import (
    ABORT_RANGE_EXCEEDED,
    CanopenHostBase,
    CanopenNodeBase,
    CanopenProfile,
    ShippedEds,
    TpdoSchedule,
    canopen_id,
    cob_ids,
    nmt_heartbeat_byte,
    send_frame,
    setpoint_abort,
)
from rwlab.wheel.cia402_state import DriveState, S, next_state, statusword
from rwlab.wheel.link import Clock, Incoming
from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams, rad_s_to_rpm, rpm_to_rad_s

__all__ = [
    "Cia402HostLink",
    "Cia402NodeLink",
    "Cia402Protocol",
    "DriveState",
    "eds_path",
    "next_state",
    "statusword",
]

PROFILE_VELOCITY, PROFILE_TORQUE = 3, 4
SUPPORTED_MODES = {0, PROFILE_VELOCITY, PROFILE_TORQUE}
MILLI = 1000  # 0.001 rpm per rpm; ‰ per unit
NMT_OPERATIONAL = 0x05
REJECTED_BIT = 0x10  # 0x2005: a setpoint was refused since the last fault reset
ERROR_CODES = {  # CiA 301 error code classes, as in the ``canopen`` profile
    Fault.OVERSPEED: 0x8400,
    Fault.OVERCURRENT: 0x2300,
    Fault.WATCHDOG: 0x8130,
    Fault.OVERTEMP: 0x4200,
}


EDS = ShippedEds("cia402_wheel.eds")
eds_path = EDS.path  # the path of ``cia402_wheel.eds``, the profile's object dictionary


def object_dictionary(node_id: int) -> ObjectDictionary:
    """The drive's object dictionary for wheel ``node_id`` (CANopen id ``node_id + 1``).

    Parameters
    ----------
    node_id : int
        0..15.

    Returns
    -------
    canopen.ObjectDictionary
    """
    return EDS.dictionary(canopen_id(node_id))


class Cia402NodeLink(CanopenNodeBase):
    """The twin as a CiA 402 drive (``canopen.LocalNode`` with the drive state machine).

    Parameters
    ----------
    bus : can.BusABC
    node_id : int
        The wheel's node id, 0..15.
    clock : WallClock or SimClock
    """

    def __init__(self, bus: can.BusABC, node_id: int, clock: Clock) -> None:
        super().__init__(bus, node_id, clock, canopen_id(node_id), object_dictionary(node_id))
        self.local.rpdo.read(from_od=True)
        for number in (1, 2):
            self.local.rpdo[number].add_callback(self._on_rpdo)
        self.schedule = TpdoSchedule(self.local)
        self.state = S.SWITCH_ON_DISABLED
        self.mode = 0  # modes of operation in force (0x6061)
        self._controlword = 0
        self._target_velocity = 0  # 0.001 rpm
        self._target_torque = 0  # ‰ of rated torque
        self._values: dict[int, int] = {}
        self._rejected = False
        self._limited = False
        self._speed_rpm = 0.0
        self._ids = {0x000, 0x200 + self.cid, 0x300 + self.cid, 0x600 + self.cid}
        self._rpdo_bytes = {0x200 + self.cid: 7, 0x300 + self.cid: 4}  # RPDO1, RPDO2 maps
        self._own = {0x180 + self.cid, 0x280 + self.cid, 0x380 + self.cid, 0x480 + self.cid}

    # -- units ------------------------------------------------------------------------------
    def _rated_torque_mnm(self) -> int:
        return max(1, round(self._params.nominal_torque * 1000))

    def _rated_current_ma(self) -> int:
        return max(1, round(self._params.current_limit * 1000))

    def _torque_limit_permille(self) -> float:
        p = self._params
        return p.inertia * rpm_to_rad_s(p.max_accel_rpm_s) * 1e6 / self._rated_torque_mnm()

    # -- receiving --------------------------------------------------------------------------
    def receive(self, now: float) -> list[tuple[float, proto.Command]]:
        self._route_frames(now, self._own, self._ids, self._rpdo_bytes)
        out, self._commands = self._commands, []
        return out

    def _on_rpdo(self, pdo_map: Any) -> None:
        if self.local.nmt.state != "OPERATIONAL":
            return  # CiA 301: RPDOs only in operational
        if len(pdo_map.data) != pdo_map.length // 8:
            self.bad_frames += 1
            return
        values = {var.index: int(var.raw) for var in pdo_map}
        if 0x60FF in values:
            self._target_velocity = values[0x60FF]
        if 0x6071 in values:
            self._target_torque = values[0x6071]
        if 0x6060 in values and values[0x6060] in SUPPORTED_MODES:
            self.mode = values[0x6060]
        self._control(values[0x6040], refresh=True)

    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Apply a write; abort (CiA 301) a setpoint beyond the limits or an unknown mode."""
        value = int(od.decode_raw(data))
        if index == 0x60FF:
            setpoint_abort(value, self._params.max_speed_rpm * MILLI)
            self._target_velocity = value
            if self.state is S.OPERATION_ENABLED and self.mode == PROFILE_VELOCITY:
                self._command()
        elif index == 0x6071:
            setpoint_abort(value, self._torque_limit_permille())
            self._target_torque = value
            if self.state is S.OPERATION_ENABLED and self.mode == PROFILE_TORQUE:
                self._command()
        elif index == 0x6060:
            if value not in SUPPORTED_MODES:
                raise SdoAbortedError(ABORT_RANGE_EXCEEDED)
            changed, self.mode = value != self.mode, value
            if changed and self.state is S.OPERATION_ENABLED:
                self._command()
        elif index == 0x6040:
            self._control(value, refresh=False)

    def _control(self, controlword: int, refresh: bool) -> None:
        """Step the state machine; tell the wheel what the new state means."""
        before = self.state
        self.state = next_state(before, controlword, self._controlword)
        self._controlword = controlword
        if before is S.FAULT and self.state is not S.FAULT:
            self._rejected = False
            self._emit(Mode.CLEAR_FAULT, 0.0)
        elif self.state is S.OPERATION_ENABLED and (refresh or before is not S.OPERATION_ENABLED):
            self._command()
        elif self.state is S.QUICK_STOP_ACTIVE and before is not S.QUICK_STOP_ACTIVE:
            self._emit(Mode.SPEED, 0.0)  # quick stop ramp: the wheel's own limit
        elif before in (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE) and self.state is not before:
            self._emit(Mode.IDLE, 0.0)

    def _command(self) -> None:
        """The wheel command of operation enabled in the mode in force."""
        if self.mode == PROFILE_VELOCITY:
            self._emit(Mode.SPEED, self._target_velocity / MILLI)
        elif self.mode == PROFILE_TORQUE:
            torque = self._target_torque * self._rated_torque_mnm() / 1e6  # N·m
            self._emit(Mode.ACCELERATION, rad_s_to_rpm(torque / self._params.inertia))
        else:
            self._emit(Mode.IDLE, 0.0)

    def _emit(self, mode: Mode, setpoint: float) -> None:
        p = self._params
        limit = {Mode.SPEED: p.max_speed_rpm, Mode.ACCELERATION: p.max_accel_rpm_s}.get(mode)
        if limit is not None and abs(setpoint) > limit:
            self._rejected = True  # passed on: the twin refuses and counts it
        self._sequence = self._sequence % 255 + 1
        self._commands.append(
            (self._arrival, proto.Command(self.node_id, mode, setpoint, self._sequence))
        )

    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> int | None:
        fixed = {
            0x6041: self._statusword(),
            0x6061: self.mode,
            0x6060: self.mode,
            0x60FF: self._target_velocity,
            0x6071: self._target_torque,
            0x6075: self._rated_current_ma(),
            0x6076: self._rated_torque_mnm(),
            0x607F: round(self._params.max_speed_rpm * MILLI),
            0x6072: min(0xFFFF, round(self._torque_limit_permille())),
        }
        if index in fixed:
            return fixed[index]
        return self._values.get(index)

    def _statusword(self) -> int:
        at_target = abs(self._speed_rpm - self._target_velocity / MILLI) < 0.01 * max(
            1.0, abs(self._target_velocity / MILLI)
        )
        return statusword(
            self.state,
            limited=self._limited or self._rejected,
            at_target=self.state is S.OPERATION_ENABLED and at_target,
            stopped=abs(self._speed_rpm) < self._params.min_measurable_rpm,
        )

    # -- sending ------------------------------------------------------------------------------
    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        """TPDO1/2 for telemetry (on their event timers); TPDO3/4, heartbeat, EMCY for a heartbeat.

        A corrupted frame is not sent: CAN's own CRC would make every receiver drop it.
        """
        if corrupt is not None:
            return
        self.network.stamp = t
        if isinstance(frame, proto.Telemetry):
            self._telemetry(frame, t)
            return
        new = frame.faults & ~self._faults
        self._faults = frame.faults
        if frame.faults and self.state is not S.FAULT:
            self._fault(frame.faults)
        self._values.update(
            {
                0x2002: max(-32768, min(32767, round(frame.temperature * 10))),
                0x2003: frame.commands_seen & 0xFFFF,
                0x2004: min(frame.uptime, 0xFFFF),
                0x2005: (int(frame.faults) & 0xF) | (REJECTED_BIT if frame.command_rejected else 0),
                0x6079: max(0, round(frame.bus_voltage * 1000)),
            }
        )
        self._rejected = self._rejected or frame.command_rejected
        tpdo, cid = self.local.tpdo, self.cid
        nmt = nmt_heartbeat_byte(self.local)
        send_frame(self.bus, 0x700 + cid, bytes([nmt]), t)
        if nmt != NMT_OPERATIONAL:
            return  # CiA 301: PDOs only in operational
        self._fill(tpdo[4])
        send_frame(self.bus, 0x480 + cid, tpdo[4].data, t)
        self._fill(tpdo[3])
        send_frame(self.bus, 0x380 + cid, tpdo[3].data, t)
        for fault, code in ERROR_CODES.items():
            if new & fault:
                self.local.emcy.send(code, 0x01, struct.pack("<B", int(frame.faults)))

    def _fault(self, faults: Fault) -> None:
        self.state = S.FAULT
        code = next((c for f, c in ERROR_CODES.items() if faults & f), 0x1000)
        self._values[0x603F] = code

    def _telemetry(self, frame: proto.Telemetry, t: float) -> None:
        if frame.fault_active and self.state is not S.FAULT:
            self._fault(self._faults)
        if not frame.fault_active and self.state is not S.FAULT:
            self._values[0x603F] = 0
        self._speed_rpm, self._limited = frame.speed_rpm, frame.speed_limited
        torque_mnm = frame.current * self._params.torque_constant * 1000
        self._values.update(
            {
                0x606C: max(-(2**31), min(2**31 - 1, round(frame.speed_rpm * MILLI))),
                0x6077: max(
                    -32768, min(32767, round(torque_mnm * 1000 / self._rated_torque_mnm()))
                ),
                0x6078: max(
                    -32768, min(32767, round(frame.current * 1e6 / self._rated_current_ma()))
                ),
                0x2001: frame.counter & 0xFF,
                0x6041: self._statusword(),
                0x6061: self.mode,
            }
        )
        tpdo, cid = self.local.tpdo, self.cid
        if self.local.nmt.state != "OPERATIONAL":
            return
        if self.schedule.due(1, t):
            self._fill(tpdo[1])
            send_frame(self.bus, 0x180 + cid, tpdo[1].data, t)
        if self.schedule.due(2, t):
            self._fill(tpdo[2])
            send_frame(self.bus, 0x280 + cid, tpdo[2].data, t)

    def _fill(self, pdo_map: Any) -> None:
        for var in pdo_map:
            var.raw = self._values.get(var.index, 0)


class Cia402HostLink(CanopenHostBase):
    """rwlab's driver of a CiA 402 drive: confirmed SDO writes out, TPDOs in.

    Every command is SDO downloads (each confirmed by the drive, or aborted):
    the target (0x60FF in 0.001 rpm, or 0x6071 in ‰ of the rated torque it
    reads from 0x6076 once), then, unless the drive already is in operation
    enabled in that mode, the mode (0x6060) and the controlwords shutdown,
    switch on, enable operation. Idle is shutdown (0x06), clear fault is fault
    reset (0x80). A command whose writes are not all confirmed is lost.

    Parameters
    ----------
    bus : can.BusABC
    node_id : int
        The wheel's node id, 0..15.
    clock : WallClock or SimClock
    """

    def __init__(self, bus: can.BusABC, node_id: int, clock: Clock) -> None:
        super().__init__(bus, node_id, clock, canopen_id(node_id), object_dictionary(node_id))
        self._rated_ma_configured = RW90.current_limit * 1000
        self._rated: tuple[int, int] | None = None  # (mN·m, mA) read from the drive
        self._enabled_mode: int | None = None  # the mode of operation enabled, as we know
        self._acked = 0
        self._confirmed = 0
        self._rejected = False
        self._status: tuple[int, int, int] = (0, 0, 0)  # statusword, mode display, velocity
        self._voltage = 0.0
        self._last_heartbeat: tuple[int, bool] | None = None

    def configure(self, params: WheelParams) -> None:
        self.inertia = params.inertia
        self._rated_ma_configured = params.current_limit * 1000

    def _download(self, index: int, value: int) -> None:
        self.remote.sdo[index].raw = value

    def _rated_values(self) -> tuple[int, int]:
        if self._rated is None:
            self._rated = (int(self.remote.sdo[0x6076].raw), int(self.remote.sdo[0x6075].raw))
        return self._rated

    def send(self, cmd: proto.Command, now: float) -> None:
        try:
            self._rated_values()
            self._send(cmd)
        except SdoError as exc:
            self.lost_commands += 1
            self._enabled_mode = None  # ask again from the start next time
            if isinstance(exc, SdoAbortedError):
                self._rejected = True
            return
        self._acked = cmd.sequence
        self._confirmed += 1

    def _send(self, cmd: proto.Command) -> None:
        if cmd.mode == Mode.CLEAR_FAULT:
            self._download(0x6040, 0x80)
            self._enabled_mode, self._rejected = None, False
            return
        if cmd.mode == Mode.IDLE:
            self._download(0x6040, 0x06)
            self._enabled_mode = None
            return
        if cmd.mode == Mode.SPEED:
            mode = PROFILE_VELOCITY
            self._download(0x60FF, round(cmd.setpoint * MILLI))
        else:
            mode = PROFILE_TORQUE
            rated_mnm, _ = self._rated_values()
            torque = self.inertia * rpm_to_rad_s(cmd.setpoint)  # N·m
            self._download(0x6071, round(torque * 1e6 / rated_mnm))
        if self._enabled_mode != mode:
            self._download(0x6060, mode)
            for word in (0x06, 0x07, 0x0F):  # shutdown, switch on, enable operation
                self._download(0x6040, word)
            self._enabled_mode = mode

    def receive(self, now: float) -> list[Incoming]:
        out: list[Incoming] = []
        for t, number, pdo_map, source in self._tpdos(now):
            values = {var.index: int(var.raw) for var in pdo_map}
            if number == 1:
                self._status = (values[0x6041], values[0x6061], values[0x606C])
                if values[0x6041] & 0x6F != S.OPERATION_ENABLED.value:
                    self._enabled_mode = None
            elif number == 2:
                out.append(Incoming(t, self._telemetry(values), source))
            elif number == 4:
                self._voltage = values[0x6079] / 1000
            else:
                out.append(Incoming(t, self._heartbeat(values), source))
        return out

    def _mode(self) -> Mode:
        word, mode, _ = self._status
        if word & 0x6F != S.OPERATION_ENABLED.value:
            return Mode.SPEED if word & 0x6F == S.QUICK_STOP_ACTIVE.value else Mode.IDLE
        return {PROFILE_VELOCITY: Mode.SPEED, PROFILE_TORQUE: Mode.ACCELERATION}.get(
            mode, Mode.IDLE
        )

    def _telemetry(self, values: dict[int, int]) -> proto.Telemetry:
        word, _, velocity = self._status
        # the drive's rated current, read with the first command; the configured one before
        rated_ma = self._rated[1] if self._rated else self._rated_ma_configured
        current = values[0x6078] * rated_ma / 1e6
        return proto.Telemetry(
            self.node_id,
            velocity / MILLI,
            current,
            self._mode(),
            word & 0x4F == S.FAULT.value,
            bool(word & 0x800),
            self._acked,
            values[0x2001],
        )

    def _heartbeat(self, values: dict[int, int]) -> proto.Heartbeat:
        bits = values[0x2005]
        return proto.Heartbeat(
            self.node_id,
            self._mode(),
            Fault(bits & 0xF),
            values[0x2002] / 10,
            values[0x2004],
            values[0x2003],
            self._voltage,
            bool(bits & REJECTED_BIT) or self._rejected,
        )


class Cia402Protocol(CanopenProfile):
    """CiA 402 drive profile (profile velocity and torque) on CiA 301, any python-can bus."""

    name = "canopen/cia402"
    description = (
        "CANopen CiA 402 drive (canopen package's BaseNode402 semantics): controlword/"
        "statusword state machine, profile velocity 0x60FF/0x606C in 0.001 rpm, profile torque"
    )
    eds = EDS
    host_class = Cia402HostLink
    node_class = Cia402NodeLink

    def addresses(self, node_id: int) -> str:
        """CANopen node ``node_id + 1`` and its COB-IDs."""
        cid = canopen_id(node_id)
        tpdos = (0x180 + cid, 0x280 + cid, 0x380 + cid, 0x480 + cid)
        return cob_ids(cid, tpdos, (0x200 + cid, 0x300 + cid))
