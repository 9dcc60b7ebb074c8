"""The experiment runner: play a test signal into a wheel and record everything.

Commands go out at absolute times t₀ + k·Ts (never "sleep after work"), every
command and every telemetry frame is written to the record with its time and
sequence number, and whatever happens — the end of the signal, Ctrl-C, a
wheel fault, any error — the wheel is left idle and the record is closed.

Against the simulated wheel the experiment runs on the simulated clock by
default (a 20-minute PRBS finishes in seconds, through real CAN frames);
``realtime=True`` runs it on the wall clock. A real bus always runs in real time.

Why this module is long: ``ExperimentConfig`` and the runner share the experiment's
checks and limits, and the real-time loop that must leave the wheel idle on every exit
is kept whole.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from rwlab import signals
from rwlab._display import ShortRepr
from rwlab._version import __version__
from rwlab.data import load as load_data
from rwlab.errors import ConfigError, WheelFault
from rwlab.testbed.record import RecordWriter
from rwlab.wheel import RW90, SimClock, WallClock, WheelClient, WheelNode, WheelParams
from rwlab.wheel.bus import open_bus, open_transport, transport_names
from rwlab.wheel.client import Implausible
from rwlab.wheel.faults import ScheduledFault, parse_fault
from rwlab.wheel.link import get_protocol
from rwlab.wheel.node import WATCHDOG_S
from rwlab.wheel.protocol import Telemetry, dbc_sha256
from rwlab.wheel.serial import open_pty

__all__ = ["SIGNALS", "ExperimentConfig", "RunSummary", "make_signal", "run_experiment"]

SIGNALS = ("prbs", "chirp", "step", "multisine", "file")
MODES = ("speed", "acceleration")
MAX_COMMANDS = 10_000_000  # 58 days at 0.5 s: a typo, not an experiment, beyond this


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything that defines an experiment, so it can be repeated exactly.

    Attributes
    ----------
    signal : {'prbs', 'chirp', 'step', 'multisine', 'file'}
    mode : {'speed', 'acceleration'}
    amplitude : float, optional
        rpm in speed mode, rpm/s in acceleration mode; default the wheel model's
        nominal speed (speed mode) or its acceleration limit (acceleration mode).
    duration : float
        Seconds of signal.
    Ts : float
        Command period, s.
    seed : int
        For random signals and the simulated wheel's noise.
    telemetry_rate : float
        Hz, for the simulated wheel.
    realtime : bool
        Run the simulated wheel on the wall clock.
    interface, channel, node_id :
        The bus. ``virtual`` starts a simulated RW90; other interfaces talk to a
        wheel that is already there (and always run in real time).
    latency : float
        Simulated wheel's command latency, s.
    min_hold, max_hold : float
        PRBS hold times, s (paper A: ≥ 5 s).
    rate_limit : bool
        Limit a speed-mode PRBS's slope to the wheel's maximum acceleration
        (its spec's ``max_accel_rpm_s``): the command then ramps instead of stepping, and a
        linear model identified from it never sees the acceleration limit bind.
        Default False: paper A's PRBS steps between random levels, the wheel
        follows each step at its acceleration limit, and the record shows that
        nonlinearity (``true`` in TOML or ``--rate-limit`` on the CLI to ramp).
    f0, f1 : float
        Chirp / multisine band, Hz (f1 default: 0.4/Ts).
    step_levels : tuple of float
        Levels of the step signal, as fractions of the amplitude.
    file : str
        CSV of setpoints for ``signal = 'file'`` (one column, or ``time_s`` + a column).
    raw_frames : bool
        Also record every CAN frame.
    protocol : str
        The wheel protocol (``rwlab``, ``canopen``, ``nsp`` or a registered one); on
        the virtual interface a byte-stream protocol's twin answers over a pty pair.
        ``"auto"`` (default): ``rwlab``, or ``nsp`` for a simulated wheel whose numbers
        rwlab's DBC cannot carry (an NRWA-T6's 6 A, an RW-0.01's 5 V bus).
    faults : tuple of str
        Faults injected into the simulated wheel, each ``NAME[=VALUE]@SECONDS``
        (:mod:`rwlab.wheel.faults`); each is recorded as a ``fault_injected`` event.
    wheel : str
        The simulated wheel: a wheel model, ``'rw90'`` (the realistic twin, default),
        ``'nrwa-t6'``, ``'rw-0.01'`` (:func:`rwlab.wheelspec.preset_names`) or
        ``'ideal'`` (the RW90 without imperfections, :data:`rwlab.wheel.physics.IDEAL`),
        a wheel spec file (``format = "rwlab.WheelSpec/1"``), or a
        wheel TOML file (``*.toml``, :meth:`rwlab.wheel.WheelParams.from_toml`,
        e.g. a unit whose driver limits the current to 0.35 A); ``unit`` then
        draws around it (leave ``unit`` out of the TOML).
    unit : int, optional
        Unit seed of the simulated wheel: another RW90 drawn within its tolerances
        (:meth:`rwlab.wheel.WheelParams.for_unit`); None is the nominal wheel.
    model : str
        ``model.json`` of an identified wheel: run the diagnosis live
        (:class:`rwlab.diagnose.watch.RecordWatch`, the GLR pipeline; speed mode at the
        model's Ts) and record each alarm as an ``alarm`` event.
    diagnosis_calibration : str
        The live diagnosis's ``calibration.json`` (``rwlab diagnose calibrate``); default:
        the twin calibration of the model's wheel preset.
    late_tolerance : float, optional
        Seconds a command may go out late before the run counts a timing fault
        (default: 10 % of Ts, at least 1 ms, at most Ts). The lateness
        statistics are recorded as a ``timing`` event before ``stop``.
    """

    signal: str = "prbs"
    mode: str = "speed"
    amplitude: float | None = None
    duration: float = 1200.0
    Ts: float = 0.5
    seed: int = 0
    telemetry_rate: float = 10.0
    realtime: bool = False
    interface: str = "virtual"
    channel: str | None = None
    node_id: int = 0
    latency: float = 0.02
    min_hold: float = 5.0
    max_hold: float = 60.0
    rate_limit: bool = False
    f0: float = 0.0001
    f1: float | None = None
    step_levels: tuple[float, ...] = (0.0, 1.0, 0.0, -1.0, 0.0)
    file: str | None = None
    raw_frames: bool = False
    faults: tuple[str, ...] = ()
    model: str | None = None
    diagnosis_calibration: str | None = None
    wheel: str = "rw90"
    unit: int | None = None
    protocol: str = "auto"
    late_tolerance: float | None = None

    def __post_init__(self) -> None:
        if self.protocol == "auto" and isinstance(self.wheel, str):
            object.__setattr__(self, "protocol", self._own_protocol())
        if self.amplitude is None and isinstance(self.wheel, str):  # the wheel model's own
            p = self.nominal_wheel()
            default = p.nominal_speed_rpm if self.mode == "speed" else p.max_accel_rpm_s
            object.__setattr__(self, "amplitude", default)
        if self.signal not in SIGNALS:
            raise ConfigError(f"unknown signal {self.signal!r}; choose from {', '.join(SIGNALS)}")
        if self.mode not in MODES:
            raise ConfigError(f"unknown mode {self.mode!r}; choose 'speed' or 'acceleration'")
        if not isinstance(self.interface, str) or self.interface not in transport_names():
            raise ConfigError(
                f"unknown interface {self.interface!r}; choose from {', '.join(transport_names())}"
            )
        for name in ("amplitude", "duration", "Ts", "telemetry_rate", "min_hold", "max_hold"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"{name} must be a positive number, got {value!r}")
        number = (int, float)
        expected: dict[str, tuple[Any, str]] = {
            "seed": (int, "an integer"),
            "node_id": (int, "an integer 0..15"),
            "realtime": (bool, "true or false"),
            "rate_limit": (bool, "true or false"),
            "raw_frames": (bool, "true or false"),
            "latency": (number, "a number of seconds"),
            "f0": (number, "a number of Hz"),
            "channel": ((str, type(None)), "a string"),
            "file": ((str, type(None)), "a string"),
            "model": ((str, type(None)), "a path to model.json"),
            "diagnosis_calibration": ((str, type(None)), "a path to calibration.json"),
            "protocol": (str, "a wheel protocol name"),
            "f1": ((*number, type(None)), "a number of Hz"),
            "wheel": (str, "a wheel model name, a wheel spec or a wheel TOML file"),
            "unit": ((int, type(None)), "an integer ≥ 0"),
        }
        for name, (kind, text) in expected.items():
            value = getattr(self, name)
            bad_bool = isinstance(value, bool) and kind is not bool
            if not isinstance(value, kind) or bad_bool:
                raise ConfigError(f"{name} must be {text}, got {value!r}")
        if self.seed < 0:
            raise ConfigError(f"seed must be an integer ≥ 0, got {self.seed}")
        tol = self.late_tolerance
        if tol is not None and (
            isinstance(tol, bool)
            or not isinstance(tol, number)
            or not (math.isfinite(tol) and tol > 0)
        ):
            raise ConfigError(f"late_tolerance must be a positive number of seconds, got {tol!r}")
        if self.diagnosis_calibration is not None and self.model is None:
            raise ConfigError("diagnosis_calibration is the live diagnosis's: it needs model")
        self.wheel_params()  # a bad preset or unit fails here, before any work
        if not 0 <= self.node_id <= 15:
            raise ConfigError(f"node_id must be an integer 0..15, got {self.node_id}")
        if not (math.isfinite(self.latency) and self.latency >= 0):
            raise ConfigError(f"latency must be a number of seconds ≥ 0, got {self.latency!r}")
        f1 = math.inf if self.f1 is None else self.f1
        if not (0 < self.f0 < f1 and math.isfinite(self.f0)):
            raise ConfigError(f"the band must be 0 < f0 < f1 Hz, got f0={self.f0}, f1={self.f1}")
        levels = self.step_levels if isinstance(self.step_levels, tuple) else ()
        if not levels or not all(
            isinstance(v, number) and not isinstance(v, bool) and math.isfinite(v) for v in levels
        ):
            raise ConfigError(f"step_levels must be a list of numbers, got {self.step_levels!r}")
        from rwlab.wheel.link import get_protocol

        protocol = get_protocol(self.protocol)  # ConfigError naming the known ones
        if self.signal == "file" and not self.file:
            raise ConfigError("signal 'file' needs file = a CSV of setpoints")
        self._check_contradictions(protocol.transports)
        if self.duration < self.Ts:
            raise ConfigError(f"duration {self.duration} s is shorter than Ts = {self.Ts} s")
        if not isinstance(self.faults, tuple):
            raise ConfigError(f"faults must be a list of NAME[=VALUE]@SECONDS, got {self.faults!r}")
        for fault in self.scheduled_faults():
            if self.interface != "virtual":
                raise ConfigError("faults can only be injected into the simulated wheel (virtual)")
            if fault.t_s > self.duration:
                raise ConfigError(f"fault {fault} starts after the experiment ({self.duration} s)")
        if self.duration / self.Ts > MAX_COMMANDS:
            raise ConfigError(
                f"duration / Ts = {self.duration / self.Ts:.3g} commands; at most "
                f"{MAX_COMMANDS:.0e} in one experiment"
            )

    def _check_contradictions(self, transports) -> None:
        """Settings that would be silently ignored next to the others are refused."""
        if self.file and self.signal != "file":
            raise ConfigError(
                f"file gives the setpoints of signal 'file', not of signal {self.signal!r}: "
                "leave file out or set signal = 'file'"
            )
        if self.raw_frames and "can" not in transports:
            raise ConfigError(
                f"raw_frames records CAN frames, and protocol {self.protocol!r} has none (it "
                "runs on a byte stream): leave raw_frames off or choose a CAN protocol"
            )
        if self.unit is not None and self.interface != "virtual":
            raise ConfigError(
                f"unit draws a simulated wheel; on interface {self.interface!r} a real wheel "
                "answers: leave unit out or use interface 'virtual'"
            )

    def wheel_params(self, base: WheelParams | None = None) -> WheelParams:
        """The simulated wheel: ``base`` (default: the ``wheel`` preset), as unit ``unit``.

        Parameters
        ----------
        base : WheelParams, optional

        Returns
        -------
        WheelParams
        """
        if base is None and self.wheel.lower().endswith(".toml"):
            from rwlab._toml import read_table

            own = read_table(self.wheel, "wheel", "wheel parameter").get("unit")
            if own is not None and self.unit is not None:
                raise ConfigError(
                    f"{self.wheel} draws unit {own} and unit = {self.unit} would draw a second "
                    "time around it (a wheel that is neither): give the unit in one place"
                )
            params = WheelParams.load(self.wheel)  # with the file's own unit, if any
        else:
            params = self.nominal_wheel(base)
        return params if self.unit is None else params.for_unit(self.unit)

    def nominal_wheel(self, base: WheelParams | None = None) -> WheelParams:
        """The wheel as configured, before any unit draw: its limits are the driver's
        settings a lab knows (the record's ``driver_settings``).

        Parameters
        ----------
        base : WheelParams, optional

        Returns
        -------
        WheelParams
        """
        if base is not None:
            return base
        return WheelParams.load(self.wheel, draw_unit=False)

    def tolerance(self) -> float:
        """How late a command may go out, s: ``late_tolerance``, else 10 % of Ts (≥ 1 ms,
        ≤ Ts): a later command shifts the signal the model is identified from."""
        if self.late_tolerance is not None:
            return float(self.late_tolerance)
        return min(self.Ts, max(0.1 * self.Ts, 1e-3))

    def scheduled_faults(self) -> list[ScheduledFault]:
        """The faults, parsed (``ConfigError`` for a bad one)."""
        return [parse_fault(text) for text in self.faults]

    def _own_protocol(self) -> str:
        """``protocol = "auto"``: rwlab's DBC, unless its signals cannot carry the simulated
        wheel (then rwlab's NSP profile, whose floats carry any value); on a real bus the
        DBC, which :meth:`check_limits` refuses for a wheel it cannot carry."""
        from rwlab.wheel.link import get_protocol
        from rwlab.wheel.signal_fit import WIDE_PROTOCOL, misfits

        if self.interface != "virtual":
            return "rwlab"
        fits = not misfits(get_protocol("rwlab").signal_ranges(), self.nominal_wheel())
        return "rwlab" if fits else WIDE_PROTOCOL

    def check_limits(self, params: WheelParams) -> None:
        """Refuse amplitudes beyond the wheel's limits, and a protocol whose signals cannot
        carry the wheel's numbers (:mod:`rwlab.wheel.signal_fit`)."""
        from rwlab.wheel.signal_fit import check_carries

        check_carries(self.protocol, params, self.wheel)
        limit, unit = (
            (params.max_speed_rpm, "rpm")
            if self.mode == "speed"
            else (params.max_accel_rpm_s, "rpm/s")
        )
        if self.amplitude > limit:
            raise ConfigError(
                f"amplitude {self.amplitude:g} {unit} exceeds the wheel's {self.mode} limit "
                f"of {limit:g} {unit}"
            )

    @classmethod
    def from_toml(cls, path: str | os.PathLike, **overrides) -> ExperimentConfig:
        """Read an ``[experiment]`` table (or top-level keys); ``overrides`` win."""
        from rwlab._toml import read_table, unknown_keys

        table = read_table(path, "experiment", "experiment")
        if not table:
            raise ConfigError(
                f"{path}: the experiment file is empty; give an [experiment] table with at "
                "least the signal and its duration"
            )
        known = {f.name for f in fields(cls)}
        unknown = unknown_keys(table, known)
        if unknown:
            raise ConfigError(
                f"{path}: unknown experiment key(s) {unknown}; known: {sorted(known)}"
            )
        table.update({k: v for k, v in overrides.items() if v is not None})
        for key in ("step_levels", "faults"):
            if isinstance(table.get(key), list):
                table[key] = tuple(table[key])
        return cls(**table)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def make_signal(cfg: ExperimentConfig, params: WheelParams = RW90) -> np.ndarray:
    """The command samples, one per Ts, in rpm or rpm/s.

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment.
    params : WheelParams
        The wheel's limits.

    Returns
    -------
    numpy.ndarray, shape (round(duration / Ts),)
        The commands.
    """
    amplitude = cfg.amplitude
    if amplitude is None:  # resolved by ExperimentConfig; a hand-made object may lack it
        raise ConfigError("the experiment has no amplitude")
    if cfg.signal == "prbs":
        x = signals.prbs(cfg.duration, cfg.Ts, amplitude, cfg.min_hold, cfg.max_hold, seed=cfg.seed)
    elif cfg.signal == "chirp":
        f1 = cfg.f1 if cfg.f1 is not None else 0.4 / cfg.Ts
        x = signals.chirp(cfg.duration, cfg.Ts, cfg.f0, f1, amplitude)
    elif cfg.signal == "multisine":
        f1 = cfg.f1 if cfg.f1 is not None else 0.4 / cfg.Ts
        x = signals.multisine(
            cfg.duration, cfg.Ts, max(cfg.f0, 1.0 / cfg.duration), f1, amplitude, seed=cfg.seed
        )
    elif cfg.signal == "step":
        hold = cfg.duration / len(cfg.step_levels)
        x = signals.steps(np.asarray(cfg.step_levels) * amplitude, hold, cfg.Ts)
    else:
        x = _signal_from_file(cfg)
    if cfg.rate_limit and cfg.mode == "speed" and cfg.signal == "prbs":
        # the wheel starts at rest, so the limited command starts from 0
        x = signals.rate_limit(x, params.max_accel_rpm_s, cfg.Ts, initial=0.0)
    limit = params.max_speed_rpm if cfg.mode == "speed" else params.max_accel_rpm_s
    if np.max(np.abs(x)) > limit * (1 + 1e-9):
        raise ConfigError(
            f"the signal reaches {np.max(np.abs(x)):g}, beyond the wheel's ±{limit:g}"
        )
    return x


