"""The ``canopen/oresat`` profile: the twin with OreSat's reaction-wheel object dictionary.

Source: the ``oresat-configs`` package, version 1.2.0 (PyPI; Portland State
Aerospace Society, GPL-3.0), card ``rw`` (``base/reaction_wheel.yaml`` with
the firmware objects of ``base/fw_common.yaml``, mission OreSat1's
``cards.csv``). ``oresat_wheel.eds`` beside this module is written by rwlab
from what that configuration generates (indices, names, types, access, PDO
maps and communication parameters; ``tests/test_canopen_profiles.py`` checks
them against the package's own dictionary); no file of the package is copied.

Objects
-------
==========  ==========================  =======  =======================================
index:sub   name                        type     meaning
==========  ==========================  =======  =======================================
0x4000:1    ctrl_stat.current_state     U8, ro   1 idle, 2 system error, 3 controller
                                                 error, 4 torque control, 5 velocity
                                                 control, 13 clear errors, …
0x4000:2    ctrl_stat.procedure_result  U8, ro   0 (the twin has no procedures)
0x4000:3    ctrl_stat.errors            U32, ro  error bits (below)
0x4001:1    motor.velocity              F32, ro  rev/s
0x4001:2    motor.current               F32, ro  A
0x4002:1/2  bus.voltage / bus.current   F32, ro  V, A
0x4003:1-3  temperature.sensor_1..3     I16, ro  0.01 °C
0x4004:1    requested.state             U8, rw   the state wanted (codes of 0x4000:1)
0x4005:1    signals.setpoint            F32, rw  rev/s in velocity control, N·m in torque
0x4007:1    reboot.request              U8, rw   1: reboot (the twin idles its motor)
0x3003:5    system.uptime               U32, ro  s
==========  ==========================  =======  =======================================

TPDOs as OreSat maps them: TPDO1 (0x180 + id) state, procedure result,
errors; TPDO2 (0x280 + id) velocity, current; TPDO3 (0x380 + id) bus voltage
and current; TPDO4 (0x480 + id) the three temperatures; transmission type 254
on an event timer of 5000 ms, which is ``rw`` (0x1800..0x1803 sub 5): rwlab's
driver writes 1000/rate ms into TPDO1/2's to stream telemetry. No RPDO: the
host writes 0x4005 and 0x4004 by SDO. Heartbeat 1000 ms (0x1017).

Node ids: OreSat1 puts its reaction wheels rw_1..rw_4 at CANopen ids 0x3C, 0x40,
0x44, 0x48 (four apart); wheel ``n`` (0..15) is CANopen id ``0x3C + 4 n``, so
wheels 0..3 answer where OreSat's do.

Where the source is silent (said so in docs/wheels/canopen.md):

- The setpoint's unit. 0x4005:1 has none; the twin takes rev/s in velocity
  control, the unit of 0x4001:1 velocity, and N·m in torque control.
- The error bits 0..21 are the motor controller's (bit 8 motor overcurrent is
  the twin's overcurrent fault); OreSat has no bit for overspeed, the command
  watchdog or overtemperature, and the twin reports those in bits 24, 25, 26,
  which OreSat leaves unassigned. A latched fault reads state 3, controller error.
- Bus current: the twin's motor power over the bus voltage,
  ``I (k_t ω + R I) / V`` (a lossless inverter); the three temperature sensors
  all read the twin's one winding temperature.
- Requested states the twin cannot run (calibrations, position and open-loop
  control, encoder tests) are aborted 0x06090030, as are unknown codes.

Refusals: a setpoint beyond the wheel's limits for the requested state, or not
a number, is aborted (CiA 301 0x06090031/0x06090032/0x06090030) and never
applied; an SDO request that is not 8 bytes is answered 0x05040001 and counted.
The TPDOs have no counter: rwlab's driver cannot see a lost TPDO here.
"""

from __future__ import annotations

