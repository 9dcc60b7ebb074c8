"""Experiment records: one append-only MCAP file per experiment.

Why MCAP: it is an open, self-describing log format that common tools read
(Foxglove, the ``mcap`` CLI, Python/C++/Rust/Go readers). Messages are written
in small uncompressed chunks, each with its CRC, and a chunk is closed and
flushed to the operating system at least every ``FLUSH_PERIOD`` s of wall time,
so a recorder killed with SIGKILL loses at most the last 100 ms, and the partial
file still opens (without its closing index). ``close()`` writes the summary
(message counts, chunk index, its own CRC) and the footer; the data section has
a CRC too. A reader therefore finds damage (a bad sector, a copy cut short) and
where it starts, instead of reading a record cut in half as if it were whole.

Channels (JSON messages, JSON-schema described):

- ``/command``   — t (s), sequence, mode, setpoint (rpm or rpm/s)
- ``/telemetry`` — t, speed_rpm, current_a, mode, fault_active, speed_limited,
  sequence_echo, counter
- ``/heartbeat`` — t, mode, faults, temperature_c, uptime_s, bus_voltage_v
- ``/event``     — t, kind, message (start, stop, fault, interrupt, error)
- ``/can``       — t, id, data (hex), direction (only if raw frames are recorded)

The ``rwlab`` metadata record holds the wheel parameters, the signal recipe,
Ts, the rwlab version and the DBC's SHA-256.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import struct
import time
import warnings
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import EndOfFile
from mcap.records import Channel, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rwlab._io import lock_exclusive, naming
from rwlab.errors import FileFormatError, RecordBusyError, RecordDamagedError, RwlabWarning
from rwlab.testbed.mcap_check import MAGIC, RecordDamage, scan

__all__ = [
    "CHANNELS",
    "Record",
    "RecordDamage",
    "RecordWriter",
    "partial_path",
    "read_record",
    "readable_seconds",
    "salvaging",
]

FLUSH_PERIOD = 0.05  # s of wall time between flushes to the OS (the promise is 100 ms)
# a chunk is closed at this size even sooner: damage then costs at most this much data
CHUNK_BYTES = 32 * 1024

_NUM = {"type": "number"}
_INT = {"type": "integer"}
CHANNELS: dict[str, dict] = {
    "/command": {"t": _NUM, "sequence": _INT, "mode": {"type": "string"}, "setpoint": _NUM},
    "/telemetry": {
        "t": _NUM,
        "speed_rpm": _NUM,
        "current_a": _NUM,
        "mode": {"type": "string"},
        "fault_active": {"type": "boolean"},
        "speed_limited": {"type": "boolean"},
        "sequence_echo": _INT,
        "counter": _INT,
    },
    "/heartbeat": {
        "t": _NUM,
        "mode": {"type": "string"},
        "faults": _INT,
        "temperature_c": _NUM,
        "uptime_s": _INT,
        "bus_voltage_v": _NUM,
    },
    "/event": {"t": _NUM, "kind": {"type": "string"}, "message": {"type": "string"}},
    "/can": {"t": _NUM, "id": _INT, "data": {"type": "string"}, "direction": {"type": "string"}},
}


def _schema(topic: str, props: dict | None = None) -> bytes:
    props = CHANNELS[topic] if props is None else props
    return json.dumps(
        {
            "title": f"rwlab{topic.replace('/', '.')}",
            "type": "object",
            "properties": props,
            "required": list(props),
        }
    ).encode()


def partial_path(path: str | os.PathLike) -> Path:
    """Where a record is written until it closes: ``name.partial.mcap`` beside ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The final record's path.

    Returns
    -------
    Path
    """
    path = Path(path)
    return path.with_name(f"{path.stem}.partial{path.suffix or '.mcap'}")


def _open_locked(path: Path, asked: Path) -> io.BufferedWriter:
    """Open ``path`` for writing under an exclusive lock, or raise ``RecordBusyError``;
    it is truncated only once the lock is held (a previous writer that renamed it to its
    record meanwhile: the lock is taken on the new file)."""
    busy = RecordBusyError(
        f"{asked} is being written by another run (into {path.name}); wait for it or "
        "choose another --out"
    )
    fd = lock_exclusive(path, busy)
    os.ftruncate(fd, 0)
    return os.fdopen(fd, "wb")


class RecordWriter:
    """Write one experiment record.

    The record is written to ``name.partial.mcap`` beside ``path`` under an
    exclusive lock, and renamed onto ``path`` when it closes: a second run on
    the same path is refused while the first writes, and a rerun with
    ``force`` replaces the old record only once the new one is complete. A
    killed run leaves the old record intact and its own partial record
    readable (until the next run on that path).

    Parameters
    ----------
    path : path-like
        The ``.mcap`` file. An existing file is an error unless ``force``.
    metadata : dict
        JSON-serialisable description (wheel, signal, Ts, versions).
    force : bool
        Replace an existing file (when this record closes).
    channels : dict, optional
        More topics beside :data:`CHANNELS` (topic → JSON-schema properties), for
        records that carry more than one wheel (``rwlab hil``).
    wall_clock : bool
        Close a chunk at least every :data:`FLUSH_PERIOD` s of wall time (the
        default, for a run on the wall clock). A run on a simulated clock passes
        False: its chunks then close by size alone, so the same run writes the
        same bytes on any machine, and a kill loses at most one chunk.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        metadata: dict,
        *,
        force: bool = False,
        channels: dict[str, dict] | None = None,
        wall_clock: bool = True,
    ) -> None:
        self.path = Path(path)
        self.wall_clock = wall_clock
        self.partial = partial_path(self.path)
        if self.path.exists() and not force:
            raise FileExistsError(f"{self.path} exists; pass force=True to replace it")
        if self.path.is_dir():
            raise IsADirectoryError(errno.EISDIR, "is a directory", str(self.path))
        if self.path.parent.exists() and not self.path.parent.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(self.path.parent))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = _open_locked(self.partial, self.path)
        try:
            with self._naming_the_record():
                self._start(metadata, channels)
        except BaseException:  # nothing recorded yet: leave no partial file, hold no lock
            self.partial.unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                self._fh.close()
            raise

    @contextlib.contextmanager
    def _naming_the_record(self) -> Iterator[None]:
        """An OS error writing (a full disk) names the record asked for, not its partial file."""
        try:
            yield
        except OSError as exc:
            if exc.filename in (None, str(self.partial)):
                raise naming(exc, self.path) from exc
            raise

    def _start(self, metadata: dict, channels: dict[str, dict] | None) -> None:
        self._writer = Writer(
            self._fh,
            chunk_size=CHUNK_BYTES,
            compression=CompressionType.NONE,
            use_chunking=True,
            use_statistics=True,
            enable_data_crcs=True,
        )
        self._writer.start(profile="rwlab", library="rwlab")
        self._channels = {}
        topics = {**CHANNELS, **(channels or {})}
        for topic, props in topics.items():
            sid = self._writer.register_schema(
                name=f"rwlab{topic.replace('/', '.')}",
                encoding="jsonschema",
                data=_schema(topic, props),
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=sid
            )
        self._writer.add_metadata("rwlab", {"json": json.dumps(metadata)})
        self._fh.flush()
        self._last_flush = time.monotonic()
        self.counts = dict.fromkeys(topics, 0)
        self.closed = False
        self.time_origin = 0.0
        """Subtracted from every message's ``t`` (the runner sets it to its first command)."""

    def write(self, topic: str, message: dict) -> None:
        """Append one message; ``message['t']`` is its clock time in seconds."""
        if self.closed:
            raise FileFormatError(f"{self.path} is closed")
        with self._naming_the_record():
            self._write(topic, message)

    def _write(self, topic: str, message: dict) -> None:
        message = {**message, "t": message["t"] - self.time_origin}
        stamp = max(0, round(message["t"] * 1e9))
        self._writer.add_message(
            self._channels[topic],
            log_time=stamp,
            publish_time=stamp,
            data=json.dumps(message, separators=(",", ":")).encode(),
        )
        self.counts[topic] += 1
        now = time.monotonic()
        if self.wall_clock and now - self._last_flush >= FLUSH_PERIOD:
            self._writer.flush()  # closes the chunk (its CRC) and flushes the file
            self._last_flush = now

    def event(self, t: float, kind: str, message: str = "") -> None:
        """Record an event (start, stop, fault, interrupt, error, ...)."""
        self.write("/event", {"t": t, "kind": kind, "message": message})

    def close(self) -> None:
        """Write the summary and footer, rename onto ``path`` and close (safe to call twice)."""
        if self.closed:
            return
        self.closed = True
        try:
            with self._naming_the_record():
                self._writer.finish()
                self._fh.flush()
                os.fsync(self._fh.fileno())
                os.replace(self.partial, self.path)  # under the lock: no other run sees a gap
        finally:  # a failed finish (a full disk) leaves the old record and this partial one
            with contextlib.suppress(OSError):  # its buffer cannot be flushed either
                self._fh.close()

    def discard(self) -> None:
        """Close and delete the partial record, leaving any old record at ``path`` as it was."""
        if self.closed:
            return
        self.closed = True
        self.partial.unlink(missing_ok=True)  # still under the lock
        self._fh.close()

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class Record:
    """An experiment record read back.

    Attributes
    ----------
    path : Path
        The file read.
    metadata : dict
        The ``rwlab`` metadata (empty if the file lost it).
    messages : dict
        topic → list of message dicts, in file order.
    complete : bool
        True when the file was closed properly (it has its footer).
    problem : str
        Why reading stopped early, when it did.
    damage : RecordDamage or None
        Where the file is damaged, for a record read with ``salvage=True``: its
        messages are those before the damage.
    """

    path: Path
    metadata: dict = field(default_factory=dict)
    messages: dict = field(default_factory=lambda: {t: [] for t in CHANNELS})
    complete: bool = False
    problem: str = ""
    damage: RecordDamage | None = None

    def topic(self, name: str) -> list[dict]:
        return self.messages.get(name, [])


