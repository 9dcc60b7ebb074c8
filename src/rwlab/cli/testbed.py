"""``rwlab experiment``, ``export`` and ``monitor``: the testbed."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import click

from rwlab.cli._common import _check_folder, _friendly_errors, _stop_signals, main
from rwlab.errors import ConfigError

# -- the testbed ----------------------------------------------------------------------


@main.command("experiment")
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False),
    help="Experiment TOML file ([experiment] table); flags override it.",
)
@click.option("--signal", type=click.Choice(["prbs", "chirp", "step", "multisine", "file"]))
@click.option("--mode", type=click.Choice(["speed", "acceleration"]))
@click.option("--amplitude", type=float, help="rpm in speed mode, rpm/s in acceleration mode.")
@click.option("--duration", type=float, help="Seconds of signal.")
@click.option("--Ts", "Ts", type=float, help="Command period, s.")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="Record file (.mcap).")
@click.option("--realtime", is_flag=True, default=None, help="Run on the wall clock.")
@click.option("--telemetry-rate", type=float, help="Simulated wheel's telemetry rate, Hz.")
@click.option("--seed", type=int)
@click.option(
    "--file",
    "setpoint_file",
    type=click.Path(dir_okay=False),
    help="CSV of setpoints for --signal file.",
)
@click.option("--interface", type=click.Choice(["virtual", "socketcan", "udp_multicast", "serial"]))
@click.option("--channel")
@click.option("--node-id", type=click.IntRange(0, 15))
@click.option("--raw-frames", is_flag=True, default=None, help="Also record every CAN frame.")
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
    "model_file",
    type=click.Path(dir_okay=False),
    help="model.json: run the fault detector live; alarms become record events.",
)
@click.option("--monitor", is_flag=True, help="Serve the live monitor while the experiment runs.")
@click.option(
    "--port", type=click.IntRange(1, 65535), default=5006, show_default=True, help="Monitor port."
)
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_friendly_errors
def experiment(
    config_file,
    signal,
    mode,
    amplitude,
    duration,
    Ts,
    out,
    realtime,
    telemetry_rate,
    seed,
    setpoint_file,
    interface,
    channel,
    node_id,
    raw_frames,
    faults,
    model_file,
    monitor,
    port,
    force,
):
    """Play a test signal into a wheel and record every command and telemetry frame.

    With the default virtual interface a simulated RW90 answers, on a simulated
    clock (a 20-minute experiment takes seconds) unless --realtime is given.
    Ctrl-C or any error leaves the wheel idle and the record closed.
    """
    from rwlab.testbed import ExperimentConfig, run_experiment

    overrides = dict(
        signal=signal,
        mode=mode,
        amplitude=amplitude,
        duration=duration,
        Ts=Ts,
        realtime=realtime,
        telemetry_rate=telemetry_rate,
        seed=seed,
        file=setpoint_file,
        interface=interface,
        channel=channel,
        node_id=node_id,
        raw_frames=raw_frames,
        faults=tuple(faults) or None,
        model=model_file,
    )
    if config_file:
        cfg = ExperimentConfig.from_toml(config_file, **overrides)
    else:
        cfg = ExperimentConfig(**{k: v for k, v in overrides.items() if v is not None})
    from rwlab.wheel import RW90

    cfg.check_limits(RW90)
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

                summary = run_experiment(cfg, out, force=force, progress=progress)
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
        f"frames, {summary.lost_frames} lost, {summary.duration:.1f} s ({summary.status})"
    )


@main.command("export")
@click.argument("record", type=click.Path(dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(["csv", "parquet", "mat"]), required=True)
@click.option("--out", type=click.Path(dir_okay=False), required=True)
@click.option("--Ts", "Ts", type=float, help="Sample time, s (default: the record's).")
@click.option(
    "--max-gap",
    type=float,
    default=None,
    help="Accept telemetry gaps up to this many seconds (default Ts).",
)
@click.option(
    "--node", type=click.IntRange(0, 15), help="The wheel, in a record of several (rwlab hil)."
)
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@_friendly_errors
def export(record, fmt, out, Ts, max_gap, node, force):
    """Write a record as CSV, Parquet or MATLAB .mat, sampled at Ts.

    Columns: time_s, command, speed_rpm, acceleration_rpm_s, current_a.
    """
    from rwlab.testbed import load_record

    _check_folder(Path(out).parent)
    data = load_record(
        record, Ts, outputs=("speed", "acceleration", "current"), max_gap=max_gap, node=node
    )
    path = Path(out)
    if path.suffix.lower() != f".{fmt}":
        path = path.with_suffix(f".{fmt}") if not path.suffix else path
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
    type=click.FloatRange(0, min_open=True),
    default=1.0,
    show_default=True,
    help="Replay speed factor.",
)
@_friendly_errors
def monitor_cmd(record, host, port, replay, speed):
    """Serve the live monitor page for a record that is being written (or replay one)."""
    from rwlab.testbed.monitor import check_port, serve

    if not host.strip():
        raise ConfigError("--host must name an address, e.g. 127.0.0.1")
    check_port(host, port)
    if replay:
        from rwlab.testbed import read_record

        read_record(record)  # a clear error now rather than a blank page later
    click.echo(f"rwlab monitor on http://{host}:{port}/ (Ctrl-C to stop)", err=True)
    try:
        serve(record, host=host, port=port, replay=replay, speed=speed)
    except KeyboardInterrupt:
        pass
