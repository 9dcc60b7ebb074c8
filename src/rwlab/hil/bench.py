"""The scenario's wheels as nodes on a bus, driven through ``WheelClient`` in acceleration mode.

:class:`WheelBank` opens one client per wheel (each on its own bus handle
with a receive filter on its node's frames, as a driver on a real bus
would), starts twins (:class:`~rwlab.wheel.WheelNode`) when asked, checks
before the run that every wheel answers and only from one source, sends each
control period's torques as acceleration commands, reads back the wheels'
momenta from their reported speeds, and idles every wheel when it closes —
whatever made it close.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from rwlab.errors import ConfigError, WheelFault, WheelTimeout
from rwlab.interrupts import uninterrupted
from rwlab.wheel import protocol as proto
from rwlab.wheel.bus import open_bus
from rwlab.wheel.client import WheelClient
from rwlab.wheel.clock import SimClock, WallClock
from rwlab.wheel.node import WheelNode
from rwlab.wheel.physics import Mode, WheelParams, rad_s_to_rpm, rpm_to_rad_s

if TYPE_CHECKING:
    import can

__all__ = ["WheelBank", "WheelReading", "check_multidrop", "twin_params_toml"]


def check_multidrop(protocol: str) -> None:
    """Refuse a protocol whose wheels cannot share the bus ``hil`` flies them on.

    Parameters
    ----------
    protocol : str
        A registry name (:func:`rwlab.wheel.link.get_protocol`).

    Raises
    ------
    ConfigError
        The protocol is unknown, or runs on a byte stream (NSP over a pty is one
        point-to-point link per wheel, not a multi-drop bus).
    """
    from rwlab.wheel.link import get_protocol

    if "can" not in get_protocol(protocol).transports:
        raise ConfigError(
            f"protocol {protocol!r} runs on a serial byte stream, one wheel per link (a pty "
            "here), and hil flies every wheel on one shared bus: choose a CAN protocol "
            "(rwlab, canopen, canopen/oresat, canopen/cia402)"
        )


class _Only:
    """A bus handle that hands on only the frames with the given ids (a driver's
    acceptance filter). Written here because python-can's own filters end a
    non-blocking ``recv(timeout=0)`` at the first frame they drop, so a poll loop
    stops while frames still wait; this one drops and reads on."""

    def __init__(self, bus, *ids: int) -> None:
        self.bus, self.ids = bus, frozenset(ids)

    def send(self, msg, timeout=None) -> None:
        with uninterrupted():  # a stop inside python-can's queue can leave its lock taken
            self.bus.send(msg, timeout)

    def recv(self, timeout: float | None = None):
        with uninterrupted():
            msg = self.bus.recv(timeout)
            while msg is not None and (msg.is_extended_id or msg.arbitration_id not in self.ids):
                msg = self.bus.recv(0)
        return msg

    def shutdown(self) -> None:
        self.bus.shutdown()


@dataclass(frozen=True)
class WheelReading:
    """What one wheel last reported, at the instant the host reads it.

    Attributes
    ----------
    node : int
    speed_rpm : float
        Reported speed, rpm.
    current_a : float
        Reported motor current, A.
    age_s : float
        Time since that frame arrived, s.
    fresh : bool
        A new frame arrived since the last reading.
    """

    node: int
    speed_rpm: float
    current_a: float
    age_s: float
    fresh: bool


class WheelBank:
    """The satellite's wheels on one bus.

    Parameters
    ----------
    interface : str
        ``virtual``, ``udp_multicast``, ``socketcan`` or ``serial``.
    channel : str, optional
        The bus channel (the interface's default otherwise).
    nodes : sequence of int
        Node id of each wheel, in the order of the scenario's wheel axes.
    params : WheelParams
        The wheels' parameters (limits for the client; physics for the twins).
    clock : SimClock or WallClock
        A SimClock needs twins (it drives them).
    twins : bool
        Start a simulated wheel for each node (``virtual`` and ``udp_multicast`` only).
    telemetry_rate : float
        Twins' telemetry rate, Hz.
    latency : float
        Twins' command-to-effect latency, s.
    seed : int
        Twins' measurement noise (node n uses seed + n).
    timeout : float
        Seconds without telemetry before a wheel is declared silent (``WheelTimeout``).
    protocol : str
        The wheel protocol's registry name (``rwlab``, ``canopen``, ``canopen/oresat``,
        ``canopen/cia402``, :func:`rwlab.wheel.link.resolve_protocol`): a CAN protocol,
        since the wheels share one bus (a byte stream's pty is one wheel's).
    """

    def __init__(
        self,
        interface: str,
        channel: str | None,
        nodes,
        params: WheelParams,
        *,
        clock: SimClock | WallClock,
        twins: bool,
        telemetry_rate: float = 10.0,
        latency: float = 0.02,
        seed: int = 0,
        timeout: float = 0.5,
        protocol: str = "rwlab",
    ) -> None:
        check_multidrop(protocol)
        nodes = [int(n) for n in nodes]
        if len(set(nodes)) != len(nodes):
            raise ConfigError(f"node ids must differ, got {nodes}")
        if twins and interface not in ("virtual", "udp_multicast"):
            raise ConfigError(
                f"twins run on the virtual and udp_multicast buses; on {interface} the wheels "
                "must be real (leave the twins off)"
            )
        if isinstance(clock, SimClock) and not (twins and interface == "virtual"):
            raise ConfigError(
                "the simulated clock needs twins on the virtual bus (it drives them); "
                "use --realtime for other buses or for wheels that already run"
            )
        self.interface, self.nodes, self.params, self.clock = interface, nodes, params, clock
        self.protocol = protocol
        self.timeout = timeout
        self.simulated = isinstance(clock, SimClock)
        self.buses: list = []
        self.twins: list[WheelNode] = []
        self.clients: list[WheelClient] = []
        self.sent = dict.fromkeys(nodes, 0)
        self.stale = dict.fromkeys(nodes, 0)
        self.active = dict.fromkeys(nodes, True)
        self._seen: dict[int, int] = {}
        try:
            for n in nodes:
                bus = self._handle(channel, proto.TELEMETRY_ID + n, proto.HEARTBEAT_ID + n)
                client = WheelClient(
                    bus, n, params, clock=clock, timeout=timeout, protocol=protocol
                )
                client.link.set_telemetry_rate(telemetry_rate)  # a polled or timed protocol's
                self.clients.append(client)
            if twins:
                for n in nodes:
                    bus = self._handle(channel, proto.COMMAND_ID + n)
                    node = WheelNode(
                        bus,
                        n,
                        params,
                        clock=clock,
                        telemetry_rate=telemetry_rate,
                        latency=latency,
                        physics_dt=0.01 if self.simulated else 1e-3,
                        seed=seed + n,
                        protocol=protocol,
                    )
                    self.twins.append(node)
                    if not self.simulated:
                        node.start(poll_period=1e-3)
        except BaseException:
            self.close()
            raise

    def _handle(self, channel, *rwlab_ids: int) -> can.BusABC:
        """One bus handle for a client or a twin. On the ``rwlab`` protocol it takes only
        ``rwlab_ids`` (its node's frames); another protocol's link takes its own node's
        COB-IDs itself and counts the rest as foreign, so its handle takes every frame."""
        bus = self._open(channel)
        if self.protocol != "rwlab":
            return cast("can.BusABC", bus)
        return cast("can.BusABC", _Only(bus, *rwlab_ids))

    def _open(self, channel):
        bus = open_bus(self.interface, channel, simulated_clock=self.simulated)
        self.buses.append(bus)
        return bus

    # -- before the run -----------------------------------------------------------------
    def preflight(self, listen_s: float = 1.0) -> dict[int, int]:
        """Listen ``listen_s`` seconds: every wheel must answer, from one source only.

        Two wheels with one node id show as telemetry counters that repeat or
        step backwards (one source counts up by one per frame, a lost frame
        only skips ahead). Returns the frames heard per node.

        Raises
        ------
        WheelTimeout
            A wheel sent nothing.
        ConfigError
            A node id answers from two sources, or a wheel reports a latched fault.
        """
        for c in self.clients:
            # a protocol whose wheel streams only once configured (OreSat's TPDO timers)
            # sets it up now, so telemetry flows from the run's first period
            c.link.start_telemetry()
        for c in self.clients:
            c.drain()
        self.clock.sleep_until(self.clock.now() + listen_s)
        heard = {}
        for c in self.clients:
            frames = [f for _, f in c.drain() if isinstance(f, proto.Telemetry)]
            heard[c.node_id] = len(frames)
            if not frames:
                raise WheelTimeout(
                    f"wheel {c.node_id} sent no telemetry in {listen_s:g} s; check that it is "
                    f"powered and on the {self.interface} bus, and its node id"
                )
            steps = [(b.counter - a.counter) % 256 for a, b in itertools.pairwise(frames)]
            if any(s == 0 or s > 128 for s in steps):
                raise ConfigError(
                    f"node {c.node_id} answers from two sources (its telemetry counter repeats "
                    "or steps back); give each wheel its own node id before flying"
                )
            if c.faults:
                raise ConfigError(
                    f"wheel {c.node_id} reports a latched fault ({c.faults!s}); clear it "
                    "(rwlab wheel cmd clear) once its cause is understood"
                )
        return heard

    # -- each control period --------------------------------------------------------------
    def command(self, torques: np.ndarray) -> dict[int, WheelFault]:
        """Send each active wheel its torque (N,) N·m as an acceleration command, rpm/s.

        Returns the wheels that refused because they report a latched fault (node →
        the ``WheelFault``); they got no command.
        """
        # a hair under the limit: the wire's float32 may round the limit itself up past
        # it, and the wheel refuses that (measured: 313.7626021 rpm/s sent as 313.7626038;
        # a second of refused commands latched the wheel's watchdog and lost the wheel)
        limit = self.params.max_accel_rpm_s * (1 - 1e-6)
        refused = {}
        for c, tau in zip(self.clients, torques, strict=True):
            if not self.active[c.node_id]:
                continue
            accel = rad_s_to_rpm(float(tau) / self.params.inertia)
            try:
                c.set_acceleration(min(max(accel, -limit), limit))
            except WheelFault as exc:
                refused[c.node_id] = exc
                continue
            self.sent[c.node_id] += 1
        return refused

    def read(self) -> list[WheelReading]:
        """Every wheel's newest telemetry; ``WheelTimeout`` for a wheel silent > ``timeout``."""
        out = []
        now = self.clock.now()
        for c in self.clients:
            before = c.latest
            c.poll()
            last = c.latest_time
            if c.latest is None or last is None or now - last > self.timeout:
                raise WheelTimeout(
                    f"wheel {c.node_id} sent no telemetry for {self.timeout:g} s; the wheels "
                    "were idled"
                )
            fresh = c.latest is not before
            if not fresh:
                self.stale[c.node_id] += 1
            out.append(
                WheelReading(c.node_id, c.latest.speed_rpm, c.latest.current, now - last, fresh)
            )
        return out

    def momenta(self, readings: list[WheelReading]) -> np.ndarray:
        """The wheels' angular momenta from their reported speeds, N·m·s (N,)."""
        return np.array([self.params.inertia * rpm_to_rad_s(r.speed_rpm) for r in readings])

    def idle(self, node: int) -> None:
        """Idle one wheel (a failed one) and stop commanding it."""
        c = self.clients[self.nodes.index(node)]
        self.active[node] = False
        c.idle()
        self.sent[node] += 1

    def drain(self) -> dict[int, list]:
        """Every wheel's frames since the last drain: node → [(t, Telemetry | Heartbeat)]."""
        return {c.node_id: c.drain() for c in self.clients}

    # -- after the run ---------------------------------------------------------------------
    def lost_commands(self, wait_s: float = 1.2) -> dict[int, int | None]:
        """Commands each wheel never received: sent − the heartbeat's count (mod 2¹⁶).

        Waits ``wait_s`` for a heartbeat sent after the last command; None where none came.
        """
        deadline = self.clock.now() + wait_s
        seen: dict[int, int] = {}
        while self.clock.now() < deadline and len(seen) < len(self.clients):
            for c in self.clients:
                for t, f in c.drain():
                    if isinstance(f, proto.Heartbeat) and t >= deadline - wait_s:
                        seen[c.node_id] = f.commands_seen
            self.clock.sleep_until(min(deadline, self.clock.now() + 0.05))
        return {n: (self.sent[n] - seen[n]) % 65536 if n in seen else None for n in self.nodes}

    def lost_telemetry(self) -> dict[int, int]:
        """Telemetry frames lost per wheel (gaps in the frame counter)."""
        return {c.node_id: c.lost_frames for c in self.clients}

    def idle_all(self) -> list[str]:
        """Idle every wheel and wait (up to ``timeout``) for each to confirm; problems found."""
        problems = []
        for c in self.clients:
            try:
                seq = c.idle()
                self.sent[c.node_id] += 1
                c.wait_ack(seq)
            except Exception as exc:  # every wheel must get its idle
                problems.append(f"wheel {c.node_id}: {exc}")
        return problems

    def close(self) -> list[str]:
        """Idle every wheel, stop the twins, close the buses (safe to call twice)."""
        problems = self.idle_all() if self.clients else []
        for node in self.twins:
            node.stop()
        for bus in self.buses:
            try:
                bus.shutdown()
            except Exception:  # a broken bus must not hide the cause
                pass
        self.clients, self.twins, self.buses = [], [], []
        return problems

    def modes(self) -> dict[int, Mode | None]:
        """The mode each wheel last reported."""
        return {c.node_id: (c.latest.mode if c.latest else None) for c in self.clients}


def twin_params_toml(params: WheelParams) -> str:
    """The wheel parameters as a TOML ``[wheel]`` table (for ``rwlab wheel serve --params``).

    Parameters
    ----------
    params : WheelParams
        The wheel's parameters.

    Returns
    -------
    str
        The TOML text.
    """
    import json

    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)  # a TOML basic string is a JSON string
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = ["[wheel]"] + [f"{k} = {value(v)}" for k, v in params.to_dict().items()]
    return "\n".join(lines) + "\n"