# Salvaging is a choice of the reader's caller; the command line's --salvage sets it for
# every record a command reads, however deep in a workflow (see :func:`salvaging`).
_SALVAGE: ContextVar[bool] = ContextVar("rwlab_salvage_records", default=False)
#: How to read a damaged record anyway, in Python's words (the command line says --salvage).
SALVAGE_ADVICE = (
    "pass salvage=True to read up to the damage (a workflow: call it within "
    "rwlab.testbed.record.salvaging())"
)


@contextlib.contextmanager
def salvaging(on: bool = True) -> Iterator[None]:
    """Within the block, records read without an explicit ``salvage=`` are salvaged.

    Parameters
    ----------
    on : bool
        Salvage (True) or refuse (False) damaged records in the block.

    Yields
    ------
    None
    """
    token = _SALVAGE.set(on)
    try:
        yield
    finally:
        _SALVAGE.reset(token)


def _take(r, record: Record, topics: dict[int, str]) -> None:
    """One record of the file (a chunk broken up already) into ``record``."""
    if isinstance(r, Channel):
        topics[r.id] = r.topic
    elif isinstance(r, Message):
        topic = topics.get(r.channel_id)
        if topic is not None:  # the testbed's topics, and any a record added
            record.messages.setdefault(topic, []).append(json.loads(r.data))
    elif isinstance(r, Metadata) and r.name == "rwlab":
        record.metadata = json.loads(r.metadata.get("json", "{}"))
    elif isinstance(r, Footer):
        record.complete = True


