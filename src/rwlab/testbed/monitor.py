"""The live monitor (the LabVIEW screen): a Bokeh server page on 127.0.0.1.

The monitor is a separate consumer. It *reads the record file* that the
recorder writes (flushed every ≤ 100 ms), so it can never block or slow the
recorder; ``rwlab experiment --monitor`` even runs it in its own process. The
page refreshes at 20 Hz and keeps only the last ``max_points`` samples per
plot (drop-oldest, for the display only: the record keeps everything).

It shows command vs speed, acceleration (derived from speed over ≥ 0.1 s),
motor current, and the wheel's mode, faults and the experiment's events. A
record of ``rwlab hil`` (a ``/satellite`` channel) adds the satellite view on
top: true and estimated pointing error against the requirement, every wheel's
momentum, the wheels still in the loop, and the alarms among the events. Given
a finished record with ``replay=True`` it plays the record back at ``speed`` times real time.
Bokeh serves its own JavaScript from the server: no CDN, works offline.
"""

from __future__ import annotations

import html
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from rwlab._optional import require
from rwlab.errors import ConfigError
from rwlab.testbed.record import RecordFollower, read_record

__all__ = [
    "acceleration_from_speed",
    "check_port",
    "free_port",
    "make_document",
    "serve",
    "serve_in_thread",
    "start_process",
    "stop_process",
]

REFRESH_MS = 50  # 20 Hz
ACCEL_WINDOW = 0.1  # s: acceleration is the speed difference over at least this long


class _Feed:
    """New messages per refresh: live from a growing file, or replayed from a finished one."""

    def __init__(self, path: Path, replay: bool, speed: float) -> None:
        self.replay = replay
        if replay:
            rec = read_record(path)
            self.metadata = rec.metadata
            self._pending = {k: deque(v) for k, v in rec.messages.items()}
            starts = [v[0]["t"] for v in rec.messages.values() if v]
            self._t0 = min(starts) if starts else 0.0
            self._wall0 = time.monotonic()
            self._speed = speed
        else:
            self._follower = RecordFollower(path)

    @property
    def meta(self) -> dict:
        return self.metadata if self.replay else self._follower.metadata

    def poll(self) -> dict[str, list[dict]]:
        if not self.replay:
            return self._follower.poll()
        horizon = self._t0 + (time.monotonic() - self._wall0) * self._speed
        out = {}
        for topic, queue in self._pending.items():
            batch = []
            while queue and queue[0]["t"] <= horizon:
                batch.append(queue.popleft())
            out[topic] = batch
        return out


