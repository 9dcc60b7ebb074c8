"""Wheel protocols: what a driver and a twin need from one, and the registry of them by name.

A :class:`WheelProtocol` turns the protocol-free messages of
:mod:`rwlab.wheel.protocol` (:class:`Command`, :class:`Telemetry`,
:class:`Heartbeat`, all in the units of the twin: rpm, rpm/s, A, °C) into
bytes on a transport and back. It makes two ends:

- a :class:`HostLink` for :class:`rwlab.wheel.WheelClient` (send commands,
  receive telemetry and heartbeats),
- a :class:`NodeLink` for :class:`rwlab.wheel.WheelNode`, the twin (receive
  commands, send telemetry and heartbeats),

so one client and one twin serve every protocol. Anything on the transport
that is not a valid message for this end is dropped and counted by the link
(``bad_frames``: damaged; ``foreign_frames``: valid but not ours), never raised.

Protocols are found by name, as python-can finds its interfaces: the ones
built in (``rwlab``, ``canopen``, ``nsp`` and the profiles of a family, named
``family/profile`` such as ``canopen/cia402``) and any a package declares under
the entry-point group ``rwlab.wheel_protocols`` (``name = "module:Class"``).
Transports likewise under ``rwlab.wheel_transports``. A family's bare name
(``canopen``) is rwlab's own profile of it; :func:`resolve_protocol` turns the
CLI's ``--protocol F --profile P`` into a registry name.
"""

from __future__ import annotations

import abc
import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from typing import Any, ClassVar

from rwlab.errors import ConfigError
from rwlab.wheel.clock import SimClock, WallClock
from rwlab.wheel.physics import WheelParams
from rwlab.wheel.protocol import Command, Heartbeat, Telemetry

Clock = WallClock | SimClock

__all__ = [
    "PROTOCOL_GROUP",
    "TRANSPORT_GROUP",
    "HostLink",
    "Incoming",
    "NodeLink",
    "WheelProtocol",
    "get_protocol",
    "profiles_of",
    "protocol_names",
    "resolve_protocol",
]

PROTOCOL_GROUP = "rwlab.wheel_protocols"
TRANSPORT_GROUP = "rwlab.wheel_transports"

BUILTIN_PROTOCOLS = {
    "rwlab": "rwlab.wheel.dbc_link:RwlabProtocol",
    "canopen": "rwlab.wheel.canopen_wheel:CanopenProtocol",
    "nsp": "rwlab.wheel.nsp:NspProtocol",
    "nsp/nrwa-t6": "rwlab.wheel.nsp_t6:NrwaT6Protocol",
    "nsp/rw4-12": "rwlab.wheel.nsp_rw4:Rw412Protocol",
    "canopen/oresat": "rwlab.wheel.canopen_oresat:OresatProtocol",
    "canopen/cia402": "rwlab.wheel.canopen_cia402:Cia402Protocol",
}
OWN_PROFILE = "rwlab"  # ``--profile rwlab``: a family's bare name, rwlab's own profile of it

RawListener = Callable[[float, int, bytes, str], None]
"""Called with (time s, id, bytes, 'rx' or 'tx') for every frame, for recording the bus."""


@dataclass(frozen=True)
class Incoming:
    """A message a host link received.

    Attributes
    ----------
    t : float
        Arrival time on the caller's clock, s.
    frame : Telemetry or Heartbeat
    source : str or None
        The sender, where the transport tells (``ip:port`` on udp_multicast).
    """

    t: float
    frame: Telemetry | Heartbeat
    source: str | None = None


