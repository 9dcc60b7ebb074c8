"""Open the bus a wheel or driver talks on, by interface name (python-can's way)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rwlab.errors import ConfigError

if TYPE_CHECKING:
    import can

__all__ = ["DEFAULT_CHANNELS", "INTERFACES", "open_bus"]

INTERFACES = ("virtual", "socketcan", "udp_multicast", "serial")
DEFAULT_CHANNELS = {
    "virtual": "rwlab",
    "socketcan": "vcan0",
    "udp_multicast": "239.74.163.2",
    "serial": "/dev/ttyUSB0",
}


def open_bus(
    interface: str,
    channel: str | None = None,
    *,
    simulated_clock: bool = False,
    baudrate: int = 115200,
) -> can.BusABC:
    """A python-can bus: ``virtual`` (in-process), ``socketcan`` (a Linux CAN device),
    ``udp_multicast`` (between processes on one machine) or ``serial`` (RS-232, SLIP).

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
        raise ConfigError(f"unknown interface {interface!r}; choose from {', '.join(INTERFACES)}")
    import can  # here, not at the top: the CLI's --help must not pay for python-can

    channel = channel or DEFAULT_CHANNELS[interface]
    try:
        if interface == "serial":
            from rwlab.wheel.serial import SlipSerialBus

            return SlipSerialBus(channel, baudrate=baudrate)
        if interface == "virtual":
            return can.Bus(
                interface="virtual", channel=channel, preserve_timestamps=simulated_clock
            )
        if interface == "socketcan":
            return can.Bus(interface="socketcan", channel=channel, bitrate=1_000_000)
        # hop limit / TTL 0: the frames never leave this host (loopback delivery only)
        return can.Bus(interface="udp_multicast", channel=channel, hop_limit=0)
    except (OSError, can.CanError, ValueError) as exc:
        raise ConfigError(f"cannot open {interface} bus on {channel!r}: {exc}") from exc
