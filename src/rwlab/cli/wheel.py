"""``rwlab wheel …``: serve a wheel twin, send it commands."""

from __future__ import annotations

import click

from rwlab.cli._common import SECONDS, Number, _friendly_errors, _stop_signals, main

# -- the wheel ------------------------------------------------------------------------


INTERFACE_HELP = (
    "virtual, socketcan, udp_multicast, serial (RS-232), or one added by "
    "an entry point (`rwlab wheel protocols` lists them)."
)
SERVE_INTERFACE_HELP = (
    "socketcan, udp_multicast, serial (RS-232), or one added by an entry point. Default: "
    "udp_multicast for a CAN protocol, serial with --channel pty for a byte-stream one "
    "(both reachable from other processes; virtual is not, and is refused)."
)


def _bus_options(func, serving: bool = False):
    interface = (
        click.option("--interface", default=None, help=SERVE_INTERFACE_HELP)
        if serving
        else click.option("--interface", default="virtual", show_default=True, help=INTERFACE_HELP)
    )
    for option in reversed(
        [
            interface,
            click.option(
                "--channel",
                default=None,
                help="Bus channel (vcan0; a multicast group, GROUP@ADDRESS to leave the "
                "loopback interface; /dev/ttyUSB0, ...; for `serve`, pty makes a "
                "pseudo-terminal pair and prints the path clients open).",
            ),
            click.option("--node-id", type=click.IntRange(0, 15), default=0, show_default=True),
            click.option(
                "--protocol",
                default="rwlab",
                show_default=True,
                help="Wheel protocol (rwlab, canopen, nsp, or a registered one; "
                "see `rwlab wheel protocols`).",
            ),
            click.option(
                "--profile",
                default=None,
                help="The protocol's profile: canopen: rwlab, oresat, cia402; nsp: its wheel "
                "families (`rwlab wheel protocols` lists them). Default: rwlab's own.",
            ),
        ]
    ):
        func = option(func)
    return func


@main.group()
def wheel() -> None:
    """The reaction wheel: run a simulated wheel (any wheel model, `rwlab wheel models`), or
    command a wheel on a bus."""