def _signal_from_file(cfg: ExperimentConfig) -> np.ndarray:
    file = str(cfg.file)
    data = load_data(file, Ts=cfg.Ts) if Path(file).suffix == ".csv" else None
    if data is None:
        raise ConfigError(f"setpoint file {cfg.file} must be a .csv")
    x = data.y[:, 0]  # a one-column file is read as the output channel
    if not math.isclose(data.Ts, cfg.Ts, rel_tol=1e-6):
        raise ConfigError(f"{cfg.file} is sampled at {data.Ts} s, the experiment at {cfg.Ts} s")
    return x[: round(cfg.duration / cfg.Ts)]


@dataclass(repr=False)
class RunSummary(ShortRepr):
    """What an experiment produced.

    Parameters
    ----------
    path : Path
        The record written.
    commands, telemetry : int
        Frames sent and received.
    lost_frames, bad_frames : int
        Telemetry frames missing, and refused (bad checksum or length).
    duration : float
        Length of the experiment, s.
    status : {'completed', 'completed with timing faults', 'interrupted', 'fault', 'error'}
        How it ended.
    timing : dict
        Command timing (:class:`Timing`): period and lateness p50/p99/max, commands late.
    alarms : tuple of str
        The live fault detector's alarms (``--model``), as the record's ``alarm`` events.
    faults_injected : tuple of str
        The faults injected into the twin (``NAME=VALUE@SECONDS``), as recorded.
    """

    path: Path
    commands: int
    telemetry: int
    lost_frames: int
    bad_frames: int
    duration: float
    status: str  # "completed", "completed with timing faults", "interrupted", "fault", "error"
    timing: dict = dataclasses.field(default_factory=dict)
    """Command timing (:class:`Timing`): period and lateness p50/p99/max, commands late."""
    alarms: tuple[str, ...] = ()
    """The live fault detector's alarms (``--model``), as the record's ``alarm`` events."""
    faults_injected: tuple[str, ...] = ()
    """The faults injected into the twin (``NAME=VALUE@SECONDS``), as recorded."""


