"""RS-232 transport: the wheel's CAN frames over a serial line, as a python-can bus.

Each frame travels as ``id (2 bytes, big-endian) | length (1) | data | CRC-16``
inside SLIP framing (RFC 1055). The CRC is CRC-16/CCITT-FALSE (poly 0x1021,
init 0xFFFF), the pair real wheels use. Frames whose CRC fails are dropped and
counted, never delivered. Because :class:`SlipSerialBus` is a ``can.BusABC``,
``WheelClient`` and ``WheelNode`` work over it unchanged.

SLIP and the CRC are a few lines each and no maintained package provides the
pair for pyserial, so they are written here.
"""

from __future__ import annotations

import time

import can

__all__ = ["SlipReader", "SlipSerialBus", "crc16_ccitt", "slip_decode", "slip_encode"]

END, ESC, ESC_END, ESC_ESC = 0xC0, 0xDB, 0xDC, 0xDD
MAX_BYTES_PER_READ = 1 << 16  # a flood is read in bounded bites


def crc16_ccitt(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data``.

    Parameters
    ----------
    data : bytes
        The bytes.
    crc : int
        Initial value (chain calls over pieces).

    Returns
    -------
    int
        The CRC, 0..65535.
    """
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CCITT_TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


def _ccitt_shifts(high: int) -> int:
    """The CRC-16/CCITT register's 8 shifts of a byte in its high half (0x1021, MSB first)."""
    crc = high << 8
    for _ in range(8):
        crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        crc &= 0xFFFF
    return crc


# the 8 shifts of each high byte, so a byte costs one look-up (the low byte only shifts up)
_CCITT_TABLE = tuple(_ccitt_shifts(i) for i in range(256))


def slip_encode(payload: bytes) -> bytes:
    """Frame ``payload`` with SLIP: END, escaped bytes, END.

    Parameters
    ----------
    payload : bytes
        The bytes to send.

    Returns
    -------
    bytes
        The framed bytes.
    """
    body = payload.replace(bytes([ESC]), bytes([ESC, ESC_ESC])).replace(
        bytes([END]), bytes([ESC, ESC_END])
    )
    return bytes([END]) + body + bytes([END])


def slip_decode(body: bytes) -> bytes:
    """Undo SLIP escaping of one frame body (without its END bytes); ValueError if malformed.

    Parameters
    ----------
    body : bytes
        One frame's escaped bytes.

    Returns
    -------
    bytes
        The payload.
    """
    out = bytearray()
    it = iter(body)
    for byte in it:
        if byte == ESC:
            nxt = next(it, None)
            if nxt == ESC_END:
                out.append(END)
            elif nxt == ESC_ESC:
                out.append(ESC)
            else:
                raise ValueError("bad SLIP escape")
        else:
            out.append(byte)
    return bytes(out)


class SlipReader:
    """Cuts a byte stream into SLIP frame bodies; bytes outside frames are dropped."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return the bodies of the frames they completed (empty ones skipped).

        Parameters
        ----------
        data : bytes
            What the port delivered.

        Returns
        -------
        list of bytes
            Escaped frame bodies, oldest first.
        """
        self._buffer += data
        bodies = []
        while True:
            start = self._buffer.find(END)
            if start < 0:
                self._buffer.clear()
                break
            end = self._buffer.find(END, start + 1)
            if end < 0:
                del self._buffer[:start]
                break
            body = bytes(self._buffer[start + 1 : end])
            del self._buffer[:end]  # the closing FEND may open the next frame
            if body:
                bodies.append(body)
        if len(self._buffer) > MAX_BYTES_PER_READ:  # a frame that never ends: drop it
            self._buffer.clear()
        return bodies


def pack(msg: can.Message) -> bytes:
    """One CAN frame as a CRC-protected serial payload."""
    head = msg.arbitration_id.to_bytes(2, "big") + bytes([len(msg.data)]) + bytes(msg.data)
    return head + crc16_ccitt(head).to_bytes(2, "big")


def unpack(payload: bytes) -> can.Message | None:
    """Inverse of :func:`pack`; None when the length or the CRC is wrong."""
    if len(payload) < 5 or len(payload) != 5 + payload[2] or payload[2] > 8:
        return None
    if crc16_ccitt(payload[:-2]) != int.from_bytes(payload[-2:], "big"):
        return None
    return can.Message(
        arbitration_id=int.from_bytes(payload[:2], "big"), data=payload[3:-2], is_extended_id=False
    )


class SlipSerialBus(can.BusABC):
    """A python-can bus over a serial port (pyserial) with SLIP framing and CRC-16.

    Parameters
    ----------
    port : serial.Serial or str
        An open pyserial port, or a pyserial URL/device name (``/dev/ttyUSB0``,
        ``loop://``) opened at ``baudrate``.
    baudrate : int
        Line speed when ``port`` is a name (default 115200).
    **kwargs
        Passed on to :class:`can.BusABC`.
    """

    def __init__(self, port, baudrate: int = 115200, **kwargs) -> None:
        import serial

        if isinstance(port, str):
            port = serial.serial_for_url(port, baudrate=baudrate, timeout=0)
        self.port = port
        self._buffer = bytearray()
        self.bad_frames = 0
        super().__init__(channel=getattr(port, "name", str(port)), **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.port.write(slip_encode(pack(msg)))

    def _recv_internal(self, timeout: float | None):
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            msg = self._next_frame()
            if msg is not None:
                msg.timestamp = time.time()
                return msg, False
            waiting = self.port.in_waiting
            if waiting:
                self._buffer += self.port.read(waiting)
                continue
            if deadline is not None and time.monotonic() >= deadline:
                return None, False
            time.sleep(1e-4)

    def _next_frame(self) -> can.Message | None:
        while True:
            start = self._buffer.find(END)
            if start < 0:
                self._buffer.clear()
                return None
            end = self._buffer.find(END, start + 1)
            if end < 0:
                del self._buffer[:start]
                return None
            body = bytes(self._buffer[start + 1 : end])
            del self._buffer[:end]  # keep the closing END: it may open the next frame
            if not body:
                continue
            try:
                msg = unpack(slip_decode(body))
            except ValueError:
                msg = None
            if msg is None:
                self.bad_frames += 1
                continue
            return msg

    def shutdown(self) -> None:
        super().shutdown()
        self.port.close()


class FdPort:
    """A pyserial-like port on a file descriptor (a pseudo-terminal's master side).

    Writes never block: bytes the other side does not read in time are dropped
    and counted in :attr:`dropped_writes`, as a UART would overrun.

    Parameters
    ----------
    fd : int
        An open descriptor; the port owns it and closes it.
    name : str
        What to call it in messages.
    """

    def __init__(self, fd: int, name: str = "pty") -> None:
        import os

        os.set_blocking(fd, False)
        self.fd, self.name = fd, name
        self.dropped_writes = 0

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read."""
        import fcntl
        import termios

        buf = fcntl.ioctl(self.fd, termios.FIONREAD, b"\0\0\0\0")
        return int.from_bytes(buf, "little")

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes, b'' when none are waiting."""
        import os

        try:
            return os.read(self.fd, size)
        except (BlockingIOError, OSError):
            return b""

    def write(self, data: bytes) -> int:
        """Write ``data``; what does not fit is dropped (counted)."""
        import os

        try:
            return os.write(self.fd, data)
        except (BlockingIOError, OSError):
            self.dropped_writes += 1
            return 0

    def close(self) -> None:
        """Close the descriptor."""
        import os

        try:
            os.close(self.fd)
        except OSError:
            pass


def open_pty(baudrate: int = 115200):
    """A pseudo-terminal pair in raw mode: (the twin's end, a pyserial port on the other).

    Parameters
    ----------
    baudrate : int
        Nominal line speed for the pyserial end (a pty does not throttle).

    Returns
    -------
    tuple
        (:class:`FdPort` on the master side, ``serial.Serial`` on the slave path).
        The slave path is ``port.port`` of the second.
    """
    import os
    import tty

    import serial

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    path = os.ttyname(slave)
    host = serial.serial_for_url(path, baudrate=baudrate, timeout=0)
    os.close(slave)
    return FdPort(master, path), host
