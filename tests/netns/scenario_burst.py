"""Issue 23: a served udp_multicast wheel and an experiment survive a burst of junk.

Run inside a private network namespace (tests/netns/run.py). Prints one JSON line.
"""

import itertools
import json
import os
import re
import select
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

import msgpack

from rwlab.testbed import read_record
from rwlab.wheel import protocol as proto
from rwlab.wheel.udp import LoopbackMulticastBus

GROUP, PORT, RATE = "239.74.163.2", 43113, 50.0
py = sys.executable
tmp = tempfile.mkdtemp()
out = os.path.join(tmp, "rec.mcap")
serve = subprocess.Popen(
    [
        py,
        "-m",
        "rwlab.cli",
        "wheel",
        "serve",
        "--interface",
        "udp_multicast",
        "--telemetry-rate",
        str(RATE),
        "--duration",
        "60",
    ],
    stderr=subprocess.PIPE,
    text=True,
)
monitor = LoopbackMulticastBus(GROUP)


wheel_source: list[str] = []


def telemetry_rate(seconds: float) -> float:
    """Valid telemetry frames per second from the served wheel, counted by a listener."""
    while monitor.recv(timeout=0) is not None or select.select([monitor], [], [], 0)[0]:
        pass  # the backlog is not this window's (recv stops after a bounded bite of junk)
    n, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        msg = monitor.recv(timeout=0.05)
        if msg is None or msg.arbitration_id != proto.TELEMETRY_ID:
            continue
        try:
            proto.decode(msg)
        except proto.ProtocolError:
            continue
        wheel_source[:] = wheel_source or [msg.channel]
        n += msg.channel == wheel_source[0]
    return n / seconds


def junk() -> list[bytes]:
    """Datagrams that are not valid wheel frames, of every kind we could think of."""

    def frame(arb: int, data: bytes, **kw) -> bytes:
        fields = {
            "timestamp": 0.0,
            "arbitration_id": arb,
            "is_extended_id": False,
            "is_remote_frame": False,
            "is_error_frame": False,
            "channel": None,
            "dlc": len(data),
            "data": data,
            "is_fd": len(data) > 8,
            "bitrate_switch": False,
            "error_state_indicator": False,
            **kw,
        }
        return msgpack.packb(fields, use_bin_type=True)

    huge = bytearray(struct.pack("<f", 1e30) + bytes([1, 7, 0, 0]))
    huge[7] = proto.frame_crc(0x100, huge)  # a valid frame asking for 1e30 rpm
    zero = bytes(8)  # passed the old sum checksum as IDLE
    bad_crc = bytearray(huge)
    bad_crc[7] ^= 1
    return [
        b"",
        b"hello",
        os.urandom(200),
        b"\xc0" * 40,
        msgpack.packb([1, 2, 3]),
        msgpack.packb({"what": "not a frame"}),
        msgpack.packb({"arbitration_id": "x"}),
        frame(0x100, zero),
        frame(0x100, bytes(bad_crc)),
        frame(0x100, b"\x01\x02\x03"),
        frame(0x100, os.urandom(64)),
        frame(0x555, os.urandom(8)),
        frame(0x100, bytes(huge)),
        frame(0x180, bytes(8)),
        b"\x82\xa4data\xc4" + os.urandom(30),
    ]


def burst(seconds: float, sent: list[int]) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", 0))
    kinds, end, n = junk(), time.monotonic() + seconds, 0
    while time.monotonic() < end:
        for datagram in kinds:
            sock.sendto(datagram, (GROUP, PORT))
            n += 1
        time.sleep(0.002)
    sent.append(n)


result: dict = {}
try:
    deadline = time.monotonic() + 30
    while telemetry_rate(0.5) == 0:
        if time.monotonic() > deadline or serve.poll() is not None:
            raise SystemExit("the wheel never answered")
    result["rate_before"] = telemetry_rate(1.0)
    exp = subprocess.Popen(
        [
            py,
            "-m",
            "rwlab.cli",
            "experiment",
            "--interface",
            "udp_multicast",
            "--signal",
            "step",
            "--amplitude",
            "600",
            "--duration",
            "7",  # still running through the burst (3 s on) and the second after it
            "--Ts",
            "0.5",
            "--out",
            out,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(3.0)
    sent: list[int] = []
    sender = threading.Thread(target=burst, args=(2.0, sent))
    sender.start()
    result["rate_during"] = telemetry_rate(2.0)
    sender.join()
    result["junk_sent"] = sent[0]
    result["rate_after"] = telemetry_rate(1.0)
    stdout, stderr = exp.communicate(timeout=90)
    result.update(exp_rc=exp.returncode, exp_stdout=stdout, exp_stderr=stderr[-2000:])
    record = read_record(out)
    result["complete"] = record.complete
    result["events"] = [(e["kind"], e["message"]) for e in record.topic("/event")]
    result["telemetry"] = len(record.topic("/telemetry"))
    times = [t["t"] for t in record.topic("/telemetry")]
    result["max_gap"] = max(b - a for a, b in itertools.pairwise(times))
    result["max_speed"] = max(abs(t["speed_rpm"]) for t in record.topic("/telemetry"))
    time.sleep(1.2)  # one more status line
finally:
    serve.terminate()
    _, serve_err = serve.communicate(timeout=20)
    monitor.shutdown()
result["serve_rc"] = serve.returncode
status = [line for line in serve_err.splitlines() if "bad=" in line]
result["serve_last_status"] = status[-1] if status else serve_err[-2000:]
numbers = {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)\b", result["serve_last_status"])}
result["serve_counts"] = numbers
print(json.dumps(result))