class Timing:
    """When each command went out against when it was due (real-time quality).

    Lateness is the send time minus the due time t₀ + k·Ts; the period is the
    interval between consecutive sends. A command later than ``tolerance`` is
    *late*; a run with a late command did not hold its sample time, and its
    record says so ("completed with timing faults").

    Parameters
    ----------
    Ts : float
        The command period, s.
    tolerance : float
        Lateness beyond which a command counts as late, s.
    """

    def __init__(self, Ts: float, tolerance: float) -> None:
        self.Ts, self.tolerance = Ts, tolerance
        self.due: list[float] = []
        self.sent: list[float] = []

    def add(self, due: float, sent: float) -> None:
        """One command: due and sent clock times, s."""
        self.due.append(due)
        self.sent.append(sent)

    def summary(self) -> dict:
        """Plain JSON: ``lateness_s`` and ``period_s`` as p50/p99/max, ``late`` (count)."""
        late = np.asarray(self.sent) - np.asarray(self.due)
        period = np.diff(self.sent)

        def stats(x: np.ndarray) -> dict:
            if not x.size:
                return {"p50": None, "p99": None, "max": None}
            return {k: float(np.percentile(x, q)) for k, q in (("p50", 50), ("p99", 99))} | {
                "max": float(np.max(x))
            }

        return {
            "Ts_s": self.Ts,
            "tolerance_s": self.tolerance,
            "commands": int(late.size),
            "late": int(np.sum(late > self.tolerance)),
            "lateness_s": stats(late),
            "period_s": stats(period),
        }


