"""A record's raw CAN frames as a Vector ASC or BLF log, for CAN tools.

An experiment run with ``--raw-frames`` on a CAN protocol keeps every frame
the driver sent and received in its record's ``/can`` topic (time, id, data,
direction). :func:`write_can_log` writes them through python-can's own
writers (``can.ASCWriter``, ``can.BLFWriter``), so CANalyzer, SavvyCAN,
``python -m can.player`` and ``python -m can.logconvert`` read them; the
format is python-can's, rwlab adds nothing to it. Time stamps are the
record's start (``start_utc``, the wall time of the first command) plus the
record's time of each frame (s since the first command, on the experiment's
clock, simulated or not); direction is the driver's (``Tx`` sent by the
driver, ``Rx`` received).
"""

from __future__ import annotations

import os
from datetime import datetime
from pathlib import Path

import can

from rwlab._io import atomic_write_bytes
from rwlab.errors import ConfigError
from rwlab.testbed.record import read_record

__all__ = ["CAN_LOG_FORMATS", "can_messages", "write_can_log"]

CAN_LOG_FORMATS = ("asc", "blf")


def can_messages(record_path: str | os.PathLike) -> list[can.Message]:
    """The raw frames of a record as python-can messages, in record order.

    Parameters
    ----------
    record_path : path-like
        An ``.mcap`` record.

    Returns
    -------
    list of can.Message
    """
    record = read_record(record_path)
    frames = record.topic("/can")
    if not frames:
        protocol = record.metadata.get("protocol", "?")
        raise ConfigError(
            f"{record_path} holds no raw CAN frames (protocol {protocol!r}); record them with "
            "`rwlab experiment --raw-frames` on a CAN protocol (rwlab, canopen and its profiles)"
        )
    start = record.metadata.get("start_utc")
    origin = datetime.fromisoformat(start).timestamp() if start else 0.0
    return [
        can.Message(
            timestamp=origin + float(f["t"]),
            arbitration_id=int(f["id"]),
            data=bytes.fromhex(f["data"]),
            is_extended_id=int(f["id"]) > 0x7FF,
            is_rx=f.get("direction", "rx") == "rx",
        )
        for f in frames
    ]


def write_can_log(record_path: str | os.PathLike, out: str | os.PathLike, fmt: str) -> int:
    """Write a record's raw CAN frames to ``out`` as ``fmt``, atomically.

    Parameters
    ----------
    record_path : path-like
        An ``.mcap`` record made with raw frames.
    out : path-like
        The log file.
    fmt : {'asc', 'blf'}
        Vector ASCII or binary logging format.

    Returns
    -------
    int
        Frames written.
    """
    if fmt not in CAN_LOG_FORMATS:
        raise ConfigError(
            f"CAN log format must be one of {', '.join(CAN_LOG_FORMATS)}, got {fmt!r}"
        )
    messages = can_messages(record_path)

    def write(tmp: Path) -> None:
        writer = can.ASCWriter(tmp) if fmt == "asc" else can.BLFWriter(tmp)
        try:
            for msg in messages:
                writer.on_message_received(msg)
        finally:
            writer.stop()

    atomic_write_bytes(out, write)
    return len(messages)
