"""Command/telemetry loop rate of WheelClient + WheelNode over python-can's virtual bus.

Run:  python bench/bench_wheel_loop.py [--rate 1000] [--seconds 5]

The host sends a speed command every 1/rate s, scheduled against absolute
time (t0 + k·T), and the node (its own thread, wall clock, zero added
latency, telemetry at the same rate) echoes each command's sequence number.
Printed: achieved loop rate, command-send jitter (actual − scheduled) and
command→echo latency percentiles, next to what classic CAN at 1 Mbit/s allows.
A benchmark, not a test: numbers depend on the machine's load.
"""

from __future__ import annotations

import argparse

import can
import numpy as np

from rwlab.wheel import WallClock, WheelClient, WheelNode


def can_frame_rate(bitrate: float = 1e6) -> tuple[float, float]:
    """8-byte standard frames per second at ``bitrate``: without and with worst-case stuffing."""
    bits = 111 + 3  # 11-bit id, 8 data bytes, CRC, ACK, EOF + interframe space
    worst = bits + (34 + 64 - 1) // 4  # stuff bits
    return bitrate / worst, bitrate / bits


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=1000.0, help="loop rate, Hz")
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    period = 1.0 / args.rate
    a = can.Bus(interface="virtual", channel="bench")
    b = can.Bus(interface="virtual", channel="bench")
    clock = WallClock()
    node = WheelNode(
        a, 0, clock=clock, telemetry_rate=min(args.rate, 1000.0), latency=0.0, physics_dt=1e-3
    ).start(poll_period=5e-5)
    jitter, latency = [], []
    sent: dict[int, float] = {}
    seen = 0
    with WheelClient(b, 0, clock=clock) as client:
        n = int(args.seconds * args.rate)
        t0 = clock.now() + 0.05
        for k in range(n):
            scheduled = t0 + k * period
            clock.sleep_until(scheduled)
            now = clock.now()
            jitter.append(now - scheduled)
            seq = client.set_speed(1000.0 if (k // 500) % 2 else -1000.0)
            sent[seq] = now
            client.poll()
            while seen < len(client.received):  # every frame, also those read inside set_speed
                t, tel = client.received[seen]
                seen += 1
                if tel.sequence_echo in sent:
                    latency.append(t - sent.pop(tel.sequence_echo))
        elapsed = clock.now() - t0
    node.stop()
    a.shutdown()
    b.shutdown()
    lo, hi = can_frame_rate()
    j = np.array(jitter) * 1e3
    lat = np.array(latency) * 1e3
    print(f"{'quantity':<44} {'value':>12}")
    print("-" * 58)
    print(f"{'target loop rate [Hz]':<44} {args.rate:12.0f}")
    print(f"{'achieved loop rate [Hz]':<44} {n / elapsed:12.1f}")
    print(
        f"{'send jitter p50 / p99 / max [ms]':<44} "
        f"{np.percentile(j, 50):.3f} / {np.percentile(j, 99):.3f} / {j.max():.3f}"
    )
    if lat.size:
        print(
            f"{'command→echo latency p50 / p99 [ms]':<44} "
            f"{np.percentile(lat, 50):.3f} / {np.percentile(lat, 99):.3f}"
        )
    print(f"{'echoes matched':<44} {lat.size:12d}")
    print(f"{'1 Mbit/s CAN, 8-byte frames [frames/s]':<44} {lo:6.0f}–{hi:.0f}")
    print(f"{'→ max command+telemetry loop per wheel [Hz]':<44} {lo / 2:6.0f}–{hi / 2:.0f}")


if __name__ == "__main__":
    main()