def run_experiment(
    cfg: ExperimentConfig,
    out: str | os.PathLike,
    *,
    params: WheelParams | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    on_alarm: Callable[[str], None] | None = None,
) -> RunSummary:
    """Run ``cfg`` and write the record to ``out`` (an ``.mcap`` file).

    ``params`` replaces the preset named by ``cfg.wheel`` (``cfg.unit`` still applies).

    ``progress(k, n)`` is called after each command. KeyboardInterrupt and
    errors idle the wheel, close the record (with an event saying why) and
    are re-raised.

    Parameters
    ----------
    cfg : ExperimentConfig
        The experiment.
    out : str or os.PathLike
        The ``.mcap`` file.
    params : WheelParams
        The simulated wheel's parameters.
    force : bool
        Replace an existing record.
    progress : callable, optional
        ``progress(k, n)`` after each command.
    on_alarm : callable, optional
        ``on_alarm(text)`` as each alarm of the live detector (``cfg.model``) comes,
        with the text of its record event.

    Returns
    -------
    RunSummary
    """
    nominal = cfg.nominal_wheel(params)
    params = cfg.wheel_params(params)
    cfg.check_limits(params)
    if cfg.interface == "virtual" and cfg.Ts >= WATCHDOG_S:  # it would idle between commands
        raise ConfigError(
            f"Ts = {cfg.Ts:g} s is not shorter than the simulated wheel's command "
            f"watchdog ({WATCHDOG_S:g} s): the wheel would idle between commands; "
            f"choose Ts < {WATCHDOG_S:g} s"
        )
    command = make_signal(cfg, params)
    # before the clock starts (loading delays no command) and before the record opens
    detector = _live_detector(cfg)
    simulated = cfg.interface == "virtual"
    realtime = cfg.realtime or not simulated
    clock = WallClock() if realtime else SimClock()
    metadata = {
        "rwlab_version": __version__,
        "dbc_sha256": dbc_sha256(),
        "protocol": cfg.protocol,
        "protocol_identity": get_protocol(cfg.protocol).identity(),
        "Ts": cfg.Ts,
        "mode": cfg.mode,
        "experiment": cfg.to_dict(),
        "wheel": params.to_dict(),
        "wheel_spec": nominal.spec().to_dict(),  # the model's datasheet, as configured
        "driver_settings": {  # what a lab knows of its wheel: configured, not drawn
            "current_limit": nominal.current_limit,
            "max_speed_rpm": nominal.max_speed_rpm,
            "max_accel_rpm_s": nominal.max_accel_rpm_s,
        },
        "wheel_source": (
            f"simulated {nominal.model} twin" if simulated else f"{cfg.interface}:{cfg.channel}"
        ),
        "clock": "wall" if realtime else "simulated",
        "start_utc": datetime.now(UTC).isoformat(timespec="milliseconds"),
        "time_origin": "s since the first command",
    }
    faults = sorted(cfg.scheduled_faults(), key=lambda f: f.t_s)
    injected = tuple(str(f) for f in faults)
    alarms: list[str] = []
    # first: a bad --out opens no bus
    writer = RecordWriter(out, metadata, force=force, wall_clock=realtime)
    stream_twin = simulated and "can" not in get_protocol(cfg.protocol).transports
    try:
        channel = cfg.channel or (f"rwlab-{os.getpid()}-{id(cfg)}" if simulated else None)
        if stream_twin:  # a serial protocol's twin answers over a pseudo-terminal pair
            node_bus, host_bus = open_pty()
        else:
            host_bus = open_transport(
                cfg.protocol, cfg.interface, channel, simulated_clock=not realtime
            )
    except BaseException:
        writer.discard()  # nothing was recorded: keep the old record, if any
        raise
    node = None
    if not stream_twin:
        node_bus = None
    try:
        if simulated:
            if not stream_twin:
                channel = host_bus.channel_id
                node_bus = open_bus("virtual", channel, simulated_clock=not realtime)
            node = WheelNode(
                node_bus,
                cfg.node_id,
                params,
                clock=clock,
                telemetry_rate=cfg.telemetry_rate,
                latency=cfg.latency,
                seed=cfg.seed,
                protocol=cfg.protocol,
            )
            if realtime:
                node.start()
        client = WheelClient(
            host_bus,
            cfg.node_id,
            params,
            clock=clock,
            timeout=max(0.5, 2 * cfg.Ts),
            protocol=cfg.protocol,
        )
        client.link.set_telemetry_rate(cfg.telemetry_rate)
    except BaseException:  # refused before the first command: no record, no bus left open
        writer.discard()
        if node is not None:
            node.stop()
        for bus in (node_bus, host_bus):
            if bus is not None:
                _close(bus)
        raise
    if cfg.raw_frames:
        client.frame_listener = lambda t, frame_id, data, direction: writer.write(
            "/can", {"t": t, "id": frame_id, "data": data.hex(), "direction": direction}
        )
    send = client.set_speed if cfg.mode == "speed" else client.set_acceleration
    status, k = "error", 0
    timing = Timing(cfg.Ts, cfg.tolerance())
    t0 = clock.now() + 0.01
    writer.time_origin = t0
    if node is not None:
        node.schedule_faults(faults, origin=t0)
    try:
        writer.event(t0, "start", f"{cfg.signal} in {cfg.mode} mode, {len(command)} commands")
        for k, value in enumerate(command):
            _record_until(client, writer, clock, t0 + k * cfg.Ts, realtime)
            while faults and faults[0].t_s <= k * cfg.Ts:
                fault = faults.pop(0)
                writer.event(t0 + fault.t_s, "fault_injected", str(fault))
            if detector is not None and client.latest is not None:
                for alarm in detector.update(
                    k * cfg.Ts,
                    float(value),
                    client.latest.speed_rpm,
                    client.latest.current,
                    clock.now() - client.latest_time,
                    client.lost_frames,
                ):
                    alarms.append(_alarm_text(alarm))
                    writer.event(clock.now(), "alarm", alarms[-1])
                    if on_alarm is not None:
                        on_alarm(alarms[-1])
            seq = send(float(value))
            sent = clock.now()
            timing.add(t0 + k * cfg.Ts, sent)
            writer.write(
                "/command",
                {"t": sent, "sequence": seq, "mode": cfg.mode, "setpoint": float(value)},
            )
            if k == 0:
                client.wait_ack(seq)  # no wheel on the bus: WheelTimeout now, not an empty record
            if progress:
                progress(k + 1, len(command))
        _record_until(client, writer, clock, t0 + len(command) * cfg.Ts, realtime)
        for fault in faults:  # those that started after the last command
            writer.event(t0 + fault.t_s, "fault_injected", str(fault))
        status = "completed" if not timing.summary()["late"] else "completed with timing faults"
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except WheelFault as exc:
        status = "fault"
        writer.event(clock.now(), "fault", str(exc))
        raise
    except Exception as exc:
        writer.event(clock.now(), "error", f"{type(exc).__name__}: {exc}")
        raise
    finally:
        try:
            client.close()  # the wheel idles first, whatever else fails
            _drain(client, writer, clock)
            dropped = _dropped_text(client)
            if dropped:
                writer.event(clock.now(), "dropped_frames", dropped)
            writer.event(clock.now(), "timing", json.dumps(timing.summary()))
            writer.event(clock.now(), "stop", status)
        finally:
            try:
                writer.close()
            finally:
                if node is not None:
                    node.stop()
                    _close(node.bus)
                _close(host_bus)
    return RunSummary(
        Path(out),
        writer.counts["/command"],
        writer.counts["/telemetry"],
        client.lost_frames,
        client.bad_frames,
        clock.now() - t0,
        status,
        timing.summary(),
        tuple(alarms),
        injected,
    )