def make_document(
    doc, path: str | Path, *, replay: bool = False, speed: float = 1.0, max_points: int = 20_000
) -> None:
    """Build the monitor page into a Bokeh ``Document`` (a Bokeh application handler).

    Parameters
    ----------
    doc : bokeh.document.Document
        The page to fill.
    path : str or Path
        The record (being written, or finished with ``replay``).
    replay : bool
        Play a finished record back.
    speed : float
        Replay speed, times real time.
    max_points : int
        Samples kept per plot.
    """
    require("bokeh", "the live monitor")
    from bokeh.layouts import column, row
    from bokeh.models import ColumnDataSource
    from bokeh.models.widgets import Div
    from bokeh.plotting import figure

    path = Path(path)
    feed = _Feed(path, replay, speed)
    cmd = ColumnDataSource({"t": [], "command": []}, name="command")
    tel = ColumnDataSource(
        {"t": [], "speed": [], "acceleration": [], "current": []}, name="telemetry"
    )
    opts: dict[str, Any] = dict(
        height=260, sizing_mode="stretch_width", tools="pan,wheel_zoom,box_zoom,reset"
    )
    f_speed = figure(title="command and measured speed [rpm]", x_axis_label="t [s]", **opts)
    f_speed.step("t", "command", source=cmd, mode="after", color="#d62728", legend_label="command")
    f_speed.line("t", "speed", source=tel, color="#1f77b4", legend_label="speed")
    f_speed.legend.location = "top_left"
    f_acc = figure(title="acceleration from speed [rpm/s]", x_range=f_speed.x_range, **opts)
    f_acc.line("t", "acceleration", source=tel, color="#2ca02c")
    f_cur = figure(title="motor current [A]", x_range=f_speed.x_range, **opts)
    f_cur.line("t", "current", source=tel, color="#9467bd")
    sat, mom, f_point, f_mom = _satellite_figures(opts)
    title = Div(text=f"<h2>rwlab monitor — {path.name}{' (replay)' if replay else ''}</h2>")
    status = Div(text="waiting for data…", name="status")
    events = Div(text="", name="events")
    doc.add_root(
        column(
            title,
            row(status, events),
            f_point,
            f_mom,
            f_speed,
            f_acc,
            f_cur,
            sizing_mode="stretch_width",
        )
    )
    doc.title = f"rwlab monitor: {path.name}"
    recent: deque[tuple[float, float]] = deque()
    state: dict[str, Any] = {"frames": 0, "lost": 0, "counter": None, "events": [], "alarms": []}

    def refresh() -> None:
        new = feed.poll()
        commands = new.get("/command", [])
        if commands:
            cmd.stream(
                {"t": [c["t"] for c in commands], "command": [c["setpoint"] for c in commands]},
                rollover=max_points,
            )
        frames = new.get("/telemetry", [])
        if frames:
            acc = []
            for m in frames:
                acc.append(acceleration_from_speed(recent, m["t"], m["speed_rpm"]))
                if state["counter"] is not None:
                    state["lost"] += (m["counter"] - state["counter"] - 1) % 256
                state["counter"] = m["counter"]
            state["frames"] += len(frames)
            tel.stream(
                {
                    "t": [m["t"] for m in frames],
                    "speed": [m["speed_rpm"] for m in frames],
                    "acceleration": acc,
                    "current": [m["current_a"] for m in frames],
                },
                rollover=max_points,
            )
        for e in new.get("/event", []):
            line = html.escape(f"{e['t']:.2f} s {e['kind']} {e['message']}")
            if e["kind"] == "alarm":  # the live fault detector's verdicts: every one stays shown
                state["alarms"].append(f'<b style="color:#c00">{line}</b>')
            elif e["kind"] == "fault_injected":
                state["events"].append(f'<b style="color:#c00">{line}</b>')
            else:
                state["events"].append(line)
        events.text = "<br>".join(state["alarms"] + state["events"][-4:])
        if frames:
            last = frames[-1]
            fault = "<b style='color:#c00'>FAULT</b>" if last["fault_active"] else "ok"
            if state["alarms"]:  # an alarm is a verdict on the wheel: red until the run ends
                fault = f"<b style='color:#c00'>ALARM ({len(state['alarms'])})</b>"
            status.text = (
                f"t = {last['t']:.2f} s &nbsp; mode <b>{last['mode']}</b> &nbsp; "
                f"speed {last['speed_rpm']:.1f} rpm &nbsp; {fault} &nbsp; "
                f"frames {state['frames']} (lost {state['lost']})"
            )
        rows = new.get("/satellite", [])
        if rows:
            _stream_satellite(rows, sat, mom, max_points)
            f_point.visible = f_mom.visible = True
            last = rows[-1]
            status.text = (
                f"t = {last['t']:.1f} s &nbsp; pointing error <b>{last['error_deg']:.4f}°</b> "
                f"&nbsp; estimation {last['estimation_error_deg']:.4f}° &nbsp; wheels in the "
                f"loop {', '.join(map(str, last['active_wheels']))}"
            )
        beats = new.get("/heartbeat", [])
        if beats and beats[-1]["faults"]:
            status.text += f" &nbsp; fault bits {beats[-1]['faults']}"

    doc.add_periodic_callback(refresh, REFRESH_MS)


