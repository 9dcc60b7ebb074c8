"""Per-command latency of the NSP profiles against a served twin over a pty (wall clock).

Run:  python bench/bench_nsp_latency.py [--commands 20] [--only nsp/nrwa-t6 ...]

For each NSP profile it starts ``rwlab wheel serve --protocol P --interface
serial --channel pty`` in its own process, opens the pty it prints, and
measures from this process, one command at a time:

- ``ack ms``: ``WheelClient.set_speed`` (the request and the wheel's ACK on the
  wire, what the link counts as a delivered command);
- ``echo ms``: from the command to the telemetry that echoes it
  (``WheelClient.wait_ack``, what ``rwlab wheel cmd`` prints as "acknowledged in");
- ``cmd s``: the wall time of one ``rwlab wheel cmd P speed 300 --watch 0``
  process (interpreter start, imports, command, idle), the best of three, and
  ``start s`` the best of three of the same process's start-up and imports alone;
- ``keep-alive``: commands the twin counted during ``rwlab wheel cmd … --watch 2``
  (4 a second expected) and whether its 1 s watchdog fired.
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import time

from rwlab.wheel import WheelClient
from rwlab.wheel.bus import open_transport

NSP_PROFILES = ("nsp/nrwa-t6", "nsp/rw4-12", "nsp")
RWLAB = [sys.executable, "-m", "rwlab.cli"]


def serve(protocol: str) -> tuple[subprocess.Popen, str]:
    """Start a twin; return it and the pty path it answers on."""
    twin = subprocess.Popen(
        [*RWLAB, "wheel", "serve", "--protocol", protocol, "--interface", "serial",
         "--channel", "pty", "--duration", "60"],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert twin.stderr is not None
    for line in twin.stderr:
        if m := re.search(r"serial:(\S+);", line):
            return twin, m.group(1)
    raise RuntimeError(f"no pty from the {protocol} twin")


def in_process(protocol: str, path: str, commands: int) -> tuple[list[float], list[float]]:
    """ACK round trips and command-to-echo times, ms."""
    port = open_transport(protocol, "serial", path)
    client = WheelClient(port, 0, protocol=protocol, timeout=2.0)
    acks, echoes = [], []
    try:
        for i in range(commands):
            t0 = time.perf_counter()
            seq = client.set_speed(100.0 + i)
            t1 = time.perf_counter()
            client.wait_ack(seq)
            acks.append((t1 - t0) * 1e3)
            echoes.append((time.perf_counter() - t0) * 1e3)
            time.sleep(0.05)
    finally:
        client.close()
        port.close()
    return acks, echoes


def best_wall(argv: list[str], tries: int = 3) -> float:
    """The shortest wall time of ``tries`` runs of a process, s."""
    walls = []
    for _ in range(tries):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, capture_output=True)
        walls.append(time.perf_counter() - t0)
    return min(walls)


def cli_command(protocol: str, path: str) -> tuple[float, float]:
    """Wall time of one ``rwlab wheel cmd … --watch 0`` process and of its imports alone, s."""
    cmd = best_wall(
        [*RWLAB, "wheel", "cmd", "--protocol", protocol, "--interface", "serial",
         "--channel", path, "speed", "300", "--watch", "0"]
    )  # fmt: skip
    imports = "import rwlab.cli.wheel, rwlab.wheel.client, rwlab.wheel.nsp_t6"
    return cmd, best_wall([sys.executable, "-c", imports])


def keep_alive(protocol: str, twin: subprocess.Popen, path: str) -> tuple[int, bool]:
    """Commands the twin counted during a 2 s watch, and whether its watchdog fired."""
    subprocess.run(
        [*RWLAB, "wheel", "cmd", "--protocol", protocol, "--interface", "serial",
         "--channel", path, "speed", "300", "--watch", "2"],
        check=False, capture_output=True,
    )  # fmt: skip
    time.sleep(1.2)  # one more status line from the twin
    twin.terminate()
    _, err = twin.communicate(timeout=10)
    counts = [int(c) for c in re.findall(r"commands=(\d+)", err)]
    watchdog = "WATCHDOG" in err
    return (max(counts) if counts else 0), watchdog


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commands", type=int, default=20)
    parser.add_argument("--only", nargs="*", help="These profiles only.")
    args = parser.parse_args()
    print(
        f"{'profile':<12} {'ack ms med/max':>15} {'echo ms med/max':>16} {'cmd s':>6} "
        f"{'start s':>7} {'twin commands':>13} {'watchdog':>8}"
    )
    for protocol in args.only or NSP_PROFILES:
        twin, path = serve(protocol)
        try:
            acks, echoes = in_process(protocol, path, args.commands)
            wall, start = cli_command(protocol, path)
            seen, watchdog = keep_alive(protocol, twin, path)
        finally:
            twin.kill()
        print(
            f"{protocol:<12} {statistics.median(acks):7.2f}/{max(acks):7.2f} "
            f"{statistics.median(echoes):8.2f}/{max(echoes):7.2f} {wall:6.2f} {start:7.2f} "
            f"{seen:>13} {'fired' if watchdog else 'no':>8}"
        )


if __name__ == "__main__":
    main()