class HostLink(abc.ABC):
    """The driver's end of a protocol on one transport, for one wheel."""

    def __init__(self) -> None:
        self.bad_frames = 0
        self.foreign_frames = 0
        self.lost_commands = 0  # commands the wheel is known not to have received
        self.raw_listener: RawListener | None = None

    def configure(self, params: WheelParams) -> None:  # noqa: B027 - most links need nothing
        """Learn the wheel's parameters (a protocol in SI units needs its inertia).

        Parameters
        ----------
        params : WheelParams
            The wheel's parameters.
        """

    def set_telemetry_rate(self, rate: float) -> None:  # noqa: B027 - streaming links ignore it
        """Set the telemetry wanted (a polling protocol polls at this rate).

        Parameters
        ----------
        rate : float
            Telemetry per second, Hz.
        """

    def start_telemetry(self) -> None:  # noqa: B027 - streaming links need nothing
        """Set the wheel up to send its telemetry at the rate asked, before any command
        (a protocol whose wheel streams only once configured, e.g. OreSat's TPDO event
        timers, does it here; otherwise it does on its first command)."""

    def poll_now(self, now: float) -> None:  # noqa: B027 - streaming links need nothing
        """Ask the wheel for its state at once, off the polling schedule (a polled
        protocol polls now; a streaming one already sends it unasked).

        Parameters
        ----------
        now : float
            Clock time, s.
        """

    @abc.abstractmethod
    def send(self, cmd: Command, now: float) -> None:
        """Send a command to the wheel.

        Parameters
        ----------
        cmd : Command
            The command.
        now : float
            Clock time, s.

        Raises
        ------
        ProtocolError
            The protocol cannot encode it.
        """

    @abc.abstractmethod
    def receive(self, now: float) -> list[Incoming]:
        """Every valid telemetry and heartbeat of this wheel waiting now, oldest first.

        Parameters
        ----------
        now : float
            Clock time, s.

        Returns
        -------
        list of Incoming
        """

    def close(self) -> None:  # noqa: B027 - most links own nothing beyond the transport
        """Release what the link opened (not the transport)."""


class NodeLink(abc.ABC):
    """The twin's end of a protocol on one transport.

    Attributes
    ----------
    silent_until : float
        Clock time, s, before which a wheel that answers polls sends no reply (the
        ``telemetry_dropout`` fault: a streaming wheel's node just queues no frames).
    """

    def __init__(self) -> None:
        self.bad_frames = 0
        self.foreign_frames = 0
        self.silent_until = -math.inf

    def configure(self, params: WheelParams) -> None:  # noqa: B027 - most links need nothing
        """Learn the wheel's parameters (as :meth:`HostLink.configure`).

        Parameters
        ----------
        params : WheelParams
        """

    def close(self) -> None:  # noqa: B027 - most links own nothing beyond the transport
        """Release what the link opened (not the transport)."""

    @abc.abstractmethod
    def receive(self, now: float) -> list[tuple[float, Command]]:
        """Every valid command for this wheel waiting now.

        Parameters
        ----------
        now : float
            Clock time, s.

        Returns
        -------
        list of (float, Command)
            Each command with its arrival time, s, oldest first.
        """

    @abc.abstractmethod
    def send(self, frame: Telemetry | Heartbeat, t: float, corrupt: int | None = None) -> None:
        """Send telemetry or a heartbeat.

        Parameters
        ----------
        frame : Telemetry or Heartbeat
            What to send.
        t : float
            Clock time, s.
        corrupt : int, optional
            Fault injection: damage the encoded message by flipping bits of its byte at
            this index (modulo its length), as a noisy line would.
        """

    def heard_twin(self) -> str | None:
        """Whether another wheel answers under this node id.

        Returns
        -------
        str or None
            Its source, if one was heard.
        """
        return None


