"""``rwlab experiment``, ``export`` and ``monitor``: the testbed."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import click

from rwlab.cli._common import (
    POSITIVE,
    Number,
    _check_folder,
    _friendly_errors,
    _only_with,
    _salvage_option,
    _stop_signals,
    main,
)
from rwlab.errors import ConfigError

# -- the testbed ----------------------------------------------------------------------


class _ExperimentCommand(click.Command):
    """``experiment --help`` shows ExperimentConfig's defaults (the options default to None so
    that a --config file's values are not overridden)."""

    def format_options(self, ctx, formatter):
        from dataclasses import fields

        from rwlab.testbed import ExperimentConfig

        defaults = {f.name: f.default for f in fields(ExperimentConfig)}
        for p in self.params:
            value = defaults.get(p.name or "")
            unset = p.get_default(ctx) in (None, getattr(click.core, "UNSET", None))
            if isinstance(p, click.Option) and unset and value not in (None, ()):
                shown = ("on" if value else "off") if isinstance(value, bool) else value
                if "[default:" not in (p.help or ""):
                    p.help = f"{p.help or ''}  [default: {shown}]".strip()
        super().format_options(ctx, formatter)


@main.command("experiment", cls=_ExperimentCommand)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False),
    help="Experiment TOML file ([experiment] table); flags override it.",
)
@click.option("--signal", type=click.Choice(["prbs", "chirp", "step", "multisine", "file"]))
@click.option("--mode", type=click.Choice(["speed", "acceleration"]))
@click.option(
    "--amplitude",
    type=float,
    help="rpm in speed mode, rpm/s in acceleration mode (default: the wheel's nominal speed "
    "or its acceleration limit).",
)
@click.option("--duration", type=float, help="Seconds of signal.")
@click.option("--Ts", "Ts", type=float, help="Command period, s.")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="Record file (.mcap).")
@click.option("--realtime", is_flag=True, default=None, help="Run on the wall clock.")
@click.option("--telemetry-rate", type=float, help="Simulated wheel's telemetry rate, Hz.")
@click.option("--seed", type=int)
@click.option(
    "--unit",
    type=click.IntRange(0),
    help="Simulated wheel unit: another wheel of the model, drawn within its tolerances.",
)
@click.option(
    "--wheel",
    metavar="NAME|FILE.toml",
    help="Simulated wheel: a wheel model (rw90, default; nrwa-t6; rw-0.01; `rwlab wheel "
    "models`), ideal (the RW90 without imperfections), a wheel spec file, or a wheel TOML "
    "file (docs/wheels/rw90.toml lists every parameter).",
)
@click.option(
    "--file",
    type=click.Path(dir_okay=False),
    help="CSV of setpoints for --signal file.",
)
@click.option(
    "--interface",
    help="virtual (a simulated wheel), socketcan, udp_multicast, serial, or one added by an "
    "entry point.",
)
@click.option("--channel")
@click.option("--node-id", type=click.IntRange(0, 15))
@click.option(
    "--protocol",
    help="Wheel protocol: rwlab (default), canopen, nsp, or a registered one "
    "(`rwlab wheel protocols`).",
)
@click.option(
    "--profile",
    help="The protocol's profile (canopen: rwlab, oresat, cia402; `rwlab wheel protocols`).",
)
@click.option(
    "--raw-frames",
    is_flag=True,
    default=None,
    help="Also record every CAN frame (CAN protocols only; `rwlab export --format asc|blf` "
    "writes them for CAN tools).",
)
@click.option(
    "--rate-limit/--no-rate-limit",
    default=None,
    help="Limit a speed-mode PRBS's slope to the wheel's acceleration limit (ramps, not "
    "steps). Default off: paper A's PRBS steps, and the wheel follows at its limit.",
)
@click.option(
    "--fault",
    "faults",
    multiple=True,
    metavar="NAME[=VALUE]@SECONDS",
    help="Inject a fault into the simulated wheel (repeatable), e.g. friction=3@900: friction, "
    "torque_constant (factors), current_limit (A), speed_sensor_bias (rpm), speed_sensor_stuck, "
    "telemetry_dropout (s).",
)
@click.option(
    "--model",
    type=click.Path(dir_okay=False),
    help="model.json: run the diagnosis live (the GLR pipeline, as rwlab diagnose); each "
    "alarm is printed as it comes and recorded as an event.",
)
@click.option(
    "--diagnosis-calibration",
    type=click.Path(dir_okay=False, exists=True),
    help="The live diagnosis's calibration.json (rwlab diagnose calibrate); default: the "
    "twin calibration of the model's wheel preset.",
)
@click.option("--monitor", is_flag=True, help="Serve the live monitor while the experiment runs.")
@click.option(
    "--port", type=click.IntRange(1, 65535), default=5006, show_default=True, help="Monitor port."
)
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_friendly_errors
def experiment(config_file, out, monitor, port, force, profile, **settings):
    """Play a test signal into a wheel and record every command and telemetry frame.

    With the default virtual interface a simulated wheel of the --wheel model (rw90 by
    default) answers, on a simulated clock (a 20-minute experiment takes seconds) unless
    --realtime is given.
    Ctrl-C or any error leaves the wheel idle and the record closed.
    """
    from rwlab.testbed import ExperimentConfig, run_experiment

    _only_with("port", monitor, "with --monitor")
    # every other option is named after its ExperimentConfig field (None: not given)
    overrides = settings | {"faults": tuple(settings["faults"]) or None}
    if config_file:
        cfg = ExperimentConfig.from_toml(config_file, **overrides)
    else:
        cfg = ExperimentConfig(**{k: v for k, v in overrides.items() if v is not None})
    if profile is not None:
        from dataclasses import replace

        from rwlab.wheel.link import resolve_protocol

        cfg = replace(cfg, protocol=resolve_protocol(cfg.protocol, profile))
    cfg.check_limits(cfg.wheel_params())
    if Path(out).suffix.lower() != ".mcap":
        raise ConfigError(f"--out {out}: a record is an .mcap file; name it NAME.mcap")
    if Path(out).exists() and not force:
        raise FileExistsError(f"{out} exists; pass --force to replace it")
    _check_folder(Path(out).parent)
    realtime = cfg.realtime or cfg.interface != "virtual"
    label = f"{cfg.signal} ({cfg.mode}, {'real time' if realtime else 'simulated clock'})"
    server = None
    try:
        with _stop_signals():
            if monitor:
                from rwlab.testbed.monitor import start_process

                # its own process, following the file being written: it never slows the run
                server = start_process(out, port=port)
                click.echo(f"live monitor: http://127.0.0.1:{port}/", err=True)
            with contextlib.ExitStack() as stack:
                bars = []

                def progress(k: int, total: int) -> None:
                    if not bars:  # shown from the first command: a failed start prints nothing
                        bar = click.progressbar(
                            length=total, label=label, show_eta=True, file=sys.stderr
                        )
                        bars.append(stack.enter_context(bar))
                    bars[0].update(1)

                def on_alarm(text: str) -> None:  # as it comes, above the progress bar
                    click.echo(f"\nalarm: {text}", err=True)

                summary = run_experiment(
                    cfg, out, force=force, progress=progress, on_alarm=on_alarm
                )
    except KeyboardInterrupt as exc:
        why = exc.args[0] if exc.args else "Ctrl-C"
        click.echo(f"\ninterrupted ({why}): the wheel is idle and {out} is closed", err=True)
        sys.exit(130)
    finally:
        if server is not None:
            from rwlab.testbed.monitor import stop_process

            stop_process(server)
    click.echo(
        f"{summary.path}: {summary.commands} commands, {summary.telemetry} telemetry "
        f"frames, {summary.lost_frames} lost, {summary.duration:.1f} s ({summary.status}); "
        f"timing: {_timing_line(summary.timing)}"
        + (f"; {summary.bad_frames} damaged frames dropped" if summary.bad_frames else "")
    )
    if cfg.model is not None:
        click.echo(f"live diagnosis: {'; '.join(summary.alarms) or 'no alarm'}")
    if summary.faults_injected:
        click.echo(f"injected: {', '.join(summary.faults_injected)}")