import math
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
    cob_ids,
    nmt_heartbeat_byte,
    send_frame,
    setpoint_abort,
)
from rwlab.wheel.link import Clock, Incoming
from rwlab.wheel.physics import Fault, Mode, WheelParams, rad_s_to_rpm, rpm_to_rad_s

__all__ = ["OresatHostLink", "OresatNodeLink", "OresatProtocol", "canopen_id", "eds_path"]

FIRST_WHEEL_ID, ID_STEP = 0x3C, 4  # OreSat1 cards.csv: rw_1..rw_4 at 0x3C, 0x40, 0x44, 0x48
IDLE, SYSTEM_ERROR, CONTROLLER_ERROR, TORQUE_CONTROL, VEL_CONTROL, CLEAR_ERRORS = 1, 2, 3, 4, 5, 13
_TO_STATE = {
    Mode.IDLE: IDLE,
    Mode.ACCELERATION: TORQUE_CONTROL,
    Mode.SPEED: VEL_CONTROL,
    Mode.CLEAR_FAULT: CLEAR_ERRORS,
}
_FROM_STATE = {v: k for k, v in _TO_STATE.items()}
MOTOR_OVERCURRENT_BIT = 1 << 8  # OreSat's error bit 8
ERROR_BITS = {  # the twin's faults in 0x4000:3; bits 24.. are rwlab's (OreSat assigns 0..21)
    Fault.OVERCURRENT: MOTOR_OVERCURRENT_BIT,
    Fault.OVERSPEED: 1 << 24,
    Fault.WATCHDOG: 1 << 25,
    Fault.OVERTEMP: 1 << 26,
}
REJECTED_ERROR_BIT = 1 << 27  # rwlab's: a setpoint was refused since the last clear errors
EMCY_CODES = {Fault.OVERSPEED: 0x8400, Fault.OVERCURRENT: 0x2300, Fault.WATCHDOG: 0x8130}
EMCY_CODES[Fault.OVERTEMP] = 0x4200
HOUSEKEEPING_MS = 1000  # TPDO3/4 (bus, temperatures): the driver asks for them at 1 Hz


EDS = ShippedEds("oresat_wheel.eds")
eds_path = EDS.path  # the path of ``oresat_wheel.eds``, the profile's object dictionary


def canopen_id(node_id: int) -> int:
    """The CANopen id of wheel ``node_id``: ``0x3C + 4 node_id`` (OreSat's rw_1 is 0x3C).

    Parameters
    ----------
    node_id : int
        0..15.

    Returns
    -------
    int
    """
    return FIRST_WHEEL_ID + ID_STEP * proto.check_node(node_id)


def object_dictionary(node_id: int) -> ObjectDictionary:
    """The dictionary for wheel ``node_id`` (a fresh copy each call).

    Parameters
    ----------
    node_id : int
        0..15.

    Returns
    -------
    canopen.ObjectDictionary
    """
    return EDS.dictionary(canopen_id(node_id))


def error_bits(faults: Fault) -> int:
    """0x4000:3 for the twin's latched ``faults``.

    Parameters
    ----------
    faults : Fault

    Returns
    -------
    int
    """
    return sum(bit for fault, bit in ERROR_BITS.items() if faults & fault)


def faults_of(errors: int) -> Fault:
    """The twin's faults in 0x4000:3 (the inverse of :func:`error_bits`).

    Parameters
    ----------
    errors : int

    Returns
    -------
    Fault
    """
    out = Fault.NONE
    for fault, bit in ERROR_BITS.items():
        if errors & bit:
            out |= fault
    return out


