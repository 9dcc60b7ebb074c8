"""The test suite's time per lane, against issue 45's targets, and its slowest steps.

Run:  python bench/bench_tests.py [--workers auto] [--lane quick|full|both] [--cold]

Rows: the quick lane (``python -m pytest -m "not slow"``, target ≤ 2 min) and the
whole suite (the README's ``python -m pytest``, target ≤ 5 min on a fresh clone, which
includes the install this script does not time), each with ``-n WORKERS`` (default
``auto``, as the suite runs: one worker per core; the targets are for 2
cores), wall time of the pytest process. ``--cold`` first removes numba's
cache (the ``__pycache__/*.nbi``/``*.nbc`` files under src/), as on a fresh clone.
Then the 25 slowest steps (setup, call or teardown) of the last lane, with whether the
test is marked ``slow``: a step of more than ~20 s in the quick lane is a candidate
for the mark or for a session fixture (tests/conftest.py). A benchmark, not a test: on
a machine shared with other work the times grow with the load.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LANES = {"quick": (["-m", "not slow"], 120.0), "full": ([], 300.0)}
_STEP = re.compile(r"^\s*([\d.]+)s (setup|call|teardown)\s+(\S+)$")


def clear_numba_cache() -> int:
    """Remove numba's cached kernels under src/; the number of files removed."""
    files = [p for ext in ("*.nbi", "*.nbc") for p in (ROOT / "src").rglob(ext)]
    for p in files:
        p.unlink()
    return len(files)


def run_lane(name: str, workers: str) -> tuple[float, int, list[tuple[float, str, str]]]:
    """Run one lane; its wall time (s), pytest's exit status and its slowest steps."""
    extra, _ = LANES[name]
    args = [sys.executable, "-m", "pytest", "-q", "-n", workers, "--durations=25", *extra]
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    start = time.perf_counter()
    done = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    steps = [
        (float(m[1]), m[2], m[3]) for line in done.stdout.splitlines() if (m := _STEP.match(line))
    ]
    if done.returncode not in (0, 1):
        sys.stderr.write(done.stdout[-3000:] + done.stderr[-3000:])
    for line in done.stdout.splitlines():  # a failing test named, whatever the lane's time
        if line.startswith(("FAILED", "ERROR")):
            sys.stderr.write(line + "\n")
    return wall, done.returncode, steps


def slow_marked(nodeid: str) -> bool:
    """Whether the test a node id names carries ``@pytest.mark.slow`` (or its module does)."""
    path, _, rest = nodeid.partition("::")
    name = rest.split("[")[0].split("::")[-1]
    text = (ROOT / path).read_text()
    if re.search(r"^pytestmark\s*=.*slow", text, re.M):
        return True
    m = re.search(rf"((?:^@.*\n)*)^(?:async )?def {re.escape(name)}\(", text, re.M)
    return bool(m and "slow" in m[1])


def main() -> None:
    """Print the lanes' table and the slowest steps."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", default="auto", help="pytest-xdist's -n (default: auto)")
    parser.add_argument("--lane", choices=("quick", "full", "both"), default="both")
    parser.add_argument("--cold", action="store_true", help="remove numba's cache first")
    opts = parser.parse_args()
    lanes = ["quick", "full"] if opts.lane == "both" else [opts.lane]
    rows, steps = [], []
    for lane in lanes:
        if opts.cold:
            print(f"removed {clear_numba_cache()} cached numba files", file=sys.stderr)
        wall, rc, steps = run_lane(lane, opts.workers)
        target = LANES[lane][1]
        rows.append((lane, opts.workers, wall, target, "yes" if wall <= target else "NO", rc))
    print(f"{'lane':<6} {'workers':>7} {'wall [s]':>9} {'target [s]':>10} {'met':>4} {'rc':>3}")
    for lane, n, wall, target, met, rc in rows:
        print(f"{lane:<6} {n:>7} {wall:>9.1f} {target:>10.0f} {met:>4} {rc:>3}")
    print(f"\nslowest steps of the {lanes[-1]} lane:")
    print(f"{'s':>7}  {'step':<8} {'slow':<4}  test")
    for seconds, step, nodeid in steps:
        mark = "yes" if slow_marked(nodeid) else "no"
        print(f"{seconds:>7.1f}  {step:<8} {mark:<4}  {nodeid}")


if __name__ == "__main__":
    main()
