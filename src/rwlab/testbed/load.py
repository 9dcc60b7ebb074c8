"""Turn an experiment record into an ``IOData`` on a uniform time grid."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rwlab.data import IOData, check_Ts
from rwlab.datafiles import from_table
from rwlab.errors import DataError, RecordGapError
from rwlab.testbed.record import Record, read_record, readable_seconds

__all__ = ["gap_free_segments", "load_record", "salvage_note", "telemetry_gaps"]

OUTPUTS = {
    "speed": ("speed_rpm", "rpm"),
    "acceleration": ("acceleration_rpm_s", "rpm/s"),
    "current": ("current_a", "A"),
    "age": ("telemetry_age_s", "s"),
    "lost": ("lost_frames", "frames"),
}


def telemetry_gaps(times: np.ndarray, max_gap: float) -> list[tuple[float, float]]:
    """(start time, length) of every interval between telemetry frames longer than ``max_gap`` s.

    Frame times jitter around the telemetry period, so an interval counts as a
    gap only when it exceeds ``max_gap`` by more than half the typical (median)
    interval: at 10 Hz, a 0.1000001 s step is not a gap, a lost frame's 0.2 s is.

    Parameters
    ----------
    times : numpy.ndarray, shape (n,)
        Frame times, s, increasing.
    max_gap : float
        Longest accepted interval, s.

    Returns
    -------
    list of (float, float)
        Start time and length of each gap, s.
    """
    if times.size < 2:
        return []
    steps = np.diff(times)
    idx = np.flatnonzero(steps > max_gap + 0.5 * float(np.median(steps)))
    return [(float(times[i]), float(steps[i])) for i in idx]


def load_record(
    path: str | os.PathLike | Record,
    Ts: float | None = None,
    *,
    outputs: tuple[str, ...] = ("speed",),
    max_gap: float | None = None,
    max_gap_samples: int | None = None,
    node: int | None = None,
    salvage: bool | None = None,
) -> IOData:
    """Sample a record at ``Ts``: command as zero-order hold, measured speed and derived values.

    Parameters
    ----------
    path : path-like or Record
        An ``.mcap`` record written by ``rwlab experiment``, or one read already
        (:func:`rwlab.testbed.read_record`: a caller that samples a record several
        ways decodes it once).
    Ts : float, optional
        Sample time in seconds (default: the record's command period).
    outputs : tuple of {'speed', 'acceleration', 'current', 'age', 'lost'}
        Output channels: measured speed (rpm), acceleration derived from it by a
        backward difference over Ts (rpm/s), motor current (A), age of the
        telemetry frame each sample repeats (s: large where frames were lost),
        telemetry frames lost so far by the frames' 8-bit counter (as
        :attr:`rwlab.wheel.WheelClient.lost_frames` counts them live).
    max_gap : float, optional
        Longest accepted interval between telemetry frames, s (default Ts),
        beyond the timestamps' jitter (half the median frame interval). Longer
        gaps raise ``RecordGapError`` listing them; pass ``numpy.inf`` to accept
        them. Without ``max_gap``, a ``Ts`` shorter than the telemetry period is
        refused (``DataError``).
    max_gap_samples : int, optional
        The same limit as a number of samples (``max_gap = max_gap_samples·Ts``),
        for callers that know a model's memory but not the record's Ts.
    node : int, optional
        The wheel to read from a record of several (``rwlab hil``: topics
        ``/wheelN/command`` and ``/wheelN/telemetry``).
    salvage : bool, optional
        Read a damaged record up to its damage instead of refusing it
        (:func:`rwlab.testbed.read_record`); the data's name and ``source``
        (``"salvaged"``) then say so.

    Returns
    -------
    IOData
        u = the command (rpm or rpm/s) issued at sample k (sent within Ts/2 after
        t₀ + k·Ts: on the wall clock a command leaves a little after its
        instant), y = the chosen outputs; sample k is the last value received
        at or before t₀ + k·Ts, t₀ the first command. ``tstart`` counts from t₀, or
        on the record's own clock where its metadata says ``"time_axis": "flight"``
        (``rwlab hil``: flight time, the spin-up at negative times), so every
        channel of such a record reads on one clock.
    """
    record = _read(path, salvage)
    path = record.path
    meta = record.metadata
    if Ts is None:
        Ts = meta.get("Ts")
    Ts = check_Ts(Ts)
    if max_gap_samples is not None:
        max_gap = max_gap_samples * Ts
    unknown = [o for o in outputs if o not in OUTPUTS]
    if unknown or not outputs:
        raise DataError(f"outputs must be chosen from {sorted(OUTPUTS)}, got {list(outputs)}")
    prefix = "" if node is None else f"/wheel{node}"
    wheels = sorted(
        t.split("/")[1] for t in record.messages if t.endswith("/telemetry") and t[1:6] == "wheel"
    )
    if node is None and wheels and not record.topic("/telemetry"):
        raise DataError(f"{path} holds several wheels ({', '.join(wheels)}): choose one (node=)")
    commands = record.topic(f"{prefix}/command")
    telemetry = record.topic(f"{prefix}/telemetry")
    if not commands or len(telemetry) < 2:
        raise DataError(f"{path}: the record holds no experiment (no commands or telemetry)")
    tc = np.array([c["t"] for c in commands])
    uc = np.array([c["setpoint"] for c in commands])
    tt = np.array([m["t"] for m in telemetry])
    period = float(np.median(np.diff(tt)))
    if max_gap is None and Ts < 0.75 * period:
        raise DataError(
            f"{path}: Ts = {Ts:g} s is shorter than the telemetry period ({period:.3g} s), "
            "so most samples would repeat the last frame; use Ts >= the telemetry period"
        )
    limit = Ts if max_gap is None else max_gap
    gaps = telemetry_gaps(tt, limit)
    if gaps:
        shown = ", ".join(
            f"{length:.3g} s at t = {start - tc[0]:.3g} s" for start, length in gaps[:5]
        )
        raise RecordGapError(
            f"{path}: {len(gaps)} telemetry gap(s) longer than {limit:g} s ({shown}"
            f"{', ...' if len(gaps) > 5 else ''}); frames were lost, so samples there are stale. "
            "Pass max_gap= to accept them."
        )
    t0 = tc[0]
    n = int(np.floor((tt[-1] - t0) / Ts + 1e-9)) + 1
    grid = t0 + Ts * np.arange(n)
    eps = 1e-9 * max(1.0, abs(grid[-1]))
    u = uc[np.maximum(np.searchsorted(tc, grid + 0.5 * Ts, side="right") - 1, 0)]
    last = np.searchsorted(tt, grid + eps, side="right") - 1
    if last[0] < 0:  # no telemetry yet at the first command: start the grid at the first frame
        keep = last >= 0
        grid, u, last = grid[keep], u[keep], last[keep]
    speed = np.array([m["speed_rpm"] for m in telemetry])[last]
    columns = {
        "speed": speed,
        "acceleration": np.concatenate([[0.0], np.diff(speed) / Ts]),
        "current": np.array([m["current_a"] for m in telemetry])[last],
        "age": grid - tt[last],
        "lost": _lost_frames(telemetry)[last],
    }
    mode = meta.get("mode", "speed")
    return IOData(
        u,
        np.column_stack([columns[o] for o in outputs]),
        Ts,
        input_names=["command"],
        output_names=[OUTPUTS[o][0] for o in outputs],
        input_units=["rpm" if mode == "speed" else "rpm/s"],
        output_units=[OUTPUTS[o][1] for o in outputs],
        tstart=float(grid[0] - _origin(meta, t0)),
        name=f"{os.path.basename(path)}{_cut_short(record)}",
        source=meta if record.damage is None else {**meta, "salvaged": salvage_note(record)},
    )


def _read(path: str | os.PathLike | Record, salvage: bool | None) -> Record:
    """The record at ``path``, or ``path`` itself when it was read already."""
    return path if isinstance(path, Record) else read_record(path, salvage=salvage)


def salvage_note(record) -> dict:
    """What outputs carry of a record read up to its damage (``source["salvaged"]``).

    Parameters
    ----------
    record : rwlab.testbed.record.Record
        A record read with ``salvage=True`` and found damaged.

    Returns
    -------
    dict
        ``damaged_at_byte``, ``file_bytes``, ``why`` and ``readable_s`` (s).
    """
    damage = record.damage
    return {
        "damaged_at_byte": damage.offset,
        "file_bytes": damage.size,
        "why": damage.why,
        "readable_s": round(readable_seconds(record), 3),
    }


def _cut_short(record) -> str:
    """What the data's name says of a record that did not run to its end: a file cut off
    mid-write, or a run stopped by Ctrl-C, a wheel fault or an error (its ``stop`` event)."""
    if record.damage is not None:
        return f" (salvaged: {record.damage.text()}; read up to the damage)"
    if not record.complete:
        return " (truncated)"
    stops = [e["message"] for e in record.topic("/event") if e["kind"] == "stop"]
    if stops and not stops[-1].startswith("completed"):
        return f" ({stops[-1]}: the run stopped before its end)"
    return ""


def _origin(meta: dict, first_command_t: float) -> float:
    """Where a record's samples count from: its own clock's zero for a record on the
    flight clock (``rwlab hil``), else its first command."""
    return 0.0 if meta.get("time_axis") == "flight" else first_command_t


def gap_free_segments(
    path: str | os.PathLike | Record,
    Ts: float | None = None,
    *,
    node: int | None = None,
    salvage: bool | None = None,
) -> list[tuple[int, int]]:
    """The parts of a record between its telemetry gaps, as sample ranges.

    The gaps are those :func:`load_record` refuses without ``max_gap`` (an
    interval between frames longer than ``Ts``, by :func:`telemetry_gaps`'s
    rule); a sample inside one that holds the frame before it for longer than one
    telemetry period holds a stale frame and belongs to no segment.

    Parameters
    ----------
    path : path-like or Record
        The record (or the record read already).
    Ts : float, optional
        Sample time, s (the record's by default), as for :func:`load_record`.
    node : int, optional
        The wheel, in a record of several.
    salvage : bool, optional
        As for :func:`load_record`.

    Returns
    -------
    list of (int, int)
        ``[i0, i1)`` ranges of the samples of ``load_record(path, Ts, max_gap=numpy.inf)``,
        in time order; one range covering every sample when the record has no gap.
    """
    record = _read(path, salvage)
    data = load_record(record, Ts, outputs=("age",), max_gap=np.inf, node=node)
    prefix = "" if node is None else f"/wheel{node}"
    t0 = record.topic(f"{prefix}/command")[0]["t"]
    tt = np.array([m["t"] for m in record.topic(f"{prefix}/telemetry")])
    grid = _origin(record.metadata, t0) + data.tstart + data.Ts * np.arange(data.N)
    eps = 1e-9 * max(1.0, abs(float(grid[-1])))
    period = float(np.median(np.diff(tt)))
    stale = np.zeros(data.N, dtype=bool)
    for start, length in telemetry_gaps(tt, data.Ts):  # the frame at `start` is held ...
        held = grid - start  # ... this long: older than one telemetry period is stale
        stale |= (held > period + eps) & (grid < start + length - eps)
    edges = np.flatnonzero(np.diff(np.concatenate([[1], stale.astype(int), [1]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _lost_frames(telemetry: list[dict]) -> np.ndarray:
    """Frames lost up to each telemetry frame, from the gaps of its 8-bit counter."""
    counter = np.array([m.get("counter", 0) for m in telemetry], dtype=np.int64)
    gaps = (np.diff(counter) - 1) % 256
    return np.concatenate([[0], np.cumsum(gaps)]).astype(float)


def read_mcap(
    path: Path | Record,
    Ts: float | None,
    input_columns=None,
    output_columns=None,
    max_gap: float | None = None,
    max_gap_samples: int | None = None,
    salvage: bool | None = None,
) -> IOData:
    """A testbed record as :func:`rwlab.data.load` reads it (registered for ``.mcap``).

    Parameters
    ----------
    path : Path or Record
        The ``.mcap`` record (or the record read already).
    Ts : float, optional
        Sample time, s (default: the record's).
    input_columns, output_columns : str or list, optional
        Channels (default ``command`` → ``speed_rpm``; every output of
        :data:`OUTPUTS` can be chosen).
    max_gap, max_gap_samples, salvage : optional
        See :func:`load_record`.

    Returns
    -------
    IOData
        With the record's metadata in ``source``.
    """
    rec = load_record(
        path,
        Ts,
        outputs=tuple(OUTPUTS),
        max_gap=max_gap,
        max_gap_samples=max_gap_samples,
        salvage=salvage,
    )
    if isinstance(path, Record):
        path = path.path
    names = ["time_s", *rec.input_names, *rec.output_names]
    units = dict(zip(names[1:], [*rec.input_units, *rec.output_units], strict=True))
    table = np.column_stack([rec.time, rec.u, rec.y])
    data = from_table(
        names,
        table,
        rec.Ts,
        None,
        path,
        "command" if input_columns is None else input_columns,
        "speed_rpm" if output_columns is None else output_columns,
        units=units,
    )
    return data._with(data.u, data.y, name=rec.name, source=rec.source)
