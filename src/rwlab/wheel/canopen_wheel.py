"""The ``canopen`` protocol: the wheel as a CiA 301 node, built on the ``canopen`` package.

The object dictionary is ``rw_canopen.eds``, shipped beside this module (an
outline after open CANopen wheels such as OreSat's): a requested state and a
setpoint written by the host, the control state, velocity, current,
temperature and faults read back.

======  =====================  ======  =============================================
index   name                   type    meaning
======  =====================  ======  =============================================
0x4000  Requested state        U8, rw  0 idle, 1 torque control, 2 velocity control,
                                       3 clear errors
0x4001  Control state          U8      the state the wheel is in (same codes)
0x4002  Setpoint               REAL32  rad/s in velocity control, N·m in torque control
0x4003  Motor torque           REAL32  N·m (k_t × current)
0x4004  Velocity               REAL32  rad/s, measured
0x4005  Current                I16     mA
0x4006  Overtemperature limit  REAL32  °C
0x4007  Temperature            REAL32  °C
0x4008  Faults                 U8      bits: 1 overspeed, 2 overcurrent, 4 watchdog,
                                       8 overtemperature
0x4009  Setpoint sequence      U8, rw  echoed in 0x400A once the setpoint is applied
0x400C  Status flags           U8      bit 0 speed limited, bit 1 a setpoint was refused
0x400F  Bus voltage            REAL32  V, the supply at the wheel's driver (1 Hz)
======  =====================  ======  =============================================

PDOs: RPDO1 (0x200 + id) carries state, setpoint and sequence from the host;
TPDO1 (0x180 + id) velocity, current, counter, sequence echo at the telemetry
rate; TPDO2 (0x280 + id) state, faults, flags with it; TPDO3 (0x380 + id)
temperature, commands seen, uptime at 1 Hz with the NMT heartbeat (0x700 + id,
operational). A fault that latches sends an EMCY (0x080 + id). SDO (0x600/0x580
+ id) reads and writes every object: a bare ``canopen`` client can drive the
wheel by writing 0x4002 then 0x4000. A setpoint beyond the wheel's limit or not
a number is aborted (CiA 301 0x06090031/32, 0x06090030) and never applied; an
unknown requested state is aborted 0x06090030; an SDO request that is not 8
bytes is answered 0x05040001 and counted (:mod:`rwlab.wheel.canopen_common`).

Node ids: wheel ``n`` (0..15) is CANopen node ``n + 1``, since CANopen node id 0
is reserved; ``rwlab wheel serve`` prints the COB-IDs it answers on.

The PDO layouts, SDO server, EMCY producer and object encoding are the
``canopen`` package's; this module only maps them to the twin's messages.
The frames are sent with the caller's time stamps (a simulated clock's, too).
"""

from __future__ import annotations

import struct
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoAbortedError

from rwlab.wheel import protocol as proto
from rwlab.wheel.canopen_common import (
    ABORT_RANGE_EXCEEDED,
    BusNetwork,
    CanopenNodeBase,
    CanopenProfile,
    ShippedEds,
    canopen_id,
    cob_ids,
    nmt_heartbeat_byte,
    send_frame,
    setpoint_abort,
)
from rwlab.wheel.dbc_link import read_frames
from rwlab.wheel.link import Clock, HostLink, Incoming
from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams, rad_s_to_rpm, rpm_to_rad_s

__all__ = ["CanopenHostLink", "CanopenNodeLink", "CanopenProtocol", "eds_path", "object_dictionary"]

IDLE, TORQUE_CONTROL, VELOCITY_CONTROL, CLEAR_ERRORS = 0, 1, 2, 3
_TO_STATE = {
    Mode.IDLE: IDLE,
    Mode.ACCELERATION: TORQUE_CONTROL,
    Mode.SPEED: VELOCITY_CONTROL,
    Mode.CLEAR_FAULT: CLEAR_ERRORS,
}
_FROM_STATE = {v: k for k, v in _TO_STATE.items()}
EMCY_CODES = {  # CiA 301 error code classes
    Fault.OVERSPEED: 0x8400,  # velocity / speed controller
    Fault.OVERCURRENT: 0x2300,  # current, device output side
    Fault.WATCHDOG: 0x8130,  # life guard / heartbeat error
    Fault.OVERTEMP: 0x4200,  # device temperature
}


