"""Real-time hardware in the loop over udp_multicast, wheels in their own processes.

Run:  python bench/bench_hil_realtime.py [--duration 600] [--scenario geo-smallsat]
          [--telemetry-rate 50] [--out DIR]

Starts one ``rwlab wheel serve --interface udp_multicast`` process per wheel of
the scenario (node ids 1..N, the scenario's wheel parameters written to a TOML
file, a private multicast group), then flies ``rwlab hil --interface
udp_multicast --wheels-running --realtime`` against them and prints the
loop-timing table from ``metrics.json``: control period p50/p99, how late the
periods started (p50/p99/max, and the count later than 5 ms), the loop's own
compute time, commands lost (sent minus the wheels' heartbeat count) and
telemetry frames lost or stale. The wheel servers are stopped (SIGINT, by their
process ids) whatever happens. A benchmark, not a test: the figures depend on the
machine's load, which it prints beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rwlab.attitude.scenario import load_scenario
from rwlab.attitude.wheels import physics_params
from rwlab.hil.bench import twin_params_toml


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--scenario", default="geo-smallsat")
    ap.add_argument("--telemetry-rate", type=float, default=50.0)
    ap.add_argument("--channel", default="239.74.163.25")
    ap.add_argument("--out", default=None)
    ap.add_argument(
        "--rt-priority",
        type=int,
        default=None,
        help="SCHED_FIFO priority for the loop and the wheel servers (chrt; CAP_SYS_NICE)",
    )
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    work = Path(tempfile.mkdtemp(prefix="rwlab-hil-bench-"))
    out = Path(args.out) if args.out else work / "run"
    params = work / "wheel.toml"
    params.write_text(twin_params_toml(physics_params(sc)))
    rwlab = [sys.executable, "-m", "rwlab.cli"]
    rt = ["chrt", "-f", str(args.rt_priority)] if args.rt_priority else []
    servers = []
    try:
        for node in range(1, sc.n_wheels + 1):
            cmd = [
                *rt,
                *rwlab,
                "wheel", "serve", "--interface", "udp_multicast", "--channel", args.channel,
                "--node-id", str(node), "--params", str(params),
                "--telemetry-rate", str(args.telemetry_rate),
            ]  # fmt: skip
            servers.append(subprocess.Popen(cmd, stderr=subprocess.DEVNULL))
        time.sleep(3.0)  # the servers import and open the bus
        load = os.getloadavg()
        hil = [
            *rwlab,
            "hil", "--scenario", args.scenario, "--interface", "udp_multicast",
            "--channel", args.channel, "--wheels-running", "--realtime",
            "--duration", str(args.duration), "--no-reference", "--out", str(out), "--force",
        ]  # fmt: skip
        if args.rt_priority:
            hil += ["--rt-priority", str(args.rt_priority)]
        started = time.monotonic()
        subprocess.run(hil, check=True)
        wall = time.monotonic() - started
    finally:
        for p in servers:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in servers:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
    m = json.loads((out / "metrics.json").read_text())
    t, b = m["timing"], m["bench"]
    policy = f"SCHED_FIFO {args.rt_priority}" if args.rt_priority else "default scheduling"
    print(f"\n{args.duration:g} s over udp_multicast, {sc.n_wheels} wheel processes, {policy}, "
          f"control period {t['period_s']:g} s; load average before {load[0]:.1f} "
          f"(1 min) on {os.cpu_count()} cores; wall {wall:.0f} s")  # fmt: skip
    rows = [
        ("control periods", t["steps"], ""),
        ("period p50", t["period_p50_s"] * 1e3, "ms"),
        ("period p99", t["period_p99_s"] * 1e3, "ms"),
        ("period max", t["period_max_s"] * 1e3, "ms"),
        ("start late p50", t["lateness_p50_s"] * 1e3, "ms"),
        ("start late p99", t["lateness_p99_s"] * 1e3, "ms"),
        ("start late max", t["lateness_max_s"] * 1e3, "ms"),
        (f"periods late > {t['late_threshold_s'] * 1e3:g} ms", t["late_steps"], ""),
        ("loop compute p50", t["compute_p50_s"] * 1e3, "ms"),
        ("loop compute p99", t["compute_p99_s"] * 1e3, "ms"),
        ("commands lost", sum(v or 0 for v in b["lost_commands"].values()), ""),
        ("telemetry frames lost", sum(b["lost_telemetry_frames"].values()), ""),
        ("stale telemetry reads", sum(b["stale_telemetry_reads"].values()), ""),
        ("steady max pointing error", m["steady_max_error_deg"], "°"),
    ]
    print(f"{'figure':<28} {'value':>12}")
    for name, value, unit in rows:
        text = f"{value:.3f}" if isinstance(value, float) else str(value)
        print(f"{name:<28} {text:>12} {unit}")


if __name__ == "__main__":
    main()