def _timing_line(t: dict) -> str:
    """The run's real-time quality in one line (see rwlab.testbed.runner.Timing)."""
    if not t.get("commands"):
        return "no command sent"
    lat, per, ms = t["lateness_s"], t["period_s"], 1e3
    text = (
        f"lateness p50/p99/max {lat['p50'] * ms:.3g}/{lat['p99'] * ms:.3g}/{lat['max'] * ms:.3g}"
        f" ms, {t['late']} of {t['commands']} commands late by > {t['tolerance_s'] * ms:.3g} ms"
    )
    if per["p50"] is not None:
        text += f"; period p50/p99/max {per['p50'] * ms:.4g}/{per['p99'] * ms:.4g}/"
        text += f"{per['max'] * ms:.4g} ms"
    return text


EXPORT_FORMATS = ("csv", "parquet", "mat", "asc", "blf")


@main.command("export")
@click.argument("record", type=click.Path(dir_okay=False))
@click.option(
    "--format",
    "fmt",
    type=click.Choice(EXPORT_FORMATS),
    help="csv, parquet, mat: sampled signals; asc, blf: the raw CAN frames of a record made "
    "with --raw-frames (Vector logs, python-can's writers). Default: the one --out's "
    "name ends with.",
)
@click.option("--out", type=click.Path(dir_okay=False), required=True)
@click.option("--Ts", "Ts", type=POSITIVE, help="Sample time, s (default: the record's).")
@click.option(
    "--max-gap",
    type=Number(0, allow_inf=True),
    default=None,
    help="Accept telemetry gaps up to this many seconds (default Ts).",
)
@click.option(
    "--node", type=click.IntRange(0, 15), help="The wheel, in a record of several (rwlab hil)."
)
@click.option(
    "--satellite",
    is_flag=True,
    help="Export the satellite's channel of an `rwlab hil` record (attitude, errors, "
    "torques, wheel momenta, sun/Earth sensor, gyro and star-tracker readings) as logged.",
)
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_salvage_option
@_friendly_errors
def export(record, fmt, out, Ts, max_gap, node, satellite, force):
    """Write a record as CSV, Parquet or MATLAB .mat, sampled at Ts; or its CAN frames.

    Columns: time_s, command, speed_rpm, acceleration_rpm_s, current_a; with
    --satellite the satellite channel of a hil record at its logging period.
    --format asc|blf writes every recorded CAN frame as a Vector log instead.
    """
    from rwlab.testbed import load_record

    path = Path(out)
    if fmt is None:
        fmt = path.suffix.lower().lstrip(".")
        if fmt not in EXPORT_FORMATS:
            raise ConfigError(
                f"--out {out} names no format ({', '.join(EXPORT_FORMATS)}); end its name "
                "with one or pass --format"
            )
    if path.suffix and path.suffix.lower() != f".{fmt}":
        raise ConfigError(
            f"--format {fmt} contradicts --out {out} (a {path.suffix} name); "
            f"name the file .{fmt} or choose the format its name says"
        )
    path = path.with_suffix(f".{fmt}") if not path.suffix else path
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass --force to replace it")
    _check_folder(path.parent)
    if fmt in ("asc", "blf"):
        if satellite or node is not None or Ts is not None or max_gap is not None:
            raise ConfigError(
                f"--format {fmt} writes the recorded CAN frames as they came; leave out "
                "--satellite, --node, --Ts and --max-gap"
            )
        from rwlab.testbed.canlog import write_can_log

        count = write_can_log(record, path, fmt)
        click.echo(f"{path}: {count} CAN frames")
        return
    if satellite:
        if node is not None or Ts is not None or max_gap is not None:
            raise ConfigError(
                "--satellite exports the satellite channel as logged; leave out --node, "
                "--Ts and --max-gap (they choose and sample a wheel's channels)"
            )
        from rwlab.hil.record import satellite_data

        data = satellite_data(record)
        data.write(path, overwrite=force, plain=True)
        click.echo(f"{path}: {data.N} satellite rows at Ts = {data.Ts:g} s")
        return
    data = load_record(
        record, Ts, outputs=("speed", "acceleration", "current"), max_gap=max_gap, node=node
    )
    if data.N < 2:
        raise ConfigError(
            f"--Ts {data.Ts:g} s leaves {data.N} sample of the record; choose a Ts shorter "
            "than the record"
        )
    data.write(path, overwrite=force, plain=True)
    click.echo(f"{path}: {data.N} samples at Ts = {data.Ts:g} s")


