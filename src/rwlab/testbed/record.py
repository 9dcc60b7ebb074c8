"""Experiment records: one append-only MCAP file per experiment.

Why MCAP: it is an open, self-describing log format that common tools read
(Foxglove, the ``mcap`` CLI, Python/C++/Rust/Go readers), and written
*unchunked* every message lands in the file as soon as it is written. The
writer flushes to the operating system at least every ``FLUSH_PERIOD`` s of
wall time, so a recorder killed with SIGKILL loses at most the last 100 ms,
and the partial file still opens (without its closing index). ``close()``
writes the summary and footer.

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

import errno
import io
import json
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from rwlab.errors import FileFormatError, RecordBusyError

__all__ = ["CHANNELS", "Record", "RecordWriter", "partial_path", "read_record"]

FLUSH_PERIOD = 0.05  # s of wall time between flushes to the OS (the promise is 100 ms)
MAGIC = b"\x89MCAP0\r\n"

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


def _open_locked(path: Path, asked: Path):
    """Open ``path`` for writing under an exclusive lock, or raise ``RecordBusyError``.

    ``fcntl.flock`` (advisory, released by the OS when the process dies) guards
    the file; it is truncated only once the lock is held, and the lock is
    retried when the file was renamed away between opening and locking.
    """
    import fcntl

    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RecordBusyError(
                f"{asked} is being written by another run (into {path.name}); wait for it or "
                "choose another --out"
            ) from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            return os.fdopen(fd, "wb")
        os.close(fd)  # the previous writer renamed it to its record meanwhile: start again


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
    """

    def __init__(
        self,
        path: str | os.PathLike,
        metadata: dict,
        *,
        force: bool = False,
        channels: dict[str, dict] | None = None,
    ) -> None:
        self.path = Path(path)
        self.partial = partial_path(self.path)
        if self.path.exists() and not force:
            raise FileExistsError(f"{self.path} exists; pass force=True to replace it")
        if self.path.is_dir():
            raise IsADirectoryError(errno.EISDIR, "is a directory", str(self.path))
        if self.path.parent.exists() and not self.path.parent.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(self.path.parent))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = _open_locked(self.partial, self.path)
        self._writer = Writer(self._fh, use_chunking=False, use_statistics=True)
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
        if now - self._last_flush >= FLUSH_PERIOD:
            self._fh.flush()
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
            self._writer.finish()
            self._fh.flush()
            os.fsync(self._fh.fileno())
            os.replace(self.partial, self.path)  # under the lock: no other run sees a gap
        finally:  # a failed finish (a full disk) leaves the old record and this partial one
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
    metadata : dict
        The ``rwlab`` metadata (empty if the file lost it).
    messages : dict
        topic → list of message dicts, in file order.
    complete : bool
        True when the file was closed properly (it has its footer).
    problem : str
        Why reading stopped early, when it did.
    """

    path: Path
    metadata: dict = field(default_factory=dict)
    messages: dict = field(default_factory=lambda: {t: [] for t in CHANNELS})
    complete: bool = False
    problem: str = ""

    def topic(self, name: str) -> list[dict]:
        return self.messages.get(name, [])


def _parse(stream, record: Record, topics: dict[int, str]) -> None:
    for r in StreamReader(stream, skip_magic=False).records:
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


def read_record(path: str | os.PathLike) -> Record:
    """Read a record, tolerating a truncated end (a crashed recorder).

    Raises ``FileFormatError`` for a file that is not an MCAP record at all.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.

    Returns
    -------
    Record
        Its metadata and topics.
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
    try:
        _parse(io.BytesIO(data), record, {})
    except (McapError, struct.error, EOFError, ValueError, json.JSONDecodeError) as exc:
        record.problem = f"file ends early or is damaged ({type(exc).__name__}: {exc})"
    if not record.metadata:
        raise FileFormatError(f"{path}: an MCAP file, but not an rwlab record (no rwlab metadata)")
    return record


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
