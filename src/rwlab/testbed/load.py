"""Turn an experiment record into an ``IOData`` on a uniform time grid."""

from __future__ import annotations

import os

import numpy as np

from rwlab.data import IOData, check_Ts
from rwlab.errors import DataError, RecordGapError
from rwlab.testbed.record import read_record

__all__ = ["load_record", "telemetry_gaps"]

OUTPUTS = {
    "speed": ("speed_rpm", "rpm"),
    "acceleration": ("acceleration_rpm_s", "rpm/s"),
    "current": ("current_a", "A"),
    "age": ("telemetry_age_s", "s"),
}


def telemetry_gaps(times: np.ndarray, max_gap: float) -> list[tuple[float, float]]:
    """(start time, length) of every interval between telemetry frames longer than ``max_gap`` s.

    Frame times jitter around the telemetry period, so an interval counts as a
    gap only when it exceeds ``max_gap`` by more than half the typical (median)
    interval: at 10 Hz, a 0.1000001 s step is not a gap, a lost frame's 0.2 s is.
    """
    if times.size < 2:
        return []
    steps = np.diff(times)
    idx = np.flatnonzero(steps > max_gap + 0.5 * float(np.median(steps)))
    return [(float(times[i]), float(steps[i])) for i in idx]


def load_record(
    path: str | os.PathLike,
    Ts: float | None = None,
    *,
    outputs: tuple[str, ...] = ("speed",),
    max_gap: float | None = None,
    node: int | None = None,
) -> IOData:
    """Sample a record at ``Ts``: command as zero-order hold, measured speed and derived values.

    Parameters
    ----------
    path : path-like
        An ``.mcap`` record written by ``rwlab experiment``.
    Ts : float, optional
        Sample time in seconds (default: the record's command period).
    outputs : tuple of {'speed', 'acceleration', 'current', 'age'}
        Output channels: measured speed (rpm), acceleration derived from it by a
        backward difference over Ts (rpm/s), motor current (A), age of the
        telemetry frame each sample repeats (s: large where frames were lost).
    max_gap : float, optional
        Longest accepted interval between telemetry frames, s (default Ts),
        beyond the timestamps' jitter (half the median frame interval). Longer
        gaps raise ``RecordGapError`` listing them; pass ``numpy.inf`` to accept
        them. Without ``max_gap``, a ``Ts`` shorter than the telemetry period is
        refused (``DataError``).
    node : int, optional
        The wheel to read from a record of several (``rwlab hil``: topics
        ``/wheelN/command`` and ``/wheelN/telemetry``).

    Returns
    -------
    IOData
        u = the command (rpm or rpm/s), y = the chosen outputs; sample k is the
        last value received at or before t₀ + k·Ts, t₀ the first command.
    """
    record = read_record(path)
    meta = record.metadata
    if Ts is None:
        Ts = meta.get("Ts")
    Ts = check_Ts(Ts)
    unknown = [o for o in outputs if o not in OUTPUTS]
    if unknown or not outputs:
        raise DataError(f"outputs must be chosen from {sorted(OUTPUTS)}, got {list(outputs)}")
    prefix = "" if node is None else f"/wheel{node}"
    wheels = sorted(
        t.split("/")[1] for t in record.messages if t.endswith("/telemetry") and t[1:6] == "wheel"
    )
    if node is None and wheels and not record.topic("/telemetry"):
        raise DataError(
            f"{path} holds several wheels ({', '.join(wheels)}): choose one (node=, CLI --node)"
        )
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
            "Pass max_gap (CLI: --max-gap) to accept them."
        )
    t0 = tc[0]
    n = int(np.floor((tt[-1] - t0) / Ts + 1e-9)) + 1
    grid = t0 + Ts * np.arange(n)
    eps = 1e-9 * max(1.0, abs(grid[-1]))
    u = uc[np.searchsorted(tc, grid + eps, side="right") - 1]
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
        tstart=float(grid[0] - t0),
        name=f"{os.path.basename(path)}{'' if record.complete else ' (truncated)'}",
    )
