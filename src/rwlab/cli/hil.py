"""``rwlab hil``: the satellite's attitude loop closed through the wheels on a bus."""

from __future__ import annotations

import warnings

import click

from rwlab.cli._common import (
    SECONDS,
    Number,
    _flight_output_options,
    _friendly_errors,
    _only_with,
    _output,
    _steps_progress,
    _stop_signals,
    _wrote,
    main,
)
from rwlab.errors import ConfigError, HilStopped

HIL_FILES = ("record.mcap", "metrics.json", "report.html")


def _nodes(text: str | None) -> tuple[int, ...] | None:
    if text is None:
        return None
    try:
        nodes = tuple(int(n) for n in text.split(","))
    except ValueError:
        raise ConfigError(f"--nodes must be node ids like 1,2,3, got {text!r}") from None
    if any(not 0 <= n <= 15 for n in nodes):
        raise ConfigError(f"--nodes must be 0..15, got {text!r}")
    return nodes


@main.command("hil")
@click.option(
    "--scenario",
    default="geo-smallsat",
    show_default=True,
    help="A built-in (geo-smallsat, geo-smallsat-pyramid, geo-comsat, geo-comsat-gyro, "
    "geo-comsat-star, geo-cubesat) or a scenario TOML file; the health check needs a "
    "redundant set (the pyramids: geo-smallsat-pyramid, geo-comsat).",
)
@click.option(
    "--wheel",
    metavar="NAME|FILE",
    default=None,
    help="The wheel model the twin nodes fly: a preset (`rwlab wheel models`) or a unit's "
    "own wheel spec file [default: the scenario's wheels.spec].",
)
@click.option(
    "--controller",
    type=click.Choice(["pd", "lqr", "lqg", "lqg_ltr"]),
    default="lqg",
    show_default=True,
)
@click.option(
    "--interface",
    type=click.Choice(["virtual", "udp_multicast", "socketcan", "serial"]),
    default="virtual",
    show_default=True,
)
@click.option("--channel", default=None, help="Bus channel (the interface's default).")
@click.option(
    "--protocol",
    default=None,
    help="Wheel protocol on the bus: rwlab, canopen, or a registered CAN one (`rwlab wheel "
    "protocols`); serial NSP wheels cannot share one bus and are refused [default: rwlab, "
    "or canopen for twins whose currents rwlab's DBC cannot carry].",
)
@click.option(
    "--profile",
    default=None,
    help="The protocol's profile (canopen: rwlab, oresat, cia402).",
)
@click.option("--nodes", default=None, help="Node id of each wheel, e.g. 1,2,3 [default: 1..N].")
@click.option("--duration", type=SECONDS, required=True, help="Seconds of flight.")
@click.option("--seed", type=click.IntRange(min=0), default=None)
@click.option("--realtime", is_flag=True, help="Wall clock (10 Hz or faster) instead of simulated.")
@click.option("--epoch", help="UTC start, ISO 8601: the real Sun, Moon and eclipses.")
@click.option(
    "--fault",
    "faults",
    multiple=True,
    help="NODE:NAME[=VALUE]@SECONDS injected into a twin, e.g. 2:torque_constant=0@1800; "
    "NAME: friction (factor), torque_constant (factor), current_limit (A), "
    "speed_sensor_bias (rpm), speed_sensor_stuck, telemetry_dropout (s).",
)
@click.option(
    "--wheels-running",
    is_flag=True,
    help="The wheels are already on the bus (e.g. `rwlab wheel serve`): start no twins.",
)
@click.option(
    "--telemetry-rate",
    type=Number(0, 10_000, low_open=True),
    default=None,
    help="Twins' telemetry, Hz [default: one per control period; 50 on the wall clock].",
)
@click.option(
    "--wheel-bias-rpm",
    type=Number(-1e5, 1e5),
    default=None,
    help="Spin the wheels up along the null space first (pyramid): no zero crossings "
    "[default: 1000 on a redundant set such as a pyramid, else 0].",
)
@click.option(
    "--diagnosis/--no-diagnosis",
    default=None,
    help="Live diagnosis of every wheel [default: on with --wheel-bias-rpm, whose wheels "
    "never hover at zero speed where the current test false-alarms]; on a redundant set "
    "the health check is the diagnosis (the GLR pipeline or the command-tracking test), "
    "elsewhere the rwlab diagnose block tests.",
)
@click.option(
    "--health-check/--no-health-check",
    default=None,
    help="Excite the wheels' null space (no body torque), probe their torque capacity and "
    "test that each wheel follows its commanded acceleration; on a redundant set it is "
    "the diagnosis [default: on with the diagnosis on a redundant set].",
)
@click.option(
    "--diagnosis-calibration",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    help="A calibration.json measured on the wheels' own healthy flights (rwlab diagnose "
    "calibrate RECORDS... --in-loop): the health check's GLR pipeline decides with it "
    "[default: the preset's shipped one, where the wheel is a preset's own].",
)
@click.option(
    "--steady-after",
    type=Number(0, 1e9),
    default=None,
    help="Seconds after which steady-state statistics start [default: half the run, "
    "at most its first hour].",
)
@click.option(
    "--calibration",
    type=SECONDS,
    default=300.0,
    show_default=True,
    help="Seconds of healthy telemetry that calibrate the diagnosis and the health check.",
)
@click.option(
    "--rt-priority",
    type=click.IntRange(1, 99),
    default=None,
    help="With --realtime: run the loop under SCHED_FIFO at this priority (needs CAP_SYS_NICE).",
)
@click.option("--no-reference", is_flag=True, help="Do not fly the simulation beside it.")
@_flight_output_options
@_friendly_errors
def hil(
    out,
    force,
    nodes,
    faults,
    wheels_running,
    no_reference,
    calibration,
    profile,
    **settings,
):
    """Fly the satellite on the host with its wheels on a bus: record.mcap, metrics.json,
    report.html.

    Each control period the attitude controller's wheel torques go out as
    acceleration commands through the wheel driver; the plant takes each wheel's
    momentum from the speed it reports. Twins answer on the virtual and
    udp_multicast buses unless --wheels-running. Whatever ends the run (its end,
    a silent wheel, a broken bus, Ctrl-C, SIGTERM, an error), every wheel is
    idled and the record closed with a stop event. Every flight counts each
    wheel's lost telemetry frames and names a dropout (the wheel flies on); on
    a redundant set the health check watches each wheel's torque.
    """
    from rwlab.cli.attitude import single_thread_blas
    from rwlab.hil.run import HilConfig, parse_node_fault, run_hil
    from rwlab.report.hil import write_hil_report
    from rwlab.wheel.link import resolve_protocol

    _only_with("calibration", settings["diagnosis"] is not False, "with the diagnosis on")
    if settings["protocol"] is not None or profile is not None:
        settings["protocol"] = resolve_protocol(settings["protocol"] or "rwlab", profile)
    single_thread_blas()
    # the options not named here are named after their HilConfig field
    cfg = HilConfig(
        nodes=_nodes(nodes),
        faults=tuple(parse_node_fault(f) for f in faults),
        twins=False if wheels_running else None,
        calibration_s=calibration,
        reference=not no_reference,
        **settings,
    )
    scenario, duration, controller = cfg.scenario, cfg.duration, cfg.controller
    from rwlab.attitude.scenario import load_scenario
    from rwlab.errors import FormatWarning

    with warnings.catch_warnings():  # a flat file's warning: once, from run_hil
        warnings.simplefilter("ignore", FormatWarning)
        steps = round(duration / load_scenario(scenario).run.dt) + 1
    # locked before anything starts; published whole on success; a failed run's record is
    # kept (with its stop event) in OUT.failed-<time>, never in OUT
    try:
        with (
            _output(out, HIL_FILES, force, "hil run", keep_failed=True) as stage,
            _stop_signals(),
            _steps_progress(steps, f"hil {controller}", unit="periods") as progress,
        ):
            result = run_hil(cfg, stage, progress=progress)
            report = write_hil_report(result, stage)
    except HilStopped as exc:
        if not exc.interrupted:
            raise
        click.echo(str(exc), err=True)  # "interrupted (…); every wheel was idled …"
        raise SystemExit(130) from None  # as every command stopped by a signal
    m = result.metrics
    if settings["protocol"] is None and m["config"]["protocol"] != "rwlab":
        click.echo(
            f"the wheels spoke {m['config']['protocol']}: rw.dbc cannot carry this wheel "
            "model's current"
        )
    for key in ("steady_max_error_deg", "steady_rms_error_deg", "max_error_deg"):
        ref = m["reference_simulation"]
        sim = f"   simulation {ref[key]:.4g}" if ref else ""
        click.echo(f"{key:<28} {m[key]:.4g}{sim}")
    health = m["health_check"]
    dropout = "telemetry_dropout"
    if health is None and not m["config"]["diagnosis"]:
        click.echo(
            "wheel torque: not watched in flight (the health check needs a redundant wheel "
            "set, the diagnosis a momentum bias; --diagnosis forces the block tests)"
        )
    if health is not None:
        windows, probes = (sum(health[k].values()) for k in ("windows_tested", "probes_tested"))
        tested, pipeline = "tracking windows", health.get("pipeline")
        how = "command-tracking test: no in-loop calibration for this wheel model"
        if pipeline is not None:
            windows, tested = sum(pipeline["decisions"].values()), "pipeline decisions"
            how = f"GLR pipeline, calibrated on {pipeline['calibration']}"
        failed = sorted({str(f["node"]) for f in m["wheel_faults"] if f["named_kind"] != dropout})
        verdict = f"alarm on wheel {', '.join(failed)}" if failed else "no alarm"
        if not (windows or probes or failed):
            verdict = f"still calibrating at the end ({calibration:g} s): nothing tested"
        click.echo(
            f"health check: {windows} {tested} and {probes} capacity probes tested "
            f"on {len(health['windows_tested'])} wheels ({how}): {verdict}"
        )
    telemetry = m["telemetry_check"]
    dropped = sorted({str(f["node"]) for f in m["wheel_faults"] if f["named_kind"] == dropout})
    blocks = sum(telemetry["blocks_tested"].values())
    unnamed = [  # frames lost that no alarm named: the link's own, or a dropout too short
        f"wheel {n}: {lost}"
        for n, lost in m["bench"]["lost_telemetry_frames"].items()
        if lost and str(n) not in dropped
    ]
    click.echo(
        f"telemetry check: {blocks} blocks of {telemetry['block_s']:g} s tested on "
        f"{len(telemetry['blocks_tested'])} wheels: "
        + (f"dropout on wheel {', '.join(dropped)}" if dropped else "no dropout")
        + ("" if blocks else f" (still measuring the loss rate at the end, {calibration:g} s)")
        + (f"; frames lost under the alarm count: {', '.join(unnamed)}" if unnamed else "")
    )
    for f in m["wheel_faults"]:
        click.echo(
            f"wheel {f['node']}: {f['named_kind']} detected at {f['detected_s']:.1f} s "
            f"({f['detector']}; injected {f['kind']} at {f['injected_s']} s); {f['action']}"
        )
    t = m["timing"]
    if t["clock"] == "wall":
        click.echo(
            f"period p50 {t['period_p50_s'] * 1e3:.2f} ms, p99 {t['period_p99_s'] * 1e3:.2f} ms; "
            f"late p99 {t['lateness_p99_s'] * 1e3:.2f} ms; late steps {t['late_steps']}"
        )
    b = m["bench"]
    click.echo(f"lost commands {b['lost_commands']}, lost telemetry {b['lost_telemetry_frames']}")
    click.echo(_wrote(out, [*result.paths.values(), report]))