MAX_WHEELS_SHOWN = 6


def _satellite_figures(opts: dict):
    """The satellite view's sources and figures (hidden until a ``/satellite`` row comes)."""
    from bokeh.models import ColumnDataSource
    from bokeh.models.annotations import Span
    from bokeh.plotting import figure

    sat = ColumnDataSource({"t": [], "error": [], "estimation": []}, name="satellite")
    mom = ColumnDataSource(
        {"t": [], **{f"h{i}": [] for i in range(1, MAX_WHEELS_SHOWN + 1)}}, name="momentum"
    )
    f_point = figure(title="satellite: pointing error [°]", x_axis_label="t [s]", **opts)
    f_point.line("t", "error", source=sat, color="#d62728", legend_label="true")
    f_point.line("t", "estimation", source=sat, color="#1f77b4", legend_label="estimation")
    f_point.add_layout(Span(location=0.1, dimension="width", line_dash="dashed"))
    f_mom = figure(title="wheel momentum [N·m·s]", x_range=f_point.x_range, **opts)
    colors = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")
    for i, c in enumerate(colors, start=1):
        f_mom.line("t", f"h{i}", source=mom, color=c, legend_label=f"wheel {i}")
    for f in (f_point, f_mom):
        f.visible = False
        f.legend.location = "top_left"
    return sat, mom, f_point, f_mom


def _stream_satellite(rows: list[dict], sat, mom, max_points: int) -> None:
    t = [r["t"] for r in rows]
    sat.stream(
        {
            "t": t,
            "error": [r["error_deg"] for r in rows],
            "estimation": [r["estimation_error_deg"] for r in rows],
        },
        rollover=max_points,
    )
    h: dict[str, list[float]] = {f"h{i}": [] for i in range(1, MAX_WHEELS_SHOWN + 1)}
    for r in rows:
        values = list(r["wheel_momentum_Nms"])[:MAX_WHEELS_SHOWN]
        values += [float("nan")] * (MAX_WHEELS_SHOWN - len(values))
        for i, v in enumerate(values, start=1):
            h[f"h{i}"].append(v)
    mom.stream({"t": t, **h}, rollover=max_points)


def acceleration_from_speed(recent: deque, t: float, speed: float) -> float:
    """Acceleration (rpm/s) at the newest frame, from the speed ≥ ``ACCEL_WINDOW`` s before.

    ``recent`` holds the (t, speed) pairs seen so far and is trimmed in place. The
    oldest frame kept is the newest one at least ``ACCEL_WINDOW`` old, so the
    difference always spans a frame interval, whatever the telemetry rate.

    Parameters
    ----------
    recent : collections.deque of (float, float)
        (t s, speed rpm) pairs, oldest first; trimmed in place.
    t : float
        The newest frame's time, s.
    speed : float
        Its speed, rpm.

    Returns
    -------
    float
        Acceleration, rpm/s (0 until a window has passed).
    """
    recent.append((t, speed))
    while len(recent) > 2 and t - recent[1][0] >= ACCEL_WINDOW:
        recent.popleft()
    dt = recent[-1][0] - recent[0][0]
    return (recent[-1][1] - recent[0][1]) / dt if dt > 0 else 0.0