@wheel.command("serve")
@lambda func: _bus_options(func, serving=True)
@click.option(
    "--telemetry-rate",
    type=Number(0, 10_000, low_open=True),
    default=100.0,
    show_default=True,
    help="Hz.",
)
@click.option(
    "--latency-ms",
    type=Number(0, 10_000),
    default=20.0,
    show_default=True,
    help="Command-to-effect latency (paper A measured ~20 ms).",
)
@click.option(
    "--watchdog",
    type=Number(0, 3600),
    default=1.0,
    show_default=True,
    help="Idle the wheel after this many seconds without a command (0: off).",
)
@click.option(
    "--params",
    type=click.Path(exists=True, dir_okay=False),
    help="Wheel parameters as TOML (default: the protocol's own wheel, see --wheel).",
)
@click.option(
    "--wheel",
    "wheel_model",
    metavar="NAME|FILE",
    help="Wheel model: a preset (`rwlab wheel models`) or a wheel spec file (default: the "
    "protocol's own wheel, nrwa-t6 for nsp/nrwa-t6; rw90 for the others).",
)
@click.option(
    "--unit",
    type=click.IntRange(0),
    default=None,
    help="Wheel unit: parameters drawn within their model's tolerances.",
)
@click.option("--duration", type=SECONDS, default=None, help="Stop after this many seconds.")
@_friendly_errors
def wheel_serve(
    interface,
    channel,
    node_id,
    protocol,
    profile,
    telemetry_rate,
    latency_ms,
    watchdog,
    params,
    wheel_model,
    unit,
    duration,
):
    """Run a simulated wheel on a bus, on the wall clock, until Ctrl-C.

    It first listens for LISTEN_S seconds and refuses to start if another wheel
    already answers under its node id there; later it reports one in its status.
    """
    import time

    from rwlab.errors import ConfigError
    from rwlab.wheel import WheelNode, WheelParams
    from rwlab.wheel.bus import DEFAULT_CHANNELS, open_transport, transport_names
    from rwlab.wheel.link import get_protocol, resolve_protocol

    protocol = resolve_protocol(protocol, profile)
    if params and wheel_model:
        raise ConfigError("give the wheel once: --params FILE or --wheel NAME|FILE")
    wheel_name = params or wheel_model or get_protocol(protocol).wheel
    wheel_params = WheelParams.load(wheel_name)
    if unit is not None:
        wheel_params = wheel_params.for_unit(unit)
    interface, channel = _served_interface(protocol, interface, channel)
    if interface not in transport_names():
        raise ConfigError(
            f"unknown interface {interface!r}; choose from {', '.join(transport_names())}"
        )
    channel = channel or DEFAULT_CHANNELS.get(interface)
    keep_open = None
    if interface == "serial" and channel == "pty":  # the twin makes its own pty pair
        from rwlab.wheel.serial import open_pty

        bus, keep_open = open_pty()  # the other end stays open: no hang-up between clients
        channel = keep_open.port
    else:
        bus = open_transport(protocol, interface, channel)
    node = None
    try:
        if "can" in get_protocol(protocol).transports:  # a shared bus; a serial line is not
            _refuse_if_answered(bus, node_id, protocol)
        node = WheelNode(
            bus,
            node_id,
            wheel_params,
            telemetry_rate=telemetry_rate,
            latency=latency_ms / 1000,
            watchdog=watchdog,
            protocol=protocol,
        ).start()
        click.echo(
            f"simulated wheel {node_id} ({protocol}) on {interface}:{channel}; Ctrl-C to stop",
            err=True,
        )
        click.echo(f"answering as {get_protocol(protocol).addresses(node_id)}", err=True)
        click.echo(_wheel_line(wheel_name, protocol, params, wheel_model, unit), err=True)
        click.echo(
            f"reach it with: rwlab wheel cmd --protocol {protocol} --interface {interface} "
            f"--channel {channel} --node-id {node_id} speed 300",
            err=True,
        )
        start = time.monotonic()
        with _stop_signals():
            while duration is None or time.monotonic() - start < duration:
                time.sleep(min(1.0, duration or 1.0))
                click.echo(f"t={time.monotonic() - start:7.1f} s {_status(node)}", err=True)
    except KeyboardInterrupt:
        pass
    finally:
        if node is not None:
            node.stop()
        _close(bus)
        if keep_open is not None:
            keep_open.close()


def _served_interface(protocol: str, interface: str | None, channel: str | None):
    """The interface and channel to serve on: one other processes reach.

    python-can's ``virtual`` bus lives inside one process, so a wheel served on it
    answers nobody: refused. Without ``--interface``, a CAN protocol is served on
    ``udp_multicast`` and a byte-stream one on a fresh pty.
    """
    from rwlab.errors import ConfigError
    from rwlab.wheel.link import get_protocol

    stream = "can" not in get_protocol(protocol).transports
    if interface == "virtual":
        other = "serial --channel pty" if stream else "udp_multicast"
        raise ConfigError(
            "the virtual interface lives inside one process: a wheel served on it cannot be "
            "reached by `rwlab wheel cmd`, `rwlab experiment` or any other process; serve it "
            f"on --interface {other} (between processes on this machine, the default), "
            + ("or a serial port" if stream else "socketcan (vcan0, a CAN adapter) or serial")
        )
    if interface is None:
        return ("serial", channel or "pty") if stream else ("udp_multicast", channel)
    return interface, channel


