"""``rwlab hil``: the attitude loop closed through the wheels on a bus, recorded and diagnosed.

Each control period (the scenario's ``dt``) the host
1. asks the :class:`~rwlab.hil.satellite.Satellite` for the wheel torques
   (sensors, MEKF, control law, allocation over the healthy wheels),
2. sends them as acceleration commands through each wheel's ``WheelClient``,
3. waits for the period's end (simulated clock: the twins run up to it;
   wall clock: it sleeps, and measures how late it woke),
4. reads every wheel's newest telemetry and closes the period with the
   momenta the wheels *report*,
5. feeds each wheel's telemetry to its live diagnoser
   (:class:`rwlab.diagnose.Diagnoser`); an alarm idles that wheel and, when
   the others still span three axes, reallocates the torque to them.

Everything that crosses the bus, the satellite's channels and every event go
into one MCAP record. Whatever ends the run — its end, a silent wheel, a
broken bus, Ctrl-C, SIGTERM, any error — every wheel is idled and the record
is closed with a ``stop`` event.

Why this module is long: one run: its configuration, the bus and twins it starts, the
loop, the fault handling and the record share one run state, and every exit path (end,
silent wheel, broken bus, signal, error) must idle the wheels in one place.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from rwlab.attitude.control import (
    CHOSEN_RHO,
    CONTROLLERS,
    LQRController,
    PDController,
    ltr_noise,
    metrics,
    pd_gains,
    slew_rate_limit,
)
from rwlab.attitude.scenario import Scenario, load_scenario
from rwlab.attitude.sim import SimResult, relative_rate
from rwlab.attitude.wheels import physics_params
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration
from rwlab.errors import ConfigError, HilStopped, RwlabError, WheelFault  # HilStopped: re-export
from rwlab.hil.bench import WheelBank
from rwlab.hil.health import (
    DITHER_PERIOD_S,
    DITHER_RPM_S,
    PROBE_EVERY_S,
    PROBE_S,
    PROBE_SHARE,
    WINDOW_S,
    NullSpaceDither,
    TrackingTest,
    nominal_friction_nm,
    null_vector,
    stiction_band_rpm,
)
from rwlab.hil.live import PipelineWatch, hil_calibration_file
from rwlab.hil.satellite import Satellite
from rwlab.hil.telemetry import BLOCK_S, DropoutTest
from rwlab.wheel import protocol as proto
from rwlab.wheel.clock import SimClock, WallClock
from rwlab.wheel.faults import ScheduledFault, parse_fault
from rwlab.wheel.link import get_protocol
from rwlab.wheel.physics import WheelParams, rad_s_to_rpm

__all__ = [
    "HilConfig",
    "HilResult",
    "HilStopped",
    "parse_node_fault",
    "run_hil",
    "zero_crossings",
]

SIM_READ_DELAY = 1e-6  # s after each control instant the simulated host reads (see run_hil)
SPIN_UP_RPM_S = 20.0  # the bias spin-up's ramp, rpm/s
SPIN_UP_HOLD_S = 10.0  # and its hold before the run, s
LATE_S = 0.005  # a wall-clock period that starts this late counts as a late step
DEFAULT_BIAS_RPM = 1000.0  # a redundant set's momentum bias unless told: far from zero speed


_NODE_FAULT = re.compile(r"^\s*(\d+)\s*:(.+)$")


def parse_node_fault(text: str) -> tuple[int, ScheduledFault]:
    """``NODE:NAME[=VALUE]@SECONDS`` (e.g. ``2:torque_constant=0@1800``) → (node, fault).

    Parameters
    ----------
    text : str
        The ``--fault`` argument.

    Returns
    -------
    (int, ScheduledFault)
        The wheel's node id and the fault scheduled on it.
    """
    match = _NODE_FAULT.match(text) if isinstance(text, str) else None
    if match is None:
        raise ConfigError(
            f"--fault {text!r} is not NODE:NAME[=VALUE]@SECONDS (e.g. 2:torque_constant=0@1800)"
        )
    return int(match.group(1)), parse_fault(match.group(2))


@dataclass(frozen=True)
class HilConfig:
    """One hardware-in-the-loop run.

    Attributes
    ----------
    scenario : str
        Built-in name or scenario TOML.
    wheel : str, optional
        The wheel model the twin nodes fly (a preset or a unit's own wheel spec file;
        ``wheels.spec`` of the scenario by default).
    force_wheel : bool
        Fly a wheel model that cannot deliver the scenario's needs
        (:mod:`rwlab.attitude.wheel_fit`); otherwise it is refused.
    controller : str
        ``pd``, ``lqr``, ``lqg`` or ``lqg_ltr`` (as ``attitude simulate``).
    interface, channel : the bus.
    protocol : str, optional
        The wheel protocol's registry name: ``rwlab``, ``canopen``,
        ``canopen/oresat``, ``canopen/cia402`` or a registered CAN one; a serial (NSP)
        profile is refused, since its wheels cannot share one bus, and so is one whose
        signals would clip the wheel's numbers. Default: ``rwlab``, or ``canopen`` for
        twins whose current rwlab's DBC cannot carry (±2.048 A: the NRWA-T6 class).
    nodes : tuple of int, optional
        Node id of each wheel in the scenario's order (default 1..N).
    duration : float
        Seconds of flight.
    seed : int, optional
        Noise seed (the scenario's by default).
    realtime : bool
        Wall clock instead of the simulated clock.
    epoch : str, optional
        Real sky from this UTC instant.
    faults : tuple of (node, ScheduledFault)
        Faults injected into the twins; their times count from the first control period.
    twins : bool, optional
        Start twins (default: on ``virtual`` and ``udp_multicast``).
    telemetry_rate : float, optional
        Twins' telemetry rate, Hz (default: one frame per control period on the
        simulated clock, 50 Hz on the wall clock).
    latency_s : float
        Twins' command-to-effect latency, s.
    wheel_bias_rpm : float, optional
        Spin the wheels up to this speed along the null space of the wheel matrix
        before the run (a pyramid's momentum bias: no zero crossings, no body momentum).
        Default :data:`DEFAULT_BIAS_RPM` on a redundant wheel set, 0 otherwise.
    diagnosis : bool, optional
        Live diagnosis of every wheel's telemetry. By default on when the wheels carry
        a momentum bias (``wheel_bias_rpm``): the diagnosers' current balance holds for
        a spinning wheel, and a wheel that hovers in the Hall sensors' dead zone (it
        reads 0 below ``min_measurable_rpm``) flips its drive's friction feed-forward
        with a sign the reading cannot show, which the current test takes for a fault
        (measured: a false alarm within 300 s on the orthogonal smallsat).
    diagnosis_calibration : str, optional
        A calibration file measured on the wheels' own healthy flights (``rwlab diagnose
        calibrate RECORDS... --in-loop``): the health check's GLR pipeline
        (:mod:`rwlab.hil.live`) decides with it; by default the preset's shipped one where
        the wheel is a preset's own, else the command-tracking test.
    health_check : bool, optional
        The null-space excitation, its capacity probes and every wheel's
        command-tracking test (:mod:`rwlab.hil.health`). Default: on with the diagnosis
        on a redundant set, where it is the diagnosis (the :mod:`rwlab.diagnose` block
        tests then do not run: a held-speed flight gives them nothing to calibrate on).
    diagnosis_period_s : float
        The diagnosers' sample time, s (a whole number of control periods).
    calibration_s, false_alarms_per_hour : the diagnosers' (:class:`rwlab.diagnose.Diagnoser`).
    log_every : int
        Control periods between satellite records (rounded to sensor periods).
    timeout_s : float
        A wheel silent this long stops the run.
    rt_priority : int, optional
        On the wall clock, run the control loop under the SCHED_FIFO real-time policy at
        this priority (1..99; Linux, needs CAP_SYS_NICE), as a bench computer would: a
        loaded machine then cannot make a control period start late.
    steady_after : float, optional
        Seconds after which the steady-state statistics start (as ``attitude simulate
        --steady-after``; default half the run, at most its first hour).
    reference : bool
        Also fly ``attitude simulate`` on the same scenario and seed with the physics
        wheel (healthy, from the same wheel momenta) for the side-by-side comparison.
    """

    scenario: str = "geo-smallsat"
    wheel: str | None = None
    force_wheel: bool = False
    controller: str = "lqg"
    interface: str = "virtual"
    channel: str | None = None
    protocol: str | None = None
    nodes: tuple[int, ...] | None = None
    duration: float = 600.0
    seed: int | None = None
    realtime: bool = False
    epoch: str | None = None
    faults: tuple[tuple[int, ScheduledFault], ...] = ()
    twins: bool | None = None
    telemetry_rate: float | None = None
    latency_s: float = 0.02
    wheel_bias_rpm: float | None = None
    diagnosis: bool | None = None
    health_check: bool | None = None
    diagnosis_calibration: str | None = None
    diagnosis_period_s: float = 0.5
    calibration_s: float = 300.0
    false_alarms_per_hour: float = 1e-3
    log_every: int = 5
    timeout_s: float = 0.5
    reference: bool = True
    rt_priority: int | None = None
    steady_after: float | None = None


@dataclass
class HilResult:
    """What a run produced (the files are written by the time it returns).

    Attributes
    ----------
    run : SimResult
        The satellite's trace, as ``attitude simulate`` returns it.
    metrics : dict
        ``metrics.json``: ``attitude simulate``'s keys, ``timing``, ``wheel_faults``,
        ``bench`` and ``config``.
    events : list of dict
        The record's events (t, kind, message).
    wheel_log : dict
        node → arrays ``t``, ``speed_rpm``, ``command_rpm_s`` at each control period.
    scenario : Scenario
    wheel_momentum0 : (N,) array
        The wheels' momenta at the start, N·m·s.
    reference : SimResult or None
        ``attitude simulate``'s run of the same scenario and seed with the physics wheel.
    paths : dict
        name → path of each file written.
    """

    run: SimResult
    metrics: dict
    events: list[dict]
    wheel_log: dict
    scenario: Scenario
    wheel_momentum0: np.ndarray
    reference: SimResult | None = None
    paths: dict = field(default_factory=dict)


def build_controller(sc: Scenario, name: str):
    """(controller, estimator, simulate keywords) as ``attitude simulate`` flies ``name``."""
    if name not in CONTROLLERS:
        raise ConfigError(f"controller must be one of {CONTROLLERS}, got {name!r}")
    estimator = "truth" if name in ("pd", "lqr") else "ekf"
    kw: dict = {}
    if name == "pd":
        pd = PDController(*pd_gains(sc))
        pd.rate_limit = slew_rate_limit(sc, pd.K)
        return pd, estimator, kw
    lqr = LQRController(sc)
    if name == "lqg_ltr":
        kw = dict(filter_torque_psd=ltr_noise(sc, lqr)[0], filter_noise_scale=math.sqrt(CHOSEN_RHO))
    return lqr, estimator, kw


class _CommandedSpeed:
    """The diagnosers' wheel model in acceleration mode: the wheel follows the speed its
    commands lead to (``step`` returns the speed command), within ``accel_limit_rpm_s``."""

    def __init__(self, Ts: float, accel_limit_rpm_s: float) -> None:
        self.Ts, self.accel_limit_rpm_s = Ts, accel_limit_rpm_s
        self.speed_rpm = 0.0

    def reset(self, speed_rpm: float) -> None:
        self.speed_rpm = float(speed_rpm)

    def step(self, command_rpm: float) -> float:
        self.speed_rpm = float(command_rpm)
        return self.speed_rpm


class _WheelWatch:
    """One wheel's live diagnosis in the loop (:mod:`rwlab.diagnose`).

    The diagnosers take a speed command and a healthy reference; in acceleration mode
    the command is the speed the commanded acceleration leads to from the last reading
    (rpm), and the reference is measured (``healthy_reference``) on this wheel's first
    ``calibration_s`` in the loop — the regime it will watch — then the
    :class:`~rwlab.diagnose.Diagnoser` tests every sample against it.
    """

    def __init__(self, Ts: float, accel_limit: float, calibration_s: float, fa_per_hour: float):
        self.model = _CommandedSpeed(Ts, accel_limit)
        self.Ts, self.calibration_s, self.fa_per_hour = Ts, calibration_s, fa_per_hour
        self.rows: list[tuple[float, ...]] = []
        self.t_start: float | None = None
        self.diagnoser: Any = None
        self._last: float | None = None

    def update(self, t: float, accel_rpm_s: float, speed: float, current: float, age: float):
        from rwlab.data import IOData
        from rwlab.diagnose import Diagnoser, healthy_reference

        command = (speed if self._last is None else self._last) + accel_rpm_s * self.Ts
        self._last = speed
        if self.diagnoser is not None:
            return self.diagnoser.update(t, command, speed, current, age, 0.0)
        if self.t_start is None:
            self.t_start = t
        self.rows.append((command, speed, current, age, 0.0))
        if t - self.t_start >= self.calibration_s:
            table = np.array(self.rows)
            data = IOData(
                table[:, :1],
                table[:, 1:],
                self.Ts,
                input_names=["command"],
                output_names=["speed_rpm", "current_a", "telemetry_age_s", "lost_frames"],
                input_units=["rpm"],
                output_units=["rpm", "A", "s", ""],
            )
            reference = healthy_reference(data, self.model, source="rwlab hil calibration")
            self.diagnoser = Diagnoser(
                self.model, reference, false_alarms_per_hour=self.fa_per_hour
            )
        return []


# An idled wheel's coast-down names a rotor fault the tracking test saw: its drag against
# the wheel model's (friction × F coasts down F times faster; a weak or dead motor, idled,
# at the model's rate). Design choices: five seconds of a ~1000-rpm coast-down (~30 rpm
# of a 6.6 rpm/s drag on the RW90, read to 0.1 rpm) and a unit's friction within ±25 % of
# its model's. Measured on the twins: friction × 1.5, 2, 4 coast 1.51, 2.01, 4.00 × the
# model's drag; k_t × 0.5, 0.7, 0 at 1.00. Hand-written: no library names wheel faults.
COAST_S = 5.0
COAST_FRICTION_RATIO = 1.25
COAST_NAMES = ("friction", "torque_constant")


@dataclass
class _CoastDown:
    """An idled wheel's coast-down being read: its fault entry, the flight time it was
    idled, and (flight time s, speed rpm) since."""

    entry: dict
    t_s: float
    samples: list[tuple[float, float]] = field(default_factory=list)


def _injected(faults, node: int, named: str, t: float) -> ScheduledFault | None:
    """The fault injected into ``node`` that an alarm at flight time ``t`` naming ``named``
    answers: the one of that name, else the latest injected before ``t``, else the first."""
    mine = sorted((f for n, f in faults if n == node), key=lambda f: f.t_s)
    before = [f for f in mine if f.t_s <= t]
    same = [f for f in before if f.name == named]
    if same or before:
        return (same or before)[-1]
    return mine[0] if mine else None


def _null_space_bias(sc: Scenario, bias_rpm: float) -> np.ndarray:
    """Wheel speeds (N,) rpm with no body momentum and |speed| = ``bias_rpm`` where possible."""
    n = null_vector(sc.wheel_matrix)
    if n is None:
        raise ConfigError(
            f"{sc.name}: its {sc.n_wheels} wheels have no null space; a momentum bias needs a "
            "redundant set (wheel_axes = 'pyramid')"
        )
    return bias_rpm * n


_SAT = {
    "t": {"type": "number"},
    "error_deg": {"type": "number"},
    "estimation_error_deg": {"type": "number"},
    "q": {"type": "array"},
    "q_est": {"type": "array"},
    "w_bo": {"type": "array"},
    "torque_demand_Nm": {"type": "array"},
    "wheel_torque_cmd_Nm": {"type": "array"},
    "wheel_momentum_Nms": {"type": "array"},
    "sun_sensor": {"type": ["array", "null"]},
    "earth_sensor": {"type": ["array", "null"]},
    "gyro_rad_s": {"type": ["array", "null"]},
    "star_tracker_q": {"type": ["array", "null"]},
    "active_wheels": {"type": "array"},
}


def _channels(nodes) -> dict[str, dict]:
    from rwlab.testbed.record import CHANNELS

    out = {"/satellite": _SAT}
    for n in nodes:
        for kind in ("command", "telemetry", "heartbeat"):
            out[f"/wheel{n}/{kind}"] = CHANNELS[f"/{kind}"]
    return out


def _frame_writer(record, node: int, clock):
    """A ``WheelClient.frame_listener`` writing each decoded frame to the node's topics
    (called with the clock time, the frame id, its bytes and 'rx' or 'tx')."""
    import can

    def listen(t: float, frame_id: int, data: bytes, direction: str) -> None:
        msg = can.Message(arbitration_id=frame_id, data=bytes(data), is_extended_id=False)
        try:
            frame = proto.decode(msg)
        except proto.ProtocolError:
            return  # the client counts bad frames
        _write_frame(record, node, t, frame)

    return listen


def _message_writer(record, client) -> None:
    """Record a client's commands and incoming telemetry and heartbeats as its link hands
    them over, protocol-free: a protocol other than rwlab's has no frame that
    :func:`rwlab.wheel.protocol.decode` reads (its SDOs and PDOs are not one message
    each), so its messages are recorded where the link has made them."""
    link, node = client.link, client.node_id
    send, receive = link.send, link.receive

    def sent(cmd: proto.Command, now: float) -> None:
        send(cmd, now)
        _write_frame(record, node, now, cmd)

    def received(now: float) -> list:
        incoming = receive(now)
        for i in incoming:
            _write_frame(record, node, i.t, i.frame)
        return incoming

    link.send, link.receive = sent, received


def _write_frame(record, node: int, t: float, frame) -> None:
    """One command, telemetry or heartbeat to the node's topic."""
    if isinstance(frame, proto.Command):
        record.write(
            f"/wheel{node}/command",
            {
                "t": t,
                "sequence": frame.sequence,
                "mode": frame.mode.name,
                "setpoint": frame.setpoint,
            },
        )
    elif isinstance(frame, proto.Telemetry):
        record.write(
            f"/wheel{node}/telemetry",
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
    elif isinstance(frame, proto.Heartbeat):
        record.write(
            f"/wheel{node}/heartbeat",
            {
                "t": t,
                "mode": frame.mode.name,
                "faults": int(frame.faults),
                "temperature_c": frame.temperature,
                "uptime_s": frame.uptime,
            },
        )


def _protocol(name: str | None, params: WheelParams, wheel: str, twins: bool) -> str:
    """The protocol named, else rwlab's, else for twins that its DBC cannot carry CANopen;
    a protocol whose signals would clip the wheel's numbers is refused."""
    from rwlab.wheel.signal_fit import WIDE_CAN_PROTOCOL, check_carries, misfits

    if name is None:
        fits = not misfits(get_protocol("rwlab").signal_ranges(), params)
        name = "rwlab" if fits or not twins else WIDE_CAN_PROTOCOL
    check_carries(name, params, wheel, instead=WIDE_CAN_PROTOCOL)
    return name


def _check(cfg: HilConfig, sc: Scenario) -> tuple[int, ...]:
    from rwlab.hil.bench import check_multidrop

    assert cfg.protocol is not None  # resolved by run_hil
    check_multidrop(cfg.protocol)  # before anything starts
    nodes = cfg.nodes or tuple(range(1, sc.n_wheels + 1))
    if len(nodes) != sc.n_wheels:
        raise ConfigError(f"{sc.name} has {sc.n_wheels} wheels; nodes names {len(nodes)} ({nodes})")
    if not (math.isfinite(cfg.duration) and cfg.duration >= sc.run.dt):
        raise ConfigError(f"duration must be at least one control period ({sc.run.dt:g} s)")
    if cfg.rt_priority is not None and not cfg.realtime:
        raise ConfigError(
            "rt_priority schedules the wall-clock loop; this run is on the simulated clock: "
            "leave rt_priority out or set realtime=True"
        )
    if cfg.realtime and sc.run.dt > 0.1 + 1e-12:
        raise ConfigError(
            f"the wall-clock loop runs at 10 Hz or faster; {sc.name} has dt {sc.run.dt:g} s"
        )
    for node, fault in cfg.faults:
        if node not in nodes:
            raise ConfigError(f"a fault names node {node}, not one of the wheels {nodes}")
        if fault.t_s > cfg.duration:
            raise ConfigError(f"fault {node}:{fault} starts after the run ends")
    sa = cfg.steady_after
    if sa is not None and not (math.isfinite(sa) and 0 <= sa < cfg.duration):
        raise ConfigError(f"steady_after must be a number of seconds in [0, duration), got {sa!r}")
    every = cfg.diagnosis_period_s / sc.run.dt
    if cfg.diagnosis is not False and (every < 1 or abs(every - round(every)) > 1e-9):
        raise ConfigError("the diagnosis period must be a whole number of control periods")
    return tuple(nodes)


def run_hil(cfg: HilConfig, out_dir, *, force: bool = False, progress=None) -> HilResult:
    """Fly ``cfg`` and write ``record.mcap`` and ``metrics.json`` into ``out_dir``.

    Parameters
    ----------
    cfg : HilConfig
    out_dir : path-like
        The output folder (created).
    force : bool
        Replace existing outputs.
    progress : callable, optional
        Called with the number of control periods flown, now and then.

    Returns
    -------
    HilResult

    Raises
    ------
    HilStopped
        A wheel went silent, the bus failed, or the run was interrupted (Ctrl-C,
        SIGTERM: ``KeyboardInterrupt``); every wheel was idled and the record closed.
    ConfigError, WheelTimeout
        Refused before the run (bad configuration, a wheel silent or answering twice).
    """
    from rwlab.data import atomic_write_bytes
    from rwlab.testbed.record import RecordWriter

    overrides: dict = {"sky.epoch": cfg.epoch} if cfg.epoch else {}
    if cfg.wheel is not None:  # the twin nodes fly this wheel model (a unit's own file)
        overrides["wheels.spec"] = cfg.wheel
    sc = load_scenario(cfg.scenario, **overrides)
    from rwlab.attitude.wheel_fit import check_wheel_fit

    wheel_forced = check_wheel_fit(sc, force=cfg.force_wheel)
    params = physics_params(sc)
    twins = cfg.twins if cfg.twins is not None else cfg.interface in ("virtual", "udp_multicast")
    protocol = _protocol(cfg.protocol, params, sc.wheels.wheel_spec.name, twins)
    cfg = replace(cfg, protocol=protocol)
    nodes = _check(cfg, sc)
    redundant = null_vector(sc.wheel_matrix) is not None
    if cfg.wheel_bias_rpm is None:
        cfg = replace(cfg, wheel_bias_rpm=DEFAULT_BIAS_RPM if redundant else 0.0)
    seed = sc.run.seed if cfg.seed is None else cfg.seed
    ctl, estimator, sim_kw = build_controller(sc, cfg.controller)
    if cfg.faults and not twins:
        raise ConfigError("--fault is injected into twins; these wheels are not twins")
    out = Path(out_dir)
    targets = {name: out / name for name in ("record.mcap", "metrics.json")}
    # report.html is the report layer's, written after: refused here too, before the run
    existing = [str(p) for p in [*targets.values(), out / "report.html"] if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{', '.join(existing)} exist; pass force=True to overwrite them")
    diagnosis = bool(cfg.wheel_bias_rpm) if cfg.diagnosis is None else cfg.diagnosis
    health = (diagnosis and redundant) if cfg.health_check is None else cfg.health_check
    if health and not redundant:
        raise ConfigError(
            f"{sc.name}: the health check excites the wheels' null space; its "
            f"{sc.n_wheels} wheels have none (use wheel_axes = 'pyramid' or leave it out)"
        )
    clock = WallClock() if cfg.realtime else SimClock()
    rate = cfg.telemetry_rate or (50.0 if cfg.realtime else 1.0 / sc.run.dt)
    config = {
        "scenario": sc.name,
        "controller": cfg.controller,
        "estimator": estimator,
        "seed": seed,
        "dt_s": sc.run.dt,
        "duration_s": cfg.duration,
        "interface": cfg.interface,
        "channel": cfg.channel,
        "protocol": protocol,
        "nodes": list(nodes),
        "clock": "wall" if cfg.realtime else "simulated",
        "twins": twins,
        "telemetry_rate_hz": rate if twins else None,
        "twin_latency_s": cfg.latency_s if twins else None,
        "wheel_bias_rpm": cfg.wheel_bias_rpm,
        "faults": [f"{n}:{f}" for n, f in cfg.faults],
        "wheel_params": params.to_dict(),
        "wheel_spec": {"name": sc.wheels.wheel_spec.name, "hash": sc.wheels.wheel_spec.hash},
        "wheel_forced": wheel_forced,
        "epoch": sc.sky.epoch,
        "diagnosis": diagnosis,
        "health_check": (
            {
                "dither_rpm_s": DITHER_RPM_S,
                "dither_period_s": DITHER_PERIOD_S,
                "window_s": WINDOW_S,
                "probe_rpm_s": PROBE_SHARE * params.max_accel_rpm_s,
                "probe_s": PROBE_S,
                "probe_every_s": PROBE_EVERY_S,
            }
            if health
            else None
        ),
        "steady_after_s": cfg.steady_after,
        "wheel_model": "bus",
    }
    _warm_up(sc, ctl, estimator, sim_kw)
    bank = WheelBank(
        cfg.interface,
        cfg.channel,
        nodes,
        params,
        clock=clock,
        twins=twins,
        telemetry_rate=rate,
        latency=cfg.latency_s,
        seed=seed,
        timeout=cfg.timeout_s,
        protocol=protocol,
    )
    record = None
    restore = _real_time(cfg.rt_priority) if cfg.realtime else None
    try:
        bank.preflight()
        out.mkdir(parents=True, exist_ok=True)
        record = RecordWriter(
            targets["record.mcap"],
            {
                "kind": "rwlab.hil/1",
                "config": config,
                "dbc_sha256": proto.dbc_sha256(),
                "protocol": protocol,
                "protocol_identity": get_protocol(protocol).identity(),
                "Ts": sc.run.dt,  # what `rwlab export --node N` samples a wheel at
                # every channel's t is flight time (the spin-up before 0): export keeps it
                "time_axis": "flight",
                "mode": "acceleration",
            },
            force=force,
            channels=_channels(nodes),
        )
        loop = _Loop(cfg, sc, nodes, bank, clock, record, ctl, estimator, sim_kw, seed)
        loop.diagnosis = diagnosis
        loop.health = health
        loop.fly(progress)
    except BaseException as exc:
        problems = bank.close()  # first of all: every wheel idle
        if record is None:  # refused before the run: nothing was flown
            raise
        kind = "interrupt" if isinstance(exc, KeyboardInterrupt) else "error"
        t = clock.now()
        record.event(t, kind, f"{type(exc).__name__}: {exc}")
        idled = "every wheel idled" + (f" ({'; '.join(problems)})" if problems else "")
        record.event(t, "stop", idled)
        record.close()
        if isinstance(exc, KeyboardInterrupt):
            raise HilStopped(
                f"interrupted ({str(exc) or 'Ctrl-C'}); every wheel was idled and the record "
                f"{targets['record.mcap']} closed",
                interrupted=True,
            ) from None
        if isinstance(exc, Exception):
            raise HilStopped(
                f"{exc} — every wheel was idled and the record {targets['record.mcap']} closed"
            ) from exc
        raise
    finally:
        if restore is not None:
            restore()
    problems = bank.close()
    run = loop.sat.result()
    m = metrics(run, sc.control.pointing_requirement_deg)
    reference = ref_metrics = None
    if cfg.reference:
        reference, ref_metrics = reference_simulation(sc, cfg, seed, loop.h0, run.t.size)
    wheel_log = loop.wheel_log()
    # the plant's momenta are the readings: count on every one the wheels sent
    m["wheel_zero_crossings"] = sum(zero_crossings(w["speed_rpm"]) for w in wheel_log.values())
    payload = {
        **m,
        "timing": loop.timing(),
        "wheel_faults": loop.wheel_faults,
        "max_error_from_first_fault_deg": loop.max_error_from_fault if cfg.faults else None,
        "bench": {**loop.bench, "idle_problems": problems},
        "diagnosis_off": loop.diagnosis_off,
        "health_check": loop.health_summary(),
        "telemetry_check": loop.telemetry_summary(),
        "measurement": measurement_effects(wheel_log, params, sc.run.dt, cfg.latency_s),
        "reference_simulation": ref_metrics,
        "config": config,
    }
    text = json.dumps(payload, indent=2, default=_json_default)
    atomic_write_bytes(targets["metrics.json"], lambda tmp: tmp.write_text(text))
    record.event(clock.now(), "stop", "end of run; every wheel idled")
    record.close()
    return HilResult(run, payload, loop.events, wheel_log, sc, loop.h0, reference, dict(targets))


def reference_simulation(sc: Scenario, cfg: HilConfig, seed: int, h0: np.ndarray, rows: int):
    """``attitude simulate``'s run of the same scenario, controller and seed with the
    physics wheel from the same momenta: (SimResult, its metrics)."""
    from rwlab.attitude.sim import simulate

    ref = sc.with_(**{"wheels.model": "physics"})
    ctl, estimator, kw = build_controller(ref, cfg.controller)
    run = simulate(
        ref,
        ctl,
        duration=cfg.duration,
        estimator=estimator,
        seed=seed,
        log_every=cfg.log_every,
        steady_after=cfg.steady_after,
        wheel_momentum0=np.asarray(h0, float),
        **kw,
    )
    m = metrics(run, sc.control.pointing_requirement_deg)
    m["wheel_model"] = "physics (healthy: the injected faults are not flown here)"
    return run, m


def measurement_effects(wheel_log: dict, params, dt: float, latency: float) -> dict:
    """What the wheels on the bus do that the simulated wheel does not, measured.

    Per wheel: the RMS difference between the torque commanded and the torque the
    reported speeds imply (N·m), the reported speed's quantum as a momentum (N·m·s)
    and as a torque over one period, and the zero crossings of the reported speed
    (where Coulomb friction turns over and the Hall sensor reads 0).
    """
    quantum_rpm = params.speed_resolution_rpm
    h_q = params.inertia * quantum_rpm * np.pi / 30
    out: dict = {
        "speed_quantum_rpm": quantum_rpm,
        "momentum_quantum_Nms": h_q,
        "torque_quantum_per_period_Nm": h_q / dt,
        "hall_dead_zone_rpm": params.min_measurable_rpm,
        "twin_latency_s": latency,
        "wheels": {},
    }
    for node, log in wheel_log.items():
        speed, cmd = log["speed_rpm"], log["command_rpm_s"]
        if speed.size < 3:
            continue
        realised = np.diff(speed) / dt  # rpm/s over each period after the first
        diff = (realised - cmd[1:]) * params.inertia * np.pi / 30
        out["wheels"][str(node)] = {
            "torque_error_rms_Nm": float(np.sqrt(np.mean(diff**2))),
            "torque_error_mean_Nm": float(np.mean(diff)),
            "torque_command_rms_Nm": float(
                np.sqrt(np.mean((cmd * params.inertia * np.pi / 30) ** 2))
            ),
            "zero_crossings": zero_crossings(speed),
            "time_reading_zero_s": float(np.sum(speed == 0) * dt),
        }
    return out


def zero_crossings(speed_rpm: np.ndarray) -> int:
    """Times a wheel's reported spin changed sign, as ``attitude simulate`` counts them.

    Parameters
    ----------
    speed_rpm : (K,) array
        The wheel's reported speed at each control period, rpm.

    Returns
    -------
    int
        Sign changes since the last non-zero reading: a dwell at exactly 0 between
        opposite signs counts once, one between equal signs not at all (the kernel's
        ``wheel_zero_crossings`` on the plant's momenta, which here are the readings).
    """
    speed = np.asarray(speed_rpm, dtype=float)
    s = np.sign(speed[speed != 0])
    return int(np.sum(s[1:] != s[:-1]))


def _real_time(priority: int | None):
    """Switch this thread to SCHED_FIFO at ``priority``; returns the undo (None: nothing)."""
    import os

    if priority is None:
        return None
    if not 1 <= priority <= 99:
        raise ConfigError(f"rt_priority must be 1..99, got {priority}")
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        raise ConfigError(
            f"cannot run the loop real-time ({exc}); run as a user with CAP_SYS_NICE "
            "(e.g. `sudo setcap cap_sys_nice+ep $(which python3)`) or leave rt_priority out"
        ) from None
    return lambda: os.sched_setscheduler(0, before[0], before[1])


def _warm_up(sc: Scenario, ctl, estimator: str, sim_kw: dict) -> None:
    """Fly one sensor period on a throwaway satellite: the compiled helpers load (or
    compile) now, not in the first control periods of a wall-clock run."""
    sat = Satellite(sc, ctl, estimator=estimator, duration=sc.sensors.period, **sim_kw)
    while not sat.done:
        sat.advance(sat.x[7:] + sat.wheel_torques() * sc.run.dt)


def _json_default(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


class _Loop:
    """The run's state between :func:`run_hil`'s setup and clean-up."""

    def __init__(self, cfg, sc, nodes, bank, clock, record, ctl, estimator, sim_kw, seed):
        self.cfg, self.sc, self.nodes, self.bank, self.clock = cfg, sc, nodes, bank, clock
        self.record, self.ctl, self.estimator, self.sim_kw, self.seed = (
            record,
            ctl,
            estimator,
            sim_kw,
            seed,
        )
        self.events: list[dict] = []
        self.wheel_faults: list[dict] = []
        self.bench: dict = {}
        self._lateness: list[float] = []
        self._compute: list[float] = []
        self._wake: list[float] = []
        self._speed: list[list[float]] = []
        self._cmd: list[list[float]] = []
        self._t: list[float] = []
        self.t0 = 0.0
        self.diagnosis = False
        self.health = False
        self.tracking: dict[int, TrackingTest] = {}
        self.tracked: dict[int, TrackingTest] = {}
        self.dither: NullSpaceDither | None = None
        # every wheel's telemetry, on every wheel set
        self.telemetry = {
            n: DropoutTest(cfg.calibration_s, cfg.false_alarms_per_hour) for n in nodes
        }
        self.diag: dict = {}
        self._recalibrate_when_still = False
        self.diagnosis_off: dict[int, str] = {}
        self._coasting: dict[int, _CoastDown] = {}  # idled wheels whose coast-down names them
        # the GLR pipeline on each wheel's telemetry (rwlab.hil.live), where the wheel model
        # has a calibration measured in the loop; restarted on the wheels left once an
        # idled wheel is at rest (the others absorb its coast-down: another regime)
        self.pipeline: DiagnosisCalibration | None = None
        self.watches: dict[int, PipelineWatch] = {}
        self._watched: list[tuple[int, PipelineWatch]] = []  # every pipeline run, for the account
        self._restart_watches = False
        self._first_fault_s = min((f.t_s for _, f in cfg.faults), default=math.inf)
        self.max_error_from_fault = 0.0
        for c in bank.clients:
            if cfg.protocol == "rwlab":  # the frames on the wire, as sent and heard
                c.frame_listener = _frame_writer(record, c.node_id, clock)
            else:
                _message_writer(record, c)

    def event(self, kind: str, message: str, t: float | None = None) -> None:
        t = self.clock.now() if t is None else t
        self.record.event(t, kind, message)
        self.events.append({"t": t - self.t0, "kind": kind, "message": message})

    def _spin_up(self, target: np.ndarray) -> None:
        """Ramp the wheels to their null-space bias in speed mode (``SPIN_UP_RPM_S``), hold
        ``SPIN_UP_HOLD_S``."""
        bank, clock, dt = self.bank, self.clock, self.sc.run.dt
        self.event("spin_up", f"wheels to {np.round(target, 1).tolist()} rpm (null space)")
        start = clock.now()
        k = 0
        while clock.now() < self.t0 - 1e-9:
            ramp = np.sign(target) * np.minimum(
                np.abs(target), (clock.now() - start) * SPIN_UP_RPM_S
            )
            for c, v in zip(bank.clients, ramp, strict=True):
                c.set_speed(float(v))
                bank.sent[c.node_id] += 1
            k += 1
            clock.sleep_until(min(self.t0, start + k * dt))
            bank.read()

    def fly(self, progress) -> None:
        cfg, sc, bank, clock = self.cfg, self.sc, self.bank, self.clock
        simulated = isinstance(clock, SimClock)
        if cfg.wheel_bias_rpm:
            target = _null_space_bias(sc, cfg.wheel_bias_rpm)
            spin_s = float(np.max(np.abs(target))) / SPIN_UP_RPM_S + SPIN_UP_HOLD_S
            self.t0 = clock.now() + spin_s
            self.record.time_origin = self.t0
            self._spin_up(target)
        delay = SIM_READ_DELAY if simulated else 0.0
        readings = bank.read()
        self.h0 = bank.momenta(readings)
        sat = self.sat = Satellite(
            sc,
            self.ctl,
            estimator=self.estimator,
            duration=cfg.duration,
            seed=self.seed,
            wheel_momentum0=self.h0,
            log_every=cfg.log_every,
            steady_after=cfg.steady_after,
            **self.sim_kw,
        )
        if not cfg.wheel_bias_rpm:
            self.t0 = clock.now()
            self.record.time_origin = self.t0
        t0 = self.t0
        self.event("start", f"{cfg.controller} on {sc.name}, {len(self.nodes)} wheels", t0)
        for node, fault in cfg.faults:
            bank.twins[self.nodes.index(node)].schedule_faults([fault], origin=t0)
            self.event("fault_scheduled", f"node {node}: {fault}", t0)
        # the block tests need sustained accelerations, which a held-speed flight under
        # the health check never gives them (they refused their calibration on every
        # wheel, every run): the health check watches the wheels instead
        rule_tests = self.diagnosis and not self.health
        diag = self.diag = self._diagnosers(self.nodes) if rule_tests else {}
        if self.health:
            path = cfg.diagnosis_calibration or hil_calibration_file(sc.wheels.wheel_spec)
            if path is not None:
                self.pipeline = DiagnosisCalibration.load(path)
                self.watches = self._watches(self.nodes, 0.0)
            self.dither = NullSpaceDither(
                sc.wheel_matrix,
                bank.params.inertia,
                probe_rpm_s=PROBE_SHARE * bank.params.max_accel_rpm_s,
            )
            self.tracking = {
                n: TrackingTest(
                    sc.run.dt,
                    bank.params,
                    cfg.calibration_s,
                    cfg.false_alarms_per_hour,
                    probe_every_s=PROBE_EVERY_S,
                    tracking=self.pipeline is None,
                )
                for n in self.nodes
            }
            self.tracked = dict(self.tracking)
            self.event(
                "health_check",
                f"null-space excitation ±{DITHER_RPM_S:g} rpm/s over {DITHER_PERIOD_S:g} s, "
                f"a {PROBE_SHARE:.0%} capacity probe every {PROBE_EVERY_S:g} s; "
                + (
                    f"the GLR pipeline watches each wheel ({self.pipeline.origin})"
                    if self.pipeline is not None
                    else f"command-tracking tests calibrate over {cfg.calibration_s:g} s"
                ),
                t0,
            )
        every = round(cfg.diagnosis_period_s / sc.run.dt)
        acc_sum = {n: 0.0 for n in self.nodes}
        report_every = max(1, sat.steps // 100)
        while not sat.done:
            k = sat.k
            t_start = clock.now()
            torques = sat.wheel_torques()
            probe = 0
            if self.dither is not None:  # no body torque: G·n = 0 over the active wheels
                torques = torques + self.dither.torques(sat.t, sat.active)
                probe = self.dither.probe_phase(sat.t)
            refused = bank.command(torques)
            for node, exc in refused.items():  # the wheel idled itself: it is lost
                self._wheel_failed(node, "latched_fault", str(exc), t_start, hard=True)
            sent = clock.now()
            if k % sat.log_every == 0:
                self._write_satellite(torques)
            for i, n in enumerate(self.nodes):
                acc_sum[n] += (
                    rad_s_to_rpm(torques[i] / bank.params.inertia) if bank.active[n] else 0.0
                )
            target = t0 + (k + 1) * sc.run.dt + delay
            clock.sleep_until(target)
            wake = clock.now()
            readings = bank.read()
            sat.advance(bank.momenta(readings))
            if sat.t >= self._first_fault_s:
                self.max_error_from_fault = max(self.max_error_from_fault, sat.error_deg)
            self._t.append((k + 1) * sc.run.dt)
            self._speed.append([r.speed_rpm for r in readings])
            self._cmd.append([rad_s_to_rpm(x / bank.params.inertia) for x in torques])
            if not simulated:
                self._lateness.append(wake - target)
                self._compute.append(sent - t_start)
                self._wake.append(wake)
            self._watch_telemetry(sat.t, wake)
            if self._coasting:
                self._name_by_coast_down(readings, sat.t, wake)
            if self.watches or self._restart_watches:
                self._watch(readings, self._cmd[-1], sat.t, wake)
            if self.tracking:
                self._track(readings, self._cmd[-1], probe, wake)
                if self.dither is not None and any(t.wants_probe for t in self.tracking.values()):
                    self.dither.probe_soon(sat.t)  # to name a drag: friction, or the motor
            if diag and (k + 1) % every == 0:
                self._diagnose(diag, readings, acc_sum, every)
                acc_sum = {n: 0.0 for n in self.nodes}
            if progress is not None and (sat.k % report_every == 0 or sat.done):
                progress(min(sat.k, sat.steps))
        bank.idle_all()
        self.bench = {
            "commands_sent": dict(bank.sent),
            "lost_commands": bank.lost_commands(),
            "lost_telemetry_frames": bank.lost_telemetry(),
            "stale_telemetry_reads": dict(bank.stale),
            "bad_frames": {c.node_id: c.bad_frames for c in bank.clients},
        }

    # -- the satellite's channel ---------------------------------------------------------
    def _write_satellite(self, torques) -> None:
        sat = self.sat
        sensors = sat.last_sensors if sat.measured else {}
        tracker = sat.last_tracker if sat.measured else None
        x = sat.x
        self.record.write(
            "/satellite",
            {
                "t": self.t0 + sat.t,
                "error_deg": sat.error_deg,
                "estimation_error_deg": sat.estimation_error_deg,
                "q": x[:4].tolist(),
                "q_est": sat.q_hat.tolist(),
                "w_bo": relative_rate(x[:4], x[4:7]).tolist(),  # relative to the orbit frame
                "torque_demand_Nm": sat.demand.tolist(),
                "wheel_torque_cmd_Nm": np.asarray(torques).tolist(),
                "wheel_momentum_Nms": x[7:].tolist(),
                "sun_sensor": None if sensors.get("sun") is None else sensors["sun"].tolist(),
                "earth_sensor": None if sensors.get("earth") is None else sensors["earth"].tolist(),
                "gyro_rad_s": sat.w_meas.tolist() if sat.sensors.gyro else None,
                "star_tracker_q": None if tracker is None else tracker.tolist(),
                "active_wheels": [n for n in self.nodes if self.bank.active[n]],
            },
        )

    # -- diagnosis -----------------------------------------------------------------------
    def _diagnosers(self, nodes) -> dict:
        """A fresh diagnoser per node; each calibrates on its first ``calibration_s`` of
        the loop (the regime it will watch: a spin-up's speed-mode ramp is another)."""
        cfg = self.cfg
        return {
            n: _WheelWatch(
                cfg.diagnosis_period_s,
                self.bank.params.max_accel_rpm_s,
                cfg.calibration_s,
                cfg.false_alarms_per_hour,
            )
            for n in nodes
        }

    def _diagnose(self, diag, readings, acc_sum, every) -> None:
        """Feed each active wheel's diagnoser. After a reallocation the others are not
        watched until the idled wheel has coasted to rest (its momentum flows into them
        meanwhile); then they recalibrate over ``calibration_s`` in the new regime."""
        now = self.clock.now()
        if self._recalibrate_when_still:
            if any(r.speed_rpm != 0 for r in readings if not self.bank.active[r.node]):
                return
            self._recalibrate_when_still = False
            left = [n for n in self.nodes if self.bank.active[n]]
            self.diag.update(self._diagnosers(left))
            self.event(
                "recalibrate",
                f"the idled wheel is at rest: nodes {left} recalibrate over "
                f"{self.cfg.calibration_s:g} s",
                now,
            )
        for r in readings:
            if not self.bank.active[r.node] or r.node not in diag:
                continue
            try:
                alarms = diag[r.node].update(
                    now - self.t0, acc_sum[r.node] / every, r.speed_rpm, r.current_a, r.age_s
                )
            except RwlabError as exc:  # the diagnosis cannot watch it: fly on, say so
                del diag[r.node]
                self.diagnosis_off[r.node] = str(exc)
                self.event("diagnosis_off", f"node {r.node}: {exc}", now)
                continue
            for a in alarms:
                self._wheel_failed(r.node, a.kind, f"{a.detector} detector", now)

    def _watches(self, nodes, t: float) -> dict[int, PipelineWatch]:
        """A fresh pipeline per node from flight time ``t``."""
        assert self.pipeline is not None
        p, cfg = self.bank.params, self.cfg
        out = {
            n: PipelineWatch(self.pipeline, p, self.sc.run.dt, cfg.false_alarms_per_hour, t)
            for n in nodes
        }
        self._watched += out.items()
        return out

    def _watch(self, readings, cmd_rpm_s, t: float, now: float) -> None:
        """Every watched wheel's pipeline, each control period (``t``: flight time). An
        alarm idles the wheel; a rotor fault's name is then its coast-down's (a lost torque
        and an added drag look alike on the dither's small accelerations until a probe
        tells them apart, which an idled wheel no longer gets)."""
        if self._restart_watches:
            if any(r.speed_rpm != 0 for r in readings if not self.bank.active[r.node]):
                return
            self._restart_watches = False
            left = [n for n in self.nodes if self.bank.active[n]]
            self.watches = self._watches(left, t)
            self.event("diagnosis_restart", f"the idled wheel is at rest: nodes {left}", now)
        for i, r in enumerate(readings):
            watch = self.watches.get(r.node)
            if watch is None or not self.bank.active[r.node]:
                continue
            events = watch.update(cmd_rpm_s[i], r.speed_rpm, r.current_a, r.age_s)
            if not events:
                continue
            e = events[0]
            del self.watches[r.node]
            self.tracking.pop(r.node, None)
            named = f"{e.fault} {e.fit.size_text()}".rstrip()
            how = (
                f"GLR pipeline: the {e.detector} statistic crossed {e.threshold:.3g}; the "
                f"likeliest fault {named}, log-LR {e.fit.log_lr:.3g} over healthy, "
                f"runner-up {e.runner_up}"
            )
            self._wheel_failed(r.node, e.fault, how, now)
            if e.fault in COAST_NAMES and not self.bank.active[r.node]:
                self._coasting[r.node] = _CoastDown(self.wheel_faults[-1], self.sat.t)

    def _track(self, readings, cmd_rpm_s, probe: int, now: float) -> None:
        """Every active wheel's command-tracking test, each control period (``probe``:
        the capacity probe's phase over it)."""
        for i, r in enumerate(readings):
            test = self.tracking.get(r.node)
            if test is None or not self.bank.active[r.node]:
                continue
            found = test.update(cmd_rpm_s[i], r.speed_rpm, r.current_a, probe)
            if found is not None:
                del self.tracking[r.node]  # an alarm is latched: the wheel is no longer tested
                self.watches.pop(r.node, None)
                label, _, named = found.test.partition(", ")  # the statistic is the test's
                how = f"{label} {found.statistic:.3g} > {found.threshold:.3g}"
                how += f", {named}" if named else ""
                self._wheel_failed(r.node, found.kind, how, now)
                if found.test == "tracking CUSUM" and found.kind in COAST_NAMES:
                    if not self.bank.active[r.node]:  # idled: its coast-down names it
                        self._coasting[r.node] = _CoastDown(self.wheel_faults[-1], self.sat.t)

    def _name_by_coast_down(self, readings, t: float, now: float) -> None:
        """Name each idled wheel's fault by its coast-down once ``COAST_S`` of it is read:
        a drag over ``COAST_FRICTION_RATIO`` × the wheel model's is friction (its size that
        ratio), else the motor (idled, a motor's torque no longer shows)."""
        p = self.bank.params
        for r in readings:
            coast = self._coasting.get(r.node)
            if coast is None:
                continue
            coast.samples.append((t, r.speed_rpm))
            if t - coast.t_s < COAST_S:
                continue
            del self._coasting[r.node]
            times, speeds = np.array(coast.samples).T
            if np.any(np.abs(speeds) < stiction_band_rpm(p)) or np.ptp(times) <= 0:
                continue  # at rest or near it: the drag there is breakaway, not the law
            decel = -float(np.polyfit(times, speeds, 1)[0])
            model = rad_s_to_rpm(nominal_friction_nm(p, float(np.mean(speeds))) / p.inertia)
            ratio = decel / model
            named = "friction" if ratio > COAST_FRICTION_RATIO else "torque_constant"
            entry = coast.entry
            entry["detector"] += (
                f"; named by its coast-down {COAST_S:g} s later: drag {ratio:.2f} × the model's"
            )
            entry["named_kind"] = named
            self.event("named", f"node {r.node}: {named} (drag {ratio:.2f} × the model's)", now)

    def _watch_telemetry(self, t: float, now: float) -> None:
        """Every active wheel's dropout test, each control period (``t``: flight time)."""
        lost = self.bank.lost_telemetry()
        for node, test in self.telemetry.items():
            if not self.bank.active[node]:
                continue
            found = test.update(t, lost[node])
            if found is not None:
                how = f"{found.test}: {found.statistic:g} frames lost in {BLOCK_S:g} s ≥ "
                how += f"{found.threshold:g}"
                self._wheel_failed(node, found.kind, how, now, keep=True)

    def telemetry_summary(self) -> dict:
        """Each wheel's healthy telemetry loss rate (frames/s; None while measuring) and
        the blocks its dropout test judged."""
        return {
            "block_s": BLOCK_S,
            "healthy_lost_per_s": {str(n): t.lost_per_s for n, t in self.telemetry.items()},
            "alarm_count": {str(n): t.limit for n, t in self.telemetry.items()},
            "blocks_tested": {str(n): t.blocks_tested for n, t in self.telemetry.items()},
        }

    def health_summary(self) -> dict | None:
        """Each tested wheel's calibrated healthy spread of the tracking residual, rpm/s,
        its healthy probes (:meth:`TrackingTest.healthy_probe_summary`) and, where the GLR
        pipeline watched the wheels, its calibration and decision times per wheel."""
        if not self.health:
            return None
        return {
            "dither_rpm_s": DITHER_RPM_S,
            "dither_period_s": DITHER_PERIOD_S,
            "window_s": WINDOW_S,
            "residual_sigma_rpm_s": {
                str(n): t.healthy_spread_rpm_s() for n, t in self.tracked.items()
            },
            "healthy_probes": {str(n): t.healthy_probe_summary() for n, t in self.tracked.items()},
            "windows_tested": {str(n): t.windows_tested for n, t in self.tracked.items()},
            "probes_tested": {str(n): t.probes_tested for n, t in self.tracked.items()},
            # the GLR pipeline's decision times per wheel (None: the tracking test watched)
            "pipeline": None
            if self.pipeline is None
            else {
                "calibration": self.pipeline.origin,
                "decisions": {
                    str(n): sum(w.live.decisions for m, w in self._watched if m == n)
                    for n in self.tracked
                },
            },
        }

    def _wheel_failed(
        self, node: int, kind: str, how: str, t: float, hard: bool = False, keep: bool = False
    ) -> None:
        """An alarm: record it, idle the wheel and reallocate when the others span 3 axes.

        A diagnosis alarm on a wheel that cannot be spared is recorded and the wheel kept;
        a ``hard`` failure (the wheel latched a fault and idled itself) that cannot be
        spared stops the run (``WheelFault``): the satellite is no longer controlled.
        ``keep``: a fault of the wheel's telemetry, not of its torque: recorded, and the
        wheel flies on.
        """
        injected = _injected(self.cfg.faults, node, kind, t - self.t0)
        entry = {
            "node": node,
            "kind": injected.name if injected else None,
            "injected_s": injected.t_s if injected else None,
            "detected_s": t - self.t0,
            "named_kind": kind,
            "detector": how,
            "action": None,
        }
        self.event("alarm", f"node {node}: {kind} ({how})", t)
        if keep:
            self.wheel_faults.append(
                {**entry, "action": "kept in the loop: its telemetry failed, not its torque"}
            )
            return
        active = np.array([self.bank.active[n] and n != node for n in self.nodes])
        try:
            self.sat.set_active(active)
        except ConfigError as exc:
            if hard:
                self.wheel_faults.append({**entry, "action": "run stopped: no spare wheel"})
                raise WheelFault(f"wheel {node} is lost ({how}) and {exc}; the run stops") from None
            entry["action"] = "kept in the loop: no spare wheel"
            self.event("no_reallocation", f"node {node}: {exc}", t)
        else:
            self.bank.idle(node)
            entry["action"] = "idled; torque reallocated to " + ", ".join(
                str(n) for n, a in zip(self.nodes, active, strict=True) if a
            )
            self.event("reallocate", f"node {node}: {entry['action']}", t)
            if self.watches:  # the others now absorb its coast-down: a regime of its own
                self._restart_watches = True
            if self.diag:
                self._recalibrate_when_still = True
                self.event(
                    "diagnosis_paused",
                    f"the other wheels' diagnosis pauses until node {node} has coasted to rest",
                    t,
                )
        self.wheel_faults.append(entry)

    # -- figures -------------------------------------------------------------------------
    def timing(self) -> dict:
        """Loop-timing quality on the wall clock (None figures on the simulated clock)."""
        out: dict = {"clock": "wall" if self._wake else "simulated", "period_s": self.sc.run.dt}
        if not self._wake:
            return out
        late = np.array(self._lateness)
        period = np.diff(np.array(self._wake))
        comp = np.array(self._compute)
        out.update(
            steps=int(late.size),
            period_p50_s=float(np.percentile(period, 50)),
            period_p99_s=float(np.percentile(period, 99)),
            period_max_s=float(period.max()),
            lateness_p50_s=float(np.percentile(late, 50)),
            lateness_p99_s=float(np.percentile(late, 99)),
            lateness_max_s=float(late.max()),
            late_steps=int(np.sum(late > LATE_S)),
            late_threshold_s=LATE_S,
            compute_p50_s=float(np.percentile(comp, 50)),
            compute_p99_s=float(np.percentile(comp, 99)),
        )
        return out

    def wheel_log(self) -> dict:
        speed, cmd, t = np.array(self._speed), np.array(self._cmd), np.array(self._t)
        return {
            n: {"t": t, "speed_rpm": speed[:, i], "command_rpm_s": cmd[:, i]}
            for i, n in enumerate(self.nodes)
        }
