import fcntl
import itertools
import os
import pty
import select
import struct
import termios

import can
import numpy as np
import pytest

from rwlab.errors import RwlabError
from rwlab.wheel import (
    Fault,
    FaultInjection,
    Mode,
    SimClock,
    SlipSerialBus,
    WallClock,
    WheelClient,
    WheelCommandError,
    WheelFault,
    WheelNode,
    WheelTimeout,
)
from rwlab.wheel import protocol as proto

_channels = itertools.count()


@pytest.fixture
def rig(request):
    """A simulated wheel and its driver on a fresh virtual bus and simulated clock."""
    opts = getattr(request, "param", {})
    channel = f"rig{next(_channels)}"
    clock = SimClock()
    node_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    host_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    node = WheelNode(
        node_bus,
        3,
        clock=clock,
        telemetry_rate=opts.get("rate", 50.0),
        latency=opts.get("latency", 0.02),
        watchdog=opts.get("watchdog", 1.0),
        faults=opts.get("faults"),
    )
    client = WheelClient(host_bus, 3, clock=clock, timeout=0.5)
    yield clock, node, client
    node.stop()
    node_bus.shutdown()
    host_bus.shutdown()


def hold(client, clock, rpm, seconds, mode="speed"):
    """Keep commanding (so the watchdog stays quiet) for ``seconds`` of simulated time."""
    for _ in range(int(seconds / 0.25)):
        (client.set_speed if mode == "speed" else client.set_acceleration)(rpm)
        clock.sleep(0.25)


def test_speed_mode_reaches_the_setpoint(rig):
    clock, _node, client = rig
    hold(client, clock, 2000, 20)
    t = client.telemetry()
    assert t.mode == Mode.SPEED and t.speed_rpm == pytest.approx(2000, abs=5)


def test_acceleration_mode_ramps_and_idle_coasts(rig):
    clock, _node, client = rig
    hold(client, clock, 100, 5, mode="accel")
    assert client.telemetry().speed_rpm == pytest.approx(500, abs=15)
    seq = client.idle()
    client.wait_ack(seq)
    clock.sleep(3)
    t = client.telemetry()
    assert t.mode == Mode.IDLE and 0 < t.speed_rpm < 500  # coasting down, not braked to zero


def test_acknowledgement_arrives_after_the_configured_latency(rig):
    _clock, node, client = rig
    seq = client.set_speed(100)
    ack = client.wait_ack(seq)
    latency = client.latency_of(seq, client.latest_time)
    assert ack.sequence_echo == seq
    assert 0.02 <= latency <= 0.02 + node.period + 1e-9


def test_commands_beyond_the_limits_are_refused_before_sending(rig):
    clock, node, client = rig
    for call, value in (
        (client.set_speed, 7801),
        (client.set_speed, -9000),
        (client.set_acceleration, 315),
        (client.set_speed, float("nan")),
    ):
        with pytest.raises(WheelCommandError):
            call(value)
    clock.sleep(0.5)
    assert node.commands_seen == 0


def test_watchdog_idles_a_wheel_left_without_commands(rig):
    clock, node, client = rig
    client.wait_ack(client.set_speed(3000))
    clock.sleep(2.0)  # watchdog is 1 s
    client.poll()
    assert node.wheel.mode == Mode.IDLE and node.wheel.faults & Fault.WATCHDOG
    with pytest.raises(WheelFault, match="WATCHDOG") as err:
        client.set_speed(1000)
    assert err.value.faults & Fault.WATCHDOG
    client.wait_ack(client.clear_fault())
    clock.sleep(1.1)  # next heartbeat reports the cleared state
    client.wait_ack(client.set_speed(1000))
    assert node.wheel.mode == Mode.SPEED


@pytest.mark.parametrize("rig", [{"faults": FaultInjection(drop_rate=0.3)}], indirect=True)
def test_dropped_frames_are_counted(rig):
    clock, _node, client = rig
    hold(client, clock, 500, 5)
    assert 40 <= client.lost_frames <= 110  # ≈ 30 % of 250 frames
    assert client.telemetry().speed_rpm > 0