def _application(path, replay, speed):
    require("bokeh", "the live monitor")
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler

    return Application(
        FunctionHandler(lambda doc: make_document(doc, path, replay=replay, speed=speed))
    )


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free on ``host`` right now.

    Parameters
    ----------
    host : str
        The address.

    Returns
    -------
    int
    """
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def check_port(host: str, port: int) -> None:
    """Raise ``ConfigError`` now if the monitor could not listen on ``host:port``.

    Parameters
    ----------
    host : str
        The address to listen on.
    port : int
        The TCP port.
    """
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as tornado binds
        try:
            s.bind((host, port))
        except (OSError, TypeError, UnicodeError, OverflowError) as exc:
            why = getattr(exc, "strerror", None) or exc
            raise ConfigError(
                f"the monitor cannot listen on {host}:{port} ({why}); "
                "choose another --host or --port"
            ) from None


def stop_process(child: subprocess.Popen) -> None:
    """Stop a monitor started by :func:`start_process` and wait for it to release its port.

    Parameters
    ----------
    child : subprocess.Popen
        As :func:`start_process` returned it.
    """
    child.terminate()
    try:
        child.wait(timeout=5)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()


def serve(
    path, *, host: str = "127.0.0.1", port: int = 5006, replay: bool = False, speed: float = 1.0
) -> None:
    """Serve the monitor until interrupted (blocking).

    Parameters
    ----------
    path : str or Path
        The record.
    host : str
        Address to listen on.
    port : int
        TCP port.
    replay : bool
        Play a finished record back.
    speed : float
        Replay speed, times real time.
    """
    from bokeh.server.server import Server

    check_port(host, port)
    server = Server(
        {"/": _application(path, replay, speed)},
        address=host,
        port=port,
        allow_websocket_origin=[f"{host}:{port}", f"localhost:{port}"],
    )
    server.start()
    try:
        server.io_loop.start()
    finally:
        server.stop()  # Ctrl-C or SIGTERM: release the port at once


class _ThreadedServer:
    def __init__(self, server, loop, thread, url: str = "") -> None:
        self._server, self._loop, self._thread = server, loop, thread
        self.url = url

    def stop(self) -> None:
        self._loop.add_callback(self._server.stop)
        self._loop.add_callback(self._loop.stop)
        self._thread.join(timeout=5)


def serve_in_thread(
    path,
    *,
    host: str = "127.0.0.1",
    port: int | None = None,
    replay: bool = False,
    speed: float = 1.0,
    wait_for_file: bool = False,
):
    """Serve the monitor from a background thread; returns a handle with ``stop()`` and ``url``.

    Parameters
    ----------
    path : str or Path
        The record.
    host : str
        Address to listen on.
    port : int, optional
        TCP port (a free one by default).
    replay, speed
        As for :func:`serve`.
    wait_for_file : bool
        Let the page wait until the record appears.

    Returns
    -------
    handle
        With ``url`` and ``stop()``.
    """
    import asyncio

    from bokeh.server.server import Server
    from tornado.ioloop import IOLoop

    port = port or free_port(host)
    ready = threading.Event()
    holder: dict[str, Any] = {}

    def run() -> None:
        asyncio.set_event_loop(asyncio.new_event_loop())
        loop = IOLoop.current()
        server = Server(
            {"/": _application(path, replay, speed)},
            address=host,
            port=port,
            io_loop=loop,
            allow_websocket_origin=[f"{host}:{port}", f"localhost:{port}"],
        )
        server.start()
        holder["server"], holder["loop"] = server, loop
        ready.set()
        loop.start()

    thread = threading.Thread(target=run, daemon=True, name="rwlab-monitor")
    thread.start()
    if not ready.wait(15):
        raise RuntimeError("the monitor server did not start")
    return _ThreadedServer(holder["server"], holder["loop"], thread, f"http://{host}:{port}/")


def start_process(path, *, host: str = "127.0.0.1", port: int = 5006) -> subprocess.Popen:
    """Run the monitor in its own process (what ``rwlab experiment --monitor`` does).

    Raises ``ConfigError`` at once if the port is taken; stop it with :func:`stop_process`.

    Parameters
    ----------
    path : str or Path
        The record.
    host : str
        Address to listen on.
    port : int
        TCP port.

    Returns
    -------
    subprocess.Popen
        The monitor's process.
    """
    check_port(host, port)
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rwlab.cli",
            "monitor",
            str(path),
            "--host",
            host,
            "--port",
            str(port),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