def _parse(stream, record: Record, topics: dict[int, str]) -> None:
    for r in StreamReader(stream, skip_magic=False).records:
        _take(r, record, topics)


def read_record(path: str | os.PathLike, *, salvage: bool | None = None) -> Record:
    """Read a record, checking its CRCs and summary.

    A killed recorder's partial file (``NAME.partial.mcap``) ends early by
    nature and is read up to its end. Any other damage (a CRC that does not
    match, an unreadable record in the middle, a file that ends before its
    summary) is refused, or read up to the damage with ``salvage=True``.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.
    salvage : bool, optional
        Read a damaged record up to its damage instead of refusing it (its
        :attr:`Record.damage` says where). Default: as :func:`salvaging` says
        (off).

    Returns
    -------
    Record
        Its metadata and topics.

    Raises
    ------
    RecordDamagedError
        A damaged record, without ``salvage``: the message gives the byte
        offset of the damage and how much of the experiment is readable.
    FileFormatError
        A file that is not an MCAP record at all.
    """
    path = Path(path)
    if not path.is_file():
        partial = partial_path(path)
        if partial.is_file() and partial != path:
            raise FileNotFoundError(
                f"no such record: {path}; the run that wrote it did not finish and left "
                f"{partial} (readable up to where it stopped): use that file"
            )
        raise FileNotFoundError(f"no such record: {path}")
    data = path.read_bytes()
    if not data.startswith(MAGIC):
        raise FileFormatError(f"{path}: not an MCAP record (bad magic bytes)")
    record = Record(path)
    damage = scan(data, lambda r, topics: _take(r, record, topics))
    if not record.metadata:
        raise FileFormatError(f"{path}: an MCAP file, but not an rwlab record (no rwlab metadata)")
    if damage is None:
        return record
    killed = path.name.endswith(".partial.mcap") and damage.why.startswith("the file ends")
    if killed:  # a recorder killed mid-write: its file ends where it stopped
        record.problem = f"file ends early (at byte {damage.offset})"
        return record
    readable = _readable(record)
    if not (_SALVAGE.get() if salvage is None else salvage):
        raise RecordDamagedError(
            f"{path}: {damage.text()}; before it, {readable}: {SALVAGE_ADVICE} (every output "
            "then says it was salvaged), or copy the record again",
            offset=damage.offset,
            readable_s=readable_seconds(record),
        )
    record.problem = damage.text()
    record.damage = damage
    warnings.warn(
        f"{path}: salvaged: {damage.text()}; read up to the damage: {readable}",
        RwlabWarning,
        stacklevel=1,  # one place: a command that reads the record twice warns once
    )
    return record


