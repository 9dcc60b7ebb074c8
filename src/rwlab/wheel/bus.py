"""Open the transport a wheel or driver talks on, by interface name (python-can's way).

Built in: ``virtual`` (in-process), ``socketcan`` (a Linux CAN device),
``udp_multicast`` (between processes: one group, the loopback interface unless
the channel is ``GROUP@IFACE_ADDRESS``, see :mod:`rwlab.wheel.udp`) and
``serial`` (RS-232: CAN frames in SLIP for CAN protocols, the raw port for
byte-stream protocols such as ``nsp``). A package adds an interface under the
entry-point group ``rwlab.wheel_transports``: ``name = "module:opener"`` with
``opener(channel, *, stream, simulated_clock, baudrate)`` returning a
python-can bus (``stream=False``) or a pyserial-like port (``stream=True``).
"""

from __future__ import annotations

import importlib
from importlib import metadata
from typing import TYPE_CHECKING, Any

from rwlab.errors import ConfigError

if TYPE_CHECKING:
    import can

__all__ = [
    "DEFAULT_CHANNELS",
    "INTERFACES",
    "open_bus",
    "open_serial_port",
    "open_transport",
    "transport_names",
]

INTERFACES = ("virtual", "socketcan", "udp_multicast", "serial")
DEFAULT_CHANNELS = {
    "virtual": "rwlab",
    "socketcan": "vcan0",
    "udp_multicast": "239.74.163.2",
    "serial": "/dev/ttyUSB0",
}
TRANSPORT_GROUP = "rwlab.wheel_transports"


def transport_names() -> dict[str, str]:
    """Every interface by name: the built-in ones, then those of entry points.

    Returns
    -------
    dict
        name -> where it comes from.
    """
    names = {name: "built in" for name in INTERFACES}
    for ep in metadata.entry_points(group=TRANSPORT_GROUP):
        names.setdefault(ep.name, ep.value)
    return names


def open_bus(
    interface: str,
    channel: str | None = None,
    *,
    simulated_clock: bool = False,
    baudrate: int = 115200,
) -> can.BusABC:
    """A python-can bus: ``virtual`` (in-process), ``socketcan`` (a Linux CAN device),
    ``udp_multicast`` (between processes on one machine: one group, on the loopback
    interface unless the channel is ``GROUP@IFACE_ADDRESS``) or ``serial`` (RS-232, SLIP).

    ``simulated_clock=True`` keeps the senders' time stamps on virtual buses, which
    a node and a driver sharing a :class:`SimClock` need.

    Parameters
    ----------
    interface : {'virtual', 'socketcan', 'udp_multicast', 'serial'}
        python-can's interface name (``serial``: rwlab's SLIP bus).
    channel : str, optional
        The channel or device (a default per interface).
    simulated_clock : bool
        Keep the senders' time stamps (virtual buses).
    baudrate : int
        Line speed of a serial bus.

    Returns
    -------
    can.BusABC
    """
    if interface not in INTERFACES:
        return _open_plugin(interface, channel, False, simulated_clock, baudrate)
    import can  # here, not at the top: the CLI's --help must not pay for python-can

    channel = channel or DEFAULT_CHANNELS[interface]
    try:
        if interface == "serial":
            from rwlab.wheel.serial import SlipSerialBus

            return SlipSerialBus(channel, baudrate=baudrate)
        if interface == "virtual":
            from rwlab.wheel.virtual import CopyingVirtualBus  # python-can's, copies made faster

            return CopyingVirtualBus(channel=channel, preserve_timestamps=simulated_clock)
        if interface == "socketcan":
            return can.Bus(interface="socketcan", channel=channel, bitrate=1_000_000)
        # one group, the loopback interface unless the channel names another (udp.py)
        from rwlab.wheel.udp import LoopbackMulticastBus

        return LoopbackMulticastBus(channel)
    except (OSError, can.CanError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"cannot open {interface} bus on {channel!r}: {exc}") from exc


def open_serial_port(channel: str, baudrate: int = 115200) -> Any:
    """A pyserial port (device name or pyserial URL), non-blocking reads.

    Parameters
    ----------
    channel : str
        ``/dev/ttyUSB0``, a pty's slave path, ``loop://``...
    baudrate : int
        Line speed, bit/s.

    Returns
    -------
    serial.Serial
    """
    import serial

    try:
        return serial.serial_for_url(channel, baudrate=baudrate, timeout=0)
    except (OSError, ValueError, serial.SerialException) as exc:
        raise ConfigError(f"cannot open serial port {channel!r}: {exc}") from exc


def open_transport(
    protocol: str,
    interface: str,
    channel: str | None = None,
    *,
    simulated_clock: bool = False,
    baudrate: int | None = None,
) -> Any:
    """The transport ``protocol`` needs on ``interface``: a python-can bus or a serial port.

    Parameters
    ----------
    protocol : str
        A wheel protocol name (:func:`rwlab.wheel.link.get_protocol`).
    interface : str
        One of :func:`transport_names`.
    channel : str, optional
        The interface's channel (its default when None).
    simulated_clock : bool
        Keep senders' time stamps (virtual buses on a SimClock).
    baudrate : int, optional
        Serial line speed, bit/s (default: the protocol's, e.g. 460800 for ``nsp/nrwa-t6``).

    Returns
    -------
    can.BusABC or serial port
    """
    from rwlab.wheel.link import get_protocol

    kinds = get_protocol(protocol).transports
    baudrate = baudrate or get_protocol(protocol).baudrate
    if "can" in kinds and interface != "serial":
        return open_bus(interface, channel, simulated_clock=simulated_clock, baudrate=baudrate)
    if "stream" in kinds and interface == "serial":
        return open_serial_port(channel or DEFAULT_CHANNELS["serial"], baudrate)
    if "can" in kinds:
        return open_bus(interface, channel, simulated_clock=simulated_clock, baudrate=baudrate)
    if interface not in INTERFACES:
        return _open_plugin(interface, channel, True, simulated_clock, baudrate)
    raise ConfigError(
        f"protocol {protocol!r} runs on a byte stream: use --interface serial "
        f"(a serial port or pty), not {interface!r}"
    )


def _open_plugin(
    interface: str, channel: str | None, stream: bool, simulated_clock: bool, baudrate: int
) -> Any:
    eps = {ep.name: ep for ep in metadata.entry_points(group=TRANSPORT_GROUP)}
    if interface not in eps:
        raise ConfigError(
            f"unknown interface {interface!r}; choose from {', '.join(transport_names())}"
        )
    module, _, attr = eps[interface].value.partition(":")
    opener = getattr(importlib.import_module(module), attr)
    return opener(channel, stream=stream, simulated_clock=simulated_clock, baudrate=baudrate)