class WheelProtocol(abc.ABC):
    """A wheel protocol, registered by :attr:`name`.

    Subclasses set :attr:`name`, :attr:`description`, :attr:`transports` (the
    transports it runs on, ``"can"`` for any python-can bus, ``"stream"`` for a
    byte stream such as a serial port) and build the two links.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    transports: ClassVar[tuple[str, ...]] = ("can",)
    baudrate: ClassVar[int] = 115_200  # a serial line's speed, bit/s, unless the user sets one
    # the wheel model (a preset of `rwlab wheel models`) a twin of this protocol is unless
    # told otherwise: the family's own wheel where rwlab ships one, else paper A's RW90
    wheel: ClassVar[str] = "rw90"

    @abc.abstractmethod
    def host_link(self, transport: Any, node_id: int, *, clock: Clock) -> HostLink:
        """The driver's link to wheel ``node_id`` on ``transport``.

        Parameters
        ----------
        transport : can.BusABC or serial port
            What :func:`rwlab.wheel.bus.open_transport` opened for this protocol.
        node_id : int
            The wheel's node id, 0..15.
        clock : WallClock or SimClock
            The driver's clock. On a :class:`rwlab.wheel.SimClock` a link uses the
            senders' time stamps, and a polling link attaches itself to the clock.

        Returns
        -------
        HostLink
        """

    @abc.abstractmethod
    def node_link(self, transport: Any, node_id: int, *, clock: Clock) -> NodeLink:
        """The twin's link as wheel ``node_id`` on ``transport``.

        Parameters
        ----------
        transport, node_id, clock
            As for :meth:`host_link` (the twin's clock).

        Returns
        -------
        NodeLink
        """

    def identity(self) -> str:
        """What names the protocol's definition exactly, for records.

        Returns
        -------
        str
            The name, and the hash of a definition file where there is one.
        """
        return self.name

    def signal_ranges(self) -> dict[str, tuple[float, float, str]]:
        """The ranges its fixed-width signals carry (:mod:`rwlab.wheel.signal_fit` checks a
        wheel against them); a protocol that declares none is not checked.

        Returns
        -------
        dict
            Quantity (``speed_rpm``, ``current_a``, ``bus_voltage_v``, ``temperature_c``,
            ``setpoint``) → (lowest, highest, the signal's name).
        """
        return {}

    def addresses(self, node_id: int) -> str:
        """What the twin of wheel ``node_id`` answers on, in the protocol's terms (for ``serve``).

        Parameters
        ----------
        node_id : int
            The wheel's node id, 0..15.

        Returns
        -------
        str
        """
        return f"node {node_id}"


def _entry_points(group: str) -> dict[str, metadata.EntryPoint]:
    return {ep.name: ep for ep in metadata.entry_points(group=group)}


def protocol_names() -> dict[str, str]:
    """Every protocol by name, with where it comes from (built in or ``module:Class``).

    Returns
    -------
    dict
        name -> ``"module:Class"``, built-ins first, then entry points.
    """
    names = dict(BUILTIN_PROTOCOLS)
    for name, ep in sorted(_entry_points(PROTOCOL_GROUP).items()):
        names.setdefault(name, ep.value)
    return names


def get_protocol(name: str) -> WheelProtocol:
    """The protocol registered as ``name``.

    Parameters
    ----------
    name : str
        ``rwlab``, ``canopen``, ``nsp``, ``nsp/nrwa-t6``, ``nsp/rw4-12`` or a name a
        package registered under the entry-point group ``rwlab.wheel_protocols``.

    Returns
    -------
    WheelProtocol
        An instance.
    """
    names = protocol_names()
    if name not in names:
        raise ConfigError(
            f"unknown wheel protocol {name!r}; choose from {', '.join(names)} "
            f"(a package adds one under the entry-point group {PROTOCOL_GROUP!r})"
        )
    target = names[name]
    module_name, _, attr = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"wheel protocol {name!r} ({target}) cannot be loaded: {exc}") from exc
    protocol = cls()
    if not isinstance(protocol, WheelProtocol):
        raise ConfigError(f"wheel protocol {name!r} ({target}) is not a WheelProtocol")
    return protocol


def profiles_of(family: str) -> list[str]:
    """The profiles registered for protocol ``family`` (``rwlab`` for its bare name).

    Parameters
    ----------
    family : str
        A protocol family, e.g. ``canopen`` or ``nsp``.

    Returns
    -------
    list of str
        Profile names, rwlab's own first when the family's bare name is registered.
    """
    names = protocol_names()
    own = [OWN_PROFILE] if family in names else []
    return own + sorted(n.split("/", 1)[1] for n in names if n.startswith(f"{family}/"))


def resolve_protocol(protocol: str, profile: str | None) -> str:
    """The registry name of ``--protocol protocol --profile profile``.

    Parameters
    ----------
    protocol : str
        A protocol family (``canopen``) or a full registry name (``canopen/cia402``).
    profile : str or None
        A profile of the family; None leaves ``protocol`` as given.

    Returns
    -------
    str
        ``family/profile``, or the family's bare name for the ``rwlab`` profile.
    """
    if profile is None:
        return protocol
    if "/" in protocol:
        raise ConfigError(
            f"--protocol {protocol} already names a profile; give --protocol "
            f"{protocol.split('/', 1)[0]} --profile {profile}, or leave out --profile"
        )
    names = protocol_names()
    if f"{protocol}/{profile}" in names:
        return f"{protocol}/{profile}"
    if profile == OWN_PROFILE and protocol in names:
        return protocol
    known = profiles_of(protocol)
    if not known:
        raise ConfigError(
            f"unknown wheel protocol {protocol!r}; choose from "
            f"{', '.join(sorted({n.split('/', 1)[0] for n in names}))}"
        )
    raise ConfigError(
        f"protocol {protocol!r} has no profile {profile!r}; choose from {', '.join(known)} "
        "(`rwlab wheel protocols` lists them)"
    )