def _wheel_line(wheel_name: str, protocol: str, params, wheel_model, unit) -> str:
    """The start-up line that names the wheel model served, and why that one."""
    if params:
        why = "--params"
    elif wheel_model:
        why = "--wheel"
    else:
        why = f"{protocol}'s default; --wheel NAME|FILE for another"
    drawn = f", unit {unit}" if unit is not None else ""
    return f"wheel model {wheel_name}{drawn} ({why})"


def _close(transport) -> None:
    """Shut a bus down, or close a serial port."""
    closer = getattr(transport, "shutdown", None) or getattr(transport, "close", None)
    if closer is not None:
        closer()


LISTEN_S = 1.5  # longer than the 1 Hz heartbeat every protocol's twin sends


def _refuse_if_answered(bus, node_id: int, protocol: str) -> None:
    """ConfigError if a wheel already answers under ``node_id`` on ``bus``."""
    import time

    from rwlab.errors import ConfigError
    from rwlab.wheel.clock import WallClock
    from rwlab.wheel.link import get_protocol

    link = get_protocol(protocol).host_link(bus, node_id, clock=WallClock())
    end = time.monotonic() + LISTEN_S
    while time.monotonic() < end:
        heard = link.receive(WallClock().now())
        if heard:
            where = heard[0].source or "this bus"
            raise ConfigError(
                f"a wheel already answers as node {node_id} from {where}; serve this one "
                "with another --node-id or --channel"
            )
        time.sleep(0.02)


def _status(node) -> str:
    """One status line: the wheel, and what the bus brought that was not for it."""
    w = node.wheel
    text = (
        f"mode={w.mode.name:<12} speed={w.measured_speed_rpm():8.1f} rpm faults={w.faults!s} "
        f"commands={node.commands_seen} rejected={node.rejected_commands} "
        f"bad={node.bad_frames} foreign={node.foreign_frames}"
    )
    if node.errors:
        text += f" errors={node.errors} (last: {node.last_error})"
    if node.twin_source:
        text += f" WARNING: another wheel answers as node {node.node_id} from {node.twin_source}"
    return text


@wheel.command("cmd")
@_bus_options
@click.argument("action", type=click.Choice(["speed", "accel", "idle", "clear"]))
@click.argument("value", type=Number(), required=False, default=0.0)
@click.option(
    "--watch",
    type=Number(0, 86_400),
    default=2.0,
    show_default=True,
    help="Seconds to print telemetry after the command.",
)
@click.option("--timeout", type=Number(0, 3600, low_open=True), default=0.5, show_default=True)
@click.option(
    "--wheel",
    "wheel_model",
    metavar="NAME|FILE",
    help="The wheel's model, for its limits and inertia (a preset or a wheel spec file; "
    "default: the protocol's own wheel, as `rwlab wheel serve` uses).",
)
@_friendly_errors
def wheel_cmd(
    interface, channel, node_id, protocol, profile, action, value, watch, timeout, wheel_model
):
    """Send one command (speed rpm, accel rpm/s, idle, clear) and print telemetry.

    On the virtual interface an in-process simulated wheel answers. The wheel is
    idled when the command ends unless the action was idle or clear.
    """
    from rwlab.wheel import WheelClient, WheelNode, WheelParams
    from rwlab.wheel.bus import open_transport
    from rwlab.wheel.link import get_protocol, resolve_protocol
    from rwlab.wheel.serial import open_pty

    protocol = resolve_protocol(protocol, profile)
    params = WheelParams.load(wheel_model or get_protocol(protocol).wheel)
    node = None
    if interface == "virtual" and "can" not in get_protocol(protocol).transports:
        node_bus, bus = open_pty()  # a serial protocol's twin answers over a pty pair
    else:
        bus = open_transport(protocol, interface, channel)
        node_bus = open_transport(protocol, interface, channel) if interface == "virtual" else None
    if node_bus is not None:
        node = WheelNode(node_bus, node_id, params, latency=0.02, protocol=protocol).start()
    client = WheelClient(bus, node_id, params, timeout=timeout, protocol=protocol)
    with _stop_signals():  # SIGTERM too ends in the finally: the wheel idles
        try:
            send = {
                "speed": lambda: client.set_speed(value),
                "accel": lambda: client.set_acceleration(value),
                "idle": client.idle,
                "clear": client.clear_fault,
            }[action]
            seq = send()
            client.wait_ack(seq)
            t0 = client.clock.now()
            click.echo(
                f"acknowledged in {client.latency_of(seq, client.latest_time) * 1000:.1f} ms"
            )
            click.echo(f"{'t [s]':>7} {'speed [rpm]':>12} {'current [A]':>12} mode")
            next_print = next_send = t0
            while client.clock.now() - t0 <= watch:
                now = client.clock.now()
                if action in ("speed", "accel") and now >= next_send:
                    send()  # keep-alive: the wheel's watchdog idles it without commands
                    next_send += 0.25
                tel = client.telemetry()
                client.raise_if_faulted()
                if now >= next_print:
                    click.echo(
                        f"{now - t0:7.2f} {tel.speed_rpm:12.1f} {tel.current:12.3f} {tel.mode.name}"
                    )
                    next_print += 0.1
                client.clock.sleep(0.005)
        finally:
            if action not in ("idle", "clear"):
                client.close()
            if node is not None:
                node.stop()
                _close(node.bus)
            _close(bus)


