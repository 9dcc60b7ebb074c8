"""A simulated reaction wheel that answers on any python-can bus.

``WheelNode`` runs :class:`WheelPhysics` and speaks a wheel protocol
(``rw.dbc`` by default; any of :mod:`rwlab.wheel.link`'s registry): it applies
commands (after the configured latency), sends telemetry at a fixed rate and a
heartbeat at 1 Hz and whenever a fault latches, and idles the wheel with a
WATCHDOG fault when valid commands stop.

It survives any traffic: what is not a valid command for it is dropped and
counted (:attr:`WheelNode.bad_frames`, :attr:`WheelNode.foreign_frames`); a
setpoint beyond the wheel's limits is refused, counted and reported by the
heartbeat's COMMAND_REJECTED bit; an error while polling is counted
(:attr:`WheelNode.errors`) and the wheel runs on.
``FaultInjection`` makes it misbehave on purpose, and
:meth:`WheelNode.schedule_faults` does so by name at given times
(:mod:`rwlab.wheel.faults`).

On a :class:`SimClock` the node advances whenever the clock does; on the wall
clock, :meth:`WheelNode.start` runs it in a background thread.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rwlab.errors import ConfigError
from rwlab.wheel import protocol as proto
from rwlab.wheel.clock import SimClock, WallClock
from rwlab.wheel.faults import ScheduledFault
from rwlab.wheel.link import get_protocol
from rwlab.wheel.physics import RW90, Fault, Mode, WheelParams, WheelPhysics

WATCHDOG_S = 1.0  # the simulated wheel's command watchdog, s (a design choice)

__all__ = ["FaultInjection", "WheelNode"]


@dataclass
class FaultInjection:
    """Ways to make the simulated wheel misbehave (all off by default).

    Attributes
    ----------
    drop_rate : float
        Fraction of outgoing frames silently dropped.
    corrupt_rate : float
        Fraction of outgoing frames with one byte altered (fails the checksum).
    extra_delay : float
        Seconds added before every outgoing frame.
    silent : bool
        The node sends nothing at all.
    stuck_speed : bool
        Reported speed frozen at its value when this was switched on.
    overcurrent : bool
        The motor driver draws a current above the fault threshold.
    speed_bias_rpm : float
        Added to the reported speed, rpm.
    dropout_until : float
        No telemetry frames are sent before this clock time, s (their counter
        still advances, so the driver counts them as lost).
    """

    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    extra_delay: float = 0.0
    silent: bool = False
    stuck_speed: bool = False
    overcurrent: bool = False
    speed_bias_rpm: float = 0.0
    dropout_until: float = -math.inf
    _stuck_value: float | None = field(default=None, repr=False)


class WheelNode:
    """A simulated wheel on a CAN bus.

    Parameters
    ----------
    bus : can.BusABC or serial port
        The transport: any python-can bus (virtual, socketcan, udp_multicast, the SLIP
        serial bus) for CAN protocols, a pyserial port for ``nsp``.
    node_id : int
        0..15; selects the frame ids (the address, for nsp).
    params : WheelParams
        Physics parameters (default RW90).
    clock : WallClock or SimClock
        Time source; a SimClock drives the node as it advances.
    telemetry_rate : float
        Telemetry frames per second, 2..1000 Hz.
    latency : float
        Seconds between a command's arrival and its effect (default 0.02, the paper's).
    watchdog : float
        Seconds without a valid command before a moving wheel is idled with a
        WATCHDOG fault; 0 disables.
    physics_dt : float
        Largest physics step, s.
    faults : FaultInjection, optional
    seed : int
        For measurement noise and fault injection.
    protocol : str
        The wheel protocol by name (:func:`rwlab.wheel.link.get_protocol`): ``rwlab``
        (default), ``canopen``, ``nsp`` or a registered one.
    """

    def __init__(
        self,
        bus: Any,
        node_id: int = 0,
        params: WheelParams = RW90,
        *,
        clock: WallClock | SimClock | None = None,
        telemetry_rate: float = 100.0,
        latency: float = 0.02,
        watchdog: float = WATCHDOG_S,
        physics_dt: float = 1e-3,
        faults: FaultInjection | None = None,
        seed: int = 0,
        protocol: str = "rwlab",
    ) -> None:
        if not 2.0 <= telemetry_rate <= 1000.0:
            raise ConfigError(f"telemetry_rate must be 2..1000 Hz, got {telemetry_rate}")
        for name, value in (("latency", latency), ("watchdog", watchdog)):
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"{name} must be ≥ 0 s, got {value}")
        if not 0 < physics_dt <= 0.01:
            raise ConfigError(f"physics_dt must be in (0, 0.01] s, got {physics_dt}")
        self.bus = bus
        self.node_id = proto.check_node(node_id)
        self.clock = clock or WallClock()
        self.wheel = WheelPhysics(params, seed)
        self.period = 1.0 / telemetry_rate
        self.latency = latency
        self.watchdog = watchdog
        self.physics_dt = physics_dt
        self.inject = faults or FaultInjection()
        self.rng = np.random.default_rng(seed + 1)
        # the wheel's own timing jitter and frame loss (WheelParams), a stream of their own
        self._timing_rng = np.random.default_rng([seed, 0x4A4954])
        self.protocol = get_protocol(protocol)
        self.link = self.protocol.node_link(bus, self.node_id, clock=self.clock)
        self.link.configure(params)
        self.t = self.clock.now()
        self.t0 = self.t
        self._next_telemetry = self.t
        self._next_heartbeat = self.t
        self._pending: list[tuple[float, proto.Command]] = []
        self._scheduled: list[tuple[float, ScheduledFault]] = []
        self._outbox: list[tuple[float, proto.Telemetry | proto.Heartbeat]] = []
        self._last_command = self.t
        self._applied_seq = 0
        self._counter = 0
        self.commands_seen = 0
        self.rejected_commands = 0
        self.command_rejected = False  # latched until CLEAR_FAULT, reported by the heartbeat
        self.send_failures = 0
        self.errors = 0
        self.last_error: str | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        if isinstance(self.clock, SimClock):
            self.clock.attach(self.poll)

    def schedule_faults(self, faults: Iterable[ScheduledFault], origin: float) -> None:
        """Apply each :class:`ScheduledFault` at clock time ``origin + fault.t_s``, s."""
        with self._lock:
            due = self._scheduled + [(origin + f.t_s, f) for f in faults]
            self._scheduled = sorted(due, key=lambda item: item[0])

    def _apply(self, fault: ScheduledFault) -> None:
        wheel, inject = self.wheel, self.inject
        value = 0.0 if fault.value is None else fault.value  # None only for speed_sensor_stuck
        if fault.name == "friction":
            wheel.friction_factor = value
        elif fault.name == "torque_constant":
            wheel.torque_constant_factor = value
        elif fault.name == "current_limit":
            wheel.current_limit = value
        elif fault.name == "speed_sensor_bias":
            inject.speed_bias_rpm = value
        elif fault.name == "speed_sensor_stuck":
            inject.stuck_speed = True
        elif fault.name == "telemetry_dropout":
            inject.dropout_until = self.link.silent_until = self.t + value

    # -- running -------------------------------------------------------------------
    def poll(self, now: float) -> None:
        """Receive frames, then run physics and send frames up to time ``now``."""
        with self._lock:
            self._receive(now)
            while True:
                events = [now, self._next_telemetry, self._next_heartbeat]
                events += [t for t, _ in self._pending[:1]]
                events += [t for t, _ in self._outbox[:1]]
                events += [t for t, _ in self._scheduled[:1]]
                t_next = max(self.t, min(events))
                self._advance(t_next)
                self._handle_events()
                if self.t >= now:
                    break

    @property
    def bad_frames(self) -> int:
        """Damaged frames and datagrams received, plus frames the transport refused to send."""
        return (
            self.link.bad_frames
            + int(getattr(self.bus, "bad_datagrams", 0))
            + int(getattr(self.bus, "bad_frames", 0))
            + self.send_failures
        )

    @property
    def foreign_frames(self) -> int:
        """Valid frames of other protocols received (and ignored)."""
        return self.link.foreign_frames

    @property
    def twin_source(self) -> str | None:
        """Where another wheel answering under this node id was heard from, if one was."""
        return self.link.heard_twin()

    def _receive(self, now: float) -> None:
        for arrival, cmd in self.link.receive(now):
            if not self._within_limits(cmd):
                self.rejected_commands += 1
                self.command_rejected = True
                continue
            self._pending.append((max(arrival, self.t) + self.latency, cmd))
        self._pending.sort(key=lambda p: p[0])

    def _within_limits(self, cmd: proto.Command) -> bool:
        """A setpoint the wheel may obey (a node refuses what its host should never send)."""
        p = self.wheel.params
        limit = {Mode.SPEED: p.max_speed_rpm, Mode.ACCELERATION: p.max_accel_rpm_s}.get(cmd.mode)
        return math.isfinite(cmd.setpoint) and (limit is None or abs(cmd.setpoint) <= limit)

    def _advance(self, t_next: float) -> None:
        span = t_next - self.t
        if span > 0:
            steps = max(1, math.ceil(span / self.physics_dt - 1e-9))
            self.wheel.run(span / steps, steps)
        self.t = t_next

    def _handle_events(self) -> None:
        faults_before = (self.wheel.faults, self.command_rejected)
        while self._scheduled and self._scheduled[0][0] <= self.t:
            self._apply(self._scheduled.pop(0)[1])
        while self._pending and self._pending[0][0] <= self.t:
            _, cmd = self._pending.pop(0)
            self.commands_seen += 1
            self._last_command = self.t
            self._applied_seq = cmd.sequence
            if cmd.mode == Mode.CLEAR_FAULT:
                self.command_rejected = False
            self.wheel.command(cmd.mode, cmd.setpoint)
        if self.inject.overcurrent:
            self.wheel.forced_current = 2 * self.wheel.params.overcurrent_fault
        wd = self.watchdog
        if wd and self.wheel.mode != Mode.IDLE and self.t - self._last_command > wd:
            self.wheel.latch(Fault.WATCHDOG)
        if self.t >= self._next_telemetry:
            frame = self._telemetry()
            if self.t >= self.inject.dropout_until:
                self._queue(frame)
            self._next_telemetry += self.period
            if self._next_telemetry <= self.t:  # fell behind (wall clock): do not burst
                self._next_telemetry = self.t + self.period
        if (
            self.t >= self._next_heartbeat
            or (
                self.wheel.faults,
                self.command_rejected,
            )
            != faults_before
        ):
            self._queue(
                proto.Heartbeat(
                    self.node_id,
                    self.wheel.mode,
                    self.wheel.faults,
                    self.wheel.temperature,
                    int(self.t - self.t0),
                    self.commands_seen,
                    bus_voltage=self.wheel.measured_bus_voltage(),
                    command_rejected=self.command_rejected,
                )
            )
            if self.t >= self._next_heartbeat:
                self._next_heartbeat += 1.0
        self._flush()

    def _telemetry(self) -> proto.Telemetry:
        speed = self.wheel.measured_speed_rpm() + self.inject.speed_bias_rpm
        if self.inject.stuck_speed:
            if self.inject._stuck_value is None:
                self.inject._stuck_value = speed
            speed = self.inject._stuck_value
        self._counter = (self._counter + 1) & 0xFF
        return proto.Telemetry(
            self.node_id,
            speed,
            self.wheel.measured_current(),
            self.wheel.mode,
            bool(self.wheel.faults),
            self.wheel.speed_limited,
            self._applied_seq,
            self._counter,
        )

    def _queue(self, frame: proto.Telemetry | proto.Heartbeat) -> None:
        p = self.wheel.params
        if p.frame_loss_rate and self._timing_rng.random() < p.frame_loss_rate:
            return  # lost on the way (the telemetry counter shows it)
        jitter = p.telemetry_jitter_s * self._timing_rng.random() if p.telemetry_jitter_s else 0.0
        self._outbox.append((self.t + self.inject.extra_delay + jitter, frame))
        if jitter:
            self._outbox.sort(key=lambda item: item[0])

    def _flush(self) -> None:
        while self._outbox and self._outbox[0][0] <= self.t:
            release, frame = self._outbox.pop(0)
            if self.inject.silent or self.rng.random() < self.inject.drop_rate:
                continue
            corrupt = None
            if self.rng.random() < self.inject.corrupt_rate:
                corrupt = int(self.rng.integers(0, 7))
            try:
                self.link.send(frame, release, corrupt)
            except Exception:  # a full or broken transport must not kill the wheel
                self.send_failures += 1

    # -- wall-clock thread -------------------------------------------------------------
    def start(self, poll_period: float = 2e-4) -> WheelNode:
        """Run on the wall clock in a background thread (not for a SimClock)."""
        if isinstance(self.clock, SimClock):
            raise ConfigError("a node on a SimClock runs when the clock advances; do not start it")
        if self._thread is None:
            self._stop.clear()
            # the first step loads the twin's compiled kernels (~1 s): before it answers,
            # so a client's first request is not lost to a timeout (python-canopen's SDO
            # client waits 0.3 s)
            self._poll_once()
            self._thread = threading.Thread(
                target=self._run,
                args=(poll_period,),
                daemon=True,
                name=f"wheel-node-{self.node_id}",
            )
            self._thread.start()
        return self

    def _run(self, poll_period: float) -> None:
        while not self._stop.is_set():
            self._poll_once()
            self._stop.wait(poll_period)

    def _poll_once(self) -> None:
        try:
            self.poll(self.clock.now())
        except Exception as exc:  # stray traffic or a transport hiccup: count, run on
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"

    def stop(self) -> None:
        """Stop the thread (if any) and detach from a SimClock."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if isinstance(self.clock, SimClock):
            self.clock.detach(self.poll)
        self.link.close()

    def __enter__(self) -> WheelNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
