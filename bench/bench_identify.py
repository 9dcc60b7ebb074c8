"""Wall time of ``rwlab identify`` against ``rwlab ident arx`` on one record, and of ``rwlab demo``.

Run:  python bench/bench_identify.py [--record FILE.mcap] [--repeats 5] [--quick]
          [--baseline SRC] [--no-demo | --demo-only] [--demo-repeats N]

Makes a 25-minute PRBS record of the RW90 twin (simulated clock, seed 3) unless
``--record`` names one, then runs, ``--repeats`` times and back to back (so a busy
machine slows both alike), ``rwlab identify`` and ``rwlab ident arx FILE 2 2 1`` on it
as the command line does (a fresh process each: imports and the record's read
included), after one round not counted (numba's cache and Python's compiled modules
filled, even where PYTHONDONTWRITEBYTECODE is set). ``--baseline SRC``
also times ``identify`` from another source tree (e.g. ``git archive 96f5310 src |
tar -x -C /tmp/base`` and ``--baseline /tmp/base/src``), in the same rounds. The
table gives the median wall and CPU time (this process's children) with the spread
(min–max) and the ratio of the medians; the target (issue 45) is identify ≤ 2×
ident arx. Then ``rwlab demo`` (``--quick``: its quick version) with a fresh
numba cache: once cold (every kernel compiled), then ``--demo-repeats`` times warm
(the cache filled; with ``--baseline``, that tree's demo too, in the same rounds),
target ≤ 20 s warm on a quiet machine.

The machine's load average is printed with each table: on a shared machine the
numbers are an upper bound, and the spread says how far to trust them. A
benchmark, not a test.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def run(args: list[str], src: Path = SRC, env: dict | None = None) -> tuple[float, float]:
    """Wall and CPU seconds of ``python -m rwlab.cli ARGS`` with ``src`` first on the path."""
    env = {**os.environ, **(env or {}), "PYTHONPATH": str(src)}
    # as on a user's machine, compiled modules are cached (the uncounted round writes
    # them): a tree without them compiles every module it imports, each run (~0.1 s)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "rwlab.cli", *args], env=env, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"rwlab {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def make_record(folder: Path, duration: float) -> Path:
    path = folder / f"prbs_{duration:g}s.mcap"
    args = ["experiment", "--duration", str(duration), "--seed", "3", "--out", str(path)]
    wall, _ = run(args)
    print(f"made {path} ({duration:g} s PRBS, simulated clock) in {wall:.1f} s")
    return path


def load() -> str:
    return "load average " + " ".join(f"{x:.1f}" for x in os.getloadavg())


def spread(values: list[float]) -> str:
    return f"{statistics.median(values):7.2f} ({min(values):.2f}–{max(values):.2f})"


def bench_identify(record: Path, repeats: int, baseline: Path | None, out: Path) -> None:
    cases = {
        "ident arx": (["ident", "arx", str(record), "2", "2", "1"], SRC),
        "identify": (["identify", str(record), "--out", str(out / "new"), "--force"], SRC),
    }
    if baseline is not None:
        args = ["identify", str(record), "--out", str(out / "base"), "--force"]
        cases["identify (baseline)"] = (args, baseline)
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
    for args, src in cases.values():  # a round not counted: numba caches, disk caches
        run(args, src)
    print(f"\nidentify vs ident arx on {record.name}, {repeats} rounds ({load()} at start)")
    for _ in range(repeats):
        for name, (args, src) in cases.items():
            times[name].append(run(args, src))
    arx = times["ident arx"]
    print(f"{'command':<22} {'wall s, median (min–max)':>26} {'CPU s, median (min–max)':>26}")
    print(f"{'':<22} {'':>26} {'':>26}  ratio to arx (wall, CPU)")
    for name, rows in times.items():
        wall, cpu = [r[0] for r in rows], [r[1] for r in rows]
        ratio_w = statistics.median(wall) / statistics.median([r[0] for r in arx])
        ratio_c = statistics.median(cpu) / statistics.median([r[1] for r in arx])
        print(f"{name:<22} {spread(wall):>26} {spread(cpu):>26}  {ratio_w:5.2f}  {ratio_c:5.2f}")
    per_round = [t[0] / a[0] for t, a in zip(times["identify"], arx, strict=True)]
    print(f"identify / ident arx per round (wall): {', '.join(f'{r:.2f}' for r in per_round)}")
    print(f"target: identify ≤ 2× ident arx ({load()} at end)")


def bench_demo(quick: bool, out: Path, repeats: int = 1, baseline: Path | None = None) -> None:
    args = ["demo", "--out", str(out / "demo"), *(["--quick"] if quick else [])]
    trees = {"demo": SRC} | ({"demo (baseline)": baseline} if baseline is not None else {})
    # a fresh numba cache per tree: the first run compiles every kernel
    envs = {n: {"NUMBA_CACHE_DIR": str(out / f"numba-cache-{i}")} for i, n in enumerate(trees)}
    print(f"\nrwlab demo{' --quick' if quick else ''} ({load()} at start)")
    print(f"{'run':<34} {'wall s':>8} {'CPU s':>8}")
    for name, src in trees.items():
        wall, cpu = run(args, src, env=envs[name])
        print(f"{name + ', cold (numba cache empty)':<34} {wall:8.1f} {cpu:8.1f}")
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in trees}
    for _ in range(repeats):  # back to back, so a busy machine slows both alike
        for name, src in trees.items():
            times[name].append(run(args, src, env=envs[name]))
    print(f"warm (numba cache filled), {repeats} rounds: wall s and CPU s, median (min–max)")
    for name, rows in times.items():
        wall, cpu = [r[0] for r in rows], [r[1] for r in rows]
        print(f"{name:<22} {spread(wall):>26} {spread(cpu):>26}")
    print(f"target: ≤ 20 s warm on a quiet machine, the full demo ({load()} at end)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", type=Path, help="a record (default: a new 25-min PRBS)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline", type=Path, help="another source tree's src/ to time")
    parser.add_argument("--quick", action="store_true", help="3 rounds, the quick demo")
    parser.add_argument("--no-demo", action="store_true", help="skip the demo")
    parser.add_argument("--demo-only", action="store_true", help="only the demo")
    parser.add_argument("--demo-repeats", type=int, default=1, help="warm demo runs")
    args = parser.parse_args()
    repeats = 3 if args.quick else args.repeats
    with tempfile.TemporaryDirectory(prefix="bench_identify_") as tmp:
        out = Path(tmp)
        if not args.demo_only:
            record = args.record or make_record(out, 1500.0)
            bench_identify(record, repeats, args.baseline, out)
        if not args.no_demo:
            bench_demo(args.quick, out, args.demo_repeats, args.baseline)


if __name__ == "__main__":
    main()