@main.command("monitor")
@click.argument("record", type=click.Path(dir_okay=False))
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to serve on (0.0.0.0 exposes it to the network).",
)
@click.option("--port", type=click.IntRange(1, 65535), default=5006, show_default=True)
@click.option("--replay", is_flag=True, help="Play a finished record back instead of following it.")
@click.option(
    "--speed",
    type=POSITIVE,
    default=1.0,
    show_default=True,
    help="Replay speed factor.",
)
@_salvage_option
@_friendly_errors
def monitor_cmd(record, host, port, replay, speed):
    """Serve the live monitor page for a record that is being written (or replay one)."""
    from rwlab.testbed.monitor import check_port, serve

    if not host.strip():
        raise ConfigError("--host must name an address, e.g. 127.0.0.1")
    check_port(host, port)
    from rwlab.testbed.record import partial_path

    if not Path(record).is_file() and not partial_path(record).is_file():
        raise FileNotFoundError(
            f"no such record: {record} (nor {partial_path(record).name} being written); "
            "start the experiment first, or give the path of an existing record"
        )
    if replay:
        from rwlab.testbed import read_record

        read_record(record)  # a clear error now rather than a blank page later
    click.echo(f"rwlab monitor on http://{host}:{port}/ (Ctrl-C to stop)", err=True)
    try:
        serve(record, host=host, port=port, replay=replay, speed=speed)
    except KeyboardInterrupt:
        pass