@wheel.command("protocols")
@_friendly_errors
def wheel_protocols():
    """List the wheel protocols and transports (built in, and added by entry points)."""
    from rwlab.wheel.bus import transport_names
    from rwlab.wheel.link import get_protocol, protocol_names

    click.echo("protocols (a family's bare name is its rwlab profile):")
    for name, target in protocol_names().items():
        try:
            protocol = get_protocol(name)
            about = f"{protocol.description} [transports: {', '.join(protocol.transports)}]"
        except Exception as exc:  # a broken plugin is listed with why, not fatal
            about = f"cannot be loaded: {exc}"
        family, _, profile = name.partition("/")
        shown = f"--protocol {family}" + (f" --profile {profile}" if profile else "")
        click.echo(f"  {name:<16} ({shown}) {target}\n                   {about}")
    click.echo("interfaces:")
    for name, target in transport_names().items():
        click.echo(f"  {name:<14} {target}")


@wheel.command("models")
@click.argument("name", required=False)
@click.option("--json", "as_json", is_flag=True, help="A JSON list of objects, one per model.")
@_friendly_errors
def wheel_models(name, as_json):
    """List the shipped wheel models (presets) with their limits; with NAME, print that
    one whole as a wheel spec TOML to copy into your own file and edit.

    Each is a wheel spec file (rwlab/wheelspec/presets/NAME.toml) whose every number
    says where it comes from; pass NAME or your own spec file to --wheel.
    """
    import json

    from rwlab.errors import ConfigError
    from rwlab.wheelspec import WheelSpec, preset_names

    if name is not None:
        if as_json:
            raise ConfigError("--json lists every model; leave it out to print NAME's TOML")
        click.echo(WheelSpec.load(name).to_toml(), nl=False)
        return
    rows = [WheelSpec.load(name).limits() for name in preset_names()]
    if as_json:
        click.echo(json.dumps(rows, indent=2, ensure_ascii=False))
        return
    click.echo(
        f"{'name':<9} {'inertia kg·m²':>13} {'speed rpm':>9} {'torque N·m':>10} "
        f"{'current A':>9} {'momentum N·m·s':>14}  mode    title"
    )
    for r in rows:
        click.echo(
            f"{r['name']:<9} {r['inertia_kg_m2']:>13.4g} {r['max_speed_rpm']:>9.0f} "
            f"{r['max_torque_nm']:>10.4g} {r['current_limit_a']:>9.3g} "
            f"{r['momentum_capacity_nms']:>14.4g}  {r['controller_mode']:<7} {r['title']}"
        )
