"""``rwlab wheel …``: serve a wheel twin, send it commands."""

from __future__ import annotations

import click

from rwlab.cli._common import SECONDS, Number, _friendly_errors, _stop_signals, main

# -- the wheel ------------------------------------------------------------------------


def _bus_options(func):
    from rwlab.wheel.bus import INTERFACES

    for option in reversed(
        [
            click.option(
                "--interface",
                type=click.Choice(INTERFACES),
                default="virtual",
                show_default=True,
                help="python-can interface (serial = RS-232 with SLIP).",
            ),
            click.option(
                "--channel",
                default=None,
                help="Bus channel (vcan0, a multicast group, /dev/ttyUSB0, ...).",
            ),
            click.option("--node-id", type=click.IntRange(0, 15), default=0, show_default=True),
        ]
    ):
        func = option(func)
    return func


@main.group()
def wheel() -> None:
    """The reaction wheel: run a simulated RW90, or command a wheel on a bus."""


@wheel.command("serve")
@_bus_options
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
    help="Wheel parameters as TOML (default RW90).",
)
@click.option("--duration", type=SECONDS, default=None, help="Stop after this many seconds.")
@_friendly_errors
def wheel_serve(
    interface, channel, node_id, telemetry_rate, latency_ms, watchdog, params, duration
):
    """Run a simulated wheel on a bus, on the wall clock, until Ctrl-C."""
    import time

    from rwlab.wheel import RW90, WheelNode, WheelParams
    from rwlab.wheel.bus import DEFAULT_CHANNELS, open_bus

    wheel_params = WheelParams.from_toml(params) if params else RW90
    channel = channel or DEFAULT_CHANNELS[interface]
    bus = open_bus(interface, channel)
    node = WheelNode(
        bus,
        node_id,
        wheel_params,
        telemetry_rate=telemetry_rate,
        latency=latency_ms / 1000,
        watchdog=watchdog,
    ).start()
    click.echo(f"simulated wheel {node_id} on {interface}:{channel}; Ctrl-C to stop", err=True)
    start = time.monotonic()
    try:
        with _stop_signals():
            while duration is None or time.monotonic() - start < duration:
                time.sleep(min(1.0, duration or 1.0))
                w = node.wheel
                click.echo(
                    f"t={time.monotonic() - start:7.1f} s mode={w.mode.name:<12} "
                    f"speed={w.measured_speed_rpm():8.1f} rpm faults={w.faults!s}",
                    err=True,
                )
    except KeyboardInterrupt:
        pass
    finally:
        node.stop()
        bus.shutdown()


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
@_friendly_errors
def wheel_cmd(interface, channel, node_id, action, value, watch, timeout):
    """Send one command (speed rpm, accel rpm/s, idle, clear) and print telemetry.

    On the virtual interface an in-process simulated wheel answers. The wheel is
    idled when the command ends unless the action was idle or clear.
    """
    from rwlab.wheel import WheelClient, WheelNode
    from rwlab.wheel.bus import open_bus

    bus = open_bus(interface, channel)
    node = None
    if interface == "virtual":
        node = WheelNode(open_bus(interface, channel), node_id, latency=0.02).start()
    client = WheelClient(bus, node_id, timeout=timeout)
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
                node.bus.shutdown()
            bus.shutdown()