def _close(transport: object) -> None:
    """Shut a bus down, or close a serial port."""
    closer = getattr(transport, "shutdown", None) or getattr(transport, "close", None)
    if closer is not None:
        closer()


def _dropped_text(client: WheelClient) -> str:
    """What the host dropped from the bus, or '' when nothing was."""
    counts = {
        "damaged": client.bad_frames,
        "of other protocols": client.foreign_frames,
        "implausible": client.implausible_frames,
        "commands not acknowledged": client.lost_commands,
    }
    return ", ".join(f"{n} {what}" for what, n in counts.items() if n)


def _live_detector(cfg: ExperimentConfig):
    """The live diagnosis for ``cfg.model``, or None."""
    if cfg.model is None:
        return None
    from rwlab.diagnose.watch import RecordWatch
    from rwlab.ident.model_file import WheelModelFile

    spec = WheelModelFile.load(cfg.model).wheel_spec
    if spec is not None and spec != cfg.nominal_wheel().spec():
        raise ConfigError(
            f"--model is a model of the wheel {spec.name!r}, the experiment runs "
            f"{cfg.wheel!r} (another spec): live diagnosis needs a model of the wheel it "
            "watches (rwlab identify on one of its healthy records)"
        )
    watch = RecordWatch(cfg.model, cfg.diagnosis_calibration)
    if cfg.mode != "speed" or not math.isclose(watch.scales.Ts, cfg.Ts, rel_tol=1e-6):
        raise ConfigError(
            f"live diagnosis needs speed mode at the model's Ts = {watch.scales.Ts:g} s "
            f"(the experiment: {cfg.mode} mode, Ts = {cfg.Ts:g} s)"
        )
    return watch