EDS = ShippedEds("rw_canopen.eds")
eds_path = EDS.path  # the path of ``rw_canopen.eds``, the profile's object dictionary


def object_dictionary(node_id: int) -> ObjectDictionary:
    """The wheel's object dictionary for ``node_id`` (a fresh copy each call).

    Parameters
    ----------
    node_id : int
        0..15 (the CANopen node id is ``node_id + 1``: id 0 is reserved).

    Returns
    -------
    canopen.ObjectDictionary
    """
    return EDS.dictionary(canopen_id(node_id))


class CanopenNodeLink(CanopenNodeBase):
    """The twin as a CANopen node (``canopen.LocalNode``).

    Parameters
    ----------
    bus : can.BusABC
        The python-can bus.
    node_id : int
        The wheel's CANopen node id.
    clock : Clock
        Where time comes from (simulated or wall clock).
    """

    def __init__(self, bus: can.BusABC, node_id: int, clock: Clock) -> None:
        super().__init__(bus, node_id, clock, canopen_id(node_id), object_dictionary(node_id))
        self.local.rpdo.read(from_od=True)
        self.local.rpdo[1].add_callback(self._on_rpdo)
        self._values: dict[int, float] = {}
        self._ids = {0x000, 0x200 + self.cid, 0x600 + self.cid}

    # -- receiving ------------------------------------------------------------------------
    def receive(self, now: float) -> list[tuple[float, proto.Command]]:
        self._route_frames(now, {0x180 + self.cid, 0x280 + self.cid}, self._ids, {})
        out, self._commands = self._commands, []
        return out

    def _on_rpdo(self, pdo_map: Any) -> None:
        if self.local.nmt.state != "OPERATIONAL":
            return  # CiA 301: RPDOs only in operational
        if len(pdo_map.data) != 6:
            self.bad_frames += 1
            return
        state = int(pdo_map["Requested state"].raw)
        setpoint = float(pdo_map["Setpoint"].raw)
        sequence = int(pdo_map["Setpoint sequence"].raw)
        self._request(state, setpoint, sequence)

    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        """Apply a written state or setpoint; abort (CiA 301) one the wheel must refuse."""
        if index == 0x4000:
            (state,) = struct.unpack("<B", data)
            if state not in _FROM_STATE:
                raise SdoAbortedError(ABORT_RANGE_EXCEEDED)
            setpoint = self._stored_float(0x4002)
            self._check_setpoint(state, setpoint)
            self._sequence = self._sequence % 255 + 1
            self._request(state, setpoint, self._sequence)
        elif index == 0x4002:
            state = int(self.local.data_store.get(0x4000, {}).get(0, b"\0")[0])
            (setpoint,) = struct.unpack("<f", data)
            self._check_setpoint(state, setpoint)
            if state in (TORQUE_CONTROL, VELOCITY_CONTROL):
                self._sequence = self._sequence % 255 + 1
                self._request(state, setpoint, self._sequence)

    def _check_setpoint(self, state: int, setpoint: float) -> None:
        """SDO abort for a setpoint beyond the wheel's limit in ``state`` (or not a number)."""
        p = self._params
        speed_limit = rpm_to_rad_s(p.max_speed_rpm)  # rad/s
        if state == TORQUE_CONTROL:
            setpoint_abort(setpoint, p.inertia * rpm_to_rad_s(p.max_accel_rpm_s))  # N·m
        else:  # velocity control, or stored for later: the larger limit
            setpoint_abort(setpoint, speed_limit)

    def _stored_float(self, index: int) -> float:
        raw = self.local.data_store.get(index, {}).get(0)
        return struct.unpack("<f", raw)[0] if raw else 0.0

    def _request(self, state: int, setpoint: float, sequence: int) -> None:
        if state not in _FROM_STATE:
            self.bad_frames += 1
            return
        mode = _FROM_STATE[state]
        if mode == Mode.SPEED:
            value = rad_s_to_rpm(setpoint)
        elif mode == Mode.ACCELERATION:
            value = rad_s_to_rpm(setpoint / self._params.inertia)
        else:
            value = 0.0
        cmd = proto.Command(self.node_id, mode, float(value), sequence & 0xFF)
        self._commands.append((self._arrival, cmd))

    def _on_sdo_read(self, index: int, subindex: int, od: Any) -> float | int | None:
        if index == 0x4003:
            return self._values.get(0x4005, 0.0) / 1000 * self._params.torque_constant
        if index == 0x4006:
            return self._params.overtemp_fault_c
        return self._values.get(index)

    # -- sending ----------------------------------------------------------------------------
    def send(
        self, frame: proto.Telemetry | proto.Heartbeat, t: float, corrupt: int | None = None
    ) -> None:
        """TPDOs for telemetry; heartbeat, TPDO3 and (on a new fault) EMCY for a heartbeat.

        A corrupted frame is not sent: CAN's own CRC would make every receiver drop it.
        """
        if corrupt is not None:
            return
        self.network.stamp = t
        tpdo, cid = self.local.tpdo, self.cid
        operational = self.local.nmt.state == "OPERATIONAL"  # CiA 301: PDOs only then
        if isinstance(frame, proto.Telemetry):
            state = _TO_STATE.get(frame.mode, IDLE)
            values = {
                0x4004: rpm_to_rad_s(frame.speed_rpm),
                0x4005: max(-32768, min(32767, round(frame.current * 1000))),
                0x400B: frame.counter & 0xFF,
                0x400A: frame.sequence_echo & 0xFF,
                0x4001: state,
                0x4008: int(self._faults) if frame.fault_active else 0,
            }
            flags = int(self._values.get(0x400C, 0)) & ~1
            values[0x400C] = flags | int(frame.speed_limited)
            self._values.update(values)
            if operational:
                self._fill(tpdo[2])
                send_frame(self.bus, 0x280 + cid, tpdo[2].data, t)
                self._fill(tpdo[1])
                send_frame(self.bus, 0x180 + cid, tpdo[1].data, t)
            return
        new = frame.faults & ~self._faults
        self._faults = frame.faults
        flags = int(self._values.get(0x400C, 0)) & ~2
        self._values.update(
            {
                0x4007: frame.temperature,
                0x400F: frame.bus_voltage,
                0x400D: frame.commands_seen & 0xFFFF,
                0x400E: min(frame.uptime, 0xFFFF),
                0x4008: int(frame.faults) & 0xFF,
                0x400C: flags | (2 if frame.command_rejected else 0),
            }
        )
        if operational:
            self._fill(tpdo[3])
            send_frame(self.bus, 0x380 + cid, tpdo[3].data, t)
        send_frame(self.bus, 0x700 + cid, bytes([nmt_heartbeat_byte(self.local)]), t)
        for fault, code in EMCY_CODES.items():
            if new & fault:
                self.local.emcy.send(code, 0x01, struct.pack("<B", int(frame.faults)))

    def _fill(self, pdo_map: Any) -> None:
        for var in pdo_map:
            var.raw = self._values.get(var.index, 0)


