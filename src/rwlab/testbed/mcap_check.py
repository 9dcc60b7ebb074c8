"""Checking an MCAP file record by record: chunk, data-section and summary CRCs, indexes, counts.

A testbed record (:mod:`rwlab.testbed.record`) is read through :func:`scan`, which
hands every sound MCAP record to the reader's ``take`` and stops at the first
damage, saying where it is and what is wrong (:class:`RecordDamage`). The ``mcap``
library checks the chunk and data-section CRCs; the summary's CRC, the message
indexes and the summary's counts it does not check, so they are checked here
against the MCAP specification's layout.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Chunk, Footer, Message, MessageIndex, Statistics
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

__all__ = ["MAGIC", "RecordDamage", "scan"]

MAGIC = b"\x89MCAP0\r\n"
_OPCODES = frozenset(int(o) for o in Opcode)
_PARSE_ERRORS = (McapError, struct.error, EOFError, ValueError, UnicodeDecodeError, TypeError)


@dataclass(frozen=True)
class RecordDamage:
    """Where a record is damaged.

    Attributes
    ----------
    offset : int
        Byte offset of the first damaged record (or of the data's end, for a
        data-section CRC that does not match).
    size : int
        The file's size, bytes.
    why : str
        What is wrong there.
    """

    offset: int
    size: int
    why: str

    def text(self) -> str:
        """The damage in words.

        Returns
        -------
        str
            ``damaged at byte N of M (why)``.
        """
        return f"damaged at byte {self.offset} of {self.size} ({self.why})"


def scan(data: bytes, take: Callable[[Any, dict[int, str]], None]) -> RecordDamage | None:
    """Hand each MCAP record of ``data`` to ``take`` up to the first damage, checking every CRC.

    The ``mcap`` library checks each chunk's CRC (before any of the chunk's messages
    is taken) and the data section's; the summary is checked against what was read
    (its CRC, its message counts).

    Parameters
    ----------
    data : bytes
        The whole file.
    take : callable
        ``take(record, topics)`` for each MCAP record (chunks broken up), with the
        channel id → topic map of the channels declared so far (``take`` fills it).

    Returns
    -------
    RecordDamage or None
        Where reading stopped, or None for a sound file; a file that just ends (a
        killed recorder's) stops with ``why`` starting ``"the file ends"``.
    """
    size = len(data)
    stream = io.BytesIO(data)
    records = StreamReader(stream, skip_magic=False, emit_chunks=True, validate_crcs=True).records
    topics: dict[int, str] = {}
    counts: dict[int, int] = {}
    index: dict[int, list[tuple[int, int]]] = {}  # the last chunk's messages, by channel
    start = 0
    while True:
        start = stream.tell()
        if start >= len(MAGIC) and start < size and data[start] not in _OPCODES:
            return RecordDamage(
                start, size, f"no MCAP record starts there (byte 0x{data[start]:02x})"
            )
        try:
            r = next(records)
        except StopIteration:
            break
        except CRCValidationError:
            return RecordDamage(start, size, "the data section's CRC does not match")
        except _PARSE_ERRORS as exc:
            if start >= len(MAGIC) and start + 9 <= size:
                length = struct.unpack_from("<Q", data, start + 1)[0]
                if start + 9 + length <= size:  # the record is all there, and unreadable
                    return RecordDamage(start, size, f"an unreadable record: {_why(exc)}")
            return RecordDamage(start, size, "the file ends in the middle of a record")
        if isinstance(r, MessageIndex) and index.get(r.channel_id, []) != list(r.records):
            return RecordDamage(start, size, "a message index that does not match its chunk")
        try:
            if isinstance(r, Chunk):
                index = _chunk_index(r)
            inner = breakup_chunk(r, validate_crc=True) if isinstance(r, Chunk) else [r]
            for x in inner:
                if isinstance(x, Message):
                    if x.channel_id not in topics:  # every writer registers its channels first
                        return RecordDamage(start, size, "a message on a channel never declared")
                    counts[x.channel_id] = counts.get(x.channel_id, 0) + 1
                take(x, topics)
        except CRCValidationError:
            return RecordDamage(start, size, "a chunk's CRC does not match its data")
        except _PARSE_ERRORS as exc:
            return RecordDamage(start, size, f"an unreadable record: {_why(exc)}")
        if isinstance(r, Statistics) and dict(r.channel_message_counts) != counts:
            return RecordDamage(start, size, "its summary counts other messages than it holds")
        if isinstance(r, Footer):
            return _check_summary(data, r, start)
    return RecordDamage(start, size, "the file ends before its summary")


def _chunk_index(chunk: Chunk) -> dict[int, list[tuple[int, int]]]:
    """(log time, offset) of each message of an uncompressed chunk, by channel: what the
    message index records after it must hold (the MCAP spec's layout, walked by hand
    because the ``mcap`` reader skips those records without checking them)."""
    index: dict[int, list[tuple[int, int]]] = {}
    if chunk.compression:
        return index
    data, at = chunk.data, 0
    while at + 9 <= len(data):
        length = struct.unpack_from("<Q", data, at + 1)[0]
        if data[at] == Opcode.MESSAGE and at + 9 + 14 <= len(data):
            channel, _, log_time = struct.unpack_from("<HIQ", data, at + 9)
            index.setdefault(channel, []).append((log_time, at))
        at += 9 + length
    return index


def _check_summary(data: bytes, footer: Footer, footer_at: int) -> RecordDamage | None:
    """The footer's summary CRC (the ``mcap`` reader does not check it): the CRC of the
    summary section and of the footer's fields before the CRC, as the MCAP spec defines."""
    if footer.summary_crc == 0 or footer.summary_start == 0:
        return None
    covered = data[footer.summary_start : footer_at + 1 + 8 + 8 + 8]
    if zlib.crc32(covered) != footer.summary_crc:
        return RecordDamage(footer.summary_start, len(data), "its summary's CRC does not match")
    return None


def _why(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