class OresatNodeLink(CanopenNodeBase):
    """The twin as OreSat's reaction-wheel card (``canopen.LocalNode``).

    Parameters
    ----------
    bus : can.BusABC
    node_id : int
        The wheel's node id, 0..15.
    clock : WallClock or SimClock
    """

    def __init__(self, bus: can.BusABC, node_id: int, clock: Clock) -> None:
        super().__init__(bus, node_id, clock, canopen_id(node_id), object_dictionary(node_id))
        self.schedule = TpdoSchedule(self.local)
        self._values: dict[tuple[int, int], float | int] = {(0x4000, 1): IDLE}
        self._requested = IDLE
        self._setpoint = 0.0
        self._rejected = False
        self._own = {0x180 + self.cid, 0x280 + self.cid, 0x380 + self.cid, 0x480 + self.cid}

    def receive(self, now: float) -> list[tuple[float, proto.Command]]:
        self._route_frames(now, self._own, (0x000, 0x600 + self.cid), {})
        out, self._commands = self._commands, []
        return out

    # -- SDO ------------------------------------------------------------------------------
    def _limit(self, state: int) -> float:
        """The largest setpoint the wheel obeys in ``state`` (rev/s, or N·m in torque control)."""
        p = self._params
        if state == TORQUE_CONTROL:
            return p.inertia * rpm_to_rad_s(p.max_accel_rpm_s)
        return p.max_speed_rpm / 60

    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Apply a written state or setpoint; abort (CiA 301) what the wheel must refuse."""
        if (index, subindex) == (0x4005, 1):
            (setpoint,) = struct.unpack("<f", data)
            state = self._requested if self._requested in (TORQUE_CONTROL, VEL_CONTROL) else 0
            self._refuse(setpoint, state)
            self._setpoint = setpoint
            if state:
                self._emit(state)
        elif (index, subindex) == (0x4004, 1):
            state = data[0]
            if state not in _FROM_STATE:
                raise SdoAbortedError(ABORT_RANGE_EXCEEDED)
            if state in (TORQUE_CONTROL, VEL_CONTROL):
                self._refuse(self._setpoint, state)
            self._requested = state
            self._emit(state)
            if state == CLEAR_ERRORS:
                self._requested, self._rejected = IDLE, False
        elif (index, subindex) == (0x4007, 1) and data[0] == 1:
            self._requested = IDLE
            self._emit(IDLE)

    def _refuse(self, setpoint: float, state: int) -> None:
        try:
            setpoint_abort(setpoint, self._limit(state))
        except SdoAbortedError:
            self._rejected = True
            raise

    def _emit(self, state: int) -> None:
        mode = _FROM_STATE[state]
        if mode == Mode.SPEED:
            value = self._setpoint * 60  # rev/s -> rpm
        elif mode == Mode.ACCELERATION:
            value = rad_s_to_rpm(self._setpoint / self._params.inertia)
        else:
            value = 0.0
        self._sequence = self._sequence % 255 + 1
        cmd = proto.Command(self.node_id, mode, float(value), self._sequence)
        self._commands.append((self._arrival, cmd))

    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> float | int | None:
        if (index, subindex) == (0x4004, 1):
            return self._requested
        if (index, subindex) == (0x4005, 1):
            return self._setpoint
        return self._values.get((index, subindex))

    # -- sending ------------------------------------------------------------------------------
    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        """TPDO1/2 for telemetry, TPDO3/4 and the heartbeat for a heartbeat, on their timers.

        A corrupted frame is not sent: CAN's own CRC would make every receiver drop it.
        """
        if corrupt is not None:
            return
        self.network.stamp = t
        v = self._values
        if isinstance(frame, proto.Telemetry):
            if frame.fault_active or self._faults:
                state = CONTROLLER_ERROR
            else:
                state = {Mode.SPEED: VEL_CONTROL, Mode.ACCELERATION: TORQUE_CONTROL}.get(
                    frame.mode, IDLE
                )
            omega = rpm_to_rad_s(frame.speed_rpm)
            p = self._params
            power = frame.current * (
                p.torque_constant * omega + p.winding_resistance * frame.current
            )
            voltage = float(v.get((0x4002, 1), 0.0))
            v.update(
                {
                    (0x4000, 1): state,
                    (0x4000, 2): 0,
                    (0x4000, 3): error_bits(self._faults)
                    | (REJECTED_ERROR_BIT if self._rejected else 0),
                    (0x4001, 1): frame.speed_rpm / 60,
                    (0x4001, 2): frame.current,
                    (0x4002, 2): power / voltage if voltage > 0 else 0.0,
                }
            )
            self._transmit((1, 2), t)
            return
        new = frame.faults & ~self._faults
        self._faults = frame.faults
        self._rejected = self._rejected or frame.command_rejected
        temperature = max(-32768, min(32767, round(frame.temperature * 100)))
        v.update({(0x4003, k): temperature for k in (1, 2, 3)})
        v.update({(0x4002, 1): frame.bus_voltage, (0x3003, 5): frame.uptime})
        send_frame(self.bus, 0x700 + self.cid, bytes([nmt_heartbeat_byte(self.local)]), t)
        self._transmit((3, 4), t)
        for fault, code in EMCY_CODES.items():
            if new & fault:
                self.local.emcy.send(code, 0x01, struct.pack("<I", error_bits(frame.faults)))

    def _transmit(self, numbers: tuple[int, ...], t: float) -> None:
        if self.local.nmt.state != "OPERATIONAL":
            return  # CiA 301: PDOs only in operational
        for number in numbers:
            if self.schedule.due(number, t):
                pdo_map = self.local.tpdo[number]
                for var in pdo_map:
                    var.raw = self._values.get((var.index, var.subindex), 0)
                send_frame(self.bus, pdo_map.cob_id, pdo_map.data, t)


class OresatHostLink(CanopenHostBase):
    """rwlab's driver of OreSat's wheel card: SDO writes of 0x4005/0x4004, TPDOs in.

    On its first command it writes TPDO1/2's event timers to the telemetry
    period and TPDO3/4's to 1 s (they are 5 s as OreSat ships them). A speed
    command writes the setpoint (rev/s) and, when the state changes, the
    requested state; each write is confirmed by the card or aborted, and a
    command not confirmed is lost. Telemetry is built at TPDO2 from the last
    TPDO1; a heartbeat at TPDO4 from the last TPDO3.

    Parameters
    ----------
    bus : can.BusABC
    node_id : int
        The wheel's node id, 0..15.
    clock : WallClock or SimClock
    """

    def __init__(self, bus: can.BusABC, node_id: int, clock: Clock) -> None:
        super().__init__(bus, node_id, clock, canopen_id(node_id), object_dictionary(node_id))
        self.period_ms = 100  # 10 Hz until told
        self._timers_set = False
        self._state: int | None = None  # the requested state, as we last wrote it
        self._acked = 0
        self._confirmed = 0
        self._rejected = False
        self._received = 0
        self._status: tuple[int, int] = (IDLE, 0)
        self._bus_voltage = 0.0
        self._first: float | None = None

    def configure(self, params: WheelParams) -> None:
        self.inertia = params.inertia

    def set_telemetry_rate(self, rate: float) -> None:
        """Ask for TPDO1/2 every ``1/rate`` s (their event timers, ms)."""
        self.period_ms = max(1, min(0xFFFF, round(1000 / rate)))
        self._timers_set = False

    def start_telemetry(self) -> None:
        """Write the TPDO event timers now (else on the first command); a write the card
        does not confirm is tried again with that command."""
        try:
            self._set_timers()
        except SdoError:
            self._timers_set = False

    def _set_timers(self) -> None:
        sdo = self.remote.sdo
        for index, period in ((0x1800, self.period_ms), (0x1801, self.period_ms)):
            sdo[index][5].raw = period
        for index in (0x1802, 0x1803):
            sdo[index][5].raw = HOUSEKEEPING_MS
        self._timers_set = True

    def send(self, cmd: proto.Command, now: float) -> None:
        state = _TO_STATE[cmd.mode]
        if cmd.mode == Mode.SPEED:
            setpoint = cmd.setpoint / 60  # rev/s
        elif cmd.mode == Mode.ACCELERATION:
            setpoint = self.inertia * rpm_to_rad_s(cmd.setpoint)  # N·m
        else:
            setpoint = None
        if setpoint is not None and not math.isfinite(setpoint):
            raise proto.ProtocolError(f"setpoint must be finite, got {cmd.setpoint}")
        try:
            if not self._timers_set:
                self._set_timers()
            signals = self.remote.sdo[0x4005][1]
            if setpoint is not None and state == self._state:
                signals.raw = setpoint
            else:
                if setpoint is not None:
                    signals.raw = setpoint
                self.remote.sdo[0x4004][1].raw = state
                self._state = IDLE if state == CLEAR_ERRORS else state
        except SdoError as exc:
            self.lost_commands += 1
            self._state = None  # write the state again next time
            self._rejected = self._rejected or isinstance(exc, SdoAbortedError)
            return
        if state == CLEAR_ERRORS:
            self._rejected = False
        self._acked = cmd.sequence
        self._confirmed += 1

    def receive(self, now: float) -> list[Incoming]:
        out: list[Incoming] = []
        for t, number, pdo_map, source in self._tpdos(now):
            values = {(var.index, var.subindex): var.raw for var in pdo_map}
            if number == 1:
                self._status = (int(values[0x4000, 1]), int(values[0x4000, 3]))
                if self._status[0] == CONTROLLER_ERROR:
                    self._state = None
            elif number == 2:
                out.append(Incoming(t, self._telemetry(values), source))
            elif number == 3:
                self._bus_voltage = float(values[0x4002, 1])
            else:
                out.append(Incoming(t, self._heartbeat(values, t), source))
        return out

    def _mode(self) -> Mode:
        return (
            _FROM_STATE.get(self._status[0], Mode.IDLE)
            if self._status[0] != CLEAR_ERRORS
            else (Mode.IDLE)
        )

    def _telemetry(self, values: dict[tuple[int, int], Any]) -> proto.Telemetry:
        self._received += 1
        state, errors = self._status
        return proto.Telemetry(
            self.node_id,
            float(values[0x4001, 1]) * 60,
            float(values[0x4001, 2]),
            self._mode(),
            state in (SYSTEM_ERROR, CONTROLLER_ERROR) or bool(errors & ~REJECTED_ERROR_BIT),
            False,  # OreSat's dictionary does not say when the speed is limited
            self._acked,
            self._received & 0xFF,  # no counter on the wire: a lost TPDO goes unseen
        )

    def _heartbeat(self, values: dict[tuple[int, int], Any], t: float) -> proto.Heartbeat:
        if self._first is None:
            self._first = t
        _, errors = self._status
        return proto.Heartbeat(
            self.node_id,
            self._mode(),
            faults_of(errors),
            int(values[0x4003, 1]) / 100,
            int(t - self._first),  # since the driver first heard it (uptime is not in a PDO)
            self._confirmed & 0xFFFF,  # commands the card confirmed
            self._bus_voltage,
            bool(errors & REJECTED_ERROR_BIT) or self._rejected,
        )


class OresatProtocol(CanopenProfile):
    """OreSat's reaction-wheel card (oresat-configs 1.2.0) on CiA 301, any python-can bus."""

    name = "canopen/oresat"
    description = (
        "CANopen, OreSat's reaction-wheel dictionary (oresat-configs 1.2.0): SDO 0x4004/0x4005 "
        "commands, TPDO 0x4000-0x4003 telemetry, ids 0x3C + 4n"
    )
    eds = EDS
    host_class = OresatHostLink
    node_class = OresatNodeLink

    def addresses(self, node_id: int) -> str:
        """CANopen id ``0x3C + 4 node_id`` (OreSat1's rw_1..rw_4 for 0..3) and its COB-IDs."""
        cid = canopen_id(node_id)
        return cob_ids(cid, (0x180 + cid, 0x280 + cid, 0x380 + cid, 0x480 + cid), ())