class CanopenHostLink(HostLink):
    """The driver as a CANopen client (``canopen.RemoteNode``): RPDO out, TPDOs in.

    Parameters
    ----------
    bus, node_id, clock
        As for :class:`CanopenNodeLink`.
    """

    def __init__(self, bus: can.BusABC, node_id: int, clock: Clock) -> None:
        super().__init__()
        self.bus, self.node_id, self.clock = bus, proto.check_node(node_id), clock
        self.network = BusNetwork(bus)
        self.cid = canopen_id(node_id)
        self.remote = canopen.RemoteNode(self.cid, object_dictionary(node_id))
        self.network.add_node(self.remote)
        self.remote.tpdo.read(from_od=True)
        self.remote.rpdo.read(from_od=True)
        self.inertia = RW90.inertia
        cid = self.cid
        self._telemetry_id, self._state_id = 0x180 + cid, 0x280 + cid
        self._status_id, self._heartbeat_id = 0x380 + cid, 0x700 + cid
        self._state: tuple[int, int, int] = (IDLE, 0, 0)
        self._status: tuple[float, int, int] | None = None
        self._heartbeat_state: tuple[int, int] | None = None

    def configure(self, params: WheelParams) -> None:
        self.inertia = params.inertia

    def send(self, cmd: proto.Command, now: float) -> None:
        rpdo = self.remote.rpdo[1]
        setpoint = 0.0
        if cmd.mode == Mode.SPEED:
            setpoint = rpm_to_rad_s(cmd.setpoint)
        elif cmd.mode == Mode.ACCELERATION:
            setpoint = self.inertia * rpm_to_rad_s(cmd.setpoint)
        rpdo["Requested state"].raw = _TO_STATE[cmd.mode]
        rpdo["Setpoint"].raw = setpoint
        rpdo["Setpoint sequence"].raw = cmd.sequence & 0xFF
        send_frame(self.bus, rpdo.cob_id, rpdo.data, now)
        if self.raw_listener:
            self.raw_listener(now, rpdo.cob_id, bytes(rpdo.data), "tx")

    def receive(self, now: float) -> list[Incoming]:
        out = []
        tpdo = self.remote.tpdo
        for msg in read_frames(self.bus):
            t = msg.timestamp if self.clock.simulated else now
            cob, data = msg.arbitration_id, bytes(msg.data)
            if self.raw_listener:
                self.raw_listener(t, cob, data, "rx")
            source = str(msg.channel) if getattr(self.bus, "reports_sources", False) else None
            if cob not in (self._telemetry_id, self._state_id, self._status_id):
                if cob == self._heartbeat_id and len(data) != 1:
                    self.bad_frames += 1
                elif cob != self._heartbeat_id:
                    self.foreign_frames += 1  # SDO, other nodes, other protocols
                continue
            which = {self._telemetry_id: 1, self._state_id: 2, self._status_id: 3}[cob]
            pdo_map = tpdo[which]
            if len(data) != len(pdo_map.data):
                self.bad_frames += 1
                continue
            pdo_map.on_message(cob, bytearray(data), t)
            values = {var.index: var.raw for var in pdo_map}
            if which == 2:
                self._state = (values[0x4001], values[0x4008], values[0x400C])
            elif which == 3:
                self._status = (values[0x4007], values[0x400D], values[0x400E])
                if heartbeat := self._heartbeat(force=True):
                    out.append(Incoming(t, heartbeat, source))
            else:
                state, faults, flags = self._state
                telemetry = proto.Telemetry(
                    self.node_id,
                    rad_s_to_rpm(float(values[0x4004])),
                    values[0x4005] / 1000,
                    _FROM_STATE.get(state, Mode.IDLE),
                    bool(faults),
                    bool(flags & 1),
                    int(values[0x400A]),
                    int(values[0x400B]),
                )
                out.append(Incoming(t, telemetry, source))
                if heartbeat := self._heartbeat(force=False):
                    out.append(Incoming(t, heartbeat, source))
        return out

    def _heartbeat(self, force: bool) -> proto.Heartbeat | None:
        """A heartbeat at each TPDO3, and at once when the faults or the refusal flag change."""
        state, faults, flags = self._state
        changed = (faults, flags & 2) != self._heartbeat_state
        if self._status is None or not (force or changed):
            return None
        self._heartbeat_state = (faults, flags & 2)
        temperature, seen, uptime = self._status
        return proto.Heartbeat(
            self.node_id,
            _FROM_STATE.get(state, Mode.IDLE),
            Fault(faults & 0xF),
            float(temperature),
            int(uptime),
            int(seen),
            bool(flags & 2),
        )


class CanopenProtocol(CanopenProfile):
    """CANopen (CiA 301) with the shipped object dictionary, on any python-can bus."""

    name = "canopen"
    description = "CANopen CiA 301 (canopen package): RPDO setpoints, TPDO telemetry, SDO, NMT"
    eds = EDS
    host_class = CanopenHostLink
    node_class = CanopenNodeLink

    def addresses(self, node_id: int) -> str:
        """CANopen node ``node_id + 1`` (CANopen ids start at 1) and its COB-IDs."""
        cid = canopen_id(node_id)
        return cob_ids(cid, (0x180 + cid, 0x280 + cid, 0x380 + cid), (0x200 + cid,))
