"""CAN frames between processes over UDP multicast, kept on one channel and one host.

The wire format is python-can's ``udp_multicast`` (one msgpack map per
datagram, port 43113), so python-can tools on the same group still see the
frames. What python-can's bus does not do, and a bench needs, is done here:

- **isolation**: the socket is bound to the group address itself (Linux then
  delivers only datagrams sent to that group, not every group on the port) and
  ``IP_MULTICAST_ALL`` is off; membership and sending use one interface,
  the loopback (127.0.0.1) unless a channel names another, and the TTL is 0,
  so frames never leave the host unless asked to;
- **robustness**: a datagram that is not a CAN frame (not msgpack, wrong
  fields, a data length beyond 8 or 64 bytes) is dropped and counted in
  :attr:`LoopbackMulticastBus.bad_datagrams`, never raised;
- **sources**: each bus sends from its own socket, so every received frame
  carries its sender (``msg.channel = "ip:port"``) and this bus's own frames are
  not echoed back to it; a driver uses this to see two wheels answering under
  one node id.

A channel is ``GROUP`` or ``GROUP@IFACE_ADDRESS`` (e.g.
``239.74.163.2@192.168.1.10`` to reach another machine through that NIC).
"""

from __future__ import annotations

import ipaddress
import select
import socket
import struct
import time
from typing import Any

import can
import msgpack

from rwlab.errors import ConfigError

__all__ = ["DEFAULT_GROUP", "PORT", "LoopbackMulticastBus", "parse_channel"]

DEFAULT_GROUP = "239.74.163.2"
PORT = 43113  # python-can's udp_multicast port
IP_MULTICAST_ALL = 49  # Linux <linux/in.h>; Python's socket module does not name it
RECEIVE_BUFFER = 4 << 20  # bytes
MAX_DATAGRAMS_PER_READ = 512  # a flood of junk costs one bounded read, then the caller runs


def parse_channel(channel: str) -> tuple[str, str]:
    """Split ``GROUP[@IFACE_ADDRESS]`` into the IPv4 multicast group and interface address.

    Parameters
    ----------
    channel : str
        ``"239.74.163.2"`` (loopback) or ``"239.74.163.2@192.168.1.10"``.

    Returns
    -------
    tuple of str
        (group, interface address).
    """
    group, _, iface = channel.partition("@")
    try:
        group_ip = ipaddress.IPv4Address(group.strip())
        iface_ip = ipaddress.IPv4Address(iface.strip() or "127.0.0.1")
    except ValueError as exc:
        raise ConfigError(
            f"udp_multicast channel {channel!r} must be GROUP or GROUP@INTERFACE_ADDRESS with "
            f"IPv4 addresses, e.g. {DEFAULT_GROUP} or {DEFAULT_GROUP}@192.168.1.10"
        ) from exc
    if not group_ip.is_multicast:
        raise ConfigError(f"{group} is not a multicast group (224.0.0.0/4), e.g. {DEFAULT_GROUP}")
    return str(group_ip), str(iface_ip)


def _to_message(datagram: bytes) -> can.Message | None:
    """A python-can udp_multicast datagram as a message; None for anything else."""
    try:
        fields = msgpack.unpackb(datagram, raw=False)
        if not isinstance(fields, dict):
            return None
        allowed = {
            "timestamp",
            "arbitration_id",
            "is_extended_id",
            "is_remote_frame",
            "is_error_frame",
            "dlc",
            "data",
            "is_fd",
            "bitrate_switch",
            "error_state_indicator",
        }
        kwargs: dict[str, Any] = {k: v for k, v in fields.items() if k in allowed}
        if not isinstance(kwargs.get("data", b""), (bytes, bytearray)):
            return None
        return can.Message(check=True, **kwargs)
    except Exception:  # msgpack's and can.Message's errors are many; all mean "not a frame"
        return None


class LoopbackMulticastBus(can.BusABC):
    """A python-can bus on one UDP multicast channel, on the loopback interface by default.

    Parameters
    ----------
    channel : str
        ``GROUP`` or ``GROUP@IFACE_ADDRESS`` (IPv4).
    port : int
        UDP port (python-can's 43113 by default).
    ttl : int
        Multicast TTL: 0 keeps frames on this host; raised to 1 when an interface is named.
    **kwargs
        Passed on to :class:`can.BusABC`.
    """

    reports_sources = True

    def __init__(
        self, channel: str = DEFAULT_GROUP, port: int = PORT, ttl: int | None = None, **kwargs: Any
    ) -> None:
        group, iface = parse_channel(channel)
        self.group, self.iface, self.port = group, iface, port
        ttl = (0 if iface == "127.0.0.1" else 1) if ttl is None else ttl
        self.bad_datagrams = 0
        self._rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            rx = self._rx
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            rx.setsockopt(socket.IPPROTO_IP, IP_MULTICAST_ALL, 0)
            # room for a burst (the kernel caps it at net.core.rmem_max)
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            rx.bind((group, port))  # only datagrams addressed to this group
            mreq = socket.inet_aton(group) + socket.inet_aton(iface)
            rx.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
            tx = self._tx
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(iface))
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", ttl))
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            tx.bind((iface, 0))
            self._me = "{}:{}".format(*tx.getsockname())
        except OSError as exc:
            self._rx.close()
            self._tx.close()
            raise ConfigError(
                f"cannot join multicast group {group} on interface {iface}: {exc}"
            ) from exc
        super().__init__(channel=channel, **kwargs)
        self.channel_info = f"udp multicast {group}:{port} on {iface}"

    @property
    def source(self) -> str:
        """This bus's own address ``ip:port`` (what receivers see as the sender)."""
        return self._me

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send one frame to the group (python-can's msgpack format)."""
        fields = {
            "timestamp": msg.timestamp,
            "arbitration_id": msg.arbitration_id,
            "is_extended_id": msg.is_extended_id,
            "is_remote_frame": msg.is_remote_frame,
            "is_error_frame": msg.is_error_frame,
            "channel": None,
            "dlc": msg.dlc,
            "data": bytes(msg.data),
            "is_fd": msg.is_fd,
            "bitrate_switch": msg.bitrate_switch,
            "error_state_indicator": msg.error_state_indicator,
        }
        try:
            self._tx.sendto(msgpack.packb(fields, use_bin_type=True), (self.group, self.port))
        except OSError as exc:
            raise can.CanOperationError(f"cannot send to {self.group}: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        for _ in range(MAX_DATAGRAMS_PER_READ):
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                ready, _, _ = select.select([self._rx], [], [], wait)
                if not ready:
                    return None, False
                datagram, (ip, port) = self._rx.recvfrom(65535)
            except OSError as exc:
                raise can.CanOperationError(f"cannot read from {self.group}: {exc}") from exc
            sender = f"{ip}:{port}"
            if sender == self._me:
                continue  # our own frame, looped back
            msg = _to_message(datagram)
            if msg is None:
                self.bad_datagrams += 1
                continue
            msg.timestamp = time.time()
            msg.channel = sender
            return msg, False
        return None, False  # a flood: let the caller run, read the rest next time

    def fileno(self) -> int:
        """The receiving socket's descriptor."""
        return self._rx.fileno()

    def shutdown(self) -> None:
        """Leave the group and close both sockets."""
        super().shutdown()
        self._rx.close()
        self._tx.close()
