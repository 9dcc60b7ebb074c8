"""GEO closed-loop simulation speed: rwlab vs Basilisk on the same plant and step.

Run:  python bench/bench_attitude.py [--hours 2] [--peer SCRIPT --basilisk-python PATH]

Plant (both): J = diag(1200, 1000, 1500) kg·m², three orthogonal 50 N·m·s wheels,
gravity gradient plus a constant SRP-like torque (5, −3, 8)·1e-6 N·m, RK4 at
dt = 0.1 s, orbit-frame pointing from a 2° error, attitude feedback every step.
rwlab rows:
- "plant + PD (truth)": PD on the true state (Basilisk's mrpFeedback gains);
- "full LQG loop": the same plus sun/earth sensors every 0.5 s and the MEKF
  every step, the controller acting on the estimate.
Basilisk runs the peer script given with ``--peer`` (the project keeps none: use
the shared ``peers/basilisk_geo_peer.py`` beside the checkout, which needs PyPI
`bsk`) with the Python given (default: this one). It must print JSON lines with
``exec_s`` and ``hours``. Printed: wall seconds per simulated day. A benchmark,
not a test: numbers depend on the machine's load.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from rwlab.attitude.plant import DisturbanceModel
from rwlab.attitude.scenario import SCENARIOS
from rwlab.attitude.sim import PDController, simulate


def rwlab_case(hours: float, estimator: str) -> float:
    sc = SCENARIOS["geo-comsat"].with_(
        disturbances=DisturbanceModel(
            oblateness=False,
            solar_pressure=False,
            third_body=False,
            constant_torque=(5e-6, -3e-6, 8e-6),
        ),
        process_noise_torque=0.0,
    )
    ctl = PDController(kp=20.0, kd=400.0)  # mrpFeedback K = 40 on σ ≈ q_v/2, P = 400
    simulate(sc, ctl, duration=10, estimator=estimator)  # compile outside the timing
    t0 = time.perf_counter()
    r = simulate(sc, ctl, duration=hours * 3600, estimator=estimator, log_every=100)
    elapsed = time.perf_counter() - t0
    assert r.error_deg[-1] < 0.05, "the loop did not close"
    return elapsed / hours * 24


def basilisk_case(hours: float, peer: str | None, python: str) -> float | None:
    """Seconds per simulated day from the peer's JSON record lines, or None without one."""
    if peer is None:
        return None
    try:
        out = subprocess.run(
            [python, peer, "--hours", str(hours), "--dt", "0.1", "--repeats", "1"],
            capture_output=True,
            text=True,
            timeout=3600,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    for line in reversed(out.stdout.splitlines()):
        if line.startswith("{"):
            row = json.loads(line)
            return row["exec_s"] / row["hours"] * 24
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=2.0, help="simulated hours per case")
    parser.add_argument("--peer", help="the Basilisk peer script (not kept in the project)")
    parser.add_argument(
        "--basilisk-python",
        default=sys.executable,
        help="a Python that can import Basilisk (pip install bsk)",
    )
    args = parser.parse_args()
    rows = [
        ("rwlab plant + PD (truth), dt 0.1 s", rwlab_case(args.hours, "truth")),
        ("rwlab full LQG loop (sensors + MEKF), dt 0.1 s", rwlab_case(args.hours, "ekf")),
        (
            "Basilisk peer (mrpFeedback), dt 0.1 s",
            basilisk_case(args.hours, args.peer, args.basilisk_python),
        ),
    ]
    print(f"{'case':<50} {'s per simulated day':>20}")
    print("-" * 72)
    for name, value in rows:
        shown = "n/a (no peer or bsk)" if value is None else f"{value:20.1f}"
        print(f"{name:<50} {shown:>20}")


if __name__ == "__main__":
    main()