def _alarm_text(event) -> str:
    """An alarm's line: the fault, its size and interval, what crossed, the runner-up; or
    its re-labelling by a better-supported fault."""
    f = event.fit
    named = f"{f.fault} at {event.t_s:.1f} s {f.size_text()}".rstrip()
    if event.relabelled:
        t, was = event.relabelled[-1]
        return f"{named} (re-labelled from {was} at {t:.1f} s)"
    runner = "" if event.runner_up is None else f"; runner-up {event.runner_up}"
    return (
        f"{named} ({event.detector} crossed, log-LR "
        f"{event.fit.log_lr:.3g} > {event.threshold:.3g}{runner})"
    )


def _record_until(
    client: WheelClient, writer: RecordWriter, clock, t_next: float, realtime: bool
) -> None:
    """Wait until ``t_next``, writing every frame that arrives meanwhile."""
    if not realtime:
        clock.sleep_until(t_next)
        _drain(client, writer, clock)
        return
    while clock.now() < t_next:
        _drain(client, writer, clock)
        clock.sleep_until(min(t_next, clock.now() + 0.005))
    _drain(client, writer, clock)


def _drain(client: WheelClient, writer: RecordWriter, clock) -> None:
    for t, frame in client.drain():
        if isinstance(frame, Implausible):  # flagged, never recorded as the wheel's state
            writer.event(t, "implausible_telemetry", frame.reason)
        elif isinstance(frame, Telemetry):
            writer.write(
                "/telemetry",
                {
                    "t": t,
                    "speed_rpm": frame.speed_rpm,
                    "current_a": frame.current,
                    "mode": frame.mode.name,
                    "fault_active": frame.fault_active,
                    "speed_limited": frame.speed_limited,
                    "sequence_echo": frame.sequence_echo,
                    "counter": frame.counter,
                },
            )
        else:
            writer.write(
                "/heartbeat",
                {
                    "t": t,
                    "mode": frame.mode.name,
                    "faults": int(frame.faults),
                    "temperature_c": frame.temperature,
                    "bus_voltage_v": frame.bus_voltage,
                    "uptime_s": frame.uptime,
                },
            )
