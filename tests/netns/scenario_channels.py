"""Issue 28: udp_multicast channels isolate, and two wheels under one node id are refused.

Run inside a private network namespace (tests/netns/run.py); argv[1] names the
case. Prints one JSON line.
"""

import json
import os
import socket
import subprocess
import sys
import tempfile
import time

from rwlab.testbed import read_record
from rwlab.wheel import WallClock, WheelClient
from rwlab.wheel import protocol as proto
from rwlab.wheel.udp import LoopbackMulticastBus

A, B = "239.74.163.2", "239.74.163.3"
py = sys.executable


SERVE = ("wheel", "serve", "--interface", "udp_multicast", "--telemetry-rate", "50")
# a wheel serve that imports the CLI and what `wheel serve` imports before it listens (under
# load those imports alone took longer than the listen), says so (a file GO.PID), then
# starts when the file GO (argv[1]) appears
AT_GO = (
    "import os, sys, time; from rwlab.cli import main; go = sys.argv.pop(1)\n"
    "from rwlab.wheel import WheelNode; from rwlab.wheel.bus import open_transport\n"
    "from rwlab.wheel.link import get_protocol; get_protocol('rwlab')\n"
    "open(f'{go}.{os.getpid()}', 'w').close()\n"
    "while not os.path.exists(go): time.sleep(0.005)\n"
    "sys.argv[0] = 'rwlab'; sys.exit(main())"
)


def serve(group: str, *extra: str, go: str | None = None) -> subprocess.Popen:
    args = [*SERVE, "--channel", group, "--duration", "60", *extra]
    start = [py, "-m", "rwlab.cli"] if go is None else [py, "-c", AT_GO, go]
    return subprocess.Popen([*start, *args], stderr=subprocess.PIPE, text=True)


def wait_for_wheel(bus: LoopbackMulticastBus, timeout: float = 30) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = bus.recv(timeout=0.1)
        if msg is not None and msg.arbitration_id == proto.TELEMETRY_ID:
            return
    raise SystemExit("no wheel answered")


def stop(proc: subprocess.Popen) -> str:
    proc.terminate()
    return proc.communicate(timeout=20)[1]


def serve_together(listen: LoopbackMulticastBus) -> tuple[subprocess.Popen, subprocess.Popen]:
    """Two wheels on one id, started together so neither hears the other first.

    On a loaded machine two starts can be more than serve's 1.5 s listen apart (their
    imports alone), and the later one is then refused (as it should be): both import
    first and start on one signal (a file appearing), and the pair starts again if
    one was refused all the same.
    """
    for _ in range(3):
        folder = tempfile.mkdtemp()
        go = os.path.join(folder, "go")
        pair = serve(A, go=go), serve(A, go=go)
        end = time.monotonic() + 60
        while len(os.listdir(folder)) < 2 and time.monotonic() < end:
            time.sleep(0.05)  # both import the CLI
        open(go, "w").close()
        wait_for_wheel(listen)
        time.sleep(2.0)
        if all(p.poll() is None for p in pair):
            return pair
        for p in pair:
            stop(p)
    raise SystemExit("two wheels could not be started together")


def channels() -> dict:
    result: dict = {}
    # the bus: a frame sent to B never reaches a bus on A (same port, same host)
    on_a, on_b = LoopbackMulticastBus(A), LoopbackMulticastBus(B)
    raw = on_a._tx
    result["multicast_if"] = socket.inet_ntoa(
        raw.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)
    )
    result["ttl"] = raw.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL)
    result["rx_bound_to"] = on_a._rx.getsockname()[0]
    sender = LoopbackMulticastBus(B)
    for k in range(20):
        sender.send(proto.encode(proto.Command(0, proto.Mode.SPEED, 100.0, k)))
    time.sleep(0.2)
    result["a_got"] = sum(1 for _ in iter(lambda: on_a.recv(timeout=0.05), None))
    result["b_got"] = sum(1 for _ in iter(lambda: on_b.recv(timeout=0.05), None))
    for bus in (on_a, on_b, sender):
        bus.shutdown()
    # the wheel: served on A, commanded on B for 3 s, it stays idle
    wheel = serve(A)
    listen = LoopbackMulticastBus(A)
    try:
        wait_for_wheel(listen)
        other = LoopbackMulticastBus(B)
        client = WheelClient(other, 0, clock=WallClock())
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            client.set_speed(3000.0)
            time.sleep(0.1)
        other.shutdown()
        speeds = []
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            msg = listen.recv(timeout=0.05)
            if msg is not None and msg.arbitration_id == proto.TELEMETRY_ID:
                speeds.append(proto.decode(msg).speed_rpm)
        result["speed_on_a"] = max(abs(s) for s in speeds)
        # and a command on A is obeyed (the test can fail)
        client = WheelClient(listen, 0, clock=WallClock())
        client.wait_ack(client.set_speed(300.0), timeout=2.0)
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            client.set_speed(300.0)
            time.sleep(0.1)
        result["speed_when_commanded_on_a"] = client.telemetry().speed_rpm
        client.close()
    finally:
        listen.shutdown()
        err = stop(wheel)
    result["serve_status"] = [line for line in err.splitlines() if "commands=" in line][-1:]
    return result


def twins() -> dict:
    result: dict = {}
    listen = LoopbackMulticastBus(A)
    first, second = serve_together(listen)
    tmp = tempfile.mkdtemp()
    try:
        late = serve(A)  # a wheel served later on the same id is refused at once
        late_err = late.communicate(timeout=30)[1]
        result["late_rc"], result["late_err"] = late.returncode, late_err.strip()[-400:]
        out = os.path.join(tmp, "rec.mcap")
        exp = subprocess.run(
            [
                py,
                "-m",
                "rwlab.cli",
                "experiment",
                "--interface",
                "udp_multicast",
                "--channel",
                A,
                "--signal",
                "step",
                "--amplitude",
                "300",
                "--duration",
                "4",
                "--Ts",
                "0.5",
                "--out",
                out,
            ],
            capture_output=True,
            text=True,
            timeout=90,
        )
        result["exp_rc"], result["exp_err"] = exp.returncode, exp.stderr.strip()[-600:]
        record = read_record(out)
        result["stop"] = [e["message"] for e in record.topic("/event") if e["kind"] == "stop"]
        result["error_events"] = [
            e["message"] for e in record.topic("/event") if e["kind"] == "error"
        ]
    finally:
        listen.shutdown()
        errs = [stop(first), stop(second)]
    result["serve_warned"] = ["WARNING: another wheel" in e for e in errs]
    return result


print(json.dumps({"channels": channels, "twins": twins}[sys.argv[1]]()))