def _received_by_counter(faults):
    """Run a 5 s speed hold and return {frame counter: telemetry} as the driver received it."""
    clock = SimClock()
    channel = f"cmp{next(_channels)}"
    buses = [
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) for _ in range(2)
    ]
    node = WheelNode(buses[0], 3, clock=clock, telemetry_rate=50, faults=faults)
    client = WheelClient(buses[1], 3, clock=clock)
    hold(client, clock, 500, 5)
    for b in buses:
        b.shutdown()
    return {t.counter: t for _, t in client.received}, client, node


def test_corrupted_frames_are_dropped_not_believed():
    clean, _, _ = _received_by_counter(None)
    damaged, client, _ = _received_by_counter(FaultInjection(corrupt_rate=0.5))
    assert client.bad_frames > 50 and len(damaged) < len(clean)
    assert all(clean[k] == t for k, t in damaged.items())  # every frame believed is intact


@pytest.mark.parametrize("rig", [{"faults": FaultInjection(silent=True)}], indirect=True)
def test_a_silent_wheel_raises_timeouts(rig):
    _clock, _node, client = rig
    with pytest.raises(WheelTimeout):
        client.wait_ack(client.set_speed(100))
    with pytest.raises(WheelTimeout):
        client.telemetry()
    with pytest.raises(WheelTimeout):
        list(client.stream(2.0))


@pytest.mark.parametrize("rig", [{"faults": FaultInjection(extra_delay=0.2)}], indirect=True)
def test_delayed_replies_show_in_the_latency(rig):
    _clock, _node, client = rig
    seq = client.set_speed(100)
    client.wait_ack(seq)
    assert client.latency_of(seq, client.latest_time) >= 0.22 - 1e-9


@pytest.mark.parametrize("rig", [{"faults": FaultInjection(stuck_speed=True)}], indirect=True)
def test_stuck_speed_sensor_reports_a_frozen_value(rig):
    clock, node, client = rig
    hold(client, clock, 2000, 5)
    reported = {t.speed_rpm for _, t in client.received}
    assert reported == {0.0} and node.wheel.speed > 100


@pytest.mark.parametrize("rig", [{"faults": FaultInjection(overcurrent=True)}], indirect=True)
def test_overcurrent_latches_and_is_reported_by_name(rig):
    clock, _node, client = rig
    client.set_speed(100)
    clock.sleep(0.2)
    with pytest.raises(WheelFault, match="OVERCURRENT"):
        list(client.stream(1.0))


def test_garbage_frames_never_crash_driver_or_node(rig):
    clock, node, client = rig
    rng = np.random.default_rng(0)
    injector = can.Bus(interface="virtual", channel=node.bus.channel_id, preserve_timestamps=True)
    try:
        for i in range(500):
            base = [0x100, 0x180, 0x700, int(rng.integers(0, 0x7FF))][i % 4]
            data = rng.integers(0, 256, int(rng.integers(0, 9))).astype(np.uint8).tobytes()
            msg = can.Message(
                arbitration_id=base + 3 if base < 0x7F0 else base,
                data=data,
                is_extended_id=False,
                timestamp=clock.now(),
            )
            injector.send(msg)
        hold(client, clock, 800, 3)
    finally:
        injector.shutdown()
    assert client.bad_frames > 0 and node.bad_frames > 0
    assert client.telemetry().speed_rpm > 100  # and the wheel still works


def test_the_context_manager_leaves_the_wheel_idle_after_an_error(rig):
    clock, node, client = rig
    with pytest.raises(RuntimeError), client:
        client.wait_ack(client.set_speed(3000))
        raise RuntimeError("experiment crashed")
    clock.sleep(0.1)
    assert node.wheel.mode == Mode.IDLE