def readable_seconds(record: Record) -> float:
    """Seconds of experiment a (cut) record holds.

    Parameters
    ----------
    record : Record
        A record as read.

    Returns
    -------
    float
        From its first command to its last telemetry frame, s, over every wheel
        of a record of several (0 without either).
    """
    commands = [t for t in record.messages if t.endswith("/command") and record.messages[t]]
    frames = [t for t in record.messages if t.endswith("/telemetry") and record.messages[t]]
    if not commands or not frames:
        return 0.0
    t0 = min(record.messages[t][0]["t"] for t in commands)
    return max(0.0, max(record.messages[t][-1]["t"] for t in frames) - t0)


def _readable(record: Record) -> str:
    """What a damaged record still holds, in words: seconds, samples at its Ts, frames."""
    seconds = readable_seconds(record)
    frames = sum(len(m) for t, m in record.messages.items() if t.endswith("/telemetry"))
    if not frames:
        return "no telemetry is readable"
    Ts = record.metadata.get("Ts")
    samples = ""
    if isinstance(Ts, (int, float)) and Ts > 0:
        samples = f"{int(seconds / Ts + 1e-9) + 1} samples at Ts = {Ts:g} s, "
    return f"the first {seconds:.1f} s are readable ({samples}{frames} telemetry frames)"


class RecordFollower:
    """Read a record that is still being written, a little more on each call.

    ``path`` is the record's final name; until it closes, its partial file is read.

    Only complete MCAP records are parsed, so a half-written message is never
    seen; the writer is never blocked (this only reads the file).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._offset = len(MAGIC)
        self._topics: dict[int, str] = {}
        self.metadata: dict = {}
        self.complete = False

    def poll(self) -> dict[str, list[dict]]:
        """New messages per topic since the last call."""
        out = Record(self.path)
        # while a run writes, the data are in its partial file, renamed (same bytes) on close
        source = self.path if self.path.exists() else partial_path(self.path)
        try:
            with open(source, "rb") as fh:
                fh.seek(self._offset)
                data = fh.read()
        except FileNotFoundError:
            return out.messages
        end = 0
        while end + 9 <= len(data):  # opcode (1) + length (8) + body
            length = struct.unpack_from("<Q", data, end + 1)[0]
            if end + 9 + length > len(data):
                break
            end += 9 + length
        if end:
            out.metadata = self.metadata
            try:
                _parse(io.BytesIO(MAGIC + data[:end]), out, self._topics)
            except EndOfFile:
                pass  # the stream ends before the footer: expected while recording
            self.metadata = out.metadata
            self.complete = self.complete or out.complete
            self._offset += end
        return out.messages