def test_two_wheels_share_a_bus_by_node_id():
    clock = SimClock()
    buses = [
        can.Bus(interface="virtual", channel="shared", preserve_timestamps=True) for _ in range(3)
    ]
    try:
        nodes = [WheelNode(buses[i], i, clock=clock) for i in (0, 1)]
        c0, c1 = WheelClient(buses[2], 0, clock=clock), WheelClient(buses[2], 1, clock=clock)
        c0.set_speed(1000)
        c1.set_speed(-500)
        clock.sleep(0.5)
        assert nodes[0].wheel.setpoint > 0 and nodes[1].wheel.setpoint < 0
        for n in nodes:
            n.stop()
    finally:
        for b in buses:
            b.shutdown()


def test_wheel_errors_share_the_rwlab_base():
    assert issubclass(WheelTimeout, RwlabError) and issubclass(WheelFault, RwlabError)


def test_node_rejects_bad_configuration():
    bus = can.Bus(interface="virtual", channel="cfg")
    try:
        with pytest.raises(RwlabError):
            WheelNode(bus, telemetry_rate=5000)
        with pytest.raises(RwlabError):
            WheelNode(bus, node_id=16)
    finally:
        bus.shutdown()


def test_wall_clock_node_answers_in_real_time():
    a = can.Bus(interface="virtual", channel="wall")
    b = can.Bus(interface="virtual", channel="wall")
    node = WheelNode(a, 0, telemetry_rate=200, latency=0.0).start()
    try:
        with WheelClient(b, 0, clock=WallClock()) as client:
            ack = client.wait_ack(client.set_speed(1000), timeout=1.0)
            assert ack.mode == Mode.SPEED
    finally:
        node.stop()
        a.shutdown()
        b.shutdown()
    assert node.wheel.mode == Mode.IDLE  # the client idled it on exit


class _PtyMaster:
    """Just enough of pyserial's interface over a pty master file descriptor."""

    def __init__(self, fd):
        self.fd, self.name = fd, "pty-master"

    @property
    def in_waiting(self):
        return struct.unpack("i", fcntl.ioctl(self.fd, termios.FIONREAD, b"\0\0\0\0"))[0]

    def read(self, n):
        return os.read(self.fd, n) if select.select([self.fd], [], [], 0)[0] else b""

    def write(self, data):
        return os.write(self.fd, data)

    def close(self):
        os.close(self.fd)


def test_driver_and_wheel_talk_over_rs232_slip():
    import serial

    master, slave = pty.openpty()
    port = serial.Serial(os.ttyname(slave), 115200, timeout=0)  # pyserial sets raw mode
    node = WheelNode(SlipSerialBus(_PtyMaster(master)), 0, telemetry_rate=50, latency=0.0).start()
    host = SlipSerialBus(port)
    try:
        with WheelClient(host, 0, clock=WallClock(), timeout=1.0) as client:
            ack = client.wait_ack(client.set_speed(1000), timeout=2.0)
            assert ack.mode == Mode.SPEED
    finally:
        node.stop()
        host.shutdown()
        node.bus.shutdown()
        os.close(slave)
    assert proto.decode(proto.encode(proto.Command(0, Mode.IDLE, 0.0, 1))).mode == Mode.IDLE


def _vcan_available():
    try:
        can.Bus(interface="socketcan", channel="vcan0").shutdown()
        return True
    except Exception:
        return False


@pytest.mark.skipif(not _vcan_available(), reason="no SocketCAN vcan0 on this machine")
def test_driver_and_wheel_over_socketcan():
    a = can.Bus(interface="socketcan", channel="vcan0")
    b = can.Bus(interface="socketcan", channel="vcan0")
    node = WheelNode(a, 5, latency=0.0).start()
    try:
        with WheelClient(b, 5) as client:
            assert client.wait_ack(client.set_speed(500), timeout=1.0).mode == Mode.SPEED
    finally:
        node.stop()
        a.shutdown()
        b.shutdown()
